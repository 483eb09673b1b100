//! Constitutive models. Each model is one module; this enum dispatches between them.
//! In 2D the models are plane strain and in 1D uniaxial strain, so a bar's 1D
//! modulus is `λ + 2μ` (= E when ν = 0).

pub mod brittle;
pub mod j2_plastic;
pub mod linear_elastic;
pub mod neo_hookean;

use crate::input::plan::{Law, MaterialPlan};
use crate::physics::tensor::Mat;
use nalgebra::Matrix3;

#[derive(Clone, Debug, PartialEq)]
pub enum Material {
    LinearElastic(linear_elastic::LinearElastic),
    NeoHookean(neo_hookean::NeoHookean),
    J2Plastic(j2_plastic::J2Plastic),
    Brittle(brittle::Brittle),
}

/// A particle's internal variables, for the models that have them (empty slices of
/// the particle arrays give `None`).
pub struct Internal<'a> {
    /// Elastic left Cauchy–Green tensor and equivalent plastic strain (`j2_plastic`).
    pub plastic: Option<(&'a mut Matrix3<f64>, &'a mut f64)>,
    /// Damage (`brittle`).
    pub damage: Option<&'a mut f64>,
    /// Plane-strain out-of-plane stress σ_zz (`brittle` in 2D).
    pub stress_zz: Option<&'a mut f64>,
}

/// A model whose Cauchy stress follows from the deformation gradient alone: its
/// particles carry `F`, store no stress, and the stress is formed where it is used.
/// Every method is required, so a model that misses one does not compile; each model
/// passes the closed-form checks of `tests::check_hyperelastic`.
pub trait Hyperelastic {
    /// The Kirchhoff stress `τ = J σ` and `J = det F`: a particle's volume times its
    /// Cauchy stress is `V₀ τ`, without the division by `J`.
    fn kirchhoff<const D: usize>(&self, f: &Mat<D>) -> (Mat<D>, f64);
    /// The Cauchy stress `σ`.
    fn stress<const D: usize>(&self, f: &Mat<D>) -> Mat<D>;
    /// Plane strain (D = 2): the out-of-plane stress σ_zz, with `F₃₃ = 1`.
    fn stress_zz<const D: usize>(&self, f: &Mat<D>) -> f64;
    /// Stored energy per reference volume, `W(F)`.
    fn energy_density<const D: usize>(&self, f: &Mat<D>) -> f64;
}

/// How a particle's volume changed: over the step (`step = det(I + L Δt)`) and since
/// its reference state (`total = V / V₀ = J`), for the rate forms of the Kirchhoff
/// stress ([`linear_elastic`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeChange {
    pub step: f64,
    pub total: f64,
}

impl VolumeChange {
    /// No change: the reference state, or a step that keeps the volume.
    pub const NONE: Self = VolumeChange {
        step: 1.0,
        total: 1.0,
    };
}

/// Where a model's stress comes from; [`Material::stress_source`] decides it in one
/// exhaustive match, so a new model must say which it is.
pub enum StressSource<'a> {
    /// Formed from `F` where it is used: particles carry `F` and no stress.
    DefGrad(Hyper<'a>),
    /// State of its own (rate or history forms), which particles store.
    State,
}

/// The hyperelastic models, borrowed: [`Hyperelastic`]'s methods dispatched by an
/// exhaustive match.
#[derive(Clone, Copy)]
pub enum Hyper<'a> {
    NeoHookean(&'a neo_hookean::NeoHookean),
}

impl Hyper<'_> {
    #[inline(always)]
    pub fn kirchhoff<const D: usize>(self, f: &Mat<D>) -> (Mat<D>, f64) {
        match self {
            Hyper::NeoHookean(m) => m.kirchhoff(f),
        }
    }

    #[inline(always)]
    pub fn stress<const D: usize>(self, f: &Mat<D>) -> Mat<D> {
        match self {
            Hyper::NeoHookean(m) => m.stress(f),
        }
    }

    #[inline(always)]
    pub fn stress_zz<const D: usize>(self, f: &Mat<D>) -> f64 {
        match self {
            Hyper::NeoHookean(m) => m.stress_zz(f),
        }
    }

    #[inline(always)]
    pub fn energy_density<const D: usize>(self, f: &Mat<D>) -> f64 {
        match self {
            Hyper::NeoHookean(m) => m.energy_density(f),
        }
    }
}

