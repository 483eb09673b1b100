//! A rank's local block: its node box with ghost layers and the halo operations on
//! nodal fields stored node-major (`field[node * ncomp + c]`).

use std::collections::BTreeMap;

use crate::comm::Communicator;
use crate::layout::{Layout, GHOST};
use crate::odometer::odometer;
use crate::region::{spans_owned_by, Region, Span};
use crate::tiles::Tiles;
use crate::traffic::Traffic;

/// One rank's view of the grid.
#[derive(Clone, Debug)]
pub struct Block<const D: usize> {
    /// The rank that owns this block.
    pub rank: usize,
    /// First owned cell (global index): the block owns `[cell_lo, cell_hi)`.
    pub cell_lo: [usize; D],
    /// One past the last owned cell (global index).
    pub cell_hi: [usize; D],
    /// Global (unwrapped) index of local node 0 along each axis; negative on a periodic
    /// axis whose ghost layer wraps below 0.
    pub node_lo: [i64; D],
    /// Local node box size along each axis.
    pub node_dims: [usize; D],
    /// First owned node in local indices: the block owns `[own_lo, own_hi)` along
    /// each axis.
    pub own_lo: [usize; D],
    /// One past the last owned node in local indices.
    pub own_hi: [usize; D],
    halo: Halo<D>,
}

/// For each peer rank: the region of my ghost nodes it owns and the region of my owned
/// nodes that are ghosts in its box ([`Region`]: a few spans per axis, whatever the
/// faces' length), both in the holder's node order so that the two sides agree without
/// talking.
///
/// The halo operations exchange the nodes of `sum_send`/`sum_recv` and
/// `copy_send`/`copy_recv`: the whole regions (dense local numbering) on first use
/// unless [`Block::activate_halo`] and [`Block::map_active_halo`] restrict them to the
/// chunks some rank uses this step, in the storage numbering of a [`Tiles`].
#[derive(Clone, Debug)]
struct Halo<const D: usize> {
    peers: Vec<usize>,
    /// `ghosts[k]`: my ghost nodes owned by `peers[k]` (I am the holder).
    ghosts: Vec<Region<D>>,
    /// `owned[k]`: my owned nodes that are ghosts of `peers[k]` (it is the holder).
    owned: Vec<Region<D>>,
    send: Vec<Vec<f64>>,
    recv: Vec<Vec<f64>>,
    /// Which lists the halo operations use.
    lists: Lists,
    /// Active chunks of this step, per peer: my ghost chunks I touched (`g`), my owned
    /// chunks the peer touched (`r`), my owned chunks stored after that (`o`), my ghost
    /// chunks the peer stores (`q`).
    g: Vec<Vec<u64>>,
    r: Vec<Vec<u64>>,
    o: Vec<Vec<u64>>,
    q: Vec<Vec<u64>>,
    sum_send: Vec<Vec<usize>>,
    sum_recv: Vec<Vec<usize>>,
    copy_send: Vec<Vec<usize>>,
    copy_recv: Vec<Vec<usize>>,
    /// Every stored ghost node: the ghost copy zeroes them before writing what their
    /// owners send (a ghost node no copy reaches has no mass anywhere this step, and
    /// would otherwise keep an earlier step's value).
    ghost_stored: Vec<usize>,
    /// The node ranges of the stored tiles near the owned box's faces (scratch).
    edge: Vec<([usize; D], [usize; D])>,
    /// Per axis scratch of [`Region::chunks_in`].
    scratch: [Vec<(u64, bool)>; D],
    /// What `ghost_sum`, `ghost_copy` and `activate_halo` sent to other ranks so far.
    traffic: Traffic,
}

/// The node lists of the halo operations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Lists {
    /// None built yet.
    Unset,
    /// The whole regions, dense local numbering.
    Dense,
    /// The active chunks, storage numbering of the tiles.
    Sparse,
}

/// Chunk keys as pairs of `f64` (each half below 2^32, so exact).
fn put_keys(keys: &[u64], buf: &mut Vec<f64>) {
    buf.clear();
    for &k in keys {
        buf.push((k >> 32) as f64);
        buf.push((k & 0xffff_ffff) as f64);
    }
}

