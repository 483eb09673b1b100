//! MPMCG's node-to-node stencils over padded tiles: the averaged velocity gradient L̄ and the averaged internal force, with the padded-tile plumbing they share.

use super::*;

/// Nodes per axis of a tile with the layer one node wide around it ([`NodeView::par_tiles`]).
pub(super) const PAD: usize = TILE + 2;

/// Padded index offset of corner `r` of a cell from its lower corner: a table
/// ([`PAD_OFFS`]), since the stencils' loops over corners are not unrolled, and formed
/// there it was a loop with `pow` per corner (7 % of the 3D stencils' instructions).
#[inline(always)]
pub(super) fn pad_off<const D: usize>(r: usize) -> usize {
    PAD_OFFS[D][r & 7]
}

/// A node stencil's per-tile table of pairs along each axis: entry `[b][a][k]` is
/// `op(src(a, b)[k], src(a, b)[k + PAD^b])` for `k < NP − PAD^b`, and 0 for the last
/// `PAD^b` (which no cell reads), written into `t`.
#[inline(always)]
pub(super) fn pair_table<'t, const D: usize, const NP: usize>(
    t: &'t mut [[[f64; NP]; D]; D],
    src: impl Fn(usize, usize) -> &'t [f64; NP],
    op: impl Fn(f64, f64) -> f64,
) -> &'t [[[f64; NP]; D]; D] {
    for (b, tb) in t.iter_mut().enumerate() {
        let st = PAD.pow(b as u32);
        for (a, row) in tb.iter_mut().enumerate() {
            let s = src(a, b);
            for k in 0..NP - st {
                row[k] = op(s[k], s[k + st]);
            }
            row[NP - st..].fill(0.0);
        }
    }
    t
}

/// A node stencil's per-tile table of `rows` numbers per padded node: entry `[i][k]`
/// is `value(k, i)` for `i < rows` (a padded node's numbers read together, `k`
/// outer), written into `t`, whose first `rows` rows are returned.
#[inline(always)]
pub(super) fn pad_table<const R: usize, const NP: usize>(
    t: &mut [[f64; NP]; R],
    rows: usize,
    value: impl Fn(usize, usize) -> f64,
) -> &[[f64; NP]] {
    let t = &mut t[..rows];
    for k in 0..NP {
        for (i, row) in t.iter_mut().enumerate() {
            row[k] = value(k, i);
        }
    }
    t
}

/// Per lane of a row, all ones where the cell weight `w` is positive, else zero: the
/// mask [`kept`] applies.
#[inline(always)]
pub(super) fn keep_mask(w: &[f64; TILE]) -> [u64; TILE] {
    std::array::from_fn(|x| if w[x] > 0.0 { u64::MAX } else { 0 })
}

/// `x` where `mask` is all ones, `+0` where it is zero: `if keep { x } else { 0.0 }`,
/// bit for bit, as an `and` of the bits; both node stencils add a cell's terms through
/// it. Written as a select over a row, the compiler made the averaged velocity
/// gradient's sums single numbers on the stack with a branch per lane (a third of its
/// time in 3D); the `and` stays one vector operation over the row.
#[inline(always)]
pub(super) fn kept(x: f64, mask: u64) -> f64 {
    f64::from_bits(x.to_bits() & mask)
}

/// [`pad_off`] per dimension (0 to 3) and corner (bit `a` of `r`: the upper side
/// along axis `a`): `Σ_a r_a PAD^a`.
pub(super) const PAD_OFFS: [[usize; 8]; 4] = {
    let mut t = [[0; 8]; 4];
    let mut d = 0;
    while d < 4 {
        let mut r = 0;
        while r < 8 {
            let (mut a, mut pow) = (0, 1);
            while a < d {
                t[d][r] += ((r >> a) & 1) * pow;
                pow *= PAD;
                a += 1;
            }
            r += 1;
        }
        d += 1;
    }
    t
};

/// Per padded position of a tile ([`NodeView::par_tiles`]), the same for every tile:
/// the neighbouring tile (index `Σ_a t_a 3^a`, `t_a` 0 below, 1 this, 2 above) and
/// the node's offset within it.
pub(super) fn pad_map<const D: usize, const NP: usize>() -> [(usize, usize); NP] {
    debug_assert_eq!(NP, PAD.pow(D as u32));
    let mut map = [(0usize, 0usize); NP];
    for (k, m) in map.iter_mut().enumerate() {
        let (mut t, mut within, mut rest, mut pow) = (0, 0, k, 1);
        for a in 0..D {
            let pa = rest % PAD;
            rest /= PAD;
            t += (usize::from(pa > 0) + usize::from(pa > TILE)) * pow;
            within |= ((pa + TILE - 1) & (TILE - 1)) << (TILE_LOG * a as u32);
            pow *= 3;
        }
        *m = (t, within);
    }
    map
}

/// The padded positions' `(neighbour tile, offset within it)` pairs ([`NodeView::par_tiles`])
/// as runs `(tile, first offset, length)` of consecutive offsets in one tile, the same
/// for every tile: the first `count` entries of the array returned with `count`. A
/// tile's nodes are stored in order of their offsets, so each run is a range of
/// storage.
pub(super) fn prefetch_runs<const NP: usize>(
    map: &[(usize, usize); NP],
) -> ([(usize, usize, usize); NP], usize) {
    let mut sorted = *map;
    sorted.sort_unstable();
    let mut runs = [(0, 0, 0); NP];
    let mut count = 0;
    for &(t, within) in &sorted {
        match runs[..count].last_mut() {
            Some((rt, rw, len)) if *rt == t && *rw + *len == within => *len += 1,
            _ => {
                runs[count] = (t, within, 1);
                count += 1;
            }
        }
    }
    (runs, count)
}

/// The grid fields a node pass reads, borrowed from the solver so that the pass can run
/// on several threads (the solver itself holds a communicator, which is not `Sync`).
pub(super) struct NodeView<'a, const D: usize> {
    pub(super) tiles: &'a Tiles<D>,
    pub(super) geom: &'a Geom<D>,
    pub(super) own_lo: [usize; D],
    pub(super) own_hi: [usize; D],
    pub(super) node_lo: [i64; D],
    pub(super) faces: [[Face; 2]; D],
    pub(super) cell_w: &'a [f64],
    /// The cell integrals of [`GridFields::cell_k`], [`GridFields::cell_m`], [`GridFields::cell_md`].
    pub(super) cell_k: &'a [[[f64; D]; CORNERS]; CORNERS],
    pub(super) cell_m: &'a [[f64; CORNERS]; CORNERS],
    pub(super) cell_md: &'a [[f64; D]; CORNERS],
}

