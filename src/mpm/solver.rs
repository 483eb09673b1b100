//! The explicit MPM step on one rank's block, for every gradient scheme and update
//! order. Physics never sees MPI: it calls the decomposition layer at fixed points
//! (ghost sum after particle→grid, ghost copy before grid→particle and before the
//! node→node stencils, migration after the position update).

use crate::input::scene::{Face, Scene, Update};
use crate::mpm::kernel::lanes::LANES;
use crate::mpm::kernel::{
    self, AvgRecord, NodeRecord, SlabOrder, VelRecord, FROM_MOMENTUM, UPDATED,
};
use crate::mpm::particles::{self, Carries, Kinds, Particles};
use crate::mpm::remap::remap;
use crate::physics::benchmark::{Benchmark, Memo};
use crate::physics::material::Material;
use crate::physics::shape::{Alpha, Geom, GradientScheme};
use crate::physics::tensor::{vector, Mat, Vector};
use decomposition::tiles::TILE_LOG;
use decomposition::{Block, Communicator, Layout, Migrator, Profile, Tiles, Traffic, TILE};
use rayon::prelude::*;
use std::time::Instant;

/// The read-only context of the particle loops, borrowed field by field from a solver.
macro_rules! ctx {
    ($s:ident) => {
        kernel::Ctx {
            geom: &$s.geom,
            node_lo: $s.block.node_lo,
            tiles: &$s.tiles,
            wide: $s.scheme.wide(),
            domain: $s.scheme.domain,
            alpha: $s.scheme.alpha,
            materials: &$s.materials,
            kind_mass: &$s.kinds.mass,
            kind_vol0: &$s.kinds.vol0,
            gravity: $s.gravity,
            body_force: $s
                .benchmark
                .as_ref()
                .filter(|b| b.has_body_force())
                .map(|b| b.at($s.t).with_memo(&$s.scratch.memo)),
            faces: $s.faces,
            walls: false,
        }
    };
}

/// The particle arrays of a solver as splittable slices.
macro_rules! slices {
    ($s:ident) => {
        kernel::Slices {
            parts: $s.parts.slices(),
            tile: &$s.place.ptile,
            accel: &$s.scratch.accel,
        }
    };
}

/// Call a particle loop monomorphised for the nodes a particle touches: 2 per axis for
/// hat functions, 3 for GIMP and the domain rule (`wide`).
macro_rules! by_nodes {
    ($wide:expr, $f:ident, $($arg:expr),*) => {
        match ($wide, D) {
            (false, 1) => kernel::$f::<D, 2, 2>($($arg),*),
            (false, 2) => kernel::$f::<D, 2, 4>($($arg),*),
            (false, _) => kernel::$f::<D, 2, 8>($($arg),*),
            (true, 1) => kernel::$f::<D, 3, 3>($($arg),*),
            (true, 2) => kernel::$f::<D, 3, 9>($($arg),*),
            (true, _) => kernel::$f::<D, 3, 27>($($arg),*),
        }
    };
}

/// `$nodes.$f::<NP>(args)` with `NP = PAD^D`, the padded tile's node count (array
/// lengths cannot be computed from a const generic on stable Rust).
macro_rules! by_pad {
    ($d:expr, $nodes:expr, $f:ident, $($arg:expr),* $(,)?) => {
        match $d {
            1 => $nodes.$f::<6>($($arg),*),
            2 => $nodes.$f::<36>($($arg),*),
            _ => $nodes.$f::<216>($($arg),*),
        }
    };
}

mod centroid;
mod clock;
mod diagnostics;
mod gather;
mod grid;
mod locate;
mod migrate;
mod null_space;
mod phases;
mod scatter;
mod setup;
mod stencils;

pub use clock::{Clock, Part};
pub use diagnostics::cell_integral;
pub use grid::FULL_FILL;
use locate::*;
pub use migrate::Load;
pub use null_space::NullSpace;
use phases::*;
use scatter::*;
use stencils::*;

/// Why a run cannot go on.
#[derive(Debug, Clone, PartialEq)]
pub enum Failure {
    /// Non-finite or non-physical state (NaN, J <= 0): the run became unstable.
    Unstable(String),
    /// A particle left a bounded grid.
    LeftGrid(String),
    /// Another rank failed; its own message says why.
    Elsewhere(String),
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::Unstable(m) => write!(f, "numerically unstable: {m}"),
            Failure::LeftGrid(m) => write!(f, "material left the grid: {m}"),
            Failure::Elsewhere(m) => write!(f, "{m}"),
        }
    }
}

