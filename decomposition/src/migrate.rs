//! Particle migration: moving particles whose cell left the block to the cell's owner.
//!
//! The crate knows nothing of particle state, so a particle travels as a fixed-width
//! record of `f64` packed and unpacked by the caller (ids as `f64` are exact below
//! 2^53). One step:
//!
//! ```
//! # use decomposition::{Block, Communicator, Layout, Migrator, SerialComm};
//! # let layout = Layout::new([8], [true], [1]).unwrap();
//! # let block = Block::new(&layout, 0);
//! # let comm = SerialComm;
//! let mut mig = Migrator::new(&layout, &block, 2);
//! // After the position update, for each particle:
//! let (id, x) = (7.0, 8.25_f64); // unit cells: cell 8, one past the periodic end
//! match mig.destination([x.floor() as i64]) {
//!     Ok(d) if d.rank == comm.rank() => { /* stays; d.cell is its wrapped cell */ }
//!     Ok(d) => mig.push(d.rank, &[id, x]), // and remove it locally
//!     Err(e) => mig.fail(e),               // never return early: see `exchange`
//! }
//! for rec in mig.exchange(&comm).unwrap() { /* rec: &[f64], append the particle */ }
//! ```
//!
//! A particle may move at most [`GHOST`] cells per step (the ghost layer is what its
//! new cell's owner shares with this rank), so its destination is always a halo peer
//! and one exchange with the peers suffices: no global communication of particles.

use crate::block::Block;
use crate::comm::Communicator;
use crate::layout::{Layout, GHOST};
use crate::traffic::Traffic;
use crate::Error;

/// Where a particle belongs after a move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Destination<const D: usize> {
    /// Owner of the particle's cell.
    pub rank: usize,
    /// The cell, wrapped into `[0, cells)` on periodic axes.
    pub cell: [usize; D],
}

/// Per-peer send buffers of fixed-width records and the exchange that delivers them.
///
/// Buffers are kept between steps, so once they have grown to the largest migration
/// seen, a step allocates nothing (beyond what the communicator itself does).
#[derive(Clone, Debug)]
pub struct Migrator<const D: usize> {
    rank: usize,
    width: usize,
    layout: Layout<D>,
    cell_lo: [usize; D],
    cell_hi: [usize; D],
    /// Halo peers and this rank, ascending: the only possible destinations.
    peers: Vec<usize>,
    send: Vec<Vec<f64>>,
    recv: Vec<Vec<f64>>,
    received: Vec<f64>,
    error: Option<Error>,
    /// What the exchanges sent to other ranks so far.
    traffic: Traffic,
}

impl<const D: usize> Migrator<D> {
    /// Migration for `block` of `layout`, with records of `width` values.
    pub fn new(layout: &Layout<D>, block: &Block<D>, width: usize) -> Self {
        assert!(width > 0, "a migration record needs at least one value");
        let mut peers = block.peers().to_vec();
        // This rank too: the exchange then covers a caller that routes a staying
        // particle through it, and peers stay symmetric on both sides.
        if let Err(i) = peers.binary_search(&block.rank) {
            peers.insert(i, block.rank);
        }
        debug_assert!(peers.windows(2).all(|w| w[0] < w[1]));
        let n = peers.len();
        Self {
            rank: block.rank,
            width,
            layout: layout.clone(),
            cell_lo: block.cell_lo,
            cell_hi: block.cell_hi,
            peers,
            send: vec![Vec::new(); n],
            recv: vec![Vec::new(); n],
            received: Vec::new(),
            error: None,
            traffic: Traffic::default(),
        }
    }

    /// Migration from `block` to the owners of `layout`, another layout of the same
    /// grid and rank count (a rebalance): a particle's new owner need not be a halo
    /// peer, so every rank is a peer and an exchange sends `ranks − 1` messages per
    /// rank, most of them empty. Route with [`Layout::cell_owner`] of the new layout
    /// and [`Migrator::push`]; [`Migrator::destination`] still checks the reach from
    /// `block`.
    pub fn everywhere(layout: &Layout<D>, block: &Block<D>, width: usize) -> Self {
        let mut m = Self::new(layout, block, width);
        let n = layout.ranks();
        m.peers = (0..n).collect();
        m.send = vec![Vec::new(); n];
        m.recv = vec![Vec::new(); n];
        m
    }

    /// Values per record.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Ranks records can be sent to (halo peers and this rank), ascending.
    pub fn peers(&self) -> &[usize] {
        &self.peers
    }

