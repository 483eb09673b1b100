//! The per-particle loops of a step, written for speed: particle→grid scatter,
//! grid→particle gather and the stress update, monomorphised over the number of nodes
//! a particle touches (`NA` per axis, `N = NA^D` in all) and run on rayon threads.
//!
//! Determinism: the scatter visits particles slab by slab (slabs of
//! [`slab_thickness`] cells along the last axis, in two colours so that same-coloured
//! slabs never share a node) and each slab in a fixed order, so every node receives its contributions in the
//! same order whatever the thread count (summed first per run of particles that share
//! their nodes, `Run`, then added into the node records run by run). Particle-local
//! work splits the particle range by halving down to [`GRAIN`], independent of the
//! thread count as well.
//!
//! Speed: particles sorted by cell come in runs that share their nodes (16 in a row in
//! 2D at 4 × 4 per cell, 8 in 3D at 2 × 2 × 2). A loop looks the run's nodes up once,
//! copies the grid data it reads into small node-innermost arrays (`NodeData`) and
//! sums what it writes in such arrays (`ScatterSums`), so the per-particle work is
//! arithmetic on fixed places. Hat functions start from the local cell coordinate in
//! the cell the tile pass found (`Ctx::local`, a subtraction, a product and a
//! subtraction per axis), so no loop locates its particles again.

use crate::input::scene::Face;
use crate::mpm::particles::{self, split_mut, ParticleSlices};
use crate::physics::benchmark;
use crate::physics::material::{Internal, Material};
use crate::physics::shape::{self, Alpha, Geom};
use crate::physics::tensor::{det, Mat, Vector};
use decomposition::tiles::{Tiles, NEIGHBOURS, TILE, TILE_LOG};
use rayon::prelude::*;

pub(crate) mod lanes;
use lanes::{HALF, LANES, QUARTER};

/// Slab thickness in cells for the coloured scatter (see [`scatter`] for why
/// same-coloured slabs never share a node): a particle with hat functions writes the
/// node rows of its cell's two faces, so one cell will do; a GIMP particle writes one
/// row beyond them on each side, which needs three. Thin slabs are many, so that two
/// threads get equal shares of a colour (a 3D block 39 cells tall was 5 slabs of 4 per
/// colour: 3 for one thread, 2 for the other).
pub fn slab_thickness(gimp: bool) -> usize {
    if gimp {
        3
    } else {
        1
    }
}
/// Particles per task below which the particle loops stop splitting.
const GRAIN: usize = 4096;

/// What the particle loops read of the grid and the scene.
pub struct Ctx<'a, const D: usize> {
    pub geom: &'a Geom<D>,
    pub node_lo: [i64; D],
    /// Where the nodes of the local box are stored.
    pub tiles: &'a Tiles<D>,
    pub gimp: bool,
    pub alpha: Alpha,
    /// Per kind of particle ([`particles::Kinds`]): its material, the mass and the
    /// reference volume of each of its particles.
    pub materials: &'a [Material],
    pub kind_mass: &'a [f64],
    pub kind_vol0: &'a [f64],
    pub gravity: Vector<D>,
    /// The benchmark at the pass's time, if it applies a body force.
    pub body_force: Option<benchmark::At<'a, D>>,
    /// Boundary condition of the lower and upper face per axis.
    pub faces: [[Face; 2]; D],
    /// Fill [`Kern::ends`] (the passes that move particles or clip their velocities,
    /// in a scene with fixed or slip walls, set it).
    pub walls: bool,
}

/// Layout of a node's scatter record, `width(two_step)` numbers per node: the mass, the
/// momentum (D), the force (D), and for two-step schemes the averaged-stress sum
/// `Σ_p (1 − α_p) v_p σ_p S_j(x_p)` (its upper triangle, [`NodeRecord::SYM`] numbers:
/// the stress is symmetric, so the lower one is the same sum) and the cover
/// `Σ_p v_p S_j(x_p)` last. The records are summed over ranks as plain numbers (the
/// ghost sum).
pub struct NodeRecord<const D: usize>;

impl<const D: usize> NodeRecord<D> {
    pub const MASS: usize = 0;
    /// Entries of a symmetric D × D tensor's upper triangle.
    pub const SYM: usize = D * (D + 1) / 2;
    pub const fn width(two_step: bool) -> usize {
        1 + 2 * D + if two_step { Self::SYM + 1 } else { 0 }
    }
    pub const fn momentum(a: usize) -> usize {
        1 + a
    }
    pub const fn force(a: usize) -> usize {
        1 + D + a
    }
    /// Entry `(a, b)` of the averaged-stress sum, either triangle.
    pub const fn stress_sum(a: usize, b: usize) -> usize {
        1 + 2 * D + sym_index::<D>(a, b)
    }
    /// The cover, last in a record of `width`.
    pub const fn cover(width: usize) -> usize {
        width - 1
    }
}

/// Place of entry `(a, b)` (either triangle) of a symmetric D × D tensor stored as its
/// upper triangle row by row: `(0,0), (0,1), …, (0,D−1), (1,1), …`.
///
/// From a table ([`SYM_PLACES`]): the loops that ask are not unrolled, and formed per
/// call it was 1 % of the 3D step's instructions.
#[inline(always)]
pub const fn sym_index<const D: usize>(a: usize, b: usize) -> usize {
    SYM_PLACES[D & 3][a & 3][b & 3]
}

/// [`sym_index`] per dimension (0 to 3) and entry `(a, b)`, both below the dimension.
const SYM_PLACES: [[[usize; 4]; 4]; 4] = {
    let mut t = [[[0; 4]; 4]; 4];
    let mut d = 0;
    while d < 4 {
        let mut a = 0;
        while a < 4 {
            let mut b = 0;
            while b < 4 {
                let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
                // Entries of a D × D tensor only (the rest stay 0, never asked for).
                if hi < d {
                    t[d][a][b] = lo * d - lo * lo.saturating_sub(1) / 2 + (hi - lo);
                }
                b += 1;
            }
            a += 1;
        }
        d += 1;
    }
    t
};

/// Velocity slot: the grid velocity `p / m`, before this step's forces (with walls).
pub const FROM_MOMENTUM: usize = 0;
/// Velocity slot: the grid velocity after forces and walls, `p / m + dt f / m`.
pub const UPDATED: usize = 1;

/// Layout of a node's velocity record, [`VelRecord::WIDTH`] numbers per node: slot
/// [`FROM_MOMENTUM`] then slot [`UPDATED`], `D` each. FLIP needs both (the
/// increment); the stress update and the move read one.
pub struct VelRecord<const D: usize>;

impl<const D: usize> VelRecord<D> {
    pub const WIDTH: usize = 2 * D;
    /// Where velocity slot `slot` of node `node` starts.
    #[inline(always)]
    pub const fn at(node: usize, slot: usize) -> usize {
        node * 2 * D + slot * D
    }
}

/// Interpolation data of one particle over its `N` nodes.
pub struct Kern<const D: usize, const N: usize> {
    pub s: [f64; N],
    /// Shape-function gradients, `g[d][n]` along axis `d` at node `n` (nodes innermost,
    /// so that a loop over the nodes runs over adjacent numbers).
    pub g: [[f64; N]; D],
    pub alpha: f64,
    /// Local cell coordinate ξ per axis (linear shapes only: the offset of node `n`
    /// from the particle is `(ξ_a − o_a) h_a`, `o_a` its corner bit).
    pub frac: [f64; D],
    /// Per axis: the particle gives weight to a node on the lower / upper grid face.
    pub ends: [[bool; 2]; D],
}

