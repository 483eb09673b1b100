//! Particles as a structure of arrays. Optional state is an empty `Vec` unless the
//! scene needs it: the deformation gradient only for materials that use it, the
//! reference position only for benchmarks, the GIMP half-width only for `gimp`, the
//! out-of-plane stress only for `brittle` in 2D.

use crate::benchmark::Benchmark;
use crate::material::Material;
use crate::scene::{BodySpec, Model, Scene, Shape};
use crate::shape::Geom;
use crate::tensor::{det, vector, Mat, Vector};
use nalgebra::Matrix3;

#[derive(Clone, Debug, Default)]
pub struct Particles<const D: usize> {
    pub x: Vec<Vector<D>>,
    pub v: Vec<Vector<D>>,
    pub mass: Vec<f64>,
    /// Current volume.
    pub vol: Vec<f64>,
    /// Reference volume.
    pub vol0: Vec<f64>,
    pub stress: Vec<Mat<D>>,
    /// Deformation gradient (materials that need it).
    pub def_grad: Vec<Mat<D>>,
    /// Material index.
    pub mat: Vec<u16>,
    /// Global id, independent of the rank count.
    pub id: Vec<u64>,
    /// Reference position (benchmarks).
    pub x0: Vec<Vector<D>>,
    /// GIMP particle half-width per axis.
    pub half: Vec<[f64; D]>,
    /// Elastic left Cauchy–Green tensor, always 3 × 3 (plasticity in plane strain
    /// needs the out-of-plane stretch), and equivalent plastic strain (`j2_plastic`).
    pub be: Vec<Matrix3<f64>>,
    pub eps_p: Vec<f64>,
    /// Damage, 0 intact or 1 failed (`brittle`).
    pub damage: Vec<f64>,
    /// Plane-strain σ_zz (`brittle` in 2D, where failure makes it history-dependent;
    /// the other models derive it, see [`Material::stress_zz`]).
    pub stress_zz: Vec<f64>,
}

/// Which optional arrays the particles carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Carries {
    pub def_grad: bool,
    pub x0: bool,
    pub half: bool,
    /// `be` and `eps_p`.
    pub plastic: bool,
    pub damage: bool,
    pub stress_zz: bool,
}

impl Carries {
    /// The optional particle arrays a scene needs.
    pub fn for_scene(scene: &Scene) -> Self {
        Carries {
            def_grad: scene
                .materials
                .iter()
                .any(|m| Material::from_spec(m).needs_def_grad()),
            // Benchmarks measure displacement errors; a displacement output needs it too.
            x0: scene.benchmark.is_some()
                || scene
                    .snapshot_plan()
                    .is_some_and(|o| o.fields.contains(&crate::scene::Field::Displacement)),
            half: scene.method.gradient == crate::scene::Gradient::Gimp,
            plastic: scene.materials.iter().any(|m| m.model == Model::J2Plastic),
            damage: scene.materials.iter().any(|m| m.model == Model::Brittle),
            stress_zz: scene.dim == 2 && scene.materials.iter().any(|m| m.model == Model::Brittle),
        }
    }
}

impl<const D: usize> Particles<D> {
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Make `self` a copy of `other`, reusing `self`'s allocations (a derived
    /// `clone_from` would allocate fresh arrays every time).
    pub fn copy_from(&mut self, other: &Self) {
        self.x.clone_from(&other.x);
        self.v.clone_from(&other.v);
        self.mass.clone_from(&other.mass);
        self.vol.clone_from(&other.vol);
        self.vol0.clone_from(&other.vol0);
        self.stress.clone_from(&other.stress);
        self.def_grad.clone_from(&other.def_grad);
        self.mat.clone_from(&other.mat);
        self.id.clone_from(&other.id);
        self.x0.clone_from(&other.x0);
        self.half.clone_from(&other.half);
        self.be.clone_from(&other.be);
        self.eps_p.clone_from(&other.eps_p);
        self.damage.clone_from(&other.damage);
        self.stress_zz.clone_from(&other.stress_zz);
    }

