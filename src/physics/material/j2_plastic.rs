//! J2 (von Mises) plasticity at finite strain with linear isotropic hardening: Hencky
//! elasticity and the exponential-map return of Simo (1992), de Souza Neto et al.
//! (2008) ch. 14.
//!
//! State per particle: the elastic left Cauchy–Green tensor `b_e` (always 3×3, since
//! plane strain and uniaxial strain still have an out-of-plane elastic stretch once
//! plastic flow starts) and the equivalent plastic strain `ε_p`; initially `b_e = I`,
//! `ε_p = 0`. One step with relative deformation gradient `f = I + Δt L` (1 on the
//! missing diagonal entries):
//!
//! - trial `b_e^tr = f b_e fᵀ = Σ λ_i² n_i⊗n_i`, elastic log strains `ε_i = ½ ln λ_i²`;
//! - Hencky: `τ_i = K tr ε + 2μ dev(ε)_i`, `K = λ + 2μ/3`;
//! - yield `φ = q − (σ_y + H ε_p)`, `q = √(3/2) |dev τ|`; if `φ > 0`:
//!   `Δγ = φ / (3μ + H)`, `dev ε` and `dev τ` scaled by `1 − 3μΔγ/q`, `ε_p += Δγ`;
//! - `b_e = Σ exp(2ε_i) n_i⊗n_i`, Kirchhoff `τ = Σ τ_i n_i⊗n_i`, Cauchy `σ = τ / J`
//!   with `J = exp(tr ε) = det F` (the flow is isochoric).
//!
//! In the log strains the return is the small-strain radial return, so it is exact for
//! proportional loading with fixed principal axes, whatever the number of steps.

use crate::physics::tensor::Mat;
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

#[derive(Clone, Debug, PartialEq)]
pub struct J2Plastic {
    pub lambda: f64,
    pub mu: f64,
    pub density: f64,
    pub yield_stress: f64,
    pub hardening: f64,
}

impl J2Plastic {
    #[inline]
    fn bulk(&self) -> f64 {
        self.lambda + 2.0 * self.mu / 3.0
    }

    /// Advance one step; returns the new Cauchy stress.
    pub fn update<const D: usize>(
        &self,
        be: &mut Matrix3<f64>,
        eps_p: &mut f64,
        l: &Mat<D>,
        dt: f64,
    ) -> Mat<D> {
        let mut f = Matrix3::<f64>::identity();
        for i in 0..D {
            for j in 0..D {
                f[(i, j)] += dt * l[(i, j)];
            }
        }
        let b = f * *be * f.transpose();
        // f b fᵀ is symmetric only up to rounding; the eigensolver assumes symmetry.
        let b = (b + b.transpose()) * 0.5;
        let eig = SymmetricEigen::new(b);
        let n = eig.eigenvectors;
        let eps = eig.eigenvalues.map(|x| 0.5 * x.ln());
        let tr = eps.sum();
        let mut dev = eps.add_scalar(-tr / 3.0);

        let q = 1.5f64.sqrt() * 2.0 * self.mu * dev.norm();
        let flow = self.yield_stress + self.hardening * *eps_p;
        if q > flow {
            let dgamma = (q - flow) / (3.0 * self.mu + self.hardening);
            dev *= 1.0 - 3.0 * self.mu * dgamma / q;
            *eps_p += dgamma;
            let e2 = dev.add_scalar(tr / 3.0).map(|x| (2.0 * x).exp());
            *be = n * Matrix3::from_diagonal(&e2) * n.transpose();
        } else {
            // Elastic step: the trial state is the answer, no need for the exp∘ln round trip.
            *be = b;
        }

        let tau: Vector3<f64> = (dev * (2.0 * self.mu)).add_scalar(self.bulk() * tr);
        let sigma = n * Matrix3::from_diagonal(&tau) * n.transpose() / tr.exp();
        Mat::<D>::from_fn(|i, j| sigma[(i, j)])
    }

    /// Plane strain (D = 2): the out-of-plane Cauchy stress from `b_e`, which holds the
    /// out-of-plane elastic stretch. There `b_e` has no xz, yz entries (the step's `f`
    /// has none, and the return keeps eigenvectors), so `ε_zz = ½ ln b_zz` is a
    /// principal log strain: `τ_zz = K tr ε + 2μ (ε_zz − tr ε/3) = λ tr ε + 2μ ε_zz`,
    /// `σ_zz = τ_zz / J` with `tr ε = ln J = ½ ln det b_e`. No extra state needed.
    pub fn stress_zz(&self, be: &Matrix3<f64>) -> f64 {
        let tr = 0.5 * be.determinant().ln();
        let ezz = 0.5 * be[(2, 2)].ln();
        (self.lambda * tr + 2.0 * self.mu * ezz) / tr.exp()
    }

