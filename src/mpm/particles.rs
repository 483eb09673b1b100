//! Particles as a structure of arrays, declared once in `particle_fields!` below:
//! every array with its element type, how its checkpoint columns are named, which
//! [`Carries`] flag it needs and (for a material's state) its initial value. Sorting,
//! removal, copying, the migration and checkpoint record, seeding and the step's
//! particle slices ([`ParticleSlices`]) all follow from that declaration, so adding a
//! material state is one line there (plus a flag in `carries!` if no existing one
//! fits) and its model (its slot in `material::Internal`, filled in `kernel::deform`).
//!
//! Optional state is an empty `Vec` unless the scene needs it: the deformation
//! gradient only for materials that use it, the reference position only for
//! benchmarks, the GIMP half-width only for `gimp`, the out-of-plane stress only for
//! `brittle` in 2D.

mod arrays;
mod kinds;
mod record;
mod seed;

pub use arrays::{order_by_key_then_id, reserve, reserve_exact, split_mut};
pub use kinds::{
    mass_of, stress_of, volume_and_stress, volume_of, KindAt, KindCache, Kinds, Masses, Volumes,
};
pub use record::Record;
pub use seed::{inside, overlap, seeds_any, shape_bounds};

use crate::input::plan::Law;
use crate::input::scene::Scene;
use crate::physics::material::Material;
use crate::physics::shape::GradientScheme;
use crate::physics::tensor::{det, Mat, Vector};
use arrays::retain;
use nalgebra::Matrix3;

