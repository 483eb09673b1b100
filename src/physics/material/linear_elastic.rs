//! Isotropic linear elasticity in rate form: `σ̇ = λ tr(D) I + 2 μ D`, `D = sym(L)`.
//! Small-strain: no objective rotation, which is what the verification problems of
//! this model (vibrating bar, colliding disks) use.

use crate::physics::tensor::Mat;

#[derive(Clone, Debug, PartialEq)]
pub struct LinearElastic {
    pub lambda: f64,
    pub mu: f64,
    pub density: f64,
}

impl LinearElastic {
    #[inline]
    pub fn update_stress<const D: usize>(&self, stress: &mut Mat<D>, l: &Mat<D>, dt: f64) {
        let d = (l + l.transpose()) * 0.5;
        let tr = d.trace();
        *stress += (d * (2.0 * self.mu) + Mat::<D>::identity() * (self.lambda * tr)) * dt;
    }

    /// Plane strain (D = 2): `σ_zz = λ/(2(λ + μ)) tr σ`, the in-plane trace scaled.
    /// No state needed: with `D_zz = 0` the rate form gives `σ̇_zz = λ tr D` and
    /// `(tr σ)˙ = 2(λ + μ) tr D`, and both start at zero (particles are seeded
    /// stress-free), so the ratio holds at every step up to rounding.
    pub fn stress_zz<const D: usize>(&self, s: &Mat<D>) -> f64 {
        self.lambda / (2.0 * (self.lambda + self.mu)) * s.trace()
    }

    /// `½ σ : ε` with `ε` recovered from `σ` through the compliance, so that no strain
    /// needs storing: `tr ε = tr σ / (Dλ + 2μ)`, `ε = (σ − λ tr ε I) / 2μ`.
    pub fn energy_density<const D: usize>(&self, s: &Mat<D>) -> f64 {
        let tr = s.trace();
        let ss = s.component_mul(s).sum();
        (ss - self.lambda * tr * tr / (D as f64 * self.lambda + 2.0 * self.mu)) / (4.0 * self.mu)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::material::lame;

    /// Uniaxial strain ε in x from zero stress: σ_xx = (λ+2μ) ε, σ_yy = σ_zz = λ ε, and
    /// the energy is ½ (λ+2μ) ε².
    #[test]
    fn uniaxial_strain_3d() {
        let (lambda, mu) = lame(200.0, 0.25);
        let m = LinearElastic {
            lambda,
            mu,
            density: 1.0,
        };
        let eps = 1e-3;
        let mut s = Mat::<3>::zeros();
        let mut l = Mat::<3>::zeros();
        l[(0, 0)] = eps; // over dt = 1
        m.update_stress(&mut s, &l, 1.0);
        assert!((s[(0, 0)] - (lambda + 2.0 * mu) * eps).abs() < 1e-12);
        assert!((s[(1, 1)] - lambda * eps).abs() < 1e-12);
        assert!((s[(2, 2)] - lambda * eps).abs() < 1e-12);
        let w = m.energy_density(&s);
        assert!((w - 0.5 * (lambda + 2.0 * mu) * eps * eps).abs() < 1e-15);
    }

    /// Plane strain, uniaxial strain ε in x over many steps of random size, with an
    /// in-plane shear on the way back: σ_zz integrated as `σ̇_zz = λ tr D` (what a
    /// stored value would hold) equals the derived `λ/(2(λ+μ)) tr σ`, and for the pure
    /// uniaxial state it is the closed form `λ ε`. The energy `½ σ:ε` over all three
    /// directions has no zz term (`ε_zz = 0`), so the 2D compliance formula gives
    /// `½ (λ+2μ) ε²` with σ_zz ≠ 0.
    #[test]
    fn plane_strain_sigma_zz() {
        let (lambda, mu) = lame(200.0, 0.3);
        let m = LinearElastic {
            lambda,
            mu,
            density: 1.0,
        };
        let eps = 1e-3;
        let mut s = Mat::<2>::zeros();
        let mut szz = 0.0;
        let mut done = 0.0;
        let mut k = 1u64;
        while done < eps {
            // Uneven steps (a fixed linear congruential sequence).
            k = k
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let de = ((k >> 11) as f64 / (1u64 << 53) as f64 * 2e-4).min(eps - done);
            let mut l = Mat::<2>::zeros();
            l[(0, 0)] = de;
            m.update_stress(&mut s, &l, 1.0);
            szz += lambda * l.trace();
            done += de;
        }
        assert!((m.stress_zz(&s) - lambda * eps).abs() < 1e-13 * lambda * eps);
        assert!((szz - lambda * eps).abs() < 1e-13 * lambda * eps);
        assert!((m.energy_density(&s) - 0.5 * (lambda + 2.0 * mu) * eps * eps).abs() < 1e-15);
        // A general in-plane path: the identity still holds.
        let l = Mat::<2>::new(-3e-4, 2e-4, 5e-4, 7e-4);
        for _ in 0..7 {
            m.update_stress(&mut s, &l, 0.5);
            szz += lambda * l.trace() * 0.5;
        }
        assert!((m.stress_zz(&s) - szz).abs() < 1e-13 * lambda * eps);
    }

    /// Simple shear γ: σ_xy = μ γ, no normal stress, energy ½ μ γ².
    #[test]
    fn simple_shear_2d() {
        let m = LinearElastic {
            lambda: 3.0,
            mu: 2.0,
            density: 1.0,
        };
        let g = 2e-3;
        let mut s = Mat::<2>::zeros();
        let mut l = Mat::<2>::zeros();
        l[(0, 1)] = g;
        m.update_stress(&mut s, &l, 1.0);
        assert!((s[(0, 1)] - 2.0 * g).abs() < 1e-15 && (s[(1, 0)] - 2.0 * g).abs() < 1e-15);
        assert!(s[(0, 0)].abs() < 1e-15 && s[(1, 1)].abs() < 1e-15);
        assert!((m.energy_density(&s) - 0.5 * 2.0 * g * g).abs() < 1e-15);
    }

    /// Hydrostatic strain e per axis in 3D: p = (3λ + 2μ) e = 3K e.
    #[test]
    fn hydrostatic_3d() {
        let m = LinearElastic {
            lambda: 3.0,
            mu: 2.0,
            density: 1.0,
        };
        let e = 1e-3;
        let mut s = Mat::<3>::zeros();
        m.update_stress(&mut s, &(Mat::<3>::identity() * e), 1.0);
        for a in 0..3 {
            assert!((s[(a, a)] - (3.0 * 3.0 + 2.0 * 2.0) * e).abs() < 1e-14);
        }
        // W = ½ σ:ε = 3/2 (3λ+2μ) e²
        assert!((m.energy_density(&s) - 1.5 * 13.0 * e * e).abs() < 1e-15);
    }
}
