//! Sparse storage of a rank's nodal fields: the local node box of a [`crate::Block`]
//! is cut into tiles of [`TILE`] nodes per axis, and only *active* tiles are stored.
//!
//! The local node box stays the address space (a node is named by its local
//! coordinates, `usize` per axis, so a 65536² or 4096³ box cannot overflow), but
//! storage is `slot * TILE_NODES + offset`: slot 0 is a read-only *zero tile* that
//! every missing neighbour points at, and slots from 1 on hold the tiles the caller
//! touched since [`Tiles::begin`] (its particles' and the halo's that
//! [`crate::Block::activate_halo`] agreed on), in increasing tile key (last axis
//! slowest). Within a tile,
//! nodes are numbered axis 0 fastest. Fields are stored node-major over this storage
//! (`field[index * ncomp + c]`), so memory and every loop over the tiles follow the
//! active set, not the box.
//!
//! Finding a node from a neighbouring one is a table look-up: each slot keeps the
//! slots of its `3^D` neighbouring tiles ([`Tiles::neighbours`], 0 where a neighbour
//! is not active). A particle's nodes lie within one tile of its cell's tile, and the
//! grid stencils of MPMCG reach one node, so this table is all they need.
//!
//! Tiles are aligned so that their faces along every axis fall on the owned range's
//! lower corner (`own_lo`) plus multiples of [`TILE`]: with `TILE` equal to the
//! scatter's slab thickness, a slab of cells is a layer of tiles.
//!
//! The crate knows nothing of what the fields mean: which tiles are touched is the
//! caller's business.

/// Nodes per tile along each axis (a power of two).
pub const TILE: usize = 4;
/// `log2(TILE)`.
pub const TILE_LOG: u32 = 2;
/// Neighbour table width: `3^D <= 27` entries are used; 32 so that an index masked
/// with `& 31` needs no bounds check.
pub const NEIGHBOURS: usize = 32;

/// Active tiles of a local node box and where each one is stored.
#[derive(Clone, Debug)]
pub struct Tiles<const D: usize> {
    /// Local node box size.
    dims: [usize; D],
    /// Local node `l` sits at tile coordinate `(l + shift) / TILE`.
    shift: [usize; D],
    /// Tiles per axis.
    tdims: [usize; D],
    /// Key of the tile in each slot (slot 0: the zero tile, `u64::MAX`).
    keys: Vec<u64>,
    /// (key, slot) of each active tile in an open-addressed hash table, a power of two
    /// at least twice the active count, linear probing, `(u64::MAX, 0)` where empty:
    /// [`Tiles::slot_of_key`] in one or two probes. A binary search over the sorted
    /// keys was a chain of a dozen unpredictable branches per look-up (2 % of the
    /// vortex's step, whose runs change tile often).
    lookup: Vec<(u64, u32)>,
    /// `64 − log2(lookup.len())`: the shift that keeps a hash's top bits.
    lookup_shift: u32,
    /// Per slot: tile coordinates times TILE (in shifted node units).
    origin: Vec<[usize; D]>,
    /// Per slot: the storage index of the first node of each neighbouring tile (its
    /// slot times `TILE_NODES`), index `Σ_a (d_a + 1) 3^a` for offsets
    /// `d ∈ {-1, 0, 1}^D`; 0 (the zero tile) where the neighbour is not active.
    nbr: Vec<[usize; NEIGHBOURS]>,
    /// Touched keys since `begin` (scratch), then the active keys.
    touched: Vec<u64>,
    active: Vec<u64>,
    /// A direct-mapped memory of recently touched keys, so that the particles of one
    /// tile (sorted by cell) push its key about once.
    recent: Vec<u64>,
}

/// Entries of [`Tiles::recent`] (a power of two).
const RECENT: usize = 1024;

impl<const D: usize> Tiles<D> {
    /// Tiles over a local node box of `dims` nodes whose owned range starts at `own_lo`.
    pub fn new(dims: [usize; D], own_lo: [usize; D]) -> Self {
        assert!(D <= 3, "tiles are for 1, 2 and 3 dimensions");
        let shift: [usize; D] = std::array::from_fn(|a| (TILE - own_lo[a] % TILE) % TILE);
        let tdims: [usize; D] = std::array::from_fn(|a| (dims[a] + shift[a]).div_ceil(TILE));
        let mut t = Self {
            dims,
            shift,
            tdims,
            keys: Vec::new(),
            lookup: Vec::new(),
            lookup_shift: 64,
            origin: Vec::new(),
            nbr: Vec::new(),
            touched: Vec::new(),
            active: Vec::new(),
            recent: vec![u64::MAX; RECENT],
        };
        t.assign();
        t
    }

