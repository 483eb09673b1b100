//! Domain decomposition for a block-structured grid: partition of cells over ranks,
//! ghost layers two cells wide, halo exchange of nodal fields, particle migration, all
//! behind a [`Communicator`] trait. This crate knows nothing of materials or schemes:
//! it moves `f64` buffers.

// Per-axis loops (`for a in 0..D`) index several `[_; D]` arrays by the same axis; an
// iterator over one of them would hide that symmetry.
#![allow(clippy::needless_range_loop)]

pub mod block;
pub mod comm;
pub mod layout;
pub mod local;
pub mod migrate;
pub mod splitmix;
pub mod tiles;

pub use block::Block;
pub use comm::{Communicator, MpiComm, SerialComm};
pub use layout::{Layout, GHOST};
pub use local::LocalComm;
pub use migrate::{Destination, Migrator, Records};
pub use tiles::{Tiles, TILE};

#[derive(Clone, Debug, thiserror::Error, PartialEq, Eq)]
pub enum Error {
    #[error("no ranks")]
    NoRanks,
    #[error(
        "axis {axis}: {cells} cells cannot be split into {blocks} blocks of at least {min} cells"
    )]
    BlocksTooSmall {
        axis: usize,
        cells: usize,
        blocks: usize,
        min: usize,
    },
    #[error(
        "{ranks} ranks cannot each get a block of at least two cells per axis of a {cells:?} grid"
    )]
    TooManyRanks { ranks: usize, cells: Vec<usize> },
    #[error("rank {rank}: a particle moved to cell {cell:?}, more than {ghost} cells past its block {lo:?}..{hi:?} in one step; lower the time step (CFL number)", ghost = layout::GHOST)]
    ParticleTooFast {
        rank: usize,
        cell: Vec<i64>,
        lo: Vec<usize>,
        hi: Vec<usize>,
    },
    #[error("rank {rank}: a particle left the grid through a non-periodic boundary (cell {cell:?} of a {cells:?} grid)")]
    OutsideGrid {
        rank: usize,
        cell: Vec<i64>,
        cells: Vec<usize>,
    },
    /// Reported by every other rank when particle migration failed on `rank`, so that
    /// all ranks stop together instead of waiting for it in the next collective.
    #[error("particle migration failed on rank {rank}")]
    MigrationFailedElsewhere { rank: usize },
}

#[cfg(test)]
mod tests;
