//! mpmcg: an explicit Material Point Method with the continuous-gradient scheme
//! (MPMCG, Zhang, Ma & Giguere 2011), next to standard MPM, GIMP and the averaged
//! gradient, for 1D, 2D and 3D, distributed over MPI ranks.

// Axis loops `for a in 0..D` index several per-axis arrays at once; iterator chains
// would hide that symmetry.
#![allow(clippy::needless_range_loop)]
// `unsafe` only in the modules that allow it by name below, each block with its proof:
// the system calls (signals, the process lock, file-size limits, the CPU's features,
// HDF5 handles), the global allocator and the parallel writes of the coloured
// particle passes.
#![deny(unsafe_code)]

// Layers, each importing only from the ones above it in this list: input, physics,
// the MPM core, output, driver (tests/imports.rs checks it).
pub mod driver;
pub mod input;
pub mod mpm;
pub mod output;
pub mod physics;
