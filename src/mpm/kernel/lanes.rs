//! The arithmetic of the grid → particle passes (the stress pass, the gather and
//! MUSL's remap), written once for `B` particles of a run at a time: [`LANES`],
//! [`HALF`] or [`QUARTER`] where as many in a row share their nodes, 1 otherwise.
//!
//! Why lanes: one particle's update is a chain of small matrix products (weights,
//! velocity gradient, `F ← (I + L dt) F`, the move) that the compiler can only
//! vectorise within the particle. The particles of one run share their nodes, so their
//! node data are common and every operation is the same on each of them: over `B`
//! particles, each line below is one operation on `B` independent numbers, a vector
//! operation where `B` > 1 and plain scalar code where `B` = 1.
//!
//! Width does not change results: each lane does its particle's arithmetic in the same
//! order with the same roundings (no fused multiply-adds: Rust never contracts), and
//! what is summed over particles (the external work, the momentum) is added particle
//! by particle in order. What only some particles need (a material that stores its
//! stress, a wall's clip, GIMP's weights) is done lane by lane, so a batch is the same
//! bits as its particles taken one at a time; the tests below hold every width to
//! width 1.

use super::{pair, Alpha, Ctx, Kern, NodeData, Run, Slices, FROM_MOMENTUM, UPDATED};
use crate::input::scene::Face;
use crate::physics::material::{Internal, VolumeChange};
use crate::physics::tensor::{det, Mat, Vector};
use std::ops::Range;

/// Particles per batch: eight f64 fill an AVX-512 register (two AVX2 ones). Where a
/// run is shorter (2 × 2 particles per cell: runs of 4), batches of [`HALF`].
pub const LANES: usize = 8;
/// The short batch: half a register.
pub const HALF: usize = 4;
/// How many particles past a batch's last its `F` is prefetched.
const AHEAD: usize = 16;
/// The shortest: a quarter. Where particles cross cells (the vortex between its
/// sorts), runs of 2 and 3 are common; one at a time, they were the dearer half of the
/// stress pass.
pub const QUARTER: usize = 2;

/// Whether the stress pass and the gather take a run's particles several at a time:
/// with hat functions (with 3 nodes per axis, particles of one cell need not share their
/// nodes),
/// and not in 3D where the build has AVX-512. In 3D a batch's numbers do not fit the
/// registers (24 shape-gradient terms and nine-entry matrices per lane) and part of
/// them live on the stack, L1: the 3D block drop's stress pass took 0.56× the time of
/// one particle at a time; with AVX-512, LLVM vectorises the three-long loops over the
/// axes with gathers and scatters, and the 3D lanes ran 1.3× slower.
#[inline(always)]
pub fn batches<const D: usize>(wide: bool) -> bool {
    !(wide || D == 3 && cfg!(target_feature = "avx512f"))
}

/// Whether the lanes' marks ([`unphysical`], summed over any number of batches) say
/// that every state they mark is physical.
#[inline(always)]
pub fn physical<const B: usize>(marks: &[f64; B]) -> bool {
    marks.iter().sum::<f64>() == 0.0
}

/// The weights of `B` particles that share their nodes, lane by lane, and for a
/// two-step scheme their interpolated nodal `L̄` ([`Weights::lbar`]).
pub(crate) struct Weights<const D: usize, const N: usize, const B: usize> {
    /// Per axis the particle's place in its cell towards the upper node (hat
    /// functions and the domain rule: ξ; GIMP: 0, as [`Kern::frac`]).
    frac: [[f64; B]; D],
    /// With 3 nodes per axis, where the window starts below the cell ([`Kern::frac`]).
    below: [usize; D],
    sh: [[f64; B]; N],
    /// With 3 nodes per axis, the weights of the nodes' averages ([`Kern::avg_w`]);
    /// with hat functions they are `(1 − α) S` and not stored.
    cw: [[f64; B]; N],
    /// With 3 nodes per axis, the hat functions at the particle ([`Kern::at_point`], the
    /// move's blend at a wall);
    /// with hat functions they are `sh`.
    sp: [[f64; B]; N],
    /// With hat functions `g[d][n]` is written and read only where node `n` is the
    /// upper one of its pair along `d` ([`pair`]): a hat's derivative at the lower
    /// node is minus the upper one's, and the pair enters the gradient as the
    /// velocity's difference ([`NodeData::dv`]).
    g: [[[f64; B]; N]; D],
    alpha: [f64; B],
    /// Per lane the walls whose nodes it gives weight to ([`Kern::ends`]).
    ends: [[[bool; 2]; D]; B],
    /// Whether the run's nodes touch a wall: else `ends` are all false.
    at_wall: bool,
    /// `Σ_n S_n L̄_n` with the shape functions (under the domain rule their averages),
    /// and per column `c` `Σ_n S_n o_c(n) L̄_n` (`o_c` the node's offset from the
    /// particle's cell corner in cells), for the reconstruction
    /// ([`Weights::moving_velocity`]).
    all: [[[f64; B]; D]; D],
    upper: [[[f64; B]; D]; D],
    /// The averages' part of the particle's velocity gradient, `Σ_n c_n L̄_n` with the
    /// weights `c_n` of [`Kern::avg_w`].
    lgrad: [[[f64; B]; D]; D],
    /// Under the domain rule, `avg(S_n (x − x_p))` per axis and node ([`Kern::mom`]) and
    /// the move's term `Σ_n L̄_n avg(S_n (x − x_p))` ([`Weights::lbar`]).
    mom: [[[f64; B]; N]; D],
    lmom: [[f64; B]; D],
}

/// A set of weights of each width, zeroed once for a task's particles and filled again
/// by each batch of a pass: zeroed per batch, it was a `memset` of 3.4 kB for every
/// eight particles, 3 % of the 3D step. Every fill writes what the pass reads (of the
/// hat gradients, every entry that is read), and `L̄` in a two-step pass and never
/// otherwise, where it stays zero as a fresh set's. One room serves one pass.
pub(crate) struct Room<const D: usize, const N: usize> {
    pub(crate) lanes: Weights<D, N, LANES>,
    pub(crate) half: Weights<D, N, HALF>,
    pub(crate) quarter: Weights<D, N, QUARTER>,
    pub(crate) one: Weights<D, N, 1>,
}

impl<const D: usize, const N: usize> Room<D, N> {
    #[inline(always)]
    pub fn new() -> Self {
        Room {
            lanes: Weights::zeroed(),
            half: Weights::zeroed(),
            quarter: Weights::zeroed(),
            one: Weights::zeroed(),
        }
    }
}

/// The local coordinates ([`Ctx::local`]) of particles `r` of `x`, all in `cell`.
#[inline(always)]
pub(crate) fn local<const D: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    x: &[Vector<D>],
    r: Range<usize>,
    cell: &[f64; D],
) -> [[f64; B]; D] {
    // A fixed-size view of the batch: indices below B need no bounds checks, so the
    // loads are whole vectors.
    let xs: &[Vector<D>; B] = x[r].try_into().expect("a full batch");
    let mut xi = [[0.0; B]; D];
    for a in 0..D {
        let (lower, inv_h, c) = (ctx.geom.lower[a], ctx.geom.inv_h[a], cell[a]);
        for l in 0..B {
            xi[a][l] = (xs[l][a] - lower) * inv_h - c;
        }
    }
    xi
}