impl<const D: usize> Ctx<'_, D> {
    /// A particle's interpolation data over its `N` nodes with its wall ends, and the
    /// nodes' storage indices: [`Ctx::weights`], [`Ctx::node_indices`] and the wall
    /// ends in one, from the position alone (the solver's tests; the particle loops
    /// use the parts with [`Run`]).
    #[cfg(test)]
    pub fn kern<const NA: usize, const N: usize>(
        &self,
        x: &Vector<D>,
        half: Option<&[f64; D]>,
        cell_node: u32,
    ) -> (Kern<D, N>, [usize; N]) {
        let xa: [f64; D] = std::array::from_fn(|a| x[a]);
        let xi = self.geom.locate(&xa).1;
        let (mut k, below, w) = self.weights::<NA, N>(x, half, &xi);
        k.ends = self.wall_ends::<NA>(&self.node_sides::<NA>(cell_node, below), &w);
        (k, self.node_indices::<NA, N>(cell_node, below))
    }

    /// A particle's weights, gradients and α, without the wall ends (`ends` left
    /// unset; the nodes' storage indices are the run's), per axis whether its first node
    /// lies one below its cell (GIMP only), and its 1D weights per axis (for
    /// [`Ctx::wall_ends`]). Hat functions take the local coordinate `xi` in the cell
    /// the tile pass found ([`Ctx::local`]), GIMP the position and half-width. Particles sorted by cell share their nodes in runs: the
    /// particle loops look the nodes up once per run ([`Run`]).
    #[inline(always)]
    pub fn weights<const NA: usize, const N: usize>(
        &self,
        x: &Vector<D>,
        half: Option<&[f64; D]>,
        xi: &[f64; D],
    ) -> (Kern<D, N>, [usize; D], [[f64; 3]; D]) {
        // Three nodes per axis is GIMP, two hat functions (`by_nodes!`): decided at
        // compile time, so a hat loop carries no GIMP code.
        debug_assert_eq!(NA == 3, self.gimp);
        let w = match half {
            Some(lp) if NA == 3 => {
                let xa: [f64; D] = std::array::from_fn(|a| x[a]);
                shape::gimp(self.geom, &xa, lp)
            }
            _ => shape::hat(self.geom, xi),
        };
        let below: [usize; D] = std::array::from_fn(|a| (w.cell[a] - w.base[a]) as usize);
        let mut k = Kern {
            s: [0.0; N],
            g: [[0.0; N]; D],
            alpha: match self.alpha {
                Alpha::ProductOfShapes => w.bubble,
                Alpha::Constant(c) => c,
            },
            frac: [0.0; D],
            ends: [[false; 2]; D],
        };
        if NA == 2 {
            for a in 0..D {
                k.frac[a] = w.w[a][1];
            }
        }
        for n in 0..N {
            let mut r = n;
            let mut o = [0usize; D];
            for a in 0..D {
                o[a] = r % NA;
                r /= NA;
            }
            let mut s = 1.0;
            for a in 0..D {
                s *= w.w[a][o[a]];
            }
            for d in 0..D {
                let mut p = w.dw[d][o[d]];
                for e in 0..D {
                    if e != d {
                        p *= w.w[e][o[e]];
                    }
                }
                k.g[d][n] = p;
            }
            k.s[n] = s;
        }
        (k, below, w.w)
    }

    /// The local coordinate ξ in `cell` (its lower corner's grid coordinates) of a
    /// particle at `x`: `(x − lower) / h − c` per axis, `Geom::locate`'s arithmetic
    /// (and the tile pass's) with the cell it found, so the same bits as its ξ. The
    /// particle loops form it where they use it: the tile pass keeps no ξ per particle
    /// (24 bytes in 3D), and the loops read the position in its place.
    #[inline(always)]
    pub fn local(&self, x: &Vector<D>, cell: &[f64; D]) -> [f64; D] {
        // A plain loop: `array::from_fn`'s closure may be left as a call.
        let mut xi = [0.0; D];
        for a in 0..D {
            xi[a] = (x[a] - self.geom.lower[a]) * self.geom.inv_h[a] - cell[a];
        }
        xi
    }

    /// The grid coordinates of the cell whose lower corner is stored at `cell_node`:
    /// the cell the tile pass found ([`Ctx::local`]; the particle loops ask
    /// [`CellAt`]).
    pub fn cell_of(&self, cell_node: u32) -> [f64; D] {
        self.cell(cell_node).map(|c| c as f64)
    }

    /// The global index of the origin node of the tile in storage slot `slot`
    /// ([`CellAt`]).
    #[cold]
    #[inline(never)]
    pub fn tile_base(&self, slot: usize) -> [i64; D] {
        let (o, shift) = (self.tiles.origin(slot), self.tiles.shift());
        std::array::from_fn(|a| self.node_lo[a] + o[a] as i64 - shift[a] as i64)
    }

    /// The global index of the cell (its lower corner node) whose lower corner is
    /// stored at `cell_node`.
    #[inline(always)]
    fn cell(&self, cell_node: u32) -> [i64; D] {
        let tn = Tiles::<D>::TILE_NODES;
        let cn = cell_node as usize;
        let l = self
            .tiles
            .local(cn / tn, cn % tn)
            .expect("a particle's cell corner lies in the local box");
        std::array::from_fn(|a| self.node_lo[a] + l[a] as i64)
    }

    /// Per axis and node of a run ([`Ctx::node_indices`]'s arguments), whether the
    /// node lies on the lower (-1) or upper (+1) grid face or neither (0). Only loops
    /// that need wall ends ([`Ctx::walls`]) ask.
    #[inline(always)]
    pub fn node_sides<const NA: usize>(&self, cell_node: u32, below: [usize; D]) -> [[i32; NA]; D] {
        let mut sides = [[0; NA]; D];
        if !self.walls {
            return sides;
        }
        let c = self.cell(cell_node);
        for a in 0..D {
            let first = c[a] - below[a] as i64;
            for (o, side) in sides[a].iter_mut().enumerate() {
                *side = self.geom.end(a, first + o as i64);
            }
        }
        sides
    }

    /// Storage indices of the `N` nodes of a particle whose cell's lower corner is
    /// stored at `cell_node` and whose first node lies `below[a]` (0 or 1) below its
    /// cell along each axis.
    #[inline(always)]
    pub fn node_indices<const NA: usize, const N: usize>(
        &self,
        cell_node: u32,
        below: [usize; D],
    ) -> [usize; N] {
        // The particle's nodes lie within one tile of its cell's tile: per axis and
        // node, the step to the node's tile (×3^a, the neighbour table's numbering)
        // and the node's offset bits in that tile. `cell_node` is the storage index of
        // the cell's lower corner, which names the tile (its slot) and the corner's
        // place in it, so the common case, all nodes in that tile, needs no table.
        let cell_node = cell_node as usize;
        let tn = Tiles::<D>::TILE_NODES;
        let mut step = [[0usize; NA]; D];
        let mut bits = [[0usize; NA]; D];
        let mut pow = 1;
        let mut one_tile = true;
        let mut first = cell_node;
        for a in 0..D {
            let r = (cell_node >> (TILE_LOG * a as u32)) & (TILE - 1);
            // The first node's place relative to the tile, plus TILE (so >= 0).
            let rel = r + TILE - below[a];
            one_tile &= rel >= TILE && rel + NA <= 2 * TILE;
            first = first.wrapping_sub(below[a] << (TILE_LOG * a as u32));
            for o in 0..NA {
                let m = rel + o;
                step[a][o] = (m >> TILE_LOG) * pow;
                bits[a][o] = (m & (TILE - 1)) << (TILE_LOG * a as u32);
            }
            pow *= 3;
        }
        let nb = if one_tile {
            None
        } else {
            Some(self.tiles.neighbours(cell_node / tn))
        };
        let mut idx = [0; N];
        for (n, i) in idx.iter_mut().enumerate() {
            let mut r = n;
            let mut t = 0;
            let mut off = 0;
            let mut within = 0;
            for a in 0..D {
                let o = r % NA;
                r /= NA;
                t += step[a][o];
                off |= bits[a][o];
                within += o << (TILE_LOG * a as u32);
            }
            // `t < 27` when the slot is the particle's cell's tile; the mask only
            // spares the bounds check (a wrong slot gives a wrong node, caught by the
            // scatter's bounds assertion or visible in the result, never memory unsafety).
            *i = match nb {
                None => first.wrapping_add(within),
                Some(nb) => nb[t & (NEIGHBOURS - 1)] + off,
            };
        }
        idx
    }

    /// Per axis, whether the particle gives weight to a node on the lower / upper grid
    /// face ([`Kern::ends`]), from its nodes' `sides` ([`Ctx::node_sides`]) and its 1D
    /// weights `w`. Only the passes that move particles or clip their velocities at
    /// walls read it: the others skip this per-particle work.
    #[inline(always)]
    pub fn wall_ends<const NA: usize>(
        &self,
        sides: &[[i32; NA]; D],
        w: &[[f64; 3]; D],
    ) -> [[bool; 2]; D] {
        let mut ends = [[false; 2]; D];
        if self.walls {
            for a in 0..D {
                for o in 0..NA {
                    let side = sides[a][o];
                    if side != 0 && w[a][o] > 0.0 {
                        ends[a][usize::from(side > 0)] = true;
                    }
                }
            }
        }
        ends
    }

    /// External force per unit mass on a particle with reference position `x0`.
    #[inline(always)]
    pub fn accel(&self, x0: &[Vector<D>], p: usize) -> Vector<D> {
        match self.body_force {
            Some(b) => self.gravity + b.body_force_of(x0, p),
            None => self.gravity,
        }
    }

    /// [`Ctx::accel`] as the step's scatter kept it in `kept` (where the scene has a
    /// body force: see [`scatter`]), else formed.
    #[inline(always)]
    pub fn accel_kept(&self, kept: &[Vector<D>], x0: &[Vector<D>], p: usize) -> Vector<D> {
        match kept.get(p) {
            Some(&a) => a,
            None => self.accel(x0, p),
        }
    }
}

/// The particle arrays over a contiguous range, splittable for threads, with the
/// solver's per-particle arrays the loops need besides.
pub struct Slices<'a, const D: usize> {
    pub parts: ParticleSlices<'a, D>,
    /// Position increment of the step (two-step schemes move particles after the
    /// stress pass).
    pub dx: &'a mut [Vector<D>],
    /// Storage index of each particle's cell's lower corner node.
    pub tile: &'a [u32],
    /// The external force per unit mass the step's scatter kept, or empty
    /// ([`Ctx::accel_kept`]).
    pub accel: &'a [Vector<D>],
}

fn split<T>(s: &[T], mid: usize) -> (&[T], &[T]) {
    if s.is_empty() {
        (&[], &[])
    } else {
        s.split_at(mid)
    }
}

impl<'a, const D: usize> Slices<'a, D> {
    pub fn len(&self) -> usize {
        self.parts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }

    fn split_at(self, mid: usize) -> (Self, Self) {
        let (p0, p1) = self.parts.split_at(mid);
        let (d0, d1) = split_mut(self.dx, mid);
        let (k0, k1) = split(self.tile, mid);
        let (a0, a1) = split(self.accel, mid);
        (
            Slices {
                parts: p0,
                dx: d0,
                tile: k0,
                accel: a0,
            },
            Slices {
                parts: p1,
                dx: d1,
                tile: k1,
                accel: a1,
            },
        )
    }
}

/// Result of a particle loop: all states physical, external work done, fastest signal.
#[derive(Clone, Copy, Debug)]
pub struct Tally {
    pub ok: bool,
    pub work: f64,
    pub max_speed: f64,
}

impl Tally {
    const ZERO: Tally = Tally {
        ok: true,
        work: 0.0,
        max_speed: 0.0,
    };
    fn join(a: Tally, b: Tally) -> Tally {
        Tally {
            ok: a.ok && b.ok,
            work: a.work + b.work,
            max_speed: a.max_speed.max(b.max_speed),
        }
    }
}

/// Split the particles by halving down to GRAIN and run `f` on the pieces in parallel.
fn par<const D: usize>(s: Slices<'_, D>, f: &(impl Fn(Slices<'_, D>) -> Tally + Sync)) -> Tally {
    if s.len() <= GRAIN {
        return f(s);
    }
    let mid = s.len() / 2;
    let (a, b) = s.split_at(mid);
    let (ta, tb) = rayon::join(|| par(a, f), || par(b, f));
    Tally::join(ta, tb)
}

/// What a gather does besides interpolating velocities.
#[derive(Clone, Copy, Debug)]
pub struct GatherMode {
    pub dt: f64,
    pub flip: f64,
    /// Also update deformation and stress from velocity slot 1.
    pub stress: bool,
    /// Move particles now; otherwise store the increments in `dx` (MUSL).
    pub move_now: bool,
    /// The scheme uses grid-averaged gradients (`avg` holds L̄).
    pub two_step: bool,
    /// `avg` holds L̄ and v̄ of slot 1: move with [`moving_velocity`] (two-step
    /// schemes under USL and USF; under MUSL the stress pass sets the move).
    pub recon: bool,
    /// Report the fastest signal speed (only the step's last particle pass needs to:
    /// a wave speed costs a logarithm and a square root per particle).
    pub speed: bool,
}

/// What a stress update reads and reports.
#[derive(Clone, Copy, Debug)]
pub struct StressMode {
    /// Velocity slot of the grid record to differentiate.
    pub slot: usize,
    pub dt: f64,
    pub two_step: bool,
    /// Move the particles with [`moving_velocity`] (two-step schemes under MUSL, whose
    /// gather ran before the remap).
    pub moves: bool,
    /// Move the particles by the increments `dx` kept (one-step schemes under MUSL).
    pub moves_kept: bool,
    /// Report the fastest signal speed (see [`GatherMode::speed`]).
    pub speed: bool,
}

/// Layout of the nodal averages of the two-step schemes, `WIDTH` numbers per node: in
/// the force step σ̄_j (D × D, row-major); in the gradient step L̄_j (D × D) and then the
/// smoothed velocity v̄_j (D) at `VBAR`, so that one halo copy carries both.
pub struct AvgRecord<const D: usize>;

