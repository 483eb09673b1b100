//! A whole run: set-up, the step loop with progress and diagnostics, and the files it
//! leaves in the output folder (`summary.json`, `history.csv`).

use crate::io::Snapshots;
use crate::scene::{Face, Scene};
use crate::solver::{Failure, Solver, Totals};
use decomposition::{Communicator, Layout};
use serde::Serialize;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Clone, Debug)]
pub struct RunOptions {
    pub out: PathBuf,
    pub quiet: bool,
    pub threads: usize,
}

/// How a run ended, for the exit status.
#[derive(Debug)]
pub enum RunError {
    /// Bad input discovered at set-up (exit 2).
    Input(String),
    /// The run became unstable; the summary says so (exit 3).
    Unstable(String),
    /// Files could not be written (exit 1).
    Io(String),
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunError::Input(m) | RunError::Unstable(m) | RunError::Io(m) => f.write_str(m),
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
    /// − external work.
    pub max_relative_drift: f64,
    pub final_kinetic: f64,
    pub final_strain: f64,
    pub external_work: f64,
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

#[derive(Serialize, Debug, Clone)]
pub struct Summary {
    pub scene: String,
    pub dim: usize,
    pub gradient: String,
    pub update: String,
    pub flip: f64,
    pub status: String,
    pub message: Option<String>,
    pub ranks: usize,
    pub threads: usize,
    pub blocks: Vec<usize>,
    pub particles_per_rank: RankLoad,
    pub particles: u64,
    pub cells: Vec<usize>,
    pub steps: u64,
    pub time: f64,
    pub end_time: f64,
    pub wall_seconds: f64,
    pub particle_updates_per_second: f64,
    pub mass: MassSummary,
    pub momentum: MomentumSummary,
    pub energy: EnergySummary,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorSummary>,
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

fn layout_for<const D: usize>(scene: &Scene, ranks: usize) -> Result<Layout<D>, RunError> {
    let cells: [usize; D] = std::array::from_fn(|a| scene.grid.cells[a]);
    let periodic: [bool; D] =
        std::array::from_fn(|a| scene.grid.boundary.face(a, false) == Face::Periodic);
    Layout::choose(cells, periodic, ranks)
        .map_err(|e| RunError::Input(format!("cannot run on {ranks} ranks: {e}")))
}

/// Fewest steps between two history samples.
const DIAG_MIN_STEPS: u64 = 10;

struct History {
    file: Option<std::io::BufWriter<std::fs::File>>,
}

impl History {
    fn row<const D: usize>(
        &mut self,
        s: &Solver<D>,
        tot: &Totals,
        err: Option<(f64, f64)>,
    ) -> std::io::Result<()> {
        if let Some(f) = &mut self.file {
            write!(
                f,
                "{},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e}",
                s.step,
                s.t,
                s.dt,
                tot.kinetic,
                tot.strain,
                tot.external_work,
                tot.total_energy()
            )?;
            for a in 0..D {
                write!(f, ",{:.17e}", tot.momentum[a])?;
            }
            for a in 0..D {
                write!(f, ",{:.17e}", tot.momentum[a] / tot.mass)?;
            }
            if let Some((u, v)) = err {
                write!(f, ",{u:.17e},{v:.17e}")?;
            }
            writeln!(f)?;
        }
        Ok(())
    }
}

fn io_err(path: &Path, e: std::io::Error) -> RunError {
    RunError::Io(format!("{}: {e}", path.display()))
}

fn run_dim<const D: usize>(
    scene: &Scene,
    comm: &dyn Communicator,
    opts: &RunOptions,
) -> Result<Summary, RunError> {
    let layout = layout_for::<D>(scene, comm.size())?;
    let root = comm.rank() == 0;
    if root {
        std::fs::create_dir_all(&opts.out).map_err(|e| io_err(&opts.out, e))?;
    }
    let mut solver = Solver::<D>::new(scene, comm, layout.clone());
    let has_bench = solver.benchmark.is_some();
    let mut history = History { file: None };
    if root {
        let path = opts.out.join("history.csv");
        let f = std::fs::File::create(&path).map_err(|e| io_err(&path, e))?;
        let mut w = std::io::BufWriter::new(f);
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
        writeln!(w, "{head}").map_err(|e| io_err(&path, e))?;
        history.file = Some(w);
    }
    let mut snaps = scene
        .output
        .as_ref()
        .map(|o| (Snapshots::new(&opts.out, &o.fields), o.every));
    let mut next_out = f64::INFINITY;
    if let Some((sn, every)) = &mut snaps {
        sn.write(comm, &solver.parts, 0, 0.0)
            .map_err(|e| RunError::Io(e.to_string()))?;
        next_out = *every;
    }
    let tot0 = solver.totals();
    let err0 = solver.errors();
    history
        .row(&solver, &tot0, err0)
        .map_err(|e| io_err(&opts.out, e))?;
    let e0 = tot0.total_energy();
    let mut scale = e0.abs().max(tot0.kinetic + tot0.strain);
    let mut max_dev = 0.0f64;
    let mut max_err = err0.unwrap_or((0.0, 0.0));
    let mut last_err = err0;
    let diag_dt = scene.time.end / 1000.0;
    let mut next_diag = diag_dt;
    let mut last_diag_step = 0u64;
    let start = Instant::now();
    let mut progress = Progress::new(root && !opts.quiet);
    let mut failure: Option<Failure> = None;
    let mut last = tot0.clone();
    while !solver.done() {
        if let Err(f) = solver.advance() {
            failure = Some(f);
            break;
        }
        if has_bench {
            last_err = solver.errors();
            if let Some((u, v)) = last_err {
                max_err.0 = max_err.0.max(u);
                max_err.1 = max_err.1.max(v);
            }
        }
        // A history sample every thousandth of the run, but no closer than
        // DIAG_MIN_STEPS steps: each costs a pass over the particles.
        if (solver.t >= next_diag && solver.step >= last_diag_step + DIAG_MIN_STEPS) || solver.done() {
            next_diag = solver.t + diag_dt;
            last_diag_step = solver.step;
            last = solver.totals();
            scale = scale.max(last.kinetic + last.strain);
            max_dev = max_dev.max((last.total_energy() - e0).abs());
            history
                .row(&solver, &last, last_err)
                .map_err(|e| io_err(&opts.out, e))?;
        }
        if let Some((sn, every)) = &mut snaps {
            // Write when an output time is reached (to within a thousandth of a step).
            if solver.t >= next_out - 1e-3 * solver.dt || solver.done() {
                sn.write(comm, &solver.parts, solver.step, solver.t)
                    .map_err(|e| RunError::Io(e.to_string()))?;
                while next_out <= solver.t + 1e-3 * solver.dt {
                    next_out += *every;
                }
            }
        }
        progress.tick(&solver, start);
    }
    if failure.is_some() {
        last = solver.totals();
        // Report the failing rank's own reason on rank 0, not "failed elsewhere".
        let mine = match &failure {
            Some(Failure::Elsewhere(_)) | None => String::new(),
            Some(f) => format!("rank {}: {f}", comm.rank()),
        };
        let all = comm.gather_bytes(mine.as_bytes());
        if let Some(m) = all.iter().find(|m| !m.is_empty()) {
            failure = Some(Failure::Elsewhere(String::from_utf8_lossy(m).into_owned()));
        }
    }
    progress.finish();
    let wall = start.elapsed().as_secs_f64();
    let mut lo = [solver.parts.len() as f64];
    let mut hi = lo;
    comm.min_f64(&mut lo);
    comm.max_f64(&mut hi);
    if let Some(f) = &mut history.file {
        f.flush().map_err(|e| io_err(&opts.out, e))?;
    }
    let summary = Summary {
        scene: scene.name.clone(),
        dim: D,
        gradient: scene.method.gradient.name().into(),
        update: scene.method.update.name().into(),
        flip: scene.method.flip,
        status: if failure.is_some() {
            "unstable"
        } else {
            "completed"
        }
        .into(),
        message: failure.as_ref().map(|f| f.to_string()),
        ranks: comm.size(),
        threads: opts.threads,
        blocks: layout.procs.to_vec(),
        particles_per_rank: RankLoad {
            min: lo[0] as u64,
            mean: last.particles as f64 / comm.size() as f64,
            max: hi[0] as u64,
        },
        particles: tot0.particles,
        cells: scene.grid.cells.clone(),
        steps: solver.step,
        time: solver.t,
        end_time: scene.time.end,
        wall_seconds: wall,
        particle_updates_per_second: tot0.particles as f64 * solver.step as f64 / wall.max(1e-9),
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
            max_relative_drift: if scale > 0.0 { max_dev / scale } else { 0.0 },
            final_kinetic: last.kinetic,
            final_strain: last.strain,
            external_work: last.external_work,
        },
        error: has_bench.then(|| {
            let (fu, fv) = last_err.unwrap_or((f64::NAN, f64::NAN));
            ErrorSummary {
                displacement_l2: max_err.0,
                velocity_l2: max_err.1,
                final_displacement_l2: fu,
                final_velocity_l2: fv,
            }
        }),
    };
    if root {
        let path = opts.out.join("summary.json");
        let text = serde_json::to_string_pretty(&summary).expect("summary serialises");
        std::fs::write(&path, text + "\n").map_err(|e| io_err(&path, e))?;
    }
    match failure {
        Some(f) => Err(RunError::Unstable(f.to_string())),
        None => Ok(summary),
    }
}

/// Progress on rank 0: a line rewritten in place on a terminal, a line every ten
/// seconds otherwise (batch logs).
struct Progress {
    on: bool,
    tty: bool,
    last: Option<Instant>,
}

impl Progress {
    fn new(on: bool) -> Self {
        Self {
            on,
            tty: std::io::stderr().is_terminal(),
            last: None,
        }
    }