/// Lamé parameters from Young's modulus and Poisson's ratio.
pub fn lame(e: f64, nu: f64) -> (f64, f64) {
    let lambda = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    let mu = e / (2.0 * (1.0 + nu));
    (lambda, mu)
}

impl Material {
    /// The models of a scene's validated materials, in order (particles name them by
    /// index).
    pub fn all(plans: &[MaterialPlan]) -> Vec<Self> {
        plans.iter().map(Self::from_plan).collect()
    }

    /// The model of a validated material.
    pub fn from_plan(p: &MaterialPlan) -> Self {
        let (lambda, mu) = lame(p.youngs_modulus, p.poisson_ratio);
        let density = p.density;
        match p.law {
            Law::LinearElastic { small } => {
                Material::LinearElastic(linear_elastic::LinearElastic {
                    lambda,
                    mu,
                    density,
                    small,
                })
            }
            Law::NeoHookean => Material::NeoHookean(neo_hookean::NeoHookean {
                lambda,
                mu,
                density,
            }),
            Law::J2Plastic {
                yield_stress,
                hardening,
            } => Material::J2Plastic(j2_plastic::J2Plastic {
                lambda,
                mu,
                density,
                yield_stress,
                hardening,
            }),
            Law::Brittle { tensile_strength } => Material::Brittle(brittle::Brittle {
                lambda,
                mu,
                density,
                tensile_strength,
            }),
        }
    }

    pub fn density(&self) -> f64 {
        match self {
            Material::LinearElastic(m) => m.density,
            Material::NeoHookean(m) => m.density,
            Material::J2Plastic(m) => m.density,
            Material::Brittle(m) => m.density,
        }
    }

