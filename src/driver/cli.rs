//! The command line. Exit status: 0 done, 2 bad input or usage (an unusable checkpoint
//! included), 3 numerically unstable, 4 stopped by SIGTERM/SIGINT/SIGUSR1 after writing a
//! checkpoint, 1 any other failure (I/O, MPI).

use crate::driver::run::{self, RunError, RunOptions};
use crate::driver::signals;
use crate::input::scene::{self, SceneError};
use crate::output::checkpoint;
use clap::{Parser, Subcommand};
use decomposition::{Communicator, MpiComm};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "mpmcg",
    version,
    about = "Material Point Method with continuous gradient, MPI-parallel"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a scene (the built-in default scene if none is given).
    Run {
        /// Scene file (TOML).
        scene: Option<PathBuf>,
        /// Output folder [default: out/<scene name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Threads per rank [default: under mpirun with several ranks, each rank's share
        /// of the cores it may run on; else all cores].
        #[arg(long)]
        threads: Option<usize>,
        /// No progress line (the last line, which names the output folder, stays).
        #[arg(long, short)]
        quiet: bool,
        /// Seconds between progress updates on rank 0's stderr [default: 0.5 on a
        /// terminal, where the line is rewritten in place; 10 in a log, one line each].
        #[arg(long, value_name = "SECONDS")]
        progress_every: Option<f64>,
        /// Continue from a checkpoint (OUT/checkpoint_NNNNNN.h5) with the scene it
        /// stores. SCENE, if given, may change only time.end, time.cfl, time.dt,
        /// output.every and [checkpoint]. Output goes to the checkpoint's folder unless
        /// --out says otherwise. Any rank count works.
        #[arg(long, value_name = "CHECKPOINT.h5")]
        restart: Option<PathBuf>,
        /// At the end, print where the steps' time went: each part of the step,
        /// min / mean / max over ranks, and the time blocked in communication
        /// (`summary.json` has it under `profile` either way).
        #[arg(long)]
        profile: bool,
    },
    /// Validate a scene file and exit.
    Check {
        /// Scene file (TOML).
        scene: PathBuf,
    },
    /// Run a benchmark scene over resolutions and gradient schemes: error against cost.
    Sweep(SweepArgs),
}

#[derive(clap::Args, Debug)]
struct SweepArgs {
    /// Scene file (TOML) with a [benchmark] table.
    scene: PathBuf,
    /// Cells along x, comma-separated; other axes keep the scene's proportions.
    #[arg(long, default_value = "8,16,32,64")]
    cells: String,
    /// Gradient schemes, comma-separated (mpm, gimp, averaged, mpmcg, mpmcg-domain: MPMCG
    /// with the domain rule).
    #[arg(long, default_value = "mpm,gimp,mpmcg")]
    gradient: String,
    /// Particles per cell per direction in every body [default: the scene's].
    #[arg(long)]
    ppc: Option<usize>,
    /// MPI ranks per run; more than 1 starts each run with mpirun.
    #[arg(long, default_value_t = 1)]
    ranks: usize,
    /// Output folder [default: out/<scene name>_sweep].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Threads per rank [default: all cores in-process; under mpirun, the run's own].
    #[arg(long)]
    threads: Option<usize>,
    /// No line per run.
    #[arg(long, short)]
    quiet: bool,
}

fn scene_error(e: &SceneError) -> ExitCode {
    early_error(&e.to_string())
}

/// Ends the process with exit 2 on an error found before MPI starts (usage, scene),
/// printed once under `mpirun -n 3`, not three times.
///
/// Every rank reads the same file and finds the same error; rank 0 reports it.
/// Another rank waits first: the launcher ends the whole job when the first rank exits
/// with an error, and if that were this rank, rank 0 could be killed before its
/// message is out (seen in CI). Rank 0's exit ends the job, and this wait with it. A
/// rank still alive after [`OTHER_RANK_WAIT`] found an error that rank 0 did not (a
/// scene file missing on its node) and reports it itself, naming its rank.
fn early_error(message: &str) -> ExitCode {
    match launcher_rank() {
        None | Some(0) => say!("error: {message}"),
        Some(r) => {
            std::thread::sleep(OTHER_RANK_WAIT);
            say!("error (rank {r}): {message}");
        }
    }
    ExitCode::from(2)
}

/// How long a rank other than 0 leaves rank 0 to report an error they both found
/// before MPI starts: parsing a scene takes milliseconds; a loaded node, more.
pub const OTHER_RANK_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