    /// Nodes per tile, `TILE^D`.
    pub const TILE_NODES: usize = 1 << (TILE_LOG as usize * D);

    /// Nodes per tile, `TILE^D`.
    #[inline(always)]
    pub fn tile_nodes(&self) -> usize {
        Self::TILE_NODES
    }

    /// Slots in use, the zero tile included.
    #[inline]
    pub fn slots(&self) -> usize {
        self.keys.len()
    }

    /// Active tiles (the zero tile excluded).
    pub fn active(&self) -> usize {
        self.keys.len() - 1
    }

    /// Length of a one-component field over the storage.
    #[inline]
    pub fn nodes(&self) -> usize {
        self.keys.len() * Self::TILE_NODES
    }

    /// Local node box size.
    pub fn dims(&self) -> [usize; D] {
        self.dims
    }

    /// Per-axis shift of the tile alignment (local node `l` lies in tile `(l + shift) /
    /// TILE`).
    #[inline]
    pub fn shift(&self) -> [usize; D] {
        self.shift
    }

    fn key(&self, t: [usize; D]) -> u64 {
        let mut k = 0u64;
        for a in (0..D).rev() {
            k = k * self.tdims[a] as u64 + t[a] as u64;
        }
        k
    }

    fn coords_of_key(&self, mut k: u64) -> [usize; D] {
        let mut t = [0usize; D];
        for a in 0..D {
            t[a] = (k % self.tdims[a] as u64) as usize;
            k /= self.tdims[a] as u64;
        }
        t
    }

    /// Key of the tile holding local node `l`.
    #[inline]
    pub fn key_of(&self, l: [usize; D]) -> u64 {
        self.key(std::array::from_fn(|a| (l[a] + self.shift[a]) >> TILE_LOG))
    }

    /// Start collecting the touched tiles of the next active set.
    pub fn begin(&mut self) {
        self.touched.clear();
        self.recent.fill(u64::MAX);
    }

    /// Touch the tiles of the local nodes `lo..=hi` (per axis, clamped to the box).
    #[inline]
    pub fn touch(&mut self, lo: [i64; D], hi: [i64; D]) {
        let Some((t0, t1)) = self.tile_box(lo, hi) else {
            return;
        };
        let mut t = t0;
        loop {
            self.touch_key(self.key(t));
            if !next_tile(&mut t, &t0, &t1) {
                return;
            }
        }
    }

    /// The keys of the tiles holding the local nodes `lo..=hi` (per axis, clamped to
    /// the box) into `keys`, their count returned: what [`Tiles::touch`] touches, for
    /// callers that gather keys on several threads and touch them after
    /// ([`Tiles::touch_key`]). For boxes at most one node wider than a tile along each
    /// axis (a particle's nodes), which lie in at most `2^D` tiles.
    #[inline]
    pub fn keys_of_nodes(&self, lo: [i64; D], hi: [i64; D], keys: &mut [u64; 8]) -> usize {
        let Some((t0, t1)) = self.tile_box(lo, hi) else {
            return 0;
        };
        assert!(
            (0..D).all(|a| t1[a] <= t0[a] + 1),
            "a node box wider than a tile and a node"
        );
        let mut n = 0;
        let mut t = t0;
        loop {
            keys[n] = self.key(t);
            n += 1;
            if !next_tile(&mut t, &t0, &t1) {
                return n;
            }
        }
    }

    /// The first and last tile (per axis) of the local nodes `lo..=hi` clamped to the
    /// box, `None` if none of them is in it.
    #[inline]
    fn tile_box(&self, lo: [i64; D], hi: [i64; D]) -> Option<([usize; D], [usize; D])> {
        let mut t0 = [0usize; D];
        let mut t1 = [0usize; D];
        for a in 0..D {
            let l = lo[a].max(0) as usize;
            let h = (hi[a].max(0) as usize).min(self.dims[a] - 1);
            if l > h {
                return None;
            }
            t0[a] = (l + self.shift[a]) >> TILE_LOG;
            t1[a] = (h + self.shift[a]) >> TILE_LOG;
        }
        Some((t0, t1))
    }

