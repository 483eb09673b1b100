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

use crate::input::plan::{KindPlan, Law};
use crate::input::scene::{BodySpec, Scene, Shape};
use crate::physics::benchmark::Benchmark;
use crate::physics::material::Material;
use crate::physics::shape::{Geom, GradientScheme};
use crate::physics::tensor::{det, vector, Mat, Vector};
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

/// The Cauchy stress of particle `p` from its arrays: `stress` if the particles store
/// it (not empty), else formed from `F` (the particles' materials then all have a
/// stress that is not state, [`Carries::stress`]). `materials`: per kind.
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

/// Room for `n` elements in `v`: where it must grow, to `n` and a sixteenth, not to
/// twice its capacity as pushes would (particle state is most of a run's memory), so
/// arrivals rarely reallocate and never double the arrays.
pub fn reserve<T>(v: &mut Vec<T>, n: usize) {
    if v.capacity() < n {
        v.reserve_exact(n + n / 16 - v.len());
    }
}

/// Room for exactly `n` elements in `v` where it has less.
pub fn reserve_exact<T>(v: &mut Vec<T>, n: usize) {
    if v.capacity() < n {
        v.reserve_exact(n - v.len());
    }
}

/// Split a (possibly absent, i.e. empty) array at `mid`.
pub fn split_mut<T>(s: &mut [T], mid: usize) -> (&mut [T], &mut [T]) {
    if s.is_empty() {
        (&mut [], &mut [])
    } else {
        s.split_at_mut(mid)
    }
}

/// The indices `0 .. ids.len()` ordered by `(key(i), ids[i])` into `order`, with
/// `spare` as room (both a u32 per particle). The ids are distinct, so this is the
/// one order any sort by that pair gives; here it takes linear time: a stable radix
/// sort of the keys' span (a cell number: 15 bits for a 128² grid), 11 bits a pass,
/// then each run of equal keys (one cell's particles, mostly in id order already)
/// sorted by id. The comparison sort it replaced took `n log n` comparisons of
/// scattered keys, a quarter of a step's time on the vortex (0.85 ms; this 0.29).
pub fn order_by_key_then_id(
    key: impl Fn(u32) -> u64,
    ids: &[u64],
    order: &mut Vec<u32>,
    spare: &mut Vec<u32>,
) {
    const BITS: u32 = 11;
    // A rank's particles fit in u32 indices, as the node indices do (`ptile`): 4e9
    // particles would take over a terabyte.
    let n = u32::try_from(ids.len()).expect("fewer than 2^32 particles per rank");
    order.clear();
    order.extend(0..n);
    let (lo, hi) = (0..n).fold((u64::MAX, 0), |(lo, hi), p| {
        let k = key(p);
        (lo.min(k), hi.max(k))
    });
    let span_bits = if n == 0 {
        0
    } else {
        u64::BITS - (hi - lo).leading_zeros()
    };
    spare.clear();
    spare.resize(n as usize, 0);
    let mut shift = 0;
    while shift < span_bits {
        let digit = |p: u32| ((key(p) - lo) >> shift) as usize & ((1 << BITS) - 1);
        let mut at = [0u32; 1 << BITS];
        for &p in order.iter() {
            at[digit(p)] += 1;
        }
        let mut sum = 0;
        for a in at.iter_mut() {
            (*a, sum) = (sum, sum + *a);
        }
        for &p in order.iter() {
            let d = digit(p);
            spare[at[d] as usize] = p;
            at[d] += 1;
        }
        std::mem::swap(order, spare);
        shift += BITS;
    }
    // Each cell's run by id: one scan, a run sorted only where it is out of order.
    let (mut start, mut run_key, mut in_order) = (0, None, true);
    for i in 0..=order.len() {
        let k = order.get(i).map(|&p| key(p));
        if i > 0 && k.is_some() && k == run_key {
            in_order &= ids[order[i - 1] as usize] < ids[order[i] as usize];
            continue;
        }
        if !in_order {
            order[start..i].sort_unstable_by_key(|&p| ids[p as usize]);
        }
        (start, run_key, in_order) = (i, k, true);
    }
}

