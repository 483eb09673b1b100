//! Kinds of particle (a material and a reference volume each): the per-kind tables,
//! a particle's mass and volume from them, and the stress of its kind's material.

use super::Particles;
use crate::input::plan::{cut_levels, KindPlan};
use crate::input::scene::Scene;
use crate::physics::material::Material;
use crate::physics::shape::Geom;
use crate::physics::tensor::{det, Mat};

/// The Cauchy stress of particle `p` from its arrays: `stress` if the particles store
/// it (not empty), else formed from `F` (the particles' materials then all have a
/// stress that is not state, [`Carries::stress`](super::Carries::stress)). `materials`: per kind.
#[inline(always)]
pub fn stress_of<const D: usize>(
    stress: &[Mat<D>],
    def_grad: &[Mat<D>],
    kind: &[u16],
    materials: &[Material],
    p: usize,
) -> Mat<D> {
    if stress.is_empty() {
        let m = &materials[kind[p] as usize];
        if D == 3 {
            stress_call(m, &def_grad[p])
        } else {
            m.stress_of_def_grad(&def_grad[p])
        }
    } else {
        stress[p]
    }
}

/// [`Material::stress_of_def_grad`] as a call of its own, for the 3D scatter. Inlined
/// into that loop, the 3D block drop ran 1.05× slower than with the call (paired runs
/// against the build of `12f3fd6`, where the compiler had chosen the call by itself
/// after an unrelated change; the builds before inlined it). In 2D the compiler
/// inlines it, and that is as fast. Pinned here so that another unrelated change
/// cannot flip the choice.
#[inline(never)]
fn stress_call<const D: usize>(m: &Material, f: &Mat<D>) -> Mat<D> {
    m.stress_of_def_grad(f)
}

/// `J V₀` and `V₀ τ` ([`Material::kirchhoff_of_def_grad`]) as a call of its own in 3D,
/// as [`stress_call`]. Scaled here, not by the caller: the caller's vector products
/// read `τ` back from the call's scalar stores, which the CPU cannot forward to a
/// wider load, and that one product took a fifth of the 3D scatter's samples.
#[inline(never)]
fn kirchhoff_call<const D: usize>(m: &Material, f: &Mat<D>, vol0: f64) -> (f64, Mat<D>) {
    let (tau, j) = m.kirchhoff_of_def_grad(f);
    (j * vol0, tau * vol0)
}

/// A kind's mass, reference volume and material ([`Kinds`]), as a particle loop
/// keeps them while the kind stays the same ([`KindCache`]).
#[derive(Clone, Copy)]
pub struct KindAt<'a> {
    pub kind: u16,
    pub mass: f64,
    pub vol0: f64,
    pub material: &'a Material,
}

/// The per-kind tables of a particle loop, looked up only when the kind changes
/// from one particle to the next. Particles sorted by cell mostly share their kind,
/// and each lookup (the kind, then each table, each with its index check) came to
/// about 30 instructions per particle in the 2D scatter. The values are the
/// tables' own, so the same bits. (In the remap, which looks up the mass alone, the
/// cache cost more than the lookup.)
pub struct KindCache<'a> {
    mass: &'a [f64],
    vol0: &'a [f64],
    materials: &'a [Material],
    at: Option<KindAt<'a>>,
}

impl<'a> KindCache<'a> {
    /// Tables per kind: masses, reference volumes and materials.
    pub fn new(mass: &'a [f64], vol0: &'a [f64], materials: &'a [Material]) -> Self {
        KindCache {
            mass,
            vol0,
            materials,
            at: None,
        }
    }

    #[inline(always)]
    pub fn get(&mut self, kind: u16) -> KindAt<'a> {
        match self.at {
            Some(at) if at.kind == kind => at,
            _ => self.load(kind),
        }
    }

    #[inline(never)]
    fn load(&mut self, kind: u16) -> KindAt<'a> {
        let k = kind as usize;
        let at = KindAt {
            kind,
            mass: self.mass[k],
            vol0: self.vol0[k],
            material: &self.materials[k],
        };
        self.at = Some(at);
        at
    }
}

