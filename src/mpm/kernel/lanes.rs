//! Particle loops eight particles of a run at a time ([`LANES`], or [`HALF`] or
//! [`QUARTER`] where runs are shorter): the stress pass, the gather and MUSL's remap,
//! in 2D and 3D.
//!
//! Why: one particle's update is a chain of small matrix products (weights, velocity
//! gradient, `F ← (I + L dt) F`, the move) that the compiler can only vectorise
//! within the particle, with shuffles between 2- and 4-wide pieces. The particles of
//! one run share their nodes, so their node data are common and every operation is
//! the same on each of them: over eight particles of a run, each line below is one
//! full-width vector operation on eight independent numbers.
//!
//! Each lane does what the scalar body (`stress_one`, `gather_one`, the remap's
//! `remap_one`) does for its particle, in the same order and the same roundings (no
//! fused multiply-adds: Rust never contracts), and what is summed over particles (the
//! external work, the momentum) is still added particle by particle in order, so the
//! results are the same bits, not merely close; the tests below and the remap's hold
//! each batch to its scalar body.

use super::{
    pair, Alpha, Ctx, GatherMode, NodeData, Slices, StressMode, Tally, FROM_MOMENTUM, UPDATED,
};
use crate::mpm::particles;
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

/// Whether the batch path can take this pass at all: hat functions, and particles
/// whose stress is formed from `F` where it is used (neo-Hookean), so that
/// deforming is `F` and the volume only, with no material update per particle.
/// In 3D a batch's numbers do not fit the registers (24 shape-gradient terms and
/// nine-entry matrices per lane) and part of them live on the stack, but the stack is
/// L1: the 3D block drop's stress pass took 0.56× the time of one particle at a time
/// (perf samples). Not in 3D where the build has AVX-512: there LLVM vectorises the
/// three-long loops over the axes with gathers and scatters, and the 3D lanes ran 1.3×
/// slower than one particle at a time.
#[inline(always)]
pub fn applies<const D: usize>(gimp: bool, s: &Slices<'_, D>) -> bool {
    let wide_gathers = D == 3 && cfg!(target_feature = "avx512f");
    !gimp && !wide_gathers && s.parts.stress.is_empty() && !s.parts.def_grad.is_empty()
}

/// A particle pass the lanes take in batches: the stress pass or the gather.
#[derive(Clone, Copy)]
pub enum Pass<'a> {
    Stress(&'a StressMode),
    Gather(&'a GatherMode),
}

impl Pass<'_> {
    /// Whether the pass reports the fastest signal speed.
    pub fn speed(self) -> bool {
        match self {
            Pass::Stress(m) => m.speed,
            Pass::Gather(m) => m.speed,
        }
    }
}

/// Pass `m` over `width` ([`LANES`] or [`HALF`]) particles from `p0`
/// ([`deform_and_move`] or [`gather`]), accounted in `t`, its lanes' marks of an
/// unphysical state added into `marks` ([`unphysical`]; the caller tests them once,
/// [`physical`], after its last batch), the signal speed raised after the pass
/// (`kernel::signal_speeds`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn batch<const D: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p0: usize,
    width: usize,
    cell: &[f64; D],
    nd: &NodeData<D, N>,
    m: Pass<'_>,
    room: &mut Room<D, N>,
    t: &mut Tally,
    marks: &mut [f64; LANES],
) {
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn of<const D: usize, const N: usize, const B: usize>(
        ctx: &Ctx<'_, D>,
        s: &mut Slices<'_, D>,
        p0: usize,
        cell: &[f64; D],
        nd: &NodeData<D, N>,
        m: Pass<'_>,
        batch: &mut Batch<D, N, B>,
        t: &mut Tally,
        marks: &mut [f64; LANES],
    ) {
        let bad = match m {
            Pass::Stress(m) => deform_and_move::<D, N, B>(ctx, s, p0, cell, nd, m, batch),
            Pass::Gather(m) => gather::<D, N, B>(ctx, s, p0, cell, nd, m, batch, &mut t.work),
        };
        for l in 0..B {
            marks[l] += bad[l];
        }
    }
    match width {
        LANES => of::<D, N, LANES>(ctx, s, p0, cell, nd, m, &mut room.lanes, t, marks),
        HALF => of::<D, N, HALF>(ctx, s, p0, cell, nd, m, &mut room.half, t, marks),
        _ => of::<D, N, QUARTER>(ctx, s, p0, cell, nd, m, &mut room.quarter, t, marks),
    }
}

/// A batch of each width, zeroed once for a task's particles and filled again by
/// each batch of a pass ([`Batch::fill`]): zeroed per batch, it was a `memset` of
/// 3.4 kB for every eight particles, 3 % of the 3D step. Every fill writes the
/// weights whole (of the gradients, every entry that is read), and `L̄` whole in a two-step pass and never otherwise, where it
/// stays zero as a fresh batch's: so a pass reads what a zeroed batch would hold.
/// One room serves one pass.
pub struct Room<const D: usize, const N: usize> {
    lanes: Batch<D, N, LANES>,
    half: Batch<D, N, HALF>,
    quarter: Batch<D, N, QUARTER>,
}

