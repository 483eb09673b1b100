//! The cluster recipes of scripts/slurm/, without a batch system: the Slurm script's
//! dry run (what it would run and submit), and the host-file script for real under
//! mpirun, through a killed rank and a stop request. (The Slurm chain itself was run
//! under a one-node Slurm, scripts/slurm/local_slurm.sh: see the README.)

mod common;

use common::{files, temp_dir};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_mpmcg");

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scripts/slurm")
        .join(name)
}

/// A block of 2 700 particles for about 300 steps, checkpointed every
/// 20 steps, or by the script's wall-clock default without `[checkpoint]`.
fn scene(checkpoint: bool) -> String {
    let mut s = String::from(
        r#"name = "block"
dim = 2
[time]
end = 0.25
cfl = 0.3
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [32, 32]
[[materials]]
name = "m"
model = "linear_elastic"
density = 1.0
youngs_modulus = 100.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = { box = { lower = [0.1, 0.1], upper = [0.9, 0.9] } }
velocity_gradient = { value = [[0.5, 0.0], [0.0, -0.5]], about = [0.5, 0.5] }
"#,
    );
    if checkpoint {
        s += "[checkpoint]\nevery_steps = 20\n";
    }
    s
}

fn text(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr)
}

/// `bash scripts/slurm/mpmcg.sbatch SCENE OUT` in dry-run mode, outside Slurm.
fn sbatch_dry(dir: &Path, scene: &Path, out: &Path, env: &[(&str, &str)]) -> Output {
    let mut c = Command::new("bash");
    c.arg(script("mpmcg.sbatch"))
        .arg(scene)
        .arg(out)
        .current_dir(dir)
        .env("MPMCG", BIN)
        .env("MPMCG_DRY_RUN", "1");
    for (k, _) in std::env::vars().filter(|(k, _)| k.starts_with("SLURM_")) {
        c.env_remove(k);
    }
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().unwrap()
}