/// α of the particles at local coordinates `xi` (hat functions).
#[inline(always)]
fn alpha<const D: usize, const B: usize>(ctx: &Ctx<'_, D>, xi: &[[f64; B]; D]) -> [f64; B] {
    match ctx.alpha {
        // `shape::bubble`: Π_a 4 ξ_a (1 − ξ_a).
        Alpha::ProductOfShapes => {
            let mut b = [1.0; B];
            for xa in xi {
                for l in 0..B {
                    b[l] *= 4.0 * xa[l] * (1.0 - xa[l]);
                }
            }
            b
        }
        Alpha::Constant(c) => [c; B],
    }
}

impl<const D: usize, const N: usize, const B: usize> Weights<D, N, B> {
    /// All zero, for the fills.
    #[inline(always)]
    fn zeroed() -> Self {
        Weights {
            frac: [[0.0; B]; D],
            below: [0; D],
            sh: [[0.0; B]; N],
            cw: [[0.0; B]; N],
            sp: [[0.0; B]; N],
            g: [[[0.0; B]; N]; D],
            alpha: [0.0; B],
            ends: [[[false; 2]; D]; B],
            at_wall: false,
            all: [[[0.0; B]; D]; D],
            upper: [[[0.0; B]; D]; D],
            lgrad: [[[0.0; B]; D]; D],
            mom: [[[0.0; B]; N]; D],
            lmom: [[0.0; B]; D],
        }
    }

    /// Hat functions ([`Ctx::weights`]) of particles with local coordinates `xi` in
    /// the cell of `run`: shape functions and the walls they touch, and if
    /// `gradients` (for a velocity gradient) α and the shape functions' gradients at
    /// the upper node of each pair ([`Weights::g`]; the other entries are left as
    /// they were).
    #[inline(always)]
    pub fn hats<const NA: usize>(
        &mut self,
        ctx: &Ctx<'_, D>,
        xi: &[[f64; B]; D],
        run: &Run<D, NA, N>,
        gradients: bool,
    ) {
        // `shape::hat`: weights 1 − ξ and ξ, derivatives ∓ 1/h.
        let mut w = [[[0.0; B]; 2]; D];
        let mut dw = [[0.0; 2]; D];
        for a in 0..D {
            for l in 0..B {
                w[a][0][l] = 1.0 - xi[a][l];
            }
            w[a][1] = xi[a];
            dw[a] = [-ctx.geom.inv_h[a], ctx.geom.inv_h[a]];
        }
        self.frac = *xi;
        if gradients {
            self.alpha = alpha::<D, B>(ctx, xi);
        }
        for n in 0..N {
            let mut o = [0; D];
            for (a, o) in o.iter_mut().enumerate() {
                *o = (n >> a) & 1;
            }
            let mut sn = [1.0; B];
            for a in 0..D {
                for l in 0..B {
                    sn[l] *= w[a][o[a]][l];
                }
            }
            self.sh[n] = sn;
            if !gradients {
                continue;
            }
            for d in 0..D {
                // The gradient's entries at the lower node of a pair along `d` are never
                // read (see `g`'s docs): half the products and stores of the 3D batch's
                // gradients.
                if o[d] == 0 {
                    continue;
                }
                let mut p = [dw[d][o[d]]; B];
                for e in 0..D {
                    if e != d {
                        for l in 0..B {
                            p[l] *= w[e][o[e]][l];
                        }
                    }
                }
                self.g[d][n] = p;
            }
        }
        self.at_wall = run.at_wall();
        if self.at_wall {
            for l in 0..B {
                let mut wl = [[0.0; 3]; D];
                for a in 0..D {
                    wl[a] = [w[a][0][l], w[a][1][l], 0.0];
                }
                self.ends[l] = run.ends(ctx, &wl);
            }
        } else {
            self.ends = [[[false; 2]; D]; B];
        }
    }

    /// The interpolated nodal `L̄` of a two-step scheme ([`super::NodeData::lb`]) at
    /// the particles, over all nodes and over the upper side per column, each summed
    /// in node order, and the averages' part of the velocity gradient (hat functions:
    /// `(1 − α) Σ_n S_n L̄_n`, none where α = 1).
    #[inline(always)]
    pub fn lbar(&mut self, nd: &NodeData<D, N>) {
        if !super::hats::<D, N>() {
            return self.lbar_wide(nd);
        }
        for a in 0..D {
            for c in 0..D {
                let mut lo = [0.0; B];
                let mut hi = [0.0; B];
                for n in 0..N {
                    let v = nd.lb[a][c][n];
                    if (n >> c) & 1 == 1 {
                        for l in 0..B {
                            hi[l] += self.sh[n][l] * v;
                        }
                    } else {
                        for l in 0..B {
                            lo[l] += self.sh[n][l] * v;
                        }
                    }
                }
                for l in 0..B {
                    self.all[a][c][l] = lo[l] + hi[l];
                    let blended = (1.0 - self.alpha[l]) * self.all[a][c][l];
                    self.lgrad[a][c][l] = if self.alpha[l] != 1.0 { blended } else { 0.0 };
                }
                self.upper[a][c] = hi;
            }
        }
    }

    /// [`Weights::lbar`] with 3 nodes per axis (the domain rule), nodes numbered in
    /// base 3 from the window's first, `below` cells under the particle's cell corner;
    /// with the move's moment term ([`Weights::moving_velocity`]).
    #[inline(always)]
    fn lbar_wide(&mut self, nd: &NodeData<D, N>) {
        for a in 0..D {
            for c in 0..D {
                let (mut all, mut up, mut lg) = ([0.0; B], [0.0; B], [0.0; B]);
                let step = 3usize.pow(c as u32);
                if c == 0 {
                    self.lmom[a] = [0.0; B];
                }
                for n in 0..N {
                    let v = nd.lb[a][c][n];
                    let o = ((n / step) % 3) as f64 - self.below[c] as f64;
                    for l in 0..B {
                        all[l] += self.sh[n][l] * v;
                        up[l] += self.sh[n][l] * o * v;
                        lg[l] += self.cw[n][l] * v;
                        self.lmom[a][l] += self.mom[c][n][l] * v;
                    }
                }
                self.all[a][c] = all;
                self.upper[a][c] = up;
                self.lgrad[a][c] = lg;
            }
        }
    }

    /// `Σ_n S_n v_n` of the updated slot and `Σ_n S_n (v_n − v_n^old)` over the
    /// nodes `nd`, node by node in order.
    #[allow(clippy::type_complexity)]
    #[inline(always)]
    pub fn interpolate(&self, nd: &NodeData<D, N>) -> ([[f64; B]; D], [[f64; B]; D]) {
        let mut vn = [[0.0; B]; D];
        let mut dv = [[0.0; B]; D];
        for n in 0..N {
            for a in 0..D {
                let (v0, v1) = (nd.v[FROM_MOMENTUM][a][n], nd.v[UPDATED][a][n]);
                let d = v1 - v0;
                for l in 0..B {
                    vn[a][l] += self.sh[n][l] * v1;
                    dv[a][l] += self.sh[n][l] * d;
                }
            }
        }
        (vn, dv)
    }

    /// The grid velocity of slot `slot` at the particles, `Σ_n S_n v_n`.
    #[inline(always)]
    pub fn velocity_at(&self, nd: &NodeData<D, N>, slot: usize) -> [[f64; B]; D] {
        let mut u = [[0.0; B]; D];
        for n in 0..N {
            for a in 0..D {
                let v = nd.v[slot][a][n];
                for l in 0..B {
                    u[a][l] += self.sh[n][l] * v;
                }
            }
        }
        u
    }

    /// `Σ_n S_n x_n` added to `u`: XPIC's field `nd.x` at the particles.
    #[inline(always)]
    pub fn add_field(&self, nd: &NodeData<D, N>, u: &mut [[f64; B]; D]) {
        for n in 0..N {
            for a in 0..D {
                let x = nd.x[a][n];
                for l in 0..B {
                    u[a][l] += self.sh[n][l] * x;
                }
            }
        }
    }

