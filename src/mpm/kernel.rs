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
//! 2D at 4 × 4 per cell, 8 in 3D at 2 × 2 × 2; with 3 nodes per axis they are sorted by
//! the window of nodes they reach, which particles of up to 2^D cells share, and come
//! in runs as long). A loop looks the run's nodes up once,
//! copies the grid data it reads into small node-innermost arrays (`NodeData`) and
//! sums what it writes in such arrays (`ScatterSums`), so the per-particle work is
//! arithmetic on fixed places. Hat functions start from the local cell coordinate in
//! the cell the tile pass found (`Ctx::local`, a subtraction, a product and a
//! subtraction per axis), so no loop locates its particles again.

use crate::input::scene::Face;
use crate::mpm::particles::{self, ParticleSlices};
use crate::physics::benchmark;
use crate::physics::material::Material;
use crate::physics::shape::{self, Alpha, Geom, Reads};
use crate::physics::tensor::{det, Mat, Vector};
use decomposition::tiles::{Tiles, NEIGHBOURS, TILE, TILE_LOG};
use rayon::prelude::*;

pub(crate) mod lanes;
use lanes::{HALF, LANES, QUARTER};

// The coloured passes' parallel writes: the pointers and the slab order in `colour`,
// the scatter's writes through them.
#[allow(unsafe_code)]
mod colour;
mod gather;
mod node_data;
#[allow(unsafe_code)]
mod scatter;
pub use colour::*;
pub use gather::*;
pub use node_data::*;
pub use scatter::*;

/// Particles per task below which the particle loops stop splitting.
const GRAIN: usize = 4096;

/// What the particle loops read of the grid and the scene.
pub struct Ctx<'a, const D: usize> {
    pub geom: &'a Geom<D>,
    pub node_lo: [i64; D],
    /// Where the nodes of the local box are stored.
    pub tiles: &'a Tiles<D>,
    /// A particle touches 3 nodes per axis (GIMP, the domain rule), not 2.
    pub wide: bool,
    /// MPMCG's domain rule ([`shape::domain`]).
    pub domain: bool,
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

/// Layout of a node's scatter record, `width(two_step, moments)` numbers per node: the
/// mass, the momentum (D), the force (D), and for two-step schemes the averaged-stress
/// sum `Σ_p (1 − α_p) v_p σ_p S_j(x_p)` (its upper triangle, [`NodeRecord::SYM`]
/// numbers: the stress is symmetric, so the lower one is the same sum), with the
/// centroid correction the first moment `Σ_p m_p S_j(x_p) (x̂_p − x_j)` (D), and the
/// cover `Σ_p v_p S_j(x_p)` last. The records are summed over ranks as plain numbers
/// (the ghost sum).
pub struct NodeRecord<const D: usize>;