/// One cell's sums for a row of nodes at its corner `q` ([`NodeView::gradient_tiles`]),
/// the cell's lower corner at padded index `cell`: per component `a`,
/// `Σ_r m_qr v_a(r)` from the padded velocities `vp`, and per `(a, b)`
/// `Σ_r k_qr,b v_a(r)`, where `∫_c S_q ∂_b S_r` changes only its sign with `r_b`, so
/// the corners r and r + e_b enter as the velocity's difference along b (`dvp`).
#[inline(always)]
fn cell_sums<const D: usize, const NP: usize>(
    vp: &[[f64; NP]],
    dvp: &[[[f64; NP]; D]; D],
    (cell_m, cell_k): (&[f64; CORNERS], &[[f64; D]; CORNERS]),
    cell: usize,
) -> ([[f64; TILE]; D], [[f64; TILE]; 9]) {
    let mut mc = [[0.0; TILE]; D];
    for r in 0..(1 << D) {
        let (m, at) = (cell_m[r], cell + pad_off::<D>(r));
        for a in 0..D {
            let v = &vp[a][at..at + TILE];
            for x in 0..TILE {
                mc[a][x] += m * v[x];
            }
        }
    }
    let mut lc = [[0.0; TILE]; 9];
    for (b, dvp) in dvp.iter().enumerate() {
        for i in 0..(1 << (D - 1)) {
            let (r, r1) = kernel::pair(b, i);
            let k = cell_k[r1][b];
            let c0 = cell + pad_off::<D>(r);
            for (a, dv) in dvp.iter().enumerate() {
                let d = &dv[c0..c0 + TILE];
                for x in 0..TILE {
                    lc[a * D + b][x] += k * d[x];
                }
            }
        }
    }
    (mc, lc)
}

