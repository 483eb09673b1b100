//! A communicator that counts and times what passes through it on this rank: how
//! often a run synchronises, and how long a rank waits there for the others.

use crate::Communicator;
use std::cell::Cell;
use std::time::Instant;

/// Calls through a [`Timed`] communicator on this rank, and the seconds spent in them:
/// the time a rank is blocked in a collective or an exchange, waiting for the slowest
/// rank included.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CommStats {
    /// Collectives: reductions, scans, gathers and broadcasts (`any` is one).
    pub collectives: u64,
    /// Seconds in collectives.
    pub collective_seconds: f64,
    /// Exchanges with the peers ([`Communicator::exchange`]), one round each.
    pub exchanges: u64,
    /// Seconds in exchanges.
    pub exchange_seconds: f64,
}

impl CommStats {
    /// `self` and `other` together.
    pub fn plus(&self, other: &CommStats) -> CommStats {
        CommStats {
            collectives: self.collectives + other.collectives,
            collective_seconds: self.collective_seconds + other.collective_seconds,
            exchanges: self.exchanges + other.exchanges,
            exchange_seconds: self.exchange_seconds + other.exchange_seconds,
        }
    }

    /// What happened between `earlier` and `self`.
    pub fn since(&self, earlier: &CommStats) -> CommStats {
        CommStats {
            collectives: self.collectives - earlier.collectives,
            collective_seconds: self.collective_seconds - earlier.collective_seconds,
            exchanges: self.exchanges - earlier.exchanges,
            exchange_seconds: self.exchange_seconds - earlier.exchange_seconds,
        }
    }
}

/// `inner` with every collective and exchange counted and timed ([`CommStats`]). One
/// clock read before and after each call: tens of nanoseconds against the microseconds
/// of a message.
pub struct Timed<'a> {
    inner: &'a dyn Communicator,
    stats: Cell<CommStats>,
}

impl<'a> Timed<'a> {
    /// Count and time the calls through `inner` from now on.
    pub fn new(inner: &'a dyn Communicator) -> Self {
        Timed {
            inner,
            stats: Cell::new(CommStats::default()),
        }
    }

    /// The calls so far.
    pub fn stats(&self) -> CommStats {
        self.stats.get()
    }

    fn collective<T>(&self, f: impl FnOnce() -> T) -> T {
        let t0 = Instant::now();
        let r = f();
        let mut s = self.stats.get();
        s.collectives += 1;
        s.collective_seconds += t0.elapsed().as_secs_f64();
        self.stats.set(s);
        r
    }
}

impl Communicator for Timed<'_> {
    fn rank(&self) -> usize {
        self.inner.rank()
    }
    fn size(&self) -> usize {
        self.inner.size()
    }
    fn sum_f64(&self, x: &mut [f64]) {
        self.collective(|| self.inner.sum_f64(x))
    }
    fn max_f64(&self, x: &mut [f64]) {
        self.collective(|| self.inner.max_f64(x))
    }
    fn min_f64(&self, x: &mut [f64]) {
        self.collective(|| self.inner.min_f64(x))
    }
    fn sum_u64(&self, x: &mut [u64]) {
        self.collective(|| self.inner.sum_u64(x))
    }
    fn node_sum_u64(&self, x: &mut [u64]) {
        self.collective(|| self.inner.node_sum_u64(x))
    }
    fn exclusive_scan_u64(&self, x: u64) -> u64 {
        self.collective(|| self.inner.exclusive_scan_u64(x))
    }
    fn exchange(&self, peers: &[usize], sends: &[Vec<f64>], recvs: &mut [Vec<f64>]) {
        let t0 = Instant::now();
        self.inner.exchange(peers, sends, recvs);
        let mut s = self.stats.get();
        s.exchanges += 1;
        s.exchange_seconds += t0.elapsed().as_secs_f64();
        self.stats.set(s);
    }
    fn any(&self, flag: bool) -> bool {
        self.collective(|| self.inner.any(flag))
    }
    fn gather_bytes(&self, data: &[u8]) -> Vec<Vec<u8>> {
        self.collective(|| self.inner.gather_bytes(data))
    }
    fn broadcast_bytes(&self, data: &[u8]) -> Vec<u8> {
        self.collective(|| self.inner.broadcast_bytes(data))
    }
    fn raw_mpi(&self) -> Option<mpi::ffi::MPI_Comm> {
        self.inner.raw_mpi()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{LocalComm, SerialComm};

    #[test]
    fn every_call_is_counted_once_by_its_kind() {
        let serial = SerialComm;
        let t = Timed::new(&serial);
        let mut x = [1.0, 2.0];
        t.sum_f64(&mut x);
        t.max_f64(&mut x);
        t.min_f64(&mut x);
        t.sum_u64(&mut [3]);
        assert_eq!(t.exclusive_scan_u64(5), 0);
        // `any` is one reduction, not the inner one counted twice.
        assert!(t.any(true));
        assert_eq!(t.gather_bytes(b"ab"), vec![b"ab".to_vec()]);
        assert_eq!(t.broadcast_bytes(b"c"), b"c".to_vec());
        let mut recv = vec![Vec::new()];
        t.exchange(&[0], &[vec![4.0]], &mut recv);
        assert_eq!(recv, vec![vec![4.0]]);
        // Results pass through unchanged.
        assert_eq!(x, [1.0, 2.0]);
        let s = t.stats();
        assert_eq!((s.collectives, s.exchanges), (8, 1));
        assert!(s.collective_seconds >= 0.0 && s.exchange_seconds >= 0.0);
        let later = t.stats();
        t.max_f64(&mut x);
        let d = t.stats().since(&later);
        assert_eq!((d.collectives, d.exchanges), (1, 0));
        assert_eq!(later.plus(&d), t.stats());
    }

    #[test]
    fn ranks_count_the_same_calls_and_reduce_through_the_wrapper() {
        let counts = LocalComm::run(3, |c| {
            let t = Timed::new(c);
            let mut x = [c.rank() as f64];
            t.sum_f64(&mut x);
            assert_eq!(x, [3.0]);
            let peers: Vec<usize> = (0..3).filter(|&p| p != c.rank()).collect();
            let sends = vec![vec![c.rank() as f64]; 2];
            let mut recvs = vec![Vec::new(); 2];
            t.exchange(&peers, &sends, &mut recvs);
            assert_eq!(
                recvs,
                peers.iter().map(|&p| vec![p as f64]).collect::<Vec<_>>()
            );
            let s = t.stats();
            (s.collectives, s.exchanges)
        });
        assert_eq!(counts, vec![(1, 1); 3]);
    }
}
