//! A whole run: set-up (fresh or from a checkpoint), the step loop with progress,
//! diagnostics, snapshots, checkpoints and stop signals, and the files it leaves in
//! the output folder (`summary.json`, `history.csv`).

use crate::driver::progress::Progress;
use crate::driver::signals;
use crate::input::plan::CheckpointEvery;
use crate::input::scene::{Balance, Face, Scene};
use crate::mpm::particles::Particles;
use crate::mpm::solver::{Failure, Solver, Totals};
use crate::output::checkpoint::{self, RunState, SolverState};
use crate::output::io::{agree, Labels, Snapshots};
use decomposition::{Communicator, Layout};
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

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

#[derive(Serialize, Debug, Clone)]
pub struct MassSummary {
    pub initial: f64,
    pub r#final: f64,
}

#[derive(Serialize, Debug, Clone)]
pub struct MomentumSummary {
    pub initial: Vec<f64>,
    pub r#final: Vec<f64>,
}

#[derive(Serialize, Debug, Clone)]
pub struct EnergySummary {
    pub initial_total: f64,
    pub final_total: f64,
    /// max_t |E(t) − E(0)| / max(|E(0)|, max_t (kinetic + strain)), E = kinetic + strain
    /// + plastic work − external work.
    pub max_relative_drift: f64,
    pub final_kinetic: f64,
    pub final_strain: f64,
    pub external_work: f64,
    /// Work dissipated by plastic flow (scenes with a `j2_plastic` material).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plastic_work: Option<f64>,
}

#[derive(Serialize, Debug, Clone)]
pub struct ErrorSummary {
    /// Maximum over all steps of the volume-weighted particle L2 norm.
    pub displacement_l2: f64,
    pub velocity_l2: f64,
    pub final_displacement_l2: f64,
    pub final_velocity_l2: f64,
}

/// Particles per rank at the end of the run (load balance).
#[derive(Serialize, Debug, Clone)]
pub struct RankLoad {
    pub min: u64,
    pub mean: f64,
    pub max: u64,
}

/// Collective: `min`, `mean` and `max` of a count over ranks.
fn rank_load(comm: &dyn Communicator, x: f64) -> RankLoad {
    let (mut lo, mut hi, mut sum) = ([x], [x], [x]);
    comm.min_f64(&mut lo);
    comm.max_f64(&mut hi);
    comm.sum_f64(&mut sum);
    RankLoad {
        min: lo[0] as u64,
        mean: sum[0] / comm.size() as f64,
        max: hi[0] as u64,
    }
}

/// The sparse grid at the end of the run: active tiles of `tile_nodes` nodes each,
/// summed over ranks and per rank, and what a dense grid would have needed.
#[derive(Serialize, Debug, Clone)]
pub struct GridSummary {
    pub tile_nodes: usize,
    pub active_tiles: u64,
    pub active_tiles_per_rank: RankLoad,
    /// Tiles that would cover the whole grid (a dense grid's storage, in tiles).
    pub box_tiles: f64,
}

/// How the blocks followed the load: the `[parallel]` settings, the rebalances
/// (the one at the start of a balanced run included), the block boundaries at the end
/// and the particle imbalance there (largest rank over the mean).
#[derive(Serialize, Debug, Clone)]
pub struct BalanceSummary {
    pub mode: String,
    pub threshold: f64,
    pub rebalances: u64,
    pub cuts: Vec<Vec<usize>>,
    pub imbalance: f64,
    /// Imbalance samples of this run (every `check_every` steps, after any move).
    pub checks: u64,
    pub imbalance_mean: f64,
    pub imbalance_max: f64,
    /// The share of the samples at most 1.10.
    pub within_10_percent: f64,
}

/// Every `check_every` steps: the particle imbalance is measured (one reduction), and
/// under `auto` the blocks move if it passes the threshold. The samples (after any
/// move) are the summary's record of how balanced the run was.
struct BalanceSchedule {
    every: u64,
    auto: Option<f64>,
    checks: u64,
    sum: f64,
    max: f64,
    within: u64,
}

/// The imbalance the summary counts as balanced: the 10 %.
const BALANCED: f64 = 1.10;

impl BalanceSchedule {
    fn of(scene: &Scene) -> Self {
        let p = &scene.parallel;
        Self {
            every: p.check_every,
            auto: (p.balance == Balance::Auto).then_some(p.imbalance),
            checks: 0,
            sum: 0.0,
            max: 0.0,
            within: 0,
        }
    }

    /// Collective at a check step: measure, rebalance under `auto`. Returns whether
    /// the blocks moved.
    fn check<const D: usize>(&mut self, solver: &mut Solver<D>) -> bool {
        if !solver.step.is_multiple_of(self.every) {
            return false;
        }
        let moved = match self.auto {
            Some(threshold) => solver.rebalance(threshold),
            None => {
                solver.last_imbalance = solver.imbalance();
                false
            }
        };
        let i = solver.last_imbalance;
        self.checks += 1;
        self.sum += i;
        self.max = self.max.max(i);
        self.within += u64::from(i <= BALANCED);
        moved
    }
}

/// Where a restarted run began.
#[derive(Serialize, Debug, Clone)]
pub struct RestartSummary {
    pub checkpoint: String,
    pub step: u64,
    pub time: f64,
    /// Particle rows of the checkpoint each rank read (all of its own writer's on
    /// the writer's process grid, else those of the writers whose blocks overlap).
    pub particle_rows_read: RankLoad,
}

#[derive(Serialize, Debug, Clone)]
pub struct Summary {
    pub scene: String,
    pub dim: usize,
    pub gradient: String,
    pub update: String,
    pub flip: f64,
    /// The XPIC order, when XPIC replaced the FLIP/PIC blend.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub xpic: Option<u32>,
    /// `SI`, or `dimensionless` for benchmark scenes (as in the snapshots).
    pub units: String,
    /// `completed`, `unstable` or `interrupted`.
    pub status: String,
    pub message: Option<String>,
    pub ranks: usize,
    pub threads: usize,
    pub blocks: Vec<usize>,
    pub particles_per_rank: RankLoad,
    pub balance: BalanceSummary,
    pub grid: GridSummary,
    pub particles: u64,
    pub cells: Vec<usize>,
    pub steps: u64,
    pub time: f64,
    pub end_time: f64,
    /// Wall time of this run (since its restart, if it was restarted).
    pub wall_seconds: f64,
    /// Over the steps of this run.
    pub particle_updates_per_second: f64,
    pub mass: MassSummary,
    pub momentum: MomentumSummary,
    pub energy: EnergySummary,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorSummary>,
    /// The newest checkpoint (written by this run, or the one it restarted from): what
    /// to restart from after an interruption or instability.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_checkpoint: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub restarted_from: Option<RestartSummary>,
    /// Wall time spent writing files, part of `wall_seconds`.
    pub output_seconds: OutputSeconds,
    /// Bytes and messages sent between ranks per step.
    pub halo: HaloSummary,
}

