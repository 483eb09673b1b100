//! Constitutive models. Each model is one module; this enum dispatches between them.
//! In 2D the models are plane strain and in 1D uniaxial strain, so a bar's 1D
//! modulus is `λ + 2μ` (= E when ν = 0).

pub mod brittle;
pub mod j2_plastic;
pub mod linear_elastic;
pub mod neo_hookean;

use crate::scene::{MaterialSpec, Model};
use crate::tensor::Mat;

#[derive(Clone, Debug, PartialEq)]
pub enum Material {
    LinearElastic(linear_elastic::LinearElastic),
    NeoHookean(neo_hookean::NeoHookean),
}

/// Lamé parameters from Young's modulus and Poisson's ratio.
pub fn lame(e: f64, nu: f64) -> (f64, f64) {
    let lambda = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    let mu = e / (2.0 * (1.0 + nu));
    (lambda, mu)
}

impl Material {
    pub fn from_spec(s: &MaterialSpec) -> Self {
        let (lambda, mu) = lame(s.youngs_modulus, s.poisson_ratio);
        match s.model {
            Model::LinearElastic => Material::LinearElastic(linear_elastic::LinearElastic {
                lambda,
                mu,
                density: s.density,
            }),
            Model::NeoHookean => Material::NeoHookean(neo_hookean::NeoHookean {
                lambda,
                mu,
                density: s.density,
            }),
        }
    }

    pub fn density(&self) -> f64 {
        match self {
            Material::LinearElastic(m) => m.density,
            Material::NeoHookean(m) => m.density,
        }
    }

    /// Whether particles of this material must carry their deformation gradient.
    pub fn needs_def_grad(&self) -> bool {
        matches!(self, Material::NeoHookean(_))
    }

    /// New Cauchy stress after a step with velocity gradient `l`, given the updated
    /// deformation gradient `f` (meaningful only if [`Material::needs_def_grad`]).
    #[inline]
    pub fn update_stress<const D: usize>(
        &self,
        stress: &mut Mat<D>,
        l: &Mat<D>,
        f: &Mat<D>,
        dt: f64,
    ) {
        match self {
            Material::LinearElastic(m) => m.update_stress(stress, l, dt),
            Material::NeoHookean(m) => *stress = m.stress(f),
        }
    }

    /// Longitudinal wave speed at volume ratio `j` (for the time step).
    #[inline]
    pub fn wave_speed(&self, j: f64) -> f64 {
        match self {
            Material::LinearElastic(m) => ((m.lambda + 2.0 * m.mu) / m.density * j).sqrt(),
            Material::NeoHookean(m) => m.wave_speed(j),
        }
    }

    /// Stored energy of a particle with current volume `vol` and reference volume `vol0`.
    pub fn strain_energy<const D: usize>(
        &self,
        stress: &Mat<D>,
        f: &Mat<D>,
        vol: f64,
        vol0: f64,
    ) -> f64 {
        match self {
            Material::LinearElastic(m) => vol * m.energy_density(stress),
            Material::NeoHookean(m) => vol0 * m.energy_density(f),
        }
    }
}