    /// Apply the permutation `perm` (new position k holds old particle `perm[k]`) to
    /// every array, using `scratch` so no allocation happens once it has grown.
    pub fn permute(&mut self, perm: &[usize], scratch: &mut Vec<f64>) {
        fn apply<T: AsF64Slice>(v: &mut [T], perm: &[usize], scratch: &mut Vec<f64>) {
            if v.is_empty() {
                return;
            }
            let w = T::WIDTH;
            scratch.clear();
            for &p in perm {
                scratch.extend_from_slice(v[p].as_slice());
            }
            for (k, item) in v.iter_mut().enumerate() {
                item.set_from(&scratch[k * w..(k + 1) * w]);
            }
        }
        apply(&mut self.x, perm, scratch);
        apply(&mut self.v, perm, scratch);
        apply(&mut self.mass, perm, scratch);
        apply(&mut self.vol, perm, scratch);
        apply(&mut self.vol0, perm, scratch);
        apply(&mut self.stress, perm, scratch);
        apply(&mut self.def_grad, perm, scratch);
        apply(&mut self.x0, perm, scratch);
        apply(&mut self.half, perm, scratch);
        apply(&mut self.be, perm, scratch);
        apply(&mut self.eps_p, perm, scratch);
        apply(&mut self.damage, perm, scratch);
        apply(&mut self.stress_zz, perm, scratch);
        // Integer arrays: ids and materials fit exactly in f64 (ids < 2^53).
        scratch.clear();
        scratch.extend(perm.iter().map(|&p| self.id[p] as f64));
        for (k, id) in self.id.iter_mut().enumerate() {
            *id = scratch[k] as u64;
        }
        scratch.clear();
        scratch.extend(perm.iter().map(|&p| f64::from(self.mat[p])));
        for (k, m) in self.mat.iter_mut().enumerate() {
            *m = scratch[k] as u16;
        }
    }

    /// Values per particle in a migration record for what these particles carry.
    pub fn record_width(c: Carries) -> usize {
        let d = D;
        2 * d
            + 3
            + d * d
            + 2
            + if c.def_grad { d * d } else { 0 }
            + if c.x0 { d } else { 0 }
            + if c.half { d } else { 0 }
            + if c.plastic { 10 } else { 0 }
            + usize::from(c.damage)
            + usize::from(c.stress_zz)
    }

    /// Append particle `p` as a flat record (ids and material indices are exact in f64).
    pub fn pack(&self, p: usize, c: Carries, out: &mut Vec<f64>) {
        out.clear();
        out.extend_from_slice(self.x[p].as_slice());
        out.extend_from_slice(self.v[p].as_slice());
        out.extend_from_slice(&[self.mass[p], self.vol[p], self.vol0[p]]);
        out.extend_from_slice(self.stress[p].as_slice());
        out.push(f64::from(self.mat[p]));
        out.push(self.id[p] as f64);
        if c.def_grad {
            out.extend_from_slice(self.def_grad[p].as_slice());
        }
        if c.x0 {
            out.extend_from_slice(self.x0[p].as_slice());
        }
        if c.half {
            out.extend_from_slice(&self.half[p]);
        }
        if c.plastic {
            out.extend_from_slice(self.be[p].as_slice());
            out.push(self.eps_p[p]);
        }
        if c.damage {
            out.push(self.damage[p]);
        }
        if c.stress_zz {
            out.push(self.stress_zz[p]);
        }
    }

    /// Append a particle from a record made by [`Particles::pack`].
    pub fn unpack(&mut self, r: &[f64], c: Carries) {
        let d = D;
        let mut at = 0;
        let mut take = |n: usize| {
            let s = &r[at..at + n];
            at += n;
            s
        };
        self.x.push(Vector::<D>::from_column_slice(take(d)));
        self.v.push(Vector::<D>::from_column_slice(take(d)));
        let m = take(3);
        self.mass.push(m[0]);
        self.vol.push(m[1]);
        self.vol0.push(m[2]);
        self.stress.push(Mat::<D>::from_column_slice(take(d * d)));
        let ids = take(2);
        self.mat.push(ids[0] as u16);
        self.id.push(ids[1] as u64);
        if c.def_grad {
            self.def_grad.push(Mat::<D>::from_column_slice(take(d * d)));
        }
        if c.x0 {
            self.x0.push(Vector::<D>::from_column_slice(take(d)));
        }
        if c.half {
            let h = take(d);
            self.half.push(std::array::from_fn(|a| h[a]));
        }
        if c.plastic {
            self.be.push(Matrix3::from_column_slice(take(9)));
            self.eps_p.push(take(1)[0]);
        }
        if c.damage {
            self.damage.push(take(1)[0]);
        }
        if c.stress_zz {
            self.stress_zz.push(take(1)[0]);
        }
    }

