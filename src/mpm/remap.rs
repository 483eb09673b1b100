//! MUSL's remap in one particle pass: grid → particle velocity and particle → grid
//! momentum of the new velocity, at the same positions with the same weights.
//!
//! Modified USL updates the particle velocities from the grid, then maps the new
//! particle momentum back to the grid (at the positions the step's scatter used) to get
//! the velocity that deforms the particles. Done as a gather and a second full scatter,
//! that is two evaluations of every particle's shape functions and a second sum of
//! mass and covered volume that equal the first (the positions did not change). Here
//! one pass evaluates the weights once, updates the velocity and adds `m_p v_p S_i`
//! into a momentum-only field; mass, cover and domain weights stay those of the
//! step's scatter. The particle velocities are bit for bit those of the two passes
//! (same formulas); the nodal momenta are summed per run of particles that share their
//! nodes, as in `kernel::scatter`, so they equal the two passes' to round-off.

use crate::mpm::kernel::{
    clip_at_slip_walls, Ctx, GridPtr, NodeData, Run, SlabOrder, FROM_MOMENTUM, UPDATED,
};
use crate::physics::tensor::Vector;

/// Read-only particle arrays of the remap.
pub struct RemapParts<'a, const D: usize> {
    pub x: &'a [Vector<D>],
    pub mass: &'a [f64],
    pub x0: &'a [Vector<D>],
    pub half: &'a [[f64; D]],
    /// Storage index of each particle's cell's lower corner node.
    pub tile: &'a [u32],
    /// Each particle's local coordinate in its cell (see `kernel::Slices::xi`).
    pub xi: &'a [[f64; D]],
    /// The external force per unit mass the step's scatter kept, or empty.
    pub accel: &'a [Vector<D>],
}

/// What the remap does besides the velocity update.
#[derive(Clone, Copy, Debug)]
pub struct RemapMode {
    pub dt: f64,
    pub flip: f64,
    /// One-step schemes keep the position increment (grid velocity × dt) in `dx`; a
    /// two-step scheme's stress pass sets it from the remapped velocity.
    pub keep_dx: bool,
}

/// The particle arrays the remap writes, shared by its threads.
#[derive(Clone, Copy)]
struct ParticlePtr<const D: usize> {
    v: *mut Vector<D>,
    dx: *mut Vector<D>,
    len: usize,
}

// SAFETY: made in `remap` from `&mut` slices that it holds for its whole run. Each
// particle index is visited by one thread only: `SlabOrder::finish` puts every particle
// into `order` exactly once (a counting sort of their slabs), slabs are
// disjoint ranges of `order`, and `remap_slabs` gives every slab to one thread.
unsafe impl<const D: usize> Send for ParticlePtr<D> {}
unsafe impl<const D: usize> Sync for ParticlePtr<D> {}

/// External work done (gravity, body force, slip-wall clips) and whether every new
/// velocity is finite.
#[derive(Clone, Copy, Debug)]
pub struct RemapTally {
    pub ok: bool,
    pub work: f64,
}

impl RemapTally {
    fn join(a: Self, b: Self) -> Self {
        RemapTally {
            ok: a.ok && b.ok,
            work: a.work + b.work,
        }
    }
}

/// Update the particle velocities `v` from the grid velocities `vel` (FLIP/PIC blend,
/// clipped at slip walls as in `kernel::gather`), keep `dx` if asked, and add the new
/// momentum into `mom` (`D` per node, cleared by the caller), in the slab colours of
/// `kernel::scatter` (the same order whatever the thread count, so the same sums).
#[allow(clippy::too_many_arguments)]
pub fn remap<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: &RemapParts<'_, D>,
    v: &mut [Vector<D>],
    dx: &mut [Vector<D>],
    slabs: &SlabOrder,
    vel: &[f64],
    mom: &mut [f64],
    m: RemapMode,
) -> RemapTally {
    assert!(v.len() == parts.x.len() && (!m.keep_dx || dx.len() == v.len()));
    let pp = ParticlePtr {
        v: v.as_mut_ptr(),
        dx: dx.as_mut_ptr(),
        len: v.len(),
    };
    let grid = GridPtr::new(mom);
    let ns = slabs.slabs();
    let mut t = RemapTally {
        ok: true,
        work: 0.0,
    };
    for colour in 0..2.min(ns) {
        let count = (ns - colour).div_ceil(2);
        let c = remap_slabs::<D, NA, N>(ctx, parts, pp, slabs, vel, grid, colour, count, m);
        t = RemapTally::join(t, c);
    }
    t
}

