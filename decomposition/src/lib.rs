//! Domain decomposition for a block-structured grid: partition of cells over ranks,
//! ghost layers two cells wide, halo exchange of nodal fields, particle migration, all
//! behind a [`Communicator`] trait. This crate knows nothing of materials or schemes:
//! it moves `f64` buffers.

#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Per-axis loops (`for a in 0..D`) index several `[_; D]` arrays by the same axis; an
// iterator over one of them would hide that symmetry.
#![allow(clippy::needless_range_loop)]

pub mod block;
pub mod comm;
pub mod layout;
pub mod local;
pub mod migrate;
mod odometer;
mod region;
pub mod splitmix;
pub mod tiles;
pub mod timed;
pub mod traffic;

pub use block::Block;
pub use comm::{Communicator, MpiComm, SerialComm};
pub use layout::{Layout, Profile, GHOST};
pub use local::LocalComm;
pub use migrate::{Destination, Migrator, Records};
pub use tiles::{Tiles, TILE};
pub use timed::{CommStats, Timed};
pub use traffic::Traffic;

/// What a partition or a migration could not do.
#[derive(Clone, Debug, thiserror::Error, PartialEq, Eq)]
pub enum Error {
    /// A layout for zero ranks was asked for.
    #[error("no ranks")]
    NoRanks,
    /// An axis has too few cells for its number of blocks.
    #[error(
        "axis {axis}: {cells} cells cannot be split into {blocks} blocks of at least {min} cells"
    )]
    BlocksTooSmall {
        /// The axis.
        axis: usize,
        /// Its cells.
        cells: usize,
        /// The blocks asked for along it.
        blocks: usize,
        /// The fewest cells a block may have.
        min: usize,
    },
    /// Block boundaries that do not cut an axis into ascending blocks of the minimum
    /// width.
    #[error(
        "axis {axis}: cuts {cuts:?} do not split {cells} cells into blocks of at least {min} cells"
    )]
    BadCuts {
        /// The axis.
        axis: usize,
        /// The cuts given.
        cuts: Vec<usize>,
        /// The axis' cells.
        cells: usize,
        /// The fewest cells a block may have.
        min: usize,
    },
    /// No process grid gives every rank a block of at least two cells per axis.
    #[error(
        "{ranks} ranks cannot each get a block of at least two cells per axis of a {cells:?} grid"
    )]
    TooManyRanks {
        /// The rank count.
        ranks: usize,
        /// The grid's cells per axis.
        cells: Vec<usize>,
    },
    /// A particle moved past the ghost layer of its block in one step.
    #[error("rank {rank}: a particle moved to cell {cell:?}, more than {ghost} cells past its block {lo:?}..{hi:?} in one step; lower the time step (CFL number)", ghost = layout::GHOST)]
    ParticleTooFast {
        /// The rank it left.
        rank: usize,
        /// Its new cell (global, unwrapped).
        cell: Vec<i64>,
        /// The first owned cell of the block.
        lo: Vec<usize>,
        /// One past the last owned cell of the block.
        hi: Vec<usize>,
    },
    /// A particle left the grid through a face that is not periodic.
    #[error("rank {rank}: a particle left the grid through a non-periodic boundary (cell {cell:?} of a {cells:?} grid)")]
    OutsideGrid {
        /// The rank it left.
        rank: usize,
        /// Its new cell (global, unwrapped).
        cell: Vec<i64>,
        /// The grid's cells per axis.
        cells: Vec<usize>,
    },
    /// Reported by every other rank when particle migration failed on `rank`, so that
    /// all ranks stop together instead of waiting for it in the next collective.
    #[error("particle migration failed on rank {rank}")]
    MigrationFailedElsewhere {
        /// The rank where it failed.
        rank: usize,
    },
}

#[cfg(test)]
mod tests;
