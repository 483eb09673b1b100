//! Grid to particle: the gather (velocity, position, velocity gradient) and the stress
//! update, each written once over `B` particles at a time ([`lanes`]).

use super::*;
use lanes::{Room, Weights};

/// The running maximum `max` of the signal speed the time step must resolve (wave
/// speed plus particle speed), raised by particle `p`'s where that is larger
/// ([`Material::raise_signal_speed`]).
#[inline(always)]
pub(super) fn raise_speed<const D: usize>(
    ctx: &Ctx<'_, D>,
    s: &Slices<'_, D>,
    p: usize,
    max: f64,
) -> f64 {
    let kind = s.parts.kind[p] as usize;
    let j = if s.parts.vol.is_empty() {
        det(&s.parts.def_grad[p])
    } else {
        s.parts.vol[p] / ctx.kind_vol0[kind]
    };
    ctx.materials[kind].raise_signal_speed(j, s.parts.v[p].norm(), max)
}

/// A grid → particle pass, as [`by_runs`] runs it over batches of particles.
#[derive(Clone, Copy)]
pub(crate) enum Pass<'a> {
    Stress(&'a StressMode),
    /// The gather, with XPIC's field loaded if `.1`.
    Gather(&'a GatherMode, bool),
}

impl Pass<'_> {
    /// Whether the pass reports the fastest signal speed.
    fn speed(self) -> bool {
        match self {
            Pass::Stress(m) => m.speed,
            Pass::Gather(m, _) => m.speed,
        }
    }

    /// Whether the pass reads `L̄` at the particles ([`Weights::lbar`]).
    fn lbar(self) -> bool {
        match self {
            Pass::Stress(m) => m.two_step,
            Pass::Gather(m, _) => m.two_step && (m.recon || m.stress),
        }
    }

    /// Whether the pass forms a velocity gradient.
    fn gradients(self) -> bool {
        match self {
            Pass::Stress(_) => true,
            Pass::Gather(m, _) => m.stress,
        }
    }

    /// The pass over particles `p0 .. p0 + B` of `s` with weights `w` over their
    /// nodes' data `nd`, the external work into `work`: the lanes' marks of an
    /// unphysical state.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(crate) fn on<const D: usize, const N: usize, const B: usize>(
        self,
        ctx: &Ctx<'_, D>,
        s: &mut Slices<'_, D>,
        p0: usize,
        w: &Weights<D, N, B>,
        nd: &NodeData<D, N>,
        work: &mut f64,
    ) -> [f64; B] {
        match self {
            Pass::Stress(m) => stress_batch(ctx, s, p0, w, nd, m, work),
            Pass::Gather(m, xpic) => gather_batch(ctx, s, p0, w, nd, xpic, m, work),
        }
    }
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
        // The nodes' data of a run, read once per run.
        let load = |nd: &mut NodeData<D, N>, idx: &[usize; N]| {
            nd.load(idx, vel, avg, xpic);
            if m.stress {
                nd.load_differences_from(idx, vel, UPDATED);
            }
        };
        by_runs::<D, NA, N>(ctx, &mut s, Pass::Gather(&m, xpic.is_some()), load)
    })
}

/// What [`interpolate`] reads of the particles: where they are, their half-widths and
/// deformation gradients (for shape functions that have a domain) and cells.
pub struct Placed<'a, const D: usize> {
    pub x: &'a [Vector<D>],
    pub half: &'a [[f64; D]],
    pub def_grad: &'a [Mat<D>],
    pub tile: &'a [u32],
}

/// A grid field of `D` numbers per node interpolated at every particle with the
/// scatter's weights, `out[p] = Σ_i S_i(x_p) src_i` (ghosts included in `src`), in
/// fixed chunks on threads.
pub fn interpolate<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    at: Placed<'_, D>,
    src: &[f64],
    out: &mut [Vector<D>],
) {
    let Placed {
        x,
        half,
        def_grad,
        tile,
    } = at;
    assert!(x.len() == out.len() && tile.len() == out.len());
    out.par_chunks_mut(GRAIN).enumerate().for_each(|(k, out)| {
        let mut run = Run::<D, NA, N>::new();
        let mut cell = CellAt::<D>::new();
        for (i, o) in out.iter_mut().enumerate() {
            let p = k * GRAIN + i;
            let half = ctx.half_width(half, def_grad, p);
            let c = *cell.of(ctx, tile[p]);
            let xi = ctx.local(&x[p], &c);
            let reads = Reads {
                gradients: false,
                moments: false,
            };
            let (w, below, _) = ctx.weights::<NA, N>(&x[p], half.as_ref(), &xi, reads);
            run.enter_if_new(ctx, tile[p], below);
            let mut u = Vector::<D>::zeros();
            for (n, &s) in w.s.iter().enumerate() {
                let at = run.idx[n] * D;
                for a in 0..D {
                    u[a] += s * src[at + a];
                }
            }
            *o = u;
        }
    });
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
        let load = |nd: &mut NodeData<D, N>, idx: &[usize; N]| {
            nd.load(idx, vel, avg, None);
            nd.load_differences_from(idx, vel, m.slot);
        };
        by_runs::<D, NA, N>(ctx, &mut s, Pass::Stress(&m), load)
    })
}

