//! MUSL's remap in one particle pass: grid → particle velocity and particle → grid
//! momentum of the new velocity, at the same positions with the same weights.
//!
//! Modified USL updates the particle velocities from the grid, then maps the new
//! particle momentum back to the grid (at the positions the step's scatter used) to get
//! the velocity that deforms the particles. Done as a gather and a second full scatter,
//! that is two evaluations of every particle's shape functions and a second sum of
//! mass and covered volume that equal the first (the positions did not change). Here
//! one pass evaluates the weights once, updates the velocity and adds `m_p v_p S_i`
//! into the scatter records' momentum slots alone; mass, cover and domain weights stay
//! those of the step's scatter. The particle velocities are bit for bit those of the
//! two passes (same formulas); the nodal momenta are summed per run of particles that
//! share their nodes, as in `kernel::scatter`, so they equal the two passes' to
//! round-off.

use crate::mpm::kernel::lanes::{self, Room, Weights, HALF, LANES, QUARTER};
use crate::mpm::kernel::{CellAt, Ctx, GridPtr, NodeData, RowPtr, Run, Slab, SlabOrder};
use crate::physics::shape::Reads;
use crate::physics::tensor::Vector;

/// Read-only particle arrays of the remap.
pub struct RemapParts<'a, const D: usize> {
    pub x: &'a [Vector<D>],
    pub mass: crate::mpm::particles::Masses<'a>,
    pub x0: &'a [Vector<D>],
    pub half: &'a [[f64; D]],
    /// Deformation gradients (the domain rule's domains), or empty.
    pub def_grad: &'a [crate::physics::tensor::Mat<D>],
    /// Storage index of each particle's cell's lower corner node.
    pub tile: &'a [u32],
    /// The external force per unit mass the step's scatter kept, or empty.
    pub accel: &'a [Vector<D>],
}

/// What the remap does besides the velocity update.
#[derive(Clone, Copy, Debug)]
pub struct RemapMode {
    pub dt: f64,
    /// The velocity's step, as [`crate::mpm::kernel::GatherMode::kick`].
    pub kick: f64,
    pub flip: f64,
    /// Where a node's momentum goes in `mom`: records of `.0` numbers, its `D`
    /// components from entry `.1` on (the scatter records' momentum slots).
    pub record: (usize, usize),
}

/// The particle arrays the remap writes, shared by its threads: each visits the
/// particles of its slabs, and `SlabOrder::finish` lists every particle exactly once
/// (checked), slabs are disjoint ranges of the order, and `remap_slabs` gives every
/// slab to one thread.
#[derive(Clone, Copy)]
struct ParticlePtr<const D: usize> {
    v: RowPtr<Vector<D>>,
}

/// External work done (gravity, body force, slip-wall clips) and whether every new
/// velocity is finite.
#[derive(Clone, Copy, Debug)]
pub struct RemapTally {
    pub ok: bool,
    pub work: f64,
}

impl RemapTally {
    fn zero() -> Self {
        RemapTally {
            ok: true,
            work: 0.0,
        }
    }

    fn join(a: Self, b: Self) -> Self {
        RemapTally {
            ok: a.ok && b.ok,
            work: a.work + b.work,
        }
    }
}

/// Update the particle velocities `v` from the grid velocities `vel` (FLIP/PIC blend,
/// clipped at slip walls as in `kernel::gather`) and add the new
/// momentum into `mom` (`D` per node where `m.record` says, cleared by the caller), in
/// the slab colours of
/// `kernel::scatter` (the same order whatever the thread count, so the same sums).
#[allow(clippy::too_many_arguments)]
pub fn remap<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: &RemapParts<'_, D>,
    v: &mut [Vector<D>],
    slabs: &SlabOrder,
    vel: &[f64],
    mom: &mut [f64],
    m: RemapMode,
) -> RemapTally {
    assert_eq!(v.len(), parts.x.len());
    let pp = ParticlePtr { v: RowPtr::new(v) };
    slabs.check_reach::<NA>();
    let grid = GridPtr::new(mom);
    let slab = |slab: Slab<'_>| remap_slab::<D, NA, N>(ctx, parts, pp, slab, vel, grid, m);
    slabs.for_each_slab(&RemapTally::zero, &slab, &RemapTally::join)
}

