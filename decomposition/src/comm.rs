//! The communicator trait: everything the solver needs from MPI, and nothing more.
//!
//! Three implementations: [`SerialComm`] (one process, the 1-rank case of the same code
//! path), [`MpiComm`] (rsmpi), and [`crate::local::LocalComm`] (many ranks as threads of
//! one process, so unit tests exercise multi-rank logic without `mpirun`).

use mpi::collective::SystemOperation;
use mpi::datatype::Equivalence as _;
use mpi::traits::{
    Communicator as _, CommunicatorCollectives as _, Destination as _, Root as _, Source as _,
};

/// Collective and point-to-point operations on `f64`/`u64` buffers.
///
/// Every collective must be called by all ranks in the same order. `exchange` is the only
/// point-to-point operation: each rank sends one buffer to each of its peers and receives
/// one buffer from each; a rank may be its own peer (periodic faces on one rank).
pub trait Communicator {
    /// This rank, in `0..size()`.
    fn rank(&self) -> usize;
    /// The number of ranks.
    fn size(&self) -> usize;
    /// Element-wise sum over ranks, in place.
    fn sum_f64(&self, x: &mut [f64]);
    /// Element-wise maximum over ranks, in place.
    fn max_f64(&self, x: &mut [f64]);
    /// Element-wise minimum over ranks, in place.
    fn min_f64(&self, x: &mut [f64]);
    /// Element-wise sum over ranks, in place.
    fn sum_u64(&self, x: &mut [u64]);
    /// Element-wise sum over the ranks that share this rank's node (its memory), in
    /// place: for set-up, not the step (an MPI run forms the node's communicator anew).
    fn node_sum_u64(&self, x: &mut [u64]);
    /// Sum of `x` over ranks below this one (0 on rank 0).
    fn exclusive_scan_u64(&self, x: u64) -> u64;
    /// Send `sends[k]` to `peers[k]` and receive into `recvs[k]` from `peers[k]`.
    /// Receive buffers are resized to the incoming length (no reallocation once their
    /// capacity suffices). `peers` must be symmetric (if A lists B, B lists A) and list
    /// each rank at most once.
    fn exchange(&self, peers: &[usize], sends: &[Vec<f64>], recvs: &mut [Vec<f64>]);
    /// True on every rank if `flag` is true on any rank: how a local error reaches all.
    fn any(&self, flag: bool) -> bool {
        let mut x = [if flag { 1.0 } else { 0.0 }];
        self.max_f64(&mut x);
        x[0] > 0.0
    }
    /// Gather variable-length byte buffers on rank 0 (empty result elsewhere).
    fn gather_bytes(&self, data: &[u8]) -> Vec<Vec<u8>>;
    /// Broadcast bytes from rank 0 to all (the argument is ignored on other ranks).
    fn broadcast_bytes(&self, data: &[u8]) -> Vec<u8>;
    /// The underlying MPI communicator, for libraries that need one (parallel HDF5).
    fn raw_mpi(&self) -> Option<mpi::ffi::MPI_Comm> {
        None
    }
}

/// A single process: collectives are identities and exchanges loop back to itself.
#[derive(Debug, Default, Clone, Copy)]
pub struct SerialComm;

impl Communicator for SerialComm {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn sum_f64(&self, _: &mut [f64]) {}
    fn max_f64(&self, _: &mut [f64]) {}
    fn min_f64(&self, _: &mut [f64]) {}
    fn sum_u64(&self, _: &mut [u64]) {}
    fn node_sum_u64(&self, _: &mut [u64]) {}
    fn exclusive_scan_u64(&self, _: u64) -> u64 {
        0
    }
    fn exchange(&self, peers: &[usize], sends: &[Vec<f64>], recvs: &mut [Vec<f64>]) {
        for (k, &p) in peers.iter().enumerate() {
            assert_eq!(p, 0, "serial communicator has only rank 0");
            recvs[k].clear();
            recvs[k].extend_from_slice(&sends[k]);
        }
    }
    fn gather_bytes(&self, data: &[u8]) -> Vec<Vec<u8>> {
        vec![data.to_vec()]
    }
    fn broadcast_bytes(&self, data: &[u8]) -> Vec<u8> {
        data.to_vec()
    }
}

/// rsmpi's world communicator.
pub struct MpiComm {
    world: mpi::topology::SimpleCommunicator,
}

/// `x` reduced over all ranks by `op`, in place. The send copy of a short `x` (every
/// step's reductions: a few numbers) is on the stack, so a step allocates nothing.
fn reduce<T>(world: &mpi::topology::SimpleCommunicator, x: &mut [T], op: SystemOperation)
where
    T: Copy + Default + mpi::datatype::Equivalence,
{
    const SHORT: usize = 16;
    if x.len() <= SHORT {
        let mut send = [T::default(); SHORT];
        send[..x.len()].copy_from_slice(x);
        world.all_reduce_into(&send[..x.len()], x, op);
    } else {
        let send = x.to_vec();
        world.all_reduce_into(&send[..], x, op);
    }
}

/// The first `n` entries of `inline`, or `heap` grown to `n` (with `fill`) where
/// `inline` is too short: a scratch slice on the stack in the common case.
fn first_n<'a, T>(
    inline: &'a mut [T],
    heap: &'a mut Vec<T>,
    n: usize,
    fill: impl FnMut() -> T,
) -> &'a mut [T] {
    if n <= inline.len() {
        &mut inline[..n]
    } else {
        heap.resize_with(n, fill);
        heap
    }
}