/// Chunk keys received as pairs of `f64`, checked against the region.
fn take_keys<const D: usize>(buf: &[f64], region: &Region<D>, out: &mut Vec<u64>) {
    out.clear();
    assert!(
        buf.len().is_multiple_of(2),
        "ranks disagree on the halo's chunks"
    );
    for pair in buf.chunks_exact(2) {
        let half = |x: f64| {
            assert!(
                (0.0..4294967296.0).contains(&x) && x.fract() == 0.0,
                "ranks disagree on the halo's chunks"
            );
            x as u64
        };
        let k = (half(pair[0]) << 32) | half(pair[1]);
        assert!(region.has_key(k), "ranks disagree on the halo's chunks");
        out.push(k);
    }
}

impl<const D: usize> Block<D> {
    /// The block of `rank` in `layout`, with its halo regions.
    pub fn new(layout: &Layout<D>, rank: usize) -> Self {
        let (cell_lo, cell_hi) = layout.block_cells(rank);
        let (node_lo, node_dims, own_lo, own_hi) = node_box(layout, rank);
        Self {
            rank,
            cell_lo,
            cell_hi,
            node_lo,
            node_dims,
            own_lo,
            own_hi,
            halo: build_halo(layout, rank),
        }
    }

    /// Nodes in the local box, ghosts included.
    pub fn num_nodes(&self) -> usize {
        self.node_dims.iter().product()
    }

    /// Local linear index of a local node coordinate (axis 0 fastest).
    #[inline]
    pub fn index(&self, local: [usize; D]) -> usize {
        let mut i = 0;
        for a in (0..D).rev() {
            i = i * self.node_dims[a] + local[a];
        }
        i
    }

    /// Local node coordinate of a linear index.
    #[inline]
    pub fn coords(&self, mut i: usize) -> [usize; D] {
        let mut c = [0; D];
        for a in 0..D {
            c[a] = i % self.node_dims[a];
            i /= self.node_dims[a];
        }
        c
    }

    /// Global (unwrapped) node index of a local coordinate.
    #[inline]
    pub fn global(&self, local: [usize; D]) -> [i64; D] {
        let mut g = [0; D];
        for a in 0..D {
            g[a] = self.node_lo[a] + local[a] as i64;
        }
        g
    }

    /// Whether a local node is owned (not a ghost).
    pub fn is_owned(&self, local: [usize; D]) -> bool {
        (0..D).all(|a| local[a] >= self.own_lo[a] && local[a] < self.own_hi[a])
    }

    /// Peers this rank exchanges halo data with (itself included on periodic faces).
    pub fn peers(&self) -> &[usize] {
        &self.halo.peers
    }

    /// Collective: agree with the peers on the halo nodes in use this step, and touch
    /// their tiles. Call after touching the tiles of this rank's particles and before
    /// [`Tiles::finish`]; then [`Block::map_active_halo`]. The halo regions are cut into
    /// chunks (a region's nodes in one tile of the global grid); two exchanges of chunk
    /// keys decide:
    /// 1. each rank tells the owners which of its ghost chunks it touched; an owner
    ///    stores those chunks (a neighbour's particles put mass there);
    /// 2. each owner tells the ranks that hold its owned chunks as ghosts which of
    ///    them it stores now (its particles', and those of step 1 from any rank);
    ///    they store them, so that every node with mass reaches every copy.
    ///
    /// The ghost sum then sends the chunks of step 1, the ghost copy those of step 2.
    /// Only the touched tiles near the owned box's faces are cut into chunks (the
    /// others are passed over by one test each), so the halo's cost follows the
    /// material, not the block faces.
    pub fn activate_halo(&mut self, comm: &dyn Communicator, tiles: &mut Tiles<D>) {
        let (own_lo, own_hi) = (self.own_lo, self.own_hi);
        let h = &mut self.halo;
        h.lists = Lists::Sparse;
        let n = h.peers.len();
        // Step 1: my touched ghost chunks to their owners.
        edge_tiles(tiles, own_lo, own_hi, &mut h.edge);
        for k in 0..n {
            chunks_in_edge(&h.ghosts[k], &h.edge, &mut h.scratch, &mut h.g[k]);
            put_keys(&h.g[k], &mut h.send[k]);
        }
        h.traffic.record(self.rank, &h.peers, &h.send);
        comm.exchange(&h.peers, &h.send, &mut h.recv);
        for k in 0..n {
            take_keys(&h.recv[k], &h.owned[k], &mut h.r[k]);
            touch_chunks(&h.ghosts[k], &h.g[k], tiles);
            touch_chunks(&h.owned[k], &h.r[k], tiles);
        }
        // Step 2: my stored owned chunks to the ranks that hold them as ghosts.
        edge_tiles(tiles, own_lo, own_hi, &mut h.edge);
        for k in 0..n {
            chunks_in_edge(&h.owned[k], &h.edge, &mut h.scratch, &mut h.o[k]);
            put_keys(&h.o[k], &mut h.send[k]);
        }
        h.traffic.record(self.rank, &h.peers, &h.send);
        comm.exchange(&h.peers, &h.send, &mut h.recv);
        for k in 0..n {
            take_keys(&h.recv[k], &h.ghosts[k], &mut h.q[k]);
            touch_chunks(&h.owned[k], &h.o[k], tiles);
            touch_chunks(&h.ghosts[k], &h.q[k], tiles);
        }
    }