impl<const D: usize, const N: usize> Room<D, N> {
    #[inline(always)]
    pub fn new() -> Self {
        Room {
            lanes: Batch::zeroed(),
            half: Batch::zeroed(),
            quarter: Batch::zeroed(),
        }
    }
}

/// Whether the lanes' marks ([`unphysical`], summed over any number of batches) say
/// that every state they mark is physical.
#[inline(always)]
pub fn physical<const B: usize>(marks: &[f64; B]) -> bool {
    marks.iter().sum::<f64>() == 0.0
}

/// A batch's weights and, for a two-step scheme, its interpolated nodal `L̄`
/// ([`super::lbar_at`]), lane by lane.
struct Batch<const D: usize, const N: usize, const B: usize> {
    xi: [[f64; B]; D],
    sh: [[f64; B]; N],
    /// `g[d][n]` is written and read only where node `n` is the upper one of its pair
    /// along `d` ([`pair`]): a hat's derivative at the lower node is minus the upper
    /// one's, and the pair enters the gradient as the velocity's difference
    /// ([`NodeData::dv`]).
    g: [[[f64; B]; N]; D],
    alpha: [f64; B],
    all: [[[f64; B]; D]; D],
    upper: [[[f64; B]; D]; D],
}

impl<const D: usize, const N: usize, const B: usize> Batch<D, N, B> {
    /// All zero, for [`Batch::fill`].
    #[inline(always)]
    fn zeroed() -> Self {
        Batch {
            xi: [[0.0; B]; D],
            sh: [[0.0; B]; N],
            g: [[[0.0; B]; N]; D],
            alpha: [0.0; B],
            all: [[[0.0; B]; D]; D],
            upper: [[[0.0; B]; D]; D],
        }
    }

    /// The weights of particles `r` of `s`, in `cell` ([`Ctx::local`]), and, if
    /// `two`, their `L̄` from `nd`, in place: a batch built and returned (3.4 kB in
    /// 3D) was copied by `memcpy` into its caller's, 2 % of the 3D step.
    #[inline(always)]
    fn fill(
        &mut self,
        ctx: &Ctx<'_, D>,
        s: &Slices<'_, D>,
        r: Range<usize>,
        cell: &[f64; D],
        nd: &NodeData<D, N>,
        two: bool,
    ) {
        // A fixed-size view of the batch: indices below B need no bounds checks, so
        // the loads are whole vectors. (Plain loops over fixed arrays throughout:
        // `array::from_fn`'s closures were left as calls, with the lanes spilled
        // around them.)
        let xs: &[Vector<D>; B] = s.parts.x[r].try_into().expect("a full batch");
        let b = self;
        local_lanes(ctx, xs, cell, &mut b.xi);
        b.alpha = weights_into::<D, N, B>(ctx, &b.xi, &mut b.sh, &mut b.g);
        // `lbar_at`: the nodal L̄ at the particle, all nodes and the upper side per
        // column.
        if two {
            for a in 0..D {
                for c in 0..D {
                    let mut lo = [0.0; B];
                    let mut hi = [0.0; B];
                    for n in 0..N {
                        let v = nd.lb[a][c][n];
                        if (n >> c) & 1 == 1 {
                            for l in 0..B {
                                hi[l] += b.sh[n][l] * v;
                            }
                        } else {
                            for l in 0..B {
                                lo[l] += b.sh[n][l] * v;
                            }
                        }
                    }
                    for l in 0..B {
                        b.all[a][c][l] = lo[l] + hi[l];
                    }
                    b.upper[a][c] = hi;
                }
            }
        }
    }