/// Particle `p`'s volume `V` and `V σ` (the scatter's), `at` its kind
/// ([`KindCache`]): where the particles store neither the volume nor the stress,
/// `J V₀` and `V₀ τ` from the Kirchhoff stress `τ = J σ` of `F` (no division by `J`,
/// no second determinant); else the volume ([`volume_of`]) times the stress
/// ([`stress_of`]). `materials`: per kind.
#[inline(always)]
pub fn volume_and_stress<const D: usize>(
    stress: &[Mat<D>],
    vols: &Volumes<'_, D>,
    materials: &[Material],
    at: &KindAt<'_>,
    p: usize,
) -> (f64, Mat<D>) {
    if vols.vol.is_empty() && stress.is_empty() {
        let (m, f) = (at.material, &vols.def_grad[p]);
        if D == 3 {
            kirchhoff_call(m, f, at.vol0)
        } else {
            let (tau, j) = m.kirchhoff_of_def_grad(f);
            (j * at.vol0, tau * at.vol0)
        }
    } else {
        let v = vols.get(p);
        (
            v,
            stress_of(stress, vols.def_grad, vols.kind, materials, p) * v,
        )
    }
}

/// The kinds of particle of a scene ([`KindPlan`]): the particles of one kind share
/// their material, reference volume and mass, so each stores its kind's index (2
/// bytes), not its reference volume (8) and mass (8), in memory, migration records
/// and checkpoints. The same on every rank: it follows from the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Kinds {
    /// Per kind: the index of its material in the scene's `[[materials]]`.
    pub material: Vec<u16>,
    /// Per kind: the reference volume of each particle, the cell's volume over the
    /// particles per cell, times its share of its box.
    pub vol0: Vec<f64>,
    /// Per kind: the mass of each particle, its material's density times `vol0` (the
    /// product seeding formed when particles stored it: the same bits).
    pub mass: Vec<f64>,
}

impl Kinds {
    /// The kinds of `scene` on its grid `geom`.
    pub fn of_scene<const D: usize>(scene: &Scene, geom: &Geom<D>) -> Self {
        let materials = Material::all(&scene.plan.materials);
        Self::new(&scene.plan.kinds, geom, &materials)
    }

    pub fn new<const D: usize>(kinds: &[KindPlan], geom: &Geom<D>, materials: &[Material]) -> Self {
        // A whole box's share is exactly 1: its volume keeps the bits it had before
        // kinds had shares.
        let levels = f64::from(cut_levels(D));
        let vol0: Vec<f64> = kinds
            .iter()
            .map(|k| {
                geom.cell_volume() / k.particles_per_cell.pow(D as u32) as f64
                    * (f64::from(k.share) / levels)
            })
            .collect();
        Kinds {
            material: kinds.iter().map(|k| k.material as u16).collect(),
            mass: kinds
                .iter()
                .zip(&vol0)
                .map(|(k, v)| materials[k.material].density() * v)
                .collect(),
            vol0,
        }
    }

    /// The kind of a particle of material `material` with reference volume `vol0` (to
    /// the bit), as a checkpoint before version 6 stores it.
    pub fn find(&self, material: u16, vol0: f64) -> Option<u16> {
        (0..self.material.len())
            .find(|&k| self.material[k] == material && self.vol0[k].to_bits() == vol0.to_bits())
            .map(|k| k as u16)
    }

    /// The material of each kind, from the scene's materials.
    pub fn materials(&self, materials: &[Material]) -> Vec<Material> {
        self.material
            .iter()
            .map(|&m| materials[m as usize].clone())
            .collect()
    }
}

/// The mass of particle `p`: its kind's ([`Kinds::mass`], `kind_mass`), the same bits
/// as the mass that particles stored before (checkpoint version 4).
#[inline(always)]
pub fn mass_of(kind_mass: &[f64], kind: &[u16], p: usize) -> f64 {
    kind_mass[kind[p] as usize]
}

/// The current volume of particle `p`: stored (`vol`) where the particles carry no `F`,
/// else `det F` times its kind's reference volume (`kind_vol0`). The particles stored
/// it for all before and updated it by each step's increment `det(I + L dt)` as they
/// update `F`: the same volume up to round-off, and 8 bytes a particle.
#[inline(always)]
pub fn volume_of<const D: usize>(
    vol: &[f64],
    def_grad: &[Mat<D>],
    (kind_vol0, kind): (&[f64], &[u16]),
    p: usize,
) -> f64 {
    if vol.is_empty() {
        det(&def_grad[p]) * kind_vol0[kind[p] as usize]
    } else {
        vol[p]
    }
}