impl<const D: usize> AvgRecord<D> {
    pub const WIDTH: usize = D * D + D;
    pub const VBAR: usize = D * D;
}

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
const PAIRS: [[(usize, usize); 4]; 4] = {
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
    fn differences(&mut self, v: impl Fn(usize, usize) -> f64) {
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
        if D > 1 && N.is_multiple_of(4) {
            // Four nodes at a time, four numbers of their records at a time
            // ([`rows4`]: vector shuffles, not a store per number).
            let vw = VelRecord::<D>::WIDTH;
            for n0 in (0..N).step_by(4) {
                let at: [usize; 4] = std::array::from_fn(|l| idx[n0 + l] * vw);
                for c0 in blocks_of_four(vw) {
                    let r = rows4(vel, at.map(|i| i + c0));
                    for (k, r) in r.iter().enumerate() {
                        let c = c0 + k;
                        self.v[c / D][c % D][n0..n0 + 4].copy_from_slice(r);
                    }
                }
                if !avg.is_empty() {
                    let at: [usize; 4] = std::array::from_fn(|l| idx[n0 + l] * aw);
                    for c0 in blocks_of_four(aw) {
                        let r = rows4(avg, at.map(|i| i + c0));
                        for (k, r) in r.iter().enumerate() {
                            let c = c0 + k;
                            let row = if c < AvgRecord::<D>::VBAR {
                                &mut self.lb[c / D][c % D]
                            } else {
                                &mut self.vb[c - AvgRecord::<D>::VBAR]
                            };
                            row[n0..n0 + 4].copy_from_slice(r);
                        }
                    }
                }
            }
        } else {
            self.load_by_nodes(idx, vel, avg);
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

    /// [`NodeData::load`]'s velocities and averages a node at a time (1D, GIMP).
    #[inline(always)]
    fn load_by_nodes(&mut self, idx: &[usize; N], vel: &[f64], avg: &[f64]) {
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
    }
}

/// Where the blocks of four numbers start that cover a record of `width >= 4`
/// numbers: every fourth, the last moved back to end at the record's end (so it may
/// overlap the one before, which then writes a few numbers twice, the same values).
#[inline(always)]
fn blocks_of_four(width: usize) -> impl Iterator<Item = usize> {
    (0..width.div_ceil(4)).map(move |j| (4 * j).min(width - 4))
}

/// Four numbers from each of four records, as rows over the records:
/// `out[k][l] = src[at[l] + k]`: with AVX eight 16-byte loads, four in-lane shuffles
/// and four whole-row stores at the caller, where copying a number at a time was a
/// load and a store each (the 3D stress pass's node loading: 6.6 % of the block
/// drop's step that way, 5.0 % this way; the same numbers, moved).
#[inline(always)]
fn rows4(src: &[f64], at: [usize; 4]) -> [[f64; 4]; 4] {
    let r: [&[f64; 4]; 4] =
        std::array::from_fn(|l| src[at[l]..at[l] + 4].try_into().expect("four numbers"));
    #[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
    {
        use std::arch::x86_64::*;
        // Halves of the records, two into each register ([r0 lo | r2 lo], ...), then
        // within each 128-bit lane pick the first or the second number of each pair:
        // no shuffle crosses lanes. (Left to the compiler, the whole-array form below
        // came out as scalar loads and inserts, slower than the scalar copy.)
        // SAFETY: AVX is enabled for the whole build (the cfg above), and the binary
        // refuses to start on a CPU without the features it was built for
        // (`driver::cpu`). Each `r[l]` references four f64, so the 16-byte loads at
        // offsets 0 and 2 read inside it (unaligned loads need no alignment); and
        // `__m256d` is four f64 in order, every bit pattern valid both ways.
        unsafe {
            let half = |l: usize, k: usize| _mm_loadu_pd(r[l].as_ptr().add(k));
            let pair = |a: usize, b: usize, k: usize| {
                _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(half(a, k)), half(b, k))
            };
            let (e0, e1) = (pair(0, 2, 0), pair(1, 3, 0));
            let (f0, f1) = (pair(0, 2, 2), pair(1, 3, 2));
            [
                _mm256_unpacklo_pd(e0, e1),
                _mm256_unpackhi_pd(e0, e1),
                _mm256_unpacklo_pd(f0, f1),
                _mm256_unpackhi_pd(f0, f1),
            ]
            .map(|v| std::mem::transmute::<__m256d, [f64; 4]>(v))
        }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx")))]
    std::array::from_fn(|k| [r[0][k], r[1][k], r[2][k], r[3][k]])
}

/// The grid coordinates of a particle's cell ([`Ctx::cell_of`]) from the storage
/// index of its lower corner node (the tile pass's `tile`), kept for the last index
/// asked: consecutive particles mostly share their cell. The hat functions' local
/// coordinate is formed from it and the position ([`Ctx::local`]). A new cell in the
/// same tile is the tile's origin plus the node's offset bits, a few integer
/// operations; only a new tile asks the tiles (out of line, [`Ctx::tile_base`]: as a
/// call per cell it was 1.4 % of the 2D block drop's step).
pub(crate) struct CellAt<const D: usize> {
    node: u32,
    cell: [f64; D],
    /// The tile (slot) of the last node, and the global index of its origin node.
    slot: usize,
    base: [i64; D],
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

/// The nodes of the current run of particles: particles sorted by cell share their
/// nodes, so a particle loop looks up their storage indices and faces (and reads or
/// flushes their grid data) only when the run changes.
pub(crate) struct Run<const D: usize, const NA: usize, const N: usize> {
    /// The node set's key: the cell's lower corner in the storage and, per axis,
    /// whether the first node lies below the cell (GIMP). Equal keys, equal nodes.
    key: u64,
    pub idx: [usize; N],
    /// [`Ctx::node_sides`] of the run (all 0 unless [`Ctx::walls`]).
    pub sides: [[i32; NA]; D],
    /// Whether any of the run's nodes lies on a grid face: if not, no particle of the
    /// run has wall ends, and [`Run::ends`] skips the per-particle test.
    at_wall: bool,
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
    pub fn at_wall(&self) -> bool {
        self.at_wall
    }

    /// Whether a run has been entered (its sums may need flushing).
    pub fn started(&self) -> bool {
        self.key != u64::MAX
    }

    #[inline(always)]
    fn key_of(cell_node: u32, below: [usize; D]) -> u64 {
        let mut m = 0u64;
        for (a, &b) in below.iter().enumerate() {
            m |= (b as u64) << a;
        }
        cell_node as u64 | (m << 32)
    }

    /// Whether a particle of cell node `cell_node` with `below` starts a new run.
    #[inline(always)]
    pub fn is_new(&self, cell_node: u32, below: [usize; D]) -> bool {
        Self::key_of(cell_node, below) != self.key
    }

    /// Enter the run of a particle of cell node `cell_node` with `below` unless it is
    /// the current one; whether it entered (and its nodes' data must be read).
    #[inline(always)]
    pub fn enter_if_new(&mut self, ctx: &Ctx<'_, D>, cell_node: u32, below: [usize; D]) -> bool {
        let new = self.is_new(cell_node, below);
        if new {
            self.enter(ctx, cell_node, below);
        }
        new
    }

    /// Enter the run of such a particle: its nodes' indices and faces.
    #[inline(always)]
    pub fn enter(&mut self, ctx: &Ctx<'_, D>, cell_node: u32, below: [usize; D]) {
        self.key = Self::key_of(cell_node, below);
        self.idx = ctx.node_indices::<NA, N>(cell_node, below);
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

/// The nodal `L̄` of a two-step scheme interpolated at a particle, shared by its
/// velocity gradient and the velocity it moves with: `all = Σ_n S_n L̄_n`, and per
/// column `b` the part of that sum from the nodes on the upper side of the cell along
/// axis `b`, `upper[a][b] = Σ_{n: o_b(n) = 1} S_n L̄_n[a][b]`. Zero for one-step schemes.
pub(crate) struct LbarAt<const D: usize> {
    pub all: [[f64; D]; D],
    pub upper: [[f64; D]; D],
}

/// [`LbarAt`] of a particle with weights `k` over its nodes' data `nd`.
#[inline(always)]
pub(crate) fn lbar_at<const D: usize, const N: usize>(
    k: &Kern<D, N>,
    nd: &NodeData<D, N>,
    two: bool,
) -> LbarAt<D> {
    let mut lb = LbarAt {
        all: [[0.0; D]; D],
        upper: [[0.0; D]; D],
    };
    if two {
        for a in 0..D {
            for b in 0..D {
                // The lower and the upper side's sums, two independent chains.
                let (mut lower, mut upper) = (0.0, 0.0);
                for n in 0..N {
                    let t = k.s[n] * nd.lb[a][b][n];
                    if (n >> b) & 1 == 1 {
                        upper += t;
                    } else {
                        lower += t;
                    }
                }
                lb.all[a][b] = lower + upper;
                lb.upper[a][b] = upper;
            }
        }
    }
    lb
}

/// The velocity two-step schemes move a particle with: the nodal linear
/// reconstructions `v̄_j + L̄_j (x − x_j)` blended by the shape functions,
/// `u(x) = Σ_j S_j(x) (v̄_j + L̄_j (x − x_j))`. Exact for linear velocity fields, like
/// the grid interpolation `Σ_i S_i v_i`, but built from the same nodal averages as the
/// particle's velocity gradient, so the particles separate only as fast as their
/// deformation gradients register (README, "The schemes"). Next to a wall the
/// reconstruction of an interior node, carried to the wall by `L̄_j`, need not vanish
/// on it, while the grid velocity of slot `slot` does (the wall's nodes are held): the
/// velocity blends from `u` to the grid interpolation `Σ_i S_i v_i` with the particle's
/// shape weight on the wall's nodes, all components at a fixed wall, the normal one at
/// a slip wall. Still continuous and exact for linear fields that satisfy the walls; on
/// the wall it is the grid's. (Unblended, particles squeezed into a cantilever's clamp
/// corner left the grid through the clamp, and the clamped beam slid off the clamp.)
/// `nd` holds the particle's nodes' data ([`NodeData`]).
#[inline(always)]
pub(crate) fn moving_velocity<const D: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    k: &Kern<D, N>,
    nd: &NodeData<D, N>,
    lb: &LbarAt<D>,
    slot: usize,
) -> Vector<D> {
    // Node n's offset from the particle is (ξ − o_n) h, so
    // Σ_n S_n L̄_n (ξ − o_n) h = (Σ_n S_n L̄_n) ξ h − Σ_{n: o_b(n) = 1} S_n L̄_n h_b:
    // the interpolated L̄ the velocity gradient needs anyway, and half its terms again.
    let h = &ctx.geom.h;
    let mut u = Vector::<D>::zeros();
    for a in 0..D {
        let mut x = 0.0;
        for n in 0..N {
            x += k.s[n] * nd.vb[a][n];
        }
        for b in 0..D {
            x += (lb.all[a][b] * k.frac[b] - lb.upper[a][b]) * h[b];
        }
        u[a] = x;
    }
    if ctx.walls && k.ends.iter().flatten().any(|&e| e) {
        // The share of the particle's shape weight on wall nodes: on fixed faces (all
        // components) and on slip faces normal to each axis (that component).
        let mut keep_fixed = 1.0;
        let mut keep = [1.0; D];
        for a in 0..D {
            for side in 0..2 {
                if !k.ends[a][side] {
                    continue;
                }
                let on_face = if side == 0 {
                    1.0 - k.frac[a]
                } else {
                    k.frac[a]
                };
                match ctx.faces[a][side] {
                    Face::Fixed => keep_fixed *= 1.0 - on_face,
                    Face::Slip => keep[a] *= 1.0 - on_face,
                    Face::Free | Face::Periodic => {}
                }
            }
        }
        if keep_fixed < 1.0 || keep.iter().any(|&k| k < 1.0) {
            for a in 0..D {
                let c = keep_fixed * keep[a];
                if c < 1.0 {
                    let mut vn = 0.0;
                    for n in 0..N {
                        vn += k.s[n] * nd.v[slot][a][n];
                    }
                    u[a] = c * u[a] + (1.0 - c) * vn;
                }
            }
        }
    }
    u
}

/// A particle that touches a slip wall's node may move into that wall no faster than
/// the velocity it moves with, `vm` (which vanishes at the wall): the normal component
/// of its velocity `v` is clipped to `vm`'s. Returns the kinetic energy the clip takes
/// out (≤ 0), the wall's work.
#[inline(always)]
pub(crate) fn clip_at_slip_walls<const D: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    k: &Kern<D, N>,
    v: &mut Vector<D>,
    vm: &Vector<D>,
    mass: f64,
) -> f64 {
    let free = *v;
    for a in 0..D {
        for side in 0..2 {
            if k.ends[a][side] && ctx.faces[a][side] == Face::Slip {
                v[a] = if side == 0 {
                    v[a].max(vm[a])
                } else {
                    v[a].min(vm[a])
                };
            }
        }
    }
    // The wall is an external force: its impulse m (new − free) does the work
    // m (new − free)·(new + free)/2 by the midpoint rule gravity's work uses, i.e. the
    // kinetic energy the clip takes out. A wall at rest does no work on the continuum;
    // this is what the discrete impact dissipates there, counted so that the balance
    // keeps measuring the integrator.
    0.5 * mass * (v.norm_squared() - free.norm_squared())
}

/// Velocity gradient at a particle from velocity slot `slot` and, for two-step
/// schemes, the nodal `L̄`, read from the grid (the particle loops read their nodes'
/// data once per run and call [`velocity_gradient_at`]).
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
    velocity_gradient_at(k, &nd, &lbar_at(k, &nd, two), slot, two)
}

/// Velocity gradient at a particle from velocity slot `slot` and, for two-step
/// schemes, the nodal `L̄`, of its nodes' data `nd`.
#[inline(always)]
pub(crate) fn velocity_gradient_at<const D: usize, const N: usize>(
    k: &Kern<D, N>,
    nd: &NodeData<D, N>,
    lb: &LbarAt<D>,
    slot: usize,
    two: bool,
) -> Mat<D> {
    let mut l = Mat::<D>::zeros();
    if k.alpha != 0.0 {
        for a in 0..D {
            for b in 0..D {
                let mut x = 0.0;
                if hats::<D, N>() {
                    // A hat's derivative along b at the lower node of a pair is minus
                    // the upper one's (exactly: the same product with −1/h for 1/h),
                    // so the pair enters as its velocity difference (`nd.dv`, of
                    // `slot`).
                    for m in 0..N / 2 {
                        x += nd.dv[a][b][m] * k.g[b][pair(b, m).1];
                    }
                } else {
                    for n in 0..N {
                        x += nd.v[slot][a][n] * k.g[b][n];
                    }
                }
                l[(a, b)] = k.alpha * x;
            }
        }
    }
    if two && k.alpha != 1.0 {
        let c = 1.0 - k.alpha;
        for a in 0..D {
            for b in 0..D {
                l[(a, b)] += c * lb.all[a][b];
            }
        }
    }
    l
}

/// Deform particle `p` of `s` by `l` over `dt`: volume, deformation gradient, stress.
/// Returns whether the new state is physical.
#[inline(always)]
fn deform<const D: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p: usize,
    l: &Mat<D>,
    dt: f64,
) -> bool {
    let inc = Mat::<D>::identity() + l * dt;
    let j = det(&inc);
    // (Where the particles carry `F`, their volume is `det F · V₀`: not stored.)
    if let Some(v) = s.parts.vol.get_mut(p) {
        *v *= j;
    }
    let mat = &ctx.materials[s.parts.kind[p] as usize];
    let f = if s.parts.def_grad.is_empty() {
        Mat::<D>::identity()
    } else {
        let f = inc * s.parts.def_grad[p];
        s.parts.def_grad[p] = f;
        f
    };
    let internal = Internal {
        plastic: s.parts.be.get_mut(p).zip(s.parts.eps_p.get_mut(p)),
        damage: s.parts.damage.get_mut(p),
        stress_zz: s.parts.stress_zz.get_mut(p),
    };
    if s.parts.stress.is_empty() {
        // The stress follows from F where it is used; for the materials that do this
        // (neo-Hookean) it is finite where F is and J > 0.
        return j > 0.0 && volume_finite(s, p) && f.iter().all(|x| x.is_finite());
    }
    mat.update_stress(&mut s.parts.stress[p], l, &f, dt, internal);
    j > 0.0 && volume_finite(s, p) && s.parts.stress[p].iter().all(|x| x.is_finite())
}

/// Particle `p`'s stored volume is finite, or it stores none (its `F`, tested beside
/// this, makes it).
#[inline(always)]
fn volume_finite<const D: usize>(s: &Slices<'_, D>, p: usize) -> bool {
    s.parts.vol.get(p).is_none_or(|v| v.is_finite())
}

/// The running maximum `max` of the signal speed the time step must resolve (wave
/// speed plus particle speed), raised by particle `p`'s where that is larger
/// ([`Material::raise_signal_speed`]).
#[inline(always)]
fn raise_speed<const D: usize>(ctx: &Ctx<'_, D>, s: &Slices<'_, D>, p: usize, max: f64) -> f64 {
    let kind = s.parts.kind[p] as usize;
    let j = if s.parts.vol.is_empty() {
        det(&s.parts.def_grad[p])
    } else {
        s.parts.vol[p] / ctx.kind_vol0[kind]
    };
    ctx.materials[kind].raise_signal_speed(j, s.parts.v[p].norm(), max)
}

/// Grid → particle over all particles.
pub fn gather<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: Slices<'_, D>,
    vel: &[f64],
    avg: &[f64],
    xpic: Option<&[f64]>,
    m: GatherMode,
) -> Tally {
    let avg = if m.two_step { avg } else { &[] };
    par(parts, &|mut s: Slices<'_, D>| {
        let batches = xpic.is_none() && lanes::applies(ctx.gimp, &s);
        // The nodes' data of a run, read once per run.
        let load = |nd: &mut NodeData<D, N>, idx: &[usize; N]| {
            nd.load(idx, vel, avg, xpic);
            if m.stress {
                nd.load_differences_from(idx, vel, UPDATED);
            }
        };
        by_runs::<D, NA, N>(
            ctx,
            &mut s,
            batches,
            lanes::Pass::Gather(&m),
            load,
            |s, p, k, nd, t| gather_one(ctx, s, p, k, nd, xpic, &m, t),
        )
    })
}