    /// `velocity_gradient_at` with hat functions from the differences `nd.dv`:
    /// across the cell's pairs, times α, blended with (1 − α) L̄ for a two-step
    /// scheme; then `deform`: the increment I + L dt, its determinant J, the volume
    /// and F ← (I + L dt) F of particles `r` of `s`. Returns the lanes' marks of an
    /// unphysical state ([`unphysical`]).
    #[inline(always)]
    fn deform(
        &self,
        s: &mut Slices<'_, D>,
        r: Range<usize>,
        nd: &NodeData<D, N>,
        two: bool,
        dt: f64,
    ) -> [f64; B] {
        let alpha = &self.alpha;
        let mut lg = [[[0.0; B]; D]; D];
        for a in 0..D {
            for b in 0..D {
                let mut x = [0.0; B];
                for mm in 0..N / 2 {
                    let c = nd.dv[a][b][mm];
                    let gb = &self.g[b][pair(b, mm).1];
                    for l in 0..B {
                        x[l] += c * gb[l];
                    }
                }
                // Both sides formed, then chosen: a select per lane, not a branch.
                for l in 0..B {
                    let ax = alpha[l] * x[l];
                    lg[a][b][l] = if alpha[l] != 0.0 { ax } else { 0.0 };
                }
                if two {
                    for l in 0..B {
                        let v = lg[a][b][l];
                        let blended = v + (1.0 - alpha[l]) * self.all[a][b][l];
                        lg[a][b][l] = if alpha[l] != 1.0 { blended } else { v };
                    }
                }
            }
        }
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
        // `F`, the widest array the pass streams (72 bytes a particle in 3D), asked for
        // ahead: its loads here waited on memory (a sixth of the 3D stress pass).
        // (Past the array's end only addresses are formed: a prefetch never faults.)
        super::prefetch(s.parts.def_grad, r.end + AHEAD - B, B);
        let fs: &mut [Mat<D>; B] = (&mut s.parts.def_grad[r.clone()])
            .try_into()
            .expect("a full batch");
        let mut f = [[[0.0; B]; D]; D];
        for l in 0..B {
            for k in 0..D {
                for c in 0..D {
                    f[k][c][l] = fs[l][(k, c)];
                }
            }
        }
        let mut fnew = [[[0.0; B]; D]; D];
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
        // Where the particles carry `F`, their volume is `det F · V₀`: not stored.
        let stored = s.parts.vol.get_mut(r).map(<&mut [f64; B]>::try_from);
        let bad = match stored {
            Some(Ok(vs)) => {
                let mut vol = [0.0; B];
                for l in 0..B {
                    vol[l] = vs[l] * j[l];
                }
                *vs = vol;
                unphysical(&j, &vol, &fnew)
            }
            _ => unphysical(&j, &[0.0; B], &fnew),
        };
        for l in 0..B {
            for i in 0..D {
                for c in 0..D {
                    fs[l][(i, c)] = fnew[i][c][l];
                }
            }
        }
        bad
    }

    /// `moving_velocity` away from walls: Σ_n S_n v̄_n plus the L̄ terms.
    #[inline(always)]
    fn moving_velocity(&self, ctx: &Ctx<'_, D>, nd: &NodeData<D, N>) -> [[f64; B]; D] {
        let h = &ctx.geom.h;
        let mut u = [[0.0; B]; D];
        for a in 0..D {
            for n in 0..N {
                let c = nd.vb[a][n];
                for l in 0..B {
                    u[a][l] += self.sh[n][l] * c;
                }
            }
            for b in 0..D {
                for l in 0..B {
                    u[a][l] += (self.all[a][b][l] * self.xi[b][l] - self.upper[a][b][l]) * h[b];
                }
            }
        }
        u
    }
}

/// Per lane, a mark that is ±0 where J > 0 and the volume and `F` are finite, else
/// NaN: numbers, not bools, since `0·x` is ±0 for a finite x and NaN otherwise and a
/// lane with J <= 0 (or NaN) adds a NaN. Sums of marks stay ±0 exactly while every
/// state they mark is physical, so a pass adds each batch's marks into running ones
/// and tests them once ([`physical`]). (Per-lane bools went through the mask
/// registers bit by bit, a dozen moves and shifts per lane; and a test per batch
/// summed the lanes at the end of the batch's longest chain, where its samples
/// gathered: a quarter of the 2D stress pass's.)
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
fn advance<const D: usize, const B: usize>(
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

/// Deform and (as `m` asks) move particles `p0 .. p0 + B` of `s`, which share
/// their nodes, whose data `nd` holds (loaded, with the differences of slot
/// `m.slot`), and none of which gives weight to a wall's node: the scalar pass's
/// velocity gradient, deformation, volume, and the move with the reconstruction of
/// slot `m.slot` (`m.moves`) or by the kept increment (`m.moves_kept`). Returns the
/// lanes' marks of an unphysical state ([`unphysical`]); the signal speed is left to
/// the caller.
#[inline(always)]
fn deform_and_move<const D: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p0: usize,
    cell: &[f64; D],
    nd: &NodeData<D, N>,
    m: &StressMode,
    batch: &mut Batch<D, N, B>,
) -> [f64; B] {
    let r = p0..p0 + B;
    batch.fill(ctx, s, r.clone(), cell, nd, m.two_step);
    let bad = batch.deform(s, r.clone(), nd, m.two_step, m.dt);
    if m.moves {
        let u = batch.moving_velocity(ctx, nd);
        advance(s, r, &u, m.dt);
    } else if m.moves_kept {
        for p in r {
            s.parts.x[p] += s.dx[p];
        }
    }
    bad
}

