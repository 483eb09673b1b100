//! Block partition of a cell grid over a process grid, and each rank's local node box.
//!
//! Cells are numbered `0..cells[a]` per axis. Nodes are numbered `0..=cells[a]` on a
//! bounded axis and `0..cells[a]` on a periodic one (node `cells[a]` is node 0 again).
//! A rank owns the cells of its block and the nodes at their lower corners, plus the
//! upper boundary nodes of a bounded axis if its block touches them, so that every node
//! has exactly one owner. Its local node box adds [`GHOST`] cells on every side that has
//! a neighbour (periodic faces count, even when the neighbour is the rank itself).

use crate::Error;

/// Width of the ghost layer in cells. MPMCG needs two: its particle→node step scatters
/// one cell past the block, and its node→node stencil reads one node further.
pub const GHOST: usize = 2;

/// The global grid and how its cells are split over ranks.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout<const D: usize> {
    /// Cells of the global grid along each axis.
    pub cells: [usize; D],
    /// Whether each axis is periodic (its last cell neighbours its first).
    pub periodic: [bool; D],
    /// Number of blocks along each axis; their product is the rank count.
    pub procs: [usize; D],
    /// Per axis, where the blocks start: `procs[a] + 1` ascending cell indices from 0
    /// to `cells[a]`, block `k` owning cells `cuts[a][k]..cuts[a][k + 1]`. Equal
    /// shares unless [`Layout::with_cuts`] or [`Layout::balanced`] moved them.
    cuts: [Vec<usize>; D],
}

impl<const D: usize> Layout<D> {
    /// A layout with a fixed process grid. Each block must be at least [`GHOST`] cells
    /// wide so that a ghost layer never reaches past the neighbouring block.
    pub fn new(cells: [usize; D], periodic: [bool; D], procs: [usize; D]) -> Result<Self, Error> {
        for a in 0..D {
            // A lone block on a bounded axis has no ghost layer along it, so any width
            // will do (a 2D bar one cell thick, say).
            let needs_ghost = procs[a] > 1 || periodic[a];
            if procs[a] == 0 || (needs_ghost && cells[a] < GHOST * procs[a]) || cells[a] == 0 {
                return Err(Error::BlocksTooSmall {
                    axis: a,
                    cells: cells[a],
                    blocks: procs[a],
                    min: GHOST,
                });
            }
        }
        let cuts =
            std::array::from_fn(|a| (0..=procs[a]).map(|k| k * cells[a] / procs[a]).collect());
        Ok(Self {
            cells,
            periodic,
            procs,
            cuts,
        })
    }

    /// The same process grid with the blocks starting at `cuts` (per axis,
    /// `procs[a] + 1` ascending cell indices from 0 to `cells[a]`). Each block must be
    /// at least [`GHOST`] cells wide where it has a ghost layer along the axis, as in
    /// [`Layout::new`].
    pub fn with_cuts(&self, cuts: [Vec<usize>; D]) -> Result<Self, Error> {
        for a in 0..D {
            let c = &cuts[a];
            let min = self.min_width(a);
            let ok = c.len() == self.procs[a] + 1
                && c[0] == 0
                && c[self.procs[a]] == self.cells[a]
                && c.windows(2).all(|w| w[1] >= w[0] + min);
            if !ok {
                return Err(Error::BadCuts {
                    axis: a,
                    cuts: c.clone(),
                    cells: self.cells[a],
                    min,
                });
            }
        }
        Ok(Self {
            cuts,
            ..self.clone()
        })
    }

    /// The fewest cells a block may have along axis `a`: [`GHOST`] where blocks have
    /// a ghost layer along it (more than one block, or periodic), else one.
    fn min_width(&self, a: usize) -> usize {
        if self.procs[a] > 1 || self.periodic[a] {
            GHOST
        } else {
            1
        }
    }

    /// Where the blocks start along axis `a` (see [`Layout::with_cuts`]).
    pub fn cuts(&self, a: usize) -> &[usize] {
        &self.cuts[a]
    }

    /// The same process grid with cuts that give every block along each axis an equal
    /// share of `cost`, where `cost[a]` gives the cost of the slabs of cells along axis
    /// `a` (summed over the other axes). Blocks keep the minimum width of
    /// [`Layout::with_cuts`]. The shares are equal per axis: for a cost that is a
    /// product of per-axis profiles (a box-shaped body) every block gets an equal
    /// share; for others the cuts balance the slabs, not necessarily the blocks. A
    /// zero profile gives equal widths. Deterministic: every rank given the same
    /// costs computes the same cuts.
    pub fn balanced(&self, cost: &[Profile; D]) -> Self {
        let equal = std::array::from_fn(|a| vec![1.0; self.procs[a]]);
        self.balanced_shares(cost, &equal)
    }