    /// The velocity gradient from velocity slot `slot` (with hat functions from its
    /// differences `nd.dv`, loaded for that slot), times α, plus the averages' part
    /// ([`Weights::lbar`]) for a two-step scheme.
    #[inline(always)]
    pub fn velocity_gradient(
        &self,
        nd: &NodeData<D, N>,
        slot: usize,
        two: bool,
    ) -> [[[f64; B]; D]; D] {
        let alpha = &self.alpha;
        let mut lg = [[[0.0; B]; D]; D];
        for a in 0..D {
            for b in 0..D {
                let mut x = [0.0; B];
                if super::hats::<D, N>() {
                    for m in 0..N / 2 {
                        let c = nd.dv[a][b][m];
                        let gb = &self.g[b][pair(b, m).1];
                        for l in 0..B {
                            x[l] += c * gb[l];
                        }
                    }
                } else {
                    for n in 0..N {
                        let c = nd.v[slot][a][n];
                        for l in 0..B {
                            x[l] += c * self.g[b][n][l];
                        }
                    }
                }
                // Both sides formed, then chosen: a select per lane, not a branch.
                for l in 0..B {
                    let ax = alpha[l] * x[l];
                    lg[a][b][l] = if alpha[l] != 0.0 { ax } else { 0.0 };
                }
                if two {
                    for l in 0..B {
                        lg[a][b][l] += self.lgrad[a][b][l];
                    }
                }
            }
        }
        lg
    }

    /// The velocity two-step schemes move the particles with: the nodal linear
    /// reconstructions `v̄_j + L̄_j (x − x_j)` blended by the shape functions,
    /// `u(x) = Σ_j S_j(x) (v̄_j + L̄_j (x − x_j))`. Exact for linear velocity fields, like
    /// the grid interpolation `Σ_i S_i v_i`, but built from the same nodal averages as the
    /// particle's velocity gradient, so the particles separate only as fast as their
    /// deformation gradients register (README, "The schemes"). Under the domain rule the
    /// reconstruction's average over the particle's domain,
    /// `Σ_j avg(S_j) (v̄_j + L̄_j (x_p − x_j)) + L̄_j avg(S_j (x − x_p))`, as its gradient is
    /// averaged over that domain (at one point the clamped beams tore where the domain is
    /// cut at the clamp, docs/hard-cases.md). Next to a wall the
    /// reconstruction of an interior node, carried to the wall by `L̄_j`, need not vanish
    /// on it, while the grid velocity of slot `slot` does (the wall's nodes are held): the
    /// velocity blends from `u` to the grid interpolation `Σ_i S_i v_i` with the particle's
    /// shape weight on the wall's nodes, all components at a fixed wall, the normal one at
    /// a slip wall. Still continuous and exact for linear fields that satisfy the walls; on
    /// the wall it is the grid's. (Unblended, particles squeezed into a cantilever's clamp
    /// corner left the grid through the clamp, and the clamped beam slid off the clamp.)
    /// `nd` holds the particles' nodes' data.
    #[inline(always)]
    pub fn moving_velocity(
        &self,
        ctx: &Ctx<'_, D>,
        nd: &NodeData<D, N>,
        slot: usize,
    ) -> [[f64; B]; D] {
        let h = &ctx.geom.h;
        // The shape functions: at the particle, or under the domain rule their averages.
        let sp = &self.sh;
        let mut u = if super::hats::<D, N>() {
            [[0.0; B]; D]
        } else {
            self.lmom
        };
        for a in 0..D {
            for n in 0..N {
                let c = nd.vb[a][n];
                for l in 0..B {
                    u[a][l] += sp[n][l] * c;
                }
            }
            for b in 0..D {
                for l in 0..B {
                    u[a][l] += (self.all[a][b][l] * self.frac[b][l] - self.upper[a][b][l]) * h[b];
                }
            }
        }
        if self.at_wall {
            for l in 0..B {
                self.blend_at_walls(ctx, nd, slot, l, &mut u);
            }
        }
        u
    }

    /// [`Weights::moving_velocity`]'s blend at the walls for lane `l`: a particle on a
    /// wall's face moves with the grid, which the walls hold.
    #[inline(always)]
    fn blend_at_walls(
        &self,
        ctx: &Ctx<'_, D>,
        nd: &NodeData<D, N>,
        slot: usize,
        l: usize,
        u: &mut [[f64; B]; D],
    ) {
        if !self.touches_wall(l) {
            return;
        }
        let ends = &self.ends[l];
        let mut keep_fixed = 1.0;
        let mut keep = [1.0; D];
        for a in 0..D {
            for side in 0..2 {
                if !ends[a][side] {
                    continue;
                }
                let frac = self.frac[a][l];
                let on_face = if side == 0 { 1.0 - frac } else { frac };
                match ctx.faces[a][side] {
                    Face::Fixed => keep_fixed *= 1.0 - on_face,
                    Face::Slip => keep[a] *= 1.0 - on_face,
                    Face::Free | Face::Periodic => {}
                }
            }
        }
        for a in 0..D {
            let c = keep_fixed * keep[a];
            if c < 1.0 {
                let mut vn = 0.0;
                for n in 0..N {
                    vn += self.at_point()[n][l] * nd.v[slot][a][n];
                }
                u[a][l] = c * u[a][l] + (1.0 - c) * vn;
            }
        }
    }

    /// The shape functions, node by node, lane by lane.
    #[inline(always)]
    pub fn shape(&self) -> &[[f64; B]; N] {
        &self.sh
    }

    /// The hat functions at the particles ([`Kern::at_point`]).
    #[inline(always)]
    fn at_point(&self) -> &[[f64; B]; N] {
        if super::hats::<D, N>() {
            &self.sh
        } else {
            &self.sp
        }
    }

    /// Whether the run's nodes touch a wall.
    #[inline(always)]
    pub fn at_wall(&self) -> bool {
        self.at_wall
    }

    /// Whether lane `l` gives weight to a wall's nodes.
    #[inline(always)]
    pub fn touches_wall(&self, l: usize) -> bool {
        self.ends[l].iter().flatten().any(|&e| e)
    }

    /// Lane `l`'s velocity `v` clipped at the slip walls it touches to `vm`, the
    /// velocity it moves with ([`clip_at_slip_walls`]); returns the wall's work,
    /// exactly 0 away from walls.
    #[inline(always)]
    pub fn clip(
        &self,
        ctx: &Ctx<'_, D>,
        l: usize,
        v: &mut Vector<D>,
        vm: &Vector<D>,
        mass: f64,
    ) -> f64 {
        clip_at_slip_walls(ctx, &self.ends[l], v, vm, mass)
    }