    /// Stored (elastic) energy per reference volume: `K/2 (tr ε)² + μ |dev ε|²`,
    /// `ε = ½ ln b_e`.
    pub fn energy_density(&self, be: &Matrix3<f64>) -> f64 {
        let eps = be.symmetric_eigenvalues().map(|x| 0.5 * x.ln());
        let tr = eps.sum();
        let dev = eps.add_scalar(-tr / 3.0);
        0.5 * self.bulk() * tr * tr + self.mu * dev.norm_squared()
    }

    /// Plastic work per reference volume, the integral of the yield stress along the
    /// path: `σ_y ε_p + H ε_p²/2`.
    pub fn plastic_work_density(&self, eps_p: f64) -> f64 {
        eps_p * (self.yield_stress + 0.5 * self.hardening * eps_p)
    }

    /// Longitudinal wave speed at volume ratio `j`, over the reference density ρ₀. In
    /// uniaxial strain the spatial speed is `c² = (λ + 2μ − τ_xx) / ρ₀`; elastic Hencky
    /// has `τ_xx = (λ + 2μ) ln j`, so `c² = (λ + 2μ)(1 − ln j) / ρ₀`: faster in
    /// compression, slower in tension, where the small-strain speed is kept as a floor
    /// (as in the neo-Hookean model). Plastic flow lowers the tangent by `4μ²/(3μ+H)`,
    /// more than the `⅔ (σ_y + H ε_p)` it adds to `−τ_xx` whenever σ_y ≪ μ, so the
    /// elastic speed bounds the plastic one.
    #[inline]
    pub fn wave_speed(&self, j: f64) -> f64 {
        ((self.lambda + 2.0 * self.mu) * (1.0 - j.ln()).max(1.0) / self.density).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::material::lame;
    use nalgebra::{Rotation3, Unit};

    /// Steel-like ratios: yield strain σ_y/2μ ≈ 3e-3, mild hardening.
    fn model() -> J2Plastic {
        let (lambda, mu) = lame(200.0, 0.3);
        J2Plastic {
            lambda,
            mu,
            density: 7.8,
            yield_stress: 0.5,
            hardening: 10.0,
        }
    }

    /// The same model, elastic in the tests that want elastic states at finite strain:
    /// small elastic strains would lose relative precision, since b_e holds 1 + 2ε and
    /// its rounding (1e-16) is a 1e-16/ε relative error in the log strain.
    fn elastic_model() -> J2Plastic {
        J2Plastic {
            yield_stress: 1e3,
            ..model()
        }
    }

    fn close(a: f64, b: f64, rel: f64) -> bool {
        (a - b).abs() <= rel * b.abs()
    }

    /// One step whose relative deformation gradient is exactly `f` (dt = 1, l = f − I).
    fn step<const D: usize>(
        m: &J2Plastic,
        be: &mut Matrix3<f64>,
        ep: &mut f64,
        f: &Mat<D>,
    ) -> Mat<D> {
        m.update(be, ep, &(f - Mat::<D>::identity()), 1.0)
    }

    /// Von Mises stress of a 3×3 stress.
    fn mises(t: &Matrix3<f64>) -> f64 {
        let dev = t - Matrix3::identity() * (t.trace() / 3.0);
        1.5f64.sqrt() * dev.norm()
    }

    /// Von Mises stress of the Hencky Kirchhoff stress of `b_e` (for plane strain, where
    /// the returned stress lacks τ_zz).
    fn mises_of_be(m: &J2Plastic, be: &Matrix3<f64>) -> f64 {
        let eps = be.symmetric_eigenvalues().map(|x| 0.5 * x.ln());
        let dev = eps.add_scalar(-eps.sum() / 3.0);
        1.5f64.sqrt() * 2.0 * m.mu * dev.norm()
    }

    /// F = s I in 3D, in one step or several (increments multiply): pure pressure
    /// τ = K ln(s³) I, no plastic strain even with a tiny yield stress.
    #[test]
    fn hydrostatic_3d_is_elastic_pressure() {
        let m = J2Plastic {
            yield_stress: 1e-6,
            ..model()
        };
        for &s in &[0.8, 1.25] {
            for &n in &[1, 5] {
                let mut be = Matrix3::identity();
                let mut ep = 0.0;
                let inc = Mat::<3>::identity() * f64::powf(s, 1.0 / n as f64);
                let mut sig = Mat::<3>::zeros();
                for _ in 0..n {
                    sig = step(&m, &mut be, &mut ep, &inc);
                }
                let j = s * s * s;
                let tau = m.bulk() * j.ln();
                assert_eq!(ep, 0.0);
                for a in 0..3 {
                    assert!(close(sig[(a, a)] * j, tau, 1e-13), "{s} {n}: {sig}");
                    for b in 0..a {
                        assert!(sig[(a, b)].abs() < 1e-14 * tau.abs(), "{s} {n}: {sig}");
                    }
                }
                assert!((be - Matrix3::identity() * (s * s)).norm() < 1e-14);
            }
        }
    }

    /// F = s I in the D simulated directions, stretch 1 in the others: elastic Hencky,
    /// τ_i = λ tr ε + 2μ ε_i with ε = (ln s, .., 0, ..), σ = τ / s^D.
    fn check_hydrostatic_lower_d<const D: usize>() {
        let m = elastic_model();
        let s: f64 = 1.2;
        let mut be = Matrix3::identity();
        let mut ep = 0.0;
        let sig = step(&m, &mut be, &mut ep, &(Mat::<D>::identity() * s));
        let e = s.ln();
        let tr = D as f64 * e;
        let expect = m.lambda * tr + 2.0 * m.mu * e;
        assert_eq!(ep, 0.0);
        for a in 0..D {
            assert!(
                close(sig[(a, a)] * tr.exp(), expect, 1e-13),
                "D = {D}: {sig}"
            );
            for b in 0..a {
                assert!(sig[(a, b)].abs() < 1e-14 * expect, "D = {D}: {sig}");
            }
        }
        // The missing directions carry Kirchhoff stress λ tr ε only.
        if D < 3 {
            let (mut be3, mut ep3) = (Matrix3::identity(), 0.0);
            let mut f3 = Mat::<3>::identity();
            for a in 0..D {
                f3[(a, a)] = s;
            }
            let s3 = step(&m, &mut be3, &mut ep3, &f3);
            assert!(close(s3[(2, 2)] * tr.exp(), m.lambda * tr, 1e-13));
        }
        for a in 0..3 {
            let x = if a < D { s * s } else { 1.0 };
            assert!((be[(a, a)] - x).abs() < 1e-15);
        }
    }

    #[test]
    fn hydrostatic_plane_strain_and_1d() {
        check_hydrostatic_lower_d::<2>();
        check_hydrostatic_lower_d::<1>();
    }

    /// Closed-form uniaxial-strain state at log strain e (monotonic loading from rest):
    /// (ε_p, τ_xx, τ_yy = τ_zz, b_e diagonal).
    fn uniaxial_closed_form(m: &J2Plastic, e: f64) -> (f64, f64, f64, [f64; 3]) {
        let k = m.bulk();
        let sign = e.signum();
        let (ep, d) = if 2.0 * m.mu * e.abs() <= m.yield_stress {
            (0.0, 2.0 * m.mu * e)
        } else {
            let ep = (2.0 * m.mu * e.abs() - m.yield_stress) / (3.0 * m.mu + m.hardening);
            (ep, sign * (m.yield_stress + m.hardening * ep))
        };
        // Plastic strain increment direction (3/2) dev τ / q = sign (1, −½, −½).
        let exx = e - sign * ep;
        let eyy = 0.5 * sign * ep;
        let be = [(2.0 * exx).exp(), (2.0 * eyy).exp(), (2.0 * eyy).exp()];
        (ep, k * e + 2.0 * d / 3.0, k * e - d / 3.0, be)
    }

    /// Drive F = diag(λ, 1, 1) from 1 to `end` in `n` equal stretch steps, checking every
    /// state against the closed form; returns the final (σ_xx, ε_p).
    fn uniaxial_path<const D: usize>(m: &J2Plastic, end: f64, n: usize) -> (f64, f64) {
        let mut be = Matrix3::identity();
        let mut ep = 0.0;
        let mut sig = Mat::<D>::zeros();
        let mut lam = 1.0;
        let mut yielded = 0;
        for k in 1..=n {
            let next = 1.0 + (end - 1.0) * k as f64 / n as f64;
            let mut f = Mat::<D>::identity();
            f[(0, 0)] = next / lam;
            lam = next;
            sig = step(m, &mut be, &mut ep, &f);
            let e = lam.ln();
            let (ep_x, txx, tyy, be_x) = uniaxial_closed_form(m, e);
            yielded += (ep_x > 0.0) as usize;
            let tol = 1e-12;
            // ε_p is held to the scale of the strain: near the onset of yield it is
            // the difference of nearly equal terms.
            assert!(
                (ep - ep_x).abs() <= tol * e.abs(),
                "D = {D}, λ = {lam}: ε_p {ep} vs {ep_x}"
            );
            // σ = τ / J, J = det F = λ.
            assert!(close(sig[(0, 0)] * lam, txx, tol), "D = {D}, λ = {lam}");
            if D > 1 {
                assert!(close(sig[(1, 1)] * lam, tyy, tol), "D = {D}, λ = {lam}");
                assert!(sig[(0, 1)].abs() < 1e-13);
            }
            if D > 2 {
                assert!(close(sig[(2, 2)] * lam, tyy, tol), "D = {D}, λ = {lam}");
            }
            for a in 0..3 {
                assert!(close(be[(a, a)], be_x[a], tol), "D = {D}, λ = {lam}: {be}");
            }
            // Yield stress and pressure, as stated for the model.
            if ep_x > 0.0 {
                let q = (txx - tyy) * e.signum();
                assert!(close(q, m.yield_stress + m.hardening * ep, tol));
            }
            let p = -(txx + 2.0 * tyy) / 3.0;
            assert!(close(p, -m.bulk() * e, tol));
        }
        // The paths do go elastic then plastic (when there is more than one step).
        // The path ends plastic; with fine enough steps it starts elastic.
        assert!(yielded > 0);
        if n >= 40 {
            assert!(yielded < n, "D = {D}, n = {n}: no elastic states");
        }
        (sig[(0, 0)], ep)
    }

    /// Uniaxial strain, tension and compression, in 1, 2 and 3 dimensions: the
    /// closed form along the whole path, and the end state independent of the number
    /// of steps (exact return for proportional loading).
    #[test]
    fn uniaxial_strain_tension_and_compression() {
        let m = model();
        for &end in &[1.1, 0.9] {
            let (s1, e1) = uniaxial_path::<1>(&m, end, 1);
            for &n in &[3, 40, 200] {
                let (s, e) = uniaxial_path::<1>(&m, end, n);
                assert!(close(s, s1, 1e-12) && close(e, e1, 1e-12), "{end} {n}");
                let (s, e) = uniaxial_path::<2>(&m, end, n);
                assert!(close(s, s1, 1e-12) && close(e, e1, 1e-12), "{end} {n}");
                let (s, e) = uniaxial_path::<3>(&m, end, n);
                assert!(close(s, s1, 1e-12) && close(e, e1, 1e-12), "{end} {n}");
            }
        }
    }

    /// Small simple shear F = I + γ e_x⊗e_y, elastic: the log strain of simple shear is
    /// ε = asinh(γ/2) / √(1 + γ²/4) [[γ/2, 1], [1, −γ/2]], so τ = 2μ ε exactly, i.e.
    /// τ_xy = μ(γ − γ³/6 + γ⁵/30 − …), an alternating series; J = 1 so σ = τ. Plane
    /// strain equals 3D.
    #[test]
    fn simple_shear_small_elastic() {
        let m = elastic_model();
        let g: f64 = 0.05;
        let c = (0.5 * g).asinh() / (1.0 + 0.25 * g * g).sqrt();
        let mut f = Mat::<2>::identity();
        f[(0, 1)] = g;
        let mut be = Matrix3::identity();
        let mut ep = 0.0;
        let s2 = step(&m, &mut be, &mut ep, &f);
        assert_eq!(ep, 0.0);
        // Components to within rounding of the whole tensor: the normal stresses, O(γ²),
        // come from the cancellation of principal stresses ±2μ asinh(γ/2).
        let x = Mat::<2>::new(g, 2.0, 2.0, -g) * (m.mu * c);
        assert!((s2 - x).norm() < 1e-14 * x.norm(), "{s2} vs {x}");
        let dev = m.mu * g - s2[(0, 1)];
        assert!(
            dev <= m.mu * g.powi(3) / 6.0 && dev >= m.mu * (g.powi(3) / 6.0 - g.powi(5) / 30.0)
        );

        let mut f3 = Mat::<3>::identity();
        f3[(0, 1)] = g;
        let (mut be3, mut ep3) = (Matrix3::identity(), 0.0);
        let s3 = step(&m, &mut be3, &mut ep3, &f3);
        assert!((s3.fixed_view::<2, 2>(0, 0) - s2).norm() < 1e-14);
        assert!(s3[(2, 2)].abs() < 1e-14 && (be3 - be).norm() < 1e-15);
    }

    /// Large shear with some volume change, in many steps (3D): the state ends on the
    /// yield surface, q = σ_y + H ε_p, and det b_e = J² (plastic flow is isochoric).
    /// Then a rigid rotation step f = R leaves q and ε_p unchanged and rotates τ.
    /// The same in plane strain, where the rotation is in-plane.
    #[test]
    fn large_shear_on_yield_surface_isochoric_and_objective() {
        let m = model();
        let mut l = Mat::<3>::zeros();
        l[(0, 1)] = 1.0;
        l[(0, 0)] = 0.05;
        l[(1, 1)] = -0.02;
        l[(2, 2)] = 0.01;
        let dt = 0.02;
        let (mut be, mut ep) = (Matrix3::identity(), 0.0);
        let mut ftot = Matrix3::<f64>::identity();
        let mut sig = Mat::<3>::zeros();
        let mut ep_prev = 0.0;
        for _ in 0..50 {
            ep_prev = ep;
            sig = m.update(&mut be, &mut ep, &l, dt);
            ftot = (Matrix3::identity() + l * dt) * ftot;
        }
        assert!(ep > ep_prev && ep > 0.1, "plastic in the last step: {ep}");
        let j = ftot.determinant();
        assert!(close(be.determinant(), j * j, 1e-12));
        let tau = sig * j;
        let flow = m.yield_stress + m.hardening * ep;
        assert!((mises(&tau) - flow).abs() < 1e-10 * flow);

        let r = *Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0)), 0.7)
            .matrix();
        let ep0 = ep;
        let sig_r = step(&m, &mut be, &mut ep, &r);
        assert!((ep - ep0).abs() < 1e-14 * ep0);
        let tau_r = sig_r * j;
        assert!((mises(&tau_r) - flow).abs() < 1e-10 * flow);
        assert!((tau_r - r * tau * r.transpose()).norm() < 1e-12 * tau.norm());

        // Plane strain: same shear in-plane, then an in-plane rotation.
        let l2 = Mat::<2>::new(0.05, 1.0, 0.0, -0.02);
        let (mut be2, mut ep2) = (Matrix3::identity(), 0.0);
        let mut sig2 = Mat::<2>::zeros();
        for _ in 0..50 {
            sig2 = m.update(&mut be2, &mut ep2, &l2, dt);
        }
        let r2 = Mat::<2>::new(0.6, -0.8, 0.8, 0.6);
        let ep20 = ep2;
        let q0 = mises_of_be(&m, &be2);
        let sig2_r = step(&m, &mut be2, &mut ep2, &r2);
        assert!((ep2 - ep20).abs() < 1e-14 * ep20);
        assert!((mises_of_be(&m, &be2) - q0).abs() < 1e-10 * q0);
        assert!((q0 - (m.yield_stress + m.hardening * ep2)).abs() < 1e-10 * q0);
        assert!((sig2_r - r2 * sig2 * r2.transpose()).norm() < 1e-12 * sig2.norm());
    }

    /// Plane strain σ_zz from b_e: along a plastic uniaxial-strain path in x it is the
    /// closed form τ_yy / λ (= τ_zz by symmetry), and along a large in-plane shear with
    /// volume change it equals the zz stress of the same path run in 3D (L with zero
    /// third row and column), which carries τ_zz itself.
    #[test]
    fn plane_strain_sigma_zz_from_be() {
        let m = model();
        for &end in &[1.1f64, 0.9] {
            let n = 40;
            let (mut be, mut ep) = (Matrix3::identity(), 0.0);
            let mut lam = 1.0;
            for k in 1..=n {
                let next = 1.0 + (end - 1.0) * k as f64 / n as f64;
                let mut f = Mat::<2>::identity();
                f[(0, 0)] = next / lam;
                lam = next;
                step(&m, &mut be, &mut ep, &f);
                let (ep_x, _, tyy, _) = uniaxial_closed_form(&m, lam.ln());
                assert!(close(m.stress_zz(&be) * lam, tyy, 1e-12), "λ = {lam}");
                if k == n {
                    assert!(ep_x > 0.0 && ep > 0.0, "the path ends plastic");
                }
            }
        }
        let l2 = Mat::<2>::new(0.05, 1.0, 0.3, -0.02);
        let mut l3 = Mat::<3>::zeros();
        l3.fixed_view_mut::<2, 2>(0, 0).copy_from(&l2);
        let (mut be2, mut ep2) = (Matrix3::identity(), 0.0);
        let (mut be3, mut ep3) = (Matrix3::identity(), 0.0);
        let mut s3 = Mat::<3>::zeros();
        for _ in 0..50 {
            m.update(&mut be2, &mut ep2, &l2, 0.02);
            s3 = m.update(&mut be3, &mut ep3, &l3, 0.02);
        }
        assert!(ep2 > 0.1);
        assert!((m.stress_zz(&be2) - s3[(2, 2)]).abs() < 1e-12 * s3.norm());
    }

    /// Elastic uniaxial strain: W = ½ (K + 4μ/3) e² with the log strain e = ln λ.
    #[test]
    fn energy_density_uniaxial_elastic() {
        let m = elastic_model();
        let lam: f64 = 1.2;
        let mut f = Mat::<1>::identity();
        f[(0, 0)] = lam;
        let (mut be, mut ep) = (Matrix3::identity(), 0.0);
        step(&m, &mut be, &mut ep, &f);
        assert_eq!(ep, 0.0);
        let e = lam.ln();
        let w = 0.5 * (m.bulk() + 4.0 * m.mu / 3.0) * e * e;
        assert!((m.energy_density(&be) - w).abs() < 1e-13 * w);
    }

    /// Energy balance along a plastic uniaxial-strain path: stored + plastic work equals
    /// the external work ∫ τ_xx de, in closed form: ½(K + 4μ/3) e_y² up to the yield
    /// strain e_y = σ_y/2μ, then τ_xx = K e + ⅔ (σ_y + H ε_p(e)) with ε_p linear in e.
    #[test]
    fn energy_balance_uniaxial_plastic() {
        let m = model();
        let (k, mu, sy, h) = (m.bulk(), m.mu, m.yield_stress, m.hardening);
        for &end in &[1.05f64, 0.95] {
            let mut f = Mat::<1>::identity();
            let n = 30;
            f[(0, 0)] = end.powf(1.0 / n as f64);
            let (mut be, mut ep) = (Matrix3::identity(), 0.0);
            for _ in 0..n {
                step(&m, &mut be, &mut ep, &f);
            }
            let e = end.ln().abs();
            let ey = sy / (2.0 * mu);
            let w_ext = 0.5 * (k + 4.0 * mu / 3.0) * ey * ey
                + 0.5 * k * (e * e - ey * ey)
                + 2.0 / 3.0
                    * (3.0 * mu * sy / (3.0 * mu + h) * (e - ey)
                        + h * mu / (3.0 * mu + h) * (e * e - ey * ey));
            let w = m.energy_density(&be) + m.plastic_work_density(ep);
            assert!(close(ep, (2.0 * mu * e - sy) / (3.0 * mu + h), 1e-12));
            assert!((w - w_ext).abs() < 1e-12 * w_ext, "{end}: {w} vs {w_ext}");
            assert!(close(
                m.plastic_work_density(ep),
                sy * ep + 0.5 * h * ep * ep,
                1e-15
            ));
        }
    }

    /// Wave speed: √((λ+2μ)/ρ) at rest and in tension, × √(1 − ln j) in compression.
    #[test]
    fn wave_speed_hencky_uniaxial() {
        let m = model();
        let c0 = ((m.lambda + 2.0 * m.mu) / m.density).sqrt();
        assert!(close(m.wave_speed(1.0), c0, 1e-15));
        assert!(close(m.wave_speed(1.3), c0, 1e-15));
        let j: f64 = 0.7;
        assert!(close(m.wave_speed(j), c0 * (1.0 - j.ln()).sqrt(), 1e-15));
    }
}
