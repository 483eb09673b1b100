//! Seeding: the particles a scene's bodies put on the lattice of each cell, and the
//! shapes' bounds and insides.

use super::{Carries, Kinds, Particles};
use crate::input::plan::{cut_levels, cut_samples};
use crate::input::scene::{BodySpec, Scene, Seeding, Shape};
use crate::physics::benchmark::Benchmark;
use crate::physics::material::Material;
use crate::physics::shape::Geom;
use crate::physics::tensor::{det, vector, Mat, Vector};

impl<const D: usize> Particles<D> {
    /// Seed the particles of every body whose current position falls in the owned
    /// cells `[cell_lo, cell_hi)`, in global id order.
    /// `materials`: per kind of `kinds`.
    pub fn seed(
        scene: &Scene,
        geom: &Geom<D>,
        (kinds, materials): (&Kinds, &[Material]),
        benchmark: Option<&Benchmark<D>>,
        cell_lo: [usize; D],
        cell_hi: [usize; D],
    ) -> Self {
        let carries = Carries::for_scene(scene);
        let mut p = Particles::<D>::default();
        let plan = &scene.plan;
        let seeds: Vec<BodySeed<D>> = scene
            .bodies
            .iter()
            .zip(plan.body_kind.iter().zip(&plan.body_cut_kinds))
            .map(|(body, (&k, &cut_kinds))| BodySeed {
                mat: &materials[k],
                kind: k,
                cut_kinds,
                vol0: &kinds.vol0,
                half: std::array::from_fn(|a| 0.5 * geom.h[a] / body.particles_per_cell as f64),
                carries,
            })
            .collect();
        each_seeded(
            scene,
            geom,
            benchmark,
            (cell_lo, cell_hi),
            |b, id, share, xr, motion| {
                p.push_seeded(&seeds[b], (id, share), xr, motion);
                true
            },
        );
        p
    }

    /// How many particles [`seed`](Particles::seed) would put in the owned cells
    /// `[cell_lo, cell_hi)`, without seeding them; the count stops at `stop_at`.
    pub fn count_seeded(
        scene: &Scene,
        geom: &Geom<D>,
        benchmark: Option<&Benchmark<D>>,
        (cell_lo, cell_hi): ([usize; D], [usize; D]),
        stop_at: u64,
    ) -> u64 {
        let mut n = 0u64;
        if stop_at > 0 {
            each_seeded(
                scene,
                geom,
                benchmark,
                (cell_lo, cell_hi),
                |_, _, _, _, _| {
                    n += 1;
                    n < stop_at
                },
            );
        }
        n
    }

    /// Append a new particle `id` of `seed`'s body with `share` of its lattice box
    /// ([`cut_levels`]ths): reference position `xr`, position, velocity and deformation
    /// gradient `(x, v, f)`, the stress of `f`, and every material state the scene
    /// carries at its declared initial value.
    fn push_seeded(
        &mut self,
        seed: &BodySeed<D>,
        (id, share): (u64, u32),
        xr: Vector<D>,
        (x, v, f): (Vector<D>, Vector<D>, Mat<D>),
    ) {
        let (mat, carries) = (seed.mat, seed.carries);
        let levels = cut_levels(D);
        let kind = match seed.cut_kinds {
            Some(first) if share < levels => first + share as usize - 1,
            _ => seed.kind,
        };
        let vol0 = seed.vol0[kind];
        let j = det(&f);
        self.x.push(x);
        self.v.push(v);
        debug_assert!(
            !carries.mass && !carries.vol0,
            "a seeded particle's are its kind's"
        );
        if carries.vol {
            self.vol.push(vol0 * j);
        }
        if carries.stress {
            let mut st = Mat::<D>::zeros();
            if mat.needs_def_grad() {
                let none = crate::physics::material::Internal {
                    plastic: None,
                    damage: None,
                    stress_zz: None,
                };
                let j = crate::physics::material::VolumeChange::NONE;
                mat.update_stress(&mut st, &Mat::<D>::zeros(), &f, 0.0, j, none);
            }
            self.stress.push(st);
        }
        if carries.def_grad {
            self.def_grad.push(f);
        }
        self.kind.push(kind as u16);
        self.id.push(id);
        if carries.x0 {
            self.x0.push(xr);
        }
        if carries.half {
            // A cut particle's box shrinks to its volume (a whole one's keeps its bits).
            let scale = (f64::from(share) / f64::from(levels)).powf(1.0 / D as f64);
            self.half.push(seed.half.map(|w| w * scale));
        }
        self.push_initial_state(carries);
        debug_assert!(self.consistent(carries));
    }
}