/// Wall time (rank 0's clock) spent writing snapshots and checkpoints.
#[derive(Serialize, Debug, Clone, Default)]
pub struct OutputSeconds {
    pub snapshots: f64,
    pub checkpoints: f64,
}

/// Point-to-point traffic between ranks per step, averaged over the steps of this run:
/// what the network would carry. A rank's exchange with itself (a periodic face it
/// owns both sides of) is a local copy and not counted, so one rank reports zeros.
#[derive(Serialize, Debug, Clone)]
pub struct HaloSummary {
    /// The steps averaged over.
    pub steps: u64,
    /// The grid's halo: ghost sums and copies of nodal fields.
    pub grid: TrafficSummary,
    /// Particles moving to the rank that owns their new cell.
    pub migration: TrafficSummary,
    /// Other ranks each rank shares grid nodes with (its halo and migration peers).
    pub peers_per_rank: Spread,
}

/// One kind of exchange, per step.
#[derive(Serialize, Debug, Clone)]
pub struct TrafficSummary {
    /// Exchanges per step, the same on every rank (each is a round of messages).
    pub exchanges_per_step: f64,
    /// Payload bytes a rank sent to other ranks per step.
    pub bytes_per_rank_per_step: Spread,
    /// Non-empty messages a rank sent to other ranks per step.
    pub messages_per_rank_per_step: Spread,
}

/// `min`, `mean` and `max` over ranks of a per-rank figure that need not be whole.
#[derive(Serialize, Debug, Clone)]
pub struct Spread {
    pub min: f64,
    pub mean: f64,
    pub max: f64,
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

/// Fewest steps between two history samples.
const DIAG_MIN_STEPS: u64 = 10;

/// `history.csv` on rank 0: the file, and its whole text so far (checkpoints carry it,
/// so that a restart continues the same file). Write errors are kept, not returned, so
/// that rank 0 does not leave the others waiting in a collective; the run loop agrees
/// on them.
struct History {
    file: Option<std::io::BufWriter<std::fs::File>>,
    path: PathBuf,
    text: Vec<u8>,
    error: Option<String>,
}

impl History {
    /// Collective: `history.csv` on rank 0, a new file with its header or, after a
    /// restart, the restored text up to the checkpoint; every rank learns of a failure.
    fn open<const D: usize>(
        comm: &dyn Communicator,
        out: &Path,
        solver: &Solver<D>,
        restored: Option<&RunState>,
    ) -> Result<Self, RunError> {
        let path = out.join("history.csv");
        let mut h = History {
            file: None,
            path: path.clone(),
            text: Vec::new(),
            error: None,
        };
        if comm.rank() == 0 {
            match std::fs::File::create(&path) {
                Ok(f) => h.file = Some(std::io::BufWriter::new(f)),
                Err(e) => h.error = Some(format!("{}: {e}", path.display())),
            }
            match restored {
                Some(st) => h.write(&String::from_utf8_lossy(&st.history)),
                None => h.write(&Self::header(solver)),
            }
        }
        if let Some(m) = agree(comm, h.error.clone()) {
            return Err(RunError::Io(m));
        }
        Ok(h)
    }

    /// The column names of a fresh file.
    fn header<const D: usize>(solver: &Solver<D>) -> String {
        let mut head = String::from("step,time,dt,kinetic,strain,external_work,total");
        for a in 0..D {
            head += &format!(",momentum_{a}");
        }
        for a in 0..D {
            head += &format!(",velocity_cm_{a}");
        }
        if solver.benchmark.is_some() {
            head += ",displacement_l2,velocity_l2";
        }
        if solver.carries().plastic {
            head += ",plastic_work";
        }
        head + "\n"
    }

    fn write(&mut self, s: &str) {
        if let Some(f) = &mut self.file {
            self.text.extend_from_slice(s.as_bytes());
            if let Err(e) = f.write_all(s.as_bytes()) {
                self.error
                    .get_or_insert(format!("{}: {e}", self.path.display()));
            }
        }
    }

    fn flush(&mut self) {
        if let Some(f) = &mut self.file {
            if let Err(e) = f.flush() {
                self.error
                    .get_or_insert(format!("{}: {e}", self.path.display()));
            }
        }
    }

    fn row<const D: usize>(&mut self, s: &Solver<D>, tot: &Totals, err: Option<(f64, f64)>) {
        if self.file.is_none() {
            return;
        }
        use std::fmt::Write as _;
        let mut l = String::new();
        let _ = write!(
            l,
            "{},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e}",
            s.step,
            s.t,
            s.dt,
            tot.kinetic,
            tot.strain,
            tot.external_work,
            tot.total_energy()
        );
        for a in 0..D {
            let _ = write!(l, ",{:.17e}", tot.momentum[a]);
        }
        for a in 0..D {
            let _ = write!(l, ",{:.17e}", tot.momentum[a] / tot.mass);
        }
        if let Some((u, v)) = err {
            let _ = write!(l, ",{u:.17e},{v:.17e}");
        }
        if s.carries().plastic {
            let _ = write!(l, ",{:.17e}", tot.plastic_work);
        }
        l.push('\n');
        self.write(&l);
    }
}

/// The solver and, after a restart, the run state, where it came from and the
/// checkpoint's lineage.
type SetUp<'c, const D: usize> = (
    Solver<'c, D>,
    Option<RunState>,
    Option<RestartSummary>,
    Option<String>,
);