impl<const D: usize> NodeView<'_, D> {
    /// `f(n, c, record)` for every owned node of the active tiles, with its record of
    /// `width` numbers in `out` (storage order), in parallel over tiles. For the passes
    /// that write their own node's record only: each node's result depends only on what
    /// it reads, so it is the same on any number of threads.
    pub(super) fn par_owned(
        &self,
        out: &mut [f64],
        width: usize,
        f: impl Fn(usize, [usize; D], &mut [f64]) + Sync,
    ) {
        self.each_tile(out, width, |slot, recs| {
            self.pad_nodes(slot, recs, width, |n, c, _, rec| f(n, c, rec));
        });
    }

    /// The sharpening of a two-step scheme's nodal averages (`[method] sharpen`) on the
    /// owned nodes: the first `comps` numbers `φ` of each record of `width` in `field`
    /// become `(1 + β) φ_j − β (S φ)_j`, where `(S φ)_j = (1/V_j) Σ_i φ_i ∫ w S_j S_i dv`
    /// is the consistent mass's smoothing (`node_vol` holds `V_j`). It reads the
    /// neighbours' values from a copy in `scratch`, so the ghosts must hold theirs
    /// (their first layer), and it leaves nodes without volume, where `φ` is 0, as they
    /// are. `S` keeps constants, so fields of linear motion are unchanged.
    pub(super) fn sharpen(
        &self,
        (field, width, comps): (&mut [f64], usize, usize),
        beta: f64,
        node_vol: &[f64],
        scratch: &mut [f64],
    ) {
        let nn = node_vol.len();
        for (dst, rec) in scratch[..nn * comps]
            .chunks_exact_mut(comps)
            .zip(field.chunks_exact(width))
        {
            dst.copy_from_slice(&rec[..comps]);
        }
        let src = &scratch[..nn * comps];
        self.par_owned(field, width, |n, c, rec| {
            let v = node_vol[n];
            if v <= 0.0 {
                return;
            }
            // The cells around the node, corners in order (as in `domain_weights`),
            // then each cell's corners i with their share `w_c ∫_c S_j S_i dv`.
            let mut cells = [0; 8];
            self.tiles.octant(n, false, &mut cells);
            let mut smooth = [0.0; 9];
            for (q, &cell) in cells[..1 << D].iter().enumerate() {
                let w = self.cell_w[cell];
                if !((0..D).all(|a| c[a] >= (q >> a) & 1) && w > 0.0) {
                    continue;
                }
                let mut corners = [0; 8];
                self.tiles.octant(cell, true, &mut corners);
                for (r, &i) in corners[..1 << D].iter().enumerate() {
                    let m = w * self.cell_m[q][r];
                    for (t, x) in smooth[..comps].iter_mut().enumerate() {
                        *x += m * src[i * comps + t];
                    }
                }
            }
            for t in 0..comps {
                rec[t] = (1.0 + beta) * src[n * comps + t] - beta * (smooth[t] / v);
            }
        });
    }

    /// [`NodeView::par_owned`] over the stored nodes within `reach` nodes of the owned
    /// box (the ghost layers out to `reach`): for passes that can form a ghost's value
    /// from what the ghost holds, the same bits as its owner's, instead of copying it.
    pub(super) fn par_near(
        &self,
        out: &mut [f64],
        width: usize,
        reach: usize,
        f: impl Fn(usize, [usize; D], &mut [f64]) + Sync,
    ) {
        let tn = self.tiles.tile_nodes();
        self.each_tile(out, width, |slot, recs| {
            for (o, rec) in recs.chunks_exact_mut(width).enumerate() {
                if let Some(c) = self.tiles.local(slot, o) {
                    if self.near(c, reach) {
                        f(slot * tn + o, c, rec);
                    }
                }
            }
        });
    }

    /// Whether local node `c` is owned or a ghost within `reach` nodes of the owned box.
    #[inline(always)]
    fn near(&self, c: [usize; D], reach: usize) -> bool {
        (0..D).all(|a| c[a] + reach >= self.own_lo[a] && c[a] < self.own_hi[a] + reach)
    }

    /// `f(slot, recs)` for every active tile with its records of `width` numbers in
    /// `out`, on rayon threads (in order on one).
    pub(super) fn each_tile(
        &self,
        out: &mut [f64],
        width: usize,
        f: impl Fn(usize, &mut [f64]) + Sync,
    ) {
        let tn = self.tiles.tile_nodes();
        let len = self.tiles.slots() * tn * width;
        let tile = |(slot, recs): (usize, &mut [f64])| f(slot, recs);
        if rayon::current_num_threads() == 1 {
            out[..len]
                .chunks_mut(tn * width)
                .enumerate()
                .skip(1)
                .for_each(tile);
            return;
        }
        out[..len]
            .par_chunks_mut(tn * width)
            .enumerate()
            .skip(1)
            .with_min_len(4)
            .for_each(tile);
    }

    /// `f(slot, pad, recs)` for every active tile, in parallel over tiles, with the
    /// tile's records of `width` numbers in `recs` and in `pad[k]` the storage index
    /// of the node at padded tile coordinates `p` (`k = Σ_a p_a PAD^a`, `p_a` in
    /// `0..PAD`): the tile's nodes and the layer one node wide around them, node
    /// `p − 1` of the tile, in the zero tile where that tile is not active. A node
    /// stencil reads what it needs of its neighbours into tile-local arrays once per
    /// tile instead of looking every neighbour up for every node ([`NodeView::pad_rows`],
    /// [`NodeView::row_cells`]). Each node's result depends only on what it reads, so
    /// it is the same on any number of threads.
    ///
    /// `ahead(n, len)` is called for the storage indices `n .. n + len` of the padded
    /// nodes of the next slot's tile before `f` works on this one, to prefetch what `f`
    /// will read of them: the padded nodes lie in up to `3^D` tiles scattered over the
    /// storage, and the stencils' fills of their arrays waited on those loads (a third
    /// of the 3D averaged force's time). The padded nodes go by runs of consecutive
    /// storage indices ([`prefetch_runs`]; 87 in 3D, the tile itself one of them), not
    /// one by one: a call per padded node and array was 2.4 % of the 3D step's
    /// instructions, for the same cache lines.
    pub(super) fn par_tiles<const NP: usize>(
        &self,
        out: &mut [f64],
        width: usize,
        ahead: impl Fn(usize, usize) + Sync,
        f: impl Fn(usize, &[usize; NP], &mut [f64]) + Sync,
    ) {
        let map = pad_map::<D, NP>();
        let (runs, nruns) = prefetch_runs(&map);
        self.each_tile(out, width, |slot, recs| {
            if slot + 1 < self.tiles.slots() {
                let nbr = self.tiles.neighbours(slot + 1);
                for &(t, within, len) in &runs[..nruns] {
                    ahead(nbr[t] + within, len);
                }
            }
            let nbr = self.tiles.neighbours(slot);
            let mut pad = [0; NP];
            for (p, &(t, within)) in pad.iter_mut().zip(&map) {
                *p = nbr[t] + within;
            }
            f(slot, &pad, recs);
        });
    }

    /// The local coordinates of the first node of tile `slot` when every node of the
    /// tile is owned and has a cell below it along every axis (local coordinates at
    /// least 1), as in the body's interior; else `None`. Such a tile's nodes need no
    /// per-node test ([`NodeView::pad_rows`], [`NodeView::pad_nodes`]): those tests
    /// were about 1.5 % of the 3D step's instructions.
    #[inline]
    pub(super) fn inner_first(&self, slot: usize) -> Option<[usize; D]> {
        let first = self.tiles.local_first(slot)?;
        (0..D)
            .all(|a| first[a] >= self.own_lo[a].max(1) && first[a] + TILE <= self.own_hi[a])
            .then_some(first)
    }

    /// [`Tiles::local_row`] of the row at offset `o0` of a tile whose first node is at
    /// local coordinates `first` and which lies wholly in the box.
    #[inline(always)]
    pub(super) fn inner_row(first: [usize; D], o0: usize) -> [Option<[usize; D]>; TILE] {
        let mut c = first;
        for (a, c) in c.iter_mut().enumerate().skip(1) {
            *c += (o0 >> (TILE_LOG * a as u32)) & (TILE - 1);
        }
        std::array::from_fn(|x| {
            let mut c = c;
            c[0] += x;
            Some(c)
        })
    }

    /// `f(n, c, p, record)` for every owned node of tile `slot`, with `p` its index in
    /// the tile's padded arrays ([`NodeView::par_tiles`]).
    #[inline]
    pub(super) fn pad_nodes(
        &self,
        slot: usize,
        recs: &mut [f64],
        width: usize,
        mut f: impl FnMut(usize, [usize; D], usize, &mut [f64]),
    ) {
        let tn = self.tiles.tile_nodes();
        let inner = self.inner_first(slot);
        // A row along the first axis at a time (`Tiles::local_row`), nodes in order.
        for (row, recs) in recs.chunks_exact_mut(width * TILE).enumerate() {
            let (locs, owned) = match inner {
                Some(first) => (Self::inner_row(first, row * TILE), true),
                None => (self.tiles.local_row(slot, row * TILE), false),
            };
            for (x, rec) in recs.chunks_exact_mut(width).enumerate() {
                let o = row * TILE + x;
                if let Some(c) = locs[x] {
                    if owned || self.near(c, 0) {
                        let p = (0..D)
                            .map(|a| {
                                (((o >> (TILE_LOG * a as u32)) & (TILE - 1)) + 1)
                                    * PAD.pow(a as u32)
                            })
                            .sum();
                        f(slot * tn + o, c, p, rec);
                    }
                }
            }
        }
    }

    /// For every row of [`TILE`] nodes along the first axis of tile `slot` that holds
    /// an owned node, or a ghost within `reach` nodes of the owned box:
    /// `f(o0, p0, own, cs, low)`, with `o0` the tile offset of the row's first node,
    /// `p0` its index in the tile's padded arrays ([`NodeView::par_tiles`]; the row's
    /// node `x` is at `p0 + x`), which of the row's nodes are owned or so near, their
    /// local coordinates, and per node the axes (bit `a`) along which it has no cell
    /// below ([`NodeView::row_cells`]). The node stencils work a row at a time, one node
    /// per lane.
    #[inline]
    pub(super) fn pad_rows(
        &self,
        slot: usize,
        reach: usize,
        mut f: impl FnMut(usize, usize, &[bool; TILE], &[[usize; D]; TILE], &[usize; TILE]),
    ) {
        let inner = self.inner_first(slot);
        for row in 0..TILE.pow(D as u32 - 1) {
            let o0 = row * TILE;
            let mut own = [false; TILE];
            let mut cs = [[0usize; D]; TILE];
            // Per node, the axes along which it has no cell below (local coordinate
            // 0, or outside the box): [`NodeView::row_cells`]' test per corner.
            let mut low = [0usize; TILE];
            if let Some(first) = inner {
                // Every node owned, none at local coordinate 0.
                own = [true; TILE];
                cs = Self::inner_row(first, o0).map(|c| c.unwrap_or([0; D]));
            } else {
                let locs = self.tiles.local_row(slot, o0);
                for x in 0..TILE {
                    if let Some(c) = locs[x] {
                        own[x] = self.near(c, reach);
                        cs[x] = c;
                    }
                }
                for x in 0..TILE {
                    for a in 0..D {
                        low[x] |= usize::from(cs[x][a] == 0) << a;
                    }
                }
            }
            if own.iter().any(|&o| o) {
                let p0 = (0..D)
                    .map(|a| (((o0 >> (TILE_LOG * a as u32)) & (TILE - 1)) + 1) * PAD.pow(a as u32))
                    .sum();
                f(o0, p0, &own, &cs, &low);
            }
        }
    }

    /// The cells around a row of [`pad_rows`](NodeView::pad_rows), one corner `q` at a
    /// time (corners in order, as every node loop visits them): the
    /// padded index of the lower corner of the cell whose corner `q` is the row's
    /// first node (node `x`'s is `x` further on), and per node that cell's weight from
    /// `cw` (cell weights by padded index), 0 where there is no cell (below a bounded
    /// grid face). A stencil adds a cell's terms where its weight is positive.
    #[inline(always)]
    pub(super) fn row_cells<const NP: usize>(
        cw: &[f64; NP],
        low: &[usize; TILE],
        p0: usize,
        q: usize,
    ) -> (usize, [f64; TILE]) {
        let cell = p0 - pad_off::<D>(q);
        let mut w = [0.0; TILE];
        for x in 0..TILE {
            // The cell is there unless corner q is on the upper side along an axis
            // where the node has no cell below.
            if q & low[x] == 0 {
                w[x] = cw[cell + x];
            }
        }
        (cell, w)
    }

    /// The node → node force of [`Solver::averaged_force`] on every owned node, from
    /// `sigma` (σ̄'s upper triangle per node, [`kernel::sym_index`]) into the force
    /// slots of `scat`.
    pub(super) fn force_tiles<const NP: usize>(&self, scat: &mut [f64], sw: usize, sigma: &[f64]) {
        // σ̄ is symmetric to the bit (both entries are the same sum over the same
        // volume, `averaged_force`): its upper triangle only, a third fewer numbers to
        // transpose in 3D, and the stencil reads `σ̄_ba` where it needs `σ̄_ab`.
        self.tensor_force_tiles::<NP, 6>(
            scat,
            sw,
            sigma,
            NodeRecord::<D>::SYM,
            kernel::sym_index::<D>,
        );
    }

    /// [`force_tiles`](NodeView::force_tiles) for any D × D tensor per node, stored
    /// whole row by row (`a D + b`): the centroid correction's adjoint
    /// ([`Solver::centroid_force`]), whose tensors `w ⊗ d` are not symmetric.
    pub(super) fn full_force_tiles<const NP: usize>(
        &self,
        scat: &mut [f64],
        sw: usize,
        tensor: &[f64],
    ) {
        self.tensor_force_tiles::<NP, 9>(scat, sw, tensor, D * D, |a, b| a * D + b);
    }

    /// `f_i −= Σ_j T_j · ∫ w S_j ∇S_i dv` on every owned node into the force slots of
    /// `scat`, for a tensor field `T` stored with `width` numbers per node, entry
    /// `(a, b)` at `index(a, b)`; `R` (at least `width`) sizes its table.
    ///
    /// A row of [`TILE`] nodes along the first axis at a time, one node per lane: the
    /// row's neighbours are side by side in the padded arrays, so every product below
    /// is one vector operation over the row. Each lane does its node's operations in
    /// the node's order (`t` per cell, then `f += w_c t` over the cells in order), and a
    /// cell the one-node loop skips (no cell there, or weight 0) adds an exact zero to
    /// `f`, which never holds −0 (it starts at +0, and a sum of finite numbers is −0
    /// only if both are): the same bits as one node at a time.
    fn tensor_force_tiles<const NP: usize, const R: usize>(
        &self,
        scat: &mut [f64],
        sw: usize,
        sigma: &[f64],
        width: usize,
        index: fn(usize, usize) -> usize,
    ) {
        let cell_k = self.cell_k;
        let ahead = |n: usize, len: usize| {
            kernel::prefetch(sigma, n * width, len * width);
            kernel::prefetch(self.cell_w, n, len);
        };
        self.par_tiles::<NP>(scat, sw, ahead, |slot, pad, recs| {
            // Filled in place, component by component: a row's lanes are the
            // neighbouring entries of one component. (`array::from_fn` built these in
            // a temporary and copied it, a `memcpy` of 15 kB per tile in 3D.)
            let mut sp = [[0.0; NP]; R];
            let sp = pad_table(&mut sp, width, |k, i| sigma[pad[k] * width + i]);
            let mut cw = [[0.0; NP]; 1];
            let cw = &pad_table(&mut cw, 1, |k, _| self.cell_w[pad[k]])[0];
            // The sums of σ̄_ab over padded neighbours along b,
            // `ssp[b][a][k] = σ̄_ab(k) + σ̄_ab(k + e_b)`, once per tile: each cell's pair
            // of corners along b enters the force of each of its corners' nodes, which
            // added them each time. The same addition, so the same bits. (The last
            // PAD^b entries, which no cell reads, are 0: [`pair_table`].)
            let mut ssp = [[[0.0; NP]; D]; D];
            let ssp = pair_table(&mut ssp, |a, b| &sp[index(a, b)], |lo, hi| lo + hi);
            self.pad_rows(slot, 0, |o0, p0, own, _, low| {
                let mut f = [[0.0; TILE]; D];
                for q in 0..(1 << D) {
                    let (cell, w) = Self::row_cells(cw, low, p0, q);
                    // `∫_c S_r ∂_b S_q` does not depend on `r_b` (a hat's derivative
                    // along b is constant across the cell): the corners r and r + e_b
                    // share it, so their stresses are added first (`ssp`), half the products.
                    // One component at a time, so that its sum over the pairs is one
                    // vector the whole way (over all three at once, the compiler kept
                    // the sums as pieces and reassembled them for every pair, about
                    // fifteen shuffles each); each sum takes its terms in the same
                    // order, b then i.
                    let mut t = [[0.0; TILE]; D];
                    for (a, t) in t.iter_mut().enumerate() {
                        for (b, ssp) in ssp.iter().enumerate() {
                            for i in 0..(1 << (D - 1)) {
                                let r = kernel::pair(b, i).0;
                                let k = cell_k[r][q][b];
                                let c0 = cell + pad_off::<D>(r);
                                let s = &ssp[a][c0..c0 + TILE];
                                for x in 0..TILE {
                                    t[x] += k * s[x];
                                }
                            }
                        }
                    }
                    let keep = keep_mask(&w);
                    for a in 0..D {
                        for x in 0..TILE {
                            f[a][x] += kept(w[x] * t[a][x], keep[x]);
                        }
                    }
                }
                for x in 0..TILE {
                    if own[x] {
                        let rec = &mut recs[(o0 + x) * sw..(o0 + x + 1) * sw];
                        for a in 0..D {
                            rec[NodeRecord::<D>::force(a)] -= f[a][x];
                        }
                    }
                }
            });
        });
    }

    /// `L̄_j` and `v̄_j` of [`Solver::averaged_velocity_gradient`] on every owned node
    /// and the ghosts within `reach` nodes of them into `avg`, from velocity slot `slot`
    /// of `grid_vel`.
    pub(super) fn gradient_tiles<const NP: usize>(
        &self,
        avg: &mut [f64],
        grid_vel: &[f64],
        slot: usize,
        node_vol: &[f64],
        reach: usize,
    ) {
        let aw = AvgRecord::<D>::WIDTH;
        let (cell_k, cell_m, cell_md) = (self.cell_k, self.cell_m, self.cell_md);
        // A run's velocity records are contiguous; slot `slot`'s numbers are their
        // first or last `D` of `2 D`.
        let ahead = |n: usize, len: usize| {
            kernel::prefetch(
                grid_vel,
                VelRecord::<D>::at(n, slot),
                (len - 1) * VelRecord::<D>::WIDTH + D,
            );
            kernel::prefetch(self.cell_w, n, len);
        };
        self.par_tiles::<NP>(avg, aw, ahead, |tile, pad, recs| {
            // Filled in place, component by component (see `force_tiles`).
            let mut vp = [[0.0; NP]; D];
            let vp = pad_table(&mut vp, D, |k, a| {
                grid_vel[VelRecord::<D>::at(pad[k], slot) + a]
            });
            let mut cw = [[0.0; NP]; 1];
            let cw = &pad_table(&mut cw, 1, |k, _| self.cell_w[pad[k]])[0];
            // The velocity's differences along each axis b between padded neighbours,
            // `dvp[b][a][k] = v_a(k + e_b) − v_a(k)`, once per tile: every cell's
            // edge along b enters the gradient of each of its corners' nodes (eight
            // times in 3D), which formed the difference each time. The same
            // subtraction, so the same bits. (The last PAD^b entries, which no cell
            // reads, are 0: [`pair_table`].)
            let mut dvp = [[[0.0; NP]; D]; D];
            let dvp = pair_table(&mut dvp, |a, _| &vp[a], |lo, hi| hi - lo);
            // A row of TILE nodes at a time, one per lane, as in `force_tiles`: each
            // lane does its node's operations in its order, and a skipped cell adds an
            // exact zero to sums that never hold −0, so the same bits.
            self.pad_rows(tile, reach, |o0, p0, own, cs, low| {
                // One visit of the cells: with m_ji = w_c ∫_c S_j S_i dv,
                // Σ m_ji (v_i + L̄ (x_j − x_i)) = Σ m_ji v_i + L̄ Σ m_ji (x_j − x_i), and
                // the last sum is Σ_c w_c `cell_md` of the node's corner: it needs no
                // velocity, so v̄ needs no second visit once L̄ is known.
                let mut l = [[0.0; TILE]; 9];
                let mut mv = [[0.0; TILE]; D];
                let mut md = [[0.0; TILE]; D];
                for q in 0..(1 << D) {
                    let (cell, w) = Self::row_cells(cw, low, p0, q);
                    let (mc, lc) = cell_sums(vp, dvp, (&cell_m[q], &cell_k[q]), cell);
                    let keep = keep_mask(&w);
                    for a in 0..D {
                        for x in 0..TILE {
                            mv[a][x] += kept(w[x] * mc[a][x], keep[x]);
                            md[a][x] += kept(w[x] * cell_md[q][a], keep[x]);
                        }
                        for b in 0..D {
                            for x in 0..TILE {
                                l[a * D + b][x] += kept(w[x] * lc[a * D + b][x], keep[x]);
                            }
                        }
                    }
                }
                for x in 0..TILE {
                    if !own[x] {
                        continue;
                    }
                    let rec = &mut recs[(o0 + x) * aw..(o0 + x + 1) * aw];
                    let vol = node_vol[tile * self.tiles.tile_nodes() + o0 + x];
                    let l: [f64; 9] = std::array::from_fn(|c| l[c][x]);
                    let mv: [f64; D] = std::array::from_fn(|a| mv[a][x]);
                    let md: [f64; D] = std::array::from_fn(|a| md[a][x]);
                    self.gradient_record(rec, cs[x], vol, &l, &mv, &md);
                }
            });
        });
    }

    /// A node's [`AvgRecord`] `rec` from its cell sums (`gradient_tiles`): `L̄ = l / V`
    /// and `v̄ = (mv + L̄ md) / V` with the walls of local node `c`; zero where the
    /// node's volume `vol` is not positive.
    #[inline(always)]
    pub(super) fn gradient_record(
        &self,
        rec: &mut [f64],
        c: [usize; D],
        vol: f64,
        l: &[f64; 9],
        mv: &[f64; D],
        md: &[f64; D],
    ) {
        let dd = D * D;
        if vol <= 0.0 {
            rec.iter_mut().for_each(|x| *x = 0.0);
            return;
        }
        let mut ln = [0.0; 9];
        for k in 0..dd {
            ln[k] = l[k] / vol;
        }
        let mut vb = [0.0; 6];
        for a in 0..D {
            let mut u = mv[a];
            for b in 0..D {
                u += ln[a * D + b] * md[b];
            }
            vb[a] = u / vol;
            vb[D + a] = vb[a];
        }
        self.apply_bc(c, &mut vb[..2 * D]);
        rec[..dd].copy_from_slice(&ln[..dd]);
        rec[dd..].copy_from_slice(&vb[..D]);
    }

    /// Fixed and slip faces on both velocity slots of a node.
    #[inline]
    pub(super) fn apply_bc(&self, c: [usize; D], v: &mut [f64]) {
        for a in 0..D {
            let g = self.node_lo[a] + c[a] as i64;
            let side = self.geom.end(a, g);
            if side == 0 {
                continue;
            }
            match self.faces[a][usize::from(side > 0)] {
                Face::Fixed => v.iter_mut().for_each(|x| *x = 0.0),
                Face::Slip => {
                    v[a] = 0.0;
                    v[D + a] = 0.0;
                }
                Face::Free | Face::Periodic => {}
            }
        }
    }
}