/// One task's particles `s` of a grid → particle pass (the gather or the stress
/// pass), in order: eight (or four) particles of one run away from walls at a time
/// through the lanes as `pass` where `batches` ([`lanes`]), the rest one by one through
/// `one` (with the particle's weights and wall ends), each run's node data read once
/// by `load`; then, if the pass reports it, the task's fastest signal speed
/// ([`signal_speeds`]). Returns the task's tally.
#[inline(always)]
fn by_runs<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    batches: bool,
    pass: lanes::Pass<'_>,
    load: impl Fn(&mut NodeData<D, N>, &[usize; N]),
    mut one: impl FnMut(&mut Slices<'_, D>, usize, &Kern<D, N>, &NodeData<D, N>, &mut Tally),
) -> Tally {
    let mut t = Tally::ZERO;
    let speed = pass.speed();
    let mut nd = NodeData::<D, N>::new();
    let mut run = Run::<D, NA, N>::new();
    let mut cell = CellAt::<D>::new();
    let mut marks = [0.0; LANES];
    let mut room = lanes::Room::<D, N>::new();
    let mut p = 0;
    while p < s.len() {
        let b = batch_width(batches, s.tile, p);
        if b > 1 {
            if run.enter_if_new(ctx, s.tile[p], [0; D]) {
                load(&mut nd, &run.idx);
            }
            if !run.at_wall {
                let c = cell.of(ctx, s.tile[p]);
                lanes::batch(ctx, s, p, b, c, &nd, pass, &mut room, &mut t, &mut marks);
                p += b;
                continue;
            }
        }
        let half = if ctx.gimp {
            Some(&s.parts.half[p])
        } else {
            None
        };
        let xi = ctx.local(&s.parts.x[p], cell.of(ctx, s.tile[p]));
        let (mut k, below, w) = ctx.weights::<NA, N>(&s.parts.x[p], half, &xi);
        if run.enter_if_new(ctx, s.tile[p], below) {
            load(&mut nd, &run.idx);
        }
        k.ends = run.ends(ctx, &w);
        one(s, p, &k, &nd, &mut t);
        p += 1;
    }
    t.ok &= lanes::physical(&marks);
    if speed {
        t.max_speed = signal_speeds(ctx, s, t.max_speed);
    }
    t
}

/// The running maximum `max` of the signal speed raised by every particle of `s`,
/// after the pass that set their volumes and velocities: eight at a time through
/// the lanes ([`lanes::raise_speed`], vector operations where they share a
/// material), the rest one by one. The same maximum, bit for bit, as raising it
/// particle by particle in the pass: a maximum does not depend on the order. (In the
/// pass, one particle at a time, it was a chain of branches: 4 % of the 3D step.)
#[inline(always)]
fn signal_speeds<const D: usize>(ctx: &Ctx<'_, D>, s: &Slices<'_, D>, max: f64) -> f64 {
    let mut top = max;
    let mut per_lane = [f64::NEG_INFINITY; LANES];
    let mut p = 0;
    while p + LANES <= s.len() {
        top = lanes::raise_speed::<D, LANES>(ctx, s, p, top, &mut per_lane);
        p += LANES;
    }
    top = lanes::fold(top, &per_lane);
    (p..s.len()).fold(top, |m, p| raise_speed(ctx, s, p, m))
}

