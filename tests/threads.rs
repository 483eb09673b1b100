//! The thread count changes no bit of a run. The particle loops sum into the grid per
//! slab and per run of particles that share their nodes (`kernel::scatter`, `remap`),
//! one slab per thread at a time in a fixed order, and split particle-local work at
//! points that depend on the particle count only; so 1, 2 and 3 threads (more threads
//! than this machine's cores) must give identical histories, whose every column is
//! written to the last bit.

#![forbid(unsafe_code)]

mod common;
use common::temp_dir;
use std::path::Path;
use std::process::Command;

/// A neo-Hookean block slides along the floor of a box with slip walls, under gravity,
/// touching the floor's nodes: particles cross cells, slabs and tiles. Enough particles
/// (about 5 000) that the particle loops split their range.
fn scene(dim: usize, gradient: &str, update: &str) -> String {
    let v = |x: f64| vec![format!("{x:?}"); dim].join(", ");
    let (cells, ppc) = if dim == 2 { (32, 4) } else { (16, 2) };
    let faces = ["x", "y", "z"][..dim]
        .iter()
        .map(|a| format!("{a}_lower = \"slip\", {a}_upper = \"slip\""))
        .collect::<Vec<_>>()
        .join(", ");
    let mut g = vec!["0.0".to_string(); dim];
    g[1] = "-9.81".into();
    let mut vel = vec!["0.5".to_string(); dim];
    vel[0] = "1.0".into();
    vel[1] = "0.0".into();
    // On cell faces of both grids (a partly filled cell at the floor makes plain MPM
    // under USL invert a particle within 150 steps, which is not this test's subject).
    let mut blo = vec!["0.125".to_string(); dim];
    blo[1] = "0.0".into();
    let mut bhi = vec!["0.6875".to_string(); dim];
    bhi[1] = "0.5625".into();
    format!(
        r#"
name = "threads"
dim = {dim}
[time]
end = 0.2
cfl = 0.3
[method]
gradient = "{gradient}"
update = "{update}"
[grid]
lower = [{lo}]
upper = [{hi}]
cells = [{cells}]
boundary = {{ {faces} }}
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1.0e6
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = {{ box = {{ lower = [{blo}], upper = [{bhi}] }} }}
particles_per_cell = {ppc}
velocity = [{vel}]
[gravity]
value = [{g}]
[output]
snapshots = false
"#,
        lo = v(0.0),
        hi = v(1.0),
        cells = vec![cells.to_string(); dim].join(", "),
        blo = blo.join(", "),
        bhi = bhi.join(", "),
        vel = vel.join(", "),
        g = g.join(", "),
    )
}

fn run(scene: &Path, out: &Path, threads: usize) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_mpmcg"))
        .arg("run")
        .arg(scene)
        .arg("--out")
        .arg(out)
        .args(["--quiet", "--threads", &threads.to_string()])
        .output()
        .expect("mpmcg runs");
    assert!(
        o.status.success(),
        "{} threads: {}",
        threads,
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::read_to_string(out.join("history.csv")).expect("history.csv")
}

