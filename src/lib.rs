//! mpmcg: an explicit Material Point Method with the continuous-gradient scheme
//! (MPMCG, Zhang, Ma & Giguere 2011), next to standard MPM, GIMP and the averaged
//! gradient, for 1D, 2D and 3D, distributed over MPI ranks.

// Axis loops `for a in 0..D` index several per-axis arrays at once; iterator chains
// would hide that symmetry.
#![allow(clippy::needless_range_loop)]

pub mod benchmark;
pub mod checkpoint;
pub mod cli;
pub mod gradient;
pub mod io;
pub mod kernel;
pub mod lock;
pub mod material;
pub mod particles;
pub mod progress;
pub mod run;
pub mod scene;
pub mod shape;
pub mod signals;
pub mod solver;
pub mod sweep;
pub mod tensor;