/// At a particle with weights `k` over its nodes' data `nd`: `Σ_n S_n v_n` of the
/// updated slot and `Σ_n S_n (v_n − v_n^old)` (the gather's and the remap's grid and
/// FLIP velocities).
#[inline(always)]
pub(crate) fn interpolate<const D: usize, const N: usize>(
    k: &Kern<D, N>,
    nd: &NodeData<D, N>,
) -> (Vector<D>, Vector<D>) {
    let mut vn = Vector::<D>::zeros();
    let mut dv = Vector::<D>::zeros();
    for n in 0..N {
        for a in 0..D {
            let (v0, v1) = (nd.v[FROM_MOMENTUM][a][n], nd.v[UPDATED][a][n]);
            vn[a] += k.s[n] * v1;
            dv[a] += k.s[n] * (v1 - v0);
        }
    }
    (vn, dv)
}

/// The gather for particle `p` of `s` with weights `k` over its nodes' data `nd`
/// (loaded, with the differences of the updated slot if `m.stress`): its new
/// velocity, the work on it, its deformation and move as `m` asks, accounted in `t`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn gather_one<const D: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p: usize,
    k: &Kern<D, N>,
    nd: &NodeData<D, N>,
    xpic: Option<&[f64]>,
    m: &GatherMode,
    t: &mut Tally,
) {
    let (vn, dv) = interpolate(k, nd);
    let old = s.parts.v[p];
    let mut new = match xpic {
        // XPIC(m): V = S v⁺ + S ((m − 1) v − m v*), the field precomputed.
        Some(_) => {
            let mut u = vn;
            for n in 0..N {
                for a in 0..D {
                    u[a] += k.s[n] * nd.x[a][n];
                }
            }
            u
        }
        None => (old + dv) * m.flip + vn * (1.0 - m.flip),
    };
    // The velocity the particle moves with: the grid's, or for a two-step
    // scheme whose L̄ and v̄ of slot 1 are at hand, their reconstruction.
    let lb = lbar_at(k, nd, m.two_step && (m.recon || m.stress));
    let vm = if m.recon {
        moving_velocity(ctx, k, nd, &lb, UPDATED)
    } else {
        vn
    };
    // At a slip wall the grid's normal velocity is zeroed before and after the
    // force update alike, so FLIP's increment never tells a particle that the
    // wall stopped it: particles kept their velocity into the wall (Taylor bar:
    // -176 m/s at 0.1 mm from it at 80 µs). So its normal component is clipped
    // to the one the particle moves with (which vanishes at the wall). Clipping,
    // not PIC: PIC every step also damps legitimate subgrid motion (bent beam at
    // its clamp: 6 % of the energy in two periods for the normal component, 12 %
    // for all, 1.1 % clipping). Not at fixed walls: there the material is
    // clamped, and clipping pressed the cantilever's compressed root onto the
    // clamp until particles left the grid through it (5 and 6 m beams at 3 × 3
    // per cell).
    let mass = particles::mass_of(ctx.kind_mass, s.parts.kind, p);
    t.work += clip_at_slip_walls(ctx, k, &mut new, &vm, mass);
    let a = ctx.accel_kept(s.accel, s.parts.x0, p);
    t.work += m.dt * mass * a.dot(&(old + new)) * 0.5;
    s.parts.v[p] = new;
    t.ok &= new.iter().all(|x| x.is_finite());
    if m.stress {
        let l = velocity_gradient_at(k, nd, &lb, UPDATED, m.two_step);
        t.ok &= deform(ctx, s, p, &l, m.dt);
    }
    if m.move_now {
        s.parts.x[p] += vm * m.dt;
    } else if !m.two_step {
        // (A two-step scheme's stress pass sets the increment: MUSL moves it
        // with the reconstruction of the remapped velocity.)
        s.dx[p] = vm * m.dt;
    }
}

/// How many particles from `p` the particle loops take at once: [`LANES`], [`HALF`]
/// or [`QUARTER`] where as many in a row share the cell corner `tile[p]` (and
/// `batches`, the lanes apply to the pass), else 1.
#[inline(always)]
fn batch_width(batches: bool, tile: &[u32], p: usize) -> usize {
    let same = |b: usize| p + b <= tile.len() && tile[p + 1..p + b].iter().all(|&c| c == tile[p]);
    if !batches {
        1
    } else if same(LANES) {
        LANES
    } else if same(HALF) {
        HALF
    } else if same(QUARTER) {
        QUARTER
    } else {
        1
    }
}

/// The stress pass for particle `p` of `s` with weights `k` over its nodes' data
/// `nd` (loaded, with the differences of slot `m.slot`): deform it, move it as `m`
/// asks, and account for it in `t`.
#[inline(always)]
fn stress_one<const D: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p: usize,
    k: &Kern<D, N>,
    nd: &NodeData<D, N>,
    m: &StressMode,
    t: &mut Tally,
) {
    let lb = lbar_at(k, nd, m.two_step);
    let l = velocity_gradient_at(k, nd, &lb, m.slot, m.two_step);
    t.ok &= deform(ctx, s, p, &l, m.dt);
    if m.moves {
        // MUSL, two-step scheme: the particle moves with the reconstruction of
        // the remapped velocity (and its velocity into a slip wall is clipped to
        // that, as in the gather).
        let vm = moving_velocity(ctx, k, nd, &lb, m.slot);
        // Only particles touching a wall's nodes can be clipped: the others'
        // velocities are neither read nor written here.
        if k.ends.iter().flatten().any(|&e| e) {
            let mut v = s.parts.v[p];
            let mass = particles::mass_of(ctx.kind_mass, s.parts.kind, p);
            t.work += clip_at_slip_walls(ctx, k, &mut v, &vm, mass);
            s.parts.v[p] = v;
        }
        s.parts.x[p] += vm * m.dt;
    } else if m.moves_kept {
        s.parts.x[p] += s.dx[p];
    }
}

/// Stress update from velocity slot `slot` at the current positions.
pub fn update_stress<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: Slices<'_, D>,
    vel: &[f64],
    avg: &[f64],
    m: StressMode,
) -> Tally {
    let avg = if m.two_step { avg } else { &[] };
    par(parts, &|mut s: Slices<'_, D>| {
        let batches = lanes::applies(ctx.gimp, &s);
        let load = |nd: &mut NodeData<D, N>, idx: &[usize; N]| {
            nd.load(idx, vel, avg, None);
            nd.load_differences_from(idx, vel, m.slot);
        };
        by_runs::<D, NA, N>(
            ctx,
            &mut s,
            batches,
            lanes::Pass::Stress(&m),
            load,
            |s, p, k, nd, t| stress_one(ctx, s, p, k, nd, &m, t),
        )
    })
}

/// Read-only particle arrays for the scatter.
pub struct ScatterParts<'a, const D: usize> {
    pub x: &'a [Vector<D>],
    pub v: &'a [Vector<D>],
    /// The stress where particles store it, else empty and formed from `def_grad`.
    pub stress: &'a [Mat<D>],
    pub def_grad: &'a [Mat<D>],
    pub kind: &'a [u16],
    pub vol: particles::Volumes<'a, D>,
    pub mass: particles::Masses<'a>,
    pub x0: &'a [Vector<D>],
    pub half: &'a [[f64; D]],
    /// Storage index of each particle's cell's lower corner node.
    pub tile: &'a [u32],
    /// A grid field of D numbers per node whose interpolation at the particle replaces
    /// its velocity in the momentum ([`ScatterMode::from_grid`]; XPIC's `S⁺S`).
    pub src: &'a [f64],
    /// The external force per unit mass of each particle where the scene has a body
    /// force ([`external_accel`]), else empty.
    pub accel: &'a [Vector<D>],
}

/// Each particle's external force per unit mass (gravity and the body force), into
/// `out`, one entry per particle of `x0`: formed once a step, before the forces'
/// scatter, which uses it, and kept for the work the gather or the remap of the same
/// step counts with it. A benchmark's body force costs sines and a logarithm per
/// particle; a pass of its own forms them in batches ([`At::add_body_forces`]).
pub fn external_accel<const D: usize>(ctx: &Ctx<'_, D>, x0: &[Vector<D>], out: &mut [Vector<D>]) {
    assert_eq!(out.len(), x0.len());
    const CHUNK: usize = 4096;
    out.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, out)| match ctx.body_force {
            Some(b) => b.add_body_forces(ctx.gravity, x0, c * CHUNK, out),
            None => out.fill(ctx.gravity),
        });
}

/// A particle's slab from its cell along the last axis ([`SlabOrder::begin`]).
#[derive(Clone, Copy, Debug)]
pub struct SlabIndex {
    lo: usize,
    hi: usize,
    thick: usize,
}

impl SlabIndex {
    /// The slab of a particle in cell `c` along the last axis (as `Geom::locate`
    /// gives it, so that the kern's nodes agree with the slab).
    #[inline]
    pub fn slab(self, c: i64) -> u32 {
        // The scatter's threads rely on this (see `scatter`): a particle outside its
        // block would write outside its slab's rows.
        assert!(
            (self.lo as i64..self.hi as i64).contains(&c),
            "a particle in cell {c} along the last axis is outside its block [{}, {})",
            self.lo,
            self.hi
        );
        ((c as usize - self.lo) / self.thick) as u32
    }

    /// [`SlabIndex::slab`] of `L` cells at once: one range test for all of them, and
    /// no division for slabs one cell thick (hat functions), so that the lanes of the
    /// tile pass ([`slab_thickness`]) stay vector operations.
    #[inline(always)]
    pub fn slabs<const L: usize>(self, c: &[i64; L]) -> [u32; L] {
        let (lo, hi) = (self.lo as i64, self.hi as i64);
        let mut ok = true;
        for &c in c {
            ok &= (c >= lo) & (c < hi);
        }
        if !ok {
            // The same message as one at a time, for the first cell out of range.
            return c.map(|c| self.slab(c));
        }
        if self.thick == 1 {
            c.map(|c| (c - lo) as u32)
        } else {
            c.map(|c| ((c - lo) as usize / self.thick) as u32)
        }
    }
}

/// A rank's particles in runs of one slab, chunk by chunk of [`SlabOrder::CHUNK`]:
/// what [`SlabOrder::finish`] sorts. The tile pass's runs of one cell are such runs,
/// so the order needs no slab stored per particle (4 bytes each).
///
/// `each(c, …)`'s runs must cover chunk `c`'s particles (`c · CHUNK ..`, up to
/// `count`) exactly, in order ([`SlabOrder::finish`] asserts the total).
///
/// # Safety
///
/// [`SlabOrder::finish`] writes the order from several threads where a first call of
/// `each` counted runs: `each` must give the same runs every time it is called.
pub unsafe trait SlabRuns: Sync {
    /// The particle count.
    fn count(&self) -> usize;