#[test]
fn thread_count_changes_no_bit() {
    for (dim, gradient, update) in [
        (2, "mpm", "musl"),
        (2, "gimp", "usl"),
        (2, "averaged", "usf"),
        (2, "mpmcg", "usl"),
        (2, "mpmcg", "musl"),
        (3, "mpmcg", "musl"),
    ] {
        let dir = temp_dir(&format!("threads-{dim}d-{gradient}-{update}"));
        let sc = dir.join("scene.toml");
        std::fs::write(&sc, scene(dim, gradient, update)).unwrap();
        let one = run(&sc, &dir.join("t1"), 1);
        let rows = one.lines().count();
        assert!(rows > 10, "{dim}D {gradient} {update}: {rows} history rows");
        for threads in [2, 3] {
            let other = run(&sc, &dir.join(format!("t{threads}")), threads);
            assert!(
                other == one,
                "{dim}D {gradient} {update}: {threads} threads differ from 1"
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// The same for a benchmark scene, whose history carries the error norms against the
/// exact solution: the axis-aligned MMS at 64² cells (16 384 particles, so the error
/// sum runs over several fixed chunks), past three sorts (the kept factors of the
/// reference positions then belong to other particles until refreshed).
#[test]
fn thread_count_changes_no_bit_of_the_error_norms() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("inputs/axis_aligned_mms_2d.toml")).unwrap();
    let text = text
        .replace("cells = [16, 16]", "cells = [64, 64]")
        .replace("end = 0.02 ", "end = 0.0015 ")
        + "\n[output]\nsnapshots = false\n";
    assert!(text.contains("cells = [64, 64]") && text.contains("end = 0.0015 "));
    let dir = temp_dir("threads-mms");
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, text).unwrap();
    let one = run(&sc, &dir.join("t1"), 1);
    let header = one.lines().next().unwrap();
    assert!(header.ends_with("displacement_l2,velocity_l2"), "{header}");
    let steps: u64 = one
        .lines()
        .last()
        .unwrap()
        .split(',')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(steps > 60, "{steps} steps: fewer than three sorts");
    for threads in [2, 3] {
        let other = run(&sc, &dir.join(format!("t{threads}")), threads);
        assert!(other == one, "MMS: {threads} threads differ from 1");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `mpmcg run scene --out out` on two ranks free to run on any core, with `threads`
/// per rank or the default; stops the test unless it succeeds.
fn run_two_unbound_ranks(scene: &Path, out: &Path, threads: Option<usize>) {
    let mut cmd = common::mpirun(2);
    cmd.args(["--bind-to", "none"])
        .arg(env!("CARGO_BIN_EXE_mpmcg"))
        .arg("run")
        .arg(scene)
        .arg("--out")
        .arg(out)
        .arg("--quiet");
    if let Some(t) = threads {
        cmd.args(["--threads", &t.to_string()]);
    }
    let o = cmd.output().expect("mpirun runs");
    assert!(
        o.status.success(),
        "2 ranks × {threads:?} threads: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Ranks × threads: two ranks with two threads each (more threads than this machine's
/// cores, unbound) give the bits of two ranks with one thread, MPMCG/MUSL in 2D and 3D,
/// the block crossing the cut between the ranks.
#[test]
fn threads_within_ranks_change_no_bit() {
    for dim in [2, 3] {
        let dir = temp_dir(&format!("ranks-threads-{dim}d"));
        let sc = dir.join("scene.toml");
        std::fs::write(&sc, scene(dim, "mpmcg", "musl")).unwrap();
        let run = |threads: usize| {
            let out = dir.join(format!("r2t{threads}"));
            run_two_unbound_ranks(&sc, &out, Some(threads));
            let summary = std::fs::read_to_string(out.join("summary.json")).unwrap();
            assert!(
                summary.contains(&format!("\"threads\": {threads},")),
                "{summary}"
            );
            std::fs::read_to_string(out.join("history.csv")).expect("history.csv")
        };
        let one = run(1);
        assert!(one.lines().count() > 10, "{dim}D: {one}");
        assert!(
            run(2) == one,
            "{dim}D: 2 ranks × 2 threads differ from 2 × 1"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Without `--threads`, a rank among several takes its share of the cores it may run
/// on: two unbound ranks on this machine's cores share them, so each takes
/// `cores / 2` threads (1 on two cores), not all of them (the node would run twice
/// its cores' threads).
#[test]
fn ranks_share_the_cores_they_may_run_on() {
    let dir = temp_dir("ranks-share-cores");
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, scene(2, "mpmcg", "musl")).unwrap();
    let out = dir.join("r2");
    run_two_unbound_ranks(&sc, &out, None);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    // The CPUs this process may run on, which mpirun's unbound ranks inherit.
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let list = status
        .lines()
        .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))
        .expect("Linux says which CPUs a process may run on");
    let cores: usize = list
        .trim()
        .split(',')
        .map(|r| match r.split_once('-') {
            Some((a, b)) => b.parse::<usize>().unwrap() - a.parse::<usize>().unwrap() + 1,
            None => 1,
        })
        .sum();
    assert_eq!(
        summary["threads"].as_u64(),
        Some((cores / 2).max(1) as u64),
        "{summary}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