/// Calls `f(body, id, share, xr, (x, v, F))` for each particle of every body whose
/// current position falls in the owned cells `[cell_lo, cell_hi)`, in global id order
/// ([`lattice_points`], [`initial_motion`]); stops when `f` returns false.
fn each_seeded<const D: usize>(
    scene: &Scene,
    geom: &Geom<D>,
    benchmark: Option<&Benchmark<D>>,
    (cell_lo, cell_hi): ([usize; D], [usize; D]),
    mut f: impl FnMut(usize, u64, u32, Vector<D>, (Vector<D>, Vector<D>, Mat<D>)) -> bool,
) {
    // Benchmarks may start displaced: look that many cells beyond the block.
    let disp = match benchmark {
        Some(Benchmark::AxisAlignedMms { a, .. }) => a.abs(),
        _ => 0.0,
    };
    let mut id_base = 0u64;
    for (b, body) in scene.bodies.iter().enumerate() {
        let sub = body.particles_per_cell.pow(D as u32);
        let (c0, c1) = body_cells::<D>(body, geom);
        // Restrict to the block, padded by the initial displacement.
        let pad: [usize; D] = std::array::from_fn(|a| 1 + (disp * geom.inv_h[a]).ceil() as usize);
        let r0: [usize; D] = std::array::from_fn(|a| c0[a].max(cell_lo[a].saturating_sub(pad[a])));
        let r1: [usize; D] = std::array::from_fn(|a| c1[a].min(cell_hi[a] + pad[a]));
        let dims: [usize; D] = std::array::from_fn(|a| c1[a] - c0[a]);
        let body_cells: usize = dims.iter().product();
        let mut go_on = true;
        if (0..D).all(|a| r0[a] < r1[a]) {
            lattice_points::<D>(body, geom, (c0, c1), (r0, r1), |lin, s, xref, share| {
                let xr = vector::<D>(&xref);
                let (x, v, def) = initial_motion(body, benchmark, &xr);
                let (c, _) = geom.locate(&std::array::from_fn(|a| x[a]));
                if (0..D).any(|a| c[a] < cell_lo[a] as i64 || c[a] >= cell_hi[a] as i64) {
                    return true;
                }
                let id = id_base + (lin * sub + s) as u64;
                go_on = f(b, id, share, xr, (x, v, def));
                go_on
            });
        }
        if !go_on {
            return;
        }
        id_base += (body_cells * sub) as u64;
    }
}

/// What the particles of one body share when they are seeded.
struct BodySeed<'m, const D: usize> {
    mat: &'m Material,
    /// The body's kind of particle of a whole box.
    kind: usize,
    /// Seeded `cut`: the kind of its particles of share 1 ([`Plan::body_cut_kinds`]).
    ///
    /// [`Plan::body_cut_kinds`]: crate::input::plan::Plan::body_cut_kinds
    cut_kinds: Option<usize>,
    /// The reference volume of each kind.
    vol0: &'m [f64],
    /// GIMP half-widths.
    half: [f64; D],
    carries: Carries,
}