    /// `f(s, particles)` for the runs of chunk `c` in order: together they cover its
    /// particles `c · CHUNK ..` exactly, each run in slab `s`.
    fn each(&self, c: usize, f: impl FnMut(u32, std::ops::Range<usize>));
}

/// The particle order of the coloured scatter: particle indices grouped by slab.
#[derive(Default, Debug)]
pub struct SlabOrder {
    /// `start[s]..start[s + 1]` indexes `order` for slab `s`.
    pub start: Vec<usize>,
    pub order: Vec<u32>,
    /// Per chunk of [`SlabOrder::CHUNK`] particles, its particles per slab (chunk-major),
    /// then where its first particle of each slab goes in `order`.
    counts: Vec<usize>,
    /// `below[s]`: the particles of the slabs `s − 2, s − 4, …` (same colour, below).
    below: Vec<usize>,
    /// Owned cells along the last axis, `[lo, hi)`, in slabs of `thick` cells.
    lo: usize,
    hi: usize,
    thick: usize,
}

/// Where the chunks of a parallel counting sort write `order`.
#[derive(Clone, Copy)]
struct OrderPtr(*mut u32);

// SAFETY: made in `SlabOrder::finish` from `&mut self.order`, held for its whole use.
// Chunk `c` writes `order[counts[c][s] ..]` for each of its particles in slab `s`, as
// many as it counted there (its runs are the same both times, `SlabRuns`'s contract); the offsets are an exclusive prefix sum over (slab, chunk)
// of those counts, so the ranges of different (chunk, slab) pairs are disjoint and lie
// within `order` (whose length is their total). No two threads
// write one element and no element is read while they run.
unsafe impl Send for OrderPtr {}
unsafe impl Sync for OrderPtr {}

impl OrderPtr {
    /// Write `order[k] = p`. Safety: `k` lies in `order` and no other thread reads or
    /// writes `order[k]` (see the type's safety note).
    #[inline(always)]
    unsafe fn write(self, k: usize, p: u32) {
        // SAFETY: the caller's contract.
        unsafe { *self.0.add(k) = p };
    }
}

impl SlabOrder {
    /// Particles per chunk of the parallel passes that fill the order (fixed, so the
    /// order does not depend on the thread count).
    pub const CHUNK: usize = 4096;

    /// Start grouping particles by slab (of `thick` cells, [`slab_thickness`]) along the
    /// last axis of the owned cells `[cell_lo, cell_hi)`; the returned index finds a
    /// cell's slab. Then [`SlabOrder::finish`] with the particles' runs.
    pub fn begin(&mut self, cell_lo: usize, cell_hi: usize, thick: usize) -> SlabIndex {
        let nslab = (cell_hi - cell_lo).div_ceil(thick).max(1);
        self.lo = cell_lo;
        self.hi = cell_hi;
        self.thick = thick;
        self.start.clear();
        self.start.resize(nslab + 1, 0);
        self.index()
    }

    /// How to find a cell's slab (the last [`SlabOrder::begin`]'s).
    pub fn index(&self) -> SlabIndex {
        SlabIndex {
            lo: self.lo,
            hi: self.hi,
            thick: self.thick,
        }
    }

    /// Order the particles of `runs` by slab, stably (within a slab, particles keep
    /// their array order): a counting sort over runs, its counting and placing in
    /// parallel over chunks where the per-chunk counts are few (a slab count per
    /// chunk, no more numbers than particles), else serially (many slabs, as in a huge
    /// box, with few particles). The order is the same either way.
    pub fn finish(&mut self, runs: &impl SlabRuns) {
        let nslab = self.start.len() - 1;
        let n = runs.count();
        let nchunk = n.div_ceil(Self::CHUNK);
        if nchunk * nslab <= n {
            self.count_in_chunks(nchunk, runs);
        } else {
            self.start.fill(0);
            for c in 0..nchunk {
                runs.each(c, |s, run| self.start[s as usize + 1] += run.len());
            }
            for s in 0..nslab {
                self.start[s + 1] += self.start[s];
            }
            self.order.resize(n, 0);
            let mut at = self.start.clone();
            for c in 0..nchunk {
                runs.each(c, |s, run| {
                    let k = at[s as usize];
                    for (o, p) in self.order[k..k + run.len()].iter_mut().zip(run.clone()) {
                        *o = p as u32;
                    }
                    at[s as usize] += run.len();
                });
            }
        }
        assert_eq!(self.start[nslab], n, "the runs cover every particle once");
        // Per colour, the particles of the slabs below each slab ([`SlabOrder::split`]).
        self.below.clear();
        self.below.resize(nslab + 2, 0);
        for s in 0..nslab {
            self.below[s + 2] = self.below[s] + self.start[s + 1] - self.start[s];
        }
    }

    /// [`SlabOrder::finish`]'s parallel counting sort.
    fn count_in_chunks(&mut self, nchunk: usize, runs: &impl SlabRuns) {
        use rayon::prelude::*;
        let nslab = self.start.len() - 1;
        self.counts.clear();
        self.counts.resize(nchunk * nslab, 0);
        self.counts
            .par_chunks_mut(nslab)
            .enumerate()
            .for_each(|(c, count)| {
                runs.each(c, |s, run| count[s as usize] += run.len());
            });
        // Offsets: slab by slab, chunk by chunk within a slab (so within a slab the
        // particles keep their array order). Walked chunk by chunk (the counts' own
        // order, not a stride of a slab count per step): first each slab's total, whose
        // prefix sums start the slabs, then each chunk's place after the chunks before.
        self.start.fill(0);
        for count in self.counts.chunks_exact(nslab) {
            for (t, &c) in self.start[1..].iter_mut().zip(count) {
                *t += c;
            }
        }
        for s in 0..nslab {
            self.start[s + 1] += self.start[s];
        }
        for c in 0..nchunk {
            let (next, row) = (
                &mut self.start[..nslab],
                &mut self.counts[c * nslab..][..nslab],
            );
            for (k, at) in row.iter_mut().zip(next.iter_mut()) {
                let count = *k;
                *k = *at;
                *at += count;
            }
        }
        let total = self.start[nslab];
        // `start` was advanced past each slab: back to the slabs' starts.
        for s in (1..=nslab).rev() {
            self.start[s] = self.start[s - 1];
        }
        self.start[0] = 0;
        // Every entry is written below.
        // As long as the runs counted (which the writes below stay within).
        self.order.resize(total, 0);
        let out = OrderPtr(self.order.as_mut_ptr());
        self.counts
            .par_chunks_mut(nslab)
            .enumerate()
            .for_each(|(c, cursor)| {
                runs.each(c, |s, run| {
                    // In a local, not through `cursor`, which the writes might alias
                    // as far as the compiler knows.
                    let mut k = cursor[s as usize];
                    for p in run {
                        // SAFETY: see `OrderPtr`: `k` stays within this chunk's range
                        // for slab `s`, which lies in `order` and no other thread
                        // writes.
                        unsafe { out.write(k, p as u32) };
                        k += 1;
                    }
                    cursor[s as usize] = k;
                });
            });
    }

    pub fn slabs(&self) -> usize {
        self.start.len() - 1
    }

    /// How the same-coloured slabs `first, first + 2, …` (`count` of them, at least 2)
    /// split between two tasks: `None` if they hold no particle, else how many go to
    /// the first task, at least one each, so that its particles come nearest to half
    /// of theirs; of two such splits, the one nearer the middle slab. Depends on the
    /// particles, not the threads. The recursion of the coloured loops thus halves
    /// the particles, or the slabs where a slab holds no particle, or ends at a slab
    /// that holds more than the rest: it is O(log) deep (a huge box has many empty
    /// slabs: always splitting off one slab recursed once per slab, and overflowed
    /// the stack).
    pub fn split(&self, first: usize, count: usize) -> Option<usize> {
        // The particles of the first h slabs.
        let share = |h: usize| self.below[first + 2 * h] - self.below[first];
        let total = share(count);
        if total == 0 {
            return None;
        }
        // The first h in 1..count whose share reaches half, by bisection (the shares
        // grow with h); the best split is it or the one before.
        let (mut lo, mut hi) = (1, count - 1);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if 2 * share(mid) >= total {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        let key = |h: usize| ((2 * share(h)).abs_diff(total), (2 * h).abs_diff(count));
        Some(if lo > 1 && key(lo - 1) < key(lo) {
            lo - 1
        } else {
            lo
        })
    }
}

/// How the scatter lays out its node record.
#[derive(Clone, Copy, Debug)]
pub struct ScatterMode {
    /// Record width per node.
    pub sw: usize,
    /// Scatter external and internal forces (else mass and momentum only).
    pub forces: bool,
    /// Also accumulate Σ(1−α) v σ S and the nodes' covered volume Σ v S (two-step
    /// schemes).
    pub two_step: bool,
    /// Momentum of the grid field `src` interpolated at each particle instead of the
    /// particle's velocity (grid → particle → grid in one pass, for XPIC).
    pub from_grid: bool,
}

/// The scatter's view of the node records, shared by its threads.
#[derive(Clone, Copy)]
pub(crate) struct GridPtr {
    ptr: *mut f64,
    len: usize,
}

impl GridPtr {
    pub(crate) fn new(field: &mut [f64]) -> Self {
        GridPtr {
            ptr: field.as_mut_ptr(),
            len: field.len(),
        }
    }

    /// The `width` numbers at `at` (bounds checked).
    ///
    /// # Safety
    /// The field the pointer was made from is still borrowed exclusively by the caller's
    /// caller, and no other thread reads or writes these numbers while the slice lives.
    #[inline(always)]
    pub(crate) unsafe fn record<'a>(self, at: usize, width: usize) -> &'a mut [f64] {
        assert!(
            at + width <= self.len,
            "node record outside the grid storage"
        );
        // SAFETY: in bounds (checked above); exclusive by the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(at), width) }
    }