/// Conserved and diagnostic totals over all ranks.
#[derive(Clone, Debug, Default)]
pub struct Totals {
    pub mass: f64,
    pub momentum: Vec<f64>,
    pub kinetic: f64,
    pub strain: f64,
    pub external_work: f64,
    /// Work dissipated by plastic flow.
    pub plastic_work: f64,
    pub particles: u64,
}

impl Totals {
    /// Kinetic plus stored energy minus the work done by external forces: constant for
    /// an exact integrator.
    pub fn total_energy(&self) -> f64 {
        self.kinetic + self.strain + self.plastic_work - self.external_work
    }
}

/// Corner offsets of a cell's 2^D nodes (bit `a` of the index = offset along axis `a`).
const CORNERS: usize = 8;

pub struct Solver<'c, const D: usize> {
    comm: &'c dyn Communicator,
    pub geom: Geom<D>,
    pub layout: Layout<D>,
    pub block: Block<D>,
    faces: [[Face; 2]; D],
    pub parts: Particles<D>,
    /// Per kind of particle: its material.
    pub materials: Vec<Material>,
    /// The kinds of particle: with `materials`, what each particle's kind index
    /// stands for (its reference volume and mass, [`particles::mass_of`]).
    pub kinds: Kinds,
    pub benchmark: Option<Benchmark<D>>,
    gravity: Vector<D>,
    /// The gradient scheme, resolved once: shape functions, α, two-step or not.
    pub scheme: GradientScheme,
    pub update: Update,
    /// The phases of a step: the update order's, resolved for the scheme.
    phases: Vec<Phase>,
    flip: f64,
    cfl: Option<f64>,
    fixed_dt: Option<f64>,
    pub end: f64,
    /// A time before `end` to land on exactly, like `end` (the next snapshot): the step
    /// that would pass it is shortened. Ignored unless `t < stop_at < end`.
    pub stop_at: f64,
    pub t: f64,
    pub step: u64,
    pub dt: f64,
    /// Times the block boundaries moved ([`Solver::relayout`]), restarts included.
    pub rebalances: u64,
    /// Where this rank's steps spent their time.
    pub clock: Clock,
    /// Halo and migration traffic of the blocks and migrators a rebalance replaced.
    traffic_before: (Traffic, Traffic),
    /// The imbalance [`Solver::rebalance`] found (of the particles, or by time of the
    /// ranks' measured work), or left if it moved the blocks.
    pub last_imbalance: f64,
    /// Balance by time: every rank's particles per second of work, averaged over the
    /// checks so far with the older ones' weight halved at each (empty before the
    /// first).
    speeds: Vec<f64>,
    /// Accumulated work of gravity, body forces and walls (this rank's particles).
    external_work: f64,
    /// Maximum of wave speed + particle speed after the last update: this rank's, or
    /// every rank's where `speed_agreed`.
    max_speed: f64,
    /// Whether `max_speed` is already the maximum over ranks: the step's closing
    /// reduction carries it, so that the next step size needs no reduction of its own.
    speed_agreed: bool,
    /// Which tiles of the local node box are stored, and where.
    pub tiles: Tiles<D>,
    /// XPIC's order m, if the scene asks for it (else FLIP/PIC by `flip`).
    xpic: Option<usize>,
    /// Passes of the centroid correction; 0 is off ([`Solver::centroid_velocity`]).
    centroid_passes: usize,
    /// A benchmark's body force is averaged over each particle's reference box
    /// ([`kernel::external_accel`]).
    body_force_over_domain: bool,
    /// β of the sharpening of the nodal averages L̄ and σ̄ toward their consistent-mass
    /// projection; 0 is off ([`NodeView::sharpen`]).
    sharpen: f64,
    /// The null-space diagnostic's state, if the scene asks for its field.
    pub null_space: Option<NullSpace<D>>,
    grid: GridFields<D>,
    place: Placement<D>,
    migrator: Migrator<D>,
    carries: Carries,
    scratch: Scratch<D>,
}