    fn tick<const D: usize>(&mut self, s: &Solver<D>, start: Instant) {
        if !self.on {
            return;
        }
        let now = Instant::now();
        let every = if self.tty { 0.5 } else { 10.0 };
        let due = match self.last {
            None => now.duration_since(start).as_secs_f64() >= every,
            Some(l) => now.duration_since(l).as_secs_f64() >= every,
        };
        if !due {
            return;
        }
        self.last = Some(now);
        let el = now.duration_since(start).as_secs_f64();
        let frac = (s.t / s.end).clamp(1e-12, 1.0);
        let eta = el * (1.0 - frac) / frac;
        let line = format!(
            "step {:>8}  t = {:.4e} / {:.4e} ({:5.1}%)  dt = {:.3e}  elapsed {}  ETA {}",
            s.step,
            s.t,
            s.end,
            100.0 * frac,
            s.dt,
            hms(el),
            hms(eta)
        );
        if self.tty {
            eprint!("\r{line}");
        } else {
            eprintln!("{line}");
        }
    }

    fn finish(&mut self) {
        if self.on && self.tty && self.last.is_some() {
            eprintln!();
        }
    }
}

fn hms(s: f64) -> String {
    let s = s.round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m{:02}s", s / 3600, s / 60 % 60, s % 60)
    } else if s >= 60 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{s}s")
    }
}