/// L̄ and v̄ per node ([`AvgRecord`]) as [`Solver::averaged_velocity_gradient`] left
/// them in `scat` (two-step schemes, `nodes` of them; else empty): in the scatter
/// records' storage, whose values no phase reads after the grid velocities are formed
/// from them and before the next scatter (`resolve_phases` puts XPIC's scatters before
/// L̄), so the grid holds no field of its own for them (`AvgRecord::WIDTH` is at most
/// the record's width).
pub(super) fn avg_of<const D: usize>(scat: &[f64], nodes: usize) -> &[f64] {
    &scat[..nodes * AvgRecord::<D>::WIDTH]
}

#[cfg(test)]
pub(super) mod adjoint_tests {
    //! Energy consistency: `Σ_i f_int,i · v_i = −Σ_p V_p σ_p : L_p` for any grid
    //! velocity `v` and particle stresses `σ_p`, with `f_int` from the scatter and the
    //! node→node step and `L_p` from the gather's velocity gradient at the same
    //! positions. It holds for MPMCG's two steps because the force and the averaged
    //! velocity gradient use the same cell tables (transposed) and the same `V_j`
    //! (swapping the table's indices in one of them fails this test).
    use super::*;
    use crate::input::scene;
    use crate::physics::gradient::tests::Rng;
    use decomposition::{Layout, SerialComm};