/// One task's particles `s` of a grid → particle pass, in order: with hat functions
/// [`LANES`], [`HALF`] or [`QUARTER`] particles of a run at a time where as many in a
/// row share their cell ([`batch_width`]), else one; with 3 nodes per axis one at a
/// time (their nodes depend on the particle's place in its cell, and particles sorted
/// by window share them across cells: in batches the pass gained 3 % of the step on
/// the domain rule's block drop and nothing on GIMP's). Each run's node data are read once
/// by `load`; then, if the pass reports it, the task's fastest signal speed
/// ([`signal_speeds`]). Returns the task's tally.
#[inline(always)]
pub(super) fn by_runs<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    pass: Pass<'_>,
    load: impl Fn(&mut NodeData<D, N>, &[usize; N]),
) -> Tally {
    let mut t = Tally::ZERO;
    let batches = lanes::batches::<D>(ctx.wide);
    let mut nd = NodeData::<D, N>::new();
    let mut run = Run::<D, NA, N>::new();
    let mut cell = CellAt::<D>::new();
    let mut marks = [0.0; LANES];
    let mut room = Room::<D, N>::new();
    let mut p = 0;
    while p < s.len() {
        let c = *cell.of(ctx, s.tile[p]);
        if NA == 2 {
            if run.enter_if_new(ctx, s.tile[p], [0; D]) {
                load(&mut nd, &run.idx);
            }
            let b = batch_width(batches, s.tile, p);
            let (w, m) = (&mut t.work, &mut marks);
            match b {
                LANES => hat_batch(ctx, s, p, &c, &run, &nd, pass, &mut room.lanes, w, m),
                HALF => hat_batch(ctx, s, p, &c, &run, &nd, pass, &mut room.half, w, m),
                QUARTER => hat_batch(ctx, s, p, &c, &run, &nd, pass, &mut room.quarter, w, m),
                _ => hat_batch(ctx, s, p, &c, &run, &nd, pass, &mut room.one, w, m),
            }
            p += b;
        } else {
            let xi = ctx.local(&s.parts.x[p], &c);
            let half = ctx.half_width(s.parts.half, s.parts.def_grad, p);
            let (mut k, below, w) =
                ctx.weights::<NA, N>(&s.parts.x[p], half.as_ref(), &xi, Reads::ALL);
            if run.enter_if_new(ctx, s.tile[p], below) {
                load(&mut nd, &run.idx);
            }
            k.ends = run.ends(ctx, &w);
            room.one.one(&k, run.at_wall(), below);
            if pass.lbar() {
                room.one.lbar(&nd);
            }
            marks[0] += pass.on(ctx, s, p, &room.one, &nd, &mut t.work)[0];
            p += 1;
        }
    }
    t.ok &= lanes::physical(&marks);
    if pass.speed() {
        t.max_speed = signal_speeds(ctx, s, t.max_speed);
    }
    t
}

/// `pass` over particles `p .. p + B` of `s`, hat functions in `cell` of `run` whose
/// node data `nd` holds, with weights `w`, the work into `work` and the lanes' marks
/// into `marks`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn hat_batch<const D: usize, const NA: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p: usize,
    cell: &[f64; D],
    run: &Run<D, NA, N>,
    nd: &NodeData<D, N>,
    pass: Pass<'_>,
    w: &mut Weights<D, N, B>,
    work: &mut f64,
    marks: &mut [f64; LANES],
) {
    let xi = lanes::local::<D, B>(ctx, s.parts.x, p..p + B, cell);
    w.hats(ctx, &xi, run, pass.gradients());
    if pass.lbar() {
        w.lbar(nd);
    }
    let bad = pass.on(ctx, s, p, w, nd, work);
    for l in 0..B {
        marks[l] += bad[l];
    }
}

