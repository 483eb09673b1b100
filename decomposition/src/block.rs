//! A rank's local block: its node box with ghost layers and the halo operations on
//! nodal fields stored node-major (`field[node * ncomp + c]`).

use std::collections::BTreeMap;

use crate::comm::Communicator;
use crate::layout::{Layout, GHOST};
use crate::tiles::{Tiles, TILE};
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
    halo: Halo,
    layout: Layout<D>,
}

/// For each peer rank: which of my ghost nodes it owns, and which of my owned nodes are
/// ghosts in its box, both in the order of the peer's (resp. my) local node numbering so
/// that the two sides agree without talking.
///
/// The halo operations exchange the nodes of `sum_send`/`sum_recv` and
/// `copy_send`/`copy_recv`: the whole lists (dense local numbering) until
/// [`Block::activate_halo`] and [`Block::map_active_halo`] restrict them to the chunks
/// some rank uses this step, in the storage numbering of a [`Tiles`].
#[derive(Clone, Debug, Default)]
struct Halo {
    peers: Vec<usize>,
    /// `ghosts[k]`: my local ghost nodes owned by `peers[k]`.
    ghosts: Vec<Vec<usize>>,
    /// `owned[k]`: my local owned nodes that are ghosts of `peers[k]`, in the order of
    /// that peer's `ghosts` list for me.
    owned: Vec<Vec<usize>>,
    send: Vec<Vec<f64>>,
    recv: Vec<Vec<f64>>,
    /// `ghosts` and `owned` cut into chunks (built on the first activation).
    chunked: Option<(Vec<Chunked>, Vec<Chunked>)>,
    /// Active chunks of this step, per peer: my ghost chunks I touched (`g`), my owned
    /// chunks the peer touched (`r`), my owned chunks stored after that (`o`), my ghost
    /// chunks the peer stores (`q`).
    g: Vec<Vec<u32>>,
    r: Vec<Vec<u32>>,
    o: Vec<Vec<u32>>,
    q: Vec<Vec<u32>>,
    sum_send: Vec<Vec<usize>>,
    sum_recv: Vec<Vec<usize>>,
    copy_send: Vec<Vec<usize>>,
    copy_recv: Vec<Vec<usize>>,
    /// Stored ghost nodes that no copy reaches this step (their owner stores nothing
    /// there, so their value is zero); the ghost copy zeroes them, else they would
    /// keep an earlier step's value.
    stale: Vec<usize>,
    /// What `ghost_sum`, `ghost_copy` and `activate_halo` sent to other ranks so far.
    traffic: Traffic,
}

/// A halo list cut into chunks: the entries of one tile of the global node grid
/// (wrapped global node / [`TILE`] per axis), made contiguous, chunks in the order of
/// their first entry. The two ranks of a pair see the same list in the same order and
/// the same global nodes, so they cut it alike and can name a chunk by its number.
#[derive(Clone, Debug, Default)]
struct Chunked {
    /// Local dense node indices, grouped by chunk.
    nodes: Vec<usize>,
    /// Key of the local tile ([`Tiles::key_of`]) of each node.
    keys: Vec<u64>,
    /// Chunk `c` is `nodes[start[c]..start[c + 1]]`.
    start: Vec<usize>,
    /// Chunk `c`'s distinct local tile keys: `tiles[tile_start[c]..tile_start[c + 1]]`.
    tiles: Vec<u64>,
    tile_start: Vec<usize>,
}

