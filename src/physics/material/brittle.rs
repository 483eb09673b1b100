//! Linear elasticity with tensile failure: the simplest brittle solid.
//!
//! The stress follows [`LinearElastic`] (the Jaumann rate of the Kirchhoff stress,
//! `τ ← Q τ Qᵀ + λ tr Δε I + 2μ Δε`). Each particle carries `damage ∈ {0, 1}`. An
//! intact particle whose largest principal stress exceeds the tensile strength,
//! `max eig σ > σ_t`, fails: damage becomes 1 for good. A failed particle carries no
//! tension: after every update its stress is replaced by its negative part
//! `σ⁻ = Σ min(σ_i, 0) n_i⊗n_i`.
//!
//! Failure takes effect in the step that exceeded the strength (the stress is projected
//! in that same step), so no particle ever hands the grid a principal tension above
//! `σ_t`.
//!
//! Plane strain (D = 2): the particle carries `σ_zz` (`Δτ_zz = λ tr Δε`, as `Δε_zz = 0`),
//! since once a particle has failed its projection makes `σ_zz` depend on the history,
//! not on the in-plane stress alone. `σ_zz` is a principal stress there, so the failure
//! test takes the largest of `σ₁` and `σ_zz` (for ν ≥ 0 an intact particle has
//! `σ_zz = ν(σ₁ + σ₂) ≤ σ₁` once σ₁ is tensile, so only ν < 0 changes the outcome),
//! and the projection keeps `min(σ_zz, 0)`. In 1D the untracked lateral stresses `λε`
//! never exceed `(λ+2μ)ε` when tensile, so the check on σ_xx misses no failure.

use crate::physics::material::linear_elastic::{increment, LinearElastic};
use crate::physics::material::VolumeChange;
use crate::physics::tensor::Mat;
use nalgebra::{Matrix3, SymmetricEigen};

#[derive(Clone, Debug, PartialEq)]
pub struct Brittle {
    pub lambda: f64,
    pub mu: f64,
    pub density: f64,
    pub tensile_strength: f64,
}

impl Brittle {
    #[inline]
    fn elastic(&self) -> LinearElastic {
        LinearElastic {
            lambda: self.lambda,
            mu: self.mu,
            density: self.density,
            small: false,
        }
    }

    /// Elastic update, failure check, and for a failed particle the projection onto
    /// compression. `damage` is 0 (intact) or 1 (failed; any nonzero value counts).
    /// `stress_zz` is the plane-strain out-of-plane stress (2D particles carry it).
    #[inline]
    pub fn update_stress<const D: usize>(
        &self,
        stress: &mut Mat<D>,
        damage: &mut f64,
        stress_zz: Option<&mut f64>,
        l: &Mat<D>,
        dt: f64,
        j: VolumeChange,
    ) {
        let (de, q) = increment(l, dt);
        self.elastic().apply(stress, &de, &q, j);
        let mut szz = stress_zz;
        if let Some(z) = szz.as_deref_mut() {
            // `Δε_zz = 0`: the in-plane trace alone.
            *z = *z / j.step + self.lambda * de.trace() / j.total;
        }
        let zz = szz.as_deref().copied().unwrap_or(f64::NEG_INFINITY);
        if *damage == 0.0 && max_principal(stress).max(zz) > self.tensile_strength {
            *damage = 1.0;
        }
        if *damage != 0.0 {
            *stress = negative_part(stress);
            if let Some(z) = szz {
                *z = z.min(0.0);
            }
        }
    }

    /// Energy per current volume, as [`LinearElastic::energy_density`]; a failed
    /// particle's stress is already its compressive part. In plane strain `ε_zz = 0`,
    /// so `σ_zz` does no work and the in-plane stress alone gives the energy.
    pub fn energy_density<const D: usize>(&self, s: &Mat<D>) -> f64 {
        self.elastic().energy_density(s)
    }
}

/// Centre and radius of Mohr's circle of a symmetric 2×2 matrix: eigenvalues `c ± r`.
#[inline]
fn mohr<const D: usize>(s: &Mat<D>) -> (f64, f64) {
    let c = 0.5 * (s[(0, 0)] + s[(1, 1)]);
    let r = (0.5 * (s[(0, 0)] - s[(1, 1)])).hypot(s[(0, 1)]);
    (c, r)
}

#[inline]
fn embed3<const D: usize>(s: &Mat<D>) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| if i < D && j < D { s[(i, j)] } else { 0.0 })
}