/// A fresh solver, or one continuing from `opts.restart` (every rank agrees on errors).
fn set_up<'c, const D: usize>(
    scene: &Scene,
    comm: &'c dyn Communicator,
    layout: &Layout<D>,
    opts: &RunOptions,
) -> Result<SetUp<'c, D>, RunError> {
    let balance = scene.parallel.balance;
    let Some(path) = &opts.restart else {
        let mut solver = Solver::new(scene, comm, layout.clone());
        // Seeded in equal blocks, then cut for an equal share of the particles.
        if balance != Balance::Off {
            solver.rebalance(1.0);
        }
        return Ok((solver, None, None, None));
    };
    let geom = Solver::<D>::geometry(scene);
    let carries = crate::mpm::particles::Carries::for_scene(scene);
    // The writer's blocks when it ran on this process grid (so each rank reads its own
    // rows and the run continues bit for bit), unless balancing is off.
    let r = checkpoint::read_header(path).and_then(|h| {
        let layout = match h.layout(layout) {
            Some(l) if balance != Balance::Off => l,
            _ => layout.clone(),
        };
        checkpoint::read::<D>(
            &h,
            comm.rank(),
            &layout,
            &geom,
            carries,
            &crate::mpm::particles::Kinds::of_scene(scene, &geom),
        )
        .map(|x| (h, x, layout))
    });
    if let Some(m) = agree(comm, r.as_ref().err().cloned()) {
        return Err(RunError::Input(m));
    }
    let (header, restored, layout) = r.expect("agreed: no rank failed");
    // Every rank read the same header, so every rank decides alike.
    if header.time >= scene.time.end {
        return Err(RunError::Input(format!(
            "time.end = {:e} is not after the time of checkpoint {} (t = {:e}, step {}): nothing to run; restart with a scene whose time.end is later",
            scene.time.end,
            path.display(),
            header.time,
            header.step
        )));
    }
    let mut count = [restored.parts.len() as u64];
    comm.sum_u64(&mut count);
    if count[0] != header.particles {
        return Err(RunError::Input(format!(
            "{}: damaged checkpoint: {} of its {} particles lie in this run's cells",
            path.display(),
            count[0],
            header.particles
        )));
    }
    let rebalanced = Some(&layout) != header.layout(&layout).as_ref();
    let mut solver = Solver::with_particles(scene, comm, layout, restored.parts);
    let s = restored.solver;
    solver.restore(s.t, s.step, s.dt, s.external_work, s.max_speed);
    solver.rebalances = header.rebalances;
    // Another rank count or process grid: read in equal blocks, now cut to the load.
    if rebalanced && balance != Balance::Off {
        solver.rebalance(1.0);
    }
    let info = RestartSummary {
        checkpoint: path.display().to_string(),
        step: s.step,
        time: s.t,
        particle_rows_read: rank_load(comm, restored.rows_read as f64),
    };
    let mut run = restored.run;
    // A restart with an edited scene (longer, other step size, other output or
    // checkpoint intervals: see scene::restart_difference) reschedules its output from
    // the checkpoint's time; an unchanged scene keeps the stored schedule bit for bit.
    if opts.scene_text.as_deref() != Some(header.scene_text.as_str()) {
        let next = |every: f64| ((s.t / every + 1e-9).floor() + 1.0) * every;
        run.next_snapshot = scene
            .snapshot_plan()
            .filter(|o| o.every.is_finite())
            .map_or(f64::INFINITY, |o| next(o.every));
        run.next_checkpoint = match scene.plan.checkpoint {
            Some(CheckpointEvery::Time(every)) => next(every),
            _ => f64::INFINITY,
        };
    }
    Ok((solver, Some(run), Some(info), header.lineage))
}

fn run_dim<const D: usize>(
    scene: &Scene,
    comm: &dyn Communicator,
    opts: &RunOptions,
) -> Result<Summary, RunError> {
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
    let set_up = set_up::<D>(scene, comm, &layout, opts)?;
    let mut run = Run::start(scene, comm, opts, scene_text, set_up)?;
    let ending = run.steps()?;
    run.finish(ending)
}

/// Collective: create the output folder and lock it (rank 0); every rank learns of a
/// failure. Returns rank 0's lock (`None` elsewhere).
fn claim_output(
    comm: &dyn Communicator,
    out: &Path,
) -> Result<Option<crate::output::lock::Lock>, RunError> {
    let root = comm.rank() == 0;
    let made = if root {
        std::fs::create_dir_all(out)
            .err()
            .map(|e| format!("{}: {e}", out.display()))
    } else {
        None
    };
    if let Some(m) = agree(comm, made) {
        return Err(RunError::Io(m));
    }
    let (lock, locked) = match root.then(|| crate::output::lock::acquire(out)) {
        Some(Ok(l)) => (Some(l), None),
        Some(Err(e)) => (None, Some(e)),
        None => (None, None),
    };
    let held = matches!(locked, Some(crate::output::lock::LockError::Held(_)));
    let message = locked.map(|e| match e {
        crate::output::lock::LockError::Held(m) | crate::output::lock::LockError::Io(m) => m,
    });
    if let Some(m) = agree(comm, message) {
        return Err(if comm.any(held) {
            RunError::Input(m)
        } else {
            RunError::Io(m)
        });
    }
    Ok(lock)
}

/// Collective: rank 0 of a fresh run removes an earlier run's snapshots from the
/// locked output folder ([`crate::output::io::remove_old_snapshots`]) and says so (even under
/// `--quiet`: files were deleted); every rank
/// learns of a failure.
fn clear_old_snapshots(comm: &dyn Communicator, out: &Path) -> Result<(), RunError> {
    let failed = if comm.rank() == 0 {
        match crate::output::io::remove_old_snapshots(out) {
            Ok(0) => None,
            Ok(n) => {
                // Even with --quiet: files were deleted.
                say!(
                    "note: removed {n} snapshot(s) of an earlier run from {}",
                    out.display()
                );
                None
            }
            Err(m) => Some(format!("removing an earlier run's snapshots: {m}")),
        }
    } else {
        None
    };
    match agree(comm, failed) {
        Some(m) => Err(RunError::Io(m)),
        None => Ok(()),
    }
}

/// Collective: the checkpoint lineage of this run, `stored` (a restart's) or a fresh
/// one, which rank 0 makes and every rank receives. Pruning deletes only checkpoints of
/// this run and the runs it continues; rank 0 warns of the others in `out`.
fn lineage(
    comm: &dyn Communicator,
    out: &Path,
    stored: Option<String>,
    keep: usize,
) -> checkpoint::Lineage {
    let id = match stored {
        Some(id) => id,
        None => {
            let fresh = checkpoint::Lineage::fresh(keep).id;
            String::from_utf8_lossy(&comm.broadcast_bytes(fresh.as_bytes())).into_owned()
        }
    };
    let mut lineage = checkpoint::Lineage::continued(id, keep);
    if comm.rank() == 0 {
        let others = lineage.scan(out);
        if let (Some(first), Some(last)) = (others.first(), others.last()) {
            say!(
                "warning: {} holds {} checkpoint(s) of another run ({first} ... {last}); this run does not delete them",
                out.display(),
                others.len()
            );
        }
    }
    lineage
}

