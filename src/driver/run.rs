//! A whole run: set-up (fresh or from a checkpoint), the step loop with progress,
//! diagnostics, snapshots, checkpoints and stop signals, and the files it leaves in
//! the output folder (`summary.json`, `history.csv`).

use crate::driver::progress::Progress;
use crate::input::scene::{Face, Scene};
use crate::mpm::particles::{Carries, Particles};
use crate::mpm::solver::{Failure, Solver};
use crate::output::checkpoint::{self, RunState};
use decomposition::{Communicator, Layout, Timed};
use history::History;
use rescue::Rescue;
use schedules::{BalanceSchedule, CheckpointSchedule, HistorySchedule, SnapshotSchedule};
use setup::{claim_output, clear_old_snapshots, set_up};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod history;
mod profile;
mod rescue;
mod schedules;
mod setup;
mod spread;
mod steps;
mod summary;

pub use profile::{table as profile_table, Blocked, PartSeconds, ProfileSummary};
pub use spread::Spread;
pub use summary::{
    BalanceSummary, EnergySummary, ErrorSummary, GridSummary, HaloSummary, MassSummary,
    MomentumSummary, OutputSeconds, RankLoad, RestartSummary, Summary, TrafficSummary,
};

#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    pub out: PathBuf,
    pub quiet: bool,
    pub threads: usize,
    /// The scene file's text, stored verbatim in checkpoints (`None`: the scene is
    /// serialised again, which keeps its content but not its comments and layout).
    pub scene_text: Option<String>,
    /// Continue from this checkpoint; the scene must be the one it stores.
    pub restart: Option<PathBuf>,
    /// Seconds between progress updates (`None`: 0.5 on a terminal, 10 in a log).
    pub progress_every: Option<f64>,
    /// Print where the steps' time went at the end (`summary.json` has it anyway).
    pub profile: bool,
}

/// How a run ended, for the exit status.
#[derive(Debug)]
pub enum RunError {
    /// Bad input discovered at set-up, including an unusable checkpoint (exit 2).
    Input(String),
    /// The run became unstable; the summary says so (exit 3).
    Unstable(String),
    /// Stopped by SIGTERM or SIGINT after writing a checkpoint; the summary says
    /// "interrupted" (exit 4).
    Interrupted(String),
    /// Files could not be written (exit 1).
    Io(String),
}

impl RunError {
    /// The process exit status for this outcome.
    pub fn exit_code(&self) -> u8 {
        match self {
            RunError::Input(_) => 2,
            RunError::Unstable(_) => 3,
            RunError::Interrupted(_) => 4,
            RunError::Io(_) => 1,
        }
    }
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunError::Input(m)
            | RunError::Unstable(m)
            | RunError::Interrupted(m)
            | RunError::Io(m) => f.write_str(m),
        }
    }
}

/// Run a validated scene on `comm`'s ranks. Returns the summary (written on rank 0).
pub fn run(scene: &Scene, comm: &dyn Communicator, opts: &RunOptions) -> Result<Summary, RunError> {
    match scene.dim {
        1 => run_dim::<1>(scene, comm, opts),
        2 => run_dim::<2>(scene, comm, opts),
        3 => run_dim::<3>(scene, comm, opts),
        d => Err(RunError::Input(format!("dim must be 1, 2 or 3, got {d}"))),
    }
}

/// The input checks that need the grid: every body seeds at least one particle (a body
/// outside the grid, or smaller than the particle spacing, would run to "completed" with
/// nothing in it), and no two bodies seed particles at the same place (overlapping
/// bodies would double the mass there). `mpmcg check` and every fresh run make them.
pub fn check_bodies(scene: &Scene) -> Result<(), String> {
    match scene.dim {
        1 => check_bodies_dim::<1>(scene),
        2 => check_bodies_dim::<2>(scene),
        _ => check_bodies_dim::<3>(scene),
    }
}

/// The particles the scene's bodies seed over the whole grid, for `mpmcg check`; the
/// count stops at `stop_at`.
pub fn particle_count(scene: &Scene, stop_at: u64) -> u64 {
    match scene.dim {
        1 => particle_count_dim::<1>(scene, stop_at),
        2 => particle_count_dim::<2>(scene, stop_at),
        _ => particle_count_dim::<3>(scene, stop_at),
    }
}

fn particle_count_dim<const D: usize>(scene: &Scene, stop_at: u64) -> u64 {
    let all = ([0; D], std::array::from_fn(|a| scene.grid.cells[a]));
    count_seeded_in::<D>(scene, all, stop_at)
}

