//! Isotropic linear elasticity in rate form, for the Kirchhoff stress `τ = J σ` and
//! objective through the Jaumann rate:
//! `τ̊ = τ̇ − W τ + τ W = λ tr(D) I + 2 μ D`, `D = sym L`, `W = skew L`.
//!
//! Why this form: its stored energy per reference volume, `w(τ) = ½ τ : C⁻¹ : τ`,
//! changes at exactly the stress power, `ẇ = C⁻¹τ : τ̊ = τ : D`, because the rotation
//! terms do no work on an isotropic `C⁻¹τ`. The rate form of the Cauchy stress without
//! the rotation has neither property: a body that turns is strained by its own turning,
//! and a vibrating one gains energy through `J`; the colliding disks gained a third of
//! their energy in 300 s that way. At small strain (`J ≈ 1`, `W ≈ 0`) all these forms
//! agree to first order, which is what the verification problems test.
//!
//! Integrated as Hughes & Winget (1980), on the step's displacement gradient at the
//! midpoint configuration, `M = G (I + ½ G)⁻¹` with `G = L Δt`: the strain increment
//! `Δε = sym M`, the rotation `Q = (I − ½ Δω)⁻¹ (I + ½ Δω)` with `Δω = skew M`
//! (orthogonal for any step), and `τ ← Q τ Qᵀ + λ tr Δε I + 2 μ Δε`. The midpoint
//! matters: the particles move along straight lines within a step, so a turning body
//! grows by `det(I + W Δt) = 1 + |ω Δt|²` a step, and `Δε` sees that growth (`tr Δε`
//! is `ln det(I + G)` to third order) where `sym L Δt` does not; without it a spinning
//! disk spiralled out, its radius growing 8 % in 16 turns. Particles store the Cauchy
//! stress, so the update divides by the new `J`:
//! `σ ← Q σ Qᵀ / J_step + (λ tr Δε I + 2 μ Δε) / J`.

use crate::physics::material::VolumeChange;
use crate::physics::tensor::{adjugate, det, Mat};

#[derive(Clone, Debug, PartialEq)]
pub struct LinearElastic {
    pub lambda: f64,
    pub mu: f64,
    pub density: f64,
    /// The small-strain form instead (`strain = "small"`): `σ += Δt (λ tr D I + 2μ D)`
    /// on the Cauchy stress, the update of the linear theory the verification problems
    /// solve. At a strain ε it departs from linear elasticity by about ε/2 of the
    /// stress, the finite form by 3ε/2, which at the vibrating bar's ε = 1 % is the
    /// difference between its 3.4 % and 4.0 % error against the exact solution.
    pub small: bool,
}

impl LinearElastic {
    /// The Cauchy stress after a step with velocity gradient `l` over `dt`, in which
    /// the volume changed by `j` ([`VolumeChange`]).
    #[inline]
    pub fn update_stress<const D: usize>(
        &self,
        stress: &mut Mat<D>,
        l: &Mat<D>,
        dt: f64,
        j: VolumeChange,
    ) {
        if self.small {
            let d = (l + l.transpose()) * (0.5 * dt);
            *stress += d * (2.0 * self.mu) + Mat::<D>::identity() * (self.lambda * d.trace());
            return;
        }
        let (de, q) = increment(l, dt);
        self.apply(stress, &de, &q, j);
    }

    /// `σ ← Q σ Qᵀ / J_step + (λ tr Δε I + 2 μ Δε) / J`, the increment `(Δε, Q)` of
    /// [`increment`].
    #[inline]
    pub fn apply<const D: usize>(
        &self,
        stress: &mut Mat<D>,
        de: &Mat<D>,
        q: &Mat<D>,
        j: VolumeChange,
    ) {
        let tr = de.trace();
        // Two divisions, not one per entry.
        let (over_step, over_total) = (1.0 / j.step, 1.0 / j.total);
        *stress = q * *stress * q.transpose() * over_step
            + (de * (2.0 * self.mu) + Mat::<D>::identity() * (self.lambda * tr)) * over_total;
    }