    /// Touch the tile with key `k` (a key of [`Tiles::key_of`]).
    #[inline]
    pub fn touch_key(&mut self, k: u64) {
        let r = &mut self.recent[k as usize & (RECENT - 1)];
        if *r != k {
            *r = k;
            self.touched.push(k);
        }
    }

    /// Sort the keys touched since [`Tiles::begin`] and drop repeats.
    pub fn sort_touched(&mut self) {
        self.touched.sort_unstable();
        self.touched.dedup();
    }

    /// The keys touched since [`Tiles::begin`] (ascending without repeats after
    /// [`Tiles::sort_touched`]).
    pub fn touched(&self) -> &[u64] {
        &self.touched
    }

    /// The local nodes `[lo, hi)` per axis of the tile with key `k`, clipped to the box.
    pub fn key_range(&self, k: u64) -> ([usize; D], [usize; D]) {
        self.tile_range(self.coords_of_key(k))
    }

    /// The local nodes `[lo, hi)` per axis of `slot`'s tile, clipped to the box.
    pub fn slot_range(&self, slot: usize) -> ([usize; D], [usize; D]) {
        self.tile_range(self.origin[slot].map(|o| o >> TILE_LOG))
    }

    fn tile_range(&self, t: [usize; D]) -> ([usize; D], [usize; D]) {
        let lo = std::array::from_fn(|a| ((t[a] << TILE_LOG).max(self.shift[a])) - self.shift[a]);
        let hi =
            std::array::from_fn(|a| (((t[a] + 1) << TILE_LOG) - self.shift[a]).min(self.dims[a]));
        (lo, hi)
    }

    /// Make the touched tiles the active set. Returns whether
    /// it changed; if not, slots are as before. Storage grows amortised: the caller's
    /// fields are resized to [`Tiles::nodes`], which keeps their capacity.
    pub fn finish(&mut self) -> bool {
        let mut touched = std::mem::take(&mut self.touched);
        touched.sort_unstable();
        touched.dedup();
        let changed = touched != self.active;
        if changed {
            std::mem::swap(&mut self.active, &mut touched);
            self.assign();
        }
        self.touched = touched;
        changed
    }

    /// Slots, look-up table, origins and neighbour tables for `active`.
    fn assign(&mut self) {
        self.keys.clear();
        self.keys.push(u64::MAX);
        self.keys.extend_from_slice(&self.active);
        assert!(
            self.keys.len() < u32::MAX as usize,
            "more active tiles than a u32 slot can name"
        );
        let size = (2 * self.active.len()).next_power_of_two().max(2);
        self.lookup_shift = 64 - size.trailing_zeros();
        self.lookup.clear();
        self.lookup.resize(size, (u64::MAX, 0));
        for (j, &k) in self.active.iter().enumerate() {
            let mut i = self.home(k);
            while self.lookup[i].0 != u64::MAX {
                i = (i + 1) & (size - 1);
            }
            self.lookup[i] = (k, (1 + j) as u32);
        }
        self.origin.clear();
        self.nbr.clear();
        self.origin.push([0; D]);
        self.nbr.push([0; NEIGHBOURS]);
        for s in 1..self.keys.len() {
            let t = self.coords_of_key(self.keys[s]);
            self.origin.push(std::array::from_fn(|a| t[a] << TILE_LOG));
            let mut row = [0usize; NEIGHBOURS];
            for (d, e) in row.iter_mut().enumerate().take(3usize.pow(D as u32)) {
                let mut r = d;
                let mut n = [0usize; D];
                let mut inside = true;
                for a in 0..D {
                    let o = (r % 3) as i64 - 1;
                    r /= 3;
                    let c = t[a] as i64 + o;
                    inside &= c >= 0 && c < self.tdims[a] as i64;
                    n[a] = c.max(0) as usize;
                }
                if inside {
                    *e = self.slot_of_key(self.key(n)) as usize * Self::TILE_NODES;
                }
            }
            self.nbr.push(row);
        }
    }

    /// Where key `k`'s probe sequence starts in [`Tiles::lookup`] (Fibonacci hashing:
    /// neighbouring keys land far apart).
    #[inline(always)]
    fn home(&self, k: u64) -> usize {
        (k.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> self.lookup_shift) as usize
    }