/// Snapshots at multiples of `every` in simulated time, which the steps land on; an
/// infinite `every` writes the initial and final states only.
struct SnapshotSchedule {
    writer: Snapshots,
    every: f64,
}

impl SnapshotSchedule {
    /// The scene's snapshots, `None` if it asks for none.
    fn of<const D: usize>(scene: &Scene, out: &Path) -> Option<Self> {
        scene.snapshot_plan().map(|o| Self {
            writer: Snapshots::new(out, &o.fields, Labels::of::<D>(scene)),
            every: o.every,
        })
    }

    /// Whether the step just taken reached the output time `next` (it landed on it, to
    /// round-off) or ended the run.
    fn due<const D: usize>(&self, solver: &Solver<D>, next: f64) -> bool {
        solver.t >= next - 1e-3 * solver.dt || solver.done()
    }

    /// The first output time after time `t` (step `dt`), from the current one `next`:
    /// k·every by one multiplication, since a sum of intervals would drift.
    fn after(&self, mut next: f64, t: f64, dt: f64) -> f64 {
        while next <= t + 1e-3 * dt {
            let k = ((next / self.every).round() + 1.0) * self.every;
            next = past(next, k, t, self.every);
        }
        next
    }

    /// Collective: write the particles now, adding the time taken to `seconds`.
    fn write<const D: usize>(
        &mut self,
        comm: &dyn Communicator,
        solver: &Solver<D>,
        seconds: &mut f64,
    ) -> Result<(), RunError> {
        let t0 = Instant::now();
        self.writer
            .write(
                comm,
                &solver.parts,
                (&solver.kinds, &solver.materials),
                solver.step,
                solver.t,
            )
            .map_err(|e| RunError::Io(e.to_string()))?;
        *seconds += t0.elapsed().as_secs_f64();
        Ok(())
    }
}

/// When to write checkpoints (the scene's `[checkpoint]` interval in simulated time,
/// steps or wall-clock seconds, or a stop signal) and which one is the newest.
struct CheckpointSchedule {
    every: Option<CheckpointEvery>,
    /// Wall clock since the last checkpoint, for `every_seconds`.
    clock: Instant,
    /// The newest checkpoint: written by this run, or the one it restarted from.
    last: Option<PathBuf>,
    /// The step of `last`.
    last_step: Option<u64>,
}

impl CheckpointSchedule {
    fn new(scene: &Scene, restart: Option<&PathBuf>, step: u64) -> Self {
        Self {
            every: scene.plan.checkpoint,
            clock: Instant::now(),
            last: restart.cloned(),
            last_step: restart.map(|_| step),
        }
    }

    /// The first checkpoint time of a fresh run (infinite unless the interval is in
    /// simulated time).
    fn first_time(&self) -> f64 {
        match self.every {
            Some(CheckpointEvery::Time(t)) => t,
            _ => f64::INFINITY,
        }
    }

    /// On rank 0: whether the wall-clock interval has passed. The ranks agree on it
    /// through [`Requests`].
    fn wall_due(&self) -> bool {
        matches!(self.every, Some(CheckpointEvery::Seconds(s))
            if self.clock.elapsed().as_secs_f64() >= s)
    }

    /// Whether to checkpoint after the step just taken: a stop signal asks for one, or
    /// the interval is reached (simulated time `next`, a multiple of the steps, or the
    /// agreed wall clock).
    fn due<const D: usize>(&self, solver: &Solver<D>, next: f64, req: &Requests) -> bool {
        req.signal() != 0
            || match self.every {
                Some(CheckpointEvery::Time(_)) => solver.t >= next - 1e-3 * solver.dt,
                Some(CheckpointEvery::Steps(n)) => solver.step.is_multiple_of(n),
                Some(CheckpointEvery::Seconds(_)) => req.wall_checkpoint(),
                None => false,
            }
    }

    /// The first checkpoint time after time `t` (step `dt`), from the current one
    /// `next`; unchanged unless the interval is in simulated time.
    fn after(&self, mut next: f64, t: f64, dt: f64) -> f64 {
        if let Some(CheckpointEvery::Time(every)) = self.every {
            while next <= t + 1e-3 * dt {
                next = past(next, next + every, t, every);
            }
        }
        next
    }

    /// A regular checkpoint of step `step` was written to `path`.
    fn written(&mut self, path: PathBuf, step: u64) {
        self.last = Some(path);
        self.last_step = Some(step);
        self.clock = Instant::now();
    }

    /// The newest checkpoint's path, or `""`.
    fn last_name(&self) -> String {
        self.last
            .as_ref()
            .map_or_else(String::new, |p| p.display().to_string())
    }
}

/// Requests every rank must agree on after a step. They travel with the step's own
/// reduction (a maximum): a stop signal (any rank), a wall-clock checkpoint (rank 0's
/// clock), a failed history write (rank 0).
struct Requests([f64; 3]);

impl Requests {
    fn new(signal: i32, wall_checkpoint: bool, history_failed: bool) -> Self {
        Self([
            f64::from(signal),
            f64::from(u8::from(wall_checkpoint)),
            f64::from(u8::from(history_failed)),
        ])
    }

    /// The stop signal some rank received (0: none).
    fn signal(&self) -> i32 {
        self.0[0] as i32
    }

    fn wall_checkpoint(&self) -> bool {
        self.0[1] > 0.0
    }

    fn history_failed(&self) -> bool {
        self.0[2] > 0.0
    }
}

/// History samples every thousandth of the run, but no closer than [`DIAG_MIN_STEPS`]
/// steps (each costs a pass over the particles), and one at the end.
struct HistorySchedule {
    every: f64,
}

impl HistorySchedule {
    fn of(scene: &Scene) -> Self {
        Self {
            every: scene.time.end / 1000.0,
        }
    }