#[test]
fn slurm_script_adds_wall_clock_checkpoints_and_chains_from_the_newest() {
    let dir = temp_dir("sbatch-dry");
    let sc = dir.join("block.toml");
    std::fs::write(&sc, scene(false)).unwrap();
    let out = dir.join("out");

    // First job: a fresh start with the chain's scene, then the next job submitted
    // (status 4, interrupted, is what the dry run pretends).
    let o = sbatch_dry(&dir, &sc, &out, &[]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let chain = out.join("chain_scene.toml");
    let chain_text = std::fs::read_to_string(&chain).unwrap();
    assert!(chain_text.starts_with(&scene(false)), "{chain_text}");
    assert!(
        chain_text.ends_with("[checkpoint]\nevery_seconds = 1800\n"),
        "{chain_text}"
    );
    let (s, _) = mpmcg::input::scene::load(&chain).unwrap();
    assert!(s.checkpoint.is_some());
    let srun = format!(
        "dry run: srun {BIN} run {} --out {} --threads 1\n",
        chain.display(),
        out.display()
    );
    assert!(t.contains(&srun), "{t}");
    assert!(t.contains("dry run: sbatch "), "{t}");
    assert!(t.contains("MPMCG_JOB=2"), "{t}");

    // Ranks × threads: each rank's threads on the cores Slurm gives its task, and the
    // next job asks for as many.
    let o = sbatch_dry(&dir, &sc, &out, &[("SLURM_CPUS_PER_TASK", "8")]);
    let t = text(&o);
    let srun = format!(
        "dry run: srun --cpus-per-task=8 --cpu-bind=cores {BIN} run {} --out {} --threads 8\n",
        chain.display(),
        out.display()
    );
    assert!(t.contains(&srun), "{t}");
    let next = t
        .lines()
        .find(|l| l.starts_with("dry run: sbatch "))
        .unwrap_or_else(|| panic!("no next job: {t}"));
    assert!(next.contains(" --cpus-per-task=8 "), "the next job: {next}");

    // Later jobs continue from the newest complete checkpoint (not one being written).
    for f in [
        "checkpoint_000040.h5",
        "checkpoint_000120.h5",
        ".checkpoint_000160.h5.tmp",
    ] {
        std::fs::write(out.join(f), b"").unwrap();
    }
    let o = sbatch_dry(&dir, &sc, &out, &[("MPMCG_JOB", "3")]);
    let t = text(&o);
    let restart = format!("--restart {}\n", out.join("checkpoint_000120.h5").display());
    assert!(t.contains(&restart), "{t}");
    assert!(t.contains("MPMCG_JOB=4"), "{t}");

    // A completed run ends the chain; so does the job limit.
    let o = sbatch_dry(&dir, &sc, &out, &[("MPMCG_DRY_RUN_STATUS", "0")]);
    assert!(
        o.status.success() && !text(&o).contains("sbatch "),
        "{}",
        text(&o)
    );
    let o = sbatch_dry(&dir, &sc, &out, &[("MPMCG_JOB", "20")]);
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    assert!(!text(&o).contains("dry run: sbatch"), "{}", text(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn slurm_script_keeps_a_scenes_own_checkpoints_and_refuses_a_bad_scene() {
    let dir = temp_dir("sbatch-scenes");
    let sc = dir.join("block.toml");
    std::fs::write(&sc, scene(true)).unwrap();
    let o = sbatch_dry(&dir, &sc, &dir.join("own"), &[]);
    assert!(o.status.success(), "{}", text(&o));
    let chain = std::fs::read_to_string(dir.join("own/chain_scene.toml")).unwrap();
    assert_eq!(chain, scene(true));

    let bad = dir.join("bad.toml");
    std::fs::write(&bad, scene(false).replace("cfl = 0.3", "cfl = -1")).unwrap();
    let o = sbatch_dry(&dir, &bad, &dir.join("bad"), &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("time.cfl"), "{}", text(&o));
    assert!(!dir.join("bad/chain_scene.toml").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Processes whose parent is `pid`.
fn children(pid: u32) -> Vec<u32> {
    let mut v = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
            continue;
        };
        // pid (comm) state ppid ...: comm may contain spaces, so split after ')'.
        let Some((head, rest)) = stat.rsplit_once(')') else {
            continue;
        };
        if rest.split_whitespace().nth(1) == Some(&pid.to_string()) {
            if let Some(p) = head.split_whitespace().next().and_then(|x| x.parse().ok()) {
                v.push(p);
            }
        }
    }
    v
}

fn signal(pid: u32, sig: i32) {
    // SAFETY: kill(2) with a pid this test started (the script, or a rank under it).
    unsafe {
        libc::kill(pid as i32, sig);
    }
}

/// Start the host-file script on 2 local slots and wait for its first checkpoint.
fn start_hostfile(dir: &Path, sc: &Path, out: &Path) -> Child {
    let hosts = dir.join("hosts");
    std::fs::write(&hosts, "localhost slots=2\n").unwrap();
    let mut mpirun_args = String::from("--mca mpi_yield_when_idle 1 --timeout 120");
    if Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
    {
        mpirun_args += " --allow-run-as-root";
    }
    let child = Command::new("bash")
        .arg(script("mpmcg-hostfile.sh"))
        .args([&hosts, sc, out])
        .env("MPMCG", BIN)
        .env("MPMCG_MPIRUN_ARGS", mpirun_args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !out.is_dir() || files(out, "checkpoint_").is_empty() {
        assert!(t0.elapsed() < Duration::from_secs(60), "no checkpoint");
        std::thread::sleep(Duration::from_millis(20));
    }
    child
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn hostfile_script_continues_after_a_killed_rank() {
    let dir = temp_dir("hostfile-crash");
    let sc = dir.join("block.toml");
    std::fs::write(&sc, scene(true)).unwrap();
    let out = dir.join("out");
    let child = start_hostfile(&dir, &sc, &out);
    // script → mpirun → ranks: kill one rank as a lost node would.
    let ranks: Vec<u32> = children(child.id())
        .into_iter()
        .flat_map(children)
        .collect();
    assert_eq!(ranks.len(), 2, "{ranks:?}");
    signal(ranks[1], libc::SIGKILL);
    let o = child.wait_with_output().unwrap();
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("continuing from the newest checkpoint"), "{t}");
    let j = summary(&out);
    assert_eq!(j["status"], "completed", "{t}");
    assert!(j["restarted_from"]["step"].as_u64().unwrap() >= 20, "{j}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn hostfile_script_stops_on_request_and_continues_when_rerun() {
    let dir = temp_dir("hostfile-stop");
    let sc = dir.join("block.toml");
    std::fs::write(&sc, scene(true)).unwrap();
    let out = dir.join("out");
    let child = start_hostfile(&dir, &sc, &out);
    signal(child.id(), libc::SIGTERM);
    let o = child.wait_with_output().unwrap();
    let t = text(&o);
    assert_eq!(o.status.code(), Some(4), "{t}");
    assert!(t.contains("stopped on request"), "{t}");
    let j = summary(&out);
    assert_eq!(j["status"], "interrupted", "{t}");
    // Through mpirun as SIGUSR1, which reaches the ranks at once.
    assert!(j["message"].as_str().unwrap().contains("SIGUSR1"), "{j}");
    let stopped_at = summary(&out)["steps"].as_u64().unwrap();

    // The same command again continues from the final checkpoint.
    let o = start_hostfile(&dir, &sc, &out).wait_with_output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let j = summary(&out);
    assert_eq!(j["status"], "completed");
    assert_eq!(
        j["restarted_from"]["step"].as_u64(),
        Some(stopped_at),
        "{j}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
