//! The keys of a scene file: the serde structures and enums a scene deserialises into,
//! with their defaults.

use crate::input::plan::Plan;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    pub name: String,
    pub dim: usize,
    pub time: Time,
    #[serde(default)]
    pub method: Method,
    pub grid: GridSpec,
    pub materials: Vec<MaterialSpec>,
    pub bodies: Vec<BodySpec>,
    pub benchmark: Option<BenchmarkSpec>,
    pub gravity: Option<Gravity>,
    pub output: Option<Output>,
    pub checkpoint: Option<CheckpointSpec>,
    #[serde(default)]
    pub parallel: Parallel,
    /// What validation resolved (filled by [`parse`](super::parse), not a key of the file).
    #[serde(skip)]
    pub plan: Plan,
    /// The version of the defaults the absent keys took ([`DEFAULTS`] for a new run; a
    /// restart keeps its checkpoint's), not a key of the file.
    #[serde(skip)]
    pub defaults: u32,
}

/// `[parallel]`: how the grid's blocks follow the material over ranks.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Parallel {
    /// `off`: equal blocks; `static`: blocks cut once at the start for an equal share
    /// of the particles; `auto`: that, and again whenever the imbalance passes
    /// `imbalance`; `time`: like `auto`, weighing each rank's work by its measured time.
    #[serde(default = "default_balance")]
    pub balance: Balance,
    /// The largest rank's load over the mean above which `auto` and `time` rebalance
    /// (particles under `auto`, seconds of work under `time`).
    #[serde(default = "default_imbalance")]
    pub imbalance: f64,
    /// Steps between two checks of the imbalance under `auto` (one reduction each).
    #[serde(default = "default_check_every")]
    pub check_every: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Balance {
    Off,
    Static,
    Auto,
    Time,
}

impl Balance {
    pub fn name(self) -> &'static str {
        match self {
            Balance::Off => "off",
            Balance::Static => "static",
            Balance::Auto => "auto",
            Balance::Time => "time",
        }
    }
}

fn default_balance() -> Balance {
    Balance::Auto
}
/// Rebalance at 5 % above the mean: the target is 10 % for most of a run, and
/// the imbalance grows between checks.
fn default_imbalance() -> f64 {
    1.05
}
fn default_check_every() -> u64 {
    20
}