/// The rank an MPI launcher gave this process before MPI starts, from the
/// environment of Open MPI, MPICH/Intel MPI, PMIx and Slurm; `None` without one.
fn launcher_rank() -> Option<u64> {
    [
        "OMPI_COMM_WORLD_RANK",
        "PMIX_RANK",
        "PMI_RANK",
        "SLURM_PROCID",
    ]
    .iter()
    .find_map(|k| std::env::var(k).ok())
    .and_then(|r| r.trim().parse::<u64>().ok())
}

/// Whether the MPI launcher started this process as a rank other than 0, whose
/// messages before MPI starts are left to rank 0.
pub fn launched_as_other_rank() -> bool {
    launcher_rank().is_some_and(|r| r != 0)
}

/// The most threads per rank `--threads` may ask for.
const MAX_THREADS: usize = 1024;

pub fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            if !e.use_stderr() {
                // --help, --version: on stdout, from rank 0.
                if !launched_as_other_rank() {
                    let _ = e.print();
                }
                return ExitCode::SUCCESS;
            }
            // `mpmcg` alone prints the help as an error: every rank finds it, and it is
            // no message to wait for or to tag with a rank.
            let help = e.kind() == clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand;
            if help && launched_as_other_rank() {
                return ExitCode::from(2);
            }
            if launcher_rank().is_none() || help {
                // clap's own printing: coloured on a terminal.
                let _ = e.print();
                return ExitCode::from(2);
            }
            let text = e.render().to_string();
            return early_error(text.trim_end().trim_start_matches("error: "));
        }
    };
    match cli.command {
        Command::Sweep(args) => sweep_main(args),
        Command::Check { scene } => match scene::load(&scene) {
            Ok((s, _)) => match run::check_bodies(&s) {
                Ok(()) => {
                    println!(
                        "{}: ok ({}D, {} cells, {} bodies, gradient {}; {})",
                        scene.display(),
                        s.dim,
                        s.grid.cells.iter().product::<usize>(),
                        s.bodies.len(),
                        s.method.gradient.name(),
                        particles_and_memory(&s)
                    );
                    ExitCode::SUCCESS
                }
                Err(m) => early_error(&format!("{}: {m}", scene.display())),
            },
            Err(e) => scene_error(&e),
        },
        Command::Run {
            scene,
            out,
            threads,
            quiet,
            progress_every,
            restart,
            profile,
        } => {
            if progress_every.is_some_and(|s| !(s >= 0.0 && s.is_finite())) {
                return early_error("--progress-every must be a number of seconds >= 0");
            }
            run_main(scene, out, threads, quiet, progress_every, restart, profile)
        }
    }
}

/// The scene of a fresh run: the file's, or the built-in default; its bodies checked
/// like `mpmcg check` does, so that the message names the file.
fn fresh_scene(scene: &Option<PathBuf>) -> Result<(scene::Scene, String), ExitCode> {
    let loaded = match scene {
        Some(path) => scene::load(path).map_err(|e| scene_error(&e)),
        None => match scene::parse(scene::DEFAULT_SCENE, scene::DEFAULT_SCENE_NAME) {
            Ok(s) => Ok((s, scene::DEFAULT_SCENE.to_string())),
            Err(e) => Err(scene_error(&e)),
        },
    }?;
    if let Err(m) = run::check_bodies(&loaded.0) {
        let file = scene
            .as_ref()
            .map_or(scene::DEFAULT_SCENE_NAME.into(), |p| {
                p.display().to_string()
            });
        return Err(early_error(&format!("{file}: {m}")));
    }
    Ok(loaded)
}

/// The scene stored in a checkpoint, checked against the SCENE argument if there is
/// one. Every rank reads the checkpoint and they agree; rank 0 reports.
fn restart_scene(
    comm: &dyn Communicator,
    ckpt: &std::path::Path,
    scene_file: &Option<PathBuf>,
) -> Result<(scene::Scene, String), String> {
    let header = checkpoint::read_header(ckpt);
    if let Some(m) = crate::output::io::agree(comm, header.as_ref().err().cloned()) {
        return Err(m);
    }
    let header = header.expect("agreed");
    let label = format!("{}:/scene", ckpt.display());
    // The stored scene and any given one read with the checkpoint's defaults: a
    // restart continues the run's method whatever this build's defaults are.
    let sc = scene::parse_with(&header.scene_text, &label, header.scene_defaults)
        .map_err(|e| e.to_string())?;
    if let Some(path) = scene_file {
        let (given, text) =
            scene::load_with(path, header.scene_defaults).map_err(|e| e.to_string())?;
        if text != header.scene_text {
            if let Some(key) = scene::restart_difference(&sc, &given) {
                return Err(format!(
                    "{}: key `{key}` differs from the scene of checkpoint {}; a restart may change only time.end, time.cfl, time.dt, output.every and [checkpoint] (restart without a scene to use the stored one)",
                    path.display(),
                    ckpt.display()
                ));
            }
            return Ok((given, text));
        }
    }
    Ok((sc, header.scene_text))
}