    /// Deform particles `r` of `s` by the velocity gradient `lg` over `dt`: the
    /// increment I + L dt, its determinant J, the volume, F ← (I + L dt) F and, for a
    /// material that stores its stress, the stress update lane by lane. Returns the
    /// lanes' marks of an unphysical state ([`unphysical`]).
    #[inline(always)]
    pub fn deform(
        &self,
        ctx: &Ctx<'_, D>,
        s: &mut Slices<'_, D>,
        r: Range<usize>,
        lg: &[[[f64; B]; D]; D],
        dt: f64,
    ) -> [f64; B] {
        let mut inc = [[[0.0; B]; D]; D];
        for i in 0..D {
            for k in 0..D {
                let id = if i == k { 1.0 } else { 0.0 };
                for l in 0..B {
                    inc[i][k][l] = id + lg[i][k][l] * dt;
                }
            }
        }
        let j = det_lanes(&inc);
        let mut fnew = [[[0.0; B]; D]; D];
        let carries_f = !s.parts.def_grad.is_empty();
        match carries_f.then(|| &s.parts.def_grad[r.clone()]) {
            // Particles without `F` (a material that needs none) deform with F = I.
            None => {
                for (i, row) in fnew.iter_mut().enumerate() {
                    row[i] = [1.0; B];
                }
            }
            Some(fs) => {
                // `F`, the widest array the pass streams (72 bytes a particle in 3D),
                // asked for ahead: its loads here waited on memory (a sixth of the 3D
                // stress pass). (Past the array's end only addresses are formed: a
                // prefetch never faults.)
                super::prefetch(s.parts.def_grad, r.end + AHEAD - B, B);
                let fs: &[Mat<D>; B] = fs.try_into().expect("a full batch");
                let mut f = [[[0.0; B]; D]; D];
                for l in 0..B {
                    for k in 0..D {
                        for c in 0..D {
                            f[k][c][l] = fs[l][(k, c)];
                        }
                    }
                }
                for i in 0..D {
                    for c in 0..D {
                        // nalgebra's product: the sum over k in order.
                        let mut x = [0.0; B];
                        for l in 0..B {
                            x[l] = inc[i][0][l] * f[0][c][l];
                        }
                        for k in 1..D {
                            for l in 0..B {
                                x[l] += inc[i][k][l] * f[k][c][l];
                            }
                        }
                        fnew[i][c] = x;
                    }
                }
            }
        }
        // Where the particles carry `F`, their volume is `det F · V₀`: not stored.
        let mut vol = [0.0; B];
        if let Some(Ok(vs)) = s
            .parts
            .vol
            .get_mut(r.clone())
            .map(<&mut [f64; B]>::try_from)
        {
            for l in 0..B {
                vol[l] = vs[l] * j[l];
            }
            *vs = vol;
        }
        // The marks before `F` is stored: the new `F` is still in registers. (The
        // stress, where a material stores it, follows F; for the materials that do
        // not store it (neo-Hookean) it is finite where F is and J > 0.)
        let stored = !s.parts.stress.is_empty();
        let mut bad =
            unphysical::<D, B>(&j, &vol, if stored { &[[[0.0; B]; D]; D] } else { &fnew });
        if carries_f {
            let fs: &mut [Mat<D>; B] = (&mut s.parts.def_grad[r.clone()])
                .try_into()
                .expect("a full batch");
            for l in 0..B {
                for i in 0..D {
                    for c in 0..D {
                        fs[l][(i, c)] = fnew[i][c][l];
                    }
                }
            }
        }
        if stored {
            for (l, p) in r.enumerate() {
                bad[l] += update_stress(ctx, s, p, lane(lg, l), lane(&fnew, l), j[l], dt);
            }
        }
        bad
    }
}

/// Lane `l` of a matrix held lane by lane.
#[inline(always)]
pub(crate) fn lane<const D: usize, const B: usize>(m: &[[[f64; B]; D]; D], l: usize) -> Mat<D> {
    Mat::<D>::from_fn(|i, k| m[i][k][l])
}

/// Lane `l` of a vector held lane by lane.
#[inline(always)]
pub(crate) fn column<const D: usize, const B: usize>(v: &[[f64; B]; D], l: usize) -> Vector<D> {
    Vector::<D>::from_fn(|a, _| v[a][l])
}

/// The stress update of particle `p` of `s`, whose material stores its stress, by the
/// velocity gradient `l` at the deformation gradient `f`, over `dt`, in which its
/// volume changed by `j_step`: a mark that is ±0 where the new stress is finite, else
/// NaN ([`unphysical`]).
#[inline(always)]
fn update_stress<const D: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p: usize,
    l: Mat<D>,
    f: Mat<D>,
    j_step: f64,
    dt: f64,
) -> f64 {
    let internal = Internal {
        plastic: s.parts.be.get_mut(p).zip(s.parts.eps_p.get_mut(p)),
        damage: s.parts.damage.get_mut(p),
        stress_zz: s.parts.stress_zz.get_mut(p),
    };
    let kind = s.parts.kind[p] as usize;
    // The volume is stored (already updated) unless the particles carry `F`.
    let total = match s.parts.vol.get(p) {
        Some(v) => v / ctx.kind_vol0[kind],
        None => det(&f),
    };
    let j = VolumeChange {
        step: j_step,
        total,
    };
    ctx.materials[kind].update_stress(&mut s.parts.stress[p], &l, &f, dt, j, internal);
    s.parts.stress[p].iter().map(|x| x * 0.0).sum()
}

/// Per lane, a mark that is ±0 where J > 0 and the volume and `f` are finite, else
/// NaN: numbers, not bools, since `0·x` is ±0 for a finite x and NaN otherwise and a
/// lane with J <= 0 (or NaN) adds a NaN. Sums of marks stay ±0 exactly while every
/// state they mark is physical, so a pass adds each batch's marks into running ones
/// and tests them once ([`physical`]). (Per-lane bools went through the mask
/// registers bit by bit, a dozen moves and shifts per lane.)
#[inline(always)]
fn unphysical<const D: usize, const B: usize>(
    j: &[f64; B],
    vol: &[f64; B],
    f: &[[[f64; B]; D]; D],
) -> [f64; B] {
    let mut bad = [0.0; B];
    for l in 0..B {
        bad[l] = vol[l] * 0.0 + if j[l] > 0.0 { 0.0 } else { f64::NAN };
        for row in f {
            for x in row {
                bad[l] += x[l] * 0.0;
            }
        }
    }
    bad
}

/// `x += u dt` for particles `r` of `s`.
#[inline(always)]
pub(crate) fn advance<const D: usize, const B: usize>(
    s: &mut Slices<'_, D>,
    r: Range<usize>,
    u: &[[f64; B]; D],
    dt: f64,
) {
    let x: &mut [Vector<D>; B] = (&mut s.parts.x[r]).try_into().expect("a full batch");
    for a in 0..D {
        for l in 0..B {
            x[l][a] += u[a][l] * dt;
        }
    }
}

/// A particle that touches a slip wall's node (`ends`, [`Kern::ends`]) may move into
/// that wall no faster than the velocity it moves with, `vm` (which vanishes at the
/// wall): the normal component of its velocity `v` is clipped to `vm`'s. Returns the
/// kinetic energy the clip takes out (≤ 0), the wall's work.
#[inline(always)]
pub(crate) fn clip_at_slip_walls<const D: usize>(
    ctx: &Ctx<'_, D>,
    ends: &[[bool; 2]; D],
    v: &mut Vector<D>,
    vm: &Vector<D>,
    mass: f64,
) -> f64 {
    let free = *v;
    let mut at_wall = false;
    for a in 0..D {
        for side in 0..2 {
            if ends[a][side] && ctx.faces[a][side] == Face::Slip {
                at_wall = true;
                v[a] = if side == 0 {
                    v[a].max(vm[a])
                } else {
                    v[a].min(vm[a])
                };
            }
        }
    }
    // Away from walls no work, exactly (also for a velocity that is not finite).
    if !at_wall {
        return 0.0;
    }
    // The wall is an external force: its impulse m (new − free) does the work
    // m (new − free)·(new + free)/2 by the midpoint rule gravity's work uses, i.e. the
    // kinetic energy the clip takes out. A wall at rest does no work on the continuum;
    // this is what the discrete impact dissipates there, counted so that the balance
    // keeps measuring the integrator.
    0.5 * mass * (v.norm_squared() - free.norm_squared())
}