/// How many of the particles `order` names, from its first, the remap takes at once:
/// [`LANES`], [`HALF`] or [`QUARTER`] where as many in a row share the cell corner
/// `tile` of the first, else 1 (`kernel::batch_width`, through the slab order).
#[inline(always)]
fn run_width(tile: &[u32], order: &[u32]) -> usize {
    let first = tile[order[0] as usize];
    let same =
        |b: usize| b <= order.len() && order[1..b].iter().all(|&q| tile[q as usize] == first);
    [LANES, HALF, QUARTER]
        .into_iter()
        .find(|&b| same(b))
        .unwrap_or(1)
}

/// The remap of one slab's particles: their velocities, and their momentum into the
/// records behind `grid`.
fn remap_slab<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: &RemapParts<'_, D>,
    pp: ParticlePtr<D>,
    slab: Slab<'_>,
    vel: &[f64],
    grid: GridPtr,
    m: RemapMode,
) -> RemapTally {
    let mut t = RemapTally::zero();
    // Particles sorted by cell share their nodes in runs: the nodes' velocities are
    // read, and their momentum sums added into the grid, once per run.
    let mut nd = NodeData::<D, N>::new();
    let mut sum = [[0.0; N]; D];
    let mut run = Run::<D, NA, N>::new();
    let mut cell = CellAt::<D>::new();
    let mut room = Room::<D, N>::new();
    // Hat functions: up to eight particles of a run at a time (`kernel::lanes`; in 3D
    // too: unlike the stress pass, the remap's lanes are few numbers, the nodes'
    // weights and two interpolated velocities, and fit the registers). With 3 nodes
    // per axis one at a time (in batches of a window's particles the remap took 1.3 to
    // 1.5 times as long), in runs of particles sorted by window.
    let order = slab.particles;
    let mut i = 0;
    while i < order.len() {
        let p = order[i] as usize;
        let c = *cell.of(ctx, parts.tile[p]);
        let mut enter = |run: &mut Run<D, NA, N>, below: [usize; D]| {
            if run.is_new(ctx, parts.tile[p], below) {
                if run.started() {
                    add_momentum(grid, m.record, &run.idx, &mut sum);
                }
                slab.check_cell(c[D - 1] as i64);
                run.enter(ctx, parts.tile[p], below);
                nd.load(&run.idx, vel, &[], None);
            }
        };
        if NA == 2 {
            enter(&mut run, [0; D]);
            let b = run_width(parts.tile, &order[i..]);
            let ps = &order[i..i + b];
            let (nd, sum, t) = (&nd, &mut sum, &mut t);
            match b {
                LANES => remap_hats(ctx, parts, pp, ps, &c, &run, nd, &mut room.lanes, m, sum, t),
                HALF => remap_hats(ctx, parts, pp, ps, &c, &run, nd, &mut room.half, m, sum, t),
                QUARTER => remap_hats(
                    ctx,
                    parts,
                    pp,
                    ps,
                    &c,
                    &run,
                    nd,
                    &mut room.quarter,
                    m,
                    sum,
                    t,
                ),
                _ => remap_hats(ctx, parts, pp, ps, &c, &run, nd, &mut room.one, m, sum, t),
            }
            i += b;
        } else {
            let xi = ctx.local(&parts.x[p], &c);
            let half = ctx.half_width(parts.half, parts.def_grad, p);
            let reads = Reads {
                gradients: false,
                moments: false,
            };
            let (mut k, below, w) = ctx.weights::<NA, N>(&parts.x[p], half.as_ref(), &xi, reads);
            enter(&mut run, below);
            k.ends = run.ends(ctx, &w);
            room.one.one(&k, run.at_wall(), below);
            remap_batch(
                ctx,
                parts,
                pp,
                &[p as u32],
                &room.one,
                &nd,
                m,
                &mut sum,
                &mut t,
            );
            i += 1;
        }
    }
    if run.started() {
        add_momentum(grid, m.record, &run.idx, &mut sum);
    }
    t
}