/// The initial position, velocity and deformation gradient of the particle at
/// reference position `xr`: a benchmark's exact state at t = 0 (or rest), plus the
/// body's velocity and velocity gradient.
fn initial_motion<const D: usize>(
    body: &BodySpec,
    benchmark: Option<&Benchmark<D>>,
    xr: &Vector<D>,
) -> (Vector<D>, Vector<D>, Mat<D>) {
    let (mut x, mut v, mut f) = (*xr, Vector::<D>::zeros(), Mat::<D>::identity());
    if let Some(b) = benchmark {
        let (u, vel) = b.exact(xr, 0.0);
        x += u;
        v = vel;
        f = b.deformation_gradient(xr, 0.0);
    }
    if let Some(bv) = &body.velocity {
        v += vector::<D>(bv);
    }
    if let Some(g) = &body.velocity_gradient {
        for (i, row) in g.value.iter().enumerate() {
            for (j, gij) in row.iter().enumerate() {
                let c = g.about.as_ref().map_or(0.0, |c| c[j]);
                v[i] += gij * (xr[j] - c);
            }
        }
    }
    (x, v, f)
}

/// The grid cells `c0..c1` overlapping a body's bounding box (at least one per axis; it
/// may lie beyond the grid when the body does).
fn body_cells<const D: usize>(body: &BodySpec, geom: &Geom<D>) -> ([usize; D], [usize; D]) {
    let (blo, bhi) = shape_bounds::<D>(&body.shape);
    let mut c0 = [0usize; D];
    let mut c1 = [0usize; D];
    for a in 0..D {
        let lo = ((blo[a] - geom.lower[a]) * geom.inv_h[a]).floor().max(0.0) as usize;
        let hi = (((bhi[a] - geom.lower[a]) * geom.inv_h[a]).ceil() as usize).min(geom.cells[a]);
        c0[a] = lo;
        c1[a] = hi.max(lo + 1);
    }
    (c0, c1)
}

/// Calls `f(lin, s, x, share)` for each particle `body` seeds in the cells `r0..r1` of
/// its cells `c0..c1`: box `s` of the `n^D` in a cell (`n` particles per cell and axis,
/// centred at `(q + ½)/n` of the cell), `lin` the cell's index in `c0..c1` (which, with
/// `s`, numbers the particle ids), `x` the box's centre where it lies in the shape and
/// `share` the whole box ([`cut_levels`]); seeded `cut`, a box the surface cuts gives
/// instead the centroid and share of its part inside ([`cut_part`]), none if that is
/// empty. Stops when `f` returns false.
fn lattice_points<const D: usize>(
    body: &BodySpec,
    geom: &Geom<D>,
    (c0, c1): ([usize; D], [usize; D]),
    (r0, r1): ([usize; D], [usize; D]),
    mut f: impl FnMut(usize, usize, [f64; D], u32) -> bool,
) {
    let n = body.particles_per_cell;
    let sub = n.pow(D as u32);
    let half: [f64; D] = std::array::from_fn(|a| 0.5 * geom.h[a] / n as f64);
    let reach = half.iter().map(|w| w * w).sum::<f64>().sqrt();
    let cut = body.seeding == Seeding::Cut;
    let dims: [usize; D] = std::array::from_fn(|a| c1[a] - c0[a]);
    let counts: [usize; D] = std::array::from_fn(|a| r1[a].saturating_sub(r0[a]));
    let total: usize = counts.iter().product();
    for k in 0..total {
        let mut rem = k;
        let mut cell = [0usize; D];
        for a in 0..D {
            cell[a] = r0[a] + rem % counts[a];
            rem /= counts[a];
        }
        let mut lin = 0usize;
        for a in (0..D).rev() {
            lin = lin * dims[a] + (cell[a] - c0[a]);
        }
        for s in 0..sub {
            let mut r = s;
            let mut x = [0.0; D];
            for a in 0..D {
                let q = r % n;
                r /= n;
                x[a] = geom.lower[a] + (cell[a] as f64 + (q as f64 + 0.5) / n as f64) * geom.h[a];
            }
            // A box farther from the surface than its corners lies wholly on one side.
            let seeded = if cut && surface_distance(&body.shape, &x) <= reach * (1.0 + 1e-9) {
                cut_part(&body.shape, &x, &half)
            } else {
                inside(&body.shape, &x).then_some((x, cut_levels(D)))
            };
            if let Some((x, share)) = seeded {
                if !f(lin, s, x, share) {
                    return;
                }
            }
        }
    }
}

