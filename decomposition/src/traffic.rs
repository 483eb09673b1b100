//! [`Traffic`]: what a rank's exchanges sent to other ranks, counted as they happen.
//!
//! Halo operations ([`crate::Block::ghost_sum`], [`crate::Block::ghost_copy`]) and
//! particle migration ([`crate::Migrator::exchange`]) each keep one, read with
//! [`crate::Block::traffic`] and [`crate::Migrator::traffic`]. The counts are what the
//! data would cost on a network, so a rank's exchange with itself (a periodic face on
//! one rank, a particle routed to its own rank) is left out: that is a local copy.
//! They are plain integers updated once per exchange, so counting costs nothing
//! measurable and changes no result.

use std::ops::{AddAssign, Sub};

/// Cumulative counts of one kind of exchange on one rank.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Traffic {
    /// Exchanges (calls) counted, whether or not they sent anything.
    pub exchanges: u64,
    /// Bytes of payload sent to other ranks (the `f64` values, 8 bytes each; not the
    /// length each [`crate::MpiComm`] exchange sends ahead of the data).
    pub bytes: u64,
    /// Non-empty buffers sent to other ranks: one message each.
    pub messages: u64,
}

impl Traffic {
    /// Count one exchange of `sends[k]` to `peers[k]` by rank `me`.
    pub fn record(&mut self, me: usize, peers: &[usize], sends: &[Vec<f64>]) {
        self.exchanges += 1;
        for (&p, s) in peers.iter().zip(sends) {
            if p != me && !s.is_empty() {
                self.bytes += (s.len() * std::mem::size_of::<f64>()) as u64;
                self.messages += 1;
            }
        }
    }
}

impl AddAssign for Traffic {
    /// Accumulate, e.g. the counts of a block that a rebalance replaces.
    fn add_assign(&mut self, o: Self) {
        self.exchanges += o.exchanges;
        self.bytes += o.bytes;
        self.messages += o.messages;
    }
}