    /// A 4 m × 1 m beam against the `x_lower` face, 3 × 3 particles per cell; linear
    /// elastic, a material that stores its stress, so the tests can set any stress.
    /// `gradient` names the scheme; `mpmcg-domain` is MPMCG's domain rule.
    pub(super) fn scene_text(gradient: &str, x_lower: &str) -> String {
        let (gradient, quadrature) = match gradient.strip_suffix("-domain") {
            Some(g) => (g, "quadrature = \"domain\"\n"),
            None => (gradient, ""),
        };
        format!(
            r#"
name = "adj"
dim = 2
[time]
end = 1.0
[method]
gradient = "{gradient}"
{quadrature}[grid]
lower = [0.0, -4.0]
upper = [5.0, 1.5]
cells = [20, 22]
boundary = {{ x_lower = "{x_lower}", x_upper = "slip", y_lower = "slip", y_upper = "slip" }}
[[materials]]
name = "rubber"
model = "linear_elastic"
density = 1050.0
youngs_modulus = 1.0e6
poisson_ratio = 0.3
[[bodies]]
material = "rubber"
shape = {{ box = {{ lower = [0.0, 0.0], upper = [4.0, 1.0] }} }}
particles_per_cell = 3
"#
        )
    }

    /// The beam of [`beam`] with random stresses and volumes (a material that stores
    /// its stress), and the stream that drew them.
    pub(in crate::mpm::solver) fn stressed_beam(
        gradient: &str,
        x_lower: &str,
        jitter: f64,
        seed: u64,
    ) -> (Solver<'static, 2>, Rng) {
        let mut rng = Rng(seed);
        let mut s = beam(gradient, x_lower, jitter, &mut rng);
        for p in 0..s.parts.len() {
            let (a, b, c) = (rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
            s.parts.stress[p] = Mat::<2>::new(a, c, c, b) * 1e3;
            s.parts.vol[p] *= 0.5 + rng.f64();
        }
        (s, rng)
    }

    /// (Σ f·v, −Σ V σ:L) for random stresses and volumes, positions jittered by up to
    /// `jitter` cells (partly filled cells, an irregular Ω) and a random grid velocity,
    /// with the boundary conditions applied to it if `bc`; with `passes` of the
    /// centroid correction on the force and the velocity the gradient reads, and the
    /// nodal averages sharpened by `sharpen`.
    pub(in crate::mpm::solver) fn powers(
        gradient: &str,
        x_lower: &str,
        (jitter, bc): (f64, bool),
        seed: u64,
        (passes, sharpen): (usize, f64),
    ) -> (f64, f64) {
        let (mut s, mut rng) = stressed_beam(gradient, x_lower, jitter, seed);
        s.set_centroid_passes(passes);
        s.set_sharpen(sharpen);
        s.scatter(true, true);
        if passes > 0 {
            s.centroid_offsets();
        }
        if s.scheme.two_step() {
            s.averaged_force();
        }
        if passes > 0 {
            s.centroid_force();
        }
        let mut vel = vec![0.0; s.tiles.nodes() * 4];
        let mut owned = Vec::new();
        s.for_owned(|n, c| owned.push((n, c)));
        for &(n, c) in &owned {
            let v = &mut vel[n * 4..n * 4 + 4];
            if s.grid.scat[n * s.grid.sw + NodeRecord::<2>::MASS] > s.grid.mass_floor {
                v[0] = rng.f64() - 0.5;
                v[1] = rng.f64() - 0.5;
                v[2] = v[0];
                v[3] = v[1];
                if bc {
                    s.apply_bc(c, v);
                }
            }
        }
        s.block.ghost_copy(s.comm, &mut vel, 4);
        s.grid.vel = vel;
        let mut fv = 0.0;
        for &(n, _) in &owned {
            for a in 0..2 {
                fv += s.grid.scat[n * s.grid.sw + NodeRecord::<2>::force(a)]
                    * s.grid.vel[n * 4 + 2 + a];
            }
        }
        if passes > 0 {
            s.centroid_velocity(1);
        }
        if s.scheme.two_step() {
            s.averaged_velocity_gradient(1);
        }
        let mut work = 0.0;
        for p in 0..s.parts.len() {
            let l = gradient_at(&s, p);
            work -= s.parts.vol[p] * s.parts.stress[p].component_mul(&l).sum();
        }
        (fv, work)
    }

    /// A solver on the beam of [`scene_text`] with 3 × 3 particles per cell, positions
    /// jittered by up to `jitter` cells (partly filled surface cells).
    /// Particle `p`'s velocity gradient from velocity slot 1 (with L̄ where the scheme
    /// has it), as the particle passes form it.
    pub(super) fn gradient_at(s: &Solver<'_, 2>, p: usize) -> Mat<2> {
        let ctx = ctx!(s);
        let avg = avg_of::<2>(&s.grid.scat, s.grid.node_vol.len());
        let (x, tile, two) = (&s.parts.x[p], s.place.ptile[p], s.scheme.two_step());
        match ctx.half_width(&s.parts.half, &s.parts.def_grad, p) {
            Some(half) => {
                let (k, idx) = ctx.kern::<3, 9>(x, Some(&half), tile);
                kernel::velocity_gradient(&k, &idx, &s.grid.vel, avg, 1, two)
            }
            None => {
                let (k, idx) = ctx.kern::<2, 4>(x, None, tile);
                kernel::velocity_gradient(&k, &idx, &s.grid.vel, avg, 1, two)
            }
        }
    }

    pub(in crate::mpm::solver) fn beam(
        gradient: &str,
        x_lower: &str,
        jitter: f64,
        rng: &mut Rng,
    ) -> Solver<'static, 2> {
        // Plain defaults: absent keys give MPMCG at the particle, the path tested.
        let sc = scene::parse_with(&scene_text(gradient, x_lower), "adj", scene::PLAIN_DEFAULTS)
            .unwrap();
        let layout = Layout::choose([20, 22], [false, false], 1).unwrap();
        let mut s = Solver::<2>::new(&sc, &SerialComm, layout);
        let h = s.geom.h;
        for p in 0..s.parts.len() {
            for a in 0..2 {
                let x = s.parts.x[p][a] + jitter * h[a] * (rng.f64() - 0.5);
                s.parts.x[p][a] = x.clamp(s.geom.lower[a], s.geom.upper[a]);
            }
        }
        s
    }

