//! A whole run: set-up (fresh or from a checkpoint), the step loop with progress,
//! diagnostics, snapshots, checkpoints and stop signals, and the files it leaves in
//! the output folder (`summary.json`, `history.csv`).

use crate::checkpoint::{self, RunState, SolverState};
use crate::io::{agree, Labels, Snapshots};
use crate::particles::Particles;
use crate::progress::Progress;
use crate::scene::{CheckpointEvery, Face, Scene};
use crate::signals;
use crate::solver::{Failure, Solver, Totals};
use decomposition::{Communicator, Layout};
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;
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

/// Where a restarted run began.
#[derive(Serialize, Debug, Clone)]
pub struct RestartSummary {
    pub checkpoint: String,
    pub step: u64,
    pub time: f64,
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
}

/// Wall time (rank 0's clock) spent writing snapshots and checkpoints.
#[derive(Serialize, Debug, Clone, Default)]
pub struct OutputSeconds {
    pub snapshots: f64,
    pub checkpoints: f64,
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
        if !crate::particles::seeds_any::<D>(b, &geom) {
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
            if let Some(x) = crate::particles::overlap::<D>(a, b, &geom) {
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
    let Some(path) = &opts.restart else {
        return Ok((Solver::new(scene, comm, layout.clone()), None, None, None));
    };
    let geom = Solver::<D>::geometry(scene);
    let carries = crate::particles::Carries::for_scene(scene);
    let r = checkpoint::read_header(path).and_then(|h| {
        checkpoint::read::<D>(&h, comm.rank(), layout, &geom, carries).map(|x| (h, x))
    });
    if let Some(m) = agree(comm, r.as_ref().err().cloned()) {
        return Err(RunError::Input(m));
    }
    let (header, restored) = r.expect("agreed: no rank failed");
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
    let mut solver = Solver::with_particles(scene, comm, layout.clone(), restored.parts);
    let s = restored.solver;
    solver.restore(s.t, s.step, s.dt, s.external_work, s.max_speed);
    let info = RestartSummary {
        checkpoint: path.display().to_string(),
        step: s.step,
        time: s.t,
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
        run.next_checkpoint = match scene.checkpoint.as_ref().map(|c| c.schedule()) {
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
    let root = comm.rank() == 0;
    let made = if root {
        std::fs::create_dir_all(&opts.out)
            .err()
            .map(|e| format!("{}: {e}", opts.out.display()))
    } else {
        None
    };
    if let Some(m) = agree(comm, made) {
        return Err(RunError::Io(m));
    }
    // One run at a time in a folder; the lock goes when `_lock` is dropped, on every
    // path out of this function.
    let (_lock, locked) = match root.then(|| crate::lock::acquire(&opts.out)) {
        Some(Ok(l)) => (Some(l), None),
        Some(Err(e)) => (None, Some(e)),
        None => (None, None),
    };
    let held = matches!(locked, Some(crate::lock::LockError::Held(_)));
    let message = locked.map(|e| match e {
        crate::lock::LockError::Held(m) | crate::lock::LockError::Io(m) => m,
    });
    if let Some(m) = agree(comm, message) {
        return Err(if comm.any(held) {
            RunError::Input(m)
        } else {
            RunError::Io(m)
        });
    }
    let scene_text = match &opts.scene_text {
        Some(t) => t.clone(),
        None => toml::to_string(scene).unwrap_or_default(),
    };
    let schedule = scene.checkpoint.as_ref().map(|c| c.schedule());
    let keep = scene.checkpoint.as_ref().map_or(2, |c| c.keep);
    let (mut solver, restored, restarted_from, stored) = set_up::<D>(scene, comm, &layout, opts)?;
    // Pruning deletes only checkpoints of this run and the runs it continues.
    let id = match stored {
        Some(id) => id,
        None => {
            let fresh = checkpoint::Lineage::fresh(keep).id;
            String::from_utf8_lossy(&comm.broadcast_bytes(fresh.as_bytes())).into_owned()
        }
    };
    let mut lineage = checkpoint::Lineage::continued(id, keep);
    if root {
        let others = lineage.scan(&opts.out);
        if let (Some(first), Some(last)) = (others.first(), others.last()) {
            eprintln!(
                "warning: {} holds {} checkpoint(s) of another run ({first} ... {last}); this run does not delete them",
                opts.out.display(),
                others.len()
            );
        }
    }
    let has_bench = solver.benchmark.is_some();
    let diag_dt = scene.time.end / 1000.0;

    // history.csv: a new file, or the restored one up to the checkpoint.
    let hpath = opts.out.join("history.csv");
    let mut history = History {
        file: None,
        path: hpath.clone(),
        text: Vec::new(),
        error: None,
    };
    if root {
        match std::fs::File::create(&hpath) {
            Ok(f) => history.file = Some(std::io::BufWriter::new(f)),
            Err(e) => history.error = Some(format!("{}: {e}", hpath.display())),
        }
        match &restored {
            Some(st) => {
                let text = String::from_utf8_lossy(&st.history).into_owned();
                history.write(&text);
            }
            None => {
                let mut head = String::from("step,time,dt,kinetic,strain,external_work,total");
                for a in 0..D {
                    head += &format!(",momentum_{a}");
                }
                for a in 0..D {
                    head += &format!(",velocity_cm_{a}");
                }
                if has_bench {
                    head += ",displacement_l2,velocity_l2";
                }
                if solver.carries().plastic {
                    head += ",plastic_work";
                }
                history.write(&(head + "\n"));
            }
        }
    }
    if let Some(m) = agree(comm, history.error.clone()) {
        return Err(RunError::Io(m));
    }

    // (writer, interval); an infinite interval writes the initial and final states.
    let mut snaps = scene.snapshot_plan().map(|o| {
        (
            Snapshots::new(&opts.out, &o.fields, Labels::of::<D>(scene)),
            o.every,
        )
    });
    let start = Instant::now();
    let mut output_seconds = OutputSeconds::default();
    let mut st = match restored {
        Some(mut st) => {
            if let Some((sn, _)) = &mut snaps {
                // Keep the earlier snapshots that are in this output folder (rank 0
                // decides, every rank keeps the same list).
                let mask: Vec<u8> = st
                    .snapshots
                    .iter()
                    .map(|e| u8::from(root && opts.out.join(e.file()).is_file()))
                    .collect();
                let mask = comm.broadcast_bytes(&mask);
                let mut k = 0;
                st.snapshots.retain(|_| {
                    k += 1;
                    mask[k - 1] == 1
                });
                sn.set_entries(st.snapshots.clone());
            }
            st
        }
        None => {
            let mut next_snapshot = f64::INFINITY;
            if let Some((sn, every)) = &mut snaps {
                sn.write(comm, &solver.parts, &solver.materials, 0, 0.0)
                    .map_err(|e| RunError::Io(e.to_string()))?;
                next_snapshot = *every;
                output_seconds.snapshots += start.elapsed().as_secs_f64();
            }
            let tot0 = solver.totals();
            let err0 = solver.errors();
            history.row(&solver, &tot0, err0);
            RunState {
                energy_scale: tot0.total_energy().abs().max(tot0.kinetic + tot0.strain),
                max_energy_dev: 0.0,
                max_err: err0.unwrap_or((0.0, 0.0)),
                last_err: err0,
                next_history: diag_dt,
                last_history_step: 0,
                next_snapshot,
                next_checkpoint: match schedule {
                    Some(CheckpointEvery::Time(t)) => t,
                    _ => f64::INFINITY,
                },
                snapshots: Vec::new(),
                history: Vec::new(),
                last: tot0.clone(),
                initial: tot0,
            }
        }
    };
    let e0 = st.initial.total_energy();
    let (t_start, step_start) = (solver.t, solver.step);
    let mut progress = Progress::new(root && !opts.quiet, opts.progress_every, start, t_start);
    let mut failure: Option<Failure> = None;
    let mut stopped_by = 0i32;
    let mut last_checkpoint: Option<PathBuf> = opts.restart.clone();
    let mut checkpoint_clock = Instant::now();
    let mut checkpoint_step = opts.restart.as_ref().map(|_| solver.step);
    let mut rescue = Rescue::default();
    rescue.keep(&solver, &st, history.text.len());
    while !solver.done() {
        // Requests every rank must agree on travel with the step's own reduction: a
        // stop signal (any rank), a wall-clock checkpoint (rank 0's clock), a failed
        // history write (rank 0).
        let wall_due = root
            && matches!(schedule, Some(CheckpointEvery::Seconds(s))
                if checkpoint_clock.elapsed().as_secs_f64() >= s);
        // Snapshots at exact output times: the step that would pass one is shortened.
        solver.stop_at = st.next_snapshot;
        let mut flags = [
            f64::from(signals::pending()),
            f64::from(u8::from(wall_due)),
            f64::from(u8::from(history.error.is_some())),
        ];
        if let Err(f) = solver.advance_with(&mut flags) {
            failure = Some(f);
            break;
        }
        if flags[2] > 0.0 {
            return Err(RunError::Io(history.error.take().unwrap_or_else(|| {
                format!("{}: writing failed on rank 0", hpath.display())
            })));
        }
        if has_bench {
            st.last_err = solver.errors();
            if let Some((u, v)) = st.last_err {
                st.max_err.0 = st.max_err.0.max(u);
                st.max_err.1 = st.max_err.1.max(v);
            }
        }
        // A history sample every thousandth of the run, but no closer than
        // DIAG_MIN_STEPS steps: each costs a pass over the particles.
        if (solver.t >= st.next_history && solver.step >= st.last_history_step + DIAG_MIN_STEPS)
            || solver.done()
        {
            st.next_history = solver.t + diag_dt;
            st.last_history_step = solver.step;
            st.last = solver.totals();
            st.energy_scale = st.energy_scale.max(st.last.kinetic + st.last.strain);
            st.max_energy_dev = st.max_energy_dev.max((st.last.total_energy() - e0).abs());
            history.row(&solver, &st.last, st.last_err);
        }
        if let Some((sn, every)) = &mut snaps {
            // Write when an output time is reached (the step landed on it, to round-off).
            if solver.t >= st.next_snapshot - 1e-3 * solver.dt || solver.done() {
                let t0 = Instant::now();
                sn.write(
                    comm,
                    &solver.parts,
                    &solver.materials,
                    solver.step,
                    solver.t,
                )
                .map_err(|e| RunError::Io(e.to_string()))?;
                output_seconds.snapshots += t0.elapsed().as_secs_f64();
                // k·every by one multiplication: a sum of intervals would drift.
                while st.next_snapshot <= solver.t + 1e-3 * solver.dt {
                    let next = ((st.next_snapshot / *every).round() + 1.0) * *every;
                    st.next_snapshot = past(st.next_snapshot, next, solver.t, *every);
                }
            }
        }
        let signal = flags[0] as i32;
        let due = signal != 0
            || match schedule {
                Some(CheckpointEvery::Time(_)) => solver.t >= st.next_checkpoint - 1e-3 * solver.dt,
                Some(CheckpointEvery::Steps(n)) => solver.step.is_multiple_of(n),
                Some(CheckpointEvery::Seconds(_)) => flags[1] > 0.0,
                None => false,
            };
        // A finished run needs no checkpoint.
        if due && !solver.done() {
            if let Some(CheckpointEvery::Time(every)) = schedule {
                while st.next_checkpoint <= solver.t + 1e-3 * solver.dt {
                    let next = st.next_checkpoint + every;
                    st.next_checkpoint = past(st.next_checkpoint, next, solver.t, every);
                }
            }
            history.flush();
            st.history = std::mem::take(&mut history.text);
            st.snapshots = snaps
                .as_ref()
                .map_or_else(Vec::new, |(sn, _)| sn.entries().to_vec());
            let t0 = Instant::now();
            let written =
                checkpoint::write(comm, &opts.out, &solver, &st, &scene_text, &mut lineage);
            output_seconds.checkpoints += t0.elapsed().as_secs_f64();
            history.text = std::mem::take(&mut st.history);
            last_checkpoint = Some(written.map_err(|e| RunError::Io(e.to_string()))?);
            checkpoint_step = Some(solver.step);
            checkpoint_clock = Instant::now();
        }
        if solver.step.is_multiple_of(RESCUE_EVERY) {
            rescue.keep(&solver, &st, history.text.len());
        }
        progress.tick(solver.step, solver.t, solver.end, solver.dt);
        if signal != 0 && !solver.done() {
            stopped_by = signal;
            break;
        }
    }
    let mut last = st.last.clone();
    let mut message = None;
    if failure.is_some() || stopped_by != 0 {
        last = solver.totals();
    }
    let (fail_step, fail_t) = (solver.step, solver.t);
    if failure.is_some() {
        // Report the failing rank's own reason on rank 0, not "failed elsewhere".
        let mine = match &failure {
            Some(Failure::Elsewhere(_)) | None => String::new(),
            Some(f) => format!("rank {}: {f}", comm.rank()),
        };
        let all = comm.gather_bytes(mine.as_bytes());
        if let Some(m) = all.iter().find(|m| !m.is_empty()) {
            failure = Some(Failure::Elsewhere(String::from_utf8_lossy(m).into_owned()));
        }
        // The failed state cannot be continued or inspected usefully: checkpoint the
        // last state known good instead (unless a regular checkpoint already holds it).
        if checkpoint_step != Some(rescue.solver.step) {
            rescue.restore(&mut solver, &mut st, &mut history.text);
            st.snapshots = snaps
                .as_ref()
                .map_or_else(Vec::new, |(sn, _)| sn.entries().to_vec());
            st.snapshots.retain(|e| e.step <= rescue.solver.step);
            let t0 = Instant::now();
            let written =
                checkpoint::write(comm, &opts.out, &solver, &st, &scene_text, &mut lineage);
            output_seconds.checkpoints += t0.elapsed().as_secs_f64();
            history.text = std::mem::take(&mut st.history);
            last_checkpoint = Some(written.map_err(|e| RunError::Io(e.to_string()))?);
        }
        let ckpt = last_checkpoint
            .as_ref()
            .map_or(String::new(), |p| p.display().to_string());
        message = failure.as_ref().map(|f| {
            format!(
                "{f}; the last good state (step {}, t = {:.6e}) is checkpointed in {ckpt}",
                rescue.solver.step, rescue.solver.t
            )
        });
    } else if stopped_by != 0 {
        message = Some(format!(
            "stopped by {} after step {} (t = {:.6e}); the last checkpoint is {}: continue with `mpmcg run --restart {}`",
            signals::name(stopped_by),
            solver.step,
            solver.t,
            last_checkpoint
                .as_ref()
                .map_or_else(String::new, |p| p.display().to_string()),
            last_checkpoint
                .as_ref()
                .map_or_else(|| "CHECKPOINT".to_string(), |p| p.display().to_string())
        ));
    }
    progress.finish();
    let wall = start.elapsed().as_secs_f64();
    let mut lo = [solver.parts.len() as f64, solver.tiles.active() as f64];
    let mut hi = lo;
    let mut sum = [solver.tiles.active() as u64];
    comm.min_f64(&mut lo);
    comm.max_f64(&mut hi);
    comm.sum_u64(&mut sum);
    history.flush();
    let tot0 = &st.initial;
    let status = if failure.is_some() {
        "unstable"
    } else if stopped_by != 0 {
        "interrupted"
    } else {
        "completed"
    };
    let summary = Summary {
        scene: scene.name.clone(),
        dim: D,
        gradient: scene.method.gradient.name().into(),
        update: scene.method.update.name().into(),
        flip: scene.method.flip,
        xpic: scene.method.xpic,
        units: Labels::of::<D>(scene).units,
        status: status.into(),
        message: message.clone(),
        ranks: comm.size(),
        threads: opts.threads,
        blocks: layout.procs.to_vec(),
        particles_per_rank: RankLoad {
            min: lo[0] as u64,
            mean: last.particles as f64 / comm.size() as f64,
            max: hi[0] as u64,
        },
        grid: GridSummary {
            tile_nodes: solver.tiles.tile_nodes(),
            active_tiles: sum[0],
            active_tiles_per_rank: RankLoad {
                min: lo[1] as u64,
                mean: sum[0] as f64 / comm.size() as f64,
                max: hi[1] as u64,
            },
            box_tiles: scene
                .grid
                .cells
                .iter()
                .map(|&c| (c + 1).div_ceil(decomposition::TILE) as f64)
                .product(),
        },
        particles: tot0.particles,
        cells: scene.grid.cells.clone(),
        steps: fail_step,
        time: fail_t,
        end_time: scene.time.end,
        wall_seconds: wall,
        particle_updates_per_second: tot0.particles as f64 * (solver.step - step_start) as f64
            / wall.max(1e-9),
        mass: MassSummary {
            initial: tot0.mass,
            r#final: last.mass,
        },
        momentum: MomentumSummary {
            initial: tot0.momentum.clone(),
            r#final: last.momentum.clone(),
        },
        energy: EnergySummary {
            initial_total: e0,
            final_total: last.total_energy(),
            max_relative_drift: if st.energy_scale > 0.0 {
                st.max_energy_dev / st.energy_scale
            } else {
                0.0
            },
            final_kinetic: last.kinetic,
            final_strain: last.strain,
            external_work: last.external_work,
            plastic_work: solver.carries().plastic.then_some(last.plastic_work),
        },
        error: has_bench.then(|| {
            let (fu, fv) = st.last_err.unwrap_or((f64::NAN, f64::NAN));
            ErrorSummary {
                displacement_l2: st.max_err.0,
                velocity_l2: st.max_err.1,
                final_displacement_l2: fu,
                final_velocity_l2: fv,
            }
        }),
        last_checkpoint: last_checkpoint.as_ref().map(|p| p.display().to_string()),
        restarted_from,
        output_seconds,
    };
    let mut written = history.error.take();
    if root && written.is_none() {
        let path = opts.out.join("summary.json");
        let text = serde_json::to_string_pretty(&summary).expect("summary serialises");
        // Via a temporary file: a full disk leaves the previous summary (or none), never
        // a truncated one.
        let tmp = opts.out.join(".summary.json.tmp");
        written = std::fs::write(&tmp, text + "\n")
            .and_then(|()| std::fs::rename(&tmp, &path))
            .err()
            .map(|e| {
                let _ = std::fs::remove_file(&tmp);
                format!("{}: {e}", path.display())
            });
    }
    // No rank leaves before rank 0 has written everything: mpirun ends the whole job
    // as soon as one rank exits with a non-zero status.
    if let Some(m) = agree(comm, written) {
        return Err(RunError::Io(m));
    }
    match (failure, stopped_by) {
        (Some(_), _) => Err(RunError::Unstable(message.unwrap_or_default())),
        (None, 0) => Ok(summary),
        (None, _) => Err(RunError::Interrupted(message.unwrap_or_default())),
    }
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

/// Steps between copies of the state kept for [`Rescue`]: a copy is a memcpy of the
/// particle arrays, a small fraction of a step, so every tenth step costs about 1 %
/// (below the noise of the 262 144-particle scaling benchmark).
const RESCUE_EVERY: u64 = 10;

/// The newest state known good (at most [`RESCUE_EVERY`] steps old): a run that turns
/// unstable checkpoints this, since the failed step's own state is non-finite or
/// outside the grid and can be neither continued nor usefully inspected.
#[derive(Default)]
struct Rescue<const D: usize> {
    parts: Particles<D>,
    solver: SolverState,
    run: Option<RunState>,
    history_len: usize,
}

impl<const D: usize> Rescue<D> {
    /// Copy the state after the current step; no allocation once the buffers have grown.
    fn keep(&mut self, solver: &Solver<D>, st: &RunState, history_len: usize) {
        self.parts.copy_from(&solver.parts);
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

    /// Put the kept state back into the solver, the run state and `history.csv`'s text.
    fn restore(&mut self, solver: &mut Solver<D>, st: &mut RunState, history: &mut Vec<u8>) {
        std::mem::swap(&mut solver.parts, &mut self.parts);
        let s = &self.solver;
        solver.restore(s.t, s.step, s.dt, s.external_work, s.max_speed);
        if let Some(r) = &self.run {
            st.clone_from(r);
        }
        history.truncate(self.history_len);
        st.history = std::mem::take(history);
    }
}