/// `mpmcg run`.
fn run_main(
    scene: Option<PathBuf>,
    out: Option<PathBuf>,
    threads: Option<usize>,
    quiet: bool,
    progress_every: Option<f64>,
    restart: Option<PathBuf>,
    profile: bool,
) -> ExitCode {
    // A fresh run's scene is checked before MPI starts; a restart needs every rank
    // to agree on the checkpoint, so MPI comes first.
    let fresh = match &restart {
        None => match fresh_scene(&scene) {
            Ok(x) => Some(x),
            Err(code) => return code,
        },
        Some(_) => None,
    };
    // Rayon's threads run beside MPI, which only the main thread calls: FUNNELED.
    let Some((universe, provided)) = mpi::initialize_with_threading(mpi::Threading::Funneled)
    else {
        say!("error: MPI could not be initialised");
        return ExitCode::from(1);
    };
    let comm = MpiComm::new(universe.world());
    super::out_of_memory::set_rank(comm.rank());
    let root = comm.rank() == 0;
    let (sc, text) = match (fresh, &restart) {
        (Some(x), _) => x,
        (None, Some(ckpt)) => match restart_scene(&comm, ckpt, &scene) {
            Ok(x) => x,
            Err(m) => {
                if root {
                    say!("error: {m}");
                }
                return ExitCode::from(2);
            }
        },
        (None, None) => unreachable!("a fresh run has its scene"),
    };
    let threads = match start_threads(&comm, threads) {
        Ok(t) => t,
        Err(code) => return code,
    };
    if threads > 1 && provided == mpi::Threading::Single && root {
        say!(
            "warning: this MPI library does not support threads beside it (MPI_THREAD_SINGLE); running {threads} threads per rank anyway, --threads 1 is the safe choice"
        );
    }
    if let Err(m) = signals::install() {
        if root {
            say!("warning: {m}; SIGTERM, SIGINT and SIGUSR1 will end the run without a checkpoint");
        }
    }
    let opts = RunOptions {
        out: out.unwrap_or_else(|| default_out(restart.as_deref(), &sc.name)),
        quiet,
        threads,
        scene_text: Some(text),
        restart,
        progress_every,
        profile,
    };
    let result = run::run(&sc, &comm, &opts);
    report(result, root, &opts)
}

/// `mpmcg check`'s account of a scene's size: the particles it seeds and their state's
/// bytes, counted up to what this machine has available, beyond which it says so (a
/// cluster's nodes may have more).
fn particles_and_memory(s: &scene::Scene) -> String {
    let available = super::memory::node_available();
    let bytes = run::particle_state_bytes(s);
    let stop = available.map_or(u64::MAX, |a| a / bytes + 1);
    let n = run::particle_count(s, stop);
    match available {
        Some(a) if n == stop => format!(
            "{}: run it on more nodes",
            super::memory::particles_over(n, bytes, a, "this machine has available", true)
        ),
        _ => format!(
            "{n} particles, {} of particle state at {bytes} bytes each",
            super::memory::size(n.saturating_mul(bytes))
        ),
    }
}

/// The thread count per rank (`--threads`, else under mpirun with several ranks the
/// rank's share of the cores it may run on ([`super::affinity`]), and every core alone)
/// and rayon's pool of them; the exit status if that fails.
///
/// The main thread is one of the pool's threads: a parallel loop it starts runs on
/// it, rather than being handed to a sleeping worker while it waits. On one thread
/// that is no hand-over at all (a step has dozens of parallel loops, and each
/// hand-over is two context switches). MPI and HDF5 stay on the main thread: rayon
/// only ever runs the loops' own closures on the other threads.
fn start_threads(comm: &MpiComm, threads: Option<usize>) -> Result<usize, ExitCode> {
    let threads = threads.unwrap_or_else(|| {
        if comm.size() > 1 {
            super::affinity::node_share(comm).min(MAX_THREADS)
        } else {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        }
    });
    if threads == 0 || threads > MAX_THREADS {
        if comm.rank() == 0 {
            say!("error: --threads must be between 1 and {MAX_THREADS} (threads per rank), got {threads}");
        }
        return Err(ExitCode::from(2));
    }
    if let Err(e) = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .use_current_thread()
        .build_global()
    {
        say!("error: cannot start {threads} threads: {e}");
        return Err(ExitCode::from(1));
    }
    Ok(threads)
}

