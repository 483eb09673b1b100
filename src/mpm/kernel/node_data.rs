//! What one run of particles (particles of one cell, sharing their nodes) reads of the grid: the nodes' records copied into node-innermost rows, the cell's shape functions, and the interpolations and velocity gradients formed from them.

use super::*;

/// The grid data a particle loop reads at the nodes of one run of particles (particles
/// sorted by cell share their nodes): copied once per run into fixed places, so that
/// the per-particle loops index a small buffer at constant offsets instead of the grid.
pub(crate) struct NodeData<const D: usize, const N: usize> {
    /// Velocity slots [`FROM_MOMENTUM`] and [`UPDATED`]: `v[slot][a][n]`, component `a`
    /// at node `n` (nodes innermost, as in every array here).
    pub v: [[[f64; N]; D]; 2],
    /// Two-step schemes: `L̄` (`lb[a][b][n]`, row `a`, column `b`) and `v̄` per node
    /// ([`AvgRecord`]).
    pub lb: [[[f64; N]; D]; D],
    pub vb: [[f64; N]; D],
    /// XPIC's field per node (`D` numbers a node), if any.
    pub x: [[f64; N]; D],
    /// Hat functions ([`hats`]): the velocity differences across the cell of the slot
    /// [`NodeData::load_differences_from`] was given, `dv[a][b][m] = v_a(upper) − v_a(lower)`
    /// over the `m`-th pair of nodes along axis `b` ([`pair`]); `m < N / 2`.
    pub dv: [[[f64; N]; D]; D],
}

/// Whether `N` nodes are the `2^D` corners of a cell (hat functions), not GIMP's `3^D`.
#[inline(always)]
pub const fn hats<const D: usize, const N: usize>() -> bool {
    N == 1 << D
}

/// The `m`-th pair of cell corners along axis `b` (`m < 2^(D−1)`, `b < 3`): the lower
/// corner (bit `b` clear; `m` with a zero bit put in at `b`) and the upper one. From a
/// table ([`PAIRS`]): the loops that ask are not unrolled, and formed with shifts by
/// `b` per call, with the index checks after, it was 2 % of the 3D step's
/// instructions.
#[inline(always)]
pub const fn pair(b: usize, m: usize) -> (usize, usize) {
    PAIRS[b & 3][m & 3]
}

/// [`pair`] per axis (the fourth row for the masks' sake) and pair.
pub(super) const PAIRS: [[(usize, usize); 4]; 4] = {
    let mut t = [[(0, 0); 4]; 4];
    let mut b = 0;
    while b < 4 {
        let mut m = 0;
        while m < 4 {
            let lower = ((m >> b) << (b + 1)) | (m & ((1 << b) - 1));
            t[b][m] = (lower, lower | 1 << b);
            m += 1;
        }
        b += 1;
    }
    t
};

/// Which pair along axis `b` corner `n` is in ([`pair`]'s `m`): `n` with bit `b` taken out.
#[inline(always)]
pub const fn pair_of(b: usize, n: usize) -> usize {
    ((n >> (b + 1)) << b) | (n & ((1 << b) - 1))
}

impl<const D: usize, const N: usize> NodeData<D, N> {
    pub fn new() -> Self {
        NodeData {
            v: [[[0.0; N]; D]; 2],
            lb: [[[0.0; N]; D]; D],
            vb: [[0.0; N]; D],
            x: [[0.0; N]; D],
            dv: [[[0.0; N]; D]; D],
        }
    }

    /// [`NodeData::load_differences_from`] taken from [`NodeData::v`] (for tests, which
    /// set `v` themselves).
    #[cfg(test)]
    pub fn load_differences(&mut self, slot: usize) {
        let v = self.v[slot];
        self.differences(|n, a| v[a][n]);
    }

    /// With hat functions, [`NodeData::dv`] of velocity slot `slot`: once per run,
    /// where each particle's velocity gradient then needs half the products
    /// ([`velocity_gradient_at`]). Read from the velocity records `vel` of nodes `idx`
    /// (as [`NodeData::load`] reads them), not from [`NodeData::v`]. Read back from `v`,
    /// the node values that `load` had just stored one by one came out as whole vectors,
    /// which cannot take their bytes from those stores in flight and wait for them to
    /// complete (a fifth of the 3D stress pass's node loading waited there).
    #[inline(always)]
    pub fn load_differences_from(&mut self, idx: &[usize; N], vel: &[f64], slot: usize) {
        self.differences(|n, a| vel[VelRecord::<D>::at(idx[n], slot) + a]);
    }