impl<const D: usize> NodeRecord<D> {
    pub const MASS: usize = 0;
    /// Entries of a symmetric D × D tensor's upper triangle.
    pub const SYM: usize = D * (D + 1) / 2;
    pub const fn width(two_step: bool, moments: bool) -> usize {
        1 + 2 * D + if two_step { Self::SYM + 1 } else { 0 } + if moments { D } else { 0 }
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
    /// Component `a` of the first moment (records with moments, two-step schemes).
    pub const fn moment(a: usize) -> usize {
        1 + 2 * D + Self::SYM + a
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
    /// The weights of mass, momentum and the velocity interpolation: the shape
    /// functions, under the domain rule their averages over the particle's domain.
    pub s: [f64; N],
    /// The hat functions at the particle, with which the two-step schemes' move blends
    /// into the grid velocity at a wall (`s` but under the domain rule).
    pub at_point: [f64; N],
    /// Shape-function gradients, `g[d][n]` along axis `d` at node `n` (nodes innermost,
    /// so that a loop over the nodes runs over adjacent numbers).
    pub g: [[f64; N]; D],
    pub alpha: f64,
    /// The weight of node `n`'s averages σ̄ and L̄ at the particle: `(1 − α) S_n`, or
    /// under the domain rule its average over the particle's domain.
    pub avg_w: [f64; N],
    /// Local cell coordinate ξ per axis (hat functions and the domain rule: the offset
    /// of node `n` from the particle is `(ξ_a + below_a − o_a) h_a`, `o_a` its place in
    /// the window, `below_a` where the window starts below the cell).
    pub frac: [f64; D],
    /// Per axis: the particle gives weight to a node on the lower / upper grid face.
    pub ends: [[bool; 2]; D],
    /// Under the domain rule the centred moments `avg(S_n (x − x_p))` per axis and node,
    /// with which the move averages the reconstruction over the domain (else zero).
    pub mom: [[f64; N]; D],
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
        let (mut k, below, w) = self.weights::<NA, N>(x, half, &xi, Reads::ALL);
        k.ends = self.wall_ends::<NA>(&self.node_sides::<NA>(cell_node, below), &w);
        (k, self.node_indices::<NA, N>(cell_node, below))
    }

    /// A particle's weights, gradients and α, without the wall ends (`ends` left
    /// unset; the nodes' storage indices are the run's), per axis whether its first node
    /// lies one below its cell (GIMP only), and its 1D weights per axis (for
    /// [`Ctx::wall_ends`]). Hat functions take the local coordinate `xi` in the cell
    /// the tile pass found ([`Ctx::local`]), GIMP the position and half-width. Of the
    /// data besides the shape functions only those `reads` asks for are formed (the
    /// rest left zero). Particles sorted by cell share their nodes in runs: the
    /// particle loops look the nodes up once per run ([`Run`]).
    #[inline(always)]
    pub fn weights<const NA: usize, const N: usize>(
        &self,
        x: &Vector<D>,
        half: Option<&[f64; D]>,
        xi: &[f64; D],
        reads: Reads,
    ) -> (Kern<D, N>, [usize; D], [[f64; 3]; D]) {
        // Three nodes per axis is GIMP or the domain rule, two hat functions
        // (`by_nodes!`): decided at compile time, so a hat loop carries neither.
        debug_assert_eq!(NA == 3, self.wide);
        if NA == 3 && self.domain {
            return self.domain_weights(x, half, xi, reads);
        }
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
            at_point: [0.0; N],
            avg_w: [0.0; N],
            frac: [0.0; D],
            ends: [[false; 2]; D],
            mom: [[0.0; N]; D],
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
                if !reads.gradients {
                    break;
                }
                let mut p = w.dw[d][o[d]];
                for e in 0..D {
                    if e != d {
                        p *= w.w[e][o[e]];
                    }
                }
                k.g[d][n] = p;
            }
            k.s[n] = s;
            k.at_point[n] = s;
            k.avg_w[n] = (1.0 - k.alpha) * s;
        }
        (k, below, w.w)
    }

    /// [`Ctx::weights`] under the domain rule, over the 3 nodes per axis of
    /// [`shape::domain`]'s window: the averages over the particle's domain of the
    /// shape functions in `s`, of the gradient's α-part in `g` (so `alpha` is 1) and
    /// of the averages' weights in `avg_w`; the hat functions at the particle in
    /// `at_point`. `half` is the domain's half-widths ([`Ctx::half_width`]).
    #[inline(always)]
    fn domain_weights<const N: usize>(
        &self,
        x: &Vector<D>,
        half: Option<&[f64; D]>,
        xi: &[f64; D],
        reads: Reads,
    ) -> (Kern<D, N>, [usize; D], [[f64; 3]; D]) {
        let xa: [f64; D] = std::array::from_fn(|a| x[a]);
        let half = half.expect("the domain's half-widths");
        let d = shape::domain(self.geom, &xa, half, reads);
        let below: [usize; D] = std::array::from_fn(|a| (d.cell[a] - d.base[a]) as usize);
        let mut k = Kern {
            s: [0.0; N],
            at_point: [0.0; N],
            g: [[0.0; N]; D],
            alpha: 1.0,
            avg_w: [0.0; N],
            frac: *xi,
            ends: [[false; 2]; D],
            mom: [[0.0; N]; D],
        };
        for n in 0..N {
            let mut r = n;
            let o: [usize; D] = std::array::from_fn(|_| {
                let o = r % 3;
                r /= 3;
                o
            });
            let (s, at_point) = d.node(&o);
            k.s[n] = s;
            k.at_point[n] = at_point;
            if reads.gradients {
                let (g, c) = d.gradient(&o, s);
                for b in 0..D {
                    k.g[b][n] = g[b];
                }
                k.avg_w[n] = c;
            }
            if reads.moments {
                let m = d.moments(&o);
                for b in 0..D {
                    k.mom[b][n] = m[b];
                }
            }
        }
        (k, below, d.w)
    }

    /// The half-widths of particle `p`'s domain where its shape functions have one:
    /// GIMP's fixed ones, or the domain rule's current `l0 |F e_a|` from the reference
    /// ones `half` and the deformation gradients `f` (the reference ones where the
    /// particles carry no `F`).
    #[inline(always)]
    pub fn half_width(&self, half: &[[f64; D]], f: &[Mat<D>], p: usize) -> Option<[f64; D]> {
        if !self.wide {
            return None;
        }
        let l0 = half[p];
        Some(match f.get(p) {
            Some(f) if self.domain => std::array::from_fn(|a| l0[a] * f.column(a).norm()),
            _ => l0,
        })
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
            // spares the bounds check. A wrong slot gives a wrong node: the record's
            // bounds are always checked, but under the scatter's colouring a wrong
            // in-bounds node could be one another task writes, so the slot must be
            // right (the tile pass's cell, which `SlabIndex::slab` holds in the block).
            *i = match nb {
                None => first.wrapping_add(within),
                Some(nb) => nb[t & (NEIGHBOURS - 1)] + off,
            };
        }
        idx
    }

    /// The storage index of the first of a particle's nodes ([`Ctx::node_indices`]'s
    /// first), whose cell's lower corner is stored at `cell_node` and whose window starts
    /// `below[a]` cells under it: the key of a run of particles that share their nodes
    /// (the storage map is injective, so equal first nodes are equal windows).
    #[inline(always)]
    pub fn first_node(&self, cell_node: u32, below: [usize; D]) -> usize {
        let cn = cell_node as usize;
        let mut t = 0;
        let mut off = 0;
        let mut within = true;
        let mut pow = 1;
        for a in 0..D {
            let r = (cn >> (TILE_LOG * a as u32)) & (TILE - 1);
            let m = r + TILE - below[a];
            within &= m >= TILE;
            t += (m >> TILE_LOG) * pow;
            off |= (m & (TILE - 1)) << (TILE_LOG * a as u32);
            pow *= 3;
        }
        if within {
            let mut first = cn;
            for (a, &b) in below.iter().enumerate() {
                first -= b << (TILE_LOG * a as u32);
            }
            first
        } else {
            let nb = self.tiles.neighbours(cn / Tiles::<D>::TILE_NODES);
            nb[t & (NEIGHBOURS - 1)] + off
        }
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
        let (k0, k1) = split(self.tile, mid);
        let (a0, a1) = split(self.accel, mid);
        (
            Slices {
                parts: p0,
                tile: k0,
                accel: a0,
            },
            Slices {
                parts: p1,
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
    /// The step: positions and deformation advance over it.
    pub dt: f64,
    /// The velocity's step ([`crate::mpm::Solver::kick`]): external work is the
    /// external force's impulse over it.
    pub kick: f64,
    pub flip: f64,
    /// Also update deformation and stress from velocity slot 1.
    pub stress: bool,
    /// Move particles now; under MUSL the stress pass moves them.
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
    /// Move the particles with the velocity of slot `slot` (MUSL, whose gather ran
    /// before the remap): a two-step scheme's reconstruction ([`moving_velocity`]), a
    /// one-step scheme's grid interpolation. It is the velocity whose gradient deforms
    /// them in the same pass, so that neighbours part only as their `F` says.
    pub moves: bool,
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

    // `each` walks chunk `c`'s particles once, in order, the same every call.
    impl SlabRuns for CellSlabs<'_> {
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
        let mut o = SlabOrder::new();
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
                assert_eq!(o.order(), &expect[..], "{n} particles, {threads} threads");
                assert_eq!(o.slabs(), (hi - lo).div_ceil(thick));
                for s in 0..o.slabs() {
                    for &p in o.slab(s) {
                        assert_eq!(ix.slab(cells[p as usize]) as usize, s);
                    }
                }
                assert_eq!((0..o.slabs()).map(|s| o.slab(s).len()).sum::<usize>(), n);
            }
        }
    }

    /// A slab order of one-cell slabs holding `sizes[s]` particles each.
    fn with_sizes(sizes: &[usize]) -> SlabOrder {
        let cells: Vec<i64> = (0..sizes.len())
            .flat_map(|s| std::iter::repeat_n(s as i64, sizes[s]))
            .collect();
        let mut o = SlabOrder::new();
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
