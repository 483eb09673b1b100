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
            Law::LinearElastic => Material::LinearElastic(linear_elastic::LinearElastic {
                lambda,
                mu,
                density,
            }),
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

    /// Whether particles of this material must carry their deformation gradient.
    pub fn needs_def_grad(&self) -> bool {
        matches!(self, Material::NeoHookean(_))
    }

    /// Whether the Cauchy stress is state of its own (rate or history forms), which
    /// particles must then store; else it follows from the deformation gradient
    /// ([`Material::stress_of_def_grad`]) and is formed where it is used.
    pub fn stress_is_state(&self) -> bool {
        !matches!(self, Material::NeoHookean(_))
    }

    /// The Cauchy stress of a material whose stress is not state, from `f`: the same
    /// function, hence the same numbers, as the one [`Material::update_stress`] applies.
    #[inline]
    pub fn stress_of_def_grad<const D: usize>(&self, f: &Mat<D>) -> Mat<D> {
        match self {
            Material::NeoHookean(m) => m.stress(f),
            _ => unreachable!("the particles of stateful-stress materials store σ"),
        }
    }

    /// New Cauchy stress after a step with velocity gradient `l`, given the updated
    /// deformation gradient `f` (meaningful only if [`Material::needs_def_grad`]) and
    /// the particle's internal variables (present if the model has them).
    #[inline]
    pub fn update_stress<const D: usize>(
        &self,
        stress: &mut Mat<D>,
        l: &Mat<D>,
        f: &Mat<D>,
        dt: f64,
        internal: Internal<'_>,
    ) {
        match self {
            Material::LinearElastic(m) => m.update_stress(stress, l, dt),
            Material::NeoHookean(m) => *stress = m.stress(f),
            Material::J2Plastic(m) => {
                let (be, eps_p) = internal.plastic.expect("j2_plastic particles carry be");
                *stress = m.update(be, eps_p, l, dt);
            }
            Material::Brittle(m) => {
                let d = internal.damage.expect("brittle particles carry damage");
                m.update_stress(stress, d, internal.stress_zz, l, dt);
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

    /// Stored energy of a particle with current volume `vol` and reference volume
    /// `vol0`; `be` is its elastic left Cauchy–Green tensor where it carries one.
    pub fn strain_energy<const D: usize>(
        &self,
        stress: &Mat<D>,
        f: &Mat<D>,
        be: Option<&Matrix3<f64>>,
        vol: f64,
        vol0: f64,
    ) -> f64 {
        match self {
            Material::LinearElastic(m) => vol * m.energy_density(stress),
            Material::NeoHookean(m) => vol0 * m.energy_density(f),
            Material::J2Plastic(m) => vol0 * m.energy_density(be.expect("j2_plastic carries be")),
            Material::Brittle(m) => vol * m.energy_density(stress),
        }
    }

    /// Work dissipated by plastic flow in a particle of reference volume `vol0` with
    /// equivalent plastic strain `eps_p`.
    pub fn plastic_work(&self, eps_p: f64, vol0: f64) -> f64 {
        match self {
            Material::J2Plastic(m) => vol0 * m.plastic_work_density(eps_p),
            _ => 0.0,
        }
    }
}
