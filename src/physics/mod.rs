//! Physics: what the method computes with, independent of grids, ranks and files:
//! small tensors, the grid geometry and shape functions, the gradient schemes'
//! weights, the materials and the benchmarks' exact solutions.

pub mod benchmark;
pub mod gradient;
pub mod material;
pub mod shape;
pub mod tensor;