fn retain<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
    if v.is_empty() {
        return;
    }
    let mut w = 0;
    for r in 0..v.len() {
        if keep[r] {
            v[w] = v[r];
            w += 1;
        }
    }
    v.truncate(w);
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
            half: GradientScheme::of(scene.method.gradient).gimp,
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

/// The kinds of particle of a scene ([`KindPlan`]): the particles of one kind share
/// their material, reference volume and mass, so each stores its kind's index (2
/// bytes), not its reference volume (8) and mass (8), in memory, migration records
/// and checkpoints. The same on every rank: it follows from the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Kinds {
    /// Per kind: the index of its material in the scene's `[[materials]]`.
    pub material: Vec<u16>,
    /// Per kind: the reference volume of each particle, the cell's volume over the
    /// particles per cell.
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
        let vol0: Vec<f64> = kinds
            .iter()
            .map(|k| geom.cell_volume() / k.particles_per_cell.pow(D as u32) as f64)
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

    /// Seed the particles of every body whose current position falls in the owned
    /// cells `[cell_lo, cell_hi)`, in global id order.
    /// `materials`: per kind of `kinds`.
    pub fn seed(
        scene: &Scene,
        geom: &Geom<D>,
        (kinds, materials): (&Kinds, &[Material]),
        benchmark: Option<&Benchmark<D>>,
        cell_lo: [usize; D],
        cell_hi: [usize; D],
    ) -> Self {
        let carries = Carries::for_scene(scene);
        let mut p = Particles::<D>::default();
        // Benchmarks may start displaced: look that many cells beyond the block.
        let disp = match benchmark {
            Some(Benchmark::AxisAlignedMms { a, .. }) => a.abs(),
            _ => 0.0,
        };
        let mut id_base = 0u64;
        for (body, &k) in scene.bodies.iter().zip(&scene.plan.body_kind) {
            let n = body.particles_per_cell;
            let sub = n.pow(D as u32);
            let seed = BodySeed {
                mat: &materials[k],
                kind: k as u16,
                vol0: kinds.vol0[k],
                half: std::array::from_fn(|a| 0.5 * geom.h[a] / n as f64),
                carries,
            };
            let (c0, c1) = body_cells::<D>(body, geom);
            // Restrict to the block, padded by the initial displacement.
            let pad: [usize; D] =
                std::array::from_fn(|a| 1 + (disp * geom.inv_h[a]).ceil() as usize);
            let r0: [usize; D] =
                std::array::from_fn(|a| c0[a].max(cell_lo[a].saturating_sub(pad[a])));
            let r1: [usize; D] = std::array::from_fn(|a| c1[a].min(cell_hi[a] + pad[a]));
            let dims: [usize; D] = std::array::from_fn(|a| c1[a] - c0[a]);
            let body_cells: usize = dims.iter().product();
            if (0..D).all(|a| r0[a] < r1[a]) {
                lattice_points::<D>(body, geom, (c0, c1), (r0, r1), |lin, s, xref| {
                    let xr = vector::<D>(&xref);
                    let (x, v, f) = initial_motion(body, benchmark, &xr);
                    let (c, _) = geom.locate(&std::array::from_fn(|a| x[a]));
                    if (0..D).any(|a| c[a] < cell_lo[a] as i64 || c[a] >= cell_hi[a] as i64) {
                        return true;
                    }
                    p.push_seeded(&seed, id_base + (lin * sub + s) as u64, xr, (x, v, f));
                    true
                });
            }
            id_base += (body_cells * sub) as u64;
        }
        p
    }

    /// Append a new particle of `seed`'s body: reference position `xr`, position,
    /// velocity and deformation gradient `(x, v, f)`, the stress of `f`, and every
    /// material state the scene carries at its declared initial value.
    fn push_seeded(
        &mut self,
        seed: &BodySeed<D>,
        id: u64,
        xr: Vector<D>,
        (x, v, f): (Vector<D>, Vector<D>, Mat<D>),
    ) {
        let (mat, vol0, carries) = (seed.mat, seed.vol0, seed.carries);
        let j = det(&f);
        self.x.push(x);
        self.v.push(v);
        debug_assert!(
            !carries.mass && !carries.vol0,
            "a seeded particle's are its kind's"
        );
        if carries.vol {
            self.vol.push(vol0 * j);
        }
        if carries.stress {
            let mut st = Mat::<D>::zeros();
            if mat.needs_def_grad() {
                let none = crate::physics::material::Internal {
                    plastic: None,
                    damage: None,
                    stress_zz: None,
                };
                mat.update_stress(&mut st, &Mat::<D>::zeros(), &f, 0.0, none);
            }
            self.stress.push(st);
        }
        if carries.def_grad {
            self.def_grad.push(f);
        }
        self.kind.push(seed.kind);
        self.id.push(id);
        if carries.x0 {
            self.x0.push(xr);
        }
        if carries.half {
            self.half.push(seed.half);
        }
        self.push_initial_state(carries);
        debug_assert!(self.consistent(carries));
    }
}

