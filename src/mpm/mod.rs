//! The MPM core: particles (structure of arrays), the per-particle kernels of the
//! transfers, and the solver that runs a step as a list of named phases on one rank's
//! sparse grid (halo exchange and migration through the decomposition crate).

pub mod kernel;
pub mod particles;
#[allow(unsafe_code)] // Writes through `kernel::colour`'s pointers, each with its proof.
pub mod remap;
pub mod solver;