    /// A linear grid velocity `v = W x + c` on every node that carries mass: every
    /// scheme's particle velocity gradient is `W` to round-off, at the free surfaces
    /// too. This holds because a cell weighs 0 as soon as one of its corners carries
    /// no mass; a domain reaching one cell beyond the material (e.g. the weight
    /// `Σ_k φ_k S_k`) would read the zero velocity of massless nodes there and strain a
    /// translating body. Sharpened averages too: the smoothing `S` keeps the constant
    /// L̄ of a linear field, on the surface nodes as well.
    #[test]
    pub(super) fn linear_velocity_fields_are_differentiated_exactly() {
        let w = [[0.3, -1.1], [0.7, 0.2]];
        let c = [2.0, -3.0];
        for (g, sharpen) in [
            ("mpm", 0.0),
            ("averaged", 0.0),
            ("mpmcg", 0.0),
            ("mpmcg", 2.0),
        ] {
            for jitter in [0.0, 0.9] {
                let mut s = beam(g, "free", jitter, &mut Rng(99));
                s.set_sharpen(sharpen);
                s.scatter(false, true);
                let mut vel = vec![0.0; s.tiles.nodes() * 4];
                let mut owned = Vec::new();
                s.for_owned(|n, c| owned.push((n, c)));
                for &(n, ci) in &owned {
                    if s.grid.scat[n * s.grid.sw + NodeRecord::<2>::MASS] > s.grid.mass_floor {
                        let node = std::array::from_fn(|a| s.block.node_lo[a] + ci[a] as i64);
                        let x = s.geom.node_position(node);
                        for a in 0..2 {
                            let v = w[a][0] * x[0] + w[a][1] * x[1] + c[a];
                            vel[n * 4 + a] = v;
                            vel[n * 4 + 2 + a] = v;
                        }
                    }
                }
                s.block.ghost_copy(s.comm, &mut vel, 4);
                s.grid.vel = vel;
                if s.scheme.two_step() {
                    s.averaged_velocity_gradient(1);
                }
                let mut worst = 0.0f64;
                for p in 0..s.parts.len() {
                    let l = gradient_at(&s, p);
                    for a in 0..2 {
                        for b in 0..2 {
                            worst = worst.max((l[(a, b)] - w[a][b]).abs());
                        }
                    }
                }
                assert!(
                    worst < 1e-12,
                    "{g} sharpen {sharpen} jitter {jitter}: |L − W| = {worst:e}"
                );
            }
        }
    }