    /// What the halo operations of this block ([`Block::ghost_sum`],
    /// [`Block::ghost_copy`], and the chunk agreement of [`Block::activate_halo`])
    /// have sent to other ranks since it was made: bytes, non-empty messages and the
    /// number of operations. Exchanges with itself (periodic faces) are not counted.
    pub fn traffic(&self) -> Traffic {
        self.halo.traffic
    }

    /// After [`Block::activate_halo`] and [`Tiles::finish`]: the halo operations use
    /// the storage indices of the active chunks' nodes in `tiles`.
    pub fn map_active_halo(&mut self, tiles: &Tiles<D>) {
        let (own_lo, own_hi) = (self.own_lo, self.own_hi);
        let h = &mut self.halo;
        assert!(h.lists == Lists::Sparse, "activate_halo first");
        for k in 0..h.peers.len() {
            chunk_storage(&h.ghosts[k], &h.g[k], tiles, &mut h.sum_send[k]);
            chunk_storage(&h.owned[k], &h.r[k], tiles, &mut h.sum_recv[k]);
            chunk_storage(&h.owned[k], &h.o[k], tiles, &mut h.copy_send[k]);
            chunk_storage(&h.ghosts[k], &h.q[k], tiles, &mut h.copy_recv[k]);
        }
        h.ghost_stored.clear();
        for slot in 1..tiles.slots() {
            let (lo, hi) = tiles.slot_range(slot);
            if (0..D).all(|a| lo[a] >= own_lo[a] && hi[a] <= own_hi[a]) {
                continue;
            }
            for o in 0..tiles.tile_nodes() {
                if let Some(l) = tiles.local(slot, o) {
                    if !(0..D).all(|a| l[a] >= own_lo[a] && l[a] < own_hi[a]) {
                        h.ghost_stored.push(slot * tiles.tile_nodes() + o);
                    }
                }
            }
        }
    }

    /// The whole regions as node lists in the dense local numbering, for halo
    /// operations on a field over the whole box (before any [`Block::activate_halo`]).
    fn dense_lists(&mut self) {
        if self.halo.lists != Lists::Unset {
            return;
        }
        let dims = self.node_dims;
        let h = &mut self.halo;
        for k in 0..h.peers.len() {
            let dense = |r: &Region<D>| {
                let mut v = Vec::new();
                r.for_each(|m| v.push(linear(dims, m)));
                v
            };
            h.sum_send[k] = dense(&h.ghosts[k]);
            h.sum_recv[k] = dense(&h.owned[k]);
            h.copy_send[k] = h.sum_recv[k].clone();
            h.copy_recv[k] = h.sum_send[k].clone();
        }
        h.lists = Lists::Dense;
    }

    /// The exchange of a ghost sum (`copy` false: the ghosts' entries `slots` to their
    /// owners) or a ghost copy (`copy` true: the owned nodes' to their ghosts), of
    /// records of `width` numbers in `field`: what the peers sent lands in the halo's
    /// receive buffers, in the order of the matching receive lists.
    fn exchange_slots(
        &mut self,
        comm: &dyn Communicator,
        field: &[f64],
        width: usize,
        slots: std::ops::Range<usize>,
        copy: bool,
    ) {
        debug_assert!(slots.end <= width);
        self.dense_lists();
        let (lo, hi) = (slots.start, slots.end);
        let h = &mut self.halo;
        let lists = if copy { &h.copy_send } else { &h.sum_send };
        for (k, nodes) in lists.iter().enumerate() {
            let buf = &mut h.send[k];
            buf.clear();
            for &n in nodes {
                buf.extend_from_slice(&field[n * width + lo..n * width + hi]);
            }
        }
        h.traffic.record(self.rank, &h.peers, &h.send);
        comm.exchange(&h.peers, &h.send, &mut h.recv);
    }