    /// Ask for the cache lines of the `width` numbers at `at` ahead of their use: a
    /// hint, no access (an address outside the storage is never touched).
    #[inline(always)]
    pub(crate) fn prefetch(self, at: usize, width: usize) {
        prefetch_lines(self.ptr.wrapping_add(at).cast(), width * size_of::<f64>());
    }
}

/// Ask for the cache lines of `field[at..at + width]` ahead of their use: a hint, no
/// access (a range outside the field is never touched).
#[inline(always)]
pub(crate) fn prefetch<T>(field: &[T], at: usize, width: usize) {
    prefetch_lines(
        field.as_ptr().wrapping_add(at).cast(),
        width * size_of::<T>(),
    );
}

/// Prefetch the cache lines of the `bytes` bytes from `first`: only an address, never
/// dereferenced.
#[inline(always)]
fn prefetch_lines(first: *const u8, bytes: usize) {
    #[cfg(target_arch = "x86_64")]
    if bytes > 0 {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let last = first.wrapping_add(bytes - 1) as usize;
        let mut line = first as usize & !63;
        while line <= last {
            // SAFETY: a prefetch is a hint: it never faults, whatever the address, and
            // changes no memory; its SSE is in every x86-64 CPU.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(line as *const i8) };
            line += 64;
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (first, bytes);
}

// SAFETY: a `GridPtr` is only made in `scatter` from a `&mut [f64]` that it holds for
// its whole run, and the threads given copies write node records of disjoint node sets
// (see `scatter`), so sharing it between threads is sharing disjoint parts of a buffer
// borrowed exclusively.
unsafe impl Send for GridPtr {}
unsafe impl Sync for GridPtr {}

/// Particle → grid over all particles into `scat` (cleared by the caller), in slab
/// colours so that no two threads write the same node.
///
/// Why threads never write the same record: slab `s` holds the particles whose cell
/// lies in cells `[lo + s·T, lo + (s+1)·T)` of the block along the last axis (`T` the
/// [`slab_thickness`]; `SlabIndex::slab` asserts it). A particle in cell `c` writes
/// nodes `c ..= c + 1` along that axis with hat functions, so slab `s` writes node rows
/// `lo + s·T ..= lo + (s+1)·T` and slab `s + 2` starts at row `lo + (s+2)·T`: disjoint
/// for T >= 1. A GIMP particle writes `c − 1 ..= c + 2`, so slab `s` writes up to row
/// `lo + (s+1)·T + 1` and slab `s + 2` from row `lo + (s+2)·T − 1`: disjoint for
/// T >= 3. Same-coloured slabs thus write disjoint node sets, and the
/// storage map of [`Tiles`] is injective (a node has one tile, a tile one slot), so
/// they write disjoint records. The two colours run one after the other.
///
pub fn scatter<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: &ScatterParts<'_, D>,
    slabs: &SlabOrder,
    scat: &mut [f64],
    m: ScatterMode,
) {
    let grid = GridPtr::new(scat);
    let ns = slabs.slabs();
    for colour in 0..2 {
        let first = colour;
        if first >= ns {
            continue;
        }
        let count = (ns - first).div_ceil(2);
        scatter_slabs::<D, NA, N>(ctx, parts, slabs, grid, first, count, m);
    }
}

fn scatter_slabs<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: &ScatterParts<'_, D>,
    slabs: &SlabOrder,
    grid: GridPtr,
    first: usize,
    count: usize,
    m: ScatterMode,
) {
    if count > 1 {
        // Same-coloured slabs `first, first + 2, ...`: split them in two runs.
        let Some(half) = slabs.split(first, count) else {
            return;
        };
        rayon::join(
            || scatter_slabs::<D, NA, N>(ctx, parts, slabs, grid, first, half, m),
            || {
                scatter_slabs::<D, NA, N>(
                    ctx,
                    parts,
                    slabs,
                    grid,
                    first + 2 * half,
                    count - half,
                    m,
                )
            },
        );
        return;
    }
    let mut acc = ScatterSums::<D, N>::new();
    // The sums stay in memory (L1), added into by vector loads and stores. Held in
    // registers, the compiler split them into single numbers and put them back into
    // vectors for every particle (two dozen shuffles per particle, a third of the 2D
    // scatter's samples); marking the place as seen from outside keeps it whole:
    // the 2D block drop 0.93x the time, 3D the same.
    let acc = std::hint::black_box(&mut acc);
    let mut run = Run::<D, NA, N>::new();
    let mut cell = CellAt::<D>::new();
    let mut kinds = particles::KindCache::new(ctx.kind_mass, ctx.kind_vol0, ctx.materials);
    // The arrays every particle has, each as long as the positions: one index check
    // per particle then covers them all.
    let len = parts.x.len();
    let (xs, vels, tiles, kind) = (
        &parts.x[..len],
        &parts.v[..len],
        &parts.tile[..len],
        &parts.kind[..len],
    );
    for &p in &slabs.order[slabs.start[first]..slabs.start[first + 1]] {
        let p = p as usize;
        assert!(p < len, "slab order names particle {p} of {len}");
        let at = kinds.get(kind[p]);
        // The stress first: in 3D it is a call (`particles::stress_call`), and every
        // vector register live across it is saved and reloaded; before the weights,
        // few are.
        let (vol, vs) = if m.forces {
            particles::volume_and_stress(parts.stress, &parts.vol, ctx.materials, &at, p)
        } else {
            (parts.vol.get(p), Mat::<D>::zeros())
        };
        let half = if ctx.gimp { Some(&parts.half[p]) } else { None };
        // (ξ formed here, not before the stress: there, the 2D scatter's share
        // grew 1.13 against ξ kept by the tile pass, here 1.06.)
        let xi = ctx.local(&xs[p], cell.of(ctx, tiles[p]));
        let (k, below, _) = ctx.weights::<NA, N>(&xs[p], half, &xi);
        if run.is_new(tiles[p], below) {
            if run.started() {
                acc.flush(ctx, grid, &run.idx, m);
            }
            run.enter(ctx, tiles[p], below);
            // The run's records are added into at its end, after its particles:
            // fetched meanwhile, not waited for then.
            for &n in &run.idx {
                grid.prefetch(n * m.sw, m.sw);
            }
        }
        let idx = &run.idx;
        let mass = at.mass;
        let mv = if m.from_grid {
            let mut u = Vector::<D>::zeros();
            for n in 0..N {
                let at = idx[n] * D;
                for a in 0..D {
                    u[a] += k.s[n] * parts.src[at + a];
                }
            }
            u * mass
        } else {
            vels[p] * mass
        };
        let fe = if m.forces {
            ctx.accel_kept(parts.accel, parts.x0, p) * mass
        } else {
            Vector::<D>::zeros()
        };
        acc.add(&k, mass, &mv, vol, &vs, &fe, m);
    }
    if run.started() {
        acc.flush(ctx, grid, &run.idx, m);
    }
}

/// A scatter's sums over one run of particles that share their nodes (particles sorted
/// by cell: 16 in a row in 2D at 4 × 4 per cell), added into the node records once per
/// run. The particle loop adds into these fixed places, which need no index
/// arithmetic or bounds checks and do not wait on the previous particle's store into
/// the grid; the records see one addition per run instead of one per particle.
/// Each sum is per node, nodes innermost.
///
/// Aligned to 32 bytes: the clear after each run (`memset`) then stores whole aligned
/// vectors where the next run's first particle loads them, and each load finds its
/// store to forward from. Unaligned, every such load spans two of `memset`'s stores
/// and waits for them to reach the cache: the 3D scatter's two hottest instructions
/// (12 % and 8.5 % of its samples), gone from the profile once aligned.
#[repr(C, align(32))]
struct ScatterSums<const D: usize, const N: usize> {
    mass: [f64; N],
    mom: [[f64; N]; D],
    force: [[f64; N]; D],
    /// Hat functions: the internal force's sums per pair of nodes along each axis,
    /// `pairs[a][b][m] = Σ_p α_p V_p σ_p[a][b] ∂_b S_upper(x_p)` over the `m`-th pair
    /// ([`pair`]); the upper node gets minus it, the lower one it, at the flush.
    pairs: [[[f64; N]; D]; D],
    /// The upper triangle ([`sym_index`]); 6 is the 3D count.
    stress: [[f64; N]; 6],
    cover: [f64; N],
}

impl<const D: usize, const N: usize> ScatterSums<D, N> {
    fn new() -> Self {
        ScatterSums {
            mass: [0.0; N],
            mom: [[0.0; N]; D],
            force: [[0.0; N]; D],
            pairs: [[[0.0; N]; D]; D],
            stress: [[0.0; N]; 6],
            cover: [0.0; N],
        }
    }

    /// Add one particle's contributions: mass, momentum `mv`, and as `m` asks the
    /// cover (volume `vol`), the forces (external `fe`, internal from `vs = V σ`) and
    /// the averaged-stress sum.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn add(
        &mut self,
        k: &Kern<D, N>,
        mass: f64,
        mv: &Vector<D>,
        vol: f64,
        vs: &Mat<D>,
        fe: &Vector<D>,
        m: ScatterMode,
    ) {
        // Node-innermost loops over fixed arrays: each is a few vector operations.
        for n in 0..N {
            self.mass[n] += mass * k.s[n];
        }
        for a in 0..D {
            for n in 0..N {
                self.mom[a][n] += mv[a] * k.s[n];
            }
        }
        if m.two_step {
            for n in 0..N {
                self.cover[n] += vol * k.s[n];
            }
        }
        if m.forces && hats::<D, N>() {
            // A hat's derivative along b at the lower node of a pair is exactly minus
            // the upper one's: one product per pair, not per node.
            for a in 0..D {
                for n in 0..N {
                    self.force[a][n] += fe[a] * k.s[n];
                }
                for b in 0..D {
                    let avs = k.alpha * vs[(a, b)];
                    for m in 0..N / 2 {
                        self.pairs[a][b][m] += avs * k.g[b][pair(b, m).1];
                    }
                }
            }
        } else if m.forces {
            for a in 0..D {
                for n in 0..N {
                    let mut sg = 0.0;
                    for b in 0..D {
                        sg += vs[(a, b)] * k.g[b][n];
                    }
                    self.force[a][n] += fe[a] * k.s[n] - k.alpha * sg;
                }
            }
        }
        if m.forces && m.two_step {
            let c: [f64; N] = std::array::from_fn(|n| (1.0 - k.alpha) * k.s[n]);
            for a in 0..D {
                for b in a..D {
                    let t = &mut self.stress[sym_index::<D>(a, b)];
                    for n in 0..N {
                        t[n] += c[n] * vs[(a, b)];
                    }
                }
            }
        }
    }