impl Sub for Traffic {
    type Output = Self;
    /// The counts since an earlier reading `o` of the same counter.
    fn sub(self, o: Self) -> Self {
        Self {
            exchanges: self.exchanges - o.exchanges,
            bytes: self.bytes - o.bytes,
            messages: self.messages - o.messages,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Block, Communicator, Layout, LocalComm, Migrator, SerialComm};

    /// From the geometry alone, without the halo lists: per rank, the ghost nodes of
    /// its box owned by another rank, and how many distinct other ranks own them.
    fn foreign_ghosts<const D: usize>(layout: &Layout<D>, rank: usize) -> (usize, usize) {
        let b = Block::new(layout, rank);
        let mut owners = std::collections::BTreeSet::new();
        let mut count = 0;
        for i in 0..b.num_nodes() {
            let c = b.coords(i);
            if b.is_owned(c) {
                continue;
            }
            let w = layout.wrap_node(b.global(c)).expect("box inside the grid");
            let owner = layout.node_owner(w);
            if owner != rank {
                count += 1;
                owners.insert(owner);
            }
        }
        (count, owners.len())
    }

    /// Run one ghost_sum and one ghost_copy of `ncomp` components on every rank and
    /// check the counts against the geometry: a ghost sum sends each ghost node owned
    /// elsewhere once; a ghost copy sends each such node from its owner, so the bytes
    /// over all ranks are the same.
    fn check<const D: usize>(layout: &Layout<D>, ncomp: usize) {
        let got = LocalComm::run(layout.ranks(), |comm| {
            let mut b = Block::new(layout, comm.rank());
            let mut f = vec![1.0; b.num_nodes() * ncomp];
            b.ghost_sum(comm, &mut f, ncomp);
            let after_sum = b.traffic();
            b.ghost_copy(comm, &mut f, ncomp);
            (after_sum, b.traffic() - after_sum)
        });
        let mut total = 0;
        for (rank, (sum, copy)) in got.iter().enumerate() {
            let (nodes, owners) = foreign_ghosts(layout, rank);
            assert_eq!(sum.exchanges, 1);
            assert_eq!(
                sum.bytes,
                (nodes * ncomp * 8) as u64,
                "{layout:?} rank {rank}"
            );
            assert_eq!(sum.messages, owners as u64, "{layout:?} rank {rank}");
            assert_eq!(copy.exchanges, 1);
            total += nodes;
        }
        let copied: u64 = got.iter().map(|(_, c)| c.bytes).sum();
        assert_eq!(copied, (total * ncomp * 8) as u64, "{layout:?}");
    }

    /// Halo bytes and messages equal what the geometry says, including periodic axes
    /// with one block (its own ghosts: not counted) and two (the same neighbour on both
    /// sides: one message, both faces' bytes).
    #[test]
    fn halo_counts_match_the_geometry() {
        check(&Layout::new([12], [false], [3]).unwrap(), 2);
        check(&Layout::new([12], [true], [2]).unwrap(), 1);
        check(&Layout::new([9, 7], [false, false], [2, 3]).unwrap(), 3);
        check(&Layout::new([9, 8], [true, false], [1, 2]).unwrap(), 4);
        check(&Layout::new([8, 8], [true, true], [2, 2]).unwrap(), 2);
        check(
            &Layout::new([6, 5, 7], [false, true, false], [2, 1, 3]).unwrap(),
            3,
        );
        // A check of the reference itself, by hand: rank 1 of a 12-cell line in three
        // blocks owns nodes 4..8; its box 2..=10 (two ghost cells a side) has ghosts 2
        // and 3 (rank 0's) and 8, 9 and 10 (rank 2's).
        assert_eq!(crate::GHOST, 2);
        let line = Layout::new([12], [false], [3]).unwrap();
        assert_eq!(foreign_ghosts(&line, 1), (5, 2));
    }

    /// One rank sends nothing, periodic or not, and a ghost sum still counts as an
    /// exchange.
    #[test]
    fn one_rank_sends_nothing() {
        for per in [[false, false], [true, true]] {
            let layout = Layout::new([6, 5], per, [1, 1]).unwrap();
            let mut b = Block::new(&layout, 0);
            let mut f = vec![1.0; b.num_nodes() * 2];
            b.ghost_sum(&SerialComm, &mut f, 2);
            b.ghost_copy(&SerialComm, &mut f, 2);
            let mut m = Migrator::new(&layout, &b, 3);
            m.push(0, &[1.0, 2.0, 3.0]);
            m.exchange(&SerialComm).unwrap();
            let t = Traffic {
                exchanges: 2,
                ..Traffic::default()
            };
            assert_eq!(b.traffic(), t);
            assert_eq!(m.traffic(), Traffic { exchanges: 1, ..t });
        }
    }

    /// Migration counts the records sent to other ranks, not those a rank routes to
    /// itself, and one message per rank that gets any.
    #[test]
    fn migration_counts_records_to_other_ranks() {
        let layout = Layout::new([12], [true], [3]).unwrap();
        let got = LocalComm::run(3, |comm| {
            let me = comm.rank();
            let b = Block::new(&layout, me);
            let mut m = Migrator::new(&layout, &b, 2);
            // Rank r sends r+1 records to its upper neighbour and one to itself.
            for _ in 0..=me {
                m.push((me + 1) % 3, &[0.0, 1.0]);
            }
            m.push(me, &[0.0, 1.0]);
            let received = m.exchange(comm).unwrap().len();
            (m.traffic(), received)
        });
        for (me, (t, received)) in got.iter().enumerate() {
            assert_eq!(t.exchanges, 1);
            assert_eq!(t.bytes, ((me + 1) * 2 * 8) as u64);
            assert_eq!(t.messages, 1);
            assert_eq!(*received, (me + 2) % 3 + 1 + 1);
        }
    }
}