    /// Where a particle of this block belongs once it is in global cell `cell`.
    ///
    /// `cell` may lie outside `[0, cells)` on periodic axes (an unwrapped position);
    /// any periodic image of it within [`GHOST`] cells of the block is accepted, so
    /// the caller may wrap positions whenever it likes. Errors: [`Error::OutsideGrid`]
    /// past a bounded axis, [`Error::ParticleTooFast`] if the cell is farther than
    /// [`GHOST`] cells from the block (its owner might not be a peer, and the grid
    /// transfer of the step was already wrong).
    pub fn destination(&self, cell: [i64; D]) -> Result<Destination<D>, Error> {
        let l = &self.layout;
        for a in 0..D {
            if !l.periodic[a] && !(0..l.cells[a] as i64).contains(&cell[a]) {
                return Err(Error::OutsideGrid {
                    rank: self.rank,
                    cell: cell.to_vec(),
                    cells: l.cells.to_vec(),
                });
            }
        }
        let mut wrapped = [0usize; D];
        for a in 0..D {
            let n = l.cells[a] as i64;
            let reach_lo = self.cell_lo[a] as i64 - GHOST as i64;
            let span = (self.cell_hi[a] - self.cell_lo[a] + 2 * GHOST) as i64;
            let within = if l.periodic[a] {
                span >= n || (cell[a] - reach_lo).rem_euclid(n) < span
            } else {
                (reach_lo..reach_lo + span).contains(&cell[a])
            };
            if !within {
                return Err(Error::ParticleTooFast {
                    rank: self.rank,
                    cell: cell.to_vec(),
                    lo: self.cell_lo.to_vec(),
                    hi: self.cell_hi.to_vec(),
                });
            }
            wrapped[a] = cell[a].rem_euclid(n) as usize;
        }
        Ok(Destination {
            rank: l.cell_owner(wrapped),
            cell: wrapped,
        })
    }

    /// Queue a record for `rank`, which must be one of [`Migrator::peers`] (any rank
    /// returned by [`Migrator::destination`] is).
    ///
    /// # Panics
    /// If `rank` is not a peer or `record` is not [`Migrator::width`] long: both are
    /// programming errors, not bad input.
    pub fn push(&mut self, rank: usize, record: &[f64]) {
        assert_eq!(record.len(), self.width, "migration record of wrong width");
        let k = self
            .peers
            .binary_search(&rank)
            .unwrap_or_else(|_| panic!("rank {rank} is not a migration peer of {}", self.rank));
        self.send[k].extend_from_slice(record);
    }

    /// Record a routing error; the next [`Migrator::exchange`] reports it on every rank.
    /// Only the first error is kept.
    pub fn fail(&mut self, err: Error) {
        self.error.get_or_insert(err);
    }

    /// What [`Migrator::exchange`] has sent to other ranks since this migrator was
    /// made: bytes of records, non-empty messages and the number of exchanges (one that
    /// failed sends nothing and is not counted). Records a rank routes to itself are
    /// not counted.
    pub fn traffic(&self) -> Traffic {
        self.traffic
    }

    /// Records queued so far for all peers.
    pub fn queued(&self) -> usize {
        self.send.iter().map(Vec::len).sum::<usize>() / self.width
    }

    /// Collective: deliver the queued records and return those received, ordered by
    /// source rank, then by the order the source pushed them (so the result is
    /// deterministic). Send buffers are emptied.
    ///
    /// If any rank recorded an error with [`Migrator::fail`], nothing is exchanged and
    /// every rank returns an error: its own, or [`Error::MigrationFailedElsewhere`]
    /// naming the lowest failing rank. This costs one scalar reduction, and is what
    /// keeps a rank that fails alone from leaving the others blocked; a caller that
    /// agrees on [`Migrator::failed`] in a reduction of its own calls
    /// [`Migrator::exchange_agreed`] instead.
    pub fn exchange(&mut self, comm: &dyn Communicator) -> Result<Records<'_>, Error> {
        let mut failed = [if self.failed() {
            self.rank as f64
        } else {
            f64::INFINITY
        }];
        comm.min_f64(&mut failed);
        let first = failed[0].is_finite().then_some(failed[0] as usize);
        self.exchange_agreed(comm, first)
    }

    /// Whether this rank recorded an error with [`Migrator::fail`].
    pub fn failed(&self) -> bool {
        self.error.is_some()
    }

    /// [`Migrator::exchange`] once every rank knows the lowest rank that recorded an
    /// error (`None`: none did), agreed by the caller: the same on every rank.
    pub fn exchange_agreed(
        &mut self,
        comm: &dyn Communicator,
        failed: Option<usize>,
    ) -> Result<Records<'_>, Error> {
        self.received.clear();
        if let Some(rank) = failed {
            for s in &mut self.send {
                s.clear();
            }
            return Err(self
                .error
                .take()
                .unwrap_or(Error::MigrationFailedElsewhere { rank }));
        }
        self.traffic.record(self.rank, &self.peers, &self.send);
        comm.exchange(&self.peers, &self.send, &mut self.recv);
        for s in &mut self.send {
            s.clear();
        }
        for r in &self.recv {
            assert_eq!(
                r.len() % self.width,
                0,
                "ranks disagree on the record width"
            );
            self.received.extend_from_slice(r);
        }
        Ok(Records {
            data: &self.received,
            width: self.width,
        })
    }
}

/// Records received by [`Migrator::exchange`], in delivery order.
#[derive(Clone, Copy, Debug)]
pub struct Records<'a> {
    data: &'a [f64],
    width: usize,
}

impl<'a> Records<'a> {
    /// Number of records.
    pub fn len(&self) -> usize {
        self.data.len() / self.width
    }
    /// Whether there are no records.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }
    /// All records back to back.
    pub fn as_slice(&self) -> &'a [f64] {
        self.data
    }
    /// The records, one slice of `width` values each.
    pub fn iter(&self) -> std::slice::ChunksExact<'a, f64> {
        self.data.chunks_exact(self.width)
    }
}

impl<'a> IntoIterator for Records<'a> {
    type Item = &'a [f64];
    type IntoIter = std::slice::ChunksExact<'a, f64>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}
