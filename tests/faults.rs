//! Faults a run must end cleanly from, tried as a user would: each case runs the
//! binary (on 1 rank and under `mpirun -n 2`) and asserts the exit status and the one
//! message it names.

mod common;
use common::temp_dir;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

const LOCK: &str = "mpmcg.lock";

/// The binary under test: this build's, or `MPMCG_TEST_BIN` (to show that a case
/// fails on another build, e.g. one from before its fix).
fn bin() -> String {
    std::env::var("MPMCG_TEST_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_mpmcg").into())
}

/// The command that runs `mpmcg` on `ranks` ranks (1: no mpirun), arguments to follow.
fn on_ranks(ranks: usize) -> std::process::Command {
    if ranks == 1 {
        std::process::Command::new(bin())
    } else {
        let mut c = common::mpirun(ranks);
        c.arg(bin());
        c
    }
}

/// Run `mpmcg ARGS` on `ranks` ranks (1: no mpirun).
fn mpmcg(ranks: usize, args: &[&str]) -> Output {
    on_ranks(ranks).args(args).output().unwrap()
}

/// Assert that a run ended with exit 0, showing its stderr if not.
fn assert_ok(o: &Output) {
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Run `mpmcg ARGS --quiet` on one rank and assert that it succeeds.
fn succeeds(args: &[&str]) {
    assert_ok(&mpmcg(1, &[args, &["--quiet"]].concat()));
}

/// A neo-Hookean unit cube filling a 3D grid of `cells` per axis (2 x 2 x 2 particles
/// per cell), run to `end`, with `extra` appended.
fn filled_cube(cells: usize, end: f64, extra: &str) -> String {
    format!(
        "name = \"cube\"\ndim = 3\n[time]\nend = {end:e}\n[grid]\n\
         lower = [0.0, 0.0, 0.0]\nupper = [1.0, 1.0, 1.0]\ncells = [{cells}, {cells}, {cells}]\n\
         [[materials]]\nname = \"m\"\nmodel = \"neo_hookean\"\ndensity = 1000.0\n\
         youngs_modulus = 1.0e6\npoisson_ratio = 0.3\n[[bodies]]\nmaterial = \"m\"\n\
         shape = {{ box = {{ lower = [0.0, 0.0, 0.0], upper = [1.0, 1.0, 1.0] }} }}\n{extra}"
    )
}

/// A body thrown at 1e300 m/s under a CFL step: the step collapses to 1e-302 s.
/// The run used to loop for ever with dt = 0; it now ends as unstable (exit 3) at its
/// first step, on every rank, with one message that says why.
#[test]
fn overflowing_velocity_ends_as_unstable() {
    let text = include_str!("../inputs/default.toml")
        .replacen("velocity = [0.1, 0.1]", "velocity = [1.0e300, 0.1]", 1)
        .replacen("dt = 1.0e-3", "cfl = 0.2", 1);
    assert!(text.contains("1.0e300") && text.contains("cfl = 0.2"));
    let dir = temp_dir("overflow");
    let scene = dir.join("overflow.toml");
    std::fs::write(&scene, text).unwrap();
    for ranks in [1, 2] {
        let out = dir.join(format!("out{ranks}"));
        let o = mpmcg(
            ranks,
            &[
                "run",
                scene.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--quiet",
            ],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(3), "{ranks} rank(s): {err}");
        assert!(
            err.contains("signal speed has blown up"),
            "{ranks} rank(s): {err}"
        );
        assert_eq!(
            err.matches("signal speed has blown up").count(),
            1,
            "{ranks} rank(s): one message: {err}"
        );
        let summary = std::fs::read_to_string(out.join("summary.json")).unwrap();
        assert!(summary.contains("\"unstable\""), "{summary}");
        assert!(
            !out.join(LOCK).exists(),
            "the lock is released after exit 3"
        );
    }
}

/// The default scene, shortened to `end`, with `extra` tables appended.
fn short_scene(end: f64, extra: &str) -> String {
    let text =
        include_str!("../inputs/default.toml").replacen("end = 3.0", &format!("end = {end}"), 1);
    assert!(text.contains(&format!("end = {end}")));
    format!("{text}\n{extra}\n")
}

fn is_root() -> bool {
    std::process::Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false)
}

/// A size-limited tmpfs, unmounted when dropped (also when a test panics).
struct SmallDisk(PathBuf);