    fn due<const D: usize>(&self, solver: &Solver<D>, st: &RunState) -> bool {
        (solver.t >= st.next_history && solver.step >= st.last_history_step + DIAG_MIN_STEPS)
            || solver.done()
    }
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
    /// Total energy at t = 0.
    e0: f64,
    /// The step this run started from (0, or the checkpoint's).
    step_start: u64,
    threads: usize,
    restarted_from: Option<RestartSummary>,
}

impl<'a, const D: usize> Run<'a, D> {
    /// Collective: the lineage, `history.csv` and the run state, restored or (fresh run)
    /// of the initial state, whose snapshot and history row are written.
    fn start(
        scene: &'a Scene,
        comm: &'a dyn Communicator,
        opts: &'a RunOptions,
        scene_text: String,
        (solver, restored, restarted_from, stored): SetUp<'a, D>,
    ) -> Result<Self, RunError> {
        let keep = scene.checkpoint.as_ref().map_or(2, |c| c.keep);
        let lineage = lineage(comm, &opts.out, stored, keep);
        let mut history = History::open(comm, &opts.out, &solver, restored.as_ref())?;
        let sampling = HistorySchedule::of(scene);
        let checkpoints = CheckpointSchedule::new(scene, opts.restart.as_ref(), solver.step);
        let mut snaps = SnapshotSchedule::of::<D>(scene, &opts.out);
        let start = Instant::now();
        let mut output_seconds = OutputSeconds::default();
        let st = match restored {
            Some(st) => resumed(comm, &opts.out, st, snaps.as_mut()),
            None => {
                if let Some(sn) = &mut snaps {
                    sn.write(comm, &solver, &mut output_seconds.snapshots)?;
                }
                let next_snapshot = snaps.as_ref().map_or(f64::INFINITY, |sn| sn.every);
                let st = initial(
                    &solver,
                    next_snapshot,
                    sampling.every,
                    checkpoints.first_time(),
                );
                history.row(&solver, &st.initial, st.last_err);
                st
            }
        };
        let root = comm.rank() == 0;
        let progress = Progress::new(root && !opts.quiet, opts.progress_every, start, solver.t);
        let mut rescue = Rescue::default();
        rescue.keep(&solver, &st, history.text.len());
        Ok(Self {
            scene,
            comm,
            opts,
            out: &opts.out,
            scene_text,
            e0: st.initial.total_energy(),
            step_start: solver.step,
            solver,
            st,
            history,
            sampling,
            balance: BalanceSchedule::of(scene),
            snaps,
            checkpoints,
            lineage,
            rescue,
            progress,
            start,
            output_seconds,
            threads: opts.threads,
            restarted_from,
        })
    }

    /// The step loop: until the end time, an instability or a stop signal, with the
    /// diagnostics and output each step calls for.
    fn steps(&mut self) -> Result<Ending, RunError> {
        let root = self.comm.rank() == 0;
        // The wall-clock interval counts from the first step, not from the set-up.
        self.checkpoints.clock = Instant::now();
        while !self.solver.done() {
            let wall_due = root && self.checkpoints.wall_due();
            // Snapshots at exact output times: the step that would pass one is shortened.
            self.solver.stop_at = self.st.next_snapshot;
            let mut req = Requests::new(signals::pending(), wall_due, self.history.error.is_some());
            if let Err(f) = self.solver.advance_with(&mut req.0) {
                return Ok(Ending::Unstable(f));
            }
            // Before anything is written, so that a checkpoint holds the layout the
            // run continues with.
            self.balance.check(&mut self.solver);
            if req.history_failed() {
                return Err(RunError::Io(self.history.error.take().unwrap_or_else(
                    || format!("{}: writing failed on rank 0", self.history.path.display()),
                )));
            }
            self.track_errors();
            if self.sampling.due(&self.solver, &self.st) {
                self.sample_history();
            }
            if let Some(sn) = &mut self.snaps {
                if sn.due(&self.solver, self.st.next_snapshot) {
                    sn.write(self.comm, &self.solver, &mut self.output_seconds.snapshots)?;
                    let s = &self.solver;
                    self.st.next_snapshot = sn.after(self.st.next_snapshot, s.t, s.dt);
                }
            }
            let due = self
                .checkpoints
                .due(&self.solver, self.st.next_checkpoint, &req);
            // A finished run needs no checkpoint.
            let checkpointed = due && !self.solver.done();
            if checkpointed {
                self.checkpoint()?;
            }
            // A checkpoint is a state to replay from, so the rescue is never older.
            if checkpointed || self.solver.step.is_multiple_of(RESCUE_EVERY) {
                self.rescue
                    .keep(&self.solver, &self.st, self.history.text.len());
            }
            let s = &self.solver;
            self.progress.tick(s.step, s.t, s.end, s.dt);
            if req.signal() != 0 && !self.solver.done() {
                return Ok(Ending::Stopped(req.signal()));
            }
        }
        Ok(Ending::Completed)
    }

    /// Benchmarks: the error norms after this step, and their maxima so far.
    fn track_errors(&mut self) {
        if self.solver.benchmark.is_none() {
            return;
        }
        self.st.last_err = self.solver.errors_keeping_forces();
        if let Some((u, v)) = self.st.last_err {
            self.st.max_err.0 = self.st.max_err.0.max(u);
            self.st.max_err.1 = self.st.max_err.1.max(v);
        }
    }

    /// Collective: the totals now, into the energy bounds and a row of `history.csv`.
    fn sample_history(&mut self) {
        let (s, st) = (&self.solver, &mut self.st);
        st.next_history = s.t + self.sampling.every;
        st.last_history_step = s.step;
        st.last = s.totals();
        st.energy_scale = st.energy_scale.max(st.last.kinetic + st.last.strain);
        st.max_energy_dev = st
            .max_energy_dev
            .max((st.last.total_energy() - self.e0).abs());
        self.history.row(s, &st.last, st.last_err);
    }

    /// Collective: a regular checkpoint of the state after this step.
    fn checkpoint(&mut self) -> Result<(), RunError> {
        let s = &self.solver;
        self.st.next_checkpoint = self.checkpoints.after(self.st.next_checkpoint, s.t, s.dt);
        self.history.flush();
        self.st.history = std::mem::take(&mut self.history.text);
        self.st.snapshots = self.snapshot_entries();
        let path = self.write_checkpoint()?;
        self.checkpoints.written(path, self.solver.step);
        Ok(())
    }