    /// Owned nodes' internal forces (scatter and, for two-step schemes, the node →
    /// node step) for the solver's current particles.
    /// (The nodes in local coordinates, ordered: which tiles are stored, hence the
    /// storage order, changes when a particle enters a new tile.)
    pub(super) fn internal_forces(s: &mut Solver<'static, 2>) -> Vec<f64> {
        s.scatter(true, true);
        if s.scheme.two_step() {
            s.averaged_force();
        }
        let mut f = std::collections::BTreeMap::new();
        s.for_owned(|n, c| {
            let r = n * s.grid.sw;
            let force = [
                s.grid.scat[r + NodeRecord::<2>::force(0)],
                s.grid.scat[r + NodeRecord::<2>::force(1)],
            ];
            f.insert([c[1], c[0]], force);
        });
        // Every owned node of the box, zero where no tile is stored.
        let mut out = Vec::new();
        for y in s.block.own_lo[1]..s.block.own_hi[1] {
            for x in s.block.own_lo[0]..s.block.own_hi[0] {
                out.extend_from_slice(f.get(&[y, x]).unwrap_or(&[0.0; 2]));
            }
        }
        out
    }

    /// A particle of the beam's bottom surface moved across the cell face below it, by
    /// 2e-9 cells: MPMCG's nodal forces change by O(1e-9), because the domain weights
    /// follow the particle continuously (with Ω switching whole cells on, the change
    /// was 2.3 times MPM's own jump at a face). MPM's jump is printed for comparison.
    #[test]
    pub(super) fn surface_crossing_changes_forces_continuously() {
        for g in ["mpmcg", "averaged", "mpm"] {
            let mut s = beam(g, "free", 0.0, &mut Rng(5));
            let mut rng = Rng(17);
            for p in 0..s.parts.len() {
                let (a, b, c) = (rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
                s.parts.stress[p] = Mat::<2>::new(a, c, c, b) * 1e3;
            }
            // The bottom-row particle nearest x = 2.
            let p = (0..s.parts.len())
                .min_by(|&a, &b| {
                    let k = |q: usize| (s.parts.x[q][1], (s.parts.x[q][0] - 2.0).abs());
                    k(a).partial_cmp(&k(b)).unwrap()
                })
                .unwrap();
            let eps = 1e-9 * s.geom.h[1];
            s.parts.x[p][1] = eps;
            let above = internal_forces(&mut s);
            s.parts.x[p][1] = -eps;
            let below = internal_forces(&mut s);
            let scale = above.iter().map(|v| v.abs()).fold(0.0, f64::max);
            let jump = above
                .iter()
                .zip(&below)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
                / scale;
            eprintln!("{g}: largest nodal force change {jump:.2e} of the largest force");
            if g != "mpm" {
                assert!(jump < 1e-7, "{g}: forces jump by {jump:e}");
            }
        }
    }

    #[test]
    pub(super) fn internal_force_is_adjoint_of_velocity_gradient() {
        for (g, sharpen) in [
            ("mpm", 0.0),
            ("averaged", 0.0),
            ("mpmcg", 0.0),
            ("mpmcg", 2.0),
        ] {
            for face in ["fixed", "slip", "free"] {
                for (jitter, bc) in [(0.0, false), (0.0, true), (0.6, false), (0.6, true)] {
                    let (a, b) = powers(g, face, (jitter, bc), 12345, (0, sharpen));
                    let rel = (a - b).abs() / a.abs().max(b.abs());
                    assert!(
                        rel < 1e-12,
                        "{g} sharpen {sharpen} {face} jitter {jitter} bc {bc}: {a} vs {b}"
                    );
                }
            }
        }
    }

    /// The spinning box of the sparse-grid tests in 3D (16³ cells, MPMCG), its
    /// particles jittered by up to 0.9 cells (partly filled surface cells) and given
    /// random deformation gradients `I + 0.2 (U − ½)`, with the stream that drew them.
    pub(in crate::mpm::solver) fn jittered_box_3d(seed: u64) -> (Solver<'static, 3>, Rng) {
        // Plain defaults: absent keys give MPMCG at the particle, the path tested.
        let sc = scene::parse_with(
            &super::super::setup::sparse_tests::text(3, 1.0, 16, "mpmcg"),
            "s3",
            1,
        )
        .unwrap();
        let layout = Layout::choose([16; 3], [false; 3], 1).unwrap();
        let mut s = Solver::<3>::new(&sc, &SerialComm, layout);
        let mut rng = Rng(seed);
        let h = s.geom.h;
        for p in 0..s.parts.len() {
            for a in 0..3 {
                s.parts.x[p][a] += 0.9 * h[a] * (rng.f64() - 0.5);
            }
            s.parts.def_grad[p] =
                Mat::<3>::from_fn(|i, k| f64::from(u8::from(i == k)) + 0.2 * (rng.f64() - 0.5));
        }
        (s, rng)
    }

    /// [`gradient_at`] in 3D: particle `p`'s velocity gradient from velocity slot 1,
    /// with L̄.
    pub(in crate::mpm::solver) fn gradient_at_3d(s: &Solver<'_, 3>, p: usize) -> Mat<3> {
        let ctx = ctx!(s);
        let (k, idx) = ctx.kern::<2, 8>(&s.parts.x[p], None, s.place.ptile[p]);
        let avg = avg_of::<3>(&s.grid.scat, s.grid.node_vol.len());
        kernel::velocity_gradient(&k, &idx, &s.grid.vel, avg, 1, true)
    }

    /// MPMCG's node stencils in 3D (`force_tiles`, `gradient_tiles`: a row of four
    /// nodes at a time) on the spinning box of the sparse-grid tests, its particles
    /// jittered by up to 0.9 cells so that surface cells are partly filled: a linear
    /// grid velocity gives every particle its gradient `W` to round-off, and the nodal
    /// forces are the adjoint of the particles' velocity gradients for random
    /// deformation gradients (neo-Hookean stress) and a random grid velocity; with
    /// the nodal averages sharpened too.
    #[test]
    pub(super) fn stencils_in_3d_are_exact_and_adjoint() {
        for sharpen in [0.0, 2.0] {
            let (mut s, mut rng) = jittered_box_3d(31);
            s.set_sharpen(sharpen);
            s.scatter(true, true);
            s.averaged_force();
            // The records as the grid update reads them: L̄ is formed in their storage.
            let records = s.grid.scat.clone();
            let mut owned = Vec::new();
            s.for_owned(|n, c| owned.push((n, c)));
            let w = [[0.3, -1.1, 0.4], [0.7, 0.2, -0.5], [-0.6, 0.9, 0.1]];
            let mut worst = 0.0f64;
            let mut sides = [0.0; 2];
            for linear in [true, false] {
                let mut vel = vec![0.0; s.tiles.nodes() * 6];
                for &(n, ci) in &owned {
                    if records[n * s.grid.sw + NodeRecord::<3>::MASS] > s.grid.mass_floor {
                        let node = std::array::from_fn(|a| s.block.node_lo[a] + ci[a] as i64);
                        let x = s.geom.node_position(node);
                        for a in 0..3 {
                            let v = if linear {
                                w[a][0] * x[0] + w[a][1] * x[1] + w[a][2] * x[2] + 0.5
                            } else {
                                rng.f64() - 0.5
                            };
                            vel[n * 6 + a] = v;
                            vel[n * 6 + 3 + a] = v;
                        }
                    }
                }
                s.block.ghost_copy(s.comm, &mut vel, 6);
                s.grid.vel = vel;
                s.averaged_velocity_gradient(1);
                let mut work = 0.0;
                for p in 0..s.parts.len() {
                    let l = gradient_at_3d(&s, p);
                    if linear {
                        for a in 0..3 {
                            for b in 0..3 {
                                worst = worst.max((l[(a, b)] - w[a][b]).abs());
                            }
                        }
                    } else {
                        let sigma = s.materials[0].stress_of_def_grad(&s.parts.def_grad[p]);
                        let vol = s.parts.volume(p, &s.kinds.vol0);
                        work -= vol * sigma.component_mul(&l).sum();
                    }
                }
                if !linear {
                    let mut fv = 0.0;
                    for &(n, _) in &owned {
                        for a in 0..3 {
                            fv += records[n * s.grid.sw + NodeRecord::<3>::force(a)]
                                * s.grid.vel[n * 6 + 3 + a];
                        }
                    }
                    sides = [fv, work];
                }
            }
            assert!(worst < 1e-12, "sharpen {sharpen}: |L − W| = {worst:e}");
            let [fv, work] = sides;
            let rel = (fv - work).abs() / fv.abs().max(work.abs());
            assert!(
                rel < 1e-12,
                "sharpen {sharpen}: Σ f·v = {fv}, −Σ V σ:L = {work}"
            );
            assert!(fv.abs() > 1e-3, "a test with work in it: {fv}");
        }
    }
}

#[cfg(test)]
mod kept_force_tests {
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, SerialComm};