impl Default for Parallel {
    fn default() -> Self {
        Self {
            balance: default_balance(),
            imbalance: default_imbalance(),
            check_every: default_check_every(),
        }
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Time {
    pub end: f64,
    pub cfl: Option<f64>,
    pub dt: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Gradient {
    Mpm,
    Gimp,
    Averaged,
    Mpmcg,
}

impl Gradient {
    pub const ALL: [Gradient; 4] = [
        Gradient::Mpm,
        Gradient::Gimp,
        Gradient::Averaged,
        Gradient::Mpmcg,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Gradient::Mpm => "mpm",
            Gradient::Gimp => "gimp",
            Gradient::Averaged => "averaged",
            Gradient::Mpmcg => "mpmcg",
        }
    }
}

/// Where MPMCG integrates its internal force and velocity gradient over a particle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Quadrature {
    /// At the particle's position.
    #[default]
    Point,
    /// Exactly over the particle's current domain, the box of half-widths
    /// `l0 |F e_a|` (at most half a cell): docs/schemes.md, "The domain rule".
    Domain,
}

impl Quadrature {
    pub fn name(self) -> &'static str {
        match self {
            Quadrature::Point => "point",
            Quadrature::Domain => "domain",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Update {
    Usl,
    Usf,
    Musl,
}

impl Update {
    pub fn name(self) -> &'static str {
        match self {
            Update::Usl => "usl",
            Update::Usf => "usf",
            Update::Musl => "musl",
        }
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Method {
    #[serde(default = "default_gradient")]
    pub gradient: Gradient,
    #[serde(default = "default_update")]
    pub update: Update,
    /// 1 = FLIP, 0 = PIC, in between a blend.
    #[serde(default = "default_flip")]
    pub flip: f64,
    /// The order m of XPIC(m) (Hammerquist & Nairn 2017) in place of the FLIP update
    /// of particle velocities: FLIP with its grid-invisible noise filtered out, at the
    /// cost of m − 1 more particle → grid passes per step. Off when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xpic: Option<u32>,
    /// MPMCG's quadrature of the internal force and the velocity gradient. When absent,
    /// see [`Method::resolve`]. Always written out, so that a scene written by one
    /// version reads the same in any other.
    #[serde(default)]
    pub quadrature: Quadrature,
    /// Passes of the centroid correction (MUSL, two-step schemes): the remapped grid
    /// velocity is the particles' at their mass centroid `x_i + d_i`, and each pass
    /// moves it towards the node, `v ← v₀ − L̄(v) d_i`; the grid force is its adjoint.
    /// 0 is off: docs/schemes.md, "The centroid correction".
    #[serde(default)]
    pub centroid_passes: u32,
    /// β of the sharpening of the two-step schemes' nodal averages L̄ and σ̄,
    /// `φ ← (1 + β) φ − β S φ` with `S` the consistent mass's smoothing: it cancels most
    /// of their phase error. 0 is off: docs/schemes.md, "Sharpening".
    #[serde(default)]
    pub sharpen: f64,
}

/// The version of the scene defaults a new run takes; checkpoints record theirs, so
/// that a restart resolves its stored scene as the run that wrote it did.
/// 1: every scheme at the particle (point rule), no centroid passes, no sharpening.
/// 2: MPMCG with the domain rule, `sharpen = 1` (with the domain rule) and, under MUSL
/// without XPIC, 4 centroid passes (docs/schemes.md, "Defaults"); the other schemes as
/// in 1.
pub const DEFAULTS: u32 = 2;

/// Scene defaults 1, every scheme in its plain form: what a checkpoint written before
/// the attribute existed was run with, and what a test that names each variant it
/// measures parses under.
pub const PLAIN_DEFAULTS: u32 = 1;

impl Method {
    /// The keys whose absence [`Method::resolve`] fills, by the other keys and the
    /// version of the defaults.
    pub const RESOLVED: [&'static str; 3] = ["quadrature", "centroid_passes", "sharpen"];

    /// Give each of [`Method::RESOLVED`] that `given` says is absent its value under the
    /// scene defaults `version`: under 2, MPMCG's robust and accurate settings (the
    /// particle noise of the point rule tears beams that MPM keeps whole); under
    /// [`PLAIN_DEFAULTS`] every scheme's plain form, as runs before version 2 had it.
    pub fn resolve(&mut self, version: u32, given: impl Fn(&str) -> bool) {
        let mpmcg = version > PLAIN_DEFAULTS && self.gradient == Gradient::Mpmcg;
        if !given("quadrature") {
            self.quadrature = if mpmcg {
                Quadrature::Domain
            } else {
                Quadrature::Point
            };
        }
        if !given("centroid_passes") {
            let musl = self.update == Update::Musl && self.xpic.is_none();
            self.centroid_passes = if mpmcg && musl { 4 } else { 0 };
        }
        if !given("sharpen") {
            // With the point rule sharpening amplifies the quadrature's noise.
            let domain = self.quadrature == Quadrature::Domain;
            self.sharpen = if mpmcg && domain { 1.0 } else { 0.0 };
        }
    }
}

fn default_gradient() -> Gradient {
    Gradient::Mpmcg
}
/// MUSL: its velocity gradient comes from remapped particle momentum, which stays
/// bounded at nodes that carry little mass (free surfaces). With USL those nodes' force
/// updates can blow up the grid-averaged gradient of `averaged` and `mpmcg`.
fn default_update() -> Update {
    Update::Musl
}
fn default_flip() -> f64 {
    1.0
}

impl Default for Method {
    fn default() -> Self {
        Self {
            gradient: default_gradient(),
            update: default_update(),
            flip: default_flip(),
            xpic: None,
            quadrature: Quadrature::Point,
            centroid_passes: 0,
            sharpen: 0.0,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Face {
    /// Every velocity component is zero on the face.
    #[default]
    Fixed,
    /// The normal velocity component is zero on the face.
    Slip,
    /// No constraint; material must not leave the grid.
    Free,
    /// The face is glued to the opposite one.
    Periodic,
}

#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Boundary {
    pub x_lower: Option<Face>,
    pub x_upper: Option<Face>,
    pub y_lower: Option<Face>,
    pub y_upper: Option<Face>,
    pub z_lower: Option<Face>,
    pub z_upper: Option<Face>,
}

impl Face {
    pub fn name(self) -> &'static str {
        match self {
            Face::Fixed => "fixed",
            Face::Slip => "slip",
            Face::Free => "free",
            Face::Periodic => "periodic",
        }
    }
}

impl Boundary {
    pub(super) const KEYS: [&'static str; 6] = [
        "x_lower", "x_upper", "y_lower", "y_upper", "z_lower", "z_upper",
    ];
    pub(super) fn get(&self, k: usize) -> Option<Face> {
        [
            self.x_lower,
            self.x_upper,
            self.y_lower,
            self.y_upper,
            self.z_lower,
            self.z_upper,
        ][k]
    }
    /// Face type of axis `a`, side `upper`; unlisted faces are `fixed`.
    pub fn face(&self, a: usize, upper: bool) -> Face {
        self.get(2 * a + usize::from(upper)).unwrap_or_default()
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    pub cells: Vec<usize>,
    #[serde(default)]
    pub boundary: Boundary,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Model {
    LinearElastic,
    NeoHookean,
    /// J2 plasticity at finite strain with linear isotropic hardening.
    J2Plastic,
    /// Linear elastic with tensile failure.
    Brittle,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    pub name: String,
    pub model: Model,
    pub density: f64,
    pub youngs_modulus: f64,
    pub poisson_ratio: f64,
    /// Initial yield stress (`j2_plastic`).
    pub yield_stress: Option<f64>,
    /// Linear isotropic hardening modulus (`j2_plastic`, default 0).
    pub hardening: Option<f64>,
    /// Largest principal stress before failure (`brittle`).
    pub tensile_strength: Option<f64>,
    /// `linear_elastic`'s strain: `finite` (default) or `small`.
    pub strain: Option<Strain>,
}

/// The strain of `linear_elastic`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Strain {
    /// The Jaumann rate of the Kirchhoff stress: objective, and keeps its energy.
    Finite,
    /// `σ̇ = λ tr D I + 2μ D` on the Cauchy stress: the linear theory of the
    /// verification problems (vibrating bar), neither objective nor energy-conserving
    /// at finite strain.
    Small,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    Box {
        lower: Vec<f64>,
        upper: Vec<f64>,
    },
    /// A disk in 2D, an interval in 1D.
    Sphere {
        center: Vec<f64>,
        radius: f64,
    },
    /// The ring `inner <= |x - center| <= outer` (2D).
    Annulus {
        center: Vec<f64>,
        inner: f64,
        outer: f64,
    },
    /// A cylinder along z (3D): axis through `center` = [x, y], from `z[0]` to `z[1]`.
    Cylinder {
        center: Vec<f64>,
        radius: f64,
        z: Vec<f64>,
    },
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    pub material: String,
    pub shape: Shape,
    /// Particles per cell along each direction.
    #[serde(default = "default_ppc")]
    pub particles_per_cell: usize,
    pub velocity: Option<Vec<f64>>,
    /// A linear initial velocity field added to `velocity`: `v += value · (x − about)`.
    pub velocity_gradient: Option<VelocityGradient>,
    /// How the particles of the cells the shape's surface cuts are made.
    #[serde(default)]
    pub seeding: Seeding,
}

/// How a body's particles are seeded: each sits in its own box of the lattice, `1/n`
/// of a cell per axis for `n` particles per cell.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Seeding {
    /// A particle of the box's full volume at its centre, where the centre lies in the
    /// shape: a curved surface is seeded as a staircase, and the body's volume is the
    /// shape's only to first order in the spacing.
    #[default]
    Lattice,
    /// A particle of the volume of the box's part inside the shape, at that part's
    /// centroid (both from a sub-lattice of the box, [`crate::input::plan::cut_samples`]
    /// points per axis): the body has the shape's volume, centroid and moments of inertia
    /// to second order. Boxes of the interior are seeded as `lattice` seeds them.
    Cut,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct VelocityGradient {
    /// Rows of the gradient: `value[i][j] = ∂v_i/∂x_j`.
    pub value: Vec<Vec<f64>>,
    /// The point where this part of the velocity vanishes (default: the origin).
    pub about: Option<Vec<f64>>,
}

fn default_ppc() -> usize {
    2
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BenchmarkKind {
    VibratingBar,
    AxisAlignedMms,
    GeneralizedVortex,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BenchmarkSpec {
    pub kind: BenchmarkKind,
    pub amplitude: Option<f64>,
    pub mode: Option<u32>,
    pub c: Option<f64>,
    /// Where each particle's body force is taken: at its reference position (`point`,
    /// the default) or averaged over its reference box (`domain`: 2^D Gauss points,
    /// exact for a force cubic in the reference position). Benchmarks with a body
    /// force only.
    pub body_force: Option<Quadrature>,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Gravity {
    pub value: Vec<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Field {
    Velocity,
    Stress,
    Displacement,
    /// Equivalent plastic strain (scenes with a `j2_plastic` material).
    PlasticStrain,
    /// Damage (scenes with a `brittle` material).
    Damage,
    /// The part of each particle's velocity the grid cannot see (what is left after
    /// projecting the velocities onto the grid with the consistent mass); asking for
    /// it also adds its kinetic energy to `history.csv` as `null_kinetic`.
    NullVelocity,
    /// Each particle's current volume, `J V₀` (seeded `cut`, the particles of the cells
    /// the surface cuts stand for less than the others).
    Volume,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Output {
    /// Simulated time between snapshots; `None`: only the initial and final states.
    pub every: Option<f64>,
    /// `None`: velocity and stress.
    pub fields: Option<Vec<Field>>,
    /// `Some(false)`: no snapshots at all (`every` and `fields` must then be absent).
    pub snapshots: Option<bool>,
}

/// The snapshots a run writes.
#[derive(Debug, Clone, PartialEq)]
pub struct SnapshotPlan {
    /// Simulated time between snapshots (infinite: the initial and final states only).
    pub every: f64,
    pub fields: Vec<Field>,
}

impl Scene {
    /// What the scene asks to write: `None` for `[output] snapshots = false`. Without
    /// `[output]` a run still writes its initial and final states, so that every run
    /// leaves something to look at.
    pub fn snapshot_plan(&self) -> Option<SnapshotPlan> {
        let o = self.output.as_ref();
        if o.and_then(|o| o.snapshots) == Some(false) {
            return None;
        }
        Some(SnapshotPlan {
            every: o.and_then(|o| o.every).unwrap_or(f64::INFINITY),
            fields: o
                .and_then(|o| o.fields.clone())
                .unwrap_or_else(|| vec![Field::Velocity, Field::Stress]),
        })
    }
}

/// When to write restart checkpoints: exactly one of `every` (simulated time),
/// `every_steps` or `every_seconds` (wall clock), keeping the last `keep` files.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CheckpointSpec {
    /// Simulated time between checkpoints.
    pub every: Option<f64>,
    /// Steps between checkpoints.
    pub every_steps: Option<u64>,
    /// Wall-clock seconds between checkpoints (rank 0's clock decides).
    pub every_seconds: Option<f64>,
    /// How many of the newest checkpoints to keep (older ones are deleted).
    #[serde(default = "default_keep")]
    pub keep: usize,
}

fn default_keep() -> usize {
    2
}

/// The variant names of a unit-variant enum, as serde spells them.
pub(super) fn variants<T: serde::de::DeserializeOwned>() -> &'static [&'static str] {
    use serde::de::{Error, Visitor};
    use std::cell::Cell;
    struct Probe<'a>(&'a Cell<&'static [&'static str]>);
    impl<'de> serde::Deserializer<'de> for Probe<'_> {
        type Error = serde::de::value::Error;
        fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Self::Error> {
            Err(Self::Error::custom("not an enum"))
        }
        fn deserialize_enum<V: Visitor<'de>>(
            self,
            _: &'static str,
            variants: &'static [&'static str],
            _: V,
        ) -> Result<V::Value, Self::Error> {
            self.0.set(variants);
            Err(Self::Error::custom("probe"))
        }
        serde::forward_to_deserialize_any! {
            bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
            byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map
            struct identifier ignored_any
        }
    }
    let cell = Cell::new(&[][..]);
    let _ = T::deserialize(Probe(&cell));
    cell.get()
}