    /// Where the stress comes from: the one place that says which models are
    /// hyperelastic ([`Material::needs_def_grad`], [`Material::stress_is_state`] and
    /// the stress from `F` all follow from it).
    #[inline(always)]
    pub fn stress_source(&self) -> StressSource<'_> {
        match self {
            Material::NeoHookean(m) => StressSource::DefGrad(Hyper::NeoHookean(m)),
            Material::LinearElastic(_) | Material::J2Plastic(_) | Material::Brittle(_) => {
                StressSource::State
            }
        }
    }

    /// Whether particles of this material must carry their deformation gradient.
    pub fn needs_def_grad(&self) -> bool {
        matches!(self.stress_source(), StressSource::DefGrad(_))
    }

    /// Whether the Cauchy stress is state of its own (rate or history forms), which
    /// particles must then store; else it follows from the deformation gradient
    /// ([`Material::stress_of_def_grad`]) and is formed where it is used.
    pub fn stress_is_state(&self) -> bool {
        matches!(self.stress_source(), StressSource::State)
    }

    /// The hyperelastic model, for a material whose stress is not state. Callers ask
    /// only for materials whose particles carry `F` (no stored stress).
    #[inline(always)]
    fn hyper(&self) -> Hyper<'_> {
        match self.stress_source() {
            StressSource::DefGrad(h) => h,
            StressSource::State => panic!("the particles of stateful-stress materials store σ"),
        }
    }

    /// The Cauchy stress of a material whose stress is not state, from `f`: the same
    /// function, hence the same numbers, as the one [`Material::update_stress`] applies.
    #[inline]
    pub fn stress_of_def_grad<const D: usize>(&self, f: &Mat<D>) -> Mat<D> {
        self.hyper().stress(f)
    }

    /// The Kirchhoff stress `J σ` and `J` of a material whose stress is not state, from
    /// `f` (see [`Material::stress_of_def_grad`]).
    #[inline]
    pub fn kirchhoff_of_def_grad<const D: usize>(&self, f: &Mat<D>) -> (Mat<D>, f64) {
        self.hyper().kirchhoff(f)
    }

    /// New Cauchy stress after a step with velocity gradient `l`, given the updated
    /// deformation gradient `f` (meaningful only if [`Material::needs_def_grad`]), the
    /// volume change `j` (used by the rate forms) and the particle's internal
    /// variables (present if the model has them).
    #[inline]
    pub fn update_stress<const D: usize>(
        &self,
        stress: &mut Mat<D>,
        l: &Mat<D>,
        f: &Mat<D>,
        dt: f64,
        j: VolumeChange,
        internal: Internal<'_>,
    ) {
        match self {
            Material::LinearElastic(m) => m.update_stress(stress, l, dt, j),
            Material::NeoHookean(m) => *stress = Hyperelastic::stress(m, f),
            Material::J2Plastic(m) => {
                let (be, eps_p) = internal.plastic.expect("j2_plastic particles carry be");
                *stress = m.update(be, eps_p, l, dt);
            }
            Material::Brittle(m) => {
                let d = internal.damage.expect("brittle particles carry damage");
                m.update_stress(stress, d, internal.stress_zz, l, dt, j);
            }
        }
    }

    /// Plane strain (D = 2): the out-of-plane normal stress σ_zz, which the D×D stress
    /// lacks. Derived where the state determines it (linear elastic from the in-plane
    /// stress, neo-Hookean from `F`, J2 from `b_e`); `stored` is the particle's own
    /// value for the models whose σ_zz depends on history (`brittle`).
    pub fn stress_zz<const D: usize>(
        &self,
        stress: &Mat<D>,
        f: &Mat<D>,
        be: Option<&Matrix3<f64>>,
        stored: Option<f64>,
    ) -> f64 {
        match self {
            Material::LinearElastic(m) => m.stress_zz(stress),
            Material::NeoHookean(m) => m.stress_zz(f),
            Material::J2Plastic(m) => m.stress_zz(be.expect("j2_plastic carries be")),
            Material::Brittle(_) => stored.expect("2D brittle particles carry σ_zz"),
        }
    }

    /// Longitudinal wave speed at volume ratio `j` (for the time step).
    #[inline]
    pub fn wave_speed(&self, j: f64) -> f64 {
        match self {
            Material::LinearElastic(m) => ((m.lambda + 2.0 * m.mu) / m.density * j).sqrt(),
            Material::NeoHookean(m) => m.wave_speed(j),
            Material::J2Plastic(m) => m.wave_speed(j),
            Material::Brittle(m) => ((m.lambda + 2.0 * m.mu) / m.density * j).sqrt(),
        }
    }

    /// `wave_speed(j)` for every J >= 1, as it rounds, where the model's speed is the
    /// small-strain one there (neo-Hookean and J2: `((λ + 2μ) / ρ).sqrt()`, J2's
    /// `max(1 − ln J, 1)` being 1): formed without a logarithm.
    #[inline(always)]
    pub fn stretched_wave_speed(&self) -> Option<f64> {
        match self {
            Material::NeoHookean(m) if m.lambda >= 0.0 => {
                Some(((m.lambda + 2.0 * m.mu) / m.density).sqrt())
            }
            Material::J2Plastic(m) => Some(((m.lambda + 2.0 * m.mu) / m.density).sqrt()),
            Material::NeoHookean(_) | Material::LinearElastic(_) | Material::Brittle(_) => None,
        }
    }

    /// Whether `wave_speed(j) + v <= limit` holds for certain, decided without a
    /// logarithm; false when unsure, and for the models whose speed needs none.
    ///
    /// The step's fastest signal is a running maximum over the particles, and a
    /// particle that cannot raise it need not have its speed formed
    /// ([`Material::raise_signal_speed`]). In the neo-Hookean and J2 models the
    /// logarithm is that speed's cost under compression.
    ///
    /// Both speeds are `sqrt(m / ρ)` with `m` growing with `−ln J`, which is at most
    /// `x + x²` for `x = 1 − J ∈ [0, ½]` (its series `x + x²/2 + x³/3 + ...` has the
    /// terms after `x²/2` below `x²/3` there) and 0 for J ≥ 1. With that bound in
    /// place of `−ln J`, `m ≤ ρ (limit − v)²` is checked with a relative margin of
    /// 1e-12, far above the round-off of the speed's few operations, so that a `true`
    /// also holds for the speed as `wave_speed` rounds it.
    #[inline]
    pub fn signal_speed_at_most(&self, j: f64, v: f64, limit: f64) -> bool {
        // (NaN fails it.)
        if j.is_nan() || j < 0.5 {
            return false;
        }
        let x = (1.0 - j).max(0.0);
        let bound = x + x * x;
        let (m, density) = match self {
            Material::NeoHookean(m) if m.lambda >= 0.0 => {
                (m.lambda + 2.0 * (m.mu + m.lambda * bound), m.density)
            }
            Material::J2Plastic(m) if m.lambda + 2.0 * m.mu > 0.0 => {
                ((m.lambda + 2.0 * m.mu) * (1.0 + bound), m.density)
            }
            Material::NeoHookean(_)
            | Material::J2Plastic(_)
            | Material::LinearElastic(_)
            | Material::Brittle(_) => return false,
        };
        let room = limit - v - 1e-12 * limit;
        room > 0.0 && m * (1.0 + 1e-12) <= density * room * room
    }

    /// The running maximum `max` of the signal speed the time step must resolve,
    /// `wave_speed(j) + v`, raised by a particle's at volume ratio `j` and speed `v`
    /// where that is larger: the same maximum, bit for bit, with the logarithm formed
    /// only where the particle may raise it.
    ///
    /// For J ≥ 1 the neo-Hookean and J2 speeds are the small-strain one, formed
    /// without a logarithm; for J < 1 [`Material::signal_speed_at_most`] tells which
    /// particles cannot raise the maximum. Both are formed for every particle and
    /// chosen between without a branch: only the rare particle that may raise the
    /// maximum under compression branches. Where J hovers around 1 (the vortex), a
    /// branch on its side mispredicts half the time, and the skip test alone fails for
    /// J ≥ 1 whenever every particle's speed is the maximum (a falling block).
    #[inline(always)]
    pub fn raise_signal_speed(&self, j: f64, v: f64, max: f64) -> f64 {
        let Some(small) = self.stretched_wave_speed() else {
            return max.max(self.wave_speed(j) + v);
        };
        let at_least_one = j >= 1.0;
        let skip = self.signal_speed_at_most(j, v, max);
        if !at_least_one && !skip {
            return max.max(self.wave_speed(j) + v);
        }
        let quick = small + v;
        if at_least_one {
            max.max(quick)
        } else {
            max
        }
    }

    /// Stored energy of a particle with current volume `vol()` and reference volume
    /// `vol0`; `be` is its elastic left Cauchy–Green tensor where it carries one.
    /// The current volume is asked for only by the materials whose stress is a rate
    /// form ([`kirchhoff_energy`]).
    // Inline: a call per particle in the history's totals, with `vol` formed for every
    // material, was a quarter of their time.
    #[inline]
    pub fn strain_energy<const D: usize>(
        &self,
        stress: &Mat<D>,
        f: &Mat<D>,
        be: Option<&Matrix3<f64>>,
        vol: impl FnOnce() -> f64,
        vol0: f64,
    ) -> f64 {
        match self {
            Material::LinearElastic(m) if m.small => vol() * m.energy_density(stress),
            Material::LinearElastic(m) => kirchhoff_energy(vol(), vol0, m.energy_density(stress)),
            Material::NeoHookean(m) => vol0 * m.energy_density(f),
            Material::J2Plastic(m) => vol0 * m.energy_density(be.expect("j2_plastic carries be")),
            Material::Brittle(m) => kirchhoff_energy(vol(), vol0, m.energy_density(stress)),
        }
    }

    /// Work dissipated by plastic flow in a particle of reference volume `vol0` with
    /// equivalent plastic strain `eps_p`.
    pub fn plastic_work(&self, eps_p: f64, vol0: f64) -> f64 {
        match self {
            Material::J2Plastic(m) => vol0 * m.plastic_work_density(eps_p),
            Material::LinearElastic(_) | Material::NeoHookean(_) | Material::Brittle(_) => 0.0,
        }
    }
}