    /// The error pass that keeps the vortex's body force for the next step
    /// (`errors_keeping_forces`) gives `errors`' norms to the bit after every step, and
    /// the steps that read the kept forces (a sort among them, which moves them with
    /// their particles) end with the same particles, bit for bit, as steps that formed
    /// their forces in the scatter.
    #[test]
    pub(super) fn kept_body_forces_change_no_bit() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/inputs/generalized_vortex.toml"
        ))
        .unwrap()
        .replace("cells = [64, 64]", "cells = [24, 24]");
        // Plain defaults: absent keys give MPMCG at the particle, the path tested.
        let sc = scene::parse_with(&text, "vortex", scene::PLAIN_DEFAULTS).unwrap();
        let layout = Layout::choose([24; 2], [false; 2], 1).unwrap();
        let mut kept = Solver::<2>::new(&sc, &SerialComm, layout.clone());
        let mut formed = Solver::<2>::new(&sc, &SerialComm, layout);
        for step in 0..25 {
            kept.advance().unwrap();
            formed.advance().unwrap();
            let (a, b) = (kept.errors_keeping_forces(), formed.errors());
            let bits = |e: Option<(f64, f64)>| e.map(|(u, v)| (u.to_bits(), v.to_bits()));
            assert_eq!(bits(a), bits(b), "step {step}");
            // The forces are kept, for this time, and only where asked for.
            let t = kept.t.to_bits();
            assert!(kept
                .scratch
                .memo
                .entries_mut()
                .iter()
                .all(|e| e.2.to_bits() == t));
            assert!(formed
                .scratch
                .memo
                .entries_mut()
                .iter()
                .all(|e| e.2.is_nan()));
        }
        assert!(kept.place.sorts > 0, "a sort among the steps");
        assert_eq!(kept.parts.len(), formed.parts.len());
        for p in 0..kept.parts.len() {
            for (a, b) in [
                (kept.parts.x[p], formed.parts.x[p]),
                (kept.parts.v[p], formed.parts.v[p]),
            ] {
                assert!(
                    a.iter()
                        .zip(b.iter())
                        .all(|(x, y)| x.to_bits() == y.to_bits()),
                    "particle {p}: {a:?} vs {b:?}"
                );
            }
        }
        let turned = (0..kept.parts.len())
            .map(|p| (kept.parts.x[p] - kept.parts.x0[p]).norm())
            .fold(0.0, f64::max);
        assert!(turned > 1e-4, "the ring turned ({turned:e})");
    }
}