/// The remap of particles `ps` (all in `cell` of `run`, hat functions) with their
/// nodes' velocities `nd` and weights `w`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn remap_hats<const D: usize, const NA: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    parts: &RemapParts<'_, D>,
    pp: ParticlePtr<D>,
    ps: &[u32],
    cell: &[f64; D],
    run: &Run<D, NA, N>,
    nd: &NodeData<D, N>,
    w: &mut Weights<D, N, B>,
    m: RemapMode,
    sum: &mut [[f64; N]; D],
    t: &mut RemapTally,
) {
    let ps: &[u32; B] = ps.try_into().expect("a full batch");
    // `Ctx::local` lane by lane: from a contiguous batch of positions, as the slab
    // order of sorted particles mostly gives (whole vectors), else one by one.
    let p0 = ps[0] as usize;
    let contiguous = (1..B).all(|l| ps[l] as usize == p0 + l) && p0 + B <= parts.x.len();
    let xi = if contiguous {
        lanes::local::<D, B>(ctx, parts.x, p0..p0 + B, cell)
    } else {
        let mut xi = [[0.0; B]; D];
        for a in 0..D {
            let (lower, inv_h, c) = (ctx.geom.lower[a], ctx.geom.inv_h[a], cell[a]);
            for (l, &p) in ps.iter().enumerate() {
                xi[a][l] = (parts.x[p as usize][a] - lower) * inv_h - c;
            }
        }
        xi
    };
    w.hats(ctx, &xi, run, false);
    remap_batch(ctx, parts, pp, ps, w, nd, m, sum, t);
}

/// The remap of particles `ps` (sharing their nodes) with weights `w` over their
/// nodes' velocities `nd`: the new velocities (FLIP/PIC blend, clipped at slip walls),
/// the work on them, and their momentum into the run's sums `sum`,
/// particle by particle in order.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn remap_batch<const D: usize, const N: usize, const B: usize>(
    ctx: &Ctx<'_, D>,
    parts: &RemapParts<'_, D>,
    pp: ParticlePtr<D>,
    ps: &[u32; B],
    w: &Weights<D, N, B>,
    nd: &NodeData<D, N>,
    m: RemapMode,
    sum: &mut [[f64; N]; D],
    t: &mut RemapTally,
) {
    let (vn, dv) = w.interpolate(nd);
    let sh = w.shape();
    // In 2D each particle's weights over the nodes as one row, so that its momentum
    // is added into the sums a vector over the nodes at a time: read down the lanes'
    // columns, they were a scalar product and add per node (31 instructions a
    // particle). (In 3D the 8 × 8 transposition cost more than it saved: the remap's
    // time 1.16×.)
    let by_rows = N <= 4 && B > 1;
    let mut rows = [[0.0; N]; B];
    if by_rows {
        for (n, col) in sh.iter().enumerate() {
            for (l, row) in rows.iter_mut().enumerate() {
                row[n] = col[l];
            }
        }
    }
    // The walls' test outside the particles' loop: away from walls (nearly every
    // batch) the loop has no clip in it, and its lanes stay in registers.
    let rows = &rows;
    if w.at_wall() {
        remap_each::<D, N, B, true>(ctx, parts, pp, ps, w, (&vn, &dv), rows, m, sum, t);
    } else {
        remap_each::<D, N, B, false>(ctx, parts, pp, ps, w, (&vn, &dv), rows, m, sum, t);
    }
}

/// The particles' part of [`remap_batch`], with the slip walls' clip if `WALL`.
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
#[inline(always)]
fn remap_each<const D: usize, const N: usize, const B: usize, const WALL: bool>(
    ctx: &Ctx<'_, D>,
    parts: &RemapParts<'_, D>,
    pp: ParticlePtr<D>,
    ps: &[u32; B],
    w: &Weights<D, N, B>,
    (vn, dv): (&[[f64; B]; D], &[[f64; B]; D]),
    rows: &[[f64; N]; B],
    m: RemapMode,
    sum: &mut [[f64; N]; D],
    t: &mut RemapTally,
) {
    let by_rows = N <= 4 && B > 1;
    let sh = w.shape();
    for (l, &p) in ps.iter().enumerate() {
        let p = p as usize;
        // SAFETY: p is visited by this thread only (see `ParticlePtr`); no other
        // reference to v[p] lives meanwhile.
        let vp = unsafe { pp.v.row(p) };
        let old = *vp;
        let mass = parts.mass.get(p);
        let mut new = Vector::<D>::zeros();
        let mut vnl = Vector::<D>::zeros();
        for a in 0..D {
            new[a] = (old[a] + dv[a][l]) * m.flip + vn[a][l] * (1.0 - m.flip);
            vnl[a] = vn[a][l];
        }
        if WALL {
            t.work += w.clip(ctx, l, &mut new, &vnl, mass);
        }
        let a = ctx.accel_kept(parts.accel, parts.x0, p);
        t.work += m.kick * mass * a.dot(&(old + new)) * 0.5;
        *vp = new;
        t.ok &= new.iter().all(|x| x.is_finite());
        let mv = new * mass;
        for a in 0..D {
            for n in 0..N {
                sum[a][n] += mv[a] * if by_rows { rows[l][n] } else { sh[n][l] };
            }
        }
    }
}