/// The gather ([`super::gather`]) of particles `p0 .. p0 + B` of `s`, which share
/// their nodes, whose data `nd` holds (with the differences of the updated slot if
/// `m.stress`), none of which gives weight to a wall's node, without XPIC: the new
/// velocity (FLIP/PIC blend), the external work into `t.work` particle by particle
/// in order, the velocity gradient and deformation (`m.stress`), the move or the
/// kept increment. The same bits as the scalar gather; returns the lanes' marks of an
/// unphysical state, a non-finite velocity included ([`unphysical`]; the signal speed
/// is left to the caller).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn gather<const D: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p0: usize,
    cell: &[f64; D],
    nd: &NodeData<D, N>,
    m: &GatherMode,
    batch: &mut Batch<D, N, B>,
    work: &mut f64,
) -> [f64; B] {
    let r = p0..p0 + B;
    batch.fill(
        ctx,
        s,
        r.clone(),
        cell,
        nd,
        m.two_step && (m.recon || m.stress),
    );
    let (vn, dv) = interpolate(&batch.sh, nd);
    let vs: &mut [Vector<D>; B] = (&mut s.parts.v[r.clone()])
        .try_into()
        .expect("a full batch");
    let mut bad = [0.0; B];
    for l in 0..B {
        let old = vs[l];
        let mut new = Vector::<D>::zeros();
        for a in 0..D {
            new[a] = (old[a] + dv[a][l]) * m.flip + vn[a][l] * (1.0 - m.flip);
        }
        // The external force's work (the lanes take no run at a wall, so no clip).
        let p = p0 + l;
        let mass = particles::mass_of(ctx.kind_mass, s.parts.kind, p);
        let acc = ctx.accel_kept(s.accel, s.parts.x0, p);
        *work += m.dt * mass * acc.dot(&(old + new)) * 0.5;
        vs[l] = new;
        for a in 0..D {
            bad[l] += new[a] * 0.0;
        }
    }
    if m.stress {
        let deformed = batch.deform(s, r.clone(), nd, m.two_step, m.dt);
        for l in 0..B {
            bad[l] += deformed[l];
        }
    }
    let u = if m.recon {
        batch.moving_velocity(ctx, nd)
    } else {
        vn
    };
    if m.move_now {
        advance(s, r, &u, m.dt);
    } else if !m.two_step {
        for (l, p) in r.enumerate() {
            for a in 0..D {
                s.dx[p][a] = u[a][l] * m.dt;
            }
        }
    }
    bad
}

/// The remap's share of a batch ([`crate::mpm::remap`]): for particles with local
/// coordinates `xi` (hat functions), `Σ_n S_n v_n` of the updated slot and
/// `Σ_n S_n (v_n − v_n^old)` over the run's nodes `nd`, summed node by node as the
/// scalar loop sums them, and the shape functions for the momentum's sums.
#[allow(clippy::type_complexity)]
#[inline(always)]
pub(crate) fn velocities<const D: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    xi: &[[f64; B]; D],
    nd: &NodeData<D, N>,
) -> ([[f64; B]; D], [[f64; B]; D], [[f64; B]; N]) {
    // (The shape functions into a caller's array, not returned, lost their `memcpy`
    // in 3D but made the 2D remap 1.13 of its time.)
    let mut sh = [[0.0; B]; N];
    let mut g = [[[0.0; B]; N]; D];
    weights_into::<D, N, B>(ctx, xi, &mut sh, &mut g);
    let (vn, dv) = interpolate(&sh, nd);
    (vn, dv, sh)
}

/// With shape functions `sh`, `Σ_n S_n v_n` of the updated slot and
/// `Σ_n S_n (v_n − v_n^old)` over the nodes `nd`, node by node in order as the
/// scalar loops sum them.
#[allow(clippy::type_complexity)]
#[inline(always)]
fn interpolate<const D: usize, const N: usize, const B: usize>(
    sh: &[[f64; B]; N],
    nd: &NodeData<D, N>,
) -> ([[f64; B]; D], [[f64; B]; D]) {
    let mut vn = [[0.0; B]; D];
    let mut dv = [[0.0; B]; D];
    for n in 0..N {
        for a in 0..D {
            let (v0, v1) = (nd.v[FROM_MOMENTUM][a][n], nd.v[UPDATED][a][n]);
            let d = v1 - v0;
            for l in 0..B {
                vn[a][l] += sh[n][l] * v1;
                dv[a][l] += sh[n][l] * d;
            }
        }
    }
    (vn, dv)
}

/// [`Ctx::local`] of the particles at `xs`, all in `cell`, lane by lane into `xi`
/// (the same arithmetic, so the same bits).
#[inline(always)]
pub(crate) fn local_lanes<const D: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    xs: &[Vector<D>; B],
    cell: &[f64; D],
    xi: &mut [[f64; B]; D],
) {
    for a in 0..D {
        let (lower, inv_h, c) = (ctx.geom.lower[a], ctx.geom.inv_h[a], cell[a]);
        for l in 0..B {
            xi[a][l] = (xs[l][a] - lower) * inv_h - c;
        }
    }
}