impl<const D: usize, const N: usize> Weights<D, N, 1> {
    /// One particle's weights `k` (any shape functions, GIMP's and the domain rule's
    /// included), whose window starts `below` cells under its cell.
    #[inline(always)]
    pub fn one(&mut self, k: &Kern<D, N>, at_wall: bool, below: [usize; D]) {
        for a in 0..D {
            self.frac[a] = [k.frac[a]];
        }
        self.below = below;
        for n in 0..N {
            self.sh[n] = [k.s[n]];
            self.sp[n] = [k.at_point[n]];
            self.cw[n] = [k.avg_w[n]];
            for d in 0..D {
                self.g[d][n] = [k.g[d][n]];
                self.mom[d][n] = [k.mom[d][n]];
            }
        }
        self.alpha = [k.alpha];
        self.ends = [k.ends];
        self.at_wall = at_wall;
    }
}

/// [`crate::physics::tensor::det`] lane by lane, term for term.
#[inline(always)]
fn det_lanes<const D: usize, const B: usize>(m: &[[[f64; B]; D]; D]) -> [f64; B] {
    let mut out = [0.0; B];
    for (l, out) in out.iter_mut().enumerate() {
        let e = |i: usize, k: usize| m[i][k][l];
        *out = match D {
            1 => e(0, 0),
            2 => e(0, 0) * e(1, 1) - e(0, 1) * e(1, 0),
            3 => {
                e(0, 0) * (e(1, 1) * e(2, 2) - e(1, 2) * e(2, 1))
                    - e(0, 1) * (e(1, 0) * e(2, 2) - e(1, 2) * e(2, 0))
                    + e(0, 2) * (e(1, 0) * e(2, 1) - e(1, 1) * e(2, 0))
            }
            _ => unreachable!("dimension is 1, 2 or 3"),
        };
    }
    out
}

/// The running maximum `max` of the signal speed raised by particles
/// `p0 .. p0 + B` of `s` ([`super::raise_speed`] for each in turn), with `lanes`:
/// [`fold`] of the two is the same maximum, bit for bit. Where the eight share a
/// material whose speed for J >= 1 needs no logarithm
/// ([`crate::physics::material::Material::stretched_wave_speed`]), the stretched
/// ones' speeds go as vector operations (a comparison, a choice and a maximum per
/// lane into `lanes`, which a pass keeps over all its batches and folds once), and
/// each compressed one, marked in a bit mask, through
/// [`crate::physics::material::Material::raise_signal_speed`] after them (its skip
/// test against the maximum so far, else its speed). The maximum of a set does not
/// depend on the order it is taken in, and a particle skipped against a maximum so
/// far cannot raise the final one, so this is the maximum the particle-by-particle
/// loop forms.
///
/// (A loop over the lanes that tested each lane's side of J = 1 and then skipped or
/// formed its speed stayed a loop of branches, one lane at a time: 4 % of the 2D
/// step. Folding the lanes at the end of every batch put a chain of maxima across
/// the lanes between each batch and the next.)
#[inline(always)]
pub fn raise_speed<const D: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    s: &Slices<'_, D>,
    p0: usize,
    max: f64,
    lanes: &mut [f64; B],
) -> f64 {
    let kind = s.parts.kind[p0];
    let material = &ctx.materials[kind as usize];
    let quick = match material.stretched_wave_speed() {
        Some(q) if s.parts.kind[p0 + 1..p0 + B].iter().all(|&k| k == kind) => q,
        _ => {
            return (p0..p0 + B).fold(max, |m, p| super::raise_speed(ctx, s, p, m));
        }
    };
    let r = p0..p0 + B;
    let vs: &[_; B] = s.parts.v[r.clone()].try_into().expect("a full batch");
    let mut j = [0.0; B];
    let mut v = [0.0; B];
    if s.parts.vol.is_empty() {
        let fs: &[Mat<D>; B] = s.parts.def_grad[r].try_into().expect("a full batch");
        for l in 0..B {
            j[l] = det(&fs[l]);
        }
    } else {
        let vol: &[f64; B] = s.parts.vol[r].try_into().expect("a full batch");
        let vol0 = ctx.kind_vol0[kind as usize];
        for l in 0..B {
            j[l] = vol[l] / vol0;
        }
    }
    for l in 0..B {
        v[l] = vs[l].norm();
    }
    let mut compressed = 0u32;
    for l in 0..B {
        // (A NaN counts as compressed: `raise_signal_speed` passes it over.)
        let stretched = j[l] >= 1.0;
        compressed |= u32::from(!stretched) << l;
        lanes[l] = lanes[l].max(if stretched {
            quick + v[l]
        } else {
            f64::NEG_INFINITY
        });
    }
    let mut top = max;
    if compressed != 0 {
        // The skip test passes over fewer particles against a smaller maximum: the
        // lanes' so far too.
        top = fold(top, lanes);
    }
    while compressed != 0 {
        let l = compressed.trailing_zeros() as usize;
        compressed &= compressed - 1;
        top = material.raise_signal_speed(j[l], v[l], top);
    }
    top
}

/// The larger of `max` and the largest of `lanes` ([`raise_speed`]'s): by halves, a
/// few vector operations, not a chain of eight. (`f64::max` passes a NaN over, as the
/// particle-by-particle maximum does.)
#[inline(always)]
pub fn fold<const B: usize>(max: f64, lanes: &[f64; B]) -> f64 {
    let mut c = *lanes;
    let mut width = B;
    while width > 1 {
        width /= 2;
        for l in 0..width {
            c[l] = c[l].max(c[l + width]);
        }
    }
    max.max(c[0])
}

#[cfg(test)]
mod tests {
    use super::super::gather::{hat_batch, Pass};
    use super::super::{
        raise_speed as speed_one, signal_speeds, GatherMode, Run, StressMode, Tally,
    };
    use super::*;
    use crate::mpm::particles::Particles;
    use crate::physics::material::brittle::Brittle;
    use crate::physics::material::j2_plastic::J2Plastic;
    use crate::physics::material::{lame, neo_hookean::NeoHookean, Material};
    use crate::physics::shape::Geom;
    use decomposition::splitmix::Rng;
    use decomposition::Tiles;
    use nalgebra::Matrix3;

    /// The reference volume (and mass: density 1) of [`Setup`]'s kind `k`, one kind
    /// per lane, so that the lanes' masses differ.
    fn kind_vol0(k: usize) -> f64 {
        1e-4 * (0.5 + (k as f64 + 0.5) / LANES as f64)
    }

    /// What the test particles are made of and what they carry.
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Law {
        /// Neo-Hookean: `F`, the stress formed from it; the volume stored or not.
        Hyper { vol: bool },
        /// Materials that store their stress (J2 plasticity and brittle damage, kind
        /// by kind), with `F` carried or not.
        Stored { f: bool },
    }

    const LAWS: [Law; 4] = [
        Law::Hyper { vol: true },
        Law::Hyper { vol: false },
        Law::Stored { f: true },
        Law::Stored { f: false },
    ];