impl MpiComm {
    /// Wrap a world communicator.
    pub fn new(world: mpi::topology::SimpleCommunicator) -> Self {
        Self { world }
    }
    /// End every rank at once: for fatal errors met by one rank only.
    pub fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }
    /// [`Communicator::exchange`] with its bookkeeping (the peers not yet heard from,
    /// the send requests) on the stack for up to `INLINE` peers other than this rank,
    /// so that an exchange allocates nothing, and on the heap beyond. The trait's
    /// exchange keeps 32; public so that a test on a few ranks can take the heap path.
    pub fn exchange_inline<const INLINE: usize>(
        &self,
        peers: &[usize],
        sends: &[Vec<f64>],
        recvs: &mut [Vec<f64>],
    ) {
        // One message per peer: a receive is sized by probing the message that arrived,
        // and messages are taken in the order they arrive. Messages between a pair are
        // matched in order, so a message probed from a peer is the one of this exchange
        // (each peer is listed once), and a self-peer is served by a copy.
        const TAG: i32 = 2;
        let me = self.rank();
        debug_assert!(peers
            .iter()
            .enumerate()
            .all(|(k, p)| !peers[..k].contains(p)));
        for (k, _) in peers.iter().enumerate().filter(|&(_, &p)| p == me) {
            recvs[k].clear();
            recvs[k].extend_from_slice(&sends[k]);
        }
        let remote = peers.iter().filter(|&&p| p != me).count();
        let (mut pending_inline, mut pending_heap) = ([0usize; INLINE], Vec::new());
        let pending = first_n(&mut pending_inline, &mut pending_heap, remote, || 0);
        for (slot, k) in pending
            .iter_mut()
            .zip((0..peers.len()).filter(|&k| peers[k] != me))
        {
            *slot = k;
        }
        mpi::request::scope(|scope| {
            let (mut sent_inline, mut sent_heap): ([Option<_>; INLINE], _) =
                (std::array::from_fn(|_| None), Vec::new());
            let sent = first_n(&mut sent_inline, &mut sent_heap, remote, || None);
            for (slot, &k) in sent.iter_mut().zip(pending.iter()) {
                *slot = Some(
                    self.world
                        .process_at_rank(peers[k] as i32)
                        .immediate_send_with_tag(scope, &sends[k][..], TAG),
                );
            }
            // The first `left` entries of `pending` are the peers not yet heard from.
            let mut left = remote;
            while left > 0 {
                let mut i = 0;
                while i < left {
                    let k = pending[i];
                    let from = self.world.process_at_rank(peers[k] as i32);
                    if let Some((message, status)) = from.immediate_matched_probe_with_tag(TAG) {
                        let n = status.count(f64::equivalent_datatype()) as usize;
                        recvs[k].resize(n, 0.0);
                        message.matched_receive_into(&mut recvs[k][..]);
                        left -= 1;
                        pending.swap(i, left);
                    } else {
                        i += 1;
                    }
                }
            }
            for r in sent.iter_mut().filter_map(Option::take) {
                r.wait();
            }
        });
    }

    /// Collective: the ranks that share this rank's node (its memory), as a
    /// communicator of their own.
    pub fn node(&self) -> Self {
        use mpi::topology::Communicator as _;
        Self::new(self.world.split_shared(self.world.rank()))
    }
}

impl Communicator for MpiComm {
    fn raw_mpi(&self) -> Option<mpi::ffi::MPI_Comm> {
        use mpi::raw::AsRaw;
        Some(self.world.as_raw())
    }
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }
    fn size(&self) -> usize {
        self.world.size() as usize
    }
    fn sum_f64(&self, x: &mut [f64]) {
        reduce(&self.world, x, SystemOperation::sum());
    }
    fn max_f64(&self, x: &mut [f64]) {
        reduce(&self.world, x, SystemOperation::max());
    }
    fn min_f64(&self, x: &mut [f64]) {
        reduce(&self.world, x, SystemOperation::min());
    }
    fn sum_u64(&self, x: &mut [u64]) {
        reduce(&self.world, x, SystemOperation::sum());
    }
    fn node_sum_u64(&self, x: &mut [u64]) {
        self.node().sum_u64(x);
    }
    fn exclusive_scan_u64(&self, x: u64) -> u64 {
        let mut out = 0u64;
        self.world
            .exclusive_scan_into(&x, &mut out, SystemOperation::sum());
        if self.world.rank() == 0 {
            0 // MPI leaves rank 0's result undefined
        } else {
            out
        }
    }
    fn exchange(&self, peers: &[usize], sends: &[Vec<f64>], recvs: &mut [Vec<f64>]) {
        // A 3D block has at most 26 neighbours; a rebalance, which may send to every
        // rank, takes the heap beyond 32.
        self.exchange_inline::<32>(peers, sends, recvs);
    }
    fn gather_bytes(&self, data: &[u8]) -> Vec<Vec<u8>> {
        let n = self.size();
        let root = self.world.process_at_rank(0);
        let len = data.len() as u64;
        if self.rank() == 0 {
            let mut lens = vec![0u64; n];
            root.gather_into_root(&len, &mut lens[..]);
            let mut out = vec![data.to_vec()];
            for (r, &l) in lens.iter().enumerate().skip(1) {
                let mut buf = vec![0u8; l as usize];
                self.world
                    .process_at_rank(r as i32)
                    .receive_into_with_tag(&mut buf[..], 3);
                out.push(buf);
            }
            out
        } else {
            root.gather_into(&len);
            root.send_with_tag(data, 3);
            Vec::new()
        }
    }
    fn broadcast_bytes(&self, data: &[u8]) -> Vec<u8> {
        let root = self.world.process_at_rank(0);
        let mut len = data.len() as u64;
        root.broadcast_into(&mut len);
        let mut buf = if self.rank() == 0 {
            data.to_vec()
        } else {
            vec![0u8; len as usize]
        };
        root.broadcast_into(&mut buf[..]);
        buf
    }
}
