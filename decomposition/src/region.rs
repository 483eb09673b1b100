//! A halo region: the nodes one rank (the holder) keeps as ghosts of another (the
//! owner), described per axis instead of node by node, so that it costs a few numbers
//! whatever the length of the block faces, and cut into chunks both ranks name alike.

use crate::layout::Layout;
use crate::tiles::TILE_LOG;

/// Positions `lo..hi` along one axis of the holder's box whose nodes the owner owns;
/// `to_mine` takes them to this rank's local positions (0 where this rank is the
/// holder; on the owner's side it also undoes a periodic wrap of the holder's box).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Span {
    pub lo: usize,
    pub hi: usize,
    pub to_mine: i64,
}

/// The holder's nodes at which every axis's position lies in a span, less the holder's
/// owned box. Its nodes are ordered as the holder numbers them (axis 0 fastest), which
/// both ranks know without talking. A chunk is the region's nodes in one tile of the
/// holder's unwrapped global grid (global node / `TILE` per axis), named by a key
/// relative to the region's first tile.
#[derive(Clone, Debug)]
pub(crate) struct Region<const D: usize> {
    /// Global (unwrapped) node of the holder's local position 0, per axis.
    node_lo: [i64; D],
    /// The holder's owned positions `[lo, hi)` per axis.
    own: [(usize, usize); D],
    /// Per axis, ascending and disjoint.
    spans: [Vec<Span>; D],
    /// Per axis: the global tile of the first span position, and how many tiles the
    /// spans reach (a key is the tile offsets with these as strides).
    t0: [i64; D],
    tn: [u64; D],
}

/// Global tile of global node `g` (floor division).
fn tile(g: i64) -> i64 {
    g >> TILE_LOG
}

impl<const D: usize> Region<D> {
    /// The region of a holder's box (`node_lo`, owned range `own`) over `spans`.
    pub fn new(node_lo: [i64; D], own: [(usize, usize); D], spans: [Vec<Span>; D]) -> Self {
        let mut t0 = [0; D];
        let mut tn = [0; D];
        for a in 0..D {
            if let (Some(f), Some(l)) = (spans[a].first(), spans[a].last()) {
                t0[a] = tile(node_lo[a] + f.lo as i64);
                tn[a] = (tile(node_lo[a] + l.hi as i64 - 1) - t0[a] + 1) as u64;
            }
        }
        tn.iter().try_fold(1u64, |p, &n| p.checked_mul(n)).expect(
            "a halo region's chunks fit a 64-bit key (scenes have at most 2^40 grid nodes)",
        );
        Self {
            node_lo,
            own,
            spans,
            t0,
            tn,
        }
    }

    /// No nodes: no span along some axis, or every span position owned by the holder.
    pub fn is_empty(&self) -> bool {
        (0..D).any(|a| self.spans[a].is_empty())
            || (0..D).all(|a| {
                self.spans[a]
                    .iter()
                    .all(|s| s.lo >= self.own[a].0 && s.hi <= self.own[a].1)
            })
    }

    fn owned(&self, a: usize, l: usize) -> bool {
        l >= self.own[a].0 && l < self.own[a].1
    }

    /// Whether `key` names a chunk of the region's tiles.
    pub fn has_key(&self, key: u64) -> bool {
        key < self.tn.iter().product()
    }

    /// Append to `out` the keys of the chunks with a node whose local position on this
    /// rank lies in `lo..hi` on every axis (unsorted; a key may repeat).
    /// `scratch[a]` holds (tile offset, has a position the holder does not own).
    pub fn chunks_in(
        &self,
        lo: [usize; D],
        hi: [usize; D],
        scratch: &mut [Vec<(u64, bool)>; D],
        out: &mut Vec<u64>,
    ) {
        for a in 0..D {
            let per = &mut scratch[a];
            per.clear();
            for s in &self.spans[a] {
                let p0 = s.lo.max((lo[a] as i64 - s.to_mine).max(0) as usize);
                let p1 = s.hi.min((hi[a] as i64 - s.to_mine).max(0) as usize);
                let mut p = p0;
                while p < p1 {
                    let g = self.node_lo[a] + p as i64;
                    // One past the last position of this global tile.
                    let end = (((tile(g) + 1) << TILE_LOG) - self.node_lo[a]) as usize;
                    let q = end.min(p1);
                    let outside = p < self.own[a].0 || q > self.own[a].1;
                    per.push(((tile(g) - self.t0[a]) as u64, outside));
                    p = q;
                }
            }
            if per.is_empty() {
                return;
            }
            per.sort_unstable();
            // Merge repeats of a tile, keeping whether any of them is outside.
            let mut w = 0;
            for r in 0..per.len() {
                if w > 0 && per[w - 1].0 == per[r].0 {
                    per[w - 1].1 |= per[r].1;
                } else {
                    per[w] = per[r];
                    w += 1;
                }
            }
            per.truncate(w);
        }
        let lens: [usize; D] = std::array::from_fn(|a| scratch[a].len());
        crate::odometer::odometer(lens, |i| {
            // A node of the chunk outside the holder's owned box exists iff one axis
            // has a position outside its owned range.
            if (0..D).any(|a| scratch[a][i[a]].1) {
                out.push(self.key(std::array::from_fn(|a| scratch[a][i[a]].0)));
            }
        });
    }