    /// Add every ghost node's value into its owner's node, then leave ghosts as they were
    /// (call [`Block::ghost_copy`] if they must hold the sum too).
    pub fn ghost_sum(&mut self, comm: &dyn Communicator, field: &mut [f64], ncomp: usize) {
        self.ghost_sum_slots(comm, field, ncomp, 0..ncomp);
    }

    /// [`Block::ghost_sum`] of the entries `slots` of every node's record of `width`
    /// numbers in `field`, the others left alone: a field that shares its nodes'
    /// records with others, summed without them.
    pub fn ghost_sum_slots(
        &mut self,
        comm: &dyn Communicator,
        field: &mut [f64],
        width: usize,
        slots: std::ops::Range<usize>,
    ) {
        let (lo, ncomp) = (slots.start, slots.len());
        self.exchange_slots(comm, field, width, slots, false);
        let h = &self.halo;
        for (k, nodes) in h.sum_recv.iter().enumerate() {
            let buf = &h.recv[k];
            debug_assert_eq!(buf.len(), nodes.len() * ncomp);
            for (j, &n) in nodes.iter().enumerate() {
                for c in 0..ncomp {
                    field[n * width + lo + c] += buf[j * ncomp + c];
                }
            }
        }
    }

    /// Copy every owned node's value to all its ghost copies on all ranks.
    pub fn ghost_copy(&mut self, comm: &dyn Communicator, field: &mut [f64], ncomp: usize) {
        self.ghost_copy_slots(comm, field, ncomp, 0..ncomp);
    }

    /// [`Block::ghost_copy`] of the entries `slots` of every node's record of `width`
    /// numbers in `field`, the others left alone: after a [`Block::ghost_sum_slots`],
    /// the ghosts of a field that shares its records get the sums of those slots.
    pub fn ghost_copy_slots(
        &mut self,
        comm: &dyn Communicator,
        field: &mut [f64],
        width: usize,
        slots: std::ops::Range<usize>,
    ) {
        let (lo, hi, ncomp) = (slots.start, slots.end, slots.len());
        self.exchange_slots(comm, field, width, slots, true);
        let h = &self.halo;
        for &n in &h.ghost_stored {
            field[n * width + lo..n * width + hi].fill(0.0);
        }
        for (k, nodes) in h.copy_recv.iter().enumerate() {
            let buf = &h.recv[k];
            debug_assert_eq!(buf.len(), nodes.len() * ncomp);
            for (j, &n) in nodes.iter().enumerate() {
                field[n * width + lo..n * width + hi]
                    .copy_from_slice(&buf[j * ncomp..(j + 1) * ncomp]);
            }
        }
    }
}

/// The node ranges of the touched tiles that reach within [`GHOST`] nodes of the owned
/// box's faces or past them: the only places a halo region's nodes can be (a node of
/// mine in another box lies within its ghost layer, so within `GHOST` of my faces).
fn edge_tiles<const D: usize>(
    tiles: &mut Tiles<D>,
    own_lo: [usize; D],
    own_hi: [usize; D],
    out: &mut Vec<([usize; D], [usize; D])>,
) {
    out.clear();
    tiles.sort_touched();
    for &k in tiles.touched() {
        let (lo, hi) = tiles.key_range(k);
        let inner = (0..D).all(|a| lo[a] > own_lo[a] + GHOST && hi[a] + GHOST <= own_hi[a]);
        if !inner {
            out.push((lo, hi));
        }
    }
}

/// Into `out`, ascending without repeats: the chunks of `region` with a node in one
/// of the `edge` tiles.
fn chunks_in_edge<const D: usize>(
    region: &Region<D>,
    edge: &[([usize; D], [usize; D])],
    scratch: &mut [Vec<(u64, bool)>; D],
    out: &mut Vec<u64>,
) {
    out.clear();
    if region.is_empty() {
        return;
    }
    for &(lo, hi) in edge {
        region.chunks_in(lo, hi, scratch, out);
    }
    out.sort_unstable();
    out.dedup();
}

