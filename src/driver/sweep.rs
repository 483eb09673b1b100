//! `mpmcg sweep`: speed against error (README, "Accuracy against cost"). Runs one
//! benchmark scene for every requested gradient scheme and resolution, each into
//! `OUT/<gradient>_<n>/`, and collects what the runs report into `OUT/results.csv`,
//! `OUT/report.md` (tables with observed convergence orders) and two log–log plots,
//! `error_vs_cells.svg` and `error_vs_wall_time.svg`. The tables and plots are
//! rewritten after every run, so a long sweep that is stopped keeps what it finished.
//!
//! With one rank the runs happen in this process ([`run::run`] on a [`SerialComm`]);
//! with more, each run is `mpirun -n N <exe> run OUT/<gradient>_<n>/scene.toml`, and its
//! `summary.json` is read back.

pub mod plot;
pub mod report;

pub use report::{Row, Stats};

use crate::driver::run::{self, RunError, RunOptions};
use crate::input::scene::{self, Gradient, Method, Quadrature, Scene};
use decomposition::SerialComm;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Why a sweep could not go on.
#[derive(Debug, Clone, PartialEq)]
pub enum SweepError {
    /// Bad input: scene, lists or options (exit 2).
    Input(String),
    /// Files could not be written, or `mpirun` could not be started (exit 1).
    Io(String),
}

impl SweepError {
    pub fn exit_code(&self) -> u8 {
        match self {
            SweepError::Input(_) => 2,
            SweepError::Io(_) => 1,
        }
    }
}

impl std::fmt::Display for SweepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SweepError::Input(m) | SweepError::Io(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for SweepError {}

/// `--cells 8,16,32`: whole numbers >= 1, each once; returned in increasing order.
pub fn parse_cells(list: &str) -> Result<Vec<usize>, String> {
    const HINT: &str = "give a comma-separated list of cell counts such as 8,16,32,64";
    if list.trim().is_empty() {
        return Err(format!("--cells: the list is empty; {HINT}"));
    }
    let mut cells = Vec::new();
    for item in list.split(',') {
        let t = item.trim();
        if t.is_empty() {
            return Err(format!("--cells: empty entry in {list:?}; {HINT}"));
        }
        let n: usize = t
            .parse()
            .map_err(|_| format!("--cells: {t:?} is not a whole number; {HINT}"))?;
        if n == 0 {
            return Err("--cells: cell counts must be >= 1, got 0".into());
        }
        if cells.contains(&n) {
            return Err(format!("--cells: {n} is listed twice"));
        }
        cells.push(n);
    }
    cells.sort_unstable();
    Ok(cells)
}

/// A scheme a sweep runs: a gradient and MPMCG's variant. Each name fixes the method
/// whatever the scene's `[method]` says of quadrature, centroid passes and sharpening:
/// `mpm`, `gimp`, `averaged` and `mpmcg` run with the current defaults of their
/// gradient, `mpmcg-point` is MPMCG at the particle with neither passes nor sharpening,
/// `mpmcg-domain` the domain rule alone and `mpmcg-sharp` the domain rule with
/// `sharpen = 2`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scheme {
    pub gradient: Gradient,
    /// MPMCG's quadrature and β, without centroid passes; `None` takes the defaults.
    pub variant: Option<(Quadrature, f64)>,
}

impl Scheme {
    pub const ALL: [Scheme; 7] = [
        Scheme::defaults(Gradient::Mpm),
        Scheme::defaults(Gradient::Gimp),
        Scheme::defaults(Gradient::Averaged),
        Scheme::defaults(Gradient::Mpmcg),
        Scheme::mpmcg(Quadrature::Point, 0.0),
        Scheme::mpmcg(Quadrature::Domain, 0.0),
        Scheme::mpmcg(Quadrature::Domain, 2.0),
    ];

    /// `gradient` with the current scene defaults.
    pub const fn defaults(gradient: Gradient) -> Self {
        Scheme {
            gradient,
            variant: None,
        }
    }

    /// MPMCG with `quadrature`, no centroid passes and sharpening `beta`.
    const fn mpmcg(quadrature: Quadrature, beta: f64) -> Self {
        Scheme {
            gradient: Gradient::Mpmcg,
            variant: Some((quadrature, beta)),
        }
    }