    /// [`Layout::balanced`] with unequal shares: block `k` along axis `a` gets the
    /// fraction `shares[a][k] / Σ_j shares[a][j]` of `cost[a]` (as near as whole slabs
    /// of cells allow), so that blocks of faster ranks can take more. Equal shares give
    /// [`Layout::balanced`]'s cuts exactly.
    pub fn balanced_shares(&self, cost: &[Profile; D], shares: &[Vec<f64>; D]) -> Self {
        let cuts = std::array::from_fn(|a| {
            assert!(
                cost[a].start + cost[a].cost.len() <= self.cells[a],
                "a cost profile within the axis"
            );
            assert!(
                shares[a].len() == self.procs[a] && shares[a].iter().all(|s| *s > 0.0),
                "a positive share per block along the axis"
            );
            balanced_cuts(&cost[a], self.cells[a], &shares[a], self.min_width(a))
        });
        self.with_cuts(cuts)
            .expect("balanced cuts respect the minimum block width")
    }

    /// The process grid for `ranks` ranks that exchanges the fewest ghost cells per
    /// halo update: the cells of all blocks' ghost layers except those a block owns
    /// itself (the images across a periodic axis it spans alone, which are a local
    /// copy). Periodic faces count like internal ones, bounded boundaries not at all.
    /// Ties go to the smaller total ghost volume (memory and scatter work, which
    /// favours cube-like blocks), then to the grid that splits the first axis most, so
    /// every rank computes the same answer.
    pub fn choose(cells: [usize; D], periodic: [bool; D], ranks: usize) -> Result<Self, Error> {
        fn rec<const D: usize>(
            a: usize,
            left: usize,
            procs: &mut [usize; D],
            cells: &[usize; D],
            periodic: &[bool; D],
            best: &mut Option<([usize; D], (u128, u128))>,
        ) {
            if a == D - 1 {
                procs[a] = left;
                if (0..D).any(|d| (procs[d] > 1 || periodic[d]) && cells[d] < GHOST * procs[d]) {
                    return;
                }
                // Summed over a grid of blocks, a product of per-axis block extents
                // factorises into a product over axes of the extents summed along the
                // axis: cells plus GHOST per ghost side (total box), or cells plus the
                // self-image layers of a periodic axis with one block (self-owned part).
                let mut boxes = 1u128;
                let mut own = 1u128;
                let mut inner = 1u128;
                for d in 0..D {
                    let (sides, self_sides) = match (periodic[d], procs[d]) {
                        (true, 1) => (2, 2),
                        (true, p) => (2 * p, 0),
                        (false, p) => (2 * (p - 1), 0),
                    };
                    boxes *= (cells[d] + GHOST * sides) as u128;
                    own *= (cells[d] + GHOST * self_sides) as u128;
                    inner *= cells[d] as u128;
                }
                let cost = (boxes - own, boxes - inner);
                if best.as_ref().is_none_or(|(_, c)| cost < *c) {
                    *best = Some((*procs, cost));
                }
                return;
            }
            for p in (1..=left).rev() {
                if left.is_multiple_of(p) {
                    procs[a] = p;
                    rec(a + 1, left / p, procs, cells, periodic, best);
                }
            }
        }
        if ranks == 0 {
            return Err(Error::NoRanks);
        }
        let mut best = None;
        rec(0, ranks, &mut [1usize; D], &cells, &periodic, &mut best);
        match best {
            Some((p, _)) => Self::new(cells, periodic, p),
            None => Err(Error::TooManyRanks {
                ranks,
                cells: cells.to_vec(),
            }),
        }
    }

    /// The number of ranks (blocks).
    pub fn ranks(&self) -> usize {
        self.procs.iter().product()
    }

    /// Block coordinates of a rank (axis 0 fastest).
    pub fn block_coords(&self, rank: usize) -> [usize; D] {
        let mut c = [0; D];
        let mut r = rank;
        for a in 0..D {
            c[a] = r % self.procs[a];
            r /= self.procs[a];
        }
        c
    }

    /// The rank of the block at block coordinates `coords` (inverse of
    /// [`Layout::block_coords`]).
    pub fn rank_of_block(&self, coords: [usize; D]) -> usize {
        let mut r = 0;
        for a in (0..D).rev() {
            r = r * self.procs[a] + coords[a];
        }
        r
    }