    /// The full 3 × 3 Cauchy stress of particle `p` (for output): in 2D with the
    /// plane-strain σ_zz, in 1D only σ_xx (the lateral stresses are not formed).
    pub fn stress3(&self, p: usize, materials: &[Material]) -> Matrix3<f64> {
        let s = &self.stress[p];
        let mut m = Matrix3::from_fn(|i, j| if i < D && j < D { s[(i, j)] } else { 0.0 });
        if D == 2 {
            let f = self
                .def_grad
                .get(p)
                .copied()
                .unwrap_or_else(Mat::<D>::identity);
            m[(2, 2)] = materials[self.mat[p] as usize].stress_zz(
                s,
                &f,
                self.be.get(p),
                self.stress_zz.get(p).copied(),
            );
        }
        m
    }

    /// Keep the particles whose `keep` flag is set, in order.
    pub fn retain(&mut self, keep: &[bool]) {
        fn ret<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
            if v.is_empty() {
                return;
            }
            let mut w = 0;
            for r in 0..v.len() {
                if keep[r] {
                    v[w] = v[r];
                    w += 1;
                }
            }
            v.truncate(w);
        }
        ret(&mut self.x, keep);
        ret(&mut self.v, keep);
        ret(&mut self.mass, keep);
        ret(&mut self.vol, keep);
        ret(&mut self.vol0, keep);
        ret(&mut self.stress, keep);
        ret(&mut self.def_grad, keep);
        ret(&mut self.mat, keep);
        ret(&mut self.id, keep);
        ret(&mut self.x0, keep);
        ret(&mut self.half, keep);
        ret(&mut self.be, keep);
        ret(&mut self.eps_p, keep);
        ret(&mut self.damage, keep);
        ret(&mut self.stress_zz, keep);
    }

    /// Seed the particles of every body whose current position falls in the owned
    /// cells `[cell_lo, cell_hi)`, in global id order.
    pub fn seed(
        scene: &Scene,
        geom: &Geom<D>,
        materials: &[Material],
        benchmark: Option<&Benchmark<D>>,
        cell_lo: [usize; D],
        cell_hi: [usize; D],
    ) -> Self {
        let carries = Carries::for_scene(scene);
        let mut p = Particles::<D>::default();
        // Benchmarks may start displaced: look that many cells beyond the block.
        let disp = match benchmark {
            Some(Benchmark::AxisAlignedMms { a, .. }) => a.abs(),
            _ => 0.0,
        };
        let mut id_base = 0u64;
        for body in &scene.bodies {
            let mi = scene
                .materials
                .iter()
                .position(|m| m.name == body.material)
                .expect("validated");
            let n = body.particles_per_cell;
            let sub = n.pow(D as u32);
            let seed = BodySeed {
                mat: &materials[mi],
                index: mi as u16,
                vol0: geom.cell_volume() / sub as f64,
                half: std::array::from_fn(|a| 0.5 * geom.h[a] / n as f64),
                carries,
            };
            let (c0, c1) = body_cells::<D>(body, geom);
            // Restrict to the block, padded by the initial displacement.
            let pad: [usize; D] =
                std::array::from_fn(|a| 1 + (disp * geom.inv_h[a]).ceil() as usize);
            let r0: [usize; D] =
                std::array::from_fn(|a| c0[a].max(cell_lo[a].saturating_sub(pad[a])));
            let r1: [usize; D] = std::array::from_fn(|a| c1[a].min(cell_hi[a] + pad[a]));
            let dims: [usize; D] = std::array::from_fn(|a| c1[a] - c0[a]);
            let body_cells: usize = dims.iter().product();
            if (0..D).all(|a| r0[a] < r1[a]) {
                lattice_points::<D>(body, geom, (c0, c1), (r0, r1), |lin, s, xref| {
                    let xr = vector::<D>(&xref);
                    let (x, v, f) = initial_motion(body, benchmark, &xr);
                    let (c, _) = geom.locate(&std::array::from_fn(|a| x[a]));
                    if (0..D).any(|a| c[a] < cell_lo[a] as i64 || c[a] >= cell_hi[a] as i64) {
                        return true;
                    }
                    p.push_seeded(&seed, id_base + (lin * sub + s) as u64, xr, (x, v, f));
                    true
                });
            }
            id_base += (body_cells * sub) as u64;
        }
        p
    }

    /// Append a new particle of `seed`'s body: reference position `xr`, position,
    /// velocity and deformation gradient `(x, v, f)`, the stress of `f`, and every
    /// other array the scene carries at its initial value.
    fn push_seeded(
        &mut self,
        seed: &BodySeed<D>,
        id: u64,
        xr: Vector<D>,
        (x, v, f): (Vector<D>, Vector<D>, Mat<D>),
    ) {
        let (mat, vol0, carries) = (seed.mat, seed.vol0, seed.carries);
        let j = det(&f);
        self.x.push(x);
        self.v.push(v);
        self.mass.push(mat.density() * vol0);
        self.vol0.push(vol0);
        self.vol.push(vol0 * j);
        let mut st = Mat::<D>::zeros();
        if mat.needs_def_grad() {
            let none = crate::material::Internal {
                plastic: None,
                damage: None,
                stress_zz: None,
            };
            mat.update_stress(&mut st, &Mat::<D>::zeros(), &f, 0.0, none);
        }
        self.stress.push(st);
        if carries.def_grad {
            self.def_grad.push(f);
        }
        self.mat.push(seed.index);
        self.id.push(id);
        if carries.x0 {
            self.x0.push(xr);
        }
        if carries.plastic {
            self.be.push(Matrix3::identity());
            self.eps_p.push(0.0);
        }
        if carries.damage {
            self.damage.push(0.0);
        }
        if carries.stress_zz {
            self.stress_zz.push(0.0);
        }
        if carries.half {
            self.half.push(seed.half);
        }
    }
}