impl Chunked {
    fn new<const D: usize>(
        list: &[usize],
        block: &Block<D>,
        layout: &Layout<D>,
        t: &Tiles<D>,
    ) -> Self {
        let mut order: Vec<(usize, [usize; D])> = Vec::with_capacity(list.len());
        let mut first: BTreeMap<[usize; D], usize> = BTreeMap::new();
        for (i, &n) in list.iter().enumerate() {
            let w = layout
                .wrap_node(block.global(block.coords(n)))
                .expect("halo nodes lie in the grid");
            let tile: [usize; D] = std::array::from_fn(|a| w[a] / TILE);
            let f = *first.entry(tile).or_insert(i);
            order.push((f, [0; D]));
            order[i].1 = tile;
        }
        // Stable: entries keep their list order within a chunk.
        let mut idx: Vec<usize> = (0..list.len()).collect();
        idx.sort_by_key(|&i| order[i].0);
        let mut c = Chunked::default();
        let mut prev = usize::MAX;
        for &i in &idx {
            if order[i].0 != prev {
                prev = order[i].0;
                c.start.push(c.nodes.len());
                c.tile_start.push(c.tiles.len());
            }
            let n = list[i];
            let k = t.key_of(block.coords(n));
            c.nodes.push(n);
            c.keys.push(k);
            let from = *c.tile_start.last().expect("a chunk is open");
            if !c.tiles[from..].contains(&k) {
                c.tiles.push(k);
            }
        }
        c.start.push(c.nodes.len());
        c.tile_start.push(c.tiles.len());
        c
    }

    fn chunks(&self) -> usize {
        self.start.len() - 1
    }

    fn tiles_of(&self, c: usize) -> &[u64] {
        &self.tiles[self.tile_start[c]..self.tile_start[c + 1]]
    }

    /// Append the storage indices of the stored nodes of the chunks not in `chunks`
    /// (ascending).
    fn stored_outside<const D: usize>(
        &self,
        chunks: &[u32],
        block: &Block<D>,
        t: &Tiles<D>,
        out: &mut Vec<usize>,
    ) {
        let mut next = chunks.iter().peekable();
        for c in 0..self.chunks() {
            if next.peek().is_some_and(|&&x| x as usize == c) {
                next.next();
                continue;
            }
            for i in self.start[c]..self.start[c + 1] {
                let slot = t.slot_of_key(self.keys[i]);
                if slot != 0 {
                    out.push(t.index_in(slot, block.coords(self.nodes[i])));
                }
            }
        }
    }

    /// Replace `out` by the storage indices of the nodes of `chunks` (all stored).
    fn storage<const D: usize>(
        &self,
        chunks: &[u32],
        block: &Block<D>,
        t: &Tiles<D>,
        out: &mut Vec<usize>,
    ) {
        out.clear();
        for &c in chunks {
            let c = c as usize;
            for i in self.start[c]..self.start[c + 1] {
                let slot = t.slot_of_key(self.keys[i]);
                debug_assert!(slot != 0, "an active chunk's tiles are stored");
                out.push(t.index_in(slot, block.coords(self.nodes[i])));
            }
        }
    }

    /// Replace `out` by the chunks (as `f64`) with a tile for which `on` holds.
    fn active(&self, on: impl Fn(u64) -> bool, out: &mut Vec<f64>) {
        out.clear();
        for c in 0..self.chunks() {
            if self.tiles_of(c).iter().any(|&k| on(k)) {
                out.push(c as f64);
            }
        }
    }

    /// Touch every tile of `chunks`.
    fn touch<const D: usize>(&self, chunks: &[u32], t: &mut Tiles<D>) {
        for &c in chunks {
            for &k in self.tiles_of(c as usize) {
                t.touch_key(k);
            }
        }
    }
}

/// Chunk numbers received as `f64` (exact below 2^53), checked against the list.
fn chunk_ids(buf: &[f64], list: &Chunked, out: &mut Vec<u32>) {
    out.clear();
    for &x in buf {
        let c = x as usize;
        assert!(
            c < list.chunks() && c as f64 == x,
            "ranks disagree on the halo's chunks"
        );
        out.push(c as u32);
    }
}