/// Add one run's momentum sums into the nodes `idx` of `mom`, records of `width`
/// numbers with the momentum from entry `at` on, and clear them.
#[inline(always)]
fn add_momentum<const D: usize, const N: usize>(
    grid: GridPtr,
    (width, at): (usize, usize),
    idx: &[usize; N],
    sum: &mut [[f64; N]; D],
) {
    for n in 0..N {
        // SAFETY: see `kernel::scatter`: same slabs, same colours, so no other thread
        // writes these D numbers; bounds checked by `record`.
        let rec = unsafe { grid.record(idx[n] * width + at, D) };
        for a in 0..D {
            rec[a] += sum[a][n];
        }
    }
    *sum = [[0.0; N]; D];
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::scene::Face;
    use crate::mpm::kernel::{Run, UPDATED};
    use crate::physics::material::{lame, neo_hookean::NeoHookean, Material};
    use crate::physics::shape::{Alpha, Geom};
    use decomposition::splitmix::Rng;
    use decomposition::Tiles;

    /// The bits of `x`, every NaN as one: Rust leaves a NaN's sign and payload open
    /// (Miri draws them at random), and the remap compares widths, not NaN payloads.
    fn bits(x: f64) -> u64 {
        if x.is_nan() {
            f64::NAN.to_bits()
        } else {
            x.to_bits()
        }
    }

    /// The remap gives the same bits whatever the batch width (in `D` dimensions,
    /// `N` nodes): new velocities (FLIP, PIC and a blend; clipped at a slip wall),
    /// the external work (gravity, a kept body force, the walls'),
    /// the momentum sums and the finite-state flag, for every width, with and without
    /// walls, and with a non-finite nodal velocity.
    fn lanes_match<const D: usize, const N: usize>(seed: u64) {
        let geom = Geom::<D>::new([0.0; D], [1.0; D], [10; D], [false; D]);
        let tiles = Tiles::<D>::new([12; D], [1; D]);
        let (lambda, mu) = lame(1e3, 0.2);
        let materials = [Material::NeoHookean(NeoHookean {
            lambda,
            mu,
            density: 1.0,
        })];
        let mut rooms = (Room::<D, N>::new(), Room::<D, N>::new());
        let mut rng = Rng::new(seed);
        let mut cases = 0;
        for walls in [false, true] {
            let ctx = Ctx {
                geom: &geom,
                node_lo: [-1; D],
                tiles: &tiles,
                wide: false,
                domain: false,
                alpha: Alpha::ProductOfShapes,
                materials: &materials,
                kind_mass: &[1.0],
                kind_vol0: &[1.0],
                gravity: Vector::<D>::from_fn(|a, _| if a == 1 { -9.81 } else { 0.0 }),
                body_force: None,
                faces: std::array::from_fn(|a| [if a == 1 { Face::Fixed } else { Face::Slip }; 2]),
                walls,
            };
            for flip in [1.0, 0.0, 0.95] {
                for (width, body, nan) in [
                    (LANES, false, false),
                    (LANES, true, false),
                    (HALF, true, false),
                    (QUARTER, true, false),
                    (LANES, false, true),
                ] {
                    let n = LANES;
                    // In cell 3 along every axis (h = 0.1), one at its lower face.
                    let cell = [3.0; D];
                    let x: Vec<Vector<D>> = (0..n)
                        .map(|l| {
                            Vector::<D>::from_fn(|a, _| {
                                0.3 + 0.1 * if l == 0 && a == 0 { 0.0 } else { rng.f64() }
                            })
                        })
                        .collect();
                    // A kind per particle, so that the masses differ.
                    let kind_mass: Vec<f64> = (0..n).map(|_| 1e-4 * (0.5 + rng.f64())).collect();
                    let kind: Vec<u16> = (0..n as u16).collect();
                    let accel: Vec<Vector<D>> = if body {
                        (0..n)
                            .map(|_| Vector::<D>::from_fn(|_, _| rng.f64() - 5.0))
                            .collect()
                    } else {
                        Vec::new()
                    };
                    let tile = vec![0u32; n];
                    let parts = RemapParts {
                        x: &x,
                        mass: crate::mpm::particles::Masses {
                            kind_mass: &kind_mass,
                            kind: &kind,
                        },
                        x0: &x,
                        half: &[],
                        def_grad: &[],
                        tile: &tile,
                        accel: &accel,
                    };
                    let mut nd = NodeData::<D, N>::new();
                    for a in 0..D {
                        for k in 0..N {
                            for slot in 0..2 {
                                nd.v[slot][a][k] = rng.f64() - 0.5;
                            }
                        }
                    }
                    if nan {
                        nd.v[UPDATED][1][2] = f64::INFINITY;
                    }
                    let m = RemapMode {
                        dt: 1e-3,
                        kick: 1e-3,
                        flip,
                        record: (D, 0),
                    };
                    let v0: Vec<Vector<D>> = (0..n)
                        .map(|_| Vector::<D>::from_fn(|_, _| rng.f64() - 0.5))
                        .collect();
                    let (mut va, mut vb) = (v0.clone(), v0);
                    let ptr = |v: &mut Vec<Vector<D>>| ParticlePtr { v: RowPtr::new(v) };
                    let mut ta = RemapTally {
                        ok: true,
                        work: 0.5,
                    };
                    let mut tb = ta;
                    let mut suma = [[0.25; N]; D];
                    let mut sumb = suma;
                    // With walls, a slip wall at the cell's lower nodes along the
                    // first axis and a fixed wall at its upper nodes along the second.
                    let run = Run::<D, 2, N>::with_sides(std::array::from_fn(|a| match a {
                        0 if walls => [-1, 0],
                        1 if walls => [0, 1],
                        _ => [0, 0],
                    }));
                    // One batch of particles `ps` through `remap_hats` with a room of
                    // the batch's width.
                    macro_rules! batch {
                        ($pp:expr, $ps:expr, $room:expr, $sum:expr, $t:expr) => {
                            remap_hats(&ctx, &parts, $pp, $ps, &cell, &run, &nd, $room, m, $sum, $t)
                        };
                    }
                    let pa = ptr(&mut va);
                    for p in 0..width as u32 {
                        batch!(pa, &[p], &mut rooms.0.one, &mut suma, &mut ta);
                    }
                    let pb = ptr(&mut vb);
                    let ps: Vec<u32> = (0..width as u32).collect();
                    let rb = &mut rooms.1;
                    match width {
                        LANES => batch!(pb, &ps, &mut rb.lanes, &mut sumb, &mut tb),
                        HALF => batch!(pb, &ps, &mut rb.half, &mut sumb, &mut tb),
                        _ => batch!(pb, &ps, &mut rb.quarter, &mut sumb, &mut tb),
                    }
                    let what = format!(
                        "{D}D, {width} lanes, flip {flip}, body force {body}, infinite node {nan}, walls {walls}"
                    );
                    assert_eq!(ta.ok, tb.ok, "{what}");
                    assert_eq!(ta.ok, !nan, "{what}");
                    assert_eq!(bits(ta.work), bits(tb.work), "work: {what}");
                    for p in 0..n {
                        for a in 0..D {
                            assert_eq!(bits(va[p][a]), bits(vb[p][a]), "v {p}: {what}");
                        }
                    }
                    for a in 0..D {
                        for k in 0..N {
                            assert_eq!(bits(suma[a][k]), bits(sumb[a][k]), "sum: {what}");
                        }
                    }
                    cases += 1;
                }
            }
        }
        assert_eq!(cases, 30);
    }

    #[test]
    fn remap_is_the_same_at_every_width() {
        lanes_match::<2, 4>(13);
        lanes_match::<3, 8>(14);
    }
}