/// [`Ctx::weights`] with hat functions, lane by lane: the shape functions `sh[n]`,
/// their gradients `g[d][n]` at the upper node `n` of each pair along `d` ([`pair`];
/// the other entries are left as they were) and α (returned) of particles with
/// local coordinates `xi[a]`.
#[inline(always)]
fn weights_into<const D: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    xi: &[[f64; B]; D],
    sh: &mut [[f64; B]; N],
    g: &mut [[[f64; B]; N]; D],
) -> [f64; B] {
    // Hat functions (`shape::hat`): weights 1 − ξ and ξ, derivatives ∓ 1/h.
    let mut w = [[[0.0; B]; 2]; D];
    let mut dw = [[0.0; 2]; D];
    for a in 0..D {
        for l in 0..B {
            w[a][0][l] = 1.0 - xi[a][l];
        }
        w[a][1] = xi[a];
        dw[a] = [-ctx.geom.inv_h[a], ctx.geom.inv_h[a]];
    }
    let alpha: [f64; B] = match ctx.alpha {
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
    };
    // `Ctx::weights`: shape functions and gradients over the cell's corners.
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
        sh[n] = sn;
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
            g[d][n] = p;
        }
    }
    alpha
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
    use super::super::{gather_one, raise_speed as speed_one, stress_one, Kern, Tally};
    use super::*;
    use crate::input::scene::Face;
    use crate::mpm::particles::Particles;
    use crate::physics::material::{lame, neo_hookean::NeoHookean, Material};
    use crate::physics::shape::Geom;
    use crate::physics::tensor::Vector;
    use decomposition::splitmix::Rng;
    use decomposition::Tiles;

    /// The reference volume (and mass: density 1) of [`Setup`]'s kind `k`, one kind
    /// per lane, so that the lanes' masses differ.
    fn kind_vol0(k: usize) -> f64 {
        1e-4 * (0.5 + (k as f64 + 0.5) / LANES as f64)
    }

    /// Eight particles of one cell with random local coordinates (among them ξ = 0
    /// on the first axis, where α = 0, and ξ = ½ on all axes, where α = 1),
    /// deformation gradients, volumes on both sides of J = 1, velocities and
    /// positions, of kind `l` in lane `l`; one lane with a non-finite F.
    fn particles<const D: usize>(
        rng: &mut Rng,
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
            if nan_lane == Some(l) {
                f[(1, 0)] = f64::NAN;
            }
            p.def_grad.push(f);
            p.vol.push(kind_vol0(l) * (0.85 + 0.3 * rng.f64()));
            p.kind.push(l as u16);
        }
        // Their cell (the grid's h is 0.1, [`Setup::new`]): `Ctx::local` gives the
        // lanes' ξ of 0 and ½ exactly.
        (p, std::array::from_fn(|a| [3.0, 6.0, 4.0][a]))
    }

    /// A material, a kind of particle per lane ([`kind_vol0`]), a grid and the context
    /// of a pass with gradient `alpha`.
    struct Setup<const D: usize> {
        geom: Geom<D>,
        tiles: Tiles<D>,
        materials: Vec<Material>,
        kind_vol0: Vec<f64>,
    }

    impl<const D: usize> Setup<D> {
        fn new() -> Self {
            let (lambda, mu) = lame(1e3, 0.2);
            Setup {
                geom: Geom::<D>::new([0.0; D], [1.0; D], [10; D], [false; D]),
                tiles: Tiles::<D>::new([12; D], [1; D]),
                materials: vec![
                    Material::NeoHookean(NeoHookean {
                        lambda,
                        mu,
                        density: 1.0,
                    });
                    LANES
                ],
                kind_vol0: (0..LANES).map(kind_vol0).collect(),
            }
        }

        fn ctx(&self, alpha: Alpha) -> Ctx<'_, D> {
            Ctx {
                geom: &self.geom,
                node_lo: [-1; D],
                tiles: &self.tiles,
                gimp: false,
                alpha,
                materials: &self.materials,
                kind_mass: &self.kind_vol0,
                kind_vol0: &self.kind_vol0,
                gravity: Vector::<D>::from_fn(|a, _| if a == 1 { -9.81 } else { 0.0 }),
                body_force: None,
                faces: [[Face::Slip; 2]; D],
                walls: false,
            }
        }
    }

    const ALPHAS: [Alpha; 4] = [
        Alpha::ProductOfShapes,
        Alpha::Constant(0.0),
        Alpha::Constant(1.0),
        Alpha::Constant(0.3),
    ];

    /// Velocity gradient scale, starting maximum of the signal speed, lane with a
    /// non-finite F, batch width: gentle and steep (inverting) gradients, maxima
    /// below and above the particles' speeds, both widths.
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
    /// differences of slot `slot`.
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
        dx: &'a mut [Vector<D>],
        tile: &'a [u32],
        accel: &'a [Vector<D>],
    ) -> Slices<'a, D> {
        Slices {
            parts: p.slices(),
            dx,
            tile,
            accel,
        }
    }

    /// One batch of `width` particles from the first of `sb`, in `cell`, through
    /// pass `m` (the gather's external work into `work`) in `room`, which may have
    /// served earlier batches of the same pass: whether every state is physical,
    /// and the signal speed raised from `max0` after it.
    #[allow(clippy::too_many_arguments)]
    fn one_batch<const D: usize, const N: usize>(
        ctx: &Ctx<'_, D>,
        sb: &mut Slices<'_, D>,
        width: usize,
        cell: &[f64; D],
        nd: &NodeData<D, N>,
        m: Pass<'_>,
        room: &mut Room<D, N>,
        max0: f64,
        work: &mut f64,
    ) -> (bool, f64) {
        #[allow(clippy::too_many_arguments)]
        fn of<const D: usize, const N: usize, const B: usize>(
            ctx: &Ctx<'_, D>,
            sb: &mut Slices<'_, D>,
            cell: &[f64; D],
            nd: &NodeData<D, N>,
            m: Pass<'_>,
            batch: &mut Batch<D, N, B>,
            max0: f64,
            work: &mut f64,
        ) -> (bool, f64) {
            let bad = match m {
                Pass::Stress(m) => deform_and_move::<D, N, B>(ctx, sb, 0, cell, nd, m, batch),
                Pass::Gather(m) => gather::<D, N, B>(ctx, sb, 0, cell, nd, m, batch, work),
            };
            (physical(&bad), batch_speed::<D, B>(ctx, sb, max0))
        }
        match width {
            LANES => of::<D, N, LANES>(ctx, sb, cell, nd, m, &mut room.lanes, max0, work),
            HALF => of::<D, N, HALF>(ctx, sb, cell, nd, m, &mut room.half, max0, work),
            _ => of::<D, N, QUARTER>(ctx, sb, cell, nd, m, &mut room.quarter, max0, work),
        }
    }

    /// The signal speed of the batch at the start of `s`, from `max` ([`raise_speed`]
    /// and its lanes' [`fold`]).
    fn batch_speed<const D: usize, const B: usize>(
        ctx: &Ctx<'_, D>,
        s: &Slices<'_, D>,
        max: f64,
    ) -> f64 {
        let mut lanes = [f64::NEG_INFINITY; B];
        let top = raise_speed::<D, B>(ctx, s, 0, max, &mut lanes);
        fold(top, &lanes)
    }

    /// Both particle sets (and kept increments) hold the same bits.
    fn same_bits<const D: usize>(
        a: &Particles<D>,
        b: &Particles<D>,
        dx: &[Vector<D>],
        dx_b: &[Vector<D>],
        what: &str,
    ) {
        for p in 0..LANES {
            let bits = |v: &[f64]| v.get(p).map(|x| x.to_bits());
            assert_eq!(bits(&a.vol), bits(&b.vol), "vol {p}: {what}");
            let pairs = [
                (a.def_grad[p].as_slice(), b.def_grad[p].as_slice(), "F"),
                (a.x[p].as_slice(), b.x[p].as_slice(), "x"),
                (a.v[p].as_slice(), b.v[p].as_slice(), "v"),
                (dx[p].as_slice(), dx_b[p].as_slice(), "dx"),
            ];
            for (x, y, name) in pairs {
                for (x, y) in x.iter().zip(y) {
                    assert_eq!(x.to_bits(), y.to_bits(), "{name} {p}: {what}");
                }
            }
        }
    }

    /// The stress pass's lanes give its scalar body's bits: volumes, deformation
    /// gradients, positions, the physical-state flag and the signal speed's running
    /// maximum, for both gradients' α (the bubble, 0, 1 and between), one- and
    /// two-step schemes, each way of moving, and the [`VARIANTS`]; in every other
    /// case the particles store no volume (it is then `det F · V₀`).
    #[test]
    fn lanes_match_the_scalar_pass() {
        stress_lanes_match::<2, 4>(11);
    }

    /// [`lanes_match_the_scalar_pass`] in 3D.
    #[test]
    fn lanes_match_the_scalar_pass_in_3d() {
        stress_lanes_match::<3, 8>(13);
    }

    fn stress_lanes_match<const D: usize, const N: usize>(seed: u64) {
        let setup = Setup::<D>::new();
        let mut rng = Rng::new(seed);
        let (mut cases, mut inverted) = (0, 0);
        for alpha in ALPHAS {
            let ctx = setup.ctx(alpha);
            for (two_step, moves, moves_kept) in [
                (true, true, false),
                (true, false, false),
                (false, false, true),
                (false, false, false),
            ] {
                // One room for the pass's batches, as `by_runs` keeps one: each
                // batch after the first finds the last one's numbers in it.
                let mut room = Room::new();
                for (steep, max0, nan_lane, width) in VARIANTS {
                    let slot = rng.below(2);
                    let nd = nodes::<D, N>(&mut rng, steep, slot);
                    let m = StressMode {
                        slot,
                        dt: 1e-3,
                        two_step,
                        moves,
                        moves_kept,
                        speed: true,
                    };
                    let (mut a, cell) = particles::<D>(&mut rng, nan_lane);
                    // Every other case without stored volumes: then `det F · V₀`.
                    if cases % 2 == 1 {
                        a.vol = Vec::new();
                    }
                    let mut b = a.clone();
                    let mut dx: Vec<Vector<D>> = (0..LANES)
                        .map(|_| Vector::<D>::from_fn(|_, _| rng.f64()) * 1e-3)
                        .collect();
                    let mut dx_b = dx.clone();
                    let tile = vec![0u32; LANES];
                    // One by one: the scalar pass's body.
                    let mut sa = slices(&mut a, &mut dx, &tile, &[]);
                    let mut ta = Tally {
                        max_speed: max0,
                        ..Tally::ZERO
                    };
                    for p in 0..width {
                        let (k, _, _): (Kern<D, N>, _, _) = ctx.weights::<2, N>(
                            &sa.parts.x[p],
                            None,
                            &ctx.local(&sa.parts.x[p], &cell),
                        );
                        stress_one(&ctx, &mut sa, p, &k, &nd, &m, &mut ta);
                    }
                    // The signal speed, particle by particle after the pass.
                    ta.max_speed = (0..width).fold(ta.max_speed, |v, p| speed_one(&ctx, &sa, p, v));
                    // A batch at a time.
                    let mut sb = slices(&mut b, &mut dx_b, &tile, &[]);
                    assert!(applies(false, &sb));
                    let (ok, top) = one_batch(
                        &ctx,
                        &mut sb,
                        width,
                        &cell,
                        &nd,
                        Pass::Stress(&m),
                        &mut room,
                        max0,
                        &mut 0.0,
                    );
                    let what = format!(
                        "{width} lanes, {alpha:?}, two-step {two_step}, moves {moves}/{moves_kept}, steep {steep}, max {max0}, NaN {nan_lane:?}"
                    );
                    assert_eq!(ok, ta.ok, "{what}");
                    assert_eq!(top.to_bits(), ta.max_speed.to_bits(), "{what}");
                    // (Particles past the batch are untouched by both.)
                    same_bits(&a, &b, &dx, &dx_b, &what);
                    cases += 1;
                    if !ok && nan_lane.is_none() {
                        inverted += 1;
                    }
                }
            }
        }
        assert_eq!(cases, 160);
        // The comparison covered inverted states, not only physical ones.
        assert!(inverted >= 8, "{inverted} cases inverted a particle");
    }

    /// A pass's signal speed (`kernel::signal_speeds`: eight particles at a time,
    /// the stretched ones' speeds kept per lane over all batches and folded once)
    /// is the particle-by-particle maximum, bit for bit: 3 full batches and 5 more,
    /// stretched and compressed, from maxima below, among and above theirs.
    #[test]
    fn signal_speeds_are_the_particle_by_particle_maximum() {
        let setup = Setup::<2>::new();
        let ctx = setup.ctx(Alpha::ProductOfShapes);
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
        let mut dx = vec![Vector::<2>::zeros(); n];
        let tile = vec![0u32; n];
        let s = slices(&mut p, &mut dx, &tile, &[]);
        let one_by_one = |max: f64| (0..n).fold(max, |m, q| speed_one(&ctx, &s, q, m));
        let all = one_by_one(0.0);
        let (mut below, mut above) = (0, 0);
        for max in [0.0, 0.5 * all, 0.999 * all, 2.0 * all] {
            let lanes = super::super::signal_speeds(&ctx, &s, max);
            assert_eq!(lanes.to_bits(), one_by_one(max).to_bits(), "from {max}");
            below += usize::from(lanes > max);
            above += usize::from(lanes == max);
        }
        // The particles raised the maximum from below and left it from above.
        assert_eq!((below, above), (3, 1));
    }

    /// A pass tests its lanes' marks once, after its last batch ([`batch`] adds each
    /// batch's into running ones): a batch with an unphysical lane (a NaN in `F`, or
    /// a particle inverted by a steep gradient) leaves them unphysical through
    /// physical batches of either width after it, and physical batches alone leave
    /// them physical.
    #[test]
    fn marks_keep_a_failure_through_later_batches() {
        let setup = Setup::<2>::new();
        let ctx = setup.ctx(Alpha::ProductOfShapes);
        let mut rng = Rng::new(21);
        let m = StressMode {
            slot: 0,
            dt: 1e-3,
            two_step: true,
            moves: true,
            moves_kept: false,
            speed: false,
        };
        let mut pass = |marks: &mut [f64; LANES], nan_lane, steep, width| {
            let nd = nodes::<2, 4>(&mut rng, steep, 0);
            let (mut p, cell) = particles::<2>(&mut rng, nan_lane);
            let mut dx = vec![Vector::<2>::zeros(); LANES];
            let tile = vec![0u32; LANES];
            let mut s = slices(&mut p, &mut dx, &tile, &[]);
            let mut t = Tally::ZERO;
            batch(
                &ctx,
                &mut s,
                0,
                width,
                &cell,
                &nd,
                Pass::Stress(&m),
                &mut Room::new(),
                &mut t,
                marks,
            );
        };
        let mut marks = [0.0; LANES];
        for width in [LANES, HALF, QUARTER, LANES] {
            pass(&mut marks, None, 1.0, width);
        }
        assert!(physical(&marks));
        for (nan_lane, steep, width) in [
            (Some(3), 1.0, LANES),
            (None, 1e5, HALF),
            (Some(1), 1.0, QUARTER),
        ] {
            let mut marks = [0.0; LANES];
            pass(&mut marks, nan_lane, steep, width);
            assert!(
                !physical(&marks),
                "NaN {nan_lane:?}, steep {steep}: the batch itself"
            );
            for width in [HALF, LANES, HALF] {
                pass(&mut marks, None, 1.0, width);
            }
            assert!(!physical(&marks), "NaN {nan_lane:?}, steep {steep}");
        }
    }

    /// The gather's lanes give its scalar body's bits: velocities, the external
    /// work (gravity, and a kept body force), volumes, deformation gradients,
    /// positions or kept increments, the physical-state flag and the signal
    /// speed, for each α, one- and two-step schemes (the latter moving with the
    /// reconstruction), with and without the stress update, moving now or keeping
    /// the increment, FLIP, PIC and a blend, and the [`VARIANTS`].
    #[test]
    fn gather_lanes_match_the_scalar_gather() {
        gather_lanes_match::<2, 4>(12);
    }

    /// [`gather_lanes_match_the_scalar_gather`] in 3D.
    #[test]
    fn gather_lanes_match_the_scalar_gather_in_3d() {
        gather_lanes_match::<3, 8>(14);
    }

    fn gather_lanes_match<const D: usize, const N: usize>(seed: u64) {
        let setup = Setup::<D>::new();
        let mut rng = Rng::new(seed);
        let (mut cases, mut inverted) = (0, 0);
        for alpha in ALPHAS {
            let ctx = setup.ctx(alpha);
            for (two_step, recon, stress, move_now, flip) in [
                (true, true, true, true, 1.0),
                (true, true, false, true, 0.0),
                (true, false, true, true, 0.95),
                (false, false, true, true, 1.0),
                (false, false, true, false, 0.5),
            ] {
                // One room for the pass's batches, as in `stress_lanes_match`.
                let mut room = Room::new();
                for (steep, max0, nan_lane, width) in VARIANTS {
                    let nd = nodes::<D, N>(&mut rng, steep, UPDATED);
                    let m = GatherMode {
                        dt: 1e-3,
                        flip,
                        stress,
                        move_now,
                        two_step,
                        recon,
                        speed: true,
                    };
                    let (mut a, cell) = particles::<D>(&mut rng, nan_lane);
                    let mut b = a.clone();
                    let mut dx = vec![Vector::<D>::zeros(); LANES];
                    let mut dx_b = dx.clone();
                    // A kept body force in half the cases, gravity alone in the others.
                    let accel: Vec<Vector<D>> = if cases % 2 == 0 {
                        (0..LANES)
                            .map(|_| {
                                Vector::<D>::from_fn(|a, _| {
                                    rng.f64() - if a == 1 { 10.0 } else { 0.0 }
                                })
                            })
                            .collect()
                    } else {
                        Vec::new()
                    };
                    let tile = vec![0u32; LANES];
                    let mut sa = slices(&mut a, &mut dx, &tile, &accel);
                    let mut ta = Tally {
                        max_speed: max0,
                        work: 0.25,
                        ..Tally::ZERO
                    };
                    for p in 0..width {
                        let (k, _, _): (Kern<D, N>, _, _) = ctx.weights::<2, N>(
                            &sa.parts.x[p],
                            None,
                            &ctx.local(&sa.parts.x[p], &cell),
                        );
                        gather_one(&ctx, &mut sa, p, &k, &nd, None, &m, &mut ta);
                    }
                    ta.max_speed = (0..width).fold(ta.max_speed, |v, p| speed_one(&ctx, &sa, p, v));
                    let mut sb = slices(&mut b, &mut dx_b, &tile, &accel);
                    let mut work = 0.25;
                    let (ok, top) = one_batch(
                        &ctx,
                        &mut sb,
                        width,
                        &cell,
                        &nd,
                        Pass::Gather(&m),
                        &mut room,
                        max0,
                        &mut work,
                    );
                    let what = format!(
                        "{width} lanes, {alpha:?}, two-step {two_step}, recon {recon}, stress {stress}, move now {move_now}, flip {flip}, steep {steep}, max {max0}, NaN {nan_lane:?}"
                    );
                    assert_eq!(ok, ta.ok, "{what}");
                    assert_eq!(top.to_bits(), ta.max_speed.to_bits(), "{what}");
                    assert_eq!(work.to_bits(), ta.work.to_bits(), "work: {what}");
                    same_bits(&a, &b, &dx, &dx_b, &what);
                    cases += 1;
                    if !ok && nan_lane.is_none() {
                        inverted += 1;
                    }
                }
            }
        }
        assert_eq!(cases, 200);
        assert!(inverted >= 8, "{inverted} cases inverted a particle");
    }
}