/// Touch the tiles of every node of `chunks`.
fn touch_chunks<const D: usize>(region: &Region<D>, chunks: &[u64], tiles: &mut Tiles<D>) {
    for &c in chunks {
        region.for_each_in_chunk(c, |m| {
            let k = tiles.key_of(m);
            tiles.touch_key(k);
        });
    }
}

/// Replace `out` by the storage indices of the nodes of `chunks` (all stored).
fn chunk_storage<const D: usize>(
    region: &Region<D>,
    chunks: &[u64],
    tiles: &Tiles<D>,
    out: &mut Vec<usize>,
) {
    out.clear();
    for &c in chunks {
        region.for_each_in_chunk(c, |m| {
            out.push(tiles.index(m).expect("an active chunk's tiles are stored"));
        });
    }
}

/// One axis of a rank's node box: first global (unwrapped) node, node count, and the
/// owned local range `[own_lo, own_hi)`.
#[derive(Clone, Copy, Debug)]
struct AxisBox {
    node_lo: i64,
    dims: usize,
    own_lo: usize,
    own_hi: usize,
}

impl AxisBox {
    /// Axis `a` of the box of the block with coordinate `k` along that axis. A box is
    /// the product of its axes, which is what makes the halo build cheap.
    fn new<const D: usize>(layout: &Layout<D>, a: usize, k: usize) -> Self {
        let n = layout.cells[a];
        let (lo, hi) = (layout.split(a, k), layout.split(a, k + 1));
        let per = layout.periodic[a];
        let below = if per || lo > 0 { GHOST } else { 0 };
        let above = if per || hi < n { GHOST } else { 0 };
        Self {
            node_lo: lo as i64 - below as i64,
            // Nodes lo-below ..= hi+above.
            dims: hi - lo + below + above + 1,
            own_lo: below,
            own_hi: below + hi - lo + usize::from(!per && hi == n),
        }
    }
}

type NodeBox<const D: usize> = ([i64; D], [usize; D], [usize; D], [usize; D]);

fn node_box<const D: usize>(layout: &Layout<D>, rank: usize) -> NodeBox<D> {
    let k = layout.block_coords(rank);
    let mut out = ([0i64; D], [0usize; D], [0usize; D], [0usize; D]);
    for a in 0..D {
        let b = AxisBox::new(layout, a, k[a]);
        out.0[a] = b.node_lo;
        out.1[a] = b.dims;
        out.2[a] = b.own_lo;
        out.3[a] = b.own_hi;
    }
    out
}

fn linear<const D: usize>(dims: [usize; D], c: [usize; D]) -> usize {
    let mut i = 0;
    for a in (0..D).rev() {
        i = i * dims[a] + c[a];
    }
    i
}