/// The particles' volumes ([`volume_of`]) as a view the particle loops index.
#[derive(Clone, Copy)]
pub struct Volumes<'a, const D: usize> {
    /// Empty where the particles carry `F`.
    pub vol: &'a [f64],
    pub def_grad: &'a [Mat<D>],
    /// Per kind ([`Kinds::vol0`]).
    pub kind_vol0: &'a [f64],
    pub kind: &'a [u16],
}

impl<'a, const D: usize> Volumes<'a, D> {
    /// The volumes of `parts`, of `kinds`.
    pub fn of(kinds: &'a Kinds, parts: &'a Particles<D>) -> Self {
        Volumes {
            vol: &parts.vol,
            def_grad: &parts.def_grad,
            kind_vol0: &kinds.vol0,
            kind: &parts.kind,
        }
    }

    #[inline(always)]
    pub fn get(&self, p: usize) -> f64 {
        volume_of(self.vol, self.def_grad, (self.kind_vol0, self.kind), p)
    }
}

/// The particles' masses ([`mass_of`]) as a view the particle loops index.
#[derive(Clone, Copy)]
pub struct Masses<'a> {
    /// Per kind ([`Kinds::mass`]).
    pub kind_mass: &'a [f64],
    pub kind: &'a [u16],
}

impl<'a> Masses<'a> {
    /// The masses of particles of kinds `kind` (of `kinds`).
    pub fn of(kinds: &'a Kinds, kind: &'a [u16]) -> Self {
        Masses {
            kind_mass: &kinds.mass,
            kind,
        }
    }

    #[inline(always)]
    pub fn get(&self, p: usize) -> f64 {
        mass_of(self.kind_mass, self.kind, p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A particle loop's [`KindCache`] gives the tables' values of each particle's
    /// kind, to the bit, along a sequence of kinds that stays, changes, and returns to
    /// a kind it left (a cache that kept the first kind, or did not reload on a
    /// return, would fail it); and `volume_and_stress` with it forms `J V₀` and
    /// `V₀ τ` from the tables' own volume and material.
    #[test]
    fn kind_cache_gives_each_kinds_tables() {
        use crate::physics::material::neo_hookean::NeoHookean;
        let materials: Vec<Material> = (0..3)
            .map(|k| {
                Material::NeoHookean(NeoHookean {
                    lambda: 1.0 + k as f64,
                    mu: 2.0 + 0.5 * k as f64,
                    density: 3.0,
                })
            })
            .collect();
        let mass = [0.1, 0.2, 0.3];
        let vol0 = [0.7, 0.11, 0.13];
        let kind: Vec<u16> = vec![0, 0, 1, 1, 1, 0, 2, 2, 1];
        let def_grad: Vec<Mat<2>> = (0..kind.len())
            .map(|p| Mat::<2>::new(1.0 + 0.01 * p as f64, 0.02, -0.03, 0.98))
            .collect();
        let vols = Volumes {
            vol: &[],
            def_grad: &def_grad,
            kind_vol0: &vol0,
            kind: &kind,
        };
        let mut cache = KindCache::new(&mass, &vol0, &materials);
        for (p, &k) in kind.iter().enumerate() {
            let at = cache.get(k);
            let i = k as usize;
            assert_eq!(at.kind, k);
            assert_eq!(at.mass.to_bits(), mass[i].to_bits(), "particle {p}");
            assert_eq!(at.vol0.to_bits(), vol0[i].to_bits(), "particle {p}");
            assert!(std::ptr::eq(at.material, &materials[i]), "particle {p}");
            let (v, s) = volume_and_stress(&[], &vols, &materials, &at, p);
            let (tau, j) = materials[i].kirchhoff_of_def_grad(&def_grad[p]);
            let (w, t) = (j * vol0[i], tau * vol0[i]);
            assert_eq!(v.to_bits(), w.to_bits(), "particle {p}");
            assert!(s
                .iter()
                .zip(t.iter())
                .all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }
}