/// The output folder without `--out`: a restart's checkpoint folder, else
/// `out/<scene name>`.
fn default_out(restart: Option<&Path>, name: &str) -> PathBuf {
    match restart {
        Some(ckpt) => ckpt
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .map_or_else(|| PathBuf::from("."), PathBuf::from),
        None => PathBuf::from("out").join(name),
    }
}

/// The last line of a run (rank 0) and its exit status.
fn report(result: Result<run::Summary, RunError>, root: bool, opts: &RunOptions) -> ExitCode {
    let out = &opts.out;
    match result {
        // The last line says where the files are, with --quiet too.
        Ok(s) => {
            if root && opts.profile {
                say!("{}", run::profile_table(&s.profile, s.ranks));
            }
            if root {
                say!(
                    "{}: completed {} steps to t = {:.6e} in {:.2} s ({:.3e} particle updates/s); output in {}",
                    s.scene,
                    s.steps,
                    s.time,
                    s.wall_seconds,
                    s.particle_updates_per_second,
                    out.display()
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            if root {
                let dir = out.display();
                match e {
                    RunError::Interrupted(_) => say!("interrupted: {e}; output in {dir}"),
                    RunError::Unstable(_) => say!("error: {e}; output in {dir}"),
                    _ => say!("error: {e}"),
                }
            }
            if crate::output::io::unclosed_file() {
                // HDF5 holds a file it could not close: MPI_Finalize (via HDF5's
                // clean-up callback) and HDF5's atexit handler would both crash on it.
                // Every rank agreed on this and ends here, after the run has released
                // the folder's lock and rank 0 has printed the message.
                // SAFETY: _exit ends the process at once; nothing runs after it.
                unsafe { libc::_exit(i32::from(e.exit_code())) };
            }
            ExitCode::from(e.exit_code())
        }
    }
}

/// `mpmcg sweep`: the runs, tables and plots are in [`crate::driver::sweep`].
fn sweep_main(a: SweepArgs) -> ExitCode {
    let fail = |e: crate::driver::sweep::SweepError| {
        say!("error: {e}");
        ExitCode::from(e.exit_code())
    };
    let input = |m: String| fail(crate::driver::sweep::SweepError::Input(m));
    let (base, _) = match scene::load(&a.scene) {
        Ok(x) => x,
        Err(e) => return scene_error(&e),
    };
    let cells = match crate::driver::sweep::parse_cells(&a.cells) {
        Ok(c) => c,
        Err(m) => return input(m),
    };
    let gradients = match crate::driver::sweep::parse_gradients(&a.gradient) {
        Ok(g) => g,
        Err(m) => return input(m),
    };
    // In-process runs (one rank) use this process's pool, the main thread one of its
    // threads as in `run`; 0 threads is rayon's default count.
    if a.ranks <= 1 {
        let t = a.threads.unwrap_or(0);
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .use_current_thread()
            .build_global()
        {
            say!("error: cannot start {t} threads: {e}");
            return ExitCode::from(1);
        }
    }
    let exe = match std::env::current_exe() {
        Ok(p) => p,
        Err(e) => {
            say!("error: cannot find this program's executable for mpirun: {e}");
            return ExitCode::from(1);
        }
    };
    let opts = crate::driver::sweep::Options {
        scene_file: a.scene.display().to_string(),
        cells,
        gradients,
        ppc: a.ppc,
        ranks: a.ranks,
        threads: a.threads,
        out: a
            .out
            .unwrap_or_else(|| crate::driver::sweep::default_out(&base)),
        exe,
        command: crate::driver::sweep::command_line(std::env::args()),
        quiet: a.quiet,
    };
    match crate::driver::sweep::sweep(&base, &opts) {
        Ok(rows) => {
            let count = |s: &str| rows.iter().filter(|r| r.status == s).count();
            let (unstable, failed) = (count("unstable"), count("failed"));
            if !a.quiet {
                say!(
                    "sweep: {} runs ({unstable} unstable, {failed} failed); report in {}",
                    rows.len(),
                    opts.out.join("report.md").display()
                );
            }
            if failed > 0 {
                say!(
                    "error: {failed} of {} runs failed; see the status column of {}",
                    rows.len(),
                    opts.out.join("results.csv").display()
                );
                return ExitCode::from(1);
            }
            ExitCode::SUCCESS
        }
        Err(e) => fail(e),
    }
}