    /// Plane strain (D = 2): `σ_zz = λ/(2(λ + μ)) tr σ`, the in-plane trace scaled.
    /// No state needed: with `Δε_zz = 0` a step adds `λ tr Δε` to `τ_zz` and
    /// `2(λ + μ) tr Δε` to `tr τ`, the rotation (about z) keeps both, both start at zero
    /// (particles are seeded stress-free) and `σ = τ / J` scales both alike, so the
    /// ratio holds at every step up to rounding.
    pub fn stress_zz<const D: usize>(&self, s: &Mat<D>) -> f64 {
        self.lambda / (2.0 * (self.lambda + self.mu)) * s.trace()
    }

    /// `½ σ : ε` with `ε` recovered from `σ` through the compliance, so that no strain
    /// needs storing: `tr ε = tr σ / (Dλ + 2μ)`, `ε = (σ − λ tr ε I) / 2μ`. Of the
    /// Kirchhoff stress it is the stored energy per reference volume, `w(τ)`; a
    /// particle's is `V₀ w(J σ) = V J w(σ)`.
    pub fn energy_density<const D: usize>(&self, s: &Mat<D>) -> f64 {
        let tr = s.trace();
        let ss = s.component_mul(s).sum();
        (ss - self.lambda * tr * tr / (D as f64 * self.lambda + 2.0 * self.mu)) / (4.0 * self.mu)
    }
}

/// The strain increment `Δε` and the rotation `Q` of a step with velocity gradient `l`
/// over `dt`, at the midpoint configuration (the module's comment).
#[inline]
pub fn increment<const D: usize>(l: &Mat<D>, dt: f64) -> (Mat<D>, Mat<D>) {
    let g = l * dt;
    // `M = N / d` with `N = G adj(A)`, `d = det A`, `A = I + ½ G`. The rotation is the
    // Cayley transform of the skew `B = ½ skew M = K / d`, `K = ¼ (N − Nᵀ)`, in closed
    // form `(I − B)⁻¹ (I + B) = I + 2 (B + B²) / (1 + ½ B:B)` (as `B³ = −(½ B:B) B`
    // for D ≤ 3), multiplied through by `d²` so that its division does not wait for
    // `1 / d`: two divisions side by side, not in a chain.
    let a = Mat::<D>::identity() + g * 0.5;
    let d = det(&a);
    let n = g * adjugate(&a);
    let de = (n + n.transpose()) * (0.5 / d);
    let k = (n - n.transpose()) * 0.25;
    let k2 = 0.5 * k.component_mul(&k).sum();
    let q = Mat::<D>::identity() + (k * d + k * k) * (2.0 / (d * d + k2));
    (de, q)
}