    fn key(&self, t: [u64; D]) -> u64 {
        let mut k = 0;
        for a in (0..D).rev() {
            k = k * self.tn[a] + t[a];
        }
        k
    }

    /// Call `f` with the local position on this rank of every node of chunk `key`, in
    /// the holder's order.
    pub fn for_each_in_chunk(&self, key: u64, mut f: impl FnMut([usize; D])) {
        // Per axis: the chunk's positions (at most a tile's) and their local positions.
        let mut pos = [[(0usize, 0usize); 1 << TILE_LOG]; D];
        let mut lens = [0usize; D];
        let mut k = key;
        for a in 0..D {
            let t = self.t0[a] + (k % self.tn[a]) as i64;
            k /= self.tn[a];
            let first = ((t << TILE_LOG) - self.node_lo[a]).max(0) as usize;
            let end = (((t + 1) << TILE_LOG) - self.node_lo[a]).max(0) as usize;
            for s in &self.spans[a] {
                for p in s.lo.max(first)..s.hi.min(end) {
                    pos[a][lens[a]] = (p, (p as i64 + s.to_mine) as usize);
                    lens[a] += 1;
                }
            }
        }
        crate::odometer::odometer(lens, |i| {
            if !(0..D).all(|a| self.owned(a, pos[a][i[a]].0)) {
                f(std::array::from_fn(|a| pos[a][i[a]].1));
            }
        });
    }

    /// Call `f` with the local position on this rank of every node of the region, in
    /// the holder's order (the whole halo, for exchanges over the dense box).
    pub fn for_each(&self, mut f: impl FnMut([usize; D])) {
        let pos: [Vec<(usize, usize)>; D] = std::array::from_fn(|a| {
            self.spans[a]
                .iter()
                .flat_map(|s| (s.lo..s.hi).map(move |p| (p, (p as i64 + s.to_mine) as usize)))
                .collect()
        });
        crate::odometer::odometer_outside::<D>(
            std::array::from_fn(|a| pos[a].len()),
            |a, v| self.owned(a, pos[a][v].0),
            |i| f(std::array::from_fn(|a| pos[a][i[a]].1)),
        );
    }
}

/// The positions of a box along axis `a` (first global node `node_lo`, `dims` nodes)
/// whose node the block at coordinate `k` owns, as spans; `to_mine` maps a global
/// (unwrapped) node of the box to this rank's local position, by one offset within a
/// period. Found per period the box reaches, not node by node, so a box of any length
/// costs a few spans.
pub(crate) fn spans_owned_by<const D: usize>(
    layout: &Layout<D>,
    a: usize,
    (node_lo, dims): (i64, usize),
    k: usize,
    to_mine: impl Fn(i64) -> i64,
) -> Vec<Span> {
    let n = layout.nodes(a) as i64;
    let last = k + 1 == layout.procs[a];
    // The wrapped nodes the block owns: its cells' lower corners, and on a bounded
    // axis the last block also the upper boundary node.
    let own = (
        layout.split(a, k) as i64,
        if last && !layout.periodic[a] {
            n
        } else {
            layout.split(a, k + 1) as i64
        },
    );
    let end = node_lo + dims as i64;
    let periods = if layout.periodic[a] {
        node_lo.div_euclid(n)..=(end - 1).div_euclid(n)
    } else {
        0..=0
    };
    let mut spans: Vec<Span> = Vec::new();
    for m in periods {
        let (g0, g1) = ((own.0 + m * n).max(node_lo), (own.1 + m * n).min(end));
        if g0 >= g1 {
            continue;
        }
        let (lo, hi) = ((g0 - node_lo) as usize, (g1 - node_lo) as usize);
        let off = to_mine(g0) - lo as i64;
        match spans.last_mut() {
            Some(s) if s.hi == lo && s.to_mine == off => s.hi = hi,
            _ => spans.push(Span {
                lo,
                hi,
                to_mine: off,
            }),
        }
    }
    spans
}
