//! Grid to particle, one particle at a time or in lanes: the gather (velocity, position, velocity gradient) and the stress update.

use super::*;

/// Deform particle `p` of `s` by `l` over `dt`: volume, deformation gradient, stress.
/// Returns whether the new state is physical.
#[inline(always)]
pub(super) fn deform<const D: usize>(
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
pub(super) fn volume_finite<const D: usize>(s: &Slices<'_, D>, p: usize) -> bool {
    s.parts.vol.get(p).is_none_or(|v| v.is_finite())
}

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
pub(super) fn by_runs<const D: usize, const NA: usize, const N: usize>(
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

/// The gather for particle `p` of `s` with weights `k` over its nodes' data `nd`
/// (loaded, with the differences of the updated slot if `m.stress`): its new
/// velocity, the work on it, its deformation and move as `m` asks, accounted in `t`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn gather_one<const D: usize, const N: usize>(
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

/// The stress pass for particle `p` of `s` with weights `k` over its nodes' data
/// `nd` (loaded, with the differences of slot `m.slot`): deform it, move it as `m`
/// asks, and account for it in `t`.
#[inline(always)]
pub(super) fn stress_one<const D: usize, const N: usize>(
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