    /// The snapshots written so far.
    fn snapshot_entries(&self) -> Vec<crate::output::io::Entry> {
        self.snaps
            .as_ref()
            .map_or_else(Vec::new, |sn| sn.writer.entries().to_vec())
    }

    /// Collective: write the solver and `self.st` to a checkpoint; `self.st.history`
    /// holds `history.csv`'s text for the time of the write and gives it back.
    fn write_checkpoint(&mut self) -> Result<PathBuf, RunError> {
        let t0 = Instant::now();
        let written = checkpoint::write(
            self.comm,
            self.out,
            &self.solver,
            &self.st,
            &self.scene_text,
            &mut self.lineage,
        );
        self.output_seconds.checkpoints += t0.elapsed().as_secs_f64();
        self.history.text = std::mem::take(&mut self.st.history);
        written.map_err(|e| RunError::Io(e.to_string()))
    }

    /// Collective, after an instability: the failing rank's own reason on rank 0 (not
    /// "failed elsewhere"), and a checkpoint of the last state known good, since the
    /// failed state can be neither continued nor usefully inspected (unless a regular
    /// checkpoint already holds it). Returns the message.
    fn rescue(&mut self, failure: &Failure) -> Result<String, RunError> {
        let mine = match failure {
            Failure::Elsewhere(_) => String::new(),
            f => format!("rank {}: {f}", self.comm.rank()),
        };
        let all = self.comm.gather_bytes(mine.as_bytes());
        let reason = match all.iter().find(|m| !m.is_empty()) {
            Some(m) => String::from_utf8_lossy(m).into_owned(),
            None => failure.to_string(),
        };
        let good = self.rescue.solver;
        let mut how = String::new();
        if self.checkpoints.last_step != Some(good.step) {
            let t0 = Instant::now();
            let from = self.checkpoints.last_step.unwrap_or(0);
            if let Err(why) = self.replay(&good) {
                return Ok(format!(
                    "{reason}; {why}, so no checkpoint of the last good state (step {}) was \
                     written; the newest checkpoint is {}",
                    good.step,
                    match self.checkpoints.last_name() {
                        n if n.is_empty() => "none (restart from the scene)".to_string(),
                        n => n,
                    }
                ));
            }
            let history = &mut self.history.text;
            self.rescue.restore(&mut self.st, history);
            self.st.snapshots = self.snapshot_entries();
            self.st.snapshots.retain(|e| e.step <= good.step);
            self.checkpoints.last = Some(self.write_checkpoint()?);
            how = format!(
                " (replayed from step {from} in {:.1} s)",
                t0.elapsed().as_secs_f64()
            );
        }
        Ok(format!(
            "{reason}; the last good state (step {}, t = {:.6e}) is checkpointed in {}{how}",
            good.step,
            good.t,
            self.checkpoints.last_name()
        ))
    }

    /// Collective: the solver set up again from the newest checkpoint (or the scene)
    /// and stepped, writing nothing, to the rescue's state `good`. A run is
    /// deterministic on a given rank and thread count, and a restart continues it bit
    /// for bit, so this is the state the run had: kept this way rather than as a copy,
    /// which held as much memory as the particles themselves. `Err` says why
    /// the state was not reached (a stop signal, or a replay that did not reproduce
    /// the run, which would be a bug, or a set-up that failed).
    fn replay(&mut self, good: &SolverState) -> Result<(), String> {
        let from = self.checkpoints.last.clone();
        let opts = RunOptions {
            // A checkpoint of this run holds this scene text: none of its output is
            // rescheduled, as a restart from it would keep the stored schedule.
            scene_text: match &from {
                Some(p) if Some(p) != self.opts.restart.as_ref() => Some(self.scene_text.clone()),
                _ => self.opts.scene_text.clone(),
            },
            restart: from,
            ..self.opts.clone()
        };
        if self.comm.rank() == 0 && !opts.quiet {
            eprintln!(
                "replaying from step {} to step {} to checkpoint the last good state",
                self.checkpoints.last_step.unwrap_or(0),
                good.step
            );
        }
        // The failed particles go before the replay's are seeded or read; the rest of
        // the failed solver goes when the replay's replaces it, before its first step
        // (measured: the replay's peak is then below the failed run's).
        self.solver.parts = Particles::default();
        // Every rank reaches the same error (a checkpoint removed since, say).
        let set = layout_for::<D>(self.scene, self.comm.size())
            .and_then(|layout| set_up::<D>(self.scene, self.comm, &layout, &opts));
        let (solver, restored, _, _) = match set {
            Ok(s) => s,
            Err(e) => return Err(format!("setting the run up again to replay it failed: {e}")),
        };
        self.solver = solver;
        let mut next_snapshot = match (&restored, &self.snaps) {
            (Some(st), _) => st.next_snapshot,
            (None, Some(sn)) => sn.every,
            (None, None) => f64::INFINITY,
        };
        // Its own tally: the summary's is of the run.
        let mut balance = BalanceSchedule::of(self.scene);
        while self.solver.step < good.step {
            // The loop of `steps`, for what changes the state: the steps cut at
            // snapshot times, and the rebalancing.
            self.solver.stop_at = next_snapshot;
            let mut req = Requests::new(signals::pending(), false, false);
            if let Err(f) = self.solver.advance_with(&mut req.0) {
                return Err(format!(
                    "replaying the run failed at step {} ({f})",
                    self.solver.step
                ));
            }
            balance.check(&mut self.solver);
            if let Some(sn) = &self.snaps {
                if sn.due(&self.solver, next_snapshot) {
                    let s = &self.solver;
                    next_snapshot = sn.after(next_snapshot, s.t, s.dt);
                }
            }
            if req.signal() != 0 {
                return Err(format!(
                    "{} stopped the replay at step {}",
                    signals::name(req.signal()),
                    self.solver.step
                ));
            }
        }
        let s = &self.solver;
        let (external_work, max_speed) = s.local_state();
        let same = s.step == good.step
            && s.t.to_bits() == good.t.to_bits()
            && s.dt.to_bits() == good.dt.to_bits()
            && external_work.to_bits() == good.external_work.to_bits()
            && max_speed.to_bits() == good.max_speed.to_bits();
        let mut differs = [f64::from(u8::from(!same))];
        self.comm.max_f64(&mut differs);
        if differs[0] > 0.0 {
            return Err(format!(
                "replaying the run did not reproduce its state at step {}",
                good.step
            ));
        }
        Ok(())
    }

