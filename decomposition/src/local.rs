//! [`LocalComm`]: many ranks as threads of one process.
//!
//! It exists so that unit tests exercise the multi-rank code paths (halo exchange,
//! migration, reductions) without `mpirun`, and so that a rank count can be tried in
//! a debugger. Speed is secondary: collectives allocate and go through one mutex.
//!
//! Reductions are computed by every rank from all contributions summed in rank order,
//! so every rank gets bit-identical results, as with a deterministic MPI reduction.
//!
//! A panic on one rank would leave the others blocked in a collective or a receive:
//! [`LocalComm::run`] catches it, wakes every waiting rank (which then panic too), and
//! re-raises the first panic, so a failing test fails instead of hanging.

use std::any::Any;
use std::panic::{self, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use crate::comm::Communicator;

/// One rank's contribution to a collective.
#[derive(Clone, Debug, Default)]
enum Payload {
    #[default]
    None,
    F64(Vec<f64>),
    U64(Vec<u64>),
    Bytes(Vec<u8>),
}

impl Payload {
    fn f64(&self) -> &[f64] {
        match self {
            Payload::F64(v) => v,
            _ => panic!("collective mismatch: ranks called different collectives"),
        }
    }
    fn u64(&self) -> &[u64] {
        match self {
            Payload::U64(v) => v,
            _ => panic!("collective mismatch: ranks called different collectives"),
        }
    }
    fn bytes(&self) -> &[u8] {
        match self {
            Payload::Bytes(v) => v,
            _ => panic!("collective mismatch: ranks called different collectives"),
        }
    }
}

/// State of the one collective in flight. A generation counter tells a waiting rank
/// that its collective completed; the completed contributions move into `result`, so
/// fast ranks can already deposit into `slots` for the next collective while slow ranks
/// still read this one (no rank can complete the next one before they join it).
struct Collective {
    generation: u64,
    arrived: usize,
    slots: Vec<Payload>,
    result: Arc<Vec<Payload>>,
}

struct Shared {
    size: usize,
    coll: Mutex<Collective>,
    cv: Condvar,
    /// Set when a rank panicked: every blocking wait checks it and panics in turn.
    aborted: AtomicBool,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Collective> {
        // A panicking rank never holds this lock while panicking in user code; ignore
        // poisoning so the abort path can still wake everyone.
        self.coll.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn abort(&self) {
        self.aborted.store(true, Ordering::SeqCst);
        let _guard = self.lock();
        self.cv.notify_all();
    }

    fn check(&self) {
        if self.aborted.load(Ordering::SeqCst) {
            panic::panic_any(ECHO);
        }
    }
}

/// A rank of an in-process group of threads, see the module docs.
pub struct LocalComm {
    rank: usize,
    shared: Arc<Shared>,
    /// `to[r]`: channel to rank `r` (messages are FIFO per ordered pair, as MPI's).
    to: Vec<Sender<Vec<f64>>>,
    /// `from[r]`: channel from rank `r`.
    from: Vec<Receiver<Vec<f64>>>,
}

impl LocalComm {
    /// Run `f` on `n` ranks, one thread each, and return the results in rank order.
    ///
    /// If any rank panics, all ranks are released and the first panic is re-raised.
    pub fn run<T, F>(n: usize, f: F) -> Vec<T>
    where
        T: Send,
        F: Fn(&LocalComm) -> T + Sync,
    {
        let comms = Self::group(n);
        let results: Vec<Result<T, Box<dyn Any + Send>>> = std::thread::scope(|s| {
            let handles: Vec<_> = comms
                .into_iter()
                .map(|comm| {
                    let f = &f;
                    s.spawn(move || {
                        let r = panic::catch_unwind(AssertUnwindSafe(|| f(&comm)));
                        if r.is_err() {
                            comm.shared.abort();
                        }
                        // Dropping `comm` closes its channels, which also releases ranks
                        // blocked in a receive from it.
                        drop(comm);
                        r
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().unwrap_or_else(Err))
                .collect()
        });
        // Re-raise the panic that caused the others, not one of its echoes.
        let mut cause = None;
        let mut echo = None;
        let mut out = Vec::with_capacity(n);
        for r in results {
            match r {
                Ok(v) => out.push(v),
                Err(e) if is_echo(&*e) => echo = echo.or(Some(e)),
                Err(e) => cause = cause.or(Some(e)),
            }
        }
        if let Some(e) = cause.or(echo) {
            panic::resume_unwind(e);
        }
        out
    }

    /// The `n` connected communicators of a group, one per thread of [`LocalComm::run`].
    fn group(n: usize) -> Vec<LocalComm> {
        let shared = Arc::new(Shared {
            size: n,
            coll: Mutex::new(Collective {
                generation: 0,
                arrived: 0,
                slots: vec![Payload::None; n],
                result: Arc::new(Vec::new()),
            }),
            cv: Condvar::new(),
            aborted: AtomicBool::new(false),
        });
        // senders[src][dst], receivers[dst][src]
        let mut senders: Vec<Vec<Sender<Vec<f64>>>> = (0..n).map(|_| Vec::new()).collect();
        let mut receivers: Vec<Vec<Receiver<Vec<f64>>>> = (0..n).map(|_| Vec::new()).collect();
        for sends in senders.iter_mut() {
            for recvs in receivers.iter_mut() {
                let (tx, rx) = channel();
                sends.push(tx);
                recvs.push(rx);
            }
        }
        senders
            .into_iter()
            .zip(receivers)
            .enumerate()
            .map(|(rank, (to, from))| LocalComm {
                rank,
                shared: shared.clone(),
                to,
                from,
            })
            .collect()
    }

    /// Every rank contributes a payload; every rank gets all of them in rank order.
    fn all_gather(&self, p: Payload) -> Arc<Vec<Payload>> {
        let sh = &*self.shared;
        let mut g = sh.lock();
        sh.check();
        let generation = g.generation;
        g.slots[self.rank] = p;
        g.arrived += 1;
        if g.arrived == sh.size {
            let slots = std::mem::replace(&mut g.slots, vec![Payload::None; sh.size]);
            g.result = Arc::new(slots);
            g.arrived = 0;
            g.generation += 1;
            sh.cv.notify_all();
            return g.result.clone();
        }
        while g.generation == generation {
            g = sh.cv.wait(g).unwrap_or_else(PoisonError::into_inner);
            sh.check();
        }
        g.result.clone()
    }

    fn reduce_f64(&self, x: &mut [f64], op: fn(f64, f64) -> f64) {
        let all = self.all_gather(Payload::F64(x.to_vec()));
        let first = all[0].f64();
        assert_eq!(
            first.len(),
            x.len(),
            "reduction lengths differ between ranks"
        );
        x.copy_from_slice(first);
        for p in &all[1..] {
            let v = p.f64();
            assert_eq!(v.len(), x.len(), "reduction lengths differ between ranks");
            for (a, b) in x.iter_mut().zip(v) {
                *a = op(*a, *b);
            }
        }
    }

    fn receive(&self, src: usize) -> Vec<f64> {
        loop {
            match self.from[src].recv_timeout(Duration::from_millis(50)) {
                Ok(m) => return m,
                Err(RecvTimeoutError::Timeout) => self.shared.check(),
                Err(RecvTimeoutError::Disconnected) => panic::panic_any(ECHO),
            }
        }
    }
}

/// What a rank panics with when released because another rank panicked.
const ECHO: &str = "another rank panicked";

fn is_echo(e: &(dyn Any + Send)) -> bool {
    e.downcast_ref::<&str>().is_some_and(|s| *s == ECHO)
}

impl Communicator for LocalComm {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.shared.size
    }
    fn sum_f64(&self, x: &mut [f64]) {
        self.reduce_f64(x, |a, b| a + b);
    }
    fn max_f64(&self, x: &mut [f64]) {
        self.reduce_f64(x, f64::max);
    }
    fn min_f64(&self, x: &mut [f64]) {
        self.reduce_f64(x, f64::min);
    }
    fn sum_u64(&self, x: &mut [u64]) {
        let all = self.all_gather(Payload::U64(x.to_vec()));
        x.fill(0);
        for p in all.iter() {
            let v = p.u64();
            assert_eq!(v.len(), x.len(), "reduction lengths differ between ranks");
            for (a, b) in x.iter_mut().zip(v) {
                *a += *b;
            }
        }
    }
    /// The ranks are threads of one process, so on one node.
    fn node_sum_u64(&self, x: &mut [u64]) {
        self.sum_u64(x);
    }
    fn exclusive_scan_u64(&self, x: u64) -> u64 {
        let all = self.all_gather(Payload::U64(vec![x]));
        all[..self.rank].iter().map(|p| p.u64()[0]).sum()
    }
    fn exchange(&self, peers: &[usize], sends: &[Vec<f64>], recvs: &mut [Vec<f64>]) {
        assert!(sends.len() >= peers.len() && recvs.len() >= peers.len());
        // Channels are unbounded, so posting every send before any receive cannot block.
        for (k, &p) in peers.iter().enumerate() {
            if p != self.rank {
                // The receiver lives as long as its rank; if it is gone, that rank
                // panicked and our next wait reports it.
                let _ = self.to[p].send(sends[k].clone());
            }
        }
        for (k, &p) in peers.iter().enumerate() {
            recvs[k].clear();
            if p == self.rank {
                recvs[k].extend_from_slice(&sends[k]);
            } else {
                let m = self.receive(p);
                recvs[k].extend_from_slice(&m);
            }
        }
    }
    fn gather_bytes(&self, data: &[u8]) -> Vec<Vec<u8>> {
        let all = self.all_gather(Payload::Bytes(data.to_vec()));
        if self.rank == 0 {
            all.iter().map(|p| p.bytes().to_vec()).collect()
        } else {
            Vec::new()
        }
    }
    fn broadcast_bytes(&self, data: &[u8]) -> Vec<u8> {
        let p = if self.rank == 0 {
            Payload::Bytes(data.to_vec())
        } else {
            Payload::Bytes(Vec::new())
        };
        self.all_gather(p)[0].bytes().to_vec()
    }
}