impl<const D: usize> Block<D> {
    /// The block of `rank` in `layout`, with its halo exchange lists.
    pub fn new(layout: &Layout<D>, rank: usize) -> Self {
        let (cell_lo, cell_hi) = layout.block_cells(rank);
        let (node_lo, node_dims, own_lo, own_hi) = node_box(layout, rank);
        let mut b = Self {
            rank,
            cell_lo,
            cell_hi,
            node_lo,
            node_dims,
            own_lo,
            own_hi,
            halo: Halo::default(),
            layout: layout.clone(),
        };
        b.halo = build_halo(layout, rank);
        let h = &mut b.halo;
        h.sum_send = h.ghosts.clone();
        h.sum_recv = h.owned.clone();
        h.copy_send = h.owned.clone();
        h.copy_recv = h.ghosts.clone();
        b
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
    /// [`Tiles::finish`]; then [`Block::map_active_halo`]. The halo lists are cut into
    /// chunks (one global tile's nodes each); two exchanges of chunk numbers decide:
    /// 1. each rank tells the owners which of its ghost chunks it touched; an owner
    ///    stores those chunks (a neighbour's particles put mass there);
    /// 2. each owner tells the ranks that hold its owned chunks as ghosts which of
    ///    them it stores now (its particles', and those of step 1 from any rank);
    ///    they store them, so that every node with mass reaches every copy.
    ///
    /// The ghost sum then sends the chunks of step 1, the ghost copy those of step 2.
    /// A halo chunk no rank's particles come near is neither stored nor sent, so the
    /// halo's cost follows the material, not the block faces.
    pub fn activate_halo(&mut self, comm: &dyn Communicator, tiles: &mut Tiles<D>) {
        if self.halo.chunked.is_none() {
            let chunk = |l: &Vec<Vec<usize>>| -> Vec<Chunked> {
                l.iter()
                    .map(|list| Chunked::new(list, self, &self.layout, tiles))
                    .collect()
            };
            self.halo.chunked = Some((chunk(&self.halo.ghosts), chunk(&self.halo.owned)));
        }
        let h = &mut self.halo;
        let n = h.peers.len();
        for v in [&mut h.g, &mut h.r, &mut h.o, &mut h.q] {
            v.resize_with(n, Vec::new);
        }
        let (ghosts, owned) = h.chunked.as_ref().expect("chunked above");
        // Step 1: my touched ghost chunks to their owners.
        let touched = tiles.touched_sorted();
        for k in 0..n {
            ghosts[k].active(|t| touched.binary_search(&t).is_ok(), &mut h.send[k]);
        }
        h.traffic.record(self.rank, &h.peers, &h.send);
        comm.exchange(&h.peers, &h.send, &mut h.recv);
        for k in 0..n {
            chunk_ids(&h.send[k], &ghosts[k], &mut h.g[k]);
            chunk_ids(&h.recv[k], &owned[k], &mut h.r[k]);
            ghosts[k].touch(&h.g[k], tiles);
            owned[k].touch(&h.r[k], tiles);
        }
        // Step 2: my stored owned chunks to the ranks that hold them as ghosts.
        let stored = tiles.touched_sorted();
        for k in 0..n {
            owned[k].active(|t| stored.binary_search(&t).is_ok(), &mut h.send[k]);
        }
        h.traffic.record(self.rank, &h.peers, &h.send);
        comm.exchange(&h.peers, &h.send, &mut h.recv);
        for k in 0..n {
            chunk_ids(&h.send[k], &owned[k], &mut h.o[k]);
            chunk_ids(&h.recv[k], &ghosts[k], &mut h.q[k]);
            owned[k].touch(&h.o[k], tiles);
            ghosts[k].touch(&h.q[k], tiles);
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
        let mut h = std::mem::take(&mut self.halo);
        let (ghosts, owned) = h.chunked.as_ref().expect("activate_halo first");
        h.stale.clear();
        for k in 0..h.peers.len() {
            ghosts[k].storage(&h.g[k], self, tiles, &mut h.sum_send[k]);
            owned[k].storage(&h.r[k], self, tiles, &mut h.sum_recv[k]);
            owned[k].storage(&h.o[k], self, tiles, &mut h.copy_send[k]);
            ghosts[k].storage(&h.q[k], self, tiles, &mut h.copy_recv[k]);
            ghosts[k].stored_outside(&h.q[k], self, tiles, &mut h.stale);
        }
        self.halo = h;
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
        debug_assert!(slots.end <= width);
        let (lo, hi) = (slots.start, slots.end);
        let ncomp = hi - lo;
        let h = &mut self.halo;
        for (k, nodes) in h.sum_send.iter().enumerate() {
            let buf = &mut h.send[k];
            buf.clear();
            for &n in nodes {
                buf.extend_from_slice(&field[n * width + lo..n * width + hi]);
            }
        }
        h.traffic.record(self.rank, &h.peers, &h.send);
        comm.exchange(&h.peers, &h.send, &mut h.recv);
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
        let h = &mut self.halo;
        for (k, nodes) in h.copy_send.iter().enumerate() {
            let buf = &mut h.send[k];
            buf.clear();
            for &n in nodes {
                buf.extend_from_slice(&field[n * ncomp..(n + 1) * ncomp]);
            }
        }
        h.traffic.record(self.rank, &h.peers, &h.send);
        comm.exchange(&h.peers, &h.send, &mut h.recv);
        for &n in &h.stale {
            field[n * ncomp..(n + 1) * ncomp].fill(0.0);
        }
        for (k, nodes) in h.copy_recv.iter().enumerate() {
            let buf = &h.recv[k];
            debug_assert_eq!(buf.len(), nodes.len() * ncomp);
            for (j, &n) in nodes.iter().enumerate() {
                field[n * ncomp..(n + 1) * ncomp].copy_from_slice(&buf[j * ncomp..(j + 1) * ncomp]);
            }
        }
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

    fn owns(&self, l: usize) -> bool {
        l >= self.own_lo && l < self.own_hi
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

/// Block coordinate along axis `a` of the owner of global (unwrapped) node `g`. Node
/// ownership is a product over axes too: the owner of a node is the block whose
/// per-axis coordinates own the node's per-axis indices.
fn axis_owner<const D: usize>(layout: &Layout<D>, a: usize, g: i64) -> usize {
    let w = if layout.periodic[a] {
        g.rem_euclid(layout.nodes(a) as i64) as usize
    } else {
        debug_assert!(g >= 0 && (g as usize) < layout.nodes(a));
        g as usize
    };
    layout.block_along(a, w.min(layout.cells[a] - 1))
}

/// Call `f` for every index tuple `i` with `i[a] < lens[a]`, axis 0 fastest (so local
/// node boxes are walked in increasing linear index).
fn odometer<const D: usize>(lens: [usize; D], mut f: impl FnMut([usize; D])) {
    if lens.contains(&0) {
        return;
    }
    let mut i = [0usize; D];
    loop {
        f(i);
        let mut a = 0;
        loop {
            if a == D {
                return;
            }
            i[a] += 1;
            if i[a] < lens[a] {
                break;
            }
            i[a] = 0;
            a += 1;
        }
    }
}

/// Call `f` for every index tuple `i` with `i[a] < lens[a]` for which `inner(a, i[a])`
/// is false on at least one axis, in the order of [`odometer`]. The work is
/// proportional to the tuples visited plus the inner tuples' projections, not to the
/// product of the lengths: a node box's ghost layer is walked without its interior, so
/// a huge box with a small body costs its surface, not its volume.
fn odometer_outside<const D: usize>(
    lens: [usize; D],
    inner: impl Fn(usize, usize) -> bool,
    mut f: impl FnMut([usize; D]),
) {
    if lens.contains(&0) {
        return;
    }
    // Per axis, the positions that are not inner.
    let outer: [Vec<usize>; D] =
        std::array::from_fn(|a| (0..lens[a]).filter(|&v| !inner(a, v)).collect());
    fn rec<const D: usize>(
        a: usize,
        i: &mut [usize; D],
        lens: &[usize; D],
        outer: &[Vec<usize>; D],
        inner: &impl Fn(usize, usize) -> bool,
        outside: bool,
        f: &mut impl FnMut([usize; D]),
    ) {
        if outside {
            // Everything below axis `a` (inclusive), in odometer order.
            let mut sub = [1usize; D];
            sub[..=a].copy_from_slice(&lens[..=a]);
            let hi = *i;
            odometer::<D>(sub, |j| {
                let mut t = hi;
                t[..=a].copy_from_slice(&j[..=a]);
                f(t);
            });
            return;
        }
        if a == 0 {
            for &v in &outer[0] {
                i[0] = v;
                f(*i);
            }
            return;
        }
        for v in 0..lens[a] {
            i[a] = v;
            rec(a - 1, i, lens, outer, inner, !inner(a, v), f);
        }
    }
    let mut i = [0usize; D];
    rec(D - 1, &mut i, &lens, &outer, &inner, false, &mut f);
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
fn build_halo<const D: usize>(layout: &Layout<D>, rank: usize) -> Halo {
    let me = layout.block_coords(rank);
    let mine: [AxisBox; D] = std::array::from_fn(|a| AxisBox::new(layout, a, me[a]));
    // Per peer: (my ghosts it owns, my owned nodes that are its ghosts).
    let mut lists: BTreeMap<usize, (Vec<usize>, Vec<usize>)> = BTreeMap::new();
    for (p, ghosts) in ghosts_by_owner(layout, &mine) {
        lists.entry(p).or_default().0 = ghosts;
    }
    for (p, owned) in owned_by_peer(layout, me, &mine) {
        lists.entry(p).or_default().1 = owned;
    }
    let mut h = Halo::default();
    for (p, (ghosts, owned)) in lists {
        h.peers.push(p);
        h.ghosts.push(ghosts);
        h.owned.push(owned);
    }
    h.send = vec![Vec::new(); h.peers.len()];
    h.recv = vec![Vec::new(); h.peers.len()];
    h
}

/// My ghost nodes (local linear indices in my box `mine`), grouped by the rank that
/// owns them.
fn ghosts_by_owner<const D: usize>(
    layout: &Layout<D>,
    mine: &[AxisBox; D],
) -> Vec<(usize, Vec<usize>)> {
    let my_dims: [usize; D] = std::array::from_fn(|a| mine[a].dims);
    let is_mine_owned = |l: [usize; D]| (0..D).all(|a| mine[a].owns(l[a]));
    let mut lists = Vec::new();
    let owner_along: [Vec<usize>; D] = std::array::from_fn(|a| {
        (0..mine[a].dims)
            .map(|l| axis_owner(layout, a, mine[a].node_lo + l as i64))
            .collect()
    });
    let owners: [Vec<usize>; D] = std::array::from_fn(|a| {
        let mut v = owner_along[a].clone();
        v.sort_unstable();
        v.dedup();
        v
    });
    odometer::<D>(std::array::from_fn(|a| owners[a].len()), |j| {
        let q: [usize; D] = std::array::from_fn(|a| owners[a][j[a]]);
        let pos: [Vec<usize>; D] = std::array::from_fn(|a| {
            (0..mine[a].dims)
                .filter(|&l| owner_along[a][l] == q[a])
                .collect()
        });
        let mut ghosts = Vec::new();
        odometer_outside::<D>(
            std::array::from_fn(|a| pos[a].len()),
            |a, v| mine[a].owns(pos[a][v]),
            |i| {
                let l: [usize; D] = std::array::from_fn(|a| pos[a][i[a]]);
                debug_assert!(!is_mine_owned(l));
                ghosts.push(linear(my_dims, l));
            },
        );
        if !ghosts.is_empty() {
            lists.push((layout.rank_of_block(q), ghosts));
        }
    });
    lists
}

/// My owned nodes (local linear indices in my box `mine`, at block coordinates `me`)
/// that are ghosts in other boxes, grouped by the rank whose box it is.
fn owned_by_peer<const D: usize>(
    layout: &Layout<D>,
    me: [usize; D],
    mine: &[AxisBox; D],
) -> Vec<(usize, Vec<usize>)> {
    let my_dims: [usize; D] = std::array::from_fn(|a| mine[a].dims);
    let near: [Vec<(AxisBox, Vec<usize>, usize)>; D] =
        std::array::from_fn(|a| near_blocks(layout, a, me[a]));
    let mut lists = Vec::new();
    odometer::<D>(std::array::from_fn(|a| near[a].len()), |j| {
        let other: [&(AxisBox, Vec<usize>, usize); D] = std::array::from_fn(|a| &near[a][j[a]]);
        let mut owned = Vec::new();
        // Nodes owned there are that block's nodes, i.e. mine: not ghosts.
        odometer_outside::<D>(
            std::array::from_fn(|a| other[a].1.len()),
            |a, v| other[a].0.owns(other[a].1[v]),
            |i| {
                let l: [usize; D] = std::array::from_fn(|a| other[a].1[i[a]]);
                // Wrapped global index of the node, which lies in my owned range, hence
                // equals its unwrapped index there.
                let local: [usize; D] = std::array::from_fn(|a| {
                    let g = other[a].0.node_lo + l[a] as i64;
                    let w = if layout.periodic[a] {
                        g.rem_euclid(layout.nodes(a) as i64)
                    } else {
                        g
                    };
                    let m = (w - mine[a].node_lo) as usize;
                    debug_assert!(mine[a].owns(m));
                    m
                });
                owned.push(linear(my_dims, local));
            },
        );
        if !owned.is_empty() {
            let q: [usize; D] = std::array::from_fn(|a| other[a].2);
            lists.push((layout.rank_of_block(q), owned));
        }
    });
    lists
}

/// Along axis `a`, the blocks near mine (coordinate `me`) whose box has positions I
/// own: each box, those positions and the block's coordinate.
fn near_blocks<const D: usize>(
    layout: &Layout<D>,
    a: usize,
    me: usize,
) -> Vec<(AxisBox, Vec<usize>, usize)> {
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
    ks.into_iter()
        .filter_map(|k| {
            let b = AxisBox::new(layout, a, k);
            let pos: Vec<usize> = (0..b.dims)
                .filter(|&l| axis_owner(layout, a, b.node_lo + l as i64) == me)
                .collect();
            (!pos.is_empty()).then_some((b, pos, k))
        })
        .collect()
}

/// The straightforward plan, scanning every rank's ghost nodes: the reference that
/// [`build_halo`] is tested against.
#[cfg(test)]
fn build_halo_brute<const D: usize>(layout: &Layout<D>, rank: usize) -> Halo {
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
    let mut h = Halo::default();
    for p in 0..nranks {
        if !ghosts_by[p].is_empty() || !owned_by[p].is_empty() {
            h.peers.push(p);
            h.ghosts.push(std::mem::take(&mut ghosts_by[p]));
            h.owned.push(std::mem::take(&mut owned_by[p]));
        }
    }
    h
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
            let fast = build_halo(layout, rank);
            let brute = build_halo_brute(layout, rank);
            assert_eq!(fast.peers, brute.peers, "{layout:?} rank {rank}: peers");
            assert_eq!(fast.ghosts, brute.ghosts, "{layout:?} rank {rank}: ghosts");
            assert_eq!(fast.owned, brute.owned, "{layout:?} rank {rank}: owned");
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

    /// The walk without the interior visits exactly the tuples of the full walk that
    /// have an outer position, in the same order.
    #[test]
    fn odometer_outside_skips_only_the_interior() {
        let lens = [5usize, 4, 3];
        let inner = |a: usize, v: usize| [(1..4), (1..3), (0..2)][a].contains(&v);
        let mut want = Vec::new();
        odometer(lens, |i| {
            if !(0..3).all(|a| inner(a, i[a])) {
                want.push(i);
            }
        });
        let mut got = Vec::new();
        odometer_outside(lens, inner, |i| got.push(i));
        assert_eq!(got, want);
        let mut none = 0;
        odometer_outside([4, 4], |_, _| true, |_| none += 1);
        assert_eq!(none, 0);
    }

    #[test]
    fn odometer_walks_in_linear_order() {
        let mut seen = Vec::new();
        odometer([3, 2, 2], |c| seen.push(linear([3, 2, 2], c)));
        assert_eq!(seen, (0..12).collect::<Vec<_>>());
        let mut n = 0;
        odometer([3, 0], |_| n += 1);
        assert_eq!(n, 0);
    }
}