    /// Slot of a tile key, 0 if not active.
    #[inline]
    pub fn slot_of_key(&self, k: u64) -> u32 {
        // The table is at most half full, so every probe sequence reaches an empty
        // entry (key `u64::MAX`, which no tile has: keys are below the tile count).
        let mask = self.lookup.len() - 1;
        let mut i = self.home(k);
        loop {
            let (key, slot) = self.lookup[i];
            if key == k {
                return slot;
            }
            if key == u64::MAX {
                return 0;
            }
            i = (i + 1) & mask;
        }
    }

    /// Slot of the tile holding local node `l`, 0 if not active.
    #[inline]
    pub fn slot_of(&self, l: [usize; D]) -> u32 {
        self.slot_of_key(self.key_of(l))
    }

    /// Offset within a tile of tile-local coordinates `r` (each below TILE).
    #[inline(always)]
    pub fn offset(r: [usize; D]) -> usize {
        let mut o = 0;
        for a in (0..D).rev() {
            o = (o << TILE_LOG) | r[a];
        }
        o
    }

    /// Storage index of local node `l`, if its tile is active.
    pub fn index(&self, l: [usize; D]) -> Option<usize> {
        if (0..D).any(|a| l[a] >= self.dims[a]) {
            return None;
        }
        let s = self.slot_of(l) as usize;
        let r: [usize; D] = std::array::from_fn(|a| (l[a] + self.shift[a]) & (TILE - 1));
        (s != 0).then(|| s * Self::TILE_NODES + Self::offset(r))
    }

    /// Storage index of local node `l` given its tile's slot (from
    /// [`Tiles::slot_of_key`] of [`Tiles::key_of`]`(l)`).
    #[inline]
    pub fn index_in(&self, slot: u32, l: [usize; D]) -> usize {
        let r: [usize; D] = std::array::from_fn(|a| (l[a] + self.shift[a]) & (TILE - 1));
        slot as usize * Self::TILE_NODES + Self::offset(r)
    }

    /// Tile origin of a slot, in shifted node units (`l + shift`).
    #[inline(always)]
    pub fn origin(&self, slot: usize) -> [usize; D] {
        self.origin[slot]
    }

    /// First storage index of each neighbouring tile of a slot (see the field's docs
    /// for the numbering).
    #[inline(always)]
    pub fn neighbours(&self, slot: usize) -> &[usize; NEIGHBOURS] {
        &self.nbr[slot]
    }

    /// Local coordinates of the node at `offset` in `slot`, `None` outside the box.
    #[inline]
    pub fn local(&self, slot: usize, offset: usize) -> Option<[usize; D]> {
        let o = self.origin[slot];
        let mut l = [0usize; D];
        for a in 0..D {
            l[a] = self.within(a, o[a] + ((offset >> (TILE_LOG * a as u32)) & (TILE - 1)))?;
        }
        Some(l)
    }

    /// Local coordinates of the first node of `slot`'s tile when all its nodes are in
    /// the box, `None` where the tile overhangs it: then [`Tiles::local`] of the node
    /// at `offset` is these plus the offset's position along each axis.
    #[inline]
    pub fn local_first(&self, slot: usize) -> Option<[usize; D]> {
        let o = self.origin[slot];
        let mut l = [0usize; D];
        for a in 0..D {
            if o[a] < self.shift[a] || o[a] - self.shift[a] + TILE > self.dims[a] {
                return None;
            }
            l[a] = o[a] - self.shift[a];
        }
        Some(l)
    }

    /// The local coordinate along axis `a` of shifted node coordinate `m`, `None`
    /// outside the box.
    #[inline(always)]
    fn within(&self, a: usize, m: usize) -> Option<usize> {
        (m >= self.shift[a] && m - self.shift[a] < self.dims[a]).then(|| m - self.shift[a])
    }