/// The velocity gradient over `dt = 1` whose midpoint gradient `M` ([`increment`]) is
/// exactly `e`: `G = e (I − ½ e)⁻¹`, for tests that give the law a strain (a symmetric
/// `e` strains by `e` and turns nothing).
#[cfg(test)]
pub(crate) fn strain_step<const D: usize>(e: &Mat<D>) -> Mat<D> {
    let a = Mat::<D>::identity() - e * 0.5;
    e * adjugate(&a) * (1.0 / det(&a))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::material::lame;
    use crate::physics::tensor::det;
    use decomposition::splitmix::Rng;

    fn model(e: f64, nu: f64) -> LinearElastic {
        let (lambda, mu) = lame(e, nu);
        LinearElastic {
            lambda,
            mu,
            density: 1.0,
            small: false,
        }
    }

    /// The law alone: a strain increment `de` from zero stress, no rotation or volume
    /// change.
    fn stress_of<const D: usize>(m: &LinearElastic, de: Mat<D>) -> Mat<D> {
        let mut s = Mat::<D>::zeros();
        m.apply(&mut s, &de, &Mat::<D>::identity(), VolumeChange::NONE);
        s
    }

    /// Uniaxial strain ε in x from zero stress: σ_xx = (λ+2μ) ε, σ_yy = σ_zz = λ ε, and
    /// the energy is ½ (λ+2μ) ε².
    #[test]
    fn uniaxial_strain_3d() {
        let m = model(200.0, 0.25);
        let (lambda, mu) = (m.lambda, m.mu);
        let eps = 1e-3;
        let s = stress_of(&m, Mat::<3>::from_diagonal(&[eps, 0.0, 0.0].into()));
        assert!((s[(0, 0)] - (lambda + 2.0 * mu) * eps).abs() < 1e-12);
        assert!((s[(1, 1)] - lambda * eps).abs() < 1e-12);
        assert!((s[(2, 2)] - lambda * eps).abs() < 1e-12);
        let w = m.energy_density(&s);
        assert!((w - 0.5 * (lambda + 2.0 * mu) * eps * eps).abs() < 1e-15);
    }

    /// Plane strain: the out-of-plane stress carried as a state the way `brittle` does
    /// (`σ_zz ← σ_zz / J_step + λ tr Δε / J`) equals the derived `λ/(2(λ+μ)) tr σ` over
    /// a path of stretch, shear, turning and volume change; for uniaxial strain it is
    /// the closed form `λ ε`, and the energy `½ σ:ε` has no zz term (`ε_zz = 0`), so
    /// the 2D compliance formula gives `½ (λ+2μ) ε²` with σ_zz ≠ 0.
    #[test]
    fn plane_strain_sigma_zz() {
        let m = model(200.0, 0.3);
        let (lambda, mu) = (m.lambda, m.mu);
        let eps = 1e-3;
        let s = stress_of(&m, Mat::<2>::new(eps, 0.0, 0.0, 0.0));
        assert!((m.stress_zz(&s) - lambda * eps).abs() < 1e-13 * lambda * eps);
        assert!((m.energy_density(&s) - 0.5 * (lambda + 2.0 * mu) * eps * eps).abs() < 1e-15);
        let (mut s, mut szz, mut total) = (s, lambda * eps, 1.0);
        let mut rng = Rng::new(7);
        for _ in 0..50 {
            let l = Mat::<2>::from_fn(|_, _| 4e-3 * (rng.f64() - 0.5));
            let step = det(&(Mat::<2>::identity() + l));
            total *= step;
            m.update_stress(&mut s, &l, 1.0, VolumeChange { step, total });
            szz = szz / step + lambda * increment(&l, 1.0).0.trace() / total;
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
            small: false,
        };
        let g = 2e-3;
        let s = stress_of(&m, Mat::<2>::new(0.0, 0.5 * g, 0.5 * g, 0.0));
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
            small: false,
        };
        let e = 1e-3;
        let s = stress_of(&m, Mat::<3>::identity() * e);
        for a in 0..3 {
            assert!((s[(a, a)] - (3.0 * 3.0 + 2.0 * 2.0) * e).abs() < 1e-14);
        }
        // W = ½ σ:ε = 3/2 (3λ+2μ) e²
        assert!((m.energy_density(&s) - 1.5 * 13.0 * e * e).abs() < 1e-15);
    }

    /// A rotation about the axis `n` (Rodrigues), in 3D, or in the plane for D = 2.
    fn rotation<const D: usize>(theta: f64, n: [f64; 3]) -> Mat<D> {
        let k = nalgebra::Matrix3::new(0.0, -n[2], n[1], n[2], 0.0, -n[0], -n[1], n[0], 0.0);
        let r = nalgebra::Matrix3::identity() + k * theta.sin() + k * k * (1.0 - theta.cos());
        Mat::<D>::from_fn(|i, c| r[(i, c)])
    }

    /// Objectivity: a step whose increment `I + L Δt` is a rotation `R` strains
    /// nothing (`Δε = 0`) and turns the stress by exactly `R` (`Q = R`), so after any
    /// number of such steps the stress is `R σ₀ Rᵀ` and its energy is unchanged.
    #[test]
    fn a_turning_step_turns_the_stress() {
        fn each<const D: usize>() {
            let m = model(200.0, 0.3);
            let s0 = Mat::<D>::from_fn(|i, c| 1.0 + (i + c) as f64 + 2.0 * (i * c) as f64);
            let n = [0.48, 0.6, 0.64]; // unit; D = 2 turns about the z axis
            let theta = 0.05;
            let r = rotation::<D>(theta, if D == 2 { [0.0, 0.0, 1.0] } else { n });
            let l = r - Mat::<D>::identity(); // over dt = 1
            let (de, q) = increment(&l, 1.0);
            assert!(de.norm() < 1e-16 && (q - r).norm() < 1e-15, "{de} {q}");
            let mut s = s0;
            for _ in 0..40 {
                m.update_stress(&mut s, &l, 1.0, VolumeChange::NONE);
            }
            let r40 = rotation::<D>(40.0 * theta, if D == 2 { [0.0, 0.0, 1.0] } else { n });
            // Each step turns by `q`, within `|q − r|` of `r`, on both sides, adds the
            // law's response to the rounding left in `Δε`, and rounds.
            let err = (s - r40 * s0 * r40.transpose()).norm();
            let law = (2.0 * m.mu + D as f64 * m.lambda) * de.norm();
            let bound = 40.0 * ((2.0 * (q - r).norm() + 4.0 * f64::EPSILON) * s0.norm() + law);
            assert!(err < bound, "D = {D}: {err:e} > {bound:e}");
            let (w, w0) = (m.energy_density(&s), m.energy_density(&s0));
            // `∂w/∂σ = C⁻¹σ`, at most `|σ| / 2μ`.
            assert!((w - w0).abs() < s0.norm() / (2.0 * m.mu) * bound + 4.0 * f64::EPSILON * w0);
        }
        each::<2>();
        each::<3>();
    }

    /// The midpoint strain sees the volume change of a step to third order:
    /// `tr Δε − ln det(I + G)` is `tr G³ / 12` and smaller terms, where `tr sym G` is
    /// off by `½ tr G²`. For a pure turn `sym G` has no trace at all while the
    /// particles' straight paths grow the volume by `1 + |ω Δt|²`.
    #[test]
    fn the_midpoint_strain_sees_the_volume_change() {
        fn each<const D: usize>(rng: &mut Rng) {
            for _ in 0..100 {
                let g = Mat::<D>::from_fn(|_, _| 2e-2 * (rng.f64() - 0.5));
                let (de, _) = increment(&g, 1.0);
                let exact = det(&(Mat::<D>::identity() + g)).ln();
                let n = g.norm();
                assert!((de.trace() - exact).abs() <= n * n * n, "{g}");
            }
        }
        let mut rng = Rng::new(3);
        each::<2>(&mut rng);
        each::<3>(&mut rng);
        // A pure turn by ω Δt = 1e-3: tr Δε = |ω Δt|² to fourth order.
        let w = 1e-3;
        let (de, _) = increment(&Mat::<2>::new(0.0, -w, w, 0.0), 1.0);
        assert!((de.trace() - (1.0 + w * w).ln()).abs() < w.powi(4));
    }

    /// The stored energy per reference volume, `w(τ)` with `τ = J σ`, changes over
    /// each step by exactly the trapezoidal stress power `½ (Q τ Qᵀ + τ') : Δε` (the
    /// rotation keeps `w`, and `w` is quadratic), along a random path of stretch,
    /// shear, turning and volume change: no energy is made or lost by the law.
    #[test]
    fn energy_changes_by_the_stress_power() {
        fn each<const D: usize>(rng: &mut Rng) {
            let m = model(200.0, 0.3);
            let (mut s, mut total) = (Mat::<D>::zeros(), 1.0);
            for _ in 0..300 {
                let l = Mat::<D>::from_fn(|_, _| 1e-2 * (rng.f64() - 0.5));
                let dt = 0.5;
                let step = det(&(Mat::<D>::identity() + l * dt));
                let (de, q) = increment(&l, dt);
                let tau = s * total;
                total *= step;
                m.update_stress(&mut s, &l, dt, VolumeChange { step, total });
                let tau_new = s * total;
                let power = 0.5 * (q * tau * q.transpose() + tau_new).component_mul(&de).sum();
                let change = m.energy_density(&tau_new) - m.energy_density(&tau);
                let scale = m.energy_density(&tau_new).max(1e-3);
                assert!((change - power).abs() < 1e-12 * scale, "{change} {power}");
            }
            assert!((total - 1.0).abs() > 1e-3, "the path changed the volume");
        }
        let mut rng = Rng::new(11);
        each::<2>(&mut rng);
        each::<3>(&mut rng);
    }
}