    /// After a stop signal: where to continue from.
    fn stop_message(&self, signal: i32) -> String {
        let last = self.checkpoints.last_name();
        let restart = match self.checkpoints.last {
            Some(_) => last.clone(),
            None => "CHECKPOINT".to_string(),
        };
        format!(
            "stopped by {} after step {} (t = {:.6e}); the last checkpoint is {last}: continue with `mpmcg run --restart {restart}`",
            signals::name(signal),
            self.solver.step,
            self.solver.t,
        )
    }

    /// Collective: the rescue checkpoint of an unstable run, the summary (written by
    /// rank 0) and the outcome.
    fn finish(mut self, ending: Ending) -> Result<Summary, RunError> {
        // The final totals: the last sample's, unless the loop broke off.
        let last = match ending {
            Ending::Completed => self.st.last.clone(),
            _ => self.solver.totals(),
        };
        // Of the run as it ended: the rescue replaces the solver.
        let end = (self.solver.step, self.solver.t);
        let wall = self.start.elapsed().as_secs_f64();
        let mut summary = self.summary(&last, end, wall);
        let (status, message) = match &ending {
            Ending::Completed => ("completed", None),
            Ending::Unstable(f) => ("unstable", Some(self.rescue(f)?)),
            Ending::Stopped(signal) => ("interrupted", Some(self.stop_message(*signal))),
        };
        self.progress.finish();
        summary.status = status.into();
        summary.message.clone_from(&message);
        summary.last_checkpoint = self
            .checkpoints
            .last
            .as_ref()
            .map(|p| p.display().to_string());
        summary.output_seconds = self.output_seconds.clone();
        let failed = self.history.error.take();
        write_summary(self.comm, self.out, &summary, failed)?;
        match ending {
            Ending::Completed => Ok(summary),
            Ending::Unstable(_) => Err(RunError::Unstable(message.unwrap_or_default())),
            Ending::Stopped(_) => Err(RunError::Interrupted(message.unwrap_or_default())),
        }
    }

    /// Collective: the summary of the run that ended at `end` (step, time) with the
    /// totals `last`, after `wall` seconds; its status and message are the caller's.
    fn summary(&mut self, last: &Totals, (steps, time): (u64, f64), wall: f64) -> Summary {
        let (particles_per_rank, grid) = self.loads(last.particles);
        let imbalance = self.solver.imbalance();
        let halo = self.traffic();
        self.history.flush();
        let (scene, solver, tot0) = (self.scene, &self.solver, &self.st.initial);
        Summary {
            scene: scene.name.clone(),
            dim: D,
            gradient: scene.method.gradient.name().into(),
            update: scene.method.update.name().into(),
            flip: scene.method.flip,
            xpic: scene.method.xpic,
            units: Labels::of::<D>(scene).units,
            status: String::new(),
            message: None,
            ranks: self.comm.size(),
            threads: self.threads,
            blocks: solver.layout.procs.to_vec(),
            particles_per_rank,
            balance: BalanceSummary {
                mode: scene.parallel.balance.name().into(),
                threshold: scene.parallel.imbalance,
                rebalances: solver.rebalances,
                cuts: (0..D).map(|a| solver.layout.cuts(a).to_vec()).collect(),
                imbalance,
                checks: self.balance.checks,
                imbalance_mean: self.balance.sum / self.balance.checks.max(1) as f64,
                imbalance_max: self.balance.max,
                within_10_percent: self.balance.within as f64 / self.balance.checks.max(1) as f64,
            },
            grid,
            particles: tot0.particles,
            cells: scene.grid.cells.clone(),
            steps,
            time,
            end_time: scene.time.end,
            wall_seconds: wall,
            particle_updates_per_second: tot0.particles as f64
                * (solver.step - self.step_start) as f64
                / wall.max(1e-9),
            mass: MassSummary {
                initial: tot0.mass,
                r#final: last.mass,
            },
            momentum: MomentumSummary {
                initial: tot0.momentum.clone(),
                r#final: last.momentum.clone(),
            },
            energy: self.energy(last),
            error: self.errors(),
            last_checkpoint: self
                .checkpoints
                .last
                .as_ref()
                .map(|p| p.display().to_string()),
            restarted_from: self.restarted_from.clone(),
            output_seconds: self.output_seconds.clone(),
            halo,
        }
    }

    /// Collective: per-step traffic between ranks over this run's steps, spread over
    /// ranks. Three reductions of five numbers, once per run.
    fn traffic(&self) -> HaloSummary {
        let (comm, solver) = (self.comm, &self.solver);
        let steps = solver.step - self.step_start;
        let (halo, mig) = solver.traffic();
        let me = comm.rank();
        let peers = solver.block.peers().iter().filter(|&&p| p != me).count();
        let per_step = |x: u64| x as f64 / steps.max(1) as f64;
        let mine = [
            per_step(halo.bytes),
            per_step(halo.messages),
            per_step(mig.bytes),
            per_step(mig.messages),
            peers as f64,
        ];
        let (mut lo, mut hi, mut sum) = (mine, mine, mine);
        comm.min_f64(&mut lo);
        comm.max_f64(&mut hi);
        comm.sum_f64(&mut sum);
        let n = comm.size() as f64;
        let spread = |k: usize| Spread {
            min: lo[k],
            mean: sum[k] / n,
            max: hi[k],
        };
        HaloSummary {
            steps,
            grid: TrafficSummary {
                exchanges_per_step: per_step(halo.exchanges),
                bytes_per_rank_per_step: spread(0),
                messages_per_rank_per_step: spread(1),
            },
            migration: TrafficSummary {
                exchanges_per_step: per_step(mig.exchanges),
                bytes_per_rank_per_step: spread(2),
                messages_per_rank_per_step: spread(3),
            },
            peers_per_rank: spread(4),
        }
    }