impl SmallDisk {
    /// `None` (with the reason printed) when this process may not mount.
    fn mount(dir: &Path, size: &str) -> Option<Self> {
        if !is_root() {
            eprintln!("skipped: mounting a small tmpfs needs root");
            return None;
        }
        std::fs::create_dir_all(dir).unwrap();
        let o = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir)
            .output()
            .unwrap();
        if !o.status.success() {
            eprintln!(
                "skipped: cannot mount a tmpfs: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            return None;
        }
        Some(Self(dir.to_path_buf()))
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg(&self.0).status();
    }
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// A disk that fills up while checkpoints (and, in a second scene, snapshots) are
/// written: on 1 rank this used to segfault at MPI_Finalize (HDF5 closing a file it had
/// failed to flush), on 2 ranks to hang (the aggregating rank failed alone), and to
/// leave the `.tmp` file, with "H5Dwrite failed" as the only reason. Now every rank
/// ends promptly with exit 1 and one message naming the file and the OS's reason, no
/// partial file is left, and the newest checkpoint left restarts.
#[test]
fn full_disk_ends_cleanly_and_keeps_the_last_checkpoint() {
    let dir = temp_dir("full-disk");
    // 200 KiB hold about three 56 KiB checkpoints or snapshots; the scenes write 25.
    let Some(disk) = SmallDisk::mount(&dir.join("disk"), "200k") else {
        return;
    };
    let checkpoints = dir.join("checkpoints.toml");
    std::fs::write(
        &checkpoints,
        short_scene(
            0.5,
            "[output]\nsnapshots = false\n[checkpoint]\nevery_steps = 20\nkeep = 5",
        ),
    )
    .unwrap();
    let snapshots = dir.join("snapshots.toml");
    std::fs::write(&snapshots, short_scene(0.5, "[output]\nevery = 0.02")).unwrap();
    for ranks in [1, 2] {
        for (scene, file) in [(&checkpoints, "checkpoint_"), (&snapshots, "particles_")] {
            let out = disk.0.join(format!("out{ranks}"));
            let start = Instant::now();
            let o = mpmcg(
                ranks,
                &[
                    "run",
                    scene.to_str().unwrap(),
                    "--out",
                    out.to_str().unwrap(),
                    "--quiet",
                ],
            );
            let err = String::from_utf8_lossy(&o.stderr);
            let what = format!("{ranks} rank(s), {file}: {err}");
            assert!(start.elapsed() < Duration::from_secs(60), "no hang: {what}");
            assert_eq!(o.status.code(), Some(1), "{what}");
            let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
            assert_eq!(lines.len(), 1, "one message: {what}");
            assert!(lines[0].contains("No space left on device"), "{what}");
            assert!(
                lines[0].contains(&format!("{}/{file}", out.display())),
                "{what}"
            );
            let left = names(&out);
            assert!(!left.iter().any(|n| n.ends_with(".tmp")), "{left:?}");
            assert!(
                !left.iter().any(|n| n == LOCK),
                "the lock is released: {left:?}"
            );
            let bad = lines[0].split(file).nth(1).expect("a step")[..6].to_string();
            assert!(
                !left.contains(&format!("{file}{bad}.h5")),
                "the partial file {file}{bad}.h5 is deleted: {left:?}"
            );
            if file == "checkpoint_" {
                // The newest checkpoint left is complete: a run continues from it.
                let last = common::files(&out, "checkpoint_")
                    .pop()
                    .expect("a checkpoint");
                let again = dir.join(format!("again{ranks}"));
                let (last, again) = (last.to_str().unwrap(), again.to_str().unwrap());
                succeeds(&["run", "--restart", last, "--out", again]);
            }
            std::fs::remove_dir_all(&out).unwrap();
        }
    }
    drop(disk);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A child process, killed (and reaped) if the test ends before it does.
struct Killed(std::process::Child);

impl Killed {
    /// `mpmcg run SCENE --out OUT --quiet` in the background, its stderr discarded.
    fn run(scene: &std::path::Path, out: &std::path::Path) -> Self {
        Killed(
            std::process::Command::new(bin())
                .args([
                    "run".as_ref(),
                    scene.as_os_str(),
                    "--out".as_ref(),
                    out.as_os_str(),
                    "--quiet".as_ref(),
                ])
                .stderr(std::process::Stdio::null())
                .spawn()
                .unwrap(),
        )
    }

    fn id(&self) -> u32 {
        self.0.id()
    }

    /// Send `sig` and wait for the process to end.
    fn stop(&mut self, sig: i32) -> std::process::ExitStatus {
        // SAFETY: kill(2) on the pid of a child this test started and has not reaped.
        unsafe { libc::kill(self.0.id() as i32, sig) };
        self.0.wait().unwrap()
    }
}

impl Drop for Killed {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Wait until `path` exists (at most `secs` seconds).
fn wait_for(path: &Path, secs: u64) -> bool {
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(secs) {
        if path.exists() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    false
}

/// A second run into the folder of a running one (a rerun, or two jobs with the same
/// --out): it used to interleave history.csv, prune the first run's checkpoints and
/// list its snapshots. Now it is refused with exit 2 and one message naming the holder,
/// on 1 rank and under mpirun, and leaves the first run's lock and files alone; the
/// first run, stopped by SIGTERM, releases the lock.
#[test]
fn second_run_on_a_locked_folder_is_refused() {
    let dir = temp_dir("locked");
    let long = dir.join("long.toml");
    std::fs::write(&long, short_scene(1000.0, "[output]\nsnapshots = false")).unwrap();
    let other = dir.join("other.toml");
    std::fs::write(&other, short_scene(0.1, "")).unwrap();
    let out = dir.join("out");
    let mut first = Killed::run(&long, &out);
    assert!(
        wait_for(&out.join(LOCK), 60),
        "the first run locks its folder"
    );
    let lock = std::fs::read_to_string(out.join(LOCK)).unwrap();
    assert!(lock.contains(&format!("pid = {}", first.id())), "{lock}");
    for ranks in [1, 2] {
        let o = mpmcg(
            ranks,
            &[
                "run",
                other.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--quiet",
            ],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{ranks} rank(s): {err}");
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(lines.len(), 1, "one message: {err}");
        assert!(
            lines[0].contains("in use by another run")
                && lines[0].contains(&format!("pid {}", first.id()))
                && lines[0].contains(LOCK),
            "{err}"
        );
        assert_eq!(std::fs::read_to_string(out.join(LOCK)).unwrap(), lock);
        assert!(
            !out.join("particles_000000.h5").exists(),
            "the second run wrote nothing"
        );
    }
    // SIGTERM: the first run checkpoints, ends with status 4 and unlocks.
    let status = first.stop(libc::SIGTERM);
    assert_eq!(status.code(), Some(4));
    assert!(!out.join(LOCK).exists(), "released after SIGTERM");
    assert!(!common::files(&out, "checkpoint_").is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A lock left by a killed run (this host, a pid that is gone) is taken over, and
/// released at the end; a lock of another host is not (its pid cannot be checked).
#[test]
fn stale_lock_is_taken_over() {
    let dir = temp_dir("stale");
    let scene = dir.join("short.toml");
    std::fs::write(&scene, short_scene(0.05, "")).unwrap();
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    // A pid that has just ended (and is not reused within the test).
    let mut gone = std::process::Command::new("true").spawn().unwrap();
    let dead = gone.id();
    gone.wait().unwrap();
    let host = mpmcg::output::lock::hostname();
    std::fs::write(
        out.join(LOCK),
        format!("mpmcg run lock\nhost = {host}\npid = {dead}\nstarted = 0\n"),
    )
    .unwrap();
    let args = [
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    let o = mpmcg(1, &args);
    assert_ok(&o);
    assert!(out.join("summary.json").exists());
    assert!(!out.join(LOCK).exists(), "released at the end");

    std::fs::write(
        out.join(LOCK),
        "mpmcg run lock\nhost = some-other-node\npid = 1\nstarted = 0\n",
    )
    .unwrap();
    let o = mpmcg(2, &args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("host some-other-node") && err.contains("another host"),
        "{err}"
    );
    assert!(out.join(LOCK).exists(), "another host's lock stays");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A run in a folder that holds an earlier, unrelated run's checkpoints prunes only
/// its own (it used to delete the earlier run's of lower step numbers), says that the
/// others are there, and a restart goes on pruning the checkpoints of the run it
/// continues, not the unrelated ones.
#[test]
fn pruning_deletes_only_this_runs_checkpoints() {
    let dir = temp_dir("prune");
    let out = dir.join("out");
    let scene = |end: f64, every: u64| {
        short_scene(
            end,
            &format!("[output]\nsnapshots = false\n[checkpoint]\nevery_steps = {every}\nkeep = 2"),
        )
    };
    let (a, b) = (dir.join("a.toml"), dir.join("b.toml"));
    std::fs::write(&a, scene(0.03, 10)).unwrap();
    std::fs::write(&b, scene(0.1, 7)).unwrap();
    let run = |args: &[&str]| {
        let o = mpmcg(1, args);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(0), "{args:?}: {err}");
        err
    };
    let o = out.to_str().unwrap();
    run(&["run", a.to_str().unwrap(), "--out", o, "--quiet"]);
    let ckpt = |s: u64| format!("checkpoint_{s:06}.h5");
    let has = |steps: &[u64]| {
        let names = names(&out);
        let got: Vec<&String> = names
            .iter()
            .filter(|n| n.starts_with("checkpoint_"))
            .collect();
        let want: Vec<String> = steps.iter().map(|&s| ckpt(s)).collect();
        assert_eq!(got, want.iter().collect::<Vec<_>>());
    };
    has(&[10, 20]);
    let err = run(&["run", b.to_str().unwrap(), "--out", o, "--quiet"]);
    assert!(
        err.contains(
            "holds 2 checkpoint(s) of another run (checkpoint_000010.h5 ... checkpoint_000020.h5)"
        ),
        "{err}"
    );
    // b's newest two, and a's untouched.
    has(&[10, 20, 91, 98]);
    // A restart of b (run longer) prunes b's, not a's.
    std::fs::write(&b, scene(0.12, 7)).unwrap();
    let from = out.join(ckpt(98));
    run(&[
        "run",
        b.to_str().unwrap(),
        "--restart",
        from.to_str().unwrap(),
        "--quiet",
    ]);
    has(&[10, 20, 112, 119]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A fresh run into a folder that holds an earlier run's snapshots: the old ones go
/// (they used to stay beside the new ones, unlisted in `particles.xmf`, and a script
/// globbing `particles_*.h5` read both runs), with one note, on 1 rank and on 2; the
/// other run's checkpoints stay. A restart keeps the snapshots it continues.
#[test]
fn fresh_run_replaces_an_earlier_runs_snapshots() {
    for ranks in [1, 2] {
        let dir = temp_dir(&format!("stale-snapshots-{ranks}"));
        let out = dir.join("out");
        let scene =
            |end: f64, extra: &str| short_scene(end, &format!("[output]\nevery = 0.01\n{extra}"));
        let (a, b) = (dir.join("a.toml"), dir.join("b.toml"));
        std::fs::write(&a, scene(0.05, "[checkpoint]\nevery_steps = 10")).unwrap();
        std::fs::write(&b, scene(0.02, "")).unwrap();
        let o = out.to_str().unwrap();
        let run = |ranks: usize, scene: &Path| {
            let r = mpmcg(
                ranks,
                &["run", scene.to_str().unwrap(), "--out", o, "--quiet"],
            );
            let err = String::from_utf8_lossy(&r.stderr).into_owned();
            assert_eq!(r.status.code(), Some(0), "{err}");
            err
        };
        let snaps = || -> Vec<String> {
            names(&out)
                .into_iter()
                .filter(|n| n.starts_with("particles_") && n.ends_with(".h5"))
                .collect()
        };
        run(1, &a);
        let first = snaps();
        assert_eq!(first.len(), 6, "{first:?}");
        let ckpts: Vec<String> = names(&out)
            .into_iter()
            .filter(|n| n.starts_with("checkpoint_"))
            .collect();
        assert!(!ckpts.is_empty());
        let err = run(ranks, &b);
        let second = snaps();
        assert_eq!(second.len(), 3, "{ranks} rank(s): {second:?}");
        assert_eq!(
            err.matches("note: removed 6 snapshot(s) of an earlier run from")
                .count(),
            1,
            "{ranks} rank(s): {err}"
        );
        // Every snapshot left is one the new index lists, and the reverse.
        let xmf = std::fs::read_to_string(out.join("particles.xmf")).unwrap();
        let mut listed: Vec<String> = xmf
            .match_indices("particles_")
            .map(|(i, _)| xmf[i..i + "particles_000000.h5".len()].to_string())
            .collect();
        listed.dedup();
        assert_eq!(listed, second, "{ranks} rank(s)");
        let kept: Vec<String> = names(&out)
            .into_iter()
            .filter(|n| n.starts_with("checkpoint_"))
            .collect();
        assert_eq!(kept, ckpts, "the earlier run's checkpoints stay");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Run `mpmcg ARGS` on `ranks` ranks (its own process group), killed if it has not
/// ended after `secs` seconds (then the status has no code).
fn mpmcg_within(ranks: usize, args: &[&str], secs: u64) -> Output {
    let mut cmd = on_ranks(ranks);
    cmd.args(args);
    output_within(cmd, secs)
}

/// The output of `cmd`, killed with its process group after `secs` seconds.
fn output_within(mut cmd: std::process::Command, secs: u64) -> Output {
    use std::os::unix::process::CommandExt;
    cmd.process_group(0)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    let mut child = cmd.spawn().unwrap();
    let t = Instant::now();
    while child.try_wait().unwrap().is_none() && t.elapsed() < Duration::from_secs(secs) {
        std::thread::sleep(Duration::from_millis(50));
    }
    if child.try_wait().unwrap().is_none() {
        // SAFETY: kill(2) on the process group of a child this test started.
        unsafe { libc::kill(-(child.id() as i32), libc::SIGKILL) };
    }
    child.wait_with_output().unwrap()
}

/// `output.every` or `checkpoint.every` of 1e-300 used to run for ever (a snapshot
/// every step of 1e-300 s; a checkpoint schedule loop that never advanced, deaf to
/// SIGTERM), and a `time.dt` of 1e-300 asks for 1e300 steps: each is now refused
/// with exit 2 and one message naming the key and the bound, also under mpirun.
#[test]
fn absurd_intervals_are_refused() {
    let dir = temp_dir("intervals");
    let cases = [
        ("[output]\nevery = 1e-300", "output.every", "snapshots"),
        (
            "[checkpoint]\nevery = 1e-300",
            "checkpoint.every",
            "checkpoints",
        ),
    ];
    for (i, (extra, key, what)) in cases.iter().enumerate() {
        let scene = dir.join(format!("s{i}.toml"));
        std::fs::write(&scene, short_scene(1.0, extra)).unwrap();
        for ranks in [1, 2] {
            let out = dir.join(format!("out{i}-{ranks}"));
            let o = mpmcg_within(
                ranks,
                &[
                    "run",
                    scene.to_str().unwrap(),
                    "--out",
                    out.to_str().unwrap(),
                    "--quiet",
                ],
                // A guard against the endless loop this used to be, not a timing: a
                // loaded machine (mpirun's start-up under a parallel build) took > 30 s.
                120,
            );
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{key}, {ranks} rank(s): {err}");
            let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
            assert_eq!(lines.len(), 1, "one message: {err}");
            assert!(
                lines[0].contains(&format!("key `{key}`"))
                    && lines[0].contains(&format!("1.000e300 {what}"))
                    && lines[0].contains("at most 1e6"),
                "{err}"
            );
        }
    }
    let scene = dir.join("dt.toml");
    std::fs::write(
        &scene,
        short_scene(1.0, "").replacen("dt = 1.0e-3", "dt = 1.0e-300", 1),
    )
    .unwrap();
    let o = mpmcg_within(1, &["check", scene.to_str().unwrap()], 30);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("key `time.dt`") && err.contains("1.000e300 steps"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// An error found before MPI starts is left to rank 0, which finds it too when every
/// rank reads the same file. A scene that only another rank cannot read (a file
/// missing on its node; here an MPMD launch) used to end the job with no message at
/// all: that rank now reports it itself, naming its rank.
#[test]
fn an_error_only_another_rank_finds_is_reported_by_it() {
    let dir = temp_dir("other-rank");
    let good = dir.join("good.toml");
    std::fs::write(&good, short_scene(1.0, "")).unwrap();
    let missing = dir.join("missing.toml");
    let out = dir.join("out");
    let mut cmd = common::mpirun(1);
    let run = |c: &mut std::process::Command, scene: &Path| {
        c.arg(bin()).args([
            "run",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]);
    };
    run(&mut cmd, &good);
    cmd.args([":", "-n", "1"]);
    run(&mut cmd, &missing);
    let o = output_within(cmd, 120);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(lines.len(), 1, "one message: {err}");
    assert!(
        lines[0].starts_with("error (rank 1): ")
            && lines[0].contains("missing.toml")
            && lines[0].contains("cannot read the scene file"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// SIGTERM ends a run within a step even when the scene writes a snapshot and a
/// checkpoint at every step (the most outputs validation allows): exit 4, a final
/// checkpoint, status "interrupted", the lock released. (A regression guard: the
/// intervals that used to make runs deaf to SIGTERM are refused above.)
#[test]
fn sigterm_is_honoured_within_a_step_at_the_highest_output_rate() {
    let dir = temp_dir("sigterm-busy");
    let scene = dir.join("busy.toml");
    // dt = 1e-3 and output.every = end / 1e6 = 1e-3: a snapshot every step.
    std::fs::write(
        &scene,
        short_scene(
            1000.0,
            "[output]\nevery = 1.0e-3\n[checkpoint]\nevery_steps = 1\nkeep = 1",
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let mut run = Killed::run(&scene, &out);
    assert!(
        wait_for(&out.join("particles_000005.h5"), 60),
        "the run writes snapshots"
    );
    let t = Instant::now();
    let status = run.stop(libc::SIGTERM);
    let took = t.elapsed();
    assert_eq!(status.code(), Some(4));
    assert!(
        took < Duration::from_secs(20),
        "ended {took:?} after SIGTERM"
    );
    let summary = std::fs::read_to_string(out.join("summary.json")).unwrap();
    assert!(summary.contains("\"interrupted\""), "{summary}");
    assert_eq!(common::files(&out, "checkpoint_").len(), 1, "keep = 1");
    assert!(!out.join(LOCK).exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Smaller faults, each with exit 2 and one clear message: a scene read from a device
/// without end, an impossible thread count, a restart with nothing to run, an error
/// that quotes megabytes of input, and an error under `mpirun -n 3` (printed by every
/// rank before).
/// A scene whose particles cannot fit is refused before they are seeded: 3D, 150³
/// cells of 2 × 2 × 2 particles (27 million, 4 GiB of particle state) in a process
/// whose address space is capped at 1.5 GB ends with exit status 2 and a message that
/// names the particles, the limit and what to change, within seconds, where it used to
/// end in an allocation failure (exit 134, a backtrace). Under the same cap a scene of
/// 20³ cells runs.
#[test]
fn a_scene_too_large_for_memory_is_refused_before_seeding() {
    let dir = temp_dir("too-large");
    let run = |cells: usize| {
        let sc = dir.join(format!("s{cells}.toml"));
        std::fs::write(&sc, filled_cube(cells, 1.0e-4, "")).unwrap();
        let out = dir.join(format!("o{cells}"));
        let t0 = Instant::now();
        let o = std::process::Command::new("sh")
            .args([
                "-c",
                "ulimit -v 1500000; exec \"$0\" run \"$1\" --out \"$2\" --quiet --threads 1",
                &bin(),
                sc.to_str().unwrap(),
                out.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        (o, t0.elapsed())
    };
    let (o, took) = run(150);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    for words in [
        "the particles do not fit in memory: rank 0 would seed at least",
        "(160 bytes each) takes more than the",
        "its address-space limit (ulimit -v) leaves; run on more nodes, or with fewer particles per cell or a coarser grid",
    ] {
        assert!(err.contains(words), "{words:?} not in: {err}");
    }
    assert!(
        !err.contains("panicked") && !err.contains("backtrace"),
        "{err}"
    );
    assert!(took < Duration::from_secs(60), "refused after {took:?}");
    let (o, _) = run(20);
    assert_ok(&o);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A restart from a checkpoint with more particles than the job's memory can hold:
/// refused before a row is read, on 1 rank and under `mpirun -n 2` (exit 2, one
/// message with the count, both sizes and what to change), where it used to end in an
/// allocation failure and a backtrace (exit 134); a small checkpoint restarts under the
/// same limit. Just past what the check refuses (it counts the particles' state
/// alone), the refused allocation ends the run with exit 2 and one line per rank that
/// ran out, without an abort or a backtrace, on 1 and 2 ranks.
#[test]
fn a_restart_too_large_for_memory_is_refused_before_reading() {
    let dir = temp_dir("restart-too-large");
    // 3D, 2 x 2 x 2 per cell: 50^3 cells hold 1 000 000 particles, whose state (160 MB)
    // is more than a 244 MiB address-space limit leaves beside MPI and HDF5.
    let scene = |cells: usize, end: f64| {
        let extra = "[output]\nsnapshots = false\n[checkpoint]\nevery_steps = 1\nkeep = 1\n";
        filled_cube(cells, end, extra)
    };
    // Two steps each (the step is proportional to the cell), so one checkpoint.
    let checkpoint = |cells: usize| {
        let end = 2.0e-4 * 50.0 / cells as f64;
        let (first, longer) = (
            dir.join(format!("s{cells}.toml")),
            dir.join(format!("l{cells}.toml")),
        );
        std::fs::write(&first, scene(cells, end)).unwrap();
        std::fs::write(&longer, scene(cells, 2.0 * end)).unwrap();
        let out = dir.join(format!("o{cells}"));
        succeeds(&[
            "run",
            first.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        (out.join("checkpoint_000001.h5"), longer)
    };
    let restart = |ranks: usize, (ckpt, sc): &(PathBuf, PathBuf)| {
        let mut cmd = on_ranks(ranks);
        let out = dir.join(format!("restart{ranks}"));
        let _ = std::fs::remove_dir_all(&out);
        cmd.args([
            "run",
            "--restart",
            ckpt.to_str().unwrap(),
            sc.to_str().unwrap(),
        ])
        .args(["--out", out.to_str().unwrap(), "--quiet", "--threads", "1"]);
        with_limit("-v", 250_000, &cmd).output().unwrap()
    };
    let big = checkpoint(50);
    for ranks in [1, 2] {
        let o = restart(ranks, &big);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{ranks} rank(s): {err}");
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(lines.len(), 1, "one message: {err}");
        for words in [
            "the checkpoint's particles do not fit in memory: 1000000 particles, whose state alone takes 152.6 MiB (160 bytes each), more than the",
            "the ranks' address-space limits (ulimit -v) leave; restart on more nodes",
        ] {
            assert!(lines[0].contains(words), "{words:?} not in: {err}");
        }
    }
    for ranks in [1, 2] {
        first_limit_past_the_check_runs_out(ranks, |kb| {
            let mut cmd = on_ranks(ranks);
            let out = dir.join(format!("sweep{ranks}"));
            let _ = std::fs::remove_dir_all(&out);
            cmd.args(["run", "--restart", big.0.to_str().unwrap()])
                .arg(big.1.to_str().unwrap())
                .args(["--out", out.to_str().unwrap(), "--quiet", "--threads", "1"]);
            with_limit("-v", kb, &cmd).output().unwrap()
        });
    }
    let o = restart(1, &checkpoint(10));
    assert_ok(&o);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Run `run(kb)` with the limit raised from 250 000 KB in steps of 25 000 (24 MiB)
/// while the memory check refuses it, and assert that the first run it lets through
/// runs out of memory with one line per rank that did, exit 2 and no abort: the check
/// counts the particles' state alone, the restart needs about three quarters as much
/// again (the grid, the buffers), so the first limit past the check leaves the
/// particles' arrays short, which are ours. (Further up, a limit can leave ours room
/// and HDF5 none, whose allocations it does not always check: a segfault inside
/// `H5AC_create` at one such limit, docs/reliability.md.)
fn first_limit_past_the_check_runs_out(ranks: usize, run: impl Fn(u64) -> Output) {
    let refused = "the checkpoint's particles do not fit in memory";
    for kb in (250_000..=2_000_000).step_by(25_000) {
        let o = run(kb);
        let err = String::from_utf8_lossy(&o.stderr);
        let what = format!("{ranks} rank(s), ulimit -v {kb}: {err}");
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
        if lines.len() == 1 && lines[0].contains(refused) {
            assert_eq!(o.status.code(), Some(2), "{what}");
            continue;
        }
        assert_eq!(o.status.code(), Some(2), "{what}");
        for crash in [
            "panicked",
            "backtrace",
            "memory allocation of",
            "received signal",
        ] {
            assert!(!err.contains(crash), "{what}");
        }
        assert!(!lines.is_empty() && lines.len() <= ranks, "{what}");
        let then = "); run on more nodes, or with fewer particles per cell or a coarser grid (a checkpoint restarts on any rank count)";
        for l in &lines {
            assert!(l.starts_with("error: out of memory on rank "), "{what}");
            assert!(
                l.contains(" more was refused (its address-space limit, ulimit -v, is "),
                "{what}"
            );
            assert!(l.ends_with(then), "{what}");
        }
        return;
    }
    panic!("{ranks} rank(s): the check refused every limit up to 2 GB");
}

#[test]
fn small_input_faults_end_with_exit_2() {
    let dir = temp_dir("small-faults");
    // /dev/zero used to be read until memory ran out: cap this process at 2 GB so that
    // a build without the fix fails instead of exhausting the machine.
    let o = std::process::Command::new("sh")
        .args([
            "-c",
            "ulimit -v 2000000; exec \"$0\" check /dev/zero",
            &bin(),
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "/dev/zero: {err}");
    assert!(err.contains("/dev/zero: larger than 16 MiB"), "{err}");

    let scene = dir.join("short.toml");
    std::fs::write(
        &scene,
        short_scene(0.05, "[checkpoint]\nevery_steps = 20\nkeep = 1"),
    )
    .unwrap();
    let out = dir.join("out");
    let args = [
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    let o = mpmcg(1, &[&args[..], &["--threads", "100000"]].concat());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--threads must be between 1 and 1024"),
        "{err}"
    );

    // A restart whose time.end (0.01) is before the checkpoint's time (0.04).
    let o = mpmcg(1, &args);
    assert_ok(&o);
    let ckpt = out.join("checkpoint_000040.h5");
    assert!(ckpt.exists());
    let earlier = dir.join("earlier.toml");
    std::fs::write(
        &earlier,
        short_scene(0.01, "[checkpoint]\nevery_steps = 20\nkeep = 1"),
    )
    .unwrap();
    for ranks in [1, 2] {
        let o = mpmcg(
            ranks,
            &[
                "run",
                earlier.to_str().unwrap(),
                "--restart",
                ckpt.to_str().unwrap(),
                "--quiet",
            ],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{ranks} rank(s): {err}");
        assert_eq!(err.matches("error:").count(), 1, "{err}");
        assert!(
            err.contains("time.end = 1e-2 is not after the time of checkpoint")
                && err.contains("step 40"),
            "{err}"
        );
    }

    // A 3 MB scene name: the message quotes at most 1000 bytes of it, once on 3 ranks.
    let big = dir.join("big.toml");
    std::fs::write(
        &big,
        short_scene(0.05, "").replacen(
            "name = \"colliding_disks\"",
            &format!("name = \"{}\"", "a b".repeat(1_000_000)),
            1,
        ),
    )
    .unwrap();
    for ranks in [1, 3] {
        let o = mpmcg(ranks, &["run", big.to_str().unwrap(), "--quiet"]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{ranks} rank(s)");
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(
            lines.len(),
            1,
            "{ranks} rank(s): one message, got {}",
            lines.len()
        );
        assert!(lines[0].contains("key `name`") && lines[0].contains("more bytes)"));
        assert!(lines[0].len() < 1200, "{} bytes", lines[0].len());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The pids of `parent`'s children whose environment says they are MPI rank `rank`.
fn rank_pids(parent: u32, rank: usize) -> Vec<i32> {
    let mut v = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        // "pid (comm) state ppid ...": comm may contain spaces, so split after ')'.
        let ppid = stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().nth(1))
            .and_then(|p| p.parse::<u32>().ok());
        let env = std::fs::read(format!("/proc/{pid}/environ")).unwrap_or_default();
        let want = format!("OMPI_COMM_WORLD_RANK={rank}");
        if ppid == Some(parent) && env.split(|&b| b == 0).any(|kv| kv == want.as_bytes()) {
            v.push(pid);
        }
    }
    v
}

/// A rank killed under mpirun (SIGKILL to rank 1): the other ends promptly, mpirun
/// names the rank, and the lock rank 0 held is recognised as stale by the next run in
/// the folder.
#[test]
fn killed_rank_ends_the_job_and_leaves_a_stale_lock() {
    use std::os::unix::process::CommandExt;
    let dir = temp_dir("killed-rank");
    let long = dir.join("long.toml");
    std::fs::write(&long, short_scene(1000.0, "[output]\nsnapshots = false")).unwrap();
    let out = dir.join("out");
    let mut cmd = common::mpirun(2);
    cmd.arg(bin())
        .args([
            "run",
            long.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ])
        .process_group(0)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    let mut job = Killed(cmd.spawn().unwrap());
    assert!(wait_for(&out.join(LOCK), 60), "the job starts");
    std::thread::sleep(Duration::from_millis(500));
    let victims = rank_pids(job.id(), 1);
    assert_eq!(victims.len(), 1, "rank 1 found: {victims:?}");
    let t = Instant::now();
    // SAFETY: kill(2) on a process this test's mpirun started.
    unsafe { libc::kill(victims[0], libc::SIGKILL) };
    let mut waited = None;
    while t.elapsed() < Duration::from_secs(60) {
        if let Some(s) = job.0.try_wait().unwrap() {
            waited = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let took = t.elapsed();
    let status = waited.expect("mpirun ends after a rank is killed");
    assert!(!status.success());
    let mut err = String::new();
    use std::io::Read;
    job.0
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert!(err.contains("rank 1") && err.contains("signal 9"), "{err}");
    eprintln!("the job ended {took:?} after rank 1 was killed");
    assert!(took < Duration::from_secs(30), "{took:?}");
    // The killed job's lock is stale: the next run takes it over.
    assert!(out.join(LOCK).exists(), "a killed rank 0 cannot release it");
    let short = dir.join("short.toml");
    std::fs::write(&short, short_scene(0.05, "")).unwrap();
    succeeds(&[
        "run",
        short.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!out.join(LOCK).exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `cmd` run under `ulimit -f KB` (a file size limit: works without root).
fn with_file_limit(kb: u64, cmd: &std::process::Command) -> std::process::Command {
    with_limit("-f", kb, cmd)
}

/// `cmd` run under `ulimit FLAG KB`.
fn with_limit(flag: &str, kb: u64, cmd: &std::process::Command) -> std::process::Command {
    let mut c = std::process::Command::new("sh");
    c.arg("-c")
        .arg(format!("ulimit {flag} {kb} && exec \"$@\""))
        .arg("sh")
        .arg(cmd.get_program())
        .args(cmd.get_args());
    c
}

/// A file size limit (`ulimit -f`, as a batch system may set) smaller than a
/// checkpoint: exit 1 with one message naming the checkpoint and the OS's reason
/// ("File too large"), no partial file, on 1 and 2 ranks. Here HDF5 also fails to
/// close the file (its final MPI_File_set_size is over the limit too), which used to
/// crash MPI_Finalize (exit 139 on 1 rank); the process now ends without finalising.
#[test]
fn file_size_limit_ends_cleanly() {
    let dir = temp_dir("fsize");
    // About 250 000 particles: a checkpoint of about 27 MB, over the 16 MB limit,
    // which MPI's own start-up files (PMIx shared memory) stay under.
    let scene = dir.join("big.toml");
    std::fs::write(
        &scene,
        short_scene(
            0.01,
            "[output]\nsnapshots = false\n[checkpoint]\nevery_steps = 2\nkeep = 1",
        )
        .replacen("cells = [24, 24]", "cells = [600, 600]", 1),
    )
    .unwrap();
    for ranks in [1, 2] {
        let out = dir.join(format!("out{ranks}"));
        let mut cmd = on_ranks(ranks);
        cmd.args([
            "run",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        let t = Instant::now();
        let o = with_file_limit(16000, &cmd).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(t.elapsed() < Duration::from_secs(60), "no hang");
        assert_eq!(o.status.code(), Some(1), "{ranks} rank(s): {err}");
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(lines.len(), 1, "one message: {err}");
        assert!(
            lines[0].contains("cannot write checkpoint")
                && lines[0].contains("checkpoint_000002.h5")
                && lines[0].contains("File too large"),
            "{err}"
        );
        let left = names(&out);
        assert_eq!(left, ["history.csv"], "no partial file, no lock");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
