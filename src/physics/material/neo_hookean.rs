//! Compressible neo-Hookean solid, `W = μ/2 (F:F − D) − μ ln J + λ/2 (ln J)²`, Cauchy
//! stress `σ = [μ (F Fᵀ − I) + λ ln J I] / J`. With D = 2 (plane strain, F₃₃ = 1) and
//! D = 1 (uniaxial strain) this is the 3D model restricted, since the missing
//! directions contribute `1 − 1 = 0` to `F:F − D`.

use super::Hyperelastic;
use crate::physics::tensor::{det, Mat};

#[derive(Clone, Debug, PartialEq)]
pub struct NeoHookean {
    pub lambda: f64,
    pub mu: f64,
    pub density: f64,
}

impl Hyperelastic for NeoHookean {
    /// The Kirchhoff stress `τ = J σ = μ F Fᵀ + (λ ln J − μ) I` and `J`: a particle's
    /// volume times its Cauchy stress is `V₀ τ`, without the division by `J`.
    #[inline]
    fn kirchhoff<const D: usize>(&self, f: &Mat<D>) -> (Mat<D>, f64) {
        let j = det(f);
        // Times 1: exact, so `μ F Fᵀ + c I` itself (and the compiler drops it).
        (self.scaled_tau(f, self.lambda * j.ln() - self.mu, 1.0), j)
    }

    #[inline]
    fn stress<const D: usize>(&self, f: &Mat<D>) -> Mat<D> {
        let j = det(f);
        // One division, not D² (a division takes several times a multiplication's
        // issue slots, and this runs per particle and step): round-off apart, the same.
        self.scaled_tau(f, self.lambda * j.ln() - self.mu, 1.0 / j)
    }

    /// Plane strain (D = 2): the out-of-plane stress from `F` with `F₃₃ = 1`,
    /// `σ_zz = [μ (1 − 1) + λ ln J] / J = λ ln J / J`. No state needed.
    fn stress_zz<const D: usize>(&self, f: &Mat<D>) -> f64 {
        let j = det(f);
        self.lambda * j.ln() / j
    }

    /// Energy per reference volume.
    #[inline]
    fn energy_density<const D: usize>(&self, f: &Mat<D>) -> f64 {
        let j = det(f);
        let lj = j.ln();
        0.5 * self.mu * (f.component_mul(f).sum() - D as f64) - self.mu * lj
            + 0.5 * self.lambda * lj * lj
    }
}

impl NeoHookean {
    /// `(μ F Fᵀ + c I) · scale`, entry by entry, the upper triangle mirrored:
    /// nalgebra's product went through an out-of-line `gemv` per column in 3D (1.5 % of
    /// the 3D block drop's step) and formed both triangles. The same operations in the
    /// same order, so the same bits: the sums over `m` in ascending order, and off the
    /// diagonal `I c` adds `0 c` (−0 for c < 0), as the identity's product does.
    #[inline(always)]
    fn scaled_tau<const D: usize>(&self, f: &Mat<D>, c: f64, scale: f64) -> Mat<D> {
        let off = 0.0 * c;
        let mut s = Mat::<D>::zeros();
        for i in 0..D {
            for k in i..D {
                let mut b = f[(i, 0)] * f[(k, 0)];
                for m in 1..D {
                    b += f[(i, m)] * f[(k, m)];
                }
                let v = (b * self.mu + if i == k { c } else { off }) * scale;
                s[(i, k)] = v;
                s[(k, i)] = v;
            }
        }
        s
    }