/// The halo plan of `rank`, touching only the blocks that can share nodes with it.
///
/// Boxes and node ownership are both products over axes, so everything is decided per
/// axis: along axis `a`, which block coordinates own a position of a box. Blocks are at
/// least [`GHOST`] cells wide, so a box reaches at most one block below and two above
/// (the node two cells past the block is the lower corner of the second block up when
/// the first is exactly two cells wide); the candidate set is thus within two
/// block-steps, wrapped and deduplicated on periodic axes (with one or two blocks along
/// a periodic axis the same neighbour is met in both directions). Work is proportional
/// to the box, not to the rank count.
fn build_halo<const D: usize>(layout: &Layout<D>, rank: usize) -> Halo<D> {
    let me = layout.block_coords(rank);
    let mine: [AxisBox; D] = std::array::from_fn(|a| AxisBox::new(layout, a, me[a]));
    let my_lo: [i64; D] = std::array::from_fn(|a| mine[a].node_lo);
    let my_own: [(usize, usize); D] = std::array::from_fn(|a| (mine[a].own_lo, mine[a].own_hi));
    // Per peer: (my ghosts it owns, my owned nodes that are its ghosts).
    let mut regions: BTreeMap<usize, (Option<Region<D>>, Option<Region<D>>)> = BTreeMap::new();
    // Ghost side: per axis, the block coordinates owning positions of my box.
    let owners: [Vec<(usize, Vec<Span>)>; D] = std::array::from_fn(|a| {
        near_coords(layout, a, me[a])
            .into_iter()
            .filter_map(|k| {
                let b = (mine[a].node_lo, mine[a].dims);
                let spans = spans_owned_by(layout, a, b, k, |g| g - my_lo[a]);
                (!spans.is_empty()).then_some((k, spans))
            })
            .collect()
    });
    odometer::<D>(std::array::from_fn(|a| owners[a].len()), |j| {
        let spans = std::array::from_fn(|a| owners[a][j[a]].1.clone());
        let r = Region::new(my_lo, my_own, spans);
        if !r.is_empty() {
            let q = std::array::from_fn(|a| owners[a][j[a]].0);
            regions.entry(layout.rank_of_block(q)).or_default().0 = Some(r);
        }
    });
    // Owner side: the boxes near mine with positions I own.
    let near: [Vec<(AxisBox, Vec<Span>, usize)>; D] =
        std::array::from_fn(|a| near_blocks(layout, a, me[a], my_lo[a]));
    odometer::<D>(std::array::from_fn(|a| near[a].len()), |j| {
        let other: [&(AxisBox, Vec<Span>, usize); D] = std::array::from_fn(|a| &near[a][j[a]]);
        let r = Region::new(
            std::array::from_fn(|a| other[a].0.node_lo),
            std::array::from_fn(|a| (other[a].0.own_lo, other[a].0.own_hi)),
            std::array::from_fn(|a| other[a].1.clone()),
        );
        if !r.is_empty() {
            let q = std::array::from_fn(|a| other[a].2);
            regions.entry(layout.rank_of_block(q)).or_default().1 = Some(r);
        }
    });
    let n = regions.len();
    let none = || Region::new([0; D], [(0, 0); D], std::array::from_fn(|_| Vec::new()));
    let mut h = Halo {
        peers: Vec::with_capacity(n),
        ghosts: Vec::with_capacity(n),
        owned: Vec::with_capacity(n),
        send: vec![Vec::new(); n],
        recv: vec![Vec::new(); n],
        lists: Lists::Unset,
        g: vec![Vec::new(); n],
        r: vec![Vec::new(); n],
        o: vec![Vec::new(); n],
        q: vec![Vec::new(); n],
        sum_send: vec![Vec::new(); n],
        sum_recv: vec![Vec::new(); n],
        copy_send: vec![Vec::new(); n],
        copy_recv: vec![Vec::new(); n],
        ghost_stored: Vec::new(),
        edge: Vec::new(),
        scratch: std::array::from_fn(|_| Vec::new()),
        traffic: Traffic::default(),
    };
    for (p, (ghosts, owned)) in regions {
        h.peers.push(p);
        h.ghosts.push(ghosts.unwrap_or_else(none));
        h.owned.push(owned.unwrap_or_else(none));
    }
    h
}

/// Along axis `a`, the block coordinates within two of `me` (wrapped on a periodic
/// axis, without repeats): the only ones whose boxes can share nodes with mine (see
/// [`build_halo`]).
fn near_coords<const D: usize>(layout: &Layout<D>, a: usize, me: usize) -> Vec<usize> {
    let p = layout.procs[a] as i64;
    let mut ks: Vec<usize> = (-2..=2)
        .map(|d| me as i64 + d)
        .filter_map(|k| {
            if layout.periodic[a] {
                Some(k.rem_euclid(p) as usize)
            } else {
                (0..p).contains(&k).then_some(k as usize)
            }
        })
        .collect();
    ks.sort_unstable();
    ks.dedup();
    ks
}

/// Along axis `a`, the blocks near mine (coordinate `me`, first node `my_lo`) whose box
/// has positions I own: each box, those positions as spans to my local positions, and
/// the block's coordinate.
fn near_blocks<const D: usize>(
    layout: &Layout<D>,
    a: usize,
    me: usize,
    my_lo: i64,
) -> Vec<(AxisBox, Vec<Span>, usize)> {
    let n = layout.nodes(a) as i64;
    // My owned nodes are wrapped nodes; in my box they sit at their unwrapped index.
    let to_mine = |g: i64| {
        if layout.periodic[a] {
            g.rem_euclid(n) - my_lo
        } else {
            g - my_lo
        }
    };
    near_coords(layout, a, me)
        .into_iter()
        .filter_map(|k| {
            let b = AxisBox::new(layout, a, k);
            let spans = spans_owned_by(layout, a, (b.node_lo, b.dims), me, to_mine);
            (!spans.is_empty()).then_some((b, spans, k))
        })
        .collect()
}

/// The straightforward plan, scanning every rank's ghost nodes: per peer, my ghost
/// nodes it owns (in my order) and my owned nodes that are its ghosts (in its order),
/// as local linear indices: the reference that [`build_halo`] is tested against.
#[cfg(test)]
type Lists3 = (Vec<usize>, Vec<Vec<usize>>, Vec<Vec<usize>>);