    /// [`Tiles::local`] of the [`TILE`] nodes of the row along the first axis that
    /// starts at `offset` in `slot` (its first-axis position 0): the row's other
    /// coordinates are checked once, not once per node (the node stencils ask for
    /// every row of every active tile, and per node this was 2 % of a 3D step's
    /// instructions).
    #[inline]
    pub fn local_row(&self, slot: usize, offset: usize) -> [Option<[usize; D]>; TILE] {
        debug_assert_eq!(offset & (TILE - 1), 0, "a row starts at position 0");
        let mut out = [None; TILE];
        let o = self.origin[slot];
        let mut l = [0usize; D];
        for a in 1..D {
            match self.within(a, o[a] + ((offset >> (TILE_LOG * a as u32)) & (TILE - 1))) {
                Some(c) => l[a] = c,
                None => return out,
            }
        }
        for (x, out) in out.iter_mut().enumerate() {
            *out = self.within(0, o[0] + x).map(|c| {
                l[0] = c;
                l
            });
        }
        out
    }

    /// Storage indices of the `3^D` nodes `n + d`, `d ∈ {-1, 0, 1}^D` (index
    /// `Σ_a (d_a + 1) 3^a`), of the node with storage index `n`, into `out`; a
    /// neighbour in a tile that is not active maps into the zero tile. Entries past
    /// `3^D` are left as they were (a caller reuses one buffer for many nodes).
    #[inline]
    pub fn neighbourhood(&self, n: usize, out: &mut [usize; NEIGHBOURS]) {
        let slot = n / Self::TILE_NODES;
        let off = n % Self::TILE_NODES;
        let nb = &self.nbr[slot];
        // Per axis and offset: (tile step × 3^a, position bits in that tile).
        let mut step = [[(0usize, 0usize); 3]; D];
        let mut pow = 1usize;
        for (a, st) in step.iter_mut().enumerate() {
            let r = (off >> (TILE_LOG * a as u32)) & (TILE - 1);
            for d in 0..3 {
                let m = r + d + TILE - 1; // r + (d - 1), shifted by TILE to stay >= 0
                st[d] = (
                    (m >> TILE_LOG) * pow,
                    (m & (TILE - 1)) << (TILE_LOG * a as u32),
                );
            }
            pow *= 3;
        }
        // The offsets d in odometer order (axis 0 fastest), without divisions.
        let mut digit = [0usize; D];
        for o in out.iter_mut().take(pow) {
            let mut t = 0usize;
            let mut within = 0usize;
            for a in 0..D {
                let (ts, w) = step[a][digit[a]];
                t += ts;
                within |= w;
            }
            *o = nb[t & (NEIGHBOURS - 1)] + within;
            for d in digit.iter_mut() {
                *d += 1;
                if *d < 3 {
                    break;
                }
                *d = 0;
            }
        }
    }

    /// Storage indices of the `2^D` nodes `n + s d`, `d ∈ {0, 1}^D` (index
    /// `Σ_a d_a 2^a`), `s = +1` if `upper` (the corners of the cell whose lower corner
    /// is node `n`) else `−1` (the lower corners of the cells that have node `n` as a
    /// corner): the entries of [`Tiles::neighbourhood`] a pass over one cell or over
    /// one node's cells needs, at an eighth of its work in 3D. A node in a tile that is
    /// not active maps into the zero tile.
    #[inline]
    pub fn octant(&self, n: usize, upper: bool, out: &mut [usize; 8]) {
        let slot = n / Self::TILE_NODES;
        let off = n % Self::TILE_NODES;
        let nb = &self.nbr[slot];
        for (q, o) in out.iter_mut().enumerate().take(1 << D) {
            let mut t = 0usize;
            let mut within = 0usize;
            let mut pow = 1usize;
            for a in 0..D {
                let r = (off >> (TILE_LOG * a as u32)) & (TILE - 1);
                let bit = (q >> a) & 1;
                // Shifted by TILE: tile step 0 (the previous tile), 1 (this one) or 2.
                let m = if upper {
                    r + TILE + bit
                } else {
                    r + TILE - bit
                };
                t += (m >> TILE_LOG) * pow;
                within |= (m & (TILE - 1)) << (TILE_LOG * a as u32);
                pow *= 3;
            }
            *o = nb[t & (NEIGHBOURS - 1)] + within;
        }
    }
}