    /// Add the sums into the records of nodes `idx` and start again from zero.
    #[inline(always)]
    fn flush(&mut self, ctx: &Ctx<'_, D>, grid: GridPtr, idx: &[usize; N], m: ScatterMode) {
        type R<const D: usize> = NodeRecord<D>;
        let sw = m.sw;
        if m.forces && hats::<D, N>() {
            // Each node is in one pair along each axis: it gets its pair's sum, plus at
            // the lower node and minus at the upper (`x + (−p)` is `x − p` to the bit),
            // spread over all nodes first so that the additions are whole vectors.
            for a in 0..D {
                for b in 0..D {
                    let p = &self.pairs[a][b];
                    let mut e = [0.0; N];
                    for (n, e) in e.iter_mut().enumerate() {
                        let m = pair_of(b, n);
                        *e = if (n >> b) & 1 == 0 { p[m] } else { -p[m] };
                    }
                    for n in 0..N {
                        self.force[a][n] += e[n];
                    }
                }
            }
        }
        for n in 0..N {
            debug_assert!(
                idx[n] >= ctx.tiles.tile_nodes(),
                "a particle's node in the zero tile: its tile was not touched"
            );
            // SAFETY: no other thread writes this record while this one does (see
            // `scatter`), and this thread holds no other reference into the buffer
            // while `rec` lives.
            let rec = unsafe { grid.record(idx[n] * sw, sw) };
            rec[R::<D>::MASS] += self.mass[n];
            for a in 0..D {
                rec[R::<D>::momentum(a)] += self.mom[a][n];
            }
            if m.two_step {
                rec[R::<D>::cover(sw)] += self.cover[n];
            }
            if m.forces {
                for a in 0..D {
                    rec[R::<D>::force(a)] += self.force[a][n];
                }
                if m.two_step {
                    for k in 0..R::<D>::SYM {
                        rec[R::<D>::stress_sum(0, 0) + k] += self.stress[k][n];
                    }
                }
            }
        }
        *self = Self::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use decomposition::splitmix::Rng;

    /// The slab order of `cells` (along the last axis, in `[lo, hi)`) on `threads`
    /// threads, reusing `o` as the solver does.
    fn order(
        o: &mut SlabOrder,
        (lo, hi, thick): (usize, usize, usize),
        cells: &[i64],
        threads: usize,
    ) -> SlabIndex {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool");
        pool.install(|| {
            let ix = o.begin(lo, hi, thick);
            o.finish(&CellSlabs { cells, ix });
            ix
        })
    }

    /// Particles in `cells`, in runs of one cell as the tile pass finds them (so runs
    /// next to each other may share a slab).
    struct CellSlabs<'a> {
        cells: &'a [i64],
        ix: SlabIndex,
    }

    // SAFETY: `each` walks chunk `c`'s particles once, in order, the same every call.
    unsafe impl SlabRuns for CellSlabs<'_> {
        fn count(&self) -> usize {
            self.cells.len()
        }

        fn each(&self, c: usize, mut f: impl FnMut(u32, std::ops::Range<usize>)) {
            let end = self.cells.len().min((c + 1) * SlabOrder::CHUNK);
            let mut a = c * SlabOrder::CHUNK;
            while a < end {
                let s = self.ix.slab(self.cells[a]);
                let mut b = a + 1;
                while b < end && self.cells[b] == self.cells[a] {
                    b += 1;
                }
                f(s, a..b);
                a = b;
            }
        }
    }

    /// The stored upper triangle: row by row, each place once, and `(b, a)` at the
    /// place of `(a, b)`.
    fn sym_layout<const D: usize>() {
        let mut k = 0;
        for a in 0..D {
            for b in 0..D {
                assert_eq!(sym_index::<D>(a, b), sym_index::<D>(b, a), "D {D}");
                if b >= a {
                    assert_eq!(sym_index::<D>(a, b), k, "D {D}, ({a}, {b})");
                    k += 1;
                }
            }
        }
        assert_eq!(k, NodeRecord::<D>::SYM);
    }

    /// `pair_of` names the pair `pair` puts a corner in, along every axis of 3D.
    #[test]
    fn pair_of_inverts_pair() {
        for b in 0..3 {
            for n in 0..8 {
                let (lo, hi) = pair(b, pair_of(b, n));
                assert!(
                    n == lo || n == hi,
                    "corner {n}, axis {b}: pair ({lo}, {hi})"
                );
            }
            for m in 0..4 {
                let (lo, hi) = pair(b, m);
                assert_eq!(
                    (pair_of(b, lo), pair_of(b, hi)),
                    (m, m),
                    "axis {b}, pair {m}"
                );
            }
        }
    }

    /// `NodeData::load` puts every number of the nodes' records where its doc says, in
    /// `D` dimensions with `N` nodes (four at a time where `N` allows), with and without
    /// the averages and XPIC's field, for nodes anywhere in the records.
    fn load_places<const D: usize, const N: usize>(seed: u64) {
        let mut rng = Rng::new(seed);
        let nodes = 40;
        let aw = AvgRecord::<D>::WIDTH;
        let vel: Vec<f64> = (0..nodes * VelRecord::<D>::WIDTH)
            .map(|_| rng.f64())
            .collect();
        let avg: Vec<f64> = (0..nodes * aw).map(|_| rng.f64()).collect();
        let xp: Vec<f64> = (0..nodes * D).map(|_| rng.f64()).collect();
        for with in [false, true] {
            // Distinct nodes (7 is prime to 40) in no order, the last record first.
            let mut idx = [0; N];
            for n in 0..N {
                idx[n] = (nodes - 1 + 7 * n) % nodes;
            }
            let mut nd = NodeData::<D, N>::new();
            let (a, x) = if with {
                (&avg[..], Some(&xp[..]))
            } else {
                (&[][..], None)
            };
            nd.load(&idx, &vel, a, x);
            for n in 0..N {
                for c in 0..D {
                    for slot in 0..2 {
                        let at = VelRecord::<D>::at(idx[n], slot) + c;
                        assert_eq!(nd.v[slot][c][n], vel[at], "{D}D v[{slot}][{c}][{n}]");
                    }
                    if with {
                        for b in 0..D {
                            assert_eq!(nd.lb[c][b][n], avg[idx[n] * aw + c * D + b]);
                        }
                        let vb = avg[idx[n] * aw + AvgRecord::<D>::VBAR + c];
                        assert_eq!(nd.vb[c][n], vb, "{D}D vb[{c}][{n}]");
                        assert_eq!(nd.x[c][n], xp[idx[n] * D + c], "{D}D x[{c}][{n}]");
                    } else {
                        assert_eq!((nd.lb[c][0][n], nd.vb[c][n], nd.x[c][n]), (0.0, 0.0, 0.0));
                    }
                }
            }
        }
    }

    #[test]
    fn node_data_load_places_every_number() {
        load_places::<1, 2>(1);
        load_places::<2, 4>(2);
        load_places::<3, 8>(3);
        load_places::<2, 9>(4);
        load_places::<3, 27>(5);
    }

    #[test]
    fn symmetric_tensor_places_cover_the_upper_triangle_once() {
        sym_layout::<1>();
        sym_layout::<2>();
        sym_layout::<3>();
    }

    /// The parallel counting sort is the stable sort by slab: every particle once,
    /// slabs in order, array order within a slab, across the chunks it counts in, on
    /// any number of threads, and when reused for fewer particles.
    #[test]
    fn slab_order_is_the_stable_sort_by_slab() {
        let (lo, hi) = (3usize, 40usize);
        let mut rng = Rng::new(7);
        let mut o = SlabOrder::default();
        // Counted in parallel (many particles per slab), serially (fewer particles
        // than slabs), none.
        let sizes = [3 * SlabOrder::CHUNK + 123, SlabOrder::CHUNK / 3, 20, 0];
        for (n, thick) in sizes.into_iter().zip([1, 3, 1, 1]) {
            // Scattered cells among short runs, then long runs of one cell (as sorted
            // particles give: the counting goes sixteen at a time through them).
            let cells: Vec<i64> = (0..n)
                .map(|p| {
                    lo + if p % 3 == 0 && p < n / 2 {
                        rng.below(hi - lo)
                    } else {
                        (p / 500) % (hi - lo)
                    }
                })
                .map(|c| c as i64)
                .collect();
            let slab = |p: u32| (cells[p as usize] as usize - lo) / thick;
            let mut expect: Vec<u32> = (0..n as u32).collect();
            expect.sort_by_key(|&p| slab(p));
            for threads in [1, 2, 3] {
                let ix = order(&mut o, (lo, hi, thick), &cells, threads);
                assert_eq!(o.order, expect, "{n} particles, {threads} threads");
                assert_eq!(o.slabs(), (hi - lo).div_ceil(thick));
                for s in 0..o.slabs() {
                    for &p in &o.order[o.start[s]..o.start[s + 1]] {
                        assert_eq!(ix.slab(cells[p as usize]) as usize, s);
                    }
                }
                assert_eq!(o.start[o.slabs()], n);
            }
        }
    }

    /// A slab order of one-cell slabs holding `sizes[s]` particles each.
    fn with_sizes(sizes: &[usize]) -> SlabOrder {
        let cells: Vec<i64> = (0..sizes.len())
            .flat_map(|s| std::iter::repeat_n(s as i64, sizes[s]))
            .collect();
        let mut o = SlabOrder::default();
        order(&mut o, (0, sizes.len(), 1), &cells, 1);
        o
    }

    /// How deep the coloured loops recurse over `count` slabs from `first`.
    fn depth(o: &SlabOrder, first: usize, count: usize) -> usize {
        match (count > 1).then(|| o.split(first, count)).flatten() {
            None => 1,
            Some(h) => 1 + depth(o, first, h).max(depth(o, first + 2 * h, count - h)),
        }
    }

    /// The split of a colour's slabs between two tasks leaves each at least one slab
    /// and gives the first the share nearest to half that any split could; the
    /// recursion stays logarithmic, with empty slabs (a huge box) too.
    #[test]
    fn slab_split_is_the_most_even_and_shallow() {
        let mut rng = Rng::new(11);
        for round in 0..300 {
            let ns = 2 + rng.below(if round < 200 { 30 } else { 3000 });
            // Slab sizes, many empty, some few, most many (a body's edge, its bulk).
            let sizes: Vec<usize> = (0..ns)
                .map(|_| match rng.below(if round % 2 == 0 { 4 } else { 40 }) {
                    0 => 100 + rng.below(1000),
                    1 => rng.below(10),
                    2 => 100 + rng.below(1000),
                    _ => 0,
                })
                .collect();
            let o = with_sizes(&sizes);
            for first in 0..2.min(ns) {
                let count = (ns - first).div_ceil(2);
                if count < 2 {
                    continue;
                }
                let share = |h: usize| (0..h).map(|k| sizes[first + 2 * k]).sum::<usize>();
                let total = share(count);
                let Some(h) = o.split(first, count) else {
                    assert_eq!(total, 0);
                    continue;
                };
                assert!((1..count).contains(&h));
                let best = (1..count).map(|h| (2 * share(h)).abs_diff(total)).min();
                assert_eq!(Some((2 * share(h)).abs_diff(total)), best, "{sizes:?}");
                let log = |x: usize| x.max(1).ilog2() as usize + 1;
                let d = depth(&o, first, count);
                assert!(d <= log(total) + log(count) + 2, "depth {d}: {sizes:?}");
            }
        }
        // One full slab in a huge box's 65536.
        let mut sizes = vec![0; 65536];
        sizes[40000] = 500;
        let o = with_sizes(&sizes);
        assert!(depth(&o, 0, 32768) <= 18, "{}", depth(&o, 0, 32768));
    }
}
