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
/// and the same share of their lattice box share their reference volume and mass,
/// which they need not store each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct KindPlan {
    /// The index of its material in [`Plan::materials`].
    pub material: usize,
    /// Particles per cell per axis.
    pub particles_per_cell: usize,
    /// The share of its lattice box its volume is, in [`cut_levels`]ths: all of it
    /// unless the body is seeded `cut` and the particle's box is cut by the surface.
    pub share: u32,
}

/// Points per axis of the sub-lattice that measures the part of a particle's box inside
/// a shape (`seeding = "cut"`): a box's share is known in `cut_samples^dim`ths, 256 in
/// 1D and 2D and 512 in 3D, which bounds the kinds such a body adds.
pub const fn cut_samples(dim: usize) -> u32 {
    match dim {
        1 => 256,
        2 => 16,
        _ => 8,
    }
}

/// The shares of a lattice box a cut particle may have, `cut_samples(dim)^dim`: a whole
/// box is `cut_levels(dim)` of them.
pub const fn cut_levels(dim: usize) -> u32 {
    cut_samples(dim).pow(dim as u32)
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
    /// Per `[[bodies]]` entry: the index of its kind in `kinds` (whole boxes).
    pub body_kind: Vec<usize>,
    /// Per `[[bodies]]` entry seeded `cut`: the index in `kinds` of its particles of
    /// share 1, followed by those of shares 2 to `cut_levels − 1` in order.
    pub body_cut_kinds: Vec<Option<usize>>,
    pub benchmark: Option<BenchmarkPlan>,
    /// A benchmark's body force is averaged over each particle's reference box
    /// (`[benchmark] body_force = "domain"`), not taken at its reference position.
    pub body_force_over_domain: bool,
    pub checkpoint: Option<CheckpointEvery>,
}