#[allow(clippy::too_many_arguments)]
fn remap_slabs<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: &RemapParts<'_, D>,
    pp: ParticlePtr<D>,
    slabs: &SlabOrder,
    vel: &[f64],
    grid: GridPtr,
    first: usize,
    count: usize,
    m: RemapMode,
) -> RemapTally {
    let mut t = RemapTally {
        ok: true,
        work: 0.0,
    };
    if count > 1 {
        let Some(half) = slabs.split(first, count) else {
            return t;
        };
        let (a, b) = rayon::join(
            || remap_slabs::<D, NA, N>(ctx, parts, pp, slabs, vel, grid, first, half, m),
            || {
                let rest = count - half;
                remap_slabs::<D, NA, N>(ctx, parts, pp, slabs, vel, grid, first + 2 * half, rest, m)
            },
        );
        return RemapTally::join(a, b);
    }
    // Particles sorted by cell share their nodes in runs: the nodes' velocities are
    // read, and their momentum sums added into the grid, once per run.
    let mut nd = NodeData::<D, N>::new();
    let mut sum = [[0.0; N]; D];
    let mut run = Run::<D, NA, N>::new();
    for &p in &slabs.order[slabs.start[first]..slabs.start[first + 1]] {
        let p = p as usize;
        assert!(p < pp.len, "slab order names particle {p} of {}", pp.len);
        let half = if ctx.gimp { Some(&parts.half[p]) } else { None };
        let (mut k, below, w) = ctx.weights::<NA, N>(&parts.x[p], half, &parts.xi[p]);
        if run.is_new(parts.tile[p], below) {
            if run.started() {
                add_momentum(grid, &run.idx, &mut sum);
            }
            run.enter(ctx, parts.tile[p], below);
            nd.load(&run.idx, vel, &[], None);
        }
        k.ends = run.ends(ctx, &w);
        let mut vn = Vector::<D>::zeros();
        let mut dv = Vector::<D>::zeros();
        for n in 0..N {
            for a in 0..D {
                let (v0, v1) = (nd.v[FROM_MOMENTUM][a][n], nd.v[UPDATED][a][n]);
                vn[a] += k.s[n] * v1;
                dv[a] += k.s[n] * (v1 - v0);
            }
        }
        // SAFETY: p is in bounds (asserted) and visited by this thread only (see
        // `ParticlePtr`); no other reference to v[p] or dx[p] lives meanwhile.
        let vp = unsafe { &mut *pp.v.add(p) };
        let old = *vp;
        let mass = parts.mass[p];
        let mut new = (old + dv) * m.flip + vn * (1.0 - m.flip);
        t.work += clip_at_slip_walls(ctx, &k, &mut new, &vn, mass);
        let a = ctx.accel_kept(parts.accel, parts.x0, p);
        t.work += m.dt * mass * a.dot(&(old + new)) * 0.5;
        *vp = new;
        t.ok &= new.iter().all(|x| x.is_finite());
        if m.keep_dx {
            // SAFETY: as for v[p]; dx has the particles' length when kept (asserted).
            unsafe { *pp.dx.add(p) = vn * m.dt };
        }
        let mv = new * mass;
        for a in 0..D {
            for n in 0..N {
                sum[a][n] += mv[a] * k.s[n];
            }
        }
    }
    if run.started() {
        add_momentum(grid, &run.idx, &mut sum);
    }
    t
}

/// Add one run's momentum sums into the nodes `idx` of `mom` and clear them.
#[inline(always)]
fn add_momentum<const D: usize, const N: usize>(
    grid: GridPtr,
    idx: &[usize; N],
    sum: &mut [[f64; N]; D],
) {
    for n in 0..N {
        // SAFETY: see `kernel::scatter`: same slabs, same colours, so no other thread
        // writes these D numbers; bounds checked by `record`.
        let rec = unsafe { grid.record(idx[n] * D, D) };
        for a in 0..D {
            rec[a] += sum[a][n];
        }
    }
    *sum = [[0.0; N]; D];
}
