//! Domain decomposition for a block-structured grid: partition of cells over ranks,
//! ghost layers two cells wide, halo exchange of nodal fields, particle migration, all
//! behind a [`Communicator`] trait. This crate knows nothing of materials or schemes:
//! it moves `f64` buffers.

pub mod block;
pub mod comm;
pub mod layout;

pub use block::Block;
pub use comm::{Communicator, MpiComm, SerialComm};
pub use layout::{Layout, GHOST};

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum Error {
    #[error("no ranks")]
    NoRanks,
    #[error("axis {axis}: {cells} cells cannot be split into {blocks} blocks of at least {min} cells")]
    BlocksTooSmall {
        axis: usize,
        cells: usize,
        blocks: usize,
        min: usize,
    },
    #[error("{ranks} ranks cannot each get a block of at least two cells per axis of a {cells:?} grid")]
    TooManyRanks { ranks: usize, cells: Vec<usize> },
}