    /// First cell of block `k` along axis `a` (`k = procs[a]` gives `cells[a]`).
    pub fn split(&self, a: usize, k: usize) -> usize {
        self.cuts[a][k]
    }

    /// Owned cell range `[lo, hi)` of a rank.
    pub fn block_cells(&self, rank: usize) -> ([usize; D], [usize; D]) {
        let c = self.block_coords(rank);
        let mut lo = [0; D];
        let mut hi = [0; D];
        for a in 0..D {
            lo[a] = self.split(a, c[a]);
            hi[a] = self.split(a, c[a] + 1);
        }
        (lo, hi)
    }

    /// Block index along axis `a` that owns cell `i` (0 <= i < cells[a]).
    pub(crate) fn block_along(&self, a: usize, i: usize) -> usize {
        // Inverse of `split`: the largest k with split(a, k) <= i.
        let c = &self.cuts[a];
        (c.partition_point(|&s| s <= i) - 1).min(self.procs[a] - 1)
    }

    /// Rank owning a (valid, in-range) cell.
    pub fn cell_owner(&self, cell: [usize; D]) -> usize {
        let mut c = [0; D];
        for a in 0..D {
            c[a] = self.block_along(a, cell[a]);
        }
        self.rank_of_block(c)
    }

    /// Number of distinct nodes along an axis.
    pub fn nodes(&self, a: usize) -> usize {
        if self.periodic[a] {
            self.cells[a]
        } else {
            self.cells[a] + 1
        }
    }

    /// Wrap a node index on periodic axes; `None` if it lies outside a bounded axis.
    pub fn wrap_node(&self, node: [i64; D]) -> Option<[usize; D]> {
        let mut w = [0; D];
        for a in 0..D {
            let n = self.nodes(a) as i64;
            if self.periodic[a] {
                w[a] = node[a].rem_euclid(n) as usize;
            } else if node[a] < 0 || node[a] >= n {
                return None;
            } else {
                w[a] = node[a] as usize;
            }
        }
        Some(w)
    }

    /// Owner of a wrapped node: the owner of the cell it is the lower corner of; the
    /// upper boundary node of a bounded axis goes with the last cell.
    pub fn node_owner(&self, node: [usize; D]) -> usize {
        let mut cell = node;
        for a in 0..D {
            cell[a] = cell[a].min(self.cells[a] - 1);
        }
        self.cell_owner(cell)
    }
}

/// The cost of the cell slabs along one axis: `cost[i]` is that of slab `start + i`,
/// and the slabs outside are free (the empty space around a body costs nothing to
/// describe).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Profile {
    /// The first slab with a cost.
    pub start: usize,
    /// The cost of the slabs from `start` on.
    pub cost: Vec<f64>,
}

/// Cuts of `n` cells into `shares.len()` ranges whose costs are in proportion to the
/// shares, each at least `min` cells wide (`shares.len() * min <= n`).
fn balanced_cuts(profile: &Profile, n: usize, shares: &[f64], min: usize) -> Vec<usize> {
    let blocks = shares.len();
    debug_assert!(blocks * min <= n);
    let Profile { start, cost } = profile;
    // prefix[i]: cost of cells below start + i (0 below start, the total past the end).
    let mut prefix = Vec::with_capacity(cost.len() + 1);
    prefix.push(0.0);
    for &c in cost {
        prefix.push(prefix.last().copied().unwrap_or(0.0) + c.max(0.0));
    }
    let total = prefix[cost.len()];
    let all: f64 = shares.iter().sum();
    let mut cuts: Vec<usize> = (0..=blocks).map(|k| k * n / blocks).collect();
    if total > 0.0 && total.is_finite() {
        let mut below = 0.0;
        for k in 1..blocks {
            // Equal shares sum to k and `all` exactly: the target is total · k / blocks.
            below += shares[k - 1];
            let target = total * below / all;
            // The cell boundary whose prefix is nearest the target: one inside the
            // profile, as 0 < target < total.
            let hi = prefix.partition_point(|&p| p < target).min(cost.len());
            let lo = hi.saturating_sub(1);
            cuts[k] = start
                + if target - prefix[lo] <= prefix[hi] - target {
                    lo
                } else {
                    hi
                };
        }
    }
    // The minimum width: push cuts up from the bottom, then down from the top.
    for k in 1..blocks {
        cuts[k] = cuts[k].max(cuts[k - 1] + min);
    }
    for k in (1..blocks).rev() {
        cuts[k] = cuts[k].min(cuts[k + 1] - min);
    }
    cuts
}