    /// Collective: particles and active grid tiles per rank; `particles` in all.
    fn loads(&self, particles: u64) -> (RankLoad, GridSummary) {
        let (comm, solver) = (self.comm, &self.solver);
        let mut lo = [solver.parts.len() as f64, solver.tiles.active() as f64];
        let mut hi = lo;
        let mut sum = [solver.tiles.active() as u64];
        comm.min_f64(&mut lo);
        comm.max_f64(&mut hi);
        comm.sum_u64(&mut sum);
        let ranks = comm.size() as f64;
        let particles = RankLoad {
            min: lo[0] as u64,
            mean: particles as f64 / ranks,
            max: hi[0] as u64,
        };
        let grid = GridSummary {
            tile_nodes: solver.tiles.tile_nodes(),
            active_tiles: sum[0],
            active_tiles_per_rank: RankLoad {
                min: lo[1] as u64,
                mean: sum[0] as f64 / ranks,
                max: hi[1] as u64,
            },
            box_tiles: self
                .scene
                .grid
                .cells
                .iter()
                .map(|&c| (c + 1).div_ceil(decomposition::TILE) as f64)
                .product(),
        };
        (particles, grid)
    }

    /// The energy balance, from the initial state to `last`.
    fn energy(&self, last: &Totals) -> EnergySummary {
        let st = &self.st;
        EnergySummary {
            initial_total: self.e0,
            final_total: last.total_energy(),
            max_relative_drift: if st.energy_scale > 0.0 {
                st.max_energy_dev / st.energy_scale
            } else {
                0.0
            },
            final_kinetic: last.kinetic,
            final_strain: last.strain,
            external_work: last.external_work,
            plastic_work: self.solver.carries().plastic.then_some(last.plastic_work),
        }
    }

    /// Benchmarks: the largest and the final error norms.
    fn errors(&self) -> Option<ErrorSummary> {
        let st = &self.st;
        self.solver.benchmark.is_some().then(|| {
            let (fu, fv) = st.last_err.unwrap_or((f64::NAN, f64::NAN));
            ErrorSummary {
                displacement_l2: st.max_err.0,
                velocity_l2: st.max_err.1,
                final_displacement_l2: fu,
                final_velocity_l2: fv,
            }
        })
    }
}

/// Collective: a restored run state, keeping the earlier snapshots that are in this
/// output folder (rank 0 decides, every rank keeps the same list).
fn resumed(
    comm: &dyn Communicator,
    out: &Path,
    mut st: RunState,
    snaps: Option<&mut SnapshotSchedule>,
) -> RunState {
    if let Some(sn) = snaps {
        let root = comm.rank() == 0;
        let mask: Vec<u8> = st
            .snapshots
            .iter()
            .map(|e| u8::from(root && out.join(e.file()).is_file()))
            .collect();
        let mask = comm.broadcast_bytes(&mask);
        let mut k = 0;
        st.snapshots.retain(|_| {
            k += 1;
            mask[k - 1] == 1
        });
        sn.writer.set_entries(st.snapshots.clone());
    }
    st
}

/// Collective: the run state of a fresh run, from the initial totals and errors, with
/// the first snapshot, history sample and checkpoint at these times.
fn initial<const D: usize>(
    solver: &Solver<D>,
    next_snapshot: f64,
    next_history: f64,
    next_checkpoint: f64,
) -> RunState {
    let tot0 = solver.totals();
    let err0 = solver.errors();
    RunState {
        energy_scale: tot0.total_energy().abs().max(tot0.kinetic + tot0.strain),
        max_energy_dev: 0.0,
        max_err: err0.unwrap_or((0.0, 0.0)),
        last_err: err0,
        next_history,
        last_history_step: 0,
        next_snapshot,
        next_checkpoint,
        snapshots: Vec::new(),
        history: Vec::new(),
        last: tot0.clone(),
        initial: tot0,
    }
}

/// Collective: rank 0 writes `summary.json`, unless writing `history.csv` `failed`.
/// No rank leaves before rank 0 has written everything: mpirun ends the whole job as
/// soon as one rank exits with a non-zero status.
fn write_summary(
    comm: &dyn Communicator,
    out: &Path,
    summary: &Summary,
    failed: Option<String>,
) -> Result<(), RunError> {
    let mut written = failed;
    if comm.rank() == 0 && written.is_none() {
        let path = out.join("summary.json");
        let text = serde_json::to_string_pretty(summary).expect("summary serialises");
        // Via a temporary file: a full disk leaves the previous summary (or none), never
        // a truncated one.
        let tmp = out.join(".summary.json.tmp");
        written = std::fs::write(&tmp, text + "\n")
            .and_then(|()| std::fs::rename(&tmp, &path))
            .err()
            .map(|e| {
                let _ = std::fs::remove_file(&tmp);
                format!("{}: {e}", path.display())
            });
    }
    if let Some(m) = agree(comm, written) {
        return Err(RunError::Io(m));
    }
    Ok(())
}

/// The next output time `next` after `last` on a grid of `every`, or, where `every`
/// is too small against the time to advance it in floating point (scene validation
/// bounds the number of outputs, so only a hand-made checkpoint gets here), the first
/// representable time after `t`: the schedule loops always end.
fn past(last: f64, next: f64, t: f64, every: f64) -> f64 {
    if next > last {
        next
    } else {
        (t + every).max(t.next_up())
    }
}

/// Steps between the states kept for [`Rescue`].
const RESCUE_EVERY: u64 = 10;

/// The newest state known good (at most [`RESCUE_EVERY`] steps old, never older than
/// the newest checkpoint): a run that turns unstable checkpoints this, since the
/// failed step's own state is non-finite or outside the grid and can be neither
/// continued nor usefully inspected. Only what is not in the particles: those are
/// replayed ([`Run::replay`]), and the solver's state here checks the replay.
#[derive(Default)]
struct Rescue {
    solver: SolverState,
    run: Option<RunState>,
    history_len: usize,
}

impl Rescue {
    /// Keep the state after the current step; no allocation once the buffers have grown.
    fn keep<const D: usize>(&mut self, solver: &Solver<D>, st: &RunState, history_len: usize) {
        let (external_work, max_speed) = solver.local_state();
        self.solver = SolverState {
            t: solver.t,
            step: solver.step,
            dt: solver.dt,
            external_work,
            max_speed,
        };
        match &mut self.run {
            Some(r) => r.clone_from(st),
            None => self.run = Some(st.clone()),
        }
        self.history_len = history_len;
    }

    /// Put the kept run state and `history.csv`'s text back (the solver has been
    /// replayed to the kept step).
    fn restore(&mut self, st: &mut RunState, history: &mut Vec<u8>) {
        if let Some(r) = &self.run {
            st.clone_from(r);
        }
        history.truncate(self.history_len);
        st.history = std::mem::take(history);
    }
}