/// The grid's fields, node-major over the storage of the active tiles
/// ([`Solver::tiles`]): memory and every grid pass follow the tiles the particles touch,
/// not the box.
struct GridFields<const D: usize> {
    /// Scatter records, `sw` numbers per node laid out as [`NodeRecord`] says; once
    /// the grid velocities are formed, two-step schemes' L̄ and v̄ ([`avg_of`]).
    scat: Vec<f64>,
    sw: usize,
    /// Per node: velocity before (D) and after (D) the force update; before the grid
    /// update, two-step schemes' σ̄ ([`Solver::averaged_force`]).
    vel: Vec<f64>,
    /// Per node (D), XPIC only: the field `(m − 1) v − m v*` the gather adds to the
    /// updated grid velocity ([`Solver::xpic_field`]), and the recursion's current term
    /// (the field a scatter `from_grid` interpolates, which the null-space diagnostic
    /// also uses between steps).
    xpic_add: Vec<f64>,
    xpic_term: Vec<f64>,
    /// The centroid correction's fields, empty without it: per node the offset `d_i`
    /// of its mass centroid (D), the velocity or force it starts from (D), and a D × D
    /// tensor per node for the adjoint ([`Solver::centroid_force`]).
    centroid_d: Vec<f64>,
    centroid_base: Vec<f64>,
    centroid_tensor: Vec<f64>,
    /// Per node: its fill fraction `φ_k` (see [`Solver::domain_weights`]), copied to
    /// the ghosts.
    fill: Vec<f64>,
    /// Per node: the domain weight `w_c` of the cell whose lower corner it is.
    cell_w: Vec<f64>,
    /// Per owned node: `V_j = ∫ w S_j dv`.
    node_vol: Vec<f64>,
    /// Under sharpening, a copy of the averages being sharpened (`D²` or σ̄'s upper
    /// triangle per node), which the pass reads its neighbours from; else empty.
    sharp: Vec<f64>,
    /// `∫_c S_j ∇S_i dv` over one cell for its corners j (first index) and i (second).
    cell_k: [[[f64; D]; CORNERS]; CORNERS],
    /// `∫_c S_j S_i dv` over one cell for its corners j and i.
    cell_m: [[f64; CORNERS]; CORNERS],
    /// `Σ_i ∫_c S_j S_i dv (x_j − x_i)` over one cell for its corner j.
    cell_md: [[f64; D]; CORNERS],
    /// Node mass below which a node is treated as empty.
    mass_floor: f64,
}

/// Where the particles are: the tile pass's cells and runs, the slab order of the
/// coloured passes, and how far the particles are from their order by cell.
struct Placement<const D: usize> {
    /// Per particle: storage index of its cell's lower corner node (set by a scatter
    /// of moved particles, valid until they move again). The particle loops form the
    /// local coordinate in that cell from the position ([`kernel::Ctx::local`]).
    ptile: Vec<u32>,
    /// The tile pass's runs of particles in one cell, per chunk of [`LOCATE_CHUNK`]
    /// particles.
    cell_runs: Vec<Vec<CellRun<D>>>,
    /// Per chunk of `cell_runs`, the keys of the tiles its runs' nodes lie in (each
    /// once per chunk, mostly), gathered on threads and touched after.
    run_keys: Vec<Vec<u64>>,
    /// The particles grouped by slab for the scatter and the remap.
    slabs: SlabOrder,
    /// Whether the slab order's slabs and `cell_runs` hold the tile pass's
    /// location of every particle as it is now: `relocate` locates them with the wrap
    /// (one read of the positions, not two) and keeps it if none left or arrived; the
    /// sort, a new layout and the next tile pass, which uses it, end it.
    located: bool,
    /// Per chunk of [`LOCATE_CHUNK`] particles, whether one left the grid or its block
    /// ([`Solver::wrap_and_flag`]).
    flagged: Vec<bool>,
    /// How far this rank's particles are from their order by cell (by window with 3
    /// nodes per axis) after the step's move: the runs whose cell comes before the
    /// previous run's (the particles whose window comes before the previous one's), and
    /// the particles
    /// that arrived (appended at the end). A function of the particles' positions
    /// and order alone, so a restart sorts where the uninterrupted run did.
    disorder: usize,
    /// Per chunk of [`LOCATE_CHUNK`] particles, with 3 nodes per axis, how many
    /// particles' windows come before the previous particle's in the sort's order
    /// (their disorder: such particles are sorted by window, [`Solver::sort`]).
    window_descents: Vec<usize>,
    /// Sorts since the start (or the restart): what the tests ask of the criterion.
    sorts: u64,
}

impl<const D: usize> GridFields<D> {
    /// Empty, sized by [`Solver::setup_grid`].
    fn new() -> Self {
        GridFields {
            scat: Vec::new(),
            sw: 0,
            vel: Vec::new(),
            xpic_add: Vec::new(),
            xpic_term: Vec::new(),
            centroid_d: Vec::new(),
            centroid_base: Vec::new(),
            centroid_tensor: Vec::new(),
            fill: Vec::new(),
            cell_w: Vec::new(),
            node_vol: Vec::new(),
            sharp: Vec::new(),
            cell_k: [[[0.0; D]; CORNERS]; CORNERS],
            cell_m: [[0.0; CORNERS]; CORNERS],
            cell_md: [[0.0; D]; CORNERS],
            mass_floor: 0.0,
        }
    }
}

