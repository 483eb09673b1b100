//! Output: parallel HDF5 snapshots with their XDMF index, checkpoints, and the lock
//! that keeps one run per output folder.

pub mod checkpoint;
pub mod io;
pub mod lock;