/// What the particles of one body share when they are seeded.
struct BodySeed<'m, const D: usize> {
    mat: &'m Material,
    /// The body's kind of particle.
    kind: u16,
    /// Its reference volume.
    vol0: f64,
    /// GIMP half-widths.
    half: [f64; D],
    carries: Carries,
}

/// The initial position, velocity and deformation gradient of the particle at
/// reference position `xr`: a benchmark's exact state at t = 0 (or rest), plus the
/// body's velocity and velocity gradient.
fn initial_motion<const D: usize>(
    body: &BodySpec,
    benchmark: Option<&Benchmark<D>>,
    xr: &Vector<D>,
) -> (Vector<D>, Vector<D>, Mat<D>) {
    let (mut x, mut v, mut f) = (*xr, Vector::<D>::zeros(), Mat::<D>::identity());
    if let Some(b) = benchmark {
        let (u, vel) = b.exact(xr, 0.0);
        x += u;
        v = vel;
        f = b.deformation_gradient(xr, 0.0);
    }
    if let Some(bv) = &body.velocity {
        v += vector::<D>(bv);
    }
    if let Some(g) = &body.velocity_gradient {
        for (i, row) in g.value.iter().enumerate() {
            for (j, gij) in row.iter().enumerate() {
                let c = g.about.as_ref().map_or(0.0, |c| c[j]);
                v[i] += gij * (xr[j] - c);
            }
        }
    }
    (x, v, f)
}

/// The grid cells `c0..c1` overlapping a body's bounding box (at least one per axis; it
/// may lie beyond the grid when the body does).
fn body_cells<const D: usize>(body: &BodySpec, geom: &Geom<D>) -> ([usize; D], [usize; D]) {
    let (blo, bhi) = shape_bounds::<D>(&body.shape);
    let mut c0 = [0usize; D];
    let mut c1 = [0usize; D];
    for a in 0..D {
        let lo = ((blo[a] - geom.lower[a]) * geom.inv_h[a]).floor().max(0.0) as usize;
        let hi = (((bhi[a] - geom.lower[a]) * geom.inv_h[a]).ceil() as usize).min(geom.cells[a]);
        c0[a] = lo;
        c1[a] = hi.max(lo + 1);
    }
    (c0, c1)
}