    /// `dv[a][b][m] = v(hi, a) − v(lo, a)` over the pairs ([`pair`]), with hat functions.
    #[inline(always)]
    pub(super) fn differences(&mut self, v: impl Fn(usize, usize) -> f64) {
        if !hats::<D, N>() {
            return;
        }
        for a in 0..D {
            for b in 0..D {
                for m in 0..N / 2 {
                    let (lo, hi) = pair(b, m);
                    self.dv[a][b][m] = v(hi, a) - v(lo, a);
                }
            }
        }
    }

    /// Copy the data of nodes `idx`: the velocity record from `vel`, the nodal averages
    /// from `avg` unless it is empty, XPIC's field from `xpic` if given.
    #[inline(always)]
    pub fn load(&mut self, idx: &[usize; N], vel: &[f64], avg: &[f64], xpic: Option<&[f64]>) {
        let aw = AvgRecord::<D>::WIDTH;
        for n in 0..N {
            let at = VelRecord::<D>::at(idx[n], FROM_MOMENTUM);
            let r = &vel[at..at + VelRecord::<D>::WIDTH];
            for a in 0..D {
                self.v[FROM_MOMENTUM][a][n] = r[a];
                self.v[UPDATED][a][n] = r[D + a];
            }
            if !avg.is_empty() {
                let r = &avg[idx[n] * aw..(idx[n] + 1) * aw];
                for a in 0..D {
                    for b in 0..D {
                        self.lb[a][b][n] = r[a * D + b];
                    }
                    self.vb[a][n] = r[AvgRecord::<D>::VBAR + a];
                }
            }
        }
        if let Some(x) = xpic {
            for n in 0..N {
                let r = &x[idx[n] * D..(idx[n] + 1) * D];
                for a in 0..D {
                    self.x[a][n] = r[a];
                }
            }
        }
    }
}

/// The grid coordinates of a particle's cell ([`Ctx::cell_of`]) from the storage
/// index of its lower corner node (the tile pass's `tile`), kept for the last index
/// asked: consecutive particles mostly share their cell. The hat functions' local
/// coordinate is formed from it and the position ([`Ctx::local`]). A new cell in the
/// same tile is the tile's origin plus the node's offset bits, a few integer
/// operations; only a new tile asks the tiles (out of line, [`Ctx::tile_base`]: as a
/// call per cell it was 1.4 % of the 2D block drop's step).
pub(crate) struct CellAt<const D: usize> {
    pub(super) node: u32,
    pub(super) cell: [f64; D],
    /// The tile (slot) of the last node, and the global index of its origin node.
    pub(super) slot: usize,
    pub(super) base: [i64; D],
}

impl<const D: usize> CellAt<D> {
    pub fn new() -> Self {
        // Storage index 0 is in the zero tile, slot 0, where no particle's cell lies
        // (`Solver::run_nodes` asserts it): the first particle looks its cell up.
        CellAt {
            node: 0,
            cell: [f64::NAN; D],
            slot: 0,
            base: [0; D],
        }
    }

    /// The cell whose lower corner is stored at `cell_node`.
    #[inline(always)]
    pub fn of(&mut self, ctx: &Ctx<'_, D>, cell_node: u32) -> &[f64; D] {
        if cell_node != self.node {
            let cn = cell_node as usize;
            let slot = cn / Tiles::<D>::TILE_NODES;
            if slot != self.slot {
                self.base = ctx.tile_base(slot);
                self.slot = slot;
            }
            for a in 0..D {
                let bits = (cn >> (TILE_LOG * a as u32)) & (TILE - 1);
                self.cell[a] = (self.base[a] + bits as i64) as f64;
            }
            self.node = cell_node;
            debug_assert_eq!(self.cell, ctx.cell_of(cell_node));
        }
        &self.cell
    }
}

/// The nodes of the current run of particles: particles sorted by cell (by window with
/// 3 nodes per axis) share their nodes, so a particle loop looks up their storage indices and faces (and reads or
/// flushes their grid data) only when the run changes.
pub(crate) struct Run<const D: usize, const NA: usize, const N: usize> {
    /// The node set's key: the storage index of its first node (with hat functions the
    /// cell's lower corner). Equal keys, equal nodes.
    pub(super) key: u64,
    pub idx: [usize; N],
    /// [`Ctx::node_sides`] of the run (all 0 unless [`Ctx::walls`]).
    pub sides: [[i32; NA]; D],
    /// Whether any of the run's nodes lies on a grid face: if not, no particle of the
    /// run has wall ends, and [`Run::ends`] skips the per-particle test.
    pub(super) at_wall: bool,
}