    /// Longitudinal wave speed from the current tangent modulus `λ + 2(μ − λ ln J)`
    /// over the reference density; never below the small-strain speed.
    #[inline]
    pub fn wave_speed(&self, j: f64) -> f64 {
        let small = self.lambda + 2.0 * self.mu;
        // Under tension (ln J >= 0, λ >= 0) the tangent term is at most `small`, rounding
        // included, so the maximum is `small` without the logarithm.
        let m = if j >= 1.0 && self.lambda >= 0.0 {
            small
        } else {
            (self.lambda + 2.0 * (self.mu - self.lambda * j.ln())).max(small)
        };
        (m / self.density).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> NeoHookean {
        NeoHookean {
            lambda: 5.0,
            mu: 3.0,
            density: 1.0,
        }
    }

    /// The wave speed is `sqrt(max(λ + 2(μ − λ ln J), λ + 2μ) / ρ)`, bit for bit, on
    /// both sides of J = 1 and for λ < 0 (ν < 0), where the shortcut under tension
    /// must not apply.
    #[test]
    fn wave_speed_is_the_tangent_modulus_formula() {
        for (lambda, mu) in [(5.0, 3.0), (-0.5, 3.0), (1e3 / 3.6 * 0.2 / 0.6, 1e3 / 2.4)] {
            let m = NeoHookean {
                lambda,
                mu,
                density: 1.7,
            };
            for j in [0.3, 0.9, 0.999_999, 1.0, 1.000_001, 1.2, 7.0] {
                let tangent: f64 = lambda + 2.0 * (mu - lambda * f64::ln(j));
                let want = (tangent.max(lambda + 2.0 * mu) / 1.7).sqrt();
                assert_eq!(
                    m.wave_speed(j).to_bits(),
                    want.to_bits(),
                    "λ {lambda}, J {j}"
                );
            }
        }
    }

    /// The stress is `(μ F Fᵀ + (λ ln J − μ) I) / J` as nalgebra's matrix operations
    /// form it, to the bit, in 1D, 2D and 3D, for stretches and compressions (ln J of
    /// either sign, so both signs of the zero that `I c` adds off the diagonal); so is
    /// the Kirchhoff stress `μ F Fᵀ + (λ ln J − μ) I`, with `J` the determinant, and
    /// `τ / J` is the stress to round-off (1e-15 of its largest entry).
    #[test]
    fn stress_and_kirchhoff_are_the_matrix_formulas_to_the_bit() {
        fn check<const D: usize>(m: &NeoHookean, rng: &mut decomposition::splitmix::Rng) {
            for t in 0..2000 {
                // Random near I, and (first) a diagonal stretch whose zeros are −0:
                // there F Fᵀ is −0 off the diagonal, and the sign of what `I c` adds
                // shows in the result.
                let f = Mat::<D>::from_fn(|i, k| match (t, i == k) {
                    (0, true) => 1.0 + 0.1 * i as f64,
                    (0, false) => -0.0,
                    _ => f64::from(u8::from(i == k)) + 0.4 * (rng.f64() - 0.5),
                });
                let j = det(&f);
                if j <= 0.0 {
                    continue;
                }
                let want = (f * f.transpose() * m.mu
                    + Mat::<D>::identity() * (m.lambda * j.ln() - m.mu))
                    * (1.0 / j);
                let got = m.stress(&f);
                for (g, w) in got.iter().zip(want.iter()) {
                    assert_eq!(g.to_bits(), w.to_bits(), "F {f}");
                }
                let want_tau =
                    f * f.transpose() * m.mu + Mat::<D>::identity() * (m.lambda * j.ln() - m.mu);
                let (tau, jt) = m.kirchhoff(&f);
                assert_eq!(jt.to_bits(), j.to_bits());
                let scale = got.amax();
                for ((t, w), s) in tau.iter().zip(want_tau.iter()).zip(got.iter()) {
                    assert_eq!(t.to_bits(), w.to_bits(), "F {f}");
                    assert!(
                        (t / j - s).abs() <= 1e-15 * scale,
                        "F {f}: {t} / {j} against {s}"
                    );
                }
            }
        }
        let mut rng = decomposition::splitmix::Rng::new(7);
        // λ ln J − μ of both signs: μ small against λ, and μ large.
        for (lambda, mu) in [
            (5.0, 3.0),
            (500.0, 1e-3),
            (1e3 / 3.6 * 0.2 / 0.6, 1e3 / 2.4),
        ] {
            let m = NeoHookean {
                lambda,
                mu,
                density: 1.0,
            };
            check::<1>(&m, &mut rng);
            check::<2>(&m, &mut rng);
            check::<3>(&m, &mut rng);
        }
    }

    /// Uniaxial stretch F = diag(s, 1, 1): σ_xx = [μ (s² − 1) + λ ln s] / s,
    /// σ_yy = λ ln s / s, and W matches the closed form.
    #[test]
    fn uniaxial_strain() {
        let m = model();
        let s = 1.3;
        let mut f = Mat::<3>::identity();
        f[(0, 0)] = s;
        let sig = m.stress(&f);
        assert!((sig[(0, 0)] - (3.0 * (s * s - 1.0) + 5.0 * s.ln()) / s).abs() < 1e-14);
        assert!((sig[(1, 1)] - 5.0 * s.ln() / s).abs() < 1e-14);
        let w = 0.5 * 3.0 * (s * s - 1.0) - 3.0 * s.ln() + 2.5 * s.ln().powi(2);
        assert!((m.energy_density(&f) - w).abs() < 1e-14);
        // 1D and plane strain give the same normal stress along the stretch.
        let f1 = Mat::<1>::identity() * s;
        assert!((m.stress(&f1)[(0, 0)] - sig[(0, 0)]).abs() < 1e-14);
        assert!((m.energy_density(&f1) - w).abs() < 1e-14);
    }

    /// Plane strain: σ_zz = λ ln J / J for uniaxial stretch, and for a general in-plane
    /// F it is the zz entry of the 3D model's stress at F embedded with F₃₃ = 1.
    #[test]
    fn plane_strain_sigma_zz() {
        let m = model();
        let s: f64 = 0.8;
        let f = Mat::<2>::new(s, 0.0, 0.0, 1.0);
        assert!((m.stress_zz(&f) - 5.0 * s.ln() / s).abs() < 1e-14);
        let f = Mat::<2>::new(1.2, 0.3, -0.1, 0.9);
        let mut f3 = Mat::<3>::identity();
        f3.fixed_view_mut::<2, 2>(0, 0).copy_from(&f);
        let j = det(&f);
        assert!((m.stress_zz(&f) - 5.0 * j.ln() / j).abs() < 1e-14);
        assert!((m.stress_zz(&f) - m.stress(&f3)[(2, 2)]).abs() < 1e-14);
        // The in-plane block of the 3D stress is the plane-strain stress.
        assert!((m.stress(&f3).fixed_view::<2, 2>(0, 0) - m.stress(&f)).norm() < 1e-14);
    }

    /// Simple shear F = I + γ e_x⊗e_y: J = 1, σ_xy = μγ, σ_xx = μγ², σ_yy = 0.
    #[test]
    fn simple_shear() {
        let m = model();
        let g = 0.4;
        let mut f = Mat::<2>::identity();
        f[(0, 1)] = g;
        let sig = m.stress(&f);
        assert!((sig[(0, 1)] - 3.0 * g).abs() < 1e-14);
        assert!((sig[(0, 0)] - 3.0 * g * g).abs() < 1e-14);
        assert!(sig[(1, 1)].abs() < 1e-14);
        assert!((m.energy_density(&f) - 0.5 * 3.0 * g * g).abs() < 1e-14);
    }

    /// Hydrostatic F = s I in 3D: pressure-only stress (μ (s² − 1) + 3λ ln s) / s³ and
    /// energy from the formula; the stress is the derivative of the energy: for
    /// F = s I, dW/ds = 3 s² σ_xx (Cauchy × J / s, times the three directions).
    #[test]
    fn hydrostatic() {
        let m = model();
        let s = 0.9;
        let f = Mat::<3>::identity() * s;
        let sig = m.stress(&f);
        let j = s * s * s;
        let expect = (3.0 * (s * s - 1.0) + 5.0 * j.ln()) / j;
        for a in 0..3 {
            assert!((sig[(a, a)] - expect).abs() < 1e-13);
        }
        assert!(sig[(0, 1)].abs() < 1e-15);
        let e = 1e-6;
        let dw = (m.energy_density(&(Mat::<3>::identity() * (s + e)))
            - m.energy_density(&(Mat::<3>::identity() * (s - e))))
            / (2.0 * e);
        assert!((dw - 3.0 * s * s * sig[(0, 0)]).abs() < 1e-7);
    }
}