    /// Eight particles of one cell with random local coordinates (among them ξ = 0
    /// on the first axis, where α = 0, and ξ = ½ on all axes, where α = 1),
    /// deformation gradients, volumes on both sides of J = 1, stresses, velocities
    /// and positions, of kind `l` in lane `l`; one lane with a non-finite F (or
    /// stress).
    fn particles<const D: usize>(
        rng: &mut Rng,
        law: Law,
        nan_lane: Option<usize>,
    ) -> (Particles<D>, [f64; D]) {
        let mut p = Particles::<D>::default();
        for l in 0..LANES {
            let mut c = [0.5; D];
            if l != 1 {
                c = std::array::from_fn(|_| rng.f64());
            }
            if l == 0 {
                c[0] = 0.0;
            }
            p.x.push(Vector::<D>::from_fn(|a, _| [0.3, 0.6, 0.4][a] + 0.1 * c[a]));
            p.v.push(Vector::<D>::from_fn(|_, _| rng.f64() - 0.5));
            let mut f =
                Mat::<D>::from_fn(|i, k| f64::from(u8::from(i == k)) + 0.2 * (rng.f64() - 0.5));
            let mut sigma = Mat::<D>::from_fn(|_, _| 0.1 * (rng.f64() - 0.5));
            sigma = (sigma + sigma.transpose()) * 0.5;
            if nan_lane == Some(l) {
                f[(1, 0)] = f64::NAN;
                sigma[(1, 0)] = f64::NAN;
            }
            match law {
                Law::Hyper { vol } => {
                    p.def_grad.push(f);
                    if vol {
                        p.vol.push(kind_vol0(l) * (0.85 + 0.3 * rng.f64()));
                    }
                }
                Law::Stored { f: with_f } => {
                    if with_f {
                        p.def_grad.push(f);
                    }
                    p.vol.push(kind_vol0(l) * (0.85 + 0.3 * rng.f64()));
                    p.stress.push(sigma);
                    p.be.push(Matrix3::identity() + Matrix3::from_fn(|_, _| 0.01 * rng.f64()));
                    p.eps_p.push(0.0);
                    p.damage.push(0.0);
                    p.stress_zz.push(0.0);
                }
            }
            p.kind.push(l as u16);
        }
        // Their cell (the grid's h is 0.1, [`Setup::new`]): `Ctx::local` gives the
        // lanes' ξ of 0 and ½ exactly.
        (p, std::array::from_fn(|a| [3.0, 6.0, 4.0][a]))
    }

    /// A material per kind of particle ([`kind_vol0`]) and law, a grid and the
    /// context of a pass.
    struct Setup<const D: usize> {
        geom: Geom<D>,
        tiles: Tiles<D>,
        hyper: Vec<Material>,
        stored: Vec<Material>,
        kind_vol0: Vec<f64>,
    }

    impl<const D: usize> Setup<D> {
        fn new() -> Self {
            let (lambda, mu) = lame(1e3, 0.2);
            let hyper = Material::NeoHookean(NeoHookean {
                lambda,
                mu,
                density: 1.0,
            });
            // Yield and tensile strength within the test's stresses, so that some
            // lanes yield or fail.
            let stored = (0..LANES)
                .map(|k| match k % 2 {
                    0 => Material::J2Plastic(J2Plastic {
                        lambda,
                        mu,
                        density: 1.0,
                        yield_stress: 0.05,
                        hardening: 1.0,
                    }),
                    _ => Material::Brittle(Brittle {
                        lambda,
                        mu,
                        density: 1.0,
                        tensile_strength: 0.05,
                    }),
                })
                .collect();
            Setup {
                geom: Geom::<D>::new([0.0; D], [1.0; D], [10; D], [false; D]),
                tiles: Tiles::<D>::new([12; D], [1; D]),
                hyper: vec![hyper; LANES],
                stored,
                kind_vol0: (0..LANES).map(kind_vol0).collect(),
            }
        }