impl<const D: usize, const NA: usize, const N: usize> Run<D, NA, N> {
    pub fn new() -> Self {
        Run {
            key: u64::MAX,
            idx: [0; N],
            sides: [[0; NA]; D],
            at_wall: false,
        }
    }

    /// Whether any of the run's nodes lies on a grid face.
    /// A run whose nodes lie on the walls `sides` ([`Ctx::node_sides`]), for tests.
    #[cfg(test)]
    pub fn with_sides(sides: [[i32; NA]; D]) -> Self {
        Run {
            at_wall: sides.iter().flatten().any(|&s| s != 0),
            sides,
            ..Self::new()
        }
    }

    pub fn at_wall(&self) -> bool {
        self.at_wall
    }

    /// Whether a run has been entered (its sums may need flushing).
    pub fn started(&self) -> bool {
        self.key != u64::MAX
    }

    /// Whether a particle of cell node `cell_node` whose window starts `below` cells
    /// under its cell starts a new run: whether its first node
    /// ([`Ctx::first_node`]) is not the run's.
    #[inline(always)]
    pub fn is_new(&self, ctx: &Ctx<'_, D>, cell_node: u32, below: [usize; D]) -> bool {
        Self::key_of(ctx, cell_node, below) != self.key
    }

    #[inline(always)]
    fn key_of(ctx: &Ctx<'_, D>, cell_node: u32, below: [usize; D]) -> u64 {
        if NA == 2 {
            u64::from(cell_node)
        } else {
            ctx.first_node(cell_node, below) as u64
        }
    }

    /// Enter the run of a particle of cell node `cell_node` with `below` unless it is
    /// the current one; whether it entered (and its nodes' data must be read).
    #[inline(always)]
    pub fn enter_if_new(&mut self, ctx: &Ctx<'_, D>, cell_node: u32, below: [usize; D]) -> bool {
        let new = self.is_new(ctx, cell_node, below);
        if new {
            self.enter(ctx, cell_node, below);
        }
        new
    }

    /// Enter the run of such a particle: its nodes' indices and faces.
    #[inline(always)]
    pub fn enter(&mut self, ctx: &Ctx<'_, D>, cell_node: u32, below: [usize; D]) {
        self.idx = ctx.node_indices::<NA, N>(cell_node, below);
        self.key = if NA == 2 {
            u64::from(cell_node)
        } else {
            self.idx[0] as u64
        };
        debug_assert_eq!(self.key, Self::key_of(ctx, cell_node, below));
        self.sides = ctx.node_sides::<NA>(cell_node, below);
        self.at_wall = self.sides.iter().flatten().any(|&s| s != 0);
    }

    /// [`Ctx::wall_ends`] of a particle of this run with 1D weights `w`: none where
    /// the run's nodes are all inside the grid, as most are.
    #[inline(always)]
    pub fn ends(&self, ctx: &Ctx<'_, D>, w: &[[f64; 3]; D]) -> [[bool; 2]; D] {
        if self.at_wall {
            ctx.wall_ends::<NA>(&self.sides, w)
        } else {
            [[false; 2]; D]
        }
    }
}

/// Velocity gradient at a particle with weights `k` from velocity slot `slot` and,
/// for two-step schemes, the nodal `L̄`, read from the grid (the particle loops read
/// their nodes' data once per run, [`lanes::Weights::velocity_gradient`]).
#[cfg(test)]
pub(crate) fn velocity_gradient<const D: usize, const N: usize>(
    k: &Kern<D, N>,
    idx: &[usize; N],
    vel: &[f64],
    avg: &[f64],
    slot: usize,
    two: bool,
) -> Mat<D> {
    let mut nd = NodeData::<D, N>::new();
    nd.load(idx, vel, if two { avg } else { &[] }, None);
    nd.load_differences(slot);
    let mut room = lanes::Room::<D, N>::new();
    room.one.one(k, false, [0; D]);
    if two {
        room.one.lbar(&nd);
    }
    lanes::lane(&room.one.velocity_gradient(&nd, slot, two), 0)
}