/// `V₀ w(J σ) = V J w(σ)` for an energy density `w` quadratic in the stress, given
/// `w(σ)`: the stored energy of the Kirchhoff-stress rate forms.
#[inline]
fn kirchhoff_energy(vol: f64, vol0: f64, w_of_sigma: f64) -> f64 {
    vol * vol / vol0 * w_of_sigma
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::tensor::det;
    use decomposition::splitmix::Rng;

    /// A deformation gradient near the identity with `det F > 0`.
    fn some_f<const D: usize>(rng: &mut Rng, size: f64) -> Mat<D> {
        Mat::<D>::from_fn(|i, k| f64::from(u8::from(i == k)) + size * (rng.f64() - 0.5))
    }

    /// The closed-form properties every [`Hyperelastic`] model has, in 1D, 2D and 3D:
    /// no stress or energy at rest; `τ = J σ`; the Kirchhoff stress is the energy's
    /// derivative, `τ = (∂W/∂F) Fᵀ` (central differences); objectivity,
    /// `σ(R F) = R σ(F) Rᵀ`, and `W(R F) = W(F)` for a rotation `R`; in plane strain
    /// σ_zz is the 3D model's at `F₃₃ = 1`.
    pub(crate) fn check_hyperelastic<M: Hyperelastic>(m: &M, scale: f64) {
        fn each<const D: usize, M: Hyperelastic>(m: &M, scale: f64, rng: &mut Rng) {
            let id = Mat::<D>::identity();
            assert!(
                m.stress(&id).norm() <= 1e-14 * scale,
                "σ(I) = {}",
                m.stress(&id)
            );
            assert!(m.energy_density(&id).abs() <= 1e-14 * scale);
            assert!(m.stress_zz(&id).abs() <= 1e-14 * scale);
            for _ in 0..20 {
                let f = some_f::<D>(rng, 0.4);
                let (tau, j) = m.kirchhoff(&f);
                let sigma = m.stress(&f);
                assert!((j - det(&f)).abs() <= 1e-15);
                assert!((tau - sigma * j).norm() <= 1e-13 * scale, "τ ≠ J σ");
                let h = 1e-6;
                let dw = Mat::<D>::from_fn(|a, b| {
                    let (mut up, mut down) = (f, f);
                    up[(a, b)] += h;
                    down[(a, b)] -= h;
                    (m.energy_density(&up) - m.energy_density(&down)) / (2.0 * h)
                });
                let tau_w = dw * f.transpose();
                assert!(
                    (tau_w - tau).norm() <= 1e-7 * scale,
                    "τ = {tau}, (∂W/∂F) Fᵀ = {tau_w}"
                );
                if D >= 2 {
                    let (c, s) = (0.6_f64, 0.8_f64);
                    let mut r = Mat::<D>::identity();
                    r[(0, 0)] = c;
                    r[(0, 1)] = -s;
                    r[(1, 0)] = s;
                    r[(1, 1)] = c;
                    let turned = m.stress(&(r * f));
                    assert!((turned - r * sigma * r.transpose()).norm() <= 1e-13 * scale);
                    let w = m.energy_density(&f);
                    assert!((m.energy_density(&(r * f)) - w).abs() <= 1e-13 * scale);
                }
                if D == 2 {
                    let f3 = Mat::<3>::from_fn(|a, b| match (a, b) {
                        (2, 2) => 1.0,
                        (2, _) | (_, 2) => 0.0,
                        _ => f[(a, b)],
                    });
                    let zz = m.stress_zz(&f);
                    assert!((zz - m.stress(&f3)[(2, 2)]).abs() <= 1e-13 * scale);
                }
            }
        }
        let mut rng = Rng::new(17);
        each::<1, M>(m, scale, &mut rng);
        each::<2, M>(m, scale, &mut rng);
        each::<3, M>(m, scale, &mut rng);
    }

    /// A toy model added as docs/architecture.md's recipe says (step 1, the model and
    /// its closed-form checks): the compressible Saint Venant–Kirchhoff solid,
    /// `W = λ/2 (tr E)² + μ E:E` with `E = (FᵀF − I)/2`, `τ = F S Fᵀ`,
    /// `S = λ tr E I + 2μ E`. Implementing [`Hyperelastic`] requires every method
    /// the solver uses; forgetting one is a compile error.
    struct SaintVenantKirchhoff {
        lambda: f64,
        mu: f64,
    }

    impl Hyperelastic for SaintVenantKirchhoff {
        fn kirchhoff<const D: usize>(&self, f: &Mat<D>) -> (Mat<D>, f64) {
            let e = (f.transpose() * f - Mat::<D>::identity()) * 0.5;
            let s = Mat::<D>::identity() * (self.lambda * e.trace()) + e * (2.0 * self.mu);
            (f * s * f.transpose(), det(f))
        }
        fn stress<const D: usize>(&self, f: &Mat<D>) -> Mat<D> {
            let (tau, j) = self.kirchhoff(f);
            tau / j
        }
        fn stress_zz<const D: usize>(&self, f: &Mat<D>) -> f64 {
            let e = (f.transpose() * f - Mat::<D>::identity()) * 0.5;
            self.lambda * e.trace() / det(f)
        }
        fn energy_density<const D: usize>(&self, f: &Mat<D>) -> f64 {
            let e = (f.transpose() * f - Mat::<D>::identity()) * 0.5;
            0.5 * self.lambda * e.trace().powi(2) + self.mu * e.component_mul(&e).sum()
        }
    }

    #[test]
    fn a_toy_hyperelastic_model_passes_the_recipes_checks() {
        check_hyperelastic(
            &SaintVenantKirchhoff {
                lambda: 2.0,
                mu: 1.5,
            },
            2.0,
        );
    }

    #[test]
    fn neo_hookean_passes_the_hyperelastic_checks() {
        let (lambda, mu) = lame(1e3, 0.3);
        check_hyperelastic(
            &neo_hookean::NeoHookean {
                lambda,
                mu,
                density: 1.0,
            },
            1e3,
        );
    }

    /// `needs_def_grad` and `stress_is_state` follow from `stress_source` for every
    /// law a scene can name, exactly one of the two holds, and a hyperelastic
    /// material's stress from `F` is its model's.
    #[test]
    fn every_law_says_where_its_stress_comes_from() {
        use crate::input::plan::Law;
        let laws = [
            Law::LinearElastic { small: false },
            Law::LinearElastic { small: true },
            Law::NeoHookean,
            Law::J2Plastic {
                yield_stress: 1.0,
                hardening: 0.0,
            },
            Law::Brittle {
                tensile_strength: 1.0,
            },
        ];
        let f = Mat::<2>::new(1.1, 0.2, -0.1, 0.9);
        for law in laws {
            let plan = MaterialPlan {
                law,
                youngs_modulus: 1e3,
                poisson_ratio: 0.3,
                density: 1.0,
            };
            let m = Material::from_plan(&plan);
            assert_ne!(m.needs_def_grad(), m.stress_is_state(), "{law:?}");
            match m.stress_source() {
                StressSource::DefGrad(h) => {
                    assert!(m.needs_def_grad());
                    assert_eq!(m.stress_of_def_grad(&f), h.stress(&f));
                    assert_eq!(m.kirchhoff_of_def_grad(&f), h.kirchhoff(&f));
                }
                StressSource::State => assert!(m.stress_is_state()),
            }
        }
    }

    /// `signal_speed_at_most` never says yes wrongly: over J from 0.3 to 1.6 (both
    /// sides of ½ and of 1, and within 1e-7 of 1, as in the vortex), particle speeds
    /// and limits around the formed speed, a `true` means that the formed
    /// `wave_speed(j) + v` is at most the limit. And it is tight enough to skip: for J
    /// within 1e-6 of 1 (the bound's excess is `x²/2`), with the limit 1e-9 above the
    /// formed speed, the
    /// neo-Hookean (ν ≥ 0) and J2 models say yes; the models whose speed needs no
    /// logarithm, and the neo-Hookean with ν < 0, always no. `raise_signal_speed`,
    /// which uses it, gives `max(limit, wave_speed(j) + v)` bit for bit, also for J
    /// infinite or NaN (NaN is passed over, as `f64::max` does).
    #[test]
    fn signal_speed_bound_is_safe_and_tight() {
        let (lambda, mu) = lame(1e3, 0.3);
        let (neg_lambda, neg_mu) = lame(1e3, -0.2);
        let neo = Material::NeoHookean(neo_hookean::NeoHookean {
            lambda,
            mu,
            density: 1.0,
        });
        let j2 = Material::J2Plastic(j2_plastic::J2Plastic {
            lambda,
            mu,
            density: 7.8,
            yield_stress: 0.5,
            hardening: 10.0,
        });
        let linear = Material::LinearElastic(linear_elastic::LinearElastic {
            lambda,
            mu,
            density: 1.0,
            small: false,
        });
        let auxetic = Material::NeoHookean(neo_hookean::NeoHookean {
            lambda: neg_lambda,
            mu: neg_mu,
            density: 1.0,
        });
        let mut js: Vec<f64> = (0..=130).map(|k| 0.3 + 0.01 * k as f64).collect();
        js.extend((-20..=20).map(|k| 1.0 + 5e-9 * k as f64));
        js.extend([
            0.5,
            0.5 - 1e-16,
            1.0 - 1e-6,
            1.0 + 1e-6,
            1e300,
            f64::INFINITY,
            f64::NAN,
        ]);
        let mut yes = 0;
        for (name, m) in [
            ("neo-Hookean", &neo),
            ("J2", &j2),
            ("linear", &linear),
            ("auxetic", &auxetic),
        ] {
            let can_skip = matches!(name, "neo-Hookean" | "J2");
            for &j in &js {
                for v in [0.0, 0.3, 17.0] {
                    let formed = m.wave_speed(j) + v;
                    for rel in [-1e-3, -1e-12, -1e-15, 0.0, 1e-15, 1e-12, 1e-9, 1e-3] {
                        let limit = formed * (1.0 + rel);
                        let at_most = m.signal_speed_at_most(j, v, limit);
                        let raised = m.raise_signal_speed(j, v, limit);
                        assert_eq!(
                            raised.to_bits(),
                            limit.max(formed).to_bits(),
                            "{name}: J = {j}, v = {v}: raised to {raised}, not max({limit}, {formed})"
                        );
                        assert!(
                            !at_most || formed <= limit,
                            "{name}: J = {j}, v = {v}: yes, but {formed} > {limit}"
                        );
                        yes += usize::from(at_most);
                        let near_one = (j - 1.0).abs() <= 1e-6;
                        if rel >= 1e-9 && near_one {
                            assert_eq!(at_most, can_skip, "{name}: J = {j}, v = {v}, {rel}");
                        }
                        if !can_skip {
                            assert!(!at_most, "{name}: J = {j}");
                        }
                    }
                }
            }
        }
        assert!(yes > 100, "only {yes} skips");
    }
}