        /// The context of a pass with gradient `alpha` over particles of `law`, with
        /// walls (slip across the first and third axes, fixed across the second) if
        /// `walls`.
        fn ctx(&self, alpha: Alpha, law: Law, walls: bool) -> Ctx<'_, D> {
            Ctx {
                geom: &self.geom,
                node_lo: [-1; D],
                tiles: &self.tiles,
                wide: false,
                domain: false,
                alpha,
                materials: match law {
                    Law::Hyper { .. } => &self.hyper,
                    Law::Stored { .. } => &self.stored,
                },
                kind_mass: &self.kind_vol0,
                kind_vol0: &self.kind_vol0,
                gravity: Vector::<D>::from_fn(|a, _| if a == 1 { -9.81 } else { 0.0 }),
                body_force: None,
                faces: std::array::from_fn(|a| [if a == 1 { Face::Fixed } else { Face::Slip }; 2]),
                walls,
            }
        }
    }

    /// The run of the test particles' cell: with walls, a slip wall at its lower
    /// nodes along the first axis and a fixed wall at its upper nodes along the
    /// second.
    fn run<const D: usize, const N: usize>(walls: bool) -> Run<D, 2, N> {
        Run::with_sides(std::array::from_fn(|a| match a {
            0 if walls => [-1, 0],
            1 if walls => [0, 1],
            _ => [0, 0],
        }))
    }

    const ALPHAS: [Alpha; 4] = [
        Alpha::ProductOfShapes,
        Alpha::Constant(0.0),
        Alpha::Constant(1.0),
        Alpha::Constant(0.3),
    ];

    /// Velocity gradient scale, starting maximum of the signal speed, lane with a
    /// non-finite F, batch width: gentle and steep (inverting) gradients, maxima
    /// below and above the particles' speeds, every width.
    const VARIANTS: [(f64, f64, Option<usize>, usize); 10] = [
        (1.0, 0.0, None, LANES),
        (1.0, 1e3, None, LANES),
        (1e5, 0.0, None, LANES),
        (1.0, 0.0, Some(5), LANES),
        (1.0, 0.0, None, HALF),
        (1e5, 0.0, None, HALF),
        (1.0, 0.0, Some(2), HALF),
        (1.0, 0.0, None, QUARTER),
        (1e5, 0.0, None, QUARTER),
        (1.0, 0.0, Some(1), QUARTER),
    ];

    /// Random node data of a run, velocities scaled by `steep`, with the
    /// differences of slot `slot` and an XPIC field.
    fn nodes<const D: usize, const N: usize>(
        rng: &mut Rng,
        steep: f64,
        slot: usize,
    ) -> NodeData<D, N> {
        let mut nd = NodeData::<D, N>::new();
        for a in 0..D {
            for n in 0..N {
                for slot in 0..2 {
                    nd.v[slot][a][n] = steep * (rng.f64() - 0.5);
                }
                nd.vb[a][n] = rng.f64() - 0.5;
                nd.x[a][n] = rng.f64() - 0.5;
                for b in 0..D {
                    nd.lb[a][b][n] = steep * (rng.f64() - 0.5);
                }
            }
        }
        nd.load_differences(slot);
        nd
    }

    /// A pass's view of the test particles `p` and its per-particle arrays.
    fn slices<'a, const D: usize>(
        p: &'a mut Particles<D>,
        tile: &'a [u32],
        accel: &'a [Vector<D>],
    ) -> Slices<'a, D> {
        Slices {
            parts: p.slices(),
            tile,
            accel,
        }
    }

    /// Particles `p .. p + width` of `s`, in `cell` of `run`, through `pass` as the
    /// pass's loop takes a batch of that width (`gather::hats`), with `room`, which
    /// may have served earlier batches of the same pass; the work into `work`, the
    /// lanes' marks into `marks`.
    #[allow(clippy::too_many_arguments)]
    fn batch<const D: usize, const N: usize>(
        ctx: &Ctx<'_, D>,
        s: &mut Slices<'_, D>,
        p: usize,
        width: usize,
        cell: &[f64; D],
        run: &Run<D, 2, N>,
        nd: &NodeData<D, N>,
        pass: Pass<'_>,
        room: &mut Room<D, N>,
        work: &mut f64,
        marks: &mut [f64; LANES],
    ) {
        match width {
            LANES => hat_batch(ctx, s, p, cell, run, nd, pass, &mut room.lanes, work, marks),
            HALF => hat_batch(ctx, s, p, cell, run, nd, pass, &mut room.half, work, marks),
            QUARTER => hat_batch(
                ctx,
                s,
                p,
                cell,
                run,
                nd,
                pass,
                &mut room.quarter,
                work,
                marks,
            ),
            _ => hat_batch(ctx, s, p, cell, run, nd, pass, &mut room.one, work, marks),
        }
    }

    /// Both particle sets hold the same bits.
    fn same_bits<const D: usize>(a: &Particles<D>, b: &Particles<D>, what: &str) {
        for p in 0..LANES {
            let bits = |v: &[f64]| v.get(p).map(|x| x.to_bits());
            assert_eq!(bits(&a.vol), bits(&b.vol), "vol {p}: {what}");
            assert_eq!(bits(&a.damage), bits(&b.damage), "damage {p}: {what}");
            assert_eq!(bits(&a.stress_zz), bits(&b.stress_zz), "σ_zz {p}: {what}");
            assert_eq!(bits(&a.eps_p), bits(&b.eps_p), "ε_p {p}: {what}");
            let mats = |m: &[Mat<D>]| m.get(p).map(|m| m.map(f64::to_bits));
            assert_eq!(mats(&a.def_grad), mats(&b.def_grad), "F {p}: {what}");
            assert_eq!(mats(&a.stress), mats(&b.stress), "σ {p}: {what}");
            let be = |m: &[Matrix3<f64>]| m.get(p).map(|m| m.map(f64::to_bits));
            assert_eq!(be(&a.be), be(&b.be), "b_e {p}: {what}");
            let vecs = [
                (a.x[p].as_slice(), b.x[p].as_slice(), "x"),
                (a.v[p].as_slice(), b.v[p].as_slice(), "v"),
            ];
            for (x, y, name) in vecs {
                for (x, y) in x.iter().zip(y) {
                    assert_eq!(x.to_bits(), y.to_bits(), "{name} {p}: {what}");
                }
            }
        }
    }

    /// What a comparison of widths covered: cases, states found unphysical without a
    /// NaN put in, and cases whose walls did work.
    #[derive(Default)]
    struct Cover {
        cases: usize,
        inverted: usize,
        clipped: usize,
    }

    /// Pass `pass` over `width` of the particles of `law` made from `rng` (a NaN in
    /// lane `nan_lane`), once as one batch and once one particle at a time, in one
    /// room each that earlier cases used (as `by_runs` keeps one per pass), and
    /// compare every bit: the particles' state, the external work, the physical-state
    /// flag and the signal speed's running maximum from `max0`.
    #[allow(clippy::too_many_arguments)]
    fn compare<const D: usize, const N: usize>(
        ctx: &Ctx<'_, D>,
        rng: &mut Rng,
        law: Law,
        walls: bool,
        (nd, max0, nan_lane, width): (&NodeData<D, N>, f64, Option<usize>, usize),
        pass: Pass<'_>,
        rooms: &mut (Room<D, N>, Room<D, N>),
        cover: &mut Cover,
        what: &str,
    ) {
        let (mut a, cell) = particles::<D>(rng, law, nan_lane);
        let mut b = a.clone();
        // A kept body force in half the cases, gravity alone in the others.
        let accel: Vec<Vector<D>> = if cover.cases.is_multiple_of(2) {
            (0..LANES)
                .map(|_| Vector::<D>::from_fn(|a, _| rng.f64() - if a == 1 { 10.0 } else { 0.0 }))
                .collect()
        } else {
            Vec::new()
        };
        let tile = vec![0u32; LANES];
        let run = run::<D, N>(walls);
        let work0 = 0.25;
        // One at a time.
        let mut sa = slices(&mut a, &tile, &accel);
        let (mut work_a, mut marks_a) = (work0, [0.0; LANES]);
        for p in 0..width {
            batch(
                ctx,
                &mut sa,
                p,
                1,
                &cell,
                &run,
                nd,
                pass,
                &mut rooms.0,
                &mut work_a,
                &mut marks_a,
            );
        }
        let top_a = (0..width).fold(max0, |v, p| speed_one(ctx, &sa, p, v));
        // A batch.
        let mut sb = slices(&mut b, &tile, &accel);
        let (mut work_b, mut marks_b) = (work0, [0.0; LANES]);
        batch(
            ctx,
            &mut sb,
            0,
            width,
            &cell,
            &run,
            nd,
            pass,
            &mut rooms.1,
            &mut work_b,
            &mut marks_b,
        );
        let mut per_lane = [f64::NEG_INFINITY; LANES];
        let top_b = match width {
            LANES => fold(
                raise_speed::<D, LANES>(ctx, &sb, 0, max0, &mut per_lane),
                &per_lane,
            ),
            _ => (0..width).fold(max0, |v, p| speed_one(ctx, &sb, p, v)),
        };
        let what = format!("{width} lanes, {law:?}, walls {walls}, NaN {nan_lane:?}, {what}");
        let ok = physical(&marks_a);
        assert_eq!(ok, physical(&marks_b), "{what}");
        assert_eq!(top_a.to_bits(), top_b.to_bits(), "speed: {what}");
        assert_eq!(work_a.to_bits(), work_b.to_bits(), "work: {what}");
        same_bits(&a, &b, &what);
        cover.cases += 1;
        cover.inverted += usize::from(!ok && nan_lane.is_none());
        let gravity_only = accel.is_empty() && matches!(pass, Pass::Stress(_));
        cover.clipped += usize::from(walls && gravity_only && work_a != work0);
    }

    /// The stress pass gives the same bits whatever the batch width: volumes,
    /// deformation gradients, stored stresses and internal variables, positions,
    /// velocities clipped at walls, the walls' work, the physical-state flag and the
    /// signal speed's running maximum, for each α (the bubble, 0, 1 and between),
    /// one- and two-step schemes, each way of moving, each law, with and without
    /// walls, and the [`VARIANTS`].
    #[test]
    fn stress_pass_is_the_same_at_every_width() {
        stress_widths::<2, 4>(11);
    }

    /// [`stress_pass_is_the_same_at_every_width`] in 3D.
    #[test]
    fn stress_pass_is_the_same_at_every_width_in_3d() {
        stress_widths::<3, 8>(13);
    }

    fn stress_widths<const D: usize, const N: usize>(seed: u64) {
        let setup = Setup::<D>::new();
        let mut rng = Rng::new(seed);
        let mut cover = Cover::default();
        for alpha in ALPHAS {
            for law in LAWS {
                for walls in [false, true] {
                    let ctx = setup.ctx(alpha, law, walls);
                    for (two_step, moves) in
                        [(true, true), (true, false), (false, true), (false, false)]
                    {
                        let mut rooms = (Room::new(), Room::new());
                        for (steep, max0, nan_lane, width) in VARIANTS {
                            let slot = rng.below(2);
                            let nd = nodes::<D, N>(&mut rng, steep, slot);
                            let m = StressMode {
                                slot,
                                dt: 1e-3,
                                two_step,
                                moves,
                                speed: true,
                            };
                            let what = format!(
                                "{alpha:?}, two-step {two_step}, moves {moves}, steep {steep}, max {max0}"
                            );
                            let case = (&nd, max0, nan_lane, width);
                            let pass = Pass::Stress(&m);
                            compare(
                                &ctx, &mut rng, law, walls, case, pass, &mut rooms, &mut cover,
                                &what,
                            );
                        }
                    }
                }
            }
        }
        assert_eq!(cover.cases, 4 * 4 * 2 * 4 * VARIANTS.len());
        // The comparison covered inverted states and walls that clipped.
        assert!(
            cover.inverted >= 16,
            "{} cases inverted a particle",
            cover.inverted
        );
        assert!(
            cover.clipped >= 16,
            "{} cases clipped at a wall",
            cover.clipped
        );
    }

    /// The gather gives the same bits whatever the batch width: velocities (FLIP,
    /// PIC, a blend and XPIC), clipped at walls, the external work (gravity, a kept
    /// body force, the walls'), volumes, deformation gradients, stresses, positions,
    /// the physical-state flag and the signal speed, for each α, one- and two-step
    /// schemes (the latter moving with the reconstruction), with and without the
    /// stress update, moving now or leaving the move to the stress pass, each law, with
    /// and without walls, and the [`VARIANTS`].
    #[test]
    fn gather_is_the_same_at_every_width() {
        gather_widths::<2, 4>(12);
    }

    /// [`gather_is_the_same_at_every_width`] in 3D.
    #[test]
    fn gather_is_the_same_at_every_width_in_3d() {
        gather_widths::<3, 8>(14);
    }

    fn gather_widths<const D: usize, const N: usize>(seed: u64) {
        let setup = Setup::<D>::new();
        let mut rng = Rng::new(seed);
        let mut cover = Cover::default();
        for alpha in ALPHAS {
            for law in LAWS {
                for walls in [false, true] {
                    let ctx = setup.ctx(alpha, law, walls);
                    for (two_step, recon, stress, move_now, flip, xpic) in [
                        (true, true, true, true, 1.0, false),
                        (true, true, false, true, 0.0, false),
                        (true, false, true, true, 0.95, false),
                        (false, false, true, true, 1.0, false),
                        (false, false, true, false, 0.5, false),
                        (false, false, false, false, 1.0, true),
                    ] {
                        let mut rooms = (Room::new(), Room::new());
                        for (steep, max0, nan_lane, width) in VARIANTS {
                            let nd = nodes::<D, N>(&mut rng, steep, UPDATED);
                            let m = GatherMode {
                                dt: 1e-3,
                                kick: 1e-3,
                                flip,
                                stress,
                                move_now,
                                two_step,
                                recon,
                                speed: true,
                            };
                            let what = format!(
                                "{alpha:?}, two-step {two_step}, recon {recon}, stress {stress}, move now {move_now}, flip {flip}, XPIC {xpic}, steep {steep}, max {max0}"
                            );
                            let case = (&nd, max0, nan_lane, width);
                            let pass = Pass::Gather(&m, xpic);
                            compare(
                                &ctx, &mut rng, law, walls, case, pass, &mut rooms, &mut cover,
                                &what,
                            );
                        }
                    }
                }
            }
        }
        assert_eq!(cover.cases, 4 * 4 * 2 * 6 * VARIANTS.len());
        assert!(
            cover.inverted >= 16,
            "{} cases inverted a particle",
            cover.inverted
        );
    }

    /// A pass's signal speed (`kernel::signal_speeds`: eight particles at a time,
    /// the stretched ones' speeds kept per lane over all batches and folded once)
    /// is the particle-by-particle maximum, bit for bit: 3 full batches and 5 more,
    /// stretched and compressed, from maxima below, among and above theirs.
    #[test]
    fn signal_speeds_are_the_particle_by_particle_maximum() {
        let setup = Setup::<2>::new();
        let ctx = setup.ctx(Alpha::ProductOfShapes, Law::Hyper { vol: true }, false);
        let mut rng = Rng::new(31);
        let mut p = Particles::<2>::default();
        let n = 3 * LANES + 5;
        for k in 0..n {
            p.x.push(Vector::<2>::from_fn(|_, _| 0.3 + 0.4 * rng.f64()));
            // Fast particles in the second batch, the third (the fastest; that batch
            // is all stretched, so its lanes are folded with the others only at the
            // end) and the rest.
            let fast = [(LANES + 3, 10.0), (2 * LANES + 5, 20.0), (n - 2, 15.0)];
            p.v.push(match fast.iter().find(|f| f.0 == k) {
                Some(&(_, v)) => Vector::<2>::new(0.0, v),
                None => Vector::<2>::from_fn(|_, _| rng.f64() - 0.5),
            });
            p.def_grad.push(Mat::<2>::identity());
            let stretched = (2 * LANES..3 * LANES).contains(&k);
            let j = if stretched { 1.0 } else { 0.8 } + 0.2 * rng.f64();
            // One kind, so that the batches take the quick path.
            p.vol.push(kind_vol0(0) * j);
            p.kind.push(0);
        }
        let tile = vec![0u32; n];
        let s = slices(&mut p, &tile, &[]);
        let one_by_one = |max: f64| (0..n).fold(max, |m, q| speed_one(&ctx, &s, q, m));
        let all = one_by_one(0.0);
        let (mut below, mut above) = (0, 0);
        for max in [0.0, 0.5 * all, 0.999 * all, 2.0 * all] {
            let lanes = signal_speeds(&ctx, &s, max);
            assert_eq!(lanes.to_bits(), one_by_one(max).to_bits(), "from {max}");
            below += usize::from(lanes > max);
            above += usize::from(lanes == max);
        }
        // The particles raised the maximum from below and left it from above.
        assert_eq!((below, above), (3, 1));
    }

    /// A pass tests its lanes' marks once, after its last batch (`by_runs` adds each
    /// batch's into running ones): a batch with an unphysical lane (a NaN in `F`, or
    /// a particle inverted by a steep gradient) leaves them unphysical through
    /// physical batches of any width after it, and physical batches alone leave
    /// them physical.
    #[test]
    fn marks_keep_a_failure_through_later_batches() {
        let setup = Setup::<2>::new();
        let law = Law::Hyper { vol: true };
        let ctx = setup.ctx(Alpha::ProductOfShapes, law, false);
        let mut rng = Rng::new(21);
        let m = StressMode {
            slot: 0,
            dt: 1e-3,
            two_step: true,
            moves: true,
            speed: false,
        };
        let run = run::<2, 4>(false);
        let mut pass = |marks: &mut [f64; LANES], nan_lane, steep, width| {
            let nd = nodes::<2, 4>(&mut rng, steep, 0);
            let (mut p, cell) = particles::<2>(&mut rng, law, nan_lane);
            let tile = vec![0u32; LANES];
            let mut s = slices(&mut p, &tile, &[]);
            let mut t = Tally::ZERO;
            let (pass, room) = (Pass::Stress(&m), &mut Room::new());
            batch(
                &ctx,
                &mut s,
                0,
                width,
                &cell,
                &run,
                &nd,
                pass,
                room,
                &mut t.work,
                marks,
            );
        };
        let mut marks = [0.0; LANES];
        for width in [LANES, HALF, QUARTER, 1, LANES] {
            pass(&mut marks, None, 1.0, width);
        }
        assert!(physical(&marks));
        for (nan_lane, steep, width) in [
            (Some(3), 1.0, LANES),
            (None, 1e5, HALF),
            (Some(1), 1.0, QUARTER),
            (Some(0), 1.0, 1),
        ] {
            let mut marks = [0.0; LANES];
            pass(&mut marks, nan_lane, steep, width);
            assert!(
                !physical(&marks),
                "NaN {nan_lane:?}, steep {steep}: the batch itself"
            );
            for width in [HALF, LANES, 1, HALF] {
                pass(&mut marks, None, 1.0, width);
            }
            assert!(!physical(&marks), "NaN {nan_lane:?}, steep {steep}");
        }
    }
}