/// The particles the scene's bodies seed in the cells `[lo, hi)`
/// ([`Particles::count_seeded`]); the count stops at `stop_at`.
fn count_seeded_in<const D: usize>(
    scene: &Scene,
    cells: ([usize; D], [usize; D]),
    stop_at: u64,
) -> u64 {
    let geom = Solver::<D>::geometry(scene);
    let benchmark = crate::physics::benchmark::Benchmark::<D>::new(scene);
    Particles::<D>::count_seeded(scene, &geom, benchmark.as_ref(), cells, stop_at)
}

/// The bytes of one of the scene's particles' state ([`Particles::state_bytes`]).
pub fn particle_state_bytes(scene: &Scene) -> u64 {
    let carries = Carries::for_scene(scene);
    match scene.dim {
        1 => Particles::<1>::state_bytes(carries),
        2 => Particles::<2>::state_bytes(carries),
        _ => Particles::<3>::state_bytes(carries),
    }
}

fn check_bodies_dim<const D: usize>(scene: &Scene) -> Result<(), String> {
    let geom = Solver::<D>::geometry(scene);
    for (i, b) in scene.bodies.iter().enumerate() {
        if !crate::mpm::particles::seeds_any::<D>(b, &geom) {
            let spacing =
                geom.h.iter().cloned().fold(f64::INFINITY, f64::min) / b.particles_per_cell as f64;
            return Err(format!(
                "bodies[{i}] (material \"{}\") seeds no particle: it lies outside the grid \
                 or between the particle lattice points (spacing {spacing:.3e} at \
                 particles_per_cell = {}); move it into the grid, enlarge it, or raise \
                 particles_per_cell",
                b.material, b.particles_per_cell
            ));
        }
        for (j, a) in scene.bodies[..i].iter().enumerate() {
            if let Some(x) = crate::mpm::particles::overlap::<D>(a, b, &geom) {
                return Err(format!(
                    "bodies[{j}] and bodies[{i}] overlap (both contain the particle position \
                     {x:?}): both would seed particles there, doubling the mass; make them \
                     disjoint"
                ));
            }
        }
    }
    Ok(())
}

fn layout_for<const D: usize>(scene: &Scene, ranks: usize) -> Result<Layout<D>, RunError> {
    let cells: [usize; D] = std::array::from_fn(|a| scene.grid.cells[a]);
    let periodic: [bool; D] =
        std::array::from_fn(|a| scene.grid.boundary.face(a, false) == Face::Periodic);
    Layout::choose(cells, periodic, ranks)
        .map_err(|e| RunError::Input(format!("cannot run on {ranks} ranks: {e}")))
}

fn run_dim<const D: usize>(
    scene: &Scene,
    comm: &dyn Communicator,
    opts: &RunOptions,
) -> Result<Summary, RunError> {
    // Every collective and exchange of the run counted and timed.
    let timed = Timed::new(comm);
    let comm: &dyn Communicator = &timed;
    let layout = layout_for::<D>(scene, comm.size())?;
    if opts.restart.is_none() {
        check_bodies(scene).map_err(RunError::Input)?;
    }
    // One run at a time in a folder; the lock goes when `_lock` is dropped, on every
    // path out of this function.
    let _lock = claim_output(comm, &opts.out)?;
    if opts.restart.is_none() {
        clear_old_snapshots(comm, &opts.out)?;
    }
    let scene_text = match &opts.scene_text {
        Some(t) => t.clone(),
        None => toml::to_string(scene).unwrap_or_default(),
    };
    let t0 = Instant::now();
    let set_up = set_up::<D>(scene, comm, &layout, opts)?;
    let setup_seconds = t0.elapsed().as_secs_f64();
    let mut run = Run::start(scene, &timed, opts, scene_text, set_up)?;
    run.timing.setup_seconds = setup_seconds;
    let ending = run.steps()?;
    run.finish(ending)
}

/// How the step loop ended.
enum Ending {
    Completed,
    Unstable(Failure),
    /// By this stop signal, after a checkpoint.
    Stopped(i32),
}

/// A run under way: the solver, the state a checkpoint keeps, the output schedules and
/// what the summary reports.
struct Run<'a, const D: usize> {
    scene: &'a Scene,
    comm: &'a dyn Communicator,
    /// `comm`, with its counts and times.
    timed: &'a Timed<'a>,
    opts: &'a RunOptions,
    out: &'a Path,
    /// Stored verbatim in checkpoints.
    scene_text: String,
    solver: Solver<'a, D>,
    st: RunState,
    history: History,
    sampling: HistorySchedule,
    balance: BalanceSchedule,
    snaps: Option<SnapshotSchedule>,
    checkpoints: CheckpointSchedule,
    lineage: checkpoint::Lineage,
    rescue: Rescue,
    progress: Progress,
    start: Instant,
    output_seconds: OutputSeconds,
    timing: profile::Timing,
    /// Total energy at t = 0.
    e0: f64,
    /// The step this run started from (0, or the checkpoint's).
    step_start: u64,
    threads: usize,
    restarted_from: Option<RestartSummary>,
}