/// Calls `f(lin, s, x)` for each seeding lattice point `x` of `body` inside its shape, in
/// the cells `r0..r1` of the body's cells `c0..c1`: point `s` of the `n^D` in a cell
/// (`n` particles per cell and axis, at `(q + ½)/n` of the cell), `lin` the cell's
/// index in `c0..c1` (which, with `s`, numbers the particle ids). Stops when `f`
/// returns false.
fn lattice_points<const D: usize>(
    body: &BodySpec,
    geom: &Geom<D>,
    (c0, c1): ([usize; D], [usize; D]),
    (r0, r1): ([usize; D], [usize; D]),
    mut f: impl FnMut(usize, usize, [f64; D]) -> bool,
) {
    let n = body.particles_per_cell;
    let sub = n.pow(D as u32);
    let dims: [usize; D] = std::array::from_fn(|a| c1[a] - c0[a]);
    let counts: [usize; D] = std::array::from_fn(|a| r1[a].saturating_sub(r0[a]));
    let total: usize = counts.iter().product();
    for k in 0..total {
        let mut rem = k;
        let mut cell = [0usize; D];
        for a in 0..D {
            cell[a] = r0[a] + rem % counts[a];
            rem /= counts[a];
        }
        let mut lin = 0usize;
        for a in (0..D).rev() {
            lin = lin * dims[a] + (cell[a] - c0[a]);
        }
        for s in 0..sub {
            let mut r = s;
            let mut x = [0.0; D];
            for a in 0..D {
                let q = r % n;
                r /= n;
                x[a] = geom.lower[a] + (cell[a] as f64 + (q as f64 + 0.5) / n as f64) * geom.h[a];
            }
            if inside(&body.shape, &x) && !f(lin, s, x) {
                return;
            }
        }
    }
}

/// Whether `body` seeds at least one particle in the grid of `geom`: false when it lies
/// outside the grid or between the lattice points (smaller than a particle spacing).
/// Stops at the first particle, so it costs little for any real body.
pub fn seeds_any<const D: usize>(body: &BodySpec, geom: &Geom<D>) -> bool {
    let (c0, c1) = body_cells::<D>(body, geom);
    let r1: [usize; D] = std::array::from_fn(|a| c1[a].min(geom.cells[a]));
    let mut any = false;
    lattice_points::<D>(body, geom, (c0, c1), (c0, r1), |_, _, _| {
        any = true;
        false
    });
    any
}

/// A lattice point of `b` (as seeded) that lies inside the shape of `a`, if any: the two
/// bodies would both seed particles there. Walks only the cells where their bounding
/// boxes meet.
pub fn overlap<const D: usize>(a: &BodySpec, b: &BodySpec, geom: &Geom<D>) -> Option<[f64; D]> {
    let (a0, a1) = body_cells::<D>(a, geom);
    let (b0, b1) = body_cells::<D>(b, geom);
    let r0: [usize; D] = std::array::from_fn(|k| a0[k].max(b0[k]));
    let r1: [usize; D] = std::array::from_fn(|k| a1[k].min(b1[k]).min(geom.cells[k]));
    let mut hit = None;
    lattice_points::<D>(b, geom, (b0, b1), (r0, r1), |_, _, x| {
        if inside(&a.shape, &x) {
            hit = Some(x);
        }
        hit.is_none()
    });
    hit
}

/// Bounding box of a shape.
pub fn shape_bounds<const D: usize>(s: &Shape) -> ([f64; D], [f64; D]) {
    match s {
        Shape::Box { lower, upper } => (
            std::array::from_fn(|a| lower[a]),
            std::array::from_fn(|a| upper[a]),
        ),
        Shape::Sphere { center, radius } => (
            std::array::from_fn(|a| center[a] - radius),
            std::array::from_fn(|a| center[a] + radius),
        ),
        Shape::Annulus { center, outer, .. } => (
            std::array::from_fn(|a| center[a] - outer),
            std::array::from_fn(|a| center[a] + outer),
        ),
        Shape::Cylinder { center, radius, z } => (
            std::array::from_fn(|a| if a < 2 { center[a] - radius } else { z[0] }),
            std::array::from_fn(|a| if a < 2 { center[a] + radius } else { z[1] }),
        ),
    }
}