    pub fn name(self) -> &'static str {
        match self.variant {
            None => self.gradient.name(),
            Some((Quadrature::Point, ..)) => "mpmcg-point",
            Some((Quadrature::Domain, b)) if b > 0.0 => "mpmcg-sharp",
            Some((Quadrature::Domain, ..)) => "mpmcg-domain",
        }
    }

    /// Set `method` to this scheme.
    fn apply(self, method: &mut Method) {
        method.gradient = self.gradient;
        match self.variant {
            None => method.resolve(scene::DEFAULTS, |_| false),
            Some((q, beta)) => {
                method.quadrature = q;
                method.centroid_passes = 0;
                method.sharpen = beta;
            }
        }
    }
}

/// `--gradient mpm,gimp,mpmcg`: known scheme names, each once, in the order given.
pub fn parse_gradients(list: &str) -> Result<Vec<Scheme>, String> {
    let known: Vec<&str> = Scheme::ALL.iter().map(|g| g.name()).collect();
    let hint = format!("known gradients: {}", known.join(", "));
    if list.trim().is_empty() {
        return Err(format!("--gradient: the list is empty; {hint}"));
    }
    let mut out = Vec::new();
    for item in list.split(',') {
        let t = item.trim();
        let g = Scheme::ALL
            .into_iter()
            .find(|g| g.name() == t)
            .ok_or_else(|| format!("--gradient: unknown gradient {t:?}; {hint}"))?;
        if out.contains(&g) {
            return Err(format!("--gradient: {t} is listed twice"));
        }
        out.push(g);
    }
    Ok(out)
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// The grid with `n` cells along the first axis and the other axes scaled in proportion,
/// `cells[a] = n · base[a] / base[0]`; an error unless every axis gets a whole number.
pub fn grid_at(base: &[usize], n: usize) -> Result<Vec<usize>, String> {
    let Some(&c0) = base.first().filter(|&&c| c > 0) else {
        return Err(format!("the scene's grid.cells {base:?} has no first axis"));
    };
    // n must be a multiple of c0 / gcd(c0, base[a]) for every axis.
    let step = base.iter().fold(1, |l, &c| {
        let m = c0 / gcd(c0, c);
        l / gcd(l, m) * m
    });
    base.iter()
        .enumerate()
        .map(|(a, &c)| {
            let m = n * c;
            if !m.is_multiple_of(c0) || m / c0 == 0 {
                Err(format!(
                    "--cells {n}: axis {a} would get {n}·{c}/{c0} cells, not a whole number >= 1; \
                     the sweep keeps the aspect ratio of the scene's grid {base:?}, so every \
                     cell count must be a multiple of {step}"
                ))
            } else {
                Ok(m / c0)
            }
        })
        .collect()
}

/// The scene at resolution `n` with `scheme`'s gradient and quadrature (and `ppc`
/// particles per cell per direction in every body, if given), and its TOML text. The
/// text is parsed and validated again, so what runs is exactly what `scene.toml` says.
pub fn scene_at(
    base: &Scene,
    scheme: Scheme,
    n: usize,
    ppc: Option<usize>,
) -> Result<(Scene, String), String> {
    let mut s = base.clone();
    s.grid.cells = grid_at(&base.grid.cells, n)?;
    scheme.apply(&mut s.method);
    if let Some(p) = ppc {
        for b in &mut s.bodies {
            b.particles_per_cell = p;
        }
    }
    let text = toml::to_string(&s).map_err(|e| format!("cannot write the scene as TOML: {e}"))?;
    let label = format!("<{} with {n} cells, gradient {}>", base.name, scheme.name());
    let parsed = scene::parse(&text, &label).map_err(|e| e.to_string())?;
    Ok((parsed, text))
}

/// What a sweep runs and where.
#[derive(Clone, Debug)]
pub struct Options {
    /// The scene file, for messages.
    pub scene_file: String,
    pub cells: Vec<usize>,
    pub gradients: Vec<Scheme>,
    pub ppc: Option<usize>,
    pub ranks: usize,
    /// Threads per rank; `None`: all of the pool's threads in-process, the `run`
    /// default under mpirun (each rank's share of its node's cores; a row reads what
    /// the run's summary says).
    pub threads: Option<usize>,
    pub out: PathBuf,
    /// The executable `mpirun` starts when `ranks > 1` (normally this program).
    pub exe: PathBuf,
    /// The command line, quoted into the report.
    pub command: String,
    /// No line per run on stderr.
    pub quiet: bool,
}

/// `out/<scene name>_sweep`.
pub fn default_out(scene: &Scene) -> PathBuf {
    PathBuf::from("out").join(format!("{}_sweep", scene.name))
}

/// Quote arguments for a shell where needed and join them; the program is shown by its
/// file name.
pub fn command_line(args: impl IntoIterator<Item = String>) -> String {
    let safe = |c: char| c.is_ascii_alphanumeric() || "_-./,=:+@%".contains(c);
    args.into_iter()
        .enumerate()
        .map(|(i, a)| {
            let a = if i == 0 {
                Path::new(&a)
                    .file_name()
                    .map_or(a.clone(), |f| f.to_string_lossy().into_owned())
            } else {
                a
            };
            if !a.is_empty() && a.chars().all(safe) {
                a
            } else {
                format!("'{}'", a.replace('\'', "'\\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// The part of `summary.json` the sweep reads.
#[derive(Deserialize)]
struct SummaryFile {
    status: String,
    message: Option<String>,
    ranks: usize,
    threads: usize,
    particles: u64,
    steps: u64,
    wall_seconds: f64,
    particle_updates_per_second: f64,
    error: Option<ErrorFile>,
}

/// Norms may be `null` (JSON has no NaN).
#[derive(Deserialize)]
struct ErrorFile {
    displacement_l2: Option<f64>,
    velocity_l2: Option<f64>,
}

fn read_summary(dir: &Path) -> Result<SummaryFile, String> {
    let path = dir.join("summary.json");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

fn io(path: &Path, e: std::io::Error) -> SweepError {
    SweepError::Io(format!("{}: {e}", path.display()))
}

/// How a run ended, before its summary is read: `None` if it wrote one (completed or
/// unstable), else why it failed.
type Failure = Option<String>;

fn run_in_process(scene: &Scene, dir: &Path, threads: usize) -> Result<Failure, SweepError> {
    let opts = RunOptions {
        out: dir.to_path_buf(),
        quiet: true,
        threads,
        ..RunOptions::default()
    };
    match run::run(scene, &SerialComm, &opts) {
        Ok(_) | Err(RunError::Unstable(_) | RunError::Interrupted(_)) => Ok(None),
        Err(RunError::Input(m)) => Ok(Some(m)),
        Err(RunError::Io(m)) => Err(SweepError::Io(m)),
    }
}

/// Is this process root? Open MPI's `mpirun` refuses to run as root without
/// `--allow-run-as-root`.
fn running_as_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .ok()
        .filter(|o| o.status.success())
        .is_some_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

/// The `mpirun` command for one run.
fn mpirun_command(opts: &Options, scene_file: &Path, dir: &Path, as_root: bool) -> Command {
    let mut cmd = Command::new("mpirun");
    cmd.arg("-n")
        .arg(opts.ranks.to_string())
        .arg("--oversubscribe");
    if as_root {
        cmd.arg("--allow-run-as-root");
    }
    cmd.arg(&opts.exe)
        .arg("run")
        .arg(scene_file)
        .arg("--out")
        .arg(dir)
        .arg("--quiet");
    if let Some(t) = opts.threads {
        cmd.arg("--threads").arg(t.to_string());
    }
    cmd
}

/// The line of a failed run's stderr that says why: the program's own `error:` line if
/// there is one, else the last line that is not part of mpirun's dashed boxes.
fn failure_line(stderr: &str) -> &str {
    let lines = || stderr.lines().map(str::trim);
    lines()
        .find(|l| l.starts_with("error:"))
        .or_else(|| lines().rfind(|l| !l.is_empty() && !l.chars().all(|c| c == '-')))
        .unwrap_or("no message")
}

fn run_mpirun(
    opts: &Options,
    scene_file: &Path,
    dir: &Path,
    as_root: bool,
) -> Result<Failure, SweepError> {
    let mut cmd = mpirun_command(opts, scene_file, dir, as_root);
    let out = cmd
        .output()
        .map_err(|e| SweepError::Io(format!("cannot start mpirun: {e}")))?;
    let log = dir.join("mpirun.log");
    let text = format!(
        "$ {cmd:?}\n{}{}\n{}\n",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
        out.status
    );
    std::fs::write(&log, text).map_err(|e| io(&log, e))?;
    // 0: completed, 3: unstable, 4: interrupted; each time the run wrote its summary.
    match out.status.code() {
        Some(0 | 3 | 4) => Ok(None),
        _ => {
            let err = String::from_utf8_lossy(&out.stderr);
            Ok(Some(format!(
                "mpirun {}: {} (see {})",
                out.status,
                failure_line(&err),
                log.display()
            )))
        }
    }
}

fn row_from(
    dir: &Path,
    gradient: Scheme,
    n: usize,
    ranks: usize,
    threads: usize,
    failure: Failure,
) -> Row {
    let failed = |message: String| Row {
        gradient: gradient.name().into(),
        cells: n,
        ranks,
        threads,
        status: "failed".into(),
        message: Some(message),
        stats: None,
    };
    if let Some(m) = failure {
        return failed(m);
    }
    match read_summary(dir) {
        Err(m) => failed(format!("the run left no readable summary: {m}")),
        Ok(s) => {
            let norm =
                |f: fn(&ErrorFile) -> Option<f64>| s.error.as_ref().and_then(f).unwrap_or(f64::NAN);
            Row {
                gradient: gradient.name().into(),
                cells: n,
                ranks: s.ranks,
                threads: s.threads,
                status: s.status.clone(),
                message: s.message.clone(),
                stats: Some(Stats {
                    particles: s.particles,
                    steps: s.steps,
                    wall_seconds: s.wall_seconds,
                    particle_updates_per_second: s.particle_updates_per_second,
                    displacement_l2: norm(|e| e.displacement_l2),
                    velocity_l2: norm(|e| e.velocity_l2),
                }),
            }
        }
    }
}

/// Lines for the report's header: what was run.
fn notes(base: &Scene, opts: &Options) -> Vec<String> {
    let kind = base
        .benchmark
        .as_ref()
        .and_then(|b| serde_json::to_value(b.kind).ok())
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    let grids: Vec<String> = opts
        .cells
        .iter()
        .filter_map(|&n| {
            grid_at(&base.grid.cells, n)
                .ok()
                .map(|g| format!("{n} → {g:?}"))
        })
        .collect();
    let ppc = match opts.ppc {
        Some(p) => format!("{p} in every body (--ppc)"),
        None => {
            let v: Vec<String> = base
                .bodies
                .iter()
                .map(|b| b.particles_per_cell.to_string())
                .collect();
            format!("{} (from the scene)", v.join(", "))
        }
    };
    let how = if opts.ranks > 1 {
        format!("each with `mpirun -n {}`", opts.ranks)
    } else {
        "in one process, one after the other".to_string()
    };
    vec![
        format!(
            "Scene file `{}`: {}D, benchmark `{kind}`, update `{}`, end time {}.",
            opts.scene_file,
            base.dim,
            base.method.update.name(),
            base.time.end
        ),
        format!(
            "Grids (`cells` is the count along x): {}.",
            grids.join(", ")
        ),
        format!("Particles per cell per direction: {ppc}."),
        format!("Runs: {how}; output of each in `<gradient>_<cells>/`."),
    ]
}

/// Write `results.csv`, `report.md` and the two plots for the rows so far.
pub fn write_outputs(base: &Scene, opts: &Options, rows: &[Row]) -> Result<(), SweepError> {
    let write = |name: &str, text: String| {
        let path = opts.out.join(name);
        std::fs::write(&path, text).map_err(|e| io(&path, e))
    };
    write("results.csv", report::csv(rows))?;
    let names: Vec<&str> = opts.gradients.iter().map(|g| g.name()).collect();
    let notes = notes(base, opts);
    let head = report::ReportHeader {
        scene: &base.name,
        command: &opts.command,
        notes: &notes,
    };
    write("report.md", report::markdown(&head, &names, rows))?;
    let series = |x: fn(&Row, &Stats) -> f64| -> Vec<plot::Series> {
        names
            .iter()
            .map(|g| plot::Series {
                name: g.to_string(),
                points: report::rows_of(rows, g)
                    .into_iter()
                    .filter(|r| r.completed())
                    .filter_map(|r| r.stats.as_ref().map(|s| (x(r, s), s.displacement_l2)))
                    .collect(),
            })
            .collect()
    };
    let y_label = "displacement L2 error (max over the run)";
    // Orders 1 and 2 in the cell size h. Against wall time they are slopes −p/(d+1):
    // the cost of a run grows as (1/h)^(d+1), particles times steps (CFL).
    let cost = base.dim + 1;
    let orders = |per: f64, note: &str| -> Vec<plot::Reference> {
        [1.0, 2.0]
            .iter()
            .map(|&p| plot::Reference {
                name: format!("order {p}{note}"),
                slope: -p / per,
            })
            .collect()
    };
    let sup = ["\u{b2}", "\u{b3}", "\u{2074}"][cost - 2];
    let by_cells = series(|r, _| r.cells as f64);
    write(
        "error_vs_cells.svg",
        plot::loglog(&plot::Plot {
            title: &format!("{}: displacement error against resolution", base.name),
            x_label: "cells along x",
            y_label,
            series: &by_cells,
            references: &orders(1.0, ""),
        }),
    )?;
    let by_time = series(|_, s| s.wall_seconds);
    let x_label = if opts.ranks > 1 {
        format!("wall time [s] on {} ranks", opts.ranks)
    } else {
        "wall time [s]".to_string()
    };
    write(
        "error_vs_wall_time.svg",
        plot::loglog(&plot::Plot {
            title: &format!("{}: displacement error against wall time", base.name),
            x_label: &x_label,
            y_label,
            series: &by_time,
            references: &orders(cost as f64, &format!(", cost \u{221d} n{sup}")),
        }),
    )?;
    Ok(())
}

/// Run the sweep. Every scene is built and validated before the first run; a run that
/// becomes unstable or fails is recorded (status `unstable` / `failed`) and the sweep
/// goes on. Returns the rows, gradient by gradient, each by increasing resolution.
pub fn sweep(base: &Scene, opts: &Options) -> Result<Vec<Row>, SweepError> {
    let input = |m: String| Err(SweepError::Input(m));
    if base.benchmark.is_none() {
        return input(format!(
            "{}: the scene has no [benchmark] table, so its runs have no error norms to \
             sweep; use a scene with an exact solution (e.g. inputs/vibrating_bar.toml)",
            opts.scene_file
        ));
    }
    if opts.cells.is_empty() {
        return input("--cells: the list is empty".into());
    }
    if opts.gradients.is_empty() {
        return input("--gradient: the list is empty".into());
    }
    if opts.ranks == 0 {
        return input("--ranks must be >= 1".into());
    }
    if opts.ppc == Some(0) {
        return input("--ppc must be >= 1".into());
    }
    if opts.threads == Some(0) {
        return input("--threads must be >= 1".into());
    }
    for &n in &opts.cells {
        grid_at(&base.grid.cells, n)
            .map_err(|m| SweepError::Input(format!("{}: {m}", opts.scene_file)))?;
    }
    let mut plan = Vec::new();
    for &g in &opts.gradients {
        for &n in &opts.cells {
            let (scene, text) = scene_at(base, g, n, opts.ppc)
                .map_err(|m| SweepError::Input(format!("{}: {m}", opts.scene_file)))?;
            plan.push((g, n, scene, text));
        }
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| io(&opts.out, e))?;
    let as_root = opts.ranks > 1 && running_as_root();
    let threads = opts.threads.unwrap_or(if opts.ranks > 1 {
        1
    } else {
        rayon::current_num_threads()
    });
    let total = plan.len();
    let mut rows = Vec::with_capacity(total);
    for (k, (g, n, scene, text)) in plan.into_iter().enumerate() {
        let dir = opts.out.join(format!("{}_{n}", g.name()));
        std::fs::create_dir_all(&dir).map_err(|e| io(&dir, e))?;
        let summary = dir.join("summary.json");
        if summary.exists() {
            std::fs::remove_file(&summary).map_err(|e| io(&summary, e))?;
        }
        let scene_file = dir.join("scene.toml");
        std::fs::write(&scene_file, &text).map_err(|e| io(&scene_file, e))?;
        let failure = if opts.ranks > 1 {
            run_mpirun(opts, &scene_file, &dir, as_root)?
        } else {
            run_in_process(&scene, &dir, threads)?
        };
        let row = row_from(&dir, g, n, opts.ranks, threads, failure);
        if !opts.quiet {
            let what = match &row.stats {
                Some(s) => format!(
                    "{} steps in {:.3} s, displacement error {:.3e}",
                    s.steps, s.wall_seconds, s.displacement_l2
                ),
                None => row.message.clone().unwrap_or_default(),
            };
            say!(
                "[{}/{total}] {}, {n} cells: {}, {what}",
                k + 1,
                g.name(),
                row.status
            );
        }
        rows.push(row);
        write_outputs(base, opts, &rows)?;
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_lists_are_parsed_sorted_and_checked() {
        assert_eq!(parse_cells("32, 8,16").unwrap(), vec![8, 16, 32]);
        for bad in ["", " ", "8,,16", "8,x", "8.5", "-4", "0,8", "8,8"] {
            let e = parse_cells(bad).unwrap_err();
            assert!(e.starts_with("--cells: "), "{bad:?}: {e}");
        }
        assert!(parse_cells("8,abc")
            .unwrap_err()
            .contains("\"abc\" is not a whole number"));
        assert!(parse_cells("16,8,16")
            .unwrap_err()
            .contains("16 is listed twice"));
    }

    #[test]
    fn gradient_lists_keep_their_order_and_reject_unknown_names() {
        assert_eq!(
            parse_gradients("mpmcg, mpm,gimp").unwrap(),
            vec![
                Scheme::defaults(Gradient::Mpmcg),
                Scheme::defaults(Gradient::Mpm),
                Scheme::defaults(Gradient::Gimp)
            ]
        );
        assert_eq!(
            parse_gradients("mpmcg-domain,mpmcg-point,mpmcg").unwrap(),
            vec![Scheme::ALL[5], Scheme::ALL[4], Scheme::ALL[3]]
        );
        let e = parse_gradients("mpm,bspline").unwrap_err();
        assert!(
            e.contains("unknown gradient \"bspline\"") && e.contains("averaged"),
            "{e}"
        );
        assert!(parse_gradients("").is_err());
        assert!(parse_gradients("mpm,mpm").is_err());
    }

    #[test]
    fn grids_scale_all_axes_in_proportion() {
        assert_eq!(grid_at(&[16], 8).unwrap(), vec![8]);
        assert_eq!(grid_at(&[16, 16], 64).unwrap(), vec![64, 64]);
        assert_eq!(grid_at(&[32, 16, 8], 8).unwrap(), vec![8, 4, 2]);
        assert_eq!(grid_at(&[3, 2], 9).unwrap(), vec![9, 6]);
        // 8 · 2 / 3 is not whole: the message says which multiple works.
        let e = grid_at(&[3, 2], 8).unwrap_err();
        assert!(e.contains("axis 1") && e.contains("multiple of 3"), "{e}");
        let e = grid_at(&[32, 16, 8], 2).unwrap_err();
        assert!(e.contains("multiple of 4"), "{e}");
    }

    fn bar() -> Scene {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/inputs/vibrating_bar.toml");
        scene::load(Path::new(path)).unwrap().0
    }

    #[test]
    fn scenes_at_a_resolution_round_trip_through_toml() {
        let base = bar();
        let (s, text) = scene_at(&base, Scheme::defaults(Gradient::Gimp), 32, Some(4)).unwrap();
        let again = scene::parse(&text, "t").unwrap();
        for sc in [&s, &again] {
            assert_eq!(sc.grid.cells, vec![32]);
            assert_eq!(sc.method.gradient, Gradient::Gimp);
            assert_eq!(sc.bodies[0].particles_per_cell, 4);
            assert_eq!(sc.name, base.name);
            assert_eq!(sc.time.end, base.time.end);
            assert_eq!(sc.method.update, base.method.update);
            assert!(sc.benchmark.is_some());
        }
        // Without --ppc the scene's particles per cell stay.
        let (s, _) = scene_at(&base, Scheme::defaults(Gradient::Mpm), 8, None).unwrap();
        assert_eq!(
            s.bodies[0].particles_per_cell,
            base.bodies[0].particles_per_cell
        );
        // The scene's own validation still applies.
        let e = scene_at(&base, Scheme::defaults(Gradient::Mpm), 8, Some(17)).unwrap_err();
        assert!(e.contains("particles_per_cell"), "{e}");
    }

    #[test]
    fn command_lines_are_quoted_for_a_shell() {
        let args = [
            "/usr/local/bin/mpmcg",
            "sweep",
            "my scene.toml",
            "--cells",
            "8,16",
            "it's",
        ];
        assert_eq!(
            command_line(args.map(String::from)),
            "mpmcg sweep 'my scene.toml' --cells 8,16 'it'\\''s'"
        );
    }

    #[test]
    fn a_failed_run_is_explained_by_its_error_line() {
        let stderr = "error: cannot run on 2 ranks: too few cells\n\
                      ---------------\nPrimary job  terminated normally\n---------------\n";
        assert_eq!(
            failure_line(stderr),
            "error: cannot run on 2 ranks: too few cells"
        );
        assert_eq!(
            failure_line("---\nkilled by signal 9\n---\n"),
            "killed by signal 9"
        );
        assert_eq!(failure_line(""), "no message");
    }

    #[test]
    fn mpirun_command_runs_this_scene_on_n_ranks() {
        let opts = Options {
            ranks: 3,
            threads: Some(2),
            exe: "/bin/mpmcg".into(),
            ..options(
                Path::new("/tmp/x"),
                vec![8],
                vec![Scheme::defaults(Gradient::Mpm)],
            )
        };
        let cmd = mpirun_command(
            &opts,
            Path::new("o/mpm_8/scene.toml"),
            Path::new("o/mpm_8"),
            true,
        );
        assert_eq!(cmd.get_program(), "mpirun");
        let args: Vec<_> = cmd
            .get_args()
            .map(|a| a.to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            args,
            [
                "-n",
                "3",
                "--oversubscribe",
                "--allow-run-as-root",
                "/bin/mpmcg",
                "run",
                "o/mpm_8/scene.toml",
                "--out",
                "o/mpm_8",
                "--quiet",
                "--threads",
                "2"
            ]
        );
        let cmd = mpirun_command(
            &Options {
                threads: None,
                ..opts
            },
            Path::new("s"),
            Path::new("d"),
            false,
        );
        assert!(!cmd
            .get_args()
            .any(|a| a == "--allow-run-as-root" || a == "--threads"));
    }

    fn options(out: &Path, cells: Vec<usize>, gradients: Vec<Scheme>) -> Options {
        Options {
            scene_file: "inputs/vibrating_bar.toml".into(),
            cells,
            gradients,
            ppc: None,
            ranks: 1,
            threads: None,
            out: out.to_path_buf(),
            exe: PathBuf::from("mpmcg"),
            command: "mpmcg sweep inputs/vibrating_bar.toml --cells 8,16 --gradient mpm,mpmcg"
                .into(),
            quiet: true,
        }
    }

    #[test]
    fn a_scene_without_benchmark_is_refused_before_any_run() {
        let dir = std::env::temp_dir().join(format!("mpmcg_sweep_nobench_{}", std::process::id()));
        let mut base = bar();
        base.benchmark = None;
        let e = sweep(
            &base,
            &options(&dir, vec![8], vec![Scheme::defaults(Gradient::Mpm)]),
        )
        .unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("no [benchmark]"), "{e}");
        assert!(!dir.exists(), "nothing is written");
        // A grid that cannot be scaled is also refused up front.
        let mut base = bar();
        base.dim = 2;
        base.grid.cells = vec![16, 8];
        let e = sweep(
            &base,
            &options(&dir, vec![8, 9], vec![Scheme::defaults(Gradient::Mpm)]),
        )
        .unwrap_err();
        assert!(
            matches!(e, SweepError::Input(ref m) if m.contains("multiple of 2")),
            "{e}"
        );
        assert!(!dir.exists());
    }

    /// A time step above the stability limit at 16 cells but not at 8 (h/c = 0.31 and
    /// 0.16 against dt = 0.2): the finer run blows up, is recorded as unstable with its
    /// reason, and is left out of orders and plots; the sweep carries on.
    #[test]
    fn an_unstable_run_is_recorded_and_the_sweep_goes_on() {
        let dir = std::env::temp_dir().join(format!("mpmcg_sweep_unstable_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut base = bar();
        base.time.cfl = None;
        base.time.dt = Some(0.2);
        let opts = options(
            &dir,
            vec![8, 16],
            vec![
                Scheme::defaults(Gradient::Mpm),
                Scheme::defaults(Gradient::Mpmcg),
            ],
        );
        let rows = sweep(&base, &opts).unwrap();
        let status: Vec<_> = rows.iter().map(|r| r.status.as_str()).collect();
        assert_eq!(status, ["completed", "unstable", "completed", "unstable"]);
        for r in rows.iter().filter(|r| !r.completed()) {
            let st = r.stats.as_ref().unwrap();
            assert!(st.steps < 200, "stopped early: {r:?}");
            assert!(r.message.as_ref().unwrap().contains("unstable"), "{r:?}");
        }
        let csv = std::fs::read_to_string(dir.join("results.csv")).unwrap();
        assert_eq!(csv.lines().filter(|l| l.contains(",unstable,")).count(), 2);
        let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
        assert_eq!(md.matches("| unstable |").count(), 2);
        assert_eq!(md.matches("- 16 cells, unstable: ").count(), 2);
        let svg = std::fs::read_to_string(dir.join("error_vs_cells.svg")).unwrap();
        let lines = plot::tests::polylines(&svg);
        assert_eq!(lines.iter().map(Vec::len).collect::<Vec<_>>(), [1, 1]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Real runs of the 1D vibrating bar (milliseconds each): every file appears with a
    /// row per run, the runs' own summaries agree with the rows, and refinement lowers
    /// the error.
    #[test]
    fn sweep_of_the_vibrating_bar_writes_all_outputs() {
        let dir = std::env::temp_dir().join(format!("mpmcg_sweep_bar_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let opts = options(
            &dir,
            vec![8, 16],
            vec![
                Scheme::defaults(Gradient::Mpm),
                Scheme::defaults(Gradient::Mpmcg),
            ],
        );
        let rows = sweep(&bar(), &opts).unwrap();
        assert_eq!(rows.len(), 4);
        let names: Vec<_> = rows
            .iter()
            .map(|r| (r.gradient.as_str(), r.cells))
            .collect();
        assert_eq!(
            names,
            [("mpm", 8), ("mpm", 16), ("mpmcg", 8), ("mpmcg", 16)]
        );
        for r in &rows {
            assert_eq!(r.status, "completed", "{r:?}");
            assert_eq!(r.ranks, 1);
            let st = r.stats.as_ref().unwrap();
            // Two particles per cell over the whole bar.
            assert_eq!(st.particles, 2 * r.cells as u64);
            assert!(st.steps > 0 && st.wall_seconds > 0.0);
            assert!(st.displacement_l2.is_finite() && st.displacement_l2 > 0.0);
            assert!(st.velocity_l2.is_finite() && st.velocity_l2 > 0.0);
            let run_dir = dir.join(format!("{}_{}", r.gradient, r.cells));
            let sc = scene::load(&run_dir.join("scene.toml")).unwrap().0;
            assert_eq!(sc.grid.cells, vec![r.cells]);
            assert_eq!(sc.method.gradient.name(), r.gradient);
            assert!(run_dir.join("summary.json").is_file());
        }
        for g in ["mpm", "mpmcg"] {
            let rs = report::rows_of(&rows, g);
            let e = |i: usize| rs[i].stats.as_ref().unwrap().displacement_l2;
            assert!(
                e(1) < e(0),
                "{g}: refining 8 → 16 cells must lower the error"
            );
        }
        let csv = std::fs::read_to_string(dir.join("results.csv")).unwrap();
        assert_eq!(csv, report::csv(&rows));
        assert_eq!(csv.lines().count(), 5);
        assert_eq!(csv.lines().next().unwrap(), report::CSV_HEADER);
        let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
        assert!(md.contains(&opts.command));
        assert_eq!(md.matches("\n## ").count(), 2);
        assert_eq!(md.matches("| completed |").count(), 4);
        for name in ["error_vs_cells.svg", "error_vs_wall_time.svg"] {
            let svg = std::fs::read_to_string(dir.join(name)).unwrap();
            plot::tests::check_xml(&svg);
            let lines = plot::tests::polylines(&svg);
            assert_eq!(lines.len(), 2, "{name}");
            assert!(lines.iter().all(|l| l.len() == 2), "{name}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