/// What the particles of one body share when they are seeded.
struct BodySeed<'m, const D: usize> {
    mat: &'m Material,
    /// The material's index.
    index: u16,
    /// Initial volume of each particle.
    vol0: f64,
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

/// Calls `f(lin, s, x)` for each seeding lattice point `x` of `body` inside its shape, in
/// the cells `r0..r1` of the body's cells `c0..c1`: point `s` of the `n^D` in a cell
/// (`n` particles per cell and axis, at `(q + ½)/n` of the cell), `lin` the cell's
/// index in `c0..c1` (which, with `s`, numbers the particle ids). Stops when `f`
/// returns false.
fn lattice_points<const D: usize>(
    body: &BodySpec,
    geom: &Geom<D>,
    (c0, c1): ([usize; D], [usize; D]),
    (r0, r1): ([usize; D], [usize; D]),
    mut f: impl FnMut(usize, usize, [f64; D]) -> bool,
) {
    let n = body.particles_per_cell;
    let sub = n.pow(D as u32);
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
            if inside(&body.shape, &x) && !f(lin, s, x) {
                return;
            }
        }
    }
}

/// Whether `body` seeds at least one particle in the grid of `geom`: false when it lies
/// outside the grid or between the lattice points (smaller than a particle spacing).
/// Stops at the first particle, so it costs little for any real body.
pub fn seeds_any<const D: usize>(body: &BodySpec, geom: &Geom<D>) -> bool {
    let (c0, c1) = body_cells::<D>(body, geom);
    let r1: [usize; D] = std::array::from_fn(|a| c1[a].min(geom.cells[a]));
    let mut any = false;
    lattice_points::<D>(body, geom, (c0, c1), (c0, r1), |_, _, _| {
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
    lattice_points::<D>(b, geom, (b0, b1), (r0, r1), |_, _, x| {
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

/// Is a point inside a shape (closed sets)?
pub fn inside<const D: usize>(s: &Shape, x: &[f64; D]) -> bool {
    match s {
        Shape::Box { lower, upper } => (0..D).all(|a| x[a] >= lower[a] && x[a] <= upper[a]),
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
                && x[2] >= z[0]
                && x[2] <= z[1]
        }
    }
}

/// Fixed-width `f64` view of particle array elements, for permutation and migration.
pub trait AsF64Slice: Copy {
    const WIDTH: usize;
    fn as_slice(&self) -> &[f64];
    fn set_from(&mut self, s: &[f64]);
}

impl AsF64Slice for f64 {
    const WIDTH: usize = 1;
    fn as_slice(&self) -> &[f64] {
        std::slice::from_ref(self)
    }
    fn set_from(&mut self, s: &[f64]) {
        *self = s[0];
    }
}

impl<const D: usize> AsF64Slice for [f64; D] {
    const WIDTH: usize = D;
    fn as_slice(&self) -> &[f64] {
        self
    }
    fn set_from(&mut self, s: &[f64]) {
        self.copy_from_slice(s);
    }
}

impl<const R: usize, const C: usize> AsF64Slice for nalgebra::SMatrix<f64, R, C> {
    const WIDTH: usize = R * C;
    fn as_slice(&self) -> &[f64] {
        nalgebra::SMatrix::as_slice(self)
    }
    fn set_from(&mut self, s: &[f64]) {
        self.copy_from_slice(s);
    }
}
