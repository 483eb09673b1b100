//! Output: parallel HDF5 snapshots with their XDMF index, checkpoints, and the lock
//! that keeps one run per output folder.

pub mod checkpoint;
#[allow(unsafe_code)] // HDF5 handles closed by hand; the file-size limit.
pub mod io;
#[allow(unsafe_code)] // `gethostname` and `kill(pid, 0)` for the run lock.
pub mod lock;