/// The running maximum `max` of the signal speed raised by every particle of `s`,
/// after the pass that set their volumes and velocities: eight at a time through
/// the lanes ([`lanes::raise_speed`], vector operations where they share a
/// material), the rest one by one. The same maximum, bit for bit, as raising it
/// particle by particle in the pass: a maximum does not depend on the order. (In the
/// pass, one particle at a time, it was a chain of branches: 4 % of the 3D step.)
#[inline(always)]
pub(super) fn signal_speeds<const D: usize>(ctx: &Ctx<'_, D>, s: &Slices<'_, D>, max: f64) -> f64 {
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

/// How many particles from `p` the particle loops take at once: [`LANES`], [`HALF`]
/// or [`QUARTER`] where as many in a row share the cell corner `tile[p]` (and
/// `batches`), else 1.
#[inline(always)]
pub(super) fn batch_width(batches: bool, tile: &[u32], p: usize) -> usize {
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

/// The gather of particles `p0 .. p0 + B` of `s` with weights `w` over their nodes'
/// data `nd` (loaded, with the differences of the updated slot if `m.stress`, and
/// XPIC's field if `xpic`): the new velocity (FLIP/PIC blend, or XPIC's), clipped at
/// slip walls, the external work into `work` particle by particle in order, the
/// velocity gradient and deformation (`m.stress`), and the move (`m.move_now`).
/// Returns the lanes' marks of an unphysical state, a non-finite velocity included.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn gather_batch<const D: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p0: usize,
    w: &Weights<D, N, B>,
    nd: &NodeData<D, N>,
    xpic: bool,
    m: &GatherMode,
    work: &mut f64,
) -> [f64; B] {
    let r = p0..p0 + B;
    let (vn, dv) = w.interpolate(nd);
    // The velocity the particles move with: the grid's, or for a two-step scheme
    // whose L̄ and v̄ of slot 1 are at hand, their reconstruction.
    let u = if m.recon {
        w.moving_velocity(ctx, nd, UPDATED)
    } else {
        vn
    };
    // XPIC(m): V = S v⁺ + S ((m − 1) v − m v*), the field precomputed.
    let mut vx = vn;
    if xpic {
        w.add_field(nd, &mut vx);
    }
    let vs: &mut [Vector<D>; B] = (&mut s.parts.v[r.clone()])
        .try_into()
        .expect("a full batch");
    let mut bad = [0.0; B];
    for l in 0..B {
        let old = vs[l];
        let mut new = Vector::<D>::zeros();
        for a in 0..D {
            new[a] = if xpic {
                vx[a][l]
            } else {
                (old[a] + dv[a][l]) * m.flip + vn[a][l] * (1.0 - m.flip)
            };
        }
        let p = p0 + l;
        let mass = particles::mass_of(ctx.kind_mass, s.parts.kind, p);
        // At a slip wall the grid's normal velocity is zeroed before and after the
        // force update alike, so FLIP's increment never tells a particle that the
        // wall stopped it: its normal component is clipped to the one it moves with
        // (which vanishes at the wall). Clipping, not PIC, which would also damp
        // legitimate subgrid motion; not at fixed walls, where the material is
        // clamped and clipping pressed a compressed root through the clamp.
        if w.at_wall() {
            *work += w.clip(ctx, l, &mut new, &lanes::column(&u, l), mass);
        }
        let acc = ctx.accel_kept(s.accel, s.parts.x0, p);
        *work += m.kick * mass * acc.dot(&(old + new)) * 0.5;
        vs[l] = new;
        for a in 0..D {
            bad[l] += new[a] * 0.0;
        }
    }
    if m.stress {
        let lg = w.velocity_gradient(nd, UPDATED, m.two_step);
        let deformed = w.deform(ctx, s, r.clone(), &lg, m.dt);
        for l in 0..B {
            bad[l] += deformed[l];
        }
    }
    if m.move_now {
        lanes::advance(s, r, &u, m.dt);
    }
    bad
}

/// The stress pass of particles `p0 .. p0 + B` of `s` with weights `w` over their
/// nodes' data `nd` (loaded, with the differences of slot `m.slot`): the velocity
/// gradient and deformation, and if `m.moves` the move with the velocity of slot
/// `m.slot` (a two-step scheme's reconstruction, else the grid interpolation; the
/// velocity into a slip wall clipped to it, the wall's work into `work`). Returns the
/// lanes' marks of an unphysical state; the signal speed is left to the caller.
#[inline(always)]
fn stress_batch<const D: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    s: &mut Slices<'_, D>,
    p0: usize,
    w: &Weights<D, N, B>,
    nd: &NodeData<D, N>,
    m: &StressMode,
    work: &mut f64,
) -> [f64; B] {
    let r = p0..p0 + B;
    let lg = w.velocity_gradient(nd, m.slot, m.two_step);
    let bad = w.deform(ctx, s, r.clone(), &lg, m.dt);
    if m.moves {
        let u = if m.two_step {
            w.moving_velocity(ctx, nd, m.slot)
        } else {
            w.velocity_at(nd, m.slot)
        };
        if w.at_wall() {
            for (l, p) in r.clone().enumerate() {
                // Only particles touching a wall's nodes can be clipped: the others'
                // velocities are neither read nor written here.
                if w.touches_wall(l) {
                    let mut v = s.parts.v[p];
                    let mass = particles::mass_of(ctx.kind_mass, s.parts.kind, p);
                    *work += w.clip(ctx, l, &mut v, &lanes::column(&u, l), mass);
                    s.parts.v[p] = v;
                }
            }
        }
        lanes::advance(s, r, &u, m.dt);
    }
    bad
}