/// Step `t` to the next tile of the box `t0..=t1` (first axis fastest); false after
/// the last.
#[inline]
fn next_tile<const D: usize>(t: &mut [usize; D], t0: &[usize; D], t1: &[usize; D]) -> bool {
    for a in 0..D {
        t[a] += 1;
        if t[a] <= t1[a] {
            return true;
        }
        t[a] = t0[a];
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `keys_of_nodes` names the tiles `touch` touches, for every box of a particle's
    /// nodes (2 or 4 per axis) over a box with a shift, edges and clamping included.
    #[test]
    fn keys_of_nodes_are_what_touch_touches() {
        let dims = [13usize, 11, 6];
        for width in [1i64, 3] {
            for lo in 0..9i64 {
                let c = [lo - 1, 2 * lo - 3, lo - 2];
                let (l, h) = (c, c.map(|v| v + width));
                let mut by_touch = Tiles::<3>::new(dims, [2, 0, 1]);
                by_touch.begin();
                by_touch.touch(l, h);
                let mut by_keys = Tiles::<3>::new(dims, [2, 0, 1]);
                by_keys.begin();
                let mut keys = [0; 8];
                let n = by_keys.keys_of_nodes(l, h, &mut keys);
                for &k in &keys[..n] {
                    by_keys.touch_key(k);
                }
                by_touch.sort_touched();
                by_keys.sort_touched();
                assert_eq!(by_touch.touched(), by_keys.touched(), "{l:?}..={h:?}");
            }
        }
    }

    /// Every node of the touched tiles gets a distinct storage index, missing ones
    /// none, and the neighbourhood of a node (and its octants) agrees with indexing its
    /// neighbours.
    #[test]
    fn storage_is_injective_and_neighbourhoods_agree() {
        let dims = [13usize, 11, 6];
        let mut t = Tiles::<3>::new(dims, [2, 0, 1]);
        t.begin();
        t.touch([5, 3, 2], [6, 4, 3]);
        t.touch([11, 9, 4], [12, 10, 5]);
        assert!(t.finish());
        t.begin();
        t.touch([11, 9, 4], [12, 10, 5]);
        t.touch([5, 3, 2], [6, 4, 3]);
        assert!(!t.finish(), "same set in another order is no change");
        let mut seen = std::collections::BTreeSet::new();
        let mut count = 0;
        for x in 0..dims[0] {
            for y in 0..dims[1] {
                for z in 0..dims[2] {
                    if let Some(i) = t.index([x, y, z]) {
                        assert!(i >= t.tile_nodes() && i < t.nodes());
                        assert!(seen.insert(i));
                        assert_eq!(
                            t.local(i / t.tile_nodes(), i % t.tile_nodes()),
                            Some([x, y, z])
                        );
                        count += 1;
                        let mut nb = [0; NEIGHBOURS];
                        t.neighbourhood(i, &mut nb);
                        // The octants are those of the neighbourhood.
                        let mut corners = [0; 8];
                        for (upper, s) in [(true, 1i64), (false, -1)] {
                            t.octant(i, upper, &mut corners);
                            for (q, &c) in corners.iter().enumerate() {
                                let b = |a: usize| 1 + s * ((q >> a) & 1) as i64;
                                let d = (b(0) + 3 * b(1) + 9 * b(2)) as usize;
                                assert_eq!(c, nb[d], "octant {q} of node {i}, upper {upper}");
                            }
                        }
                        for d in 0..27 {
                            let o = [d % 3, (d / 3) % 3, d / 9];
                            let l: [i64; 3] =
                                std::array::from_fn(|a| [x, y, z][a] as i64 + o[a] as i64 - 1);
                            // Outside the box a neighbour is a phantom node of a
                            // partly covered tile, which no caller reads.
                            if l.iter()
                                .zip(&dims)
                                .all(|(&v, &n)| v >= 0 && (v as usize) < n)
                            {
                                match t.index(l.map(|v| v as usize)) {
                                    Some(w) => assert_eq!(nb[d], w),
                                    None => assert!(
                                        nb[d] < t.tile_nodes(),
                                        "missing maps to the zero tile"
                                    ),
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(count > 0 && count <= t.active() * t.tile_nodes());
        assert!(t.index([5, 3, 2]).is_some() && t.index([12, 10, 5]).is_some());
        assert!(t.index([0, 10, 5]).is_none());
    }

    /// Tiles over a box of `dims` nodes shifted by `shift`, with every tile that holds
    /// a node of the box (and the layer one node wide around it) active.
    fn every_tile<const D: usize>(dims: [usize; D], shift: [usize; D]) -> Tiles<D> {
        let mut t = Tiles::<D>::new(dims, shift);
        t.begin();
        t.touch([0; D].map(|v: i64| v - 1), dims.map(|n| n as i64));
        t.finish();
        t
    }

    /// `local_first` names the tiles wholly in the box, and of each the first node's
    /// local coordinates, from which `local` of every node follows.
    #[test]
    fn local_first_is_local_of_a_whole_tile() {
        fn check<const D: usize>(dims: [usize; D], shift: [usize; D]) -> usize {
            let t = every_tile(dims, shift);
            let mut inside = 0;
            for slot in 1..t.slots() {
                let whole = (0..t.tile_nodes()).all(|o| t.local(slot, o).is_some());
                let first = t.local_first(slot);
                assert_eq!(first.is_some(), whole, "slot {slot}");
                if let Some(l) = first {
                    inside += 1;
                    for o in 0..t.tile_nodes() {
                        let want: [usize; D] = std::array::from_fn(|a| {
                            l[a] + ((o >> (TILE_LOG * a as u32)) & (TILE - 1))
                        });
                        assert_eq!(t.local(slot, o), Some(want), "slot {slot}, node {o}");
                    }
                }
            }
            inside
        }
        assert!(check([13, 11, 6], [2, 0, 1]) > 0);
        assert!(check([9, 5], [3, 1]) > 0);
        assert!(check([14, 9], [0, 3]) > 0);
    }

    /// `local_row` is `local` node by node, for every row of every active tile, where
    /// tiles overhang the box's edges (partly covered rows and rows wholly outside),
    /// in 2D and 3D.
    #[test]
    fn local_row_is_local_per_node() {
        fn check<const D: usize>(dims: [usize; D], shift: [usize; D]) -> usize {
            let t = every_tile(dims, shift);
            let mut rows = 0;
            for slot in 1..t.slots() {
                for o0 in (0..t.tile_nodes()).step_by(TILE) {
                    let row = t.local_row(slot, o0);
                    for (x, got) in row.iter().enumerate() {
                        assert_eq!(*got, t.local(slot, o0 + x), "slot {slot}, node {}", o0 + x);
                    }
                    rows += 1;
                }
            }
            rows
        }
        assert!(check([13, 11, 6], [2, 0, 1]) > 0);
        assert!(check([9, 5], [3, 1]) > 0);
    }

    /// The hash table names the slot of every active tile (its rank among the active
    /// keys, plus one: slots follow increasing key) and 0 for every other key of the
    /// box, for sets from empty to every tile, where probe sequences collide and wrap.
    #[test]
    fn slot_of_key_is_the_rank_among_active_keys() {
        let dims = [41usize, 37];
        let mut rng = crate::splitmix::Rng::new(3);
        for share in [0.0, 0.01, 0.2, 0.5, 0.9, 1.0] {
            let mut t = Tiles::<2>::new(dims, [1, 2]);
            t.begin();
            for x in 0..t.tdims[0] {
                for y in 0..t.tdims[1] {
                    if rng.f64() < share {
                        t.touch_key(t.key([x, y]));
                    }
                }
            }
            t.finish();
            let all = (t.tdims[0] * t.tdims[1]) as u64;
            for k in 0..all + 3 {
                let want = t.active.binary_search(&k).map_or(0, |i| 1 + i as u32);
                assert_eq!(t.slot_of_key(k), want, "key {k}, share {share}");
            }
            assert_eq!(t.slot_of_key(u64::MAX), 0);
        }
    }

    /// Keys of a 4096³ box's node box do not overflow, and a touched tile far out is
    /// found again.
    #[test]
    fn huge_boxes_do_not_overflow() {
        let mut t = Tiles::<3>::new([4097, 4097, 4097], [0, 0, 0]);
        t.begin();
        t.touch([4090, 4095, 4094], [4091, 4096, 4095]);
        t.finish();
        assert_eq!(t.active(), 2); // straddles a tile face along y only
        assert!(t.index([4091, 4096, 4095]).is_some());
        let mut t2 = Tiles::<2>::new([65537, 65537], [0, 0]);
        t2.begin();
        t2.touch([65535, 65535], [65536, 65536]);
        t2.finish();
        assert!(t2.index([65536, 65536]).is_some());
        assert_eq!(t2.nodes(), (1 + t2.active()) * 16);
    }
}
