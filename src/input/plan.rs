//! The parts of a scene that validation resolves into typed values, once: each
//! material's model with exactly the parameters it needs (no `Option` left to unwrap),
//! each body's material as an index, the benchmark with its defaults applied, and the
//! checkpoint schedule. The solver, the seeding, the benchmarks and the run loop read
//! these, never the raw `Option`s or names of the scene file.

/// A material's constitutive law with its own parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Law {
    /// `small`: the small-strain rate form ([`crate::input::scene::Strain::Small`]).
    LinearElastic {
        small: bool,
    },
    NeoHookean,
    /// J2 plasticity at finite strain with linear isotropic hardening.
    J2Plastic {
        yield_stress: f64,
        hardening: f64,
    },
    /// Linear elastic with tensile failure.
    Brittle {
        tensile_strength: f64,
    },
}

/// A validated material: elastic constants in range and its law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaterialPlan {
    pub density: f64,
    pub youngs_modulus: f64,
    pub poisson_ratio: f64,
    pub law: Law,
}

/// An exact-solution problem with its parameters (defaults applied).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BenchmarkPlan {
    /// A bar on `[bar[0], bar[1]]` along x, fixed at its lower end, in mode `mode`.
    VibratingBar {
        amplitude: f64,
        mode: u32,
        bar: [f64; 2],
    },
    /// The manufactured solution of the unit square/cube.
    AxisAlignedMms { amplitude: f64, c: f64 },
    /// The ring about `center`, in 2D.
    GeneralizedVortex {
        amplitude: f64,
        c: f64,
        center: [f64; 2],
    },
}

/// The checkpoint schedule of a validated `[checkpoint]` table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CheckpointEvery {
    Time(f64),
    Steps(u64),
    Seconds(f64),
}

/// A kind of particle: the particles of one material seeded with one count per cell
/// share their reference volume and mass, which they need not store each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct KindPlan {
    /// The index of its material in [`Plan::materials`].
    pub material: usize,
    /// Particles per cell per axis.
    pub particles_per_cell: usize,
}

/// Kinds a scene may have: a particle stores its kind's index in 16 bits.
pub const MAX_KINDS: usize = 1 << 16;

/// What validation resolved; built only by `scene::parse`, which refuses a scene
/// before it gets here.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Plan {
    /// One per `[[materials]]` entry, in order.
    pub materials: Vec<MaterialPlan>,
    /// The kinds of particle the bodies seed: each distinct pair of material and
    /// particles per cell, in the order the bodies first name it.
    pub kinds: Vec<KindPlan>,
    /// Per `[[bodies]]` entry: the index of its kind in `kinds`.
    pub body_kind: Vec<usize>,
    pub benchmark: Option<BenchmarkPlan>,
    pub checkpoint: Option<CheckpointEvery>,
}