impl<const D: usize> Placement<D> {
    /// No particle located yet.
    fn new() -> Self {
        Placement {
            ptile: Vec::new(),
            cell_runs: Vec::new(),
            run_keys: Vec::new(),
            slabs: SlabOrder::new(),
            located: false,
            flagged: Vec::new(),
            disorder: 0,
            window_descents: Vec::new(),
            sorts: 0,
        }
    }
}

/// Scratch reused every step (no allocation in the loop once grown).
struct Scratch<const D: usize> {
    /// Which particles stay on this rank in a migration.
    keep: Vec<bool>,
    /// The particles that left the block and their new owners ([`Solver::route`]).
    routes: Vec<(usize, usize)>,
    /// A particle's record, packed for migration.
    record: Vec<f64>,
    /// The sort's permutation and its in-place application's marks.
    perm: Vec<u32>,
    permuted: Vec<u64>,
    /// The load balance's particle counts per cell slab.
    buf: Vec<f64>,
    /// Each particle's external force per unit mass, kept by the step's scatter of
    /// forces for the work counted after it, where the scene has a body force (else
    /// empty: gravity is one vector).
    accel: Vec<Vector<D>>,
    /// The benchmark's factors of each particle's reference position (benchmarks
    /// only), refreshed at the start of a step.
    memo: Memo<D>,
    /// Per chunk of particles, the sums of [`Solver::errors_keeping_forces`].
    error_sums: Vec<[f64; 3]>,
}

impl<const D: usize> Scratch<D> {
    fn new() -> Self {
        Scratch {
            keep: Vec::new(),
            routes: Vec::new(),
            record: Vec::new(),
            perm: Vec::new(),
            permuted: Vec::new(),
            buf: Vec::new(),
            accel: Vec::new(),
            memo: Memo::default(),
            error_sums: Vec::new(),
        }
    }
}

impl<'c, const D: usize> Solver<'c, D> {
    /// A solver at t = 0 with the scene's particles seeded in this rank's block.
    pub fn new(scene: &Scene, comm: &'c dyn Communicator, layout: Layout<D>) -> Self {
        let geom = Self::geometry(scene);
        let block = Block::new(&layout, comm.rank());
        let kinds = Kinds::of_scene(scene, &geom);
        let materials = kinds.materials(&Material::all(&scene.plan.materials));
        let benchmark = Benchmark::<D>::new(scene);
        let parts = Particles::seed(
            scene,
            &geom,
            (&kinds, &materials),
            benchmark.as_ref(),
            block.cell_lo,
            block.cell_hi,
        );
        let mut s = Self::with_particles(scene, comm, layout, parts);
        // Seeded in order by cell; with 3 nodes per axis the passes want them by window
        // ([`Solver::sort`]) from the first step.
        if s.scheme.wide() {
            s.sort();
        }
        s
    }

    /// What a restart needs besides the particles: this rank's accumulated external
    /// work and the fastest signal speed after the last step (over all ranks once a
    /// step has run).
    pub fn local_state(&self) -> (f64, f64) {
        (self.external_work, self.max_speed)
    }

    /// Continue from a checkpoint: time, step, last step size, this rank's share of the
    /// external work and the fastest signal speed the next step size derives from
    /// (any value that is the maximum over ranks gives the same step).
    pub fn restore(&mut self, t: f64, step: u64, dt: f64, external_work: f64, max_speed: f64) {
        // Located afresh at the next step.
        self.place.located = false;
        self.t = t;
        self.step = step;
        self.dt = dt;
        self.external_work = external_work;
        self.max_speed = max_speed;
        self.speed_agreed = false;
    }

    /// The mass of particle `p` ([`particles::mass_of`]).
    pub fn particle_mass(&self, p: usize) -> f64 {
        particles::mass_of(&self.kinds.mass, &self.parts.kind, p)
    }

    /// Which optional particle arrays this solver's particles carry.
    pub fn carries(&self) -> Carries {
        self.carries
    }

    /// What this rank has sent to other ranks since the solver was made: by the halo
    /// operations (ghost sums and copies, and the agreement on the halo chunks in use)
    /// and by particle migration, rebalances included (their blocks and migrators are
    /// replaced, so their counts are carried over).
    pub fn traffic(&self) -> (Traffic, Traffic) {
        let (mut halo, mut mig) = self.traffic_before;
        halo += self.block.traffic();
        mig += self.migrator.traffic();
        (halo, mig)
    }

    /// Advance one step. On failure the particle state is that of the failed step.
    pub fn advance(&mut self) -> Result<(), Failure> {
        self.advance_with(&mut [])
    }