/// Declares [`Carries`]: one flag per group of optional particle arrays. The flags'
/// order is that of the checkpoint attributes `carries_<flag>`.
macro_rules! carries {
    ($($(#[$doc:meta])* $flag:ident),* $(,)?) => {
        /// Which optional arrays the particles carry.
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        pub struct Carries {
            $($(#[$doc])* pub $flag: bool,)*
        }

        impl Carries {
            /// The flags' names, in declaration order.
            pub const NAMES: &'static [&'static str] = &[$(stringify!($flag)),*];

            /// The flags, in the order of [`Carries::NAMES`].
            pub fn flags(self) -> Vec<bool> {
                vec![$(self.$flag),*]
            }

            /// From flags in the order of [`Carries::NAMES`] (as many).
            pub fn from_flags(flags: &[bool]) -> Self {
                let mut it = flags.iter().copied();
                let c = Carries {
                    $($flag: it.next().expect("one flag per name"),)*
                };
                debug_assert!(it.next().is_none());
                c
            }
        }
    };
}

carries! {
    def_grad,
    x0,
    half,
    /// `be` and `eps_p`.
    plastic,
    damage,
    stress_zz,
    /// The Cauchy stress, for materials whose stress is state of its own
    /// ([`Material::stress_is_state`]); the others' follows from `F`.
    stress,
    /// The mass: never for a scene's particles, whose mass is their kind's ([`Kinds`],
    /// [`mass_of`]); only the rows of a checkpoint of version 4 or older hold it, read
    /// and dropped.
    mass,
    /// The reference volume: never for a scene's particles, whose reference volume is
    /// their kind's ([`Kinds`]); only the rows of a checkpoint of version 5 or older
    /// hold it, read and turned into the kind.
    vol0,
    /// The current volume, for particles without `F` (their materials need none):
    /// with `F` it is `det F · V₀` ([`Volumes`]), and only the rows of a checkpoint of
    /// version 5 or older hold it, read and dropped.
    vol,
}

/// How a field's values are named in a checkpoint's `columns`: `name`, `name[a]`, or
/// `name[i][j]` column-major (as nalgebra stores matrices). Declared, not derived from
/// the type: in 1D a vector and a matrix are the same type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Columns {
    Scalar,
    Vector,
    Matrix,
}

/// One particle array as laid out in a record: its column name, naming and width.
#[derive(Clone, Copy, Debug)]
pub struct FieldInfo {
    pub column: &'static str,
    pub columns: Columns,
    pub width: usize,
}

/// `true` for arrays every particle set carries, else the scene's flag.
macro_rules! carried {
    ($c:expr, always) => {
        true
    };
    ($c:expr, $flag:ident) => {
        $c.$flag
    };
}

/// A field's column name: the declared one, else the field's name.
macro_rules! column_name {
    ($col:literal; $name:ident) => {
        $col
    };
    (; $name:ident) => {
        stringify!($name)
    };
}

/// Push a material state's initial value if the scene carries it; kinematic fields
/// (no initial value declared) are pushed by [`Particles::push_seeded`].
macro_rules! push_initial {
    ($s:ident, $c:ident, $name:ident, $carry:ident) => {};
    ($s:ident, $c:ident, $name:ident, $carry:ident, $init:expr) => {
        if carried!($c, $carry) {
            $s.$name.push($init);
        }
    };
}

/// Declares [`Particles`] and the operations that visit every array. Each line:
/// `name: element type, column naming ("column name" if not the field's), flag or
/// always [= initial value of a material state]`. The order is the record's (the
/// migration and checkpoint layout, checkpoint format 3): do not reorder.
macro_rules! particle_fields {
    ($($(#[$doc:meta])* $name:ident : $ty:ty, $cols:ident $(($col:literal))?, $carry:ident
        $(= $init:expr)?;)*) => {
        #[derive(Clone, Debug, Default)]
        pub struct Particles<const D: usize> {
            $($(#[$doc])* pub $name: Vec<$ty>,)*
        }

        /// Every particle array over a contiguous range of particles, splittable for
        /// threads (the step's particle loops, [`crate::mpm::kernel::Slices`]); arrays the
        /// particles do not carry are empty.
        pub struct ParticleSlices<'a, const D: usize> {
            $($(#[$doc])* pub $name: &'a mut [$ty],)*
        }

        impl<'a, const D: usize> ParticleSlices<'a, D> {
            pub fn len(&self) -> usize {
                self.x.len()
            }

            pub fn is_empty(&self) -> bool {
                self.x.is_empty()
            }

            /// The particles before `mid` and from `mid` on.
            pub fn split_at(self, mid: usize) -> (Self, Self) {
                $(let $name = split_mut(self.$name, mid);)*
                (
                    ParticleSlices { $($name: $name.0,)* },
                    ParticleSlices { $($name: $name.1,)* },
                )
            }
        }

        impl<const D: usize> Particles<D> {
            /// The arrays `c` carries, in record order.
            pub fn fields(c: Carries) -> Vec<FieldInfo> {
                let mut f = Vec::new();
                $(if carried!(c, $carry) {
                    f.push(FieldInfo {
                        column: column_name!($($col)?; $name),
                        columns: Columns::$cols,
                        width: <$ty as Record>::WIDTH,
                    });
                })*
                f
            }

            /// Every array as a [`ParticleSlices`] over all particles.
            pub fn slices(&mut self) -> ParticleSlices<'_, D> {
                ParticleSlices { $($name: &mut self.$name,)* }
            }

            /// Values per particle in a migration record for what these particles carry.
            pub fn record_width(c: Carries) -> usize {
                let mut w = 0;
                $(if carried!(c, $carry) {
                    w += <$ty as Record>::WIDTH;
                })*
                w
            }

            /// Bytes of a particle's state (its record, as migration and checkpoints
            /// hold it): less than a run holds per particle, which adds its grid, cell
            /// and order.
            pub fn state_bytes(c: Carries) -> u64 {
                8 * Self::record_width(c) as u64
            }

            /// Apply the permutation `perm` (new position k holds old particle `perm[k]`)
            /// to every array and to `extra` (empty, or one entry per particle); `done`
            /// (one bit per particle) is reused, so no allocation happens once it has
            /// grown. One walk along the permutation's cycles, in
            /// place: no copy of an array (one of the widest, `F` or σ, would be 72
            /// bytes per particle in 3D, held from the first sort on). The walk's
            /// loads of `perm` are a chain, paid once rather than per array (the
            /// vortex's arrays moved in 0.8 of the time of one walk each). A swap per
            /// step moves the cycle's first value along, so no array needs a saved
            /// value of its own.
            pub fn permute_with<E: Copy>(&mut self, perm: &[u32], done: &mut Vec<u64>, extra: &mut [E]) {
                let n = perm.len();
                $(debug_assert!(self.$name.is_empty() || self.$name.len() == n);)*
                debug_assert!(extra.is_empty() || extra.len() == n);
                done.clear();
                done.resize(n.div_ceil(64), 0);
                $(let $name = !self.$name.is_empty();)*
                let with_extra = !extra.is_empty();
                for start in 0..n {
                    if done[start / 64] >> (start % 64) & 1 != 0 {
                        continue;
                    }
                    // Position k takes the value of position perm[k]; the cycle's
                    // first value rides the swaps to the position that wants it.
                    let mut k = start;
                    loop {
                        done[k / 64] |= 1 << (k % 64);
                        let from = perm[k] as usize;
                        if from == start {
                            break;
                        }
                        $(if $name {
                            self.$name.swap(k, from);
                        })*
                        if with_extra {
                            extra.swap(k, from);
                        }
                        k = from;
                    }
                }
            }

            /// Release the capacity beyond the particle count (after seeding or a
            /// restart: growth by pushes leaves up to twice the state allocated).
            pub fn fit(&mut self) {
                $(self.$name.shrink_to_fit();)*
            }

            /// Room for `n` particles in every array `c` carries ([`reserve`]).
            pub fn reserve_total(&mut self, n: usize, c: Carries) {
                $(if carried!(c, $carry) {
                    reserve(&mut self.$name, n);
                })*
            }

            /// Keep the particles whose `keep` flag is set, in order.
            pub fn retain(&mut self, keep: &[bool]) {
                $(retain(&mut self.$name, keep);)*
            }

            /// Particle `p` as a flat record in `out` (ids and material indices are
            /// exact in f64).
            pub fn pack(&self, p: usize, c: Carries, out: &mut Vec<f64>) {
                out.clear();
                $(if carried!(c, $carry) {
                    self.$name[p].put(out);
                })*
            }

            /// Append a particle from a record made by [`Particles::pack`].
            pub fn unpack(&mut self, r: &[f64], c: Carries) {
                let mut at = 0;
                $(if carried!(c, $carry) {
                    let w = <$ty as Record>::WIDTH;
                    self.$name.push(<$ty as Record>::get(&r[at..at + w]));
                    at += w;
                })*
                debug_assert_eq!(at, r.len());
            }

            /// Append the initial value of every material state `c` carries.
            fn push_initial_state(&mut self, c: Carries) {
                $(push_initial!(self, c, $name, $carry $(, $init)?);)*
            }

            /// Every array `c` carries has one value per particle, the others none.
            fn consistent(&self, c: Carries) -> bool {
                let n = self.x.len();
                true $(&& self.$name.len() == if carried!(c, $carry) { n } else { 0 })*
            }
        }
    };
}

particle_fields! {
    x: Vector<D>, Vector, always;
    v: Vector<D>, Vector, always;
    /// Mass, only as read from an older checkpoint (see [`Carries::mass`]).
    mass: f64, Scalar, mass;
    /// Current volume, where the particles carry no `F` (see [`Carries::vol`]).
    vol: f64, Scalar, vol;
    /// Reference volume, only as read from an older checkpoint (see [`Carries::vol0`]).
    vol0: f64, Scalar, vol0;
    /// Cauchy stress, where it is state (see [`Carries::stress`]).
    stress: Mat<D>, Matrix, stress;
    /// The index of the particle's kind ([`Kinds`]): its material and reference
    /// volume. (A checkpoint of version 5 or older holds the material's index here.)
    kind: u16, Scalar, always;
    /// Global id, independent of the rank count.
    id: u64, Scalar, always;
    /// Deformation gradient (materials that need it).
    def_grad: Mat<D>, Matrix, def_grad;
    /// Reference position (benchmarks).
    x0: Vector<D>, Vector, x0;
    /// GIMP particle half-width per axis.
    half: [f64; D], Vector, half;
    /// Elastic left Cauchy–Green tensor, always 3 × 3 (plasticity in plane strain
    /// needs the out-of-plane stretch), and equivalent plastic strain (`j2_plastic`).
    be: Matrix3<f64>, Matrix, plastic = Matrix3::identity();
    eps_p: f64, Scalar, plastic = 0.0;
    /// Damage, 0 intact or 1 failed (`brittle`).
    damage: f64, Scalar, damage = 0.0;
    /// Plane-strain σ_zz (`brittle` in 2D, where failure makes it history-dependent;
    /// the other models derive it, see [`Material::stress_zz`]).
    stress_zz: f64, Scalar, stress_zz = 0.0;
}

impl Carries {
    /// The optional particle arrays a scene needs.
    pub fn for_scene(scene: &Scene) -> Self {
        let laws = || scene.plan.materials.iter().map(|m| m.law);
        Carries {
            def_grad: scene
                .plan
                .materials
                .iter()
                .any(|m| Material::from_plan(m).needs_def_grad()),
            // Benchmarks measure displacement errors; a displacement output needs it too.
            x0: scene.benchmark.is_some()
                || scene
                    .snapshot_plan()
                    .is_some_and(|o| o.fields.contains(&crate::input::scene::Field::Displacement)),
            // GIMP's domains, and the boxes a body force is averaged over.
            half: GradientScheme::of(scene.method.gradient, scene.method.quadrature).wide()
                || scene.plan.body_force_over_domain,
            plastic: laws().any(|l| matches!(l, Law::J2Plastic { .. })),
            damage: laws().any(|l| matches!(l, Law::Brittle { .. })),
            stress_zz: scene.dim == 2 && laws().any(|l| matches!(l, Law::Brittle { .. })),
            stress: scene
                .plan
                .materials
                .iter()
                .any(|m| Material::from_plan(m).stress_is_state()),
            mass: false,
            vol0: false,
            vol: !scene
                .plan
                .materials
                .iter()
                .any(|m| Material::from_plan(m).needs_def_grad()),
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

    /// The current volume of particle `p` ([`volume_of`]; `kind_vol0` per kind).
    #[inline]
    pub fn volume(&self, p: usize, kind_vol0: &[f64]) -> f64 {
        volume_of(&self.vol, &self.def_grad, (kind_vol0, &self.kind), p)
    }

    /// The volume ratio `J = V / V₀` of particle `p`: `det F` where the particles
    /// carry `F`.
    #[inline]
    pub fn volume_ratio(&self, p: usize, kind_vol0: &[f64]) -> f64 {
        if self.vol.is_empty() {
            det(&self.def_grad[p])
        } else {
            self.vol[p] / kind_vol0[self.kind[p] as usize]
        }
    }

    /// The Cauchy stress of particle `p`: stored, or formed from its `F`.
    #[inline]
    pub fn stress_of(&self, p: usize, materials: &[Material]) -> Mat<D> {
        stress_of(&self.stress, &self.def_grad, &self.kind, materials, p)
    }

    /// The full 3 × 3 Cauchy stress of particle `p` (for output): in 2D with the
    /// plane-strain σ_zz, in 1D only σ_xx (the lateral stresses are not formed).
    pub fn stress3(&self, p: usize, materials: &[Material]) -> Matrix3<f64> {
        let s = &self.stress_of(p, materials);
        let mut m = Matrix3::from_fn(|i, j| if i < D && j < D { s[(i, j)] } else { 0.0 });
        if D == 2 {
            let f = self
                .def_grad
                .get(p)
                .copied()
                .unwrap_or_else(Mat::<D>::identity);
            m[(2, 2)] = materials[self.kind[p] as usize].stress_zz(
                s,
                &f,
                self.be.get(p),
                self.stress_zz.get(p).copied(),
            );
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three particles carrying every array, each value distinct.
    fn sample() -> (Particles<2>, Carries) {
        let c = Carries::from_flags(&vec![true; Carries::NAMES.len()]);
        let w = Particles::<2>::record_width(c);
        let mut p = Particles::<2>::default();
        for k in 0..3 {
            let mut r: Vec<f64> = (0..w).map(|i| (100 * k + i) as f64 + 0.25).collect();
            // Material index and id are integers.
            r[2 * 2 + 3 + 4] = k as f64;
            r[2 * 2 + 3 + 4 + 1] = (1000 + k) as f64;
            p.unpack(&r, c);
        }
        (p, c)
    }

    #[test]
    fn pack_unpack_round_trip() {
        let (p, c) = sample();
        assert!(p.consistent(c));
        let mut q = Particles::<2>::default();
        let mut rec = Vec::new();
        for k in 0..p.len() {
            p.pack(k, c, &mut rec);
            assert_eq!(rec.len(), Particles::<2>::record_width(c));
            q.unpack(&rec, c);
        }
        assert_eq!(format!("{p:?}"), format!("{q:?}"));
    }

    #[test]
    fn permute_in_place_is_the_gather_by_perm() {
        // A shuffled permutation (several cycles, fixed points) applied twice to
        // reuse the marks, to two arrays, one absent and an extra one: each time
        // position k must hold old value perm[k] in every array present.
        let n = 1000;
        let mut perm: Vec<u32> = (0..n as u32).collect();
        let mut rng = decomposition::splitmix::Rng::new(12345);
        for k in (1..n).rev() {
            perm.swap(k, rng.below(k + 1));
        }
        let mut p = Particles::<2> {
            id: (0..n as u64).map(|k| k * 7 + 3).collect(),
            mass: (0..n).map(|k| k as f64 * 0.5).collect(),
            ..Default::default()
        };
        let mut extra: Vec<(u16, f64)> = (0..n).map(|k| (k as u16, -(k as f64))).collect();
        let mut done = Vec::new();
        for _ in 0..2 {
            let gather = |v: &[u64]| perm.iter().map(|&k| v[k as usize]).collect::<Vec<_>>();
            let want = (gather(&p.id), p.mass.clone(), extra.clone());
            p.permute_with(&perm, &mut done, &mut extra);
            assert_eq!(p.id, want.0);
            for k in 0..n {
                assert_eq!(p.mass[k], want.1[perm[k] as usize]);
                assert_eq!(extra[k], want.2[perm[k] as usize]);
            }
            assert!(p.x.is_empty());
        }
    }

    #[test]
    fn permute_and_retain_move_every_array() {
        let (mut p, c) = sample();
        let orig = p.clone();
        p.permute_with(&[2, 0, 1], &mut Vec::new(), &mut [(); 0]);
        p.retain(&[true, false, true]);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for (k, o) in [(0, 2), (1, 1)] {
            p.pack(k, c, &mut a);
            orig.pack(o, c, &mut b);
            assert_eq!(a, b);
        }
        assert!(p.consistent(c));
    }
}