#[cfg(test)]
fn build_halo_brute<const D: usize>(layout: &Layout<D>, rank: usize) -> Lists3 {
    let nranks = layout.ranks();
    let (my_lo, dims, _, _) = node_box(layout, rank);
    let local_of_owned = |w: [usize; D]| -> usize {
        let mut c = [0usize; D];
        for a in 0..D {
            c[a] = (w[a] as i64 - my_lo[a]) as usize;
        }
        linear(dims, c)
    };
    let mut ghosts_by: Vec<Vec<usize>> = vec![Vec::new(); nranks];
    for (i, w) in ghost_nodes(layout, rank) {
        ghosts_by[layout.node_owner(w)].push(i);
    }
    let mut owned_by: Vec<Vec<usize>> = vec![Vec::new(); nranks];
    for (other, list) in owned_by.iter_mut().enumerate() {
        for (_, w) in ghost_nodes(layout, other) {
            if layout.node_owner(w) == rank {
                list.push(local_of_owned(w));
            }
        }
    }
    let mut out: Lists3 = Default::default();
    for p in 0..nranks {
        if !ghosts_by[p].is_empty() || !owned_by[p].is_empty() {
            out.0.push(p);
            out.1.push(std::mem::take(&mut ghosts_by[p]));
            out.2.push(std::mem::take(&mut owned_by[p]));
        }
    }
    out
}

/// Ghost nodes of `rank`'s box, as (local index, wrapped global node), in local order.
#[cfg(test)]
fn ghost_nodes<const D: usize>(layout: &Layout<D>, rank: usize) -> Vec<(usize, [usize; D])> {
    let (node_lo, dims, own_lo, own_hi) = node_box(layout, rank);
    let mut out = Vec::new();
    odometer(dims, |c| {
        if (0..D).all(|a| c[a] >= own_lo[a] && c[a] < own_hi[a]) {
            return;
        }
        let g: [i64; D] = std::array::from_fn(|a| node_lo[a] + c[a] as i64);
        let w = layout
            .wrap_node(g)
            .expect("a node box lies inside the grid on bounded axes");
        out.push((linear(dims, c), w));
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_against_brute<const D: usize>(layout: &Layout<D>) {
        for rank in 0..layout.ranks() {
            let mut b = Block::new(layout, rank);
            b.dense_lists();
            let (peers, ghosts, owned) = build_halo_brute(layout, rank);
            let h = &b.halo;
            assert_eq!(h.peers, peers, "{layout:?} rank {rank}: peers");
            assert_eq!(h.sum_send, ghosts, "{layout:?} rank {rank}: ghosts");
            assert_eq!(h.sum_recv, owned, "{layout:?} rank {rank}: owned");
        }
    }

    /// The neighbour-restricted halo build gives exactly the plan of a scan over all
    /// ranks, including blocks exactly GHOST cells wide (reach two blocks up) and one
    /// or two blocks along periodic axes (the same neighbour in both directions).
    #[test]
    fn halo_matches_brute_force() {
        for (cells, per, procs) in [
            (7, false, 1),
            (7, true, 1),
            (7, false, 3),
            (7, true, 3),
            (4, true, 2),
            (5, true, 2),
            (13, true, 6),
            (13, false, 6),
            (2, true, 1),
        ] {
            check_against_brute(&Layout::new([cells], [per], [procs]).unwrap());
        }
        for per in [[false, false], [true, false], [false, true], [true, true]] {
            for (cells, procs) in [
                ([9, 7], [2, 3]),
                ([4, 4], [2, 2]),
                ([6, 5], [3, 1]),
                ([4, 9], [1, 4]),
                ([11, 4], [5, 2]),
                ([2, 3], [1, 1]),
            ] {
                check_against_brute(&Layout::new(cells, per, procs).unwrap());
            }
        }
        for per in [
            [true, false, true],
            [true, true, true],
            [false, false, false],
        ] {
            for (cells, procs) in [
                ([5, 6, 7], [2, 1, 3]),
                ([4, 4, 4], [2, 2, 1]),
                ([6, 4, 9], [3, 2, 4]),
            ] {
                check_against_brute(&Layout::new(cells, per, procs).unwrap());
            }
        }
    }
}