/// The part inside `shape` of the box of centre `x` and half-widths `half`, measured on
/// a sub-lattice of [`cut_samples`] points per axis: its centroid and its share of the
/// box in [`cut_levels`]ths, none if no point is inside; the centre itself if every
/// point is, so that such a box is seeded as `lattice` seeds it.
fn cut_part<const D: usize>(
    shape: &Shape,
    x: &[f64; D],
    half: &[f64; D],
) -> Option<([f64; D], u32)> {
    let k = cut_samples(D);
    let (mut count, mut sum) = (0u32, [0.0; D]);
    for j in 0..cut_levels(D) {
        let mut r = j;
        let y: [f64; D] = std::array::from_fn(|a| {
            let q = r % k;
            r /= k;
            x[a] + half[a] * (2.0 * (f64::from(q) + 0.5) / f64::from(k) - 1.0)
        });
        if inside(shape, &y) {
            count += 1;
            (0..D).for_each(|a| sum[a] += y[a]);
        }
    }
    match count {
        0 => None,
        c if c == cut_levels(D) => Some((*x, c)),
        c => Some((sum.map(|s| s / f64::from(c)), c)),
    }
}

/// A lower bound of the distance from `x` to the surface of `s` (exact for every shape
/// but a box's inside corners, where it is the nearest face's).
fn surface_distance<const D: usize>(s: &Shape, x: &[f64; D]) -> f64 {
    // Distance to a slab [lo, hi] along one axis: negative inside (to its nearer face).
    let slab = |x: f64, lo: f64, hi: f64| (lo - x).max(x - hi);
    // Inside every slab the nearest face; outside any, the distance to the slabs' box.
    let boxed = |d: &[f64]| {
        if d.iter().all(|&v| v <= 0.0) {
            -d.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v))
        } else {
            d.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt()
        }
    };
    let radius = |c: &[f64]| {
        (0..c.len().min(D))
            .map(|a| (x[a] - c[a]).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    match s {
        Shape::Box { lower, upper } => boxed(&std::array::from_fn::<f64, D, _>(|a| {
            slab(x[a], lower[a], upper[a])
        })),
        Shape::Sphere { center, radius: r } => (radius(center) - r).abs(),
        Shape::Annulus {
            center,
            inner,
            outer,
        } => {
            let r = radius(center);
            (r - inner).abs().min((r - outer).abs())
        }
        Shape::Cylinder {
            center,
            radius: r,
            z,
        } => boxed(&[radius(&center[..2]) - r, slab(x[2], z[0], z[1])]),
    }
}

/// Whether `body` seeds at least one particle in the grid of `geom`: false when it lies
/// outside the grid or between the lattice points (smaller than a particle spacing).
/// Stops at the first particle, so it costs little for any real body.
pub fn seeds_any<const D: usize>(body: &BodySpec, geom: &Geom<D>) -> bool {
    let (c0, c1) = body_cells::<D>(body, geom);
    let r1: [usize; D] = std::array::from_fn(|a| c1[a].min(geom.cells[a]));
    let mut any = false;
    lattice_points::<D>(body, geom, (c0, c1), (c0, r1), |_, _, _, _| {
        any = true;
        false
    });
    any
}

/// A lattice point of `b` (as seeded) that lies inside the shape of `a`, if any: the two
/// bodies would both seed particles there. Walks only the cells where their bounding
/// boxes meet.
pub fn overlap<const D: usize>(a: &BodySpec, b: &BodySpec, geom: &Geom<D>) -> Option<[f64; D]> {
    let (a0, a1) = body_cells::<D>(a, geom);
    let (b0, b1) = body_cells::<D>(b, geom);
    let r0: [usize; D] = std::array::from_fn(|k| a0[k].max(b0[k]));
    let r1: [usize; D] = std::array::from_fn(|k| a1[k].min(b1[k]).min(geom.cells[k]));
    let mut hit = None;
    lattice_points::<D>(b, geom, (b0, b1), (r0, r1), |_, _, x, _| {
        if inside(&a.shape, &x) {
            hit = Some(x);
        }
        hit.is_none()
    });
    hit
}

/// Bounding box of a shape.
pub fn shape_bounds<const D: usize>(s: &Shape) -> ([f64; D], [f64; D]) {
    match s {
        Shape::Box { lower, upper } => (
            std::array::from_fn(|a| lower[a]),
            std::array::from_fn(|a| upper[a]),
        ),
        Shape::Sphere { center, radius } => (
            std::array::from_fn(|a| center[a] - radius),
            std::array::from_fn(|a| center[a] + radius),
        ),
        Shape::Annulus { center, outer, .. } => (
            std::array::from_fn(|a| center[a] - outer),
            std::array::from_fn(|a| center[a] + outer),
        ),
        Shape::Cylinder { center, radius, z } => (
            std::array::from_fn(|a| if a < 2 { center[a] - radius } else { z[0] }),
            std::array::from_fn(|a| if a < 2 { center[a] + radius } else { z[1] }),
        ),
    }
}

/// Is a point inside a shape? Plane faces are half-open, `[lower, upper)` along their
/// axis (a point within a 1e-9 share of the extent of a face counts as on it): a face
/// that falls on a row of lattice points (an odd number of particles per cell and a face
/// half a cell off the grid's lines) then seeds that row once, on the lower side, so a
/// box seeds exactly its volume of particles and two boxes that share a face neither
/// overlap nor leave a gap. Curved surfaces are closed sets.
pub fn inside<const D: usize>(s: &Shape, x: &[f64; D]) -> bool {
    match s {
        Shape::Box { lower, upper } => (0..D).all(|a| half_open(x[a], lower[a], upper[a])),
        Shape::Sphere { center, radius } => {
            (0..D).map(|a| (x[a] - center[a]).powi(2)).sum::<f64>() <= radius * radius
        }
        Shape::Annulus {
            center,
            inner,
            outer,
        } => {
            let r2: f64 = (0..D).map(|a| (x[a] - center[a]).powi(2)).sum();
            r2 >= inner * inner && r2 <= outer * outer
        }
        Shape::Cylinder { center, radius, z } => {
            (x[0] - center[0]).powi(2) + (x[1] - center[1]).powi(2) <= radius * radius
                && half_open(x[2], z[0], z[1])
        }
    }
}

/// `lo ≤ x < hi` with both ends moved down by a 1e-9 share of `hi − lo`, so that a
/// lattice point computed a rounding error off a face is taken as on it.
fn half_open(x: f64, lo: f64, hi: f64) -> bool {
    let tol = 1e-9 * (hi - lo).abs();
    x >= lo - tol && x < hi - tol
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(lower: Vec<f64>, upper: Vec<f64>, n: usize) -> BodySpec {
        BodySpec {
            material: "m".into(),
            shape: Shape::Box { lower, upper },
            particles_per_cell: n,
            velocity: None,
            velocity_gradient: None,
            seeding: Seeding::Lattice,
        }
    }

    fn count<const D: usize>(b: &BodySpec, geom: &Geom<D>) -> usize {
        let (c0, c1) = body_cells::<D>(b, geom);
        let mut n = 0;
        lattice_points::<D>(b, geom, (c0, c1), (c0, c1), |_, _, _, _| {
            n += 1;
            true
        });
        n
    }

    #[test]
    fn a_box_seeds_its_volume_when_its_faces_lie_on_lattice_points() {
        // Cells of 0.25 from -0.125: with 3 per cell the lattice has points at 0 and 1,
        // the box's faces; with 2 per cell none lies on a face.
        let geom = Geom::<2>::new([-0.125, -0.125], [2.125, 1.375], [9, 6], [false; 2]);
        let b3 = body(vec![0.0, 0.0], vec![2.0, 1.0], 3);
        assert_eq!(count(&b3, &geom), 24 * 12);
        let b2 = body(vec![0.0, 0.0], vec![2.0, 1.0], 2);
        assert_eq!(count(&b2, &geom), 16 * 8);
        // In 3D, and a cylinder's ends likewise.
        let g3 = Geom::<3>::new([-0.125; 3], [1.125; 3], [5; 3], [false; 3]);
        assert_eq!(
            count(&body(vec![0.0; 3], vec![1.0; 3], 3), &g3),
            12 * 12 * 12
        );
        let cyl = BodySpec {
            shape: Shape::Cylinder {
                center: vec![0.5, 0.5],
                radius: 10.0,
                z: vec![0.0, 1.0],
            },
            ..body(vec![], vec![], 3)
        };
        assert_eq!(count(&cyl, &g3), 15 * 15 * 12);
    }

    #[test]
    fn boxes_that_share_a_face_on_lattice_points_do_not_overlap() {
        let geom = Geom::<2>::new([-0.125, -0.125], [2.125, 1.375], [9, 6], [false; 2]);
        let left = body(vec![0.0, 0.0], vec![1.0, 1.0], 3);
        let right = body(vec![1.0, 0.0], vec![2.0, 1.0], 3);
        assert_eq!(overlap::<2>(&left, &right, &geom), None);
        assert_eq!(overlap::<2>(&right, &left, &geom), None);
        assert_eq!(count(&left, &geom) + count(&right, &geom), 24 * 12);
        // Moved into each other by a particle spacing they do.
        let into = body(vec![1.0 - 1.0 / 12.0, 0.0], vec![2.0, 1.0], 3);
        assert!(overlap::<2>(&left, &into, &geom).is_some());
    }

    /// The particles `b` seeds on `geom`: positions and reference volumes.
    fn seeded<const D: usize>(b: &BodySpec, geom: &Geom<D>) -> Vec<([f64; D], f64)> {
        let (c0, c1) = body_cells::<D>(b, geom);
        let whole = geom.cell_volume() / b.particles_per_cell.pow(D as u32) as f64;
        let mut out = Vec::new();
        lattice_points::<D>(b, geom, (c0, c1), (c0, c1), |_, _, x, share| {
            out.push((x, whole * f64::from(share) / f64::from(cut_levels(D))));
            true
        });
        out
    }

    /// Volume, centroid and polar moment of inertia about `c` of seeded particles.
    fn moments<const D: usize>(p: &[([f64; D], f64)], c: &[f64]) -> (f64, [f64; D], f64) {
        let vol: f64 = p.iter().map(|q| q.1).sum();
        let centroid = std::array::from_fn(|a| p.iter().map(|q| q.1 * q.0[a]).sum::<f64>() / vol);
        let polar = p
            .iter()
            .map(|(x, v)| v * (0..D).map(|a| (x[a] - c[a]).powi(2)).sum::<f64>())
            .sum();
        (vol, centroid, polar)
    }

    fn cut(mut b: BodySpec) -> BodySpec {
        b.seeding = Seeding::Cut;
        b
    }

    /// Seeded `cut`, a box whose faces lie on the sub-lattice that measures the cut
    /// boxes (at 3/16 and 11/16 of a particle's box) has its volume and centroid to
    /// round-off, where the lattice's staircase misses it by 8 %; a box whose
    /// faces lie between particle boxes is seeded as the lattice seeds it, bit for bit.
    #[test]
    fn cut_seeding_gives_a_box_its_volume_and_centroid() {
        let geom = Geom::<2>::new([0.0; 2], [1.0; 2], [8, 8], [false; 2]);
        // Particle boxes of 1/16; sub-lattice lines every 1/256.
        let (lo, hi) = (
            vec![0.25 + 3.0 / 256.0, 0.5],
            vec![0.75 + 11.0 / 256.0, 0.625 + 5.0 / 256.0],
        );
        let exact = (hi[0] - lo[0]) * (hi[1] - lo[1]);
        let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
        let b = body(lo, hi, 2);
        let (v, c, _) = moments(&seeded(&cut(b.clone()), &geom), &centre);
        assert!((v - exact).abs() < 1e-14, "{v} vs {exact}");
        for a in 0..2 {
            assert!((c[a] - centre[a]).abs() < 1e-14, "{c:?} vs {centre:?}");
        }
        let (vl, _, _) = moments(&seeded(&b, &geom), &centre);
        assert!((vl - exact).abs() > 0.05 * exact, "{vl} vs {exact}");
        let aligned = body(vec![0.25, 0.125], vec![0.8125, 0.5], 2);
        let bits = |p: Vec<([f64; 2], f64)>| -> Vec<[u64; 3]> {
            p.iter()
                .map(|(x, v)| [x[0].to_bits(), x[1].to_bits(), v.to_bits()])
                .collect()
        };
        assert_eq!(
            bits(seeded(&cut(aligned.clone()), &geom)),
            bits(seeded(&aligned, &geom))
        );
    }

    /// Seeded `cut`, a disk (2D) and a ball (3D) off the grid's lines have their volume
    /// and centroid within what the sub-lattice can miss (the sub-boxes the surface
    /// crosses, at most √d times its area over the sub-spacing, each of the sub-box's
    /// volume) and the disk its polar moment within that and the particles' own moment
    /// (points, they miss `V w²/6` of each box of width `w`).
    #[test]
    fn cut_seeding_gives_round_bodies_their_volume_centroid_and_inertia() {
        use std::f64::consts::PI;
        let geom = Geom::<2>::new([0.0; 2], [1.0; 2], [40, 40], [false; 2]);
        let (c, r) = ([0.503, 0.4871], 0.25);
        let disk = body(vec![], vec![], 2);
        let disk = BodySpec {
            shape: Shape::Sphere {
                center: c.to_vec(),
                radius: r,
            },
            ..disk
        };
        let w = 1.0 / 80.0;
        let sub = w / f64::from(cut_samples(2));
        let slack = 2f64.sqrt() * 2.0 * PI * r * sub;
        let (area, polar) = (PI * r * r, 0.5 * PI * r.powi(4));
        let (v, cen, j) = moments(&seeded(&cut(disk.clone()), &geom), &c);
        assert!(
            (v - area).abs() <= slack,
            "area {v} vs {area}, slack {slack:e}"
        );
        for a in 0..2 {
            assert!((cen[a] - c[a]).abs() * v <= slack * (r + sub), "{cen:?}");
        }
        let own = area * w * w / 6.0;
        assert!(
            (j - polar).abs() <= own + slack * (r + sub).powi(2),
            "polar {j} vs {polar}"
        );
        // A ball, 2 per cell.
        let g3 = Geom::<3>::new([0.0; 3], [1.0; 3], [12, 12, 12], [false; 3]);
        let (c3, r3) = ([0.51, 0.47, 0.493], 0.3);
        let ball = BodySpec {
            shape: Shape::Sphere {
                center: c3.to_vec(),
                radius: r3,
            },
            ..body(vec![], vec![], 2)
        };
        let sub3 = 1.0 / 24.0 / f64::from(cut_samples(3));
        let slack3 = 3f64.sqrt() * 4.0 * PI * r3 * r3 * sub3;
        let (v3, cen3, _) = moments(&seeded(&cut(ball), &g3), &c3);
        let vol3 = 4.0 / 3.0 * PI * r3.powi(3);
        assert!(
            (v3 - vol3).abs() <= slack3,
            "volume {v3} vs {vol3}, slack {slack3:e}"
        );
        for a in 0..3 {
            assert!(
                (cen3[a] - c3[a]).abs() * v3 <= slack3 * (r3 + sub3),
                "{cen3:?}"
            );
        }
    }
}