/// Is a point inside a shape (closed sets)?
pub fn inside<const D: usize>(s: &Shape, x: &[f64; D]) -> bool {
    match s {
        Shape::Box { lower, upper } => (0..D).all(|a| x[a] >= lower[a] && x[a] <= upper[a]),
        Shape::Sphere { center, radius } => {
            (0..D).map(|a| (x[a] - center[a]).powi(2)).sum::<f64>() <= radius * radius
        }
        Shape::Annulus {
            center,
            inner,
            outer,
        } => {
            let r2: f64 = (0..D).map(|a| (x[a] - center[a]).powi(2)).sum();
            r2 >= inner * inner && r2 <= outer * outer
        }
        Shape::Cylinder { center, radius, z } => {
            (x[0] - center[0]).powi(2) + (x[1] - center[1]).powi(2) <= radius * radius
                && x[2] >= z[0]
                && x[2] <= z[1]
        }
    }
}

/// An array element as a fixed number of `f64` values, for permutation and the
/// migration and checkpoint record. Integers round-trip exactly (material indices are
/// u16, ids < 2^53).
pub trait Record: Copy {
    const WIDTH: usize;
    fn put(&self, out: &mut Vec<f64>);
    fn get(s: &[f64]) -> Self;
}

impl Record for f64 {
    const WIDTH: usize = 1;
    fn put(&self, out: &mut Vec<f64>) {
        out.push(*self);
    }
    fn get(s: &[f64]) -> Self {
        s[0]
    }
}

impl Record for u16 {
    const WIDTH: usize = 1;
    fn put(&self, out: &mut Vec<f64>) {
        out.push(f64::from(*self));
    }
    fn get(s: &[f64]) -> Self {
        s[0] as u16
    }
}

impl Record for u64 {
    const WIDTH: usize = 1;
    fn put(&self, out: &mut Vec<f64>) {
        out.push(*self as f64);
    }
    fn get(s: &[f64]) -> Self {
        s[0] as u64
    }
}

impl<const D: usize> Record for [f64; D] {
    const WIDTH: usize = D;
    fn put(&self, out: &mut Vec<f64>) {
        out.extend_from_slice(self);
    }
    fn get(s: &[f64]) -> Self {
        std::array::from_fn(|a| s[a])
    }
}

impl<const R: usize, const C: usize> Record for nalgebra::SMatrix<f64, R, C> {
    const WIDTH: usize = R * C;
    fn put(&self, out: &mut Vec<f64>) {
        out.extend_from_slice(self.as_slice());
    }
    fn get(s: &[f64]) -> Self {
        Self::from_column_slice(&s[..R * C])
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

    /// The radix order is the comparison sort's by (key, id), ids breaking ties: keys
    /// with many ties (few cells), keys spanning 41 bits (four passes), input sorted
    /// but for a few moved entries (the particles between two sorts), and 0 or 1 entry.
    #[test]
    fn order_by_key_then_id_is_the_sort_by_key_and_id() {
        let mut rng = decomposition::splitmix::Rng::new(7);
        let mut cases: Vec<(Vec<u64>, Vec<u64>)> = Vec::new();
        for (n, span) in [(5000, 40), (3000, 1u64 << 41), (0, 1), (1, 1)] {
            let keys = (0..n)
                .map(|_| 1000 + rng.below(span as usize) as u64)
                .collect();
            let mut ids: Vec<u64> = (0..n as u64).map(|k| 3 * k + 1).collect();
            for k in (1..ids.len()).rev() {
                ids.swap(k, rng.below(k + 1));
            }
            cases.push((keys, ids));
        }
        // Sorted by (key, id), then 50 entries given other keys.
        let (mut keys, mut ids): (Vec<u64>, Vec<u64>) = (0..4000u64).map(|k| (k / 9, k)).unzip();
        for _ in 0..50 {
            let k = rng.below(keys.len());
            keys[k] = rng.below(450) as u64;
            let j = rng.below(ids.len());
            ids.swap(k, j);
        }
        cases.push((keys, ids));
        let (mut order, mut spare) = (Vec::new(), Vec::new());
        for (keys, ids) in &cases {
            order_by_key_then_id(|p| keys[p as usize], ids, &mut order, &mut spare);
            let mut want: Vec<u32> = (0..keys.len() as u32).collect();
            want.sort_by_key(|&p| (keys[p as usize], ids[p as usize]));
            assert_eq!(order, want, "{} keys", keys.len());
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