/// Largest eigenvalue of a symmetric D×D matrix, D ≤ 3. Dispatched per D (closed form
/// for D ≤ 2, nalgebra on a concrete 3×3 otherwise) so generic callers need no bounds.
#[inline]
fn max_principal<const D: usize>(s: &Mat<D>) -> f64 {
    match D {
        1 => s[(0, 0)],
        2 => {
            let (c, r) = mohr(s);
            c + r
        }
        3 => embed3(s).symmetric_eigenvalues().max(),
        _ => unreachable!("dimension is 1, 2 or 3"),
    }
}

/// `Σ min(σ_i, 0) n_i⊗n_i` of a symmetric D×D matrix, D ≤ 3.
#[inline]
fn negative_part<const D: usize>(s: &Mat<D>) -> Mat<D> {
    match D {
        1 => s.map(|x| x.min(0.0)),
        2 => {
            let (c, r) = mohr(s);
            let (hi, lo) = (c + r, c - r);
            if hi <= 0.0 {
                *s
            } else if lo >= 0.0 {
                Mat::<D>::zeros()
            } else {
                // lo · n_lo⊗n_lo, with the projector n_lo⊗n_lo = (s − hi I)/(lo − hi);
                // lo < 0 < hi keeps the division well conditioned.
                (s - Mat::<D>::identity() * hi) * (lo / (lo - hi))
            }
        }
        3 => {
            let e = SymmetricEigen::new(embed3(s));
            let neg = e.eigenvalues.map(|x| x.min(0.0));
            let m = e.eigenvectors * Matrix3::from_diagonal(&neg) * e.eigenvectors.transpose();
            Mat::<D>::from_fn(|i, j| m[(i, j)])
        }
        _ => unreachable!("dimension is 1, 2 or 3"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::material::lame;
    use crate::physics::material::linear_elastic::strain_step;
    use nalgebra::{Rotation3, Unit, Vector3};

    fn model() -> Brittle {
        let (lambda, mu) = lame(30.0, 0.2);
        Brittle {
            lambda,
            mu,
            density: 2.4,
            tensile_strength: 3e-3,
        }
    }

    /// One step of uniaxial strain increment `de` in x (dt = 1).
    fn uniaxial<const D: usize>(m: &Brittle, s: &mut Mat<D>, d: &mut f64, de: f64) {
        let mut e = Mat::<D>::zeros();
        e[(0, 0)] = de;
        m.update_stress(s, d, None, &strain_step(&e), 1.0, VolumeChange::NONE);
    }

    fn check_uniaxial<const D: usize>() {
        let m = model();
        let big = m.lambda + 2.0 * m.mu;
        let eps_t = m.tensile_strength / big; // σ_xx reaches the strength here

        // Below the strength: intact, exact elastic stress.
        let (mut s, mut d) = (Mat::<D>::zeros(), 0.0);
        let e = 0.999 * eps_t;
        uniaxial(&m, &mut s, &mut d, e);
        assert_eq!(d, 0.0);
        for a in 0..D {
            let x = if a == 0 { big * e } else { m.lambda * e };
            assert!((s[(a, a)] - x).abs() < 1e-15, "D = {D}: {s}");
        }
        // Compression of an intact particle, back through zero: elastic.
        uniaxial(&m, &mut s, &mut d, -2.0 * e);
        assert_eq!(d, 0.0);
        assert!((s[(0, 0)] + big * e).abs() < 1e-15);

        // Just above: fails in that step; all principal stresses were tensile, so the
        // projected stress is zero.
        let (mut s, mut d) = (Mat::<D>::zeros(), 0.0);
        uniaxial(&m, &mut s, &mut d, 1.001 * eps_t);
        assert_eq!(d, 1.0);
        assert_eq!(s, Mat::<D>::zeros());

        // Failed: further tension carries nothing, compression is elastic (all
        // principal stresses negative), and reloading in tension does not heal.
        uniaxial(&m, &mut s, &mut d, 0.5 * eps_t);
        assert_eq!(s, Mat::<D>::zeros());
        let c = 2.0 * eps_t;
        uniaxial(&m, &mut s, &mut d, -c);
        assert_eq!(d, 1.0);
        for a in 0..D {
            let x = if a == 0 { -big * c } else { -m.lambda * c };
            assert!((s[(a, a)] - x).abs() < 1e-15, "D = {D}: {s}");
        }
        let w = 0.5 * big * c * c;
        assert!((m.energy_density(&s) - w).abs() < 1e-14 * w);
        // Unload by c/2 (still compressive, elastic), then pull by 2c: the stress
        // passes through zero and stays there.
        uniaxial(&m, &mut s, &mut d, 0.5 * c);
        assert!((s[(0, 0)] + 0.5 * big * c).abs() < 1e-15);
        uniaxial(&m, &mut s, &mut d, 2.0 * c);
        assert_eq!(s, Mat::<D>::zeros());
        assert_eq!(d, 1.0);
    }

    #[test]
    fn uniaxial_strain_fails_just_above_strength() {
        check_uniaxial::<1>();
        check_uniaxial::<2>();
        check_uniaxial::<3>();
    }

    /// Hydrostatic compression, however large, never fails: σ = (Dλ + 2μ) e I.
    #[test]
    fn hydrostatic_compression_never_fails() {
        let m = model();
        let mut s = Mat::<3>::zeros();
        let mut d = 0.0;
        let e = -0.01; // σ ≈ −0.5, far beyond the strength in magnitude
        for _ in 0..10 {
            let l = strain_step(&(Mat::<3>::identity() * e));
            m.update_stress(&mut s, &mut d, None, &l, 1.0, VolumeChange::NONE);
        }
        assert_eq!(d, 0.0);
        let x = (3.0 * m.lambda + 2.0 * m.mu) * 10.0 * e;
        assert!((s - Mat::<3>::identity() * x).norm() < 1e-14 * x.abs());
        let mut s2 = Mat::<2>::zeros();
        let l = strain_step(&(Mat::<2>::identity() * e));
        m.update_stress(&mut s2, &mut d, None, &l, 1.0, VolumeChange::NONE);
        assert_eq!(d, 0.0);
        assert!((s2 - Mat::<2>::identity() * ((2.0 * m.lambda + 2.0 * m.mu) * e)).norm() < 1e-15);
    }

    /// Simple shear γ in one step: σ_xy = μγ is the largest principal stress, so the
    /// particle fails at γ = σ_t / μ. Above it the stress is the compressive part
    /// −μγ n⊗n, n = (1, −1)/√2: [[−μγ/2, μγ/2], [μγ/2, −μγ/2]].
    fn check_shear<const D: usize>() {
        let m = model();
        let gc = m.tensile_strength / m.mu;
        let shear = |g: f64| {
            let mut e = Mat::<D>::zeros();
            e[(0, 1)] = 0.5 * g;
            e[(1, 0)] = 0.5 * g;
            let (mut s, mut d) = (Mat::<D>::zeros(), 0.0);
            m.update_stress(
                &mut s,
                &mut d,
                None,
                &strain_step(&e),
                1.0,
                VolumeChange::NONE,
            );
            (s, d)
        };
        let g = 0.999 * gc;
        let (s, d) = shear(g);
        assert_eq!(d, 0.0);
        assert!((s[(0, 1)] - m.mu * g).abs() < 1e-15 && (s[(1, 0)] - m.mu * g).abs() < 1e-15);
        assert!(s[(0, 0)].abs() < 1e-15 && s[(1, 1)].abs() < 1e-15);

        let g = 1.001 * gc;
        let (s, d) = shear(g);
        assert_eq!(d, 1.0);
        let h = 0.5 * m.mu * g;
        let mut x = Mat::<D>::zeros();
        x[(0, 0)] = -h;
        x[(1, 1)] = -h;
        x[(0, 1)] = h;
        x[(1, 0)] = h;
        assert!((s - x).norm() < 1e-15, "D = {D}: {s}");
    }

    #[test]
    fn simple_shear_fails_at_strength_over_mu() {
        check_shear::<2>();
        check_shear::<3>();
    }

    /// Plane strain σ_zz: λε for intact uniaxial strain; zero after a shear failure
    /// (isochoric shear gives none, and the projection keeps it), where the linear
    /// elastic relation ν tr σ would claim −νμγ, which is why brittle particles store
    /// it; compression after a tensile failure gives −λc. With ν < 0, in-plane
    /// compression makes σ_zz = 2λe the largest principal stress: the particle fails
    /// on it although both in-plane principal stresses are compressive.
    #[test]
    fn plane_strain_sigma_zz() {
        let m = model();
        let big = m.lambda + 2.0 * m.mu;
        let eps_t = m.tensile_strength / big;
        // `e`, the step's midpoint gradient: its symmetric part the strain, its skew
        // part the turn (a simple shear has both).
        let step = |s: &mut Mat<2>, d: &mut f64, z: &mut f64, e: Mat<2>| {
            m.update_stress(s, d, Some(z), &strain_step(&e), 1.0, VolumeChange::NONE);
        };
        let (mut s, mut d, mut z) = (Mat::<2>::zeros(), 0.0, 0.0);
        let e = 0.9 * eps_t;
        step(&mut s, &mut d, &mut z, Mat::<2>::new(e, 0.0, 0.0, 0.0));
        assert_eq!(d, 0.0);
        assert!((z - m.lambda * e).abs() < 1e-15);
        // Tensile failure, then compression by c.
        step(
            &mut s,
            &mut d,
            &mut z,
            Mat::<2>::new(0.2 * eps_t, 0.0, 0.0, 0.0),
        );
        assert_eq!((d, z), (1.0, 0.0));
        let c = 2.0 * eps_t;
        step(&mut s, &mut d, &mut z, Mat::<2>::new(-c, 0.0, 0.0, 0.0));
        assert!((z + m.lambda * c).abs() < 1e-15);

        let (mut s, mut d, mut z) = (Mat::<2>::zeros(), 0.0, 0.0);
        let g = 1.001 * m.tensile_strength / m.mu;
        step(&mut s, &mut d, &mut z, Mat::<2>::new(0.0, g, 0.0, 0.0));
        assert_eq!((d, z), (1.0, 0.0));
        let nu = m.lambda / (2.0 * (m.lambda + m.mu));
        assert!((nu * s.trace() + nu * m.mu * g).abs() < 1e-15);

        let (lambda, mu) = lame(30.0, -0.5);
        let aux = Brittle {
            lambda,
            mu,
            ..model()
        };
        let e = -1.001 * aux.tensile_strength / (-2.0 * lambda);
        let (mut s, mut d, mut z) = (Mat::<2>::zeros(), 0.0, 0.0);
        aux.update_stress(
            &mut s,
            &mut d,
            Some(&mut z),
            &strain_step(&(Mat::<2>::identity() * e)),
            1.0,
            VolumeChange::NONE,
        );
        assert!(max_principal(&s) < 0.0);
        assert_eq!((d, z), (1.0, 0.0));
        assert!((s - Mat::<2>::identity() * (2.0 * (lambda + mu) * e)).norm() < 1e-15);
        // Just below, intact, with σ_zz = 2λe.
        let e = -0.999 * aux.tensile_strength / (-2.0 * lambda);
        let (mut s, mut d, mut z) = (Mat::<2>::zeros(), 0.0, 0.0);
        aux.update_stress(
            &mut s,
            &mut d,
            Some(&mut z),
            &strain_step(&(Mat::<2>::identity() * e)),
            1.0,
            VolumeChange::NONE,
        );
        assert_eq!(d, 0.0);
        assert!((z - 2.0 * lambda * e).abs() < 1e-15);
    }

    /// The negative part of R diag(σ) Rᵀ is R diag(min(σ, 0)) Rᵀ, and the largest
    /// principal value is max σ; in 2D and 3D, mixed signs and all of one sign.
    #[test]
    fn principal_values_and_negative_part() {
        let r3 =
            *Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(1.0, -2.0, 0.5)), 0.9)
                .matrix();
        for diag in [[3.0f64, -2.0, -5.0], [1.0, 2.0, 0.5], [-1.0, -4.0, -0.5]] {
            let s = r3 * Matrix3::from_diagonal(&Vector3::from(diag)) * r3.transpose();
            let neg = r3
                * Matrix3::from_diagonal(&Vector3::from(diag).map(|x| x.min(0.0)))
                * r3.transpose();
            assert!((negative_part(&s) - neg).norm() < 1e-14, "{diag:?}");
            let mx = diag.iter().cloned().fold(f64::MIN, f64::max);
            assert!((max_principal(&s) - mx).abs() < 1e-14);
        }
        let (c, sn) = (0.6, 0.8);
        let r2 = Mat::<2>::new(c, -sn, sn, c);
        for diag in [[3.0f64, -2.0], [1.0, 2.0], [-1.0, -4.0]] {
            let s = r2 * Mat::<2>::from_diagonal(&diag.into()) * r2.transpose();
            let neg = r2
                * Mat::<2>::from_diagonal(&nalgebra::Vector2::from(diag).map(|x| x.min(0.0)))
                * r2.transpose();
            assert!((negative_part(&s) - neg).norm() < 1e-14, "{diag:?}");
            assert!((max_principal(&s) - diag[0].max(diag[1])).abs() < 1e-14);
        }
        let s1 = Mat::<1>::new(-2.0);
        assert_eq!(negative_part(&s1), s1);
        assert_eq!(negative_part(&Mat::<1>::new(2.0)), Mat::<1>::zeros());
    }
}