    /// Advance one step and agree on up to three caller flags (values >= 0, e.g. "a
    /// signal arrived", "a checkpoint is due"): on success each holds its maximum over
    /// all ranks. They travel in the reduction every step makes anyway, so agreeing
    /// costs no extra message.
    pub fn advance_with(&mut self, flags: &mut [f64]) -> Result<(), Failure> {
        assert!(flags.len() <= 3, "at most three flags per step");
        let t0 = Instant::now();
        let dt = self.choose_dt()?;
        self.clock.add(Part::TimeStep, t0);
        let kick = self.kick(dt);
        self.dt = dt;
        if let Some(b) = &self.benchmark {
            self.scratch.memo.refresh(b, &self.parts.x0);
        }
        let mut ok = true;
        for k in 0..self.phases.len() {
            let t0 = Instant::now();
            ok &= self.run_phase(self.phases[k], dt, kick);
            self.clock.add(Part::of(self.phases[k]), t0);
        }
        // Valid for this step only (and the particle count may change below).
        self.scratch.accel.clear();
        self.t += dt;
        self.step += 1;
        let t0 = Instant::now();
        let left = self.route();
        self.clock.add(Part::Migrate, t0);
        // One reduction: the verdict, the caller's flags, the signal speed the next
        // step size follows from (migration and rebalancing move particles between
        // ranks but do not change the fastest one) and the lowest rank whose particles
        // cannot be handed over (as `size - rank`, so that the maximum finds it).
        let n = flags.len();
        let size = self.comm.size();
        let mut agree = [0.0; 6];
        agree[0] = if ok { 0.0 } else { 1.0 };
        agree[1..1 + n].copy_from_slice(flags);
        agree[1 + n] = self.max_speed;
        if self.migrator.failed() {
            agree[2 + n] = (size - self.comm.rank()) as f64;
        }
        let t0 = Instant::now();
        self.comm.max_f64(&mut agree[..3 + n]);
        self.clock.add(Part::Check, t0);
        flags.copy_from_slice(&agree[1..1 + n]);
        self.max_speed = agree[1 + n];
        self.speed_agreed = true;
        if agree[0] > 0.0 {
            return Err(Failure::Unstable(format!(
                "non-finite or inverted (J <= 0) particle state at step {}, t = {:.6e}",
                self.step, self.t
            )));
        }
        let failed = (agree[2 + n] > 0.0).then(|| size - agree[2 + n] as usize);
        let t0 = Instant::now();
        self.hand_over(failed, left)?;
        self.clock.add(Part::Migrate, t0);
        if self.place.disorder as f64 > SORT_DISORDER * self.parts.len() as f64 {
            let t0 = Instant::now();
            self.sort();
            self.clock.add(Part::Sort, t0);
        }
        Ok(())
    }

    /// Carry out one phase of a step (see [`Phase`]). Returns whether the particle state
    /// stayed physical.
    fn run_phase(&mut self, phase: Phase, dt: f64, kick: f64) -> bool {
        match phase {
            Phase::Scatter { forces, moved } => self.scatter(forces, moved),
            Phase::AveragedForce => self.averaged_force(),
            Phase::GridUpdate { forces } => self.grid_velocity(if forces { kick } else { 0.0 }),
            Phase::AveragedGradient { slot } => self.averaged_velocity_gradient(slot),
            Phase::Gather {
                stress,
                move_now,
                speed,
            } => return self.gather((dt, kick), stress, move_now, speed),
            Phase::Stress { slot, speed, moves } => {
                return self.update_stress_from(slot, dt, speed, moves)
            }
            Phase::XpicField => self.xpic_field(),
            Phase::Remap => return self.remap(dt, kick),
            Phase::CentroidOffsets => self.centroid_offsets(),
            Phase::CentroidForce => self.centroid_force(),
            Phase::CentroidVelocity { slot } => self.centroid_velocity(slot),
        }
        true
    }

    /// The velocity's step for a step of `dt`: the mean of this step and the last, and
    /// half of it on the first step. Velocities live half a step before positions
    /// (the particles' velocity after a step is the mean over it), so a step whose
    /// size changes is still centred (leapfrog with variable steps): with the step's
    /// own size the velocity gained an error of the order of the change in step
    /// size at every step, first order in dt over a run whose step follows the
    /// signal speed. A body in free fall lands on `½ g t²` exactly.
    pub fn kick(&self, dt: f64) -> f64 {
        if self.step == 0 {
            0.5 * dt
        } else {
            0.5 * (self.dt + dt)
        }
    }

    pub fn done(&self) -> bool {
        self.t >= self.end * (1.0 - 1e-12)
    }
}
