//! Checkpoints, restart, stop signals and the files a run writes, through the real
//! binary under `mpirun` (1 to 3 ranks, `--oversubscribe`):
//!
//! - a run restarted from its half-way checkpoint ends bit for bit where the
//!   uninterrupted run ends on the same rank count, and within 1e-12 on another;
//! - a run killed with SIGKILL restarts from its last complete checkpoint and ends
//!   like an uninterrupted run; SIGTERM ends a run cleanly with a final checkpoint,
//!   status "interrupted" and exit status 4; a run that turns unstable checkpoints
//!   its last good state, replayed bit for bit from its newest checkpoint (a stop
//!   signal ends the replay), which continues with a smaller step;
//! - a restart may run longer than planned (bit for bit like the longer run) and
//!   refuses any other change to the scene, naming the key;
//! - snapshots and the XDMF index read back;
//! - unusable checkpoints end with exit status 2 and a message naming the file.

mod common;
use common::{files, temp_dir};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_mpmcg");

/// `mpirun -n N mpmcg ARGS...`.
fn mpirun_cmd(n: usize, args: &[&str]) -> Command {
    let mut c = common::mpirun(n);
    c.arg(BIN).args(args);
    c
}

fn mpirun(n: usize, args: &[&str]) -> Output {
    mpirun_cmd(n, args).output().expect("mpirun runs")
}

/// Run and require exit status 0.
fn ok(n: usize, args: &[&str]) {
    let o = mpirun(n, args);
    assert_eq!(
        o.status.code(),
        Some(0),
        "mpirun -n {n} mpmcg {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// Particle state of a snapshot sorted by id: id, then position, velocity, stress and
/// displacement rows (3 + 3 + 9 + 3 values).
type Rows = Vec<(i64, Vec<f64>)>;

fn snapshot(path: &Path) -> Rows {
    let f = hdf5::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let id: Vec<i64> = f.dataset("id").unwrap().read_raw().unwrap();
    let cols: Vec<(Vec<f64>, usize)> = [
        ("position", 3),
        ("velocity", 3),
        ("stress", 9),
        ("displacement", 3),
    ]
    .iter()
    .map(|&(name, w)| (f.dataset(name).unwrap().read_raw::<f64>().unwrap(), w))
    .collect();
    let mut rows: Rows = (0..id.len())
        .map(|i| {
            let mut r = Vec::new();
            for (c, w) in &cols {
                r.extend_from_slice(&c[i * w..(i + 1) * w]);
            }
            (id[i], r)
        })
        .collect();
    rows.sort_by_key(|r| r.0);
    rows
}

fn last_snapshot(out: &Path) -> PathBuf {
    files(out, "particles_").pop().expect("a snapshot")
}

fn summary(out: &Path) -> Value {
    let p = out.join("summary.json");
    serde_json::from_str(
        &std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display())),
    )
    .unwrap()
}

/// The summary fields that describe the simulated state (not the wall clock).
const STATE_KEYS: [&str; 6] = ["steps", "time", "particles", "mass", "momentum", "energy"];

/// Bit-identical final state: the last snapshot, the summary's state fields and the
/// history.
fn assert_identical(a: &Path, b: &Path, what: &str) {
    let (sa, sb) = (snapshot(&last_snapshot(a)), snapshot(&last_snapshot(b)));
    assert_eq!(sa.len(), sb.len(), "{what}: particle count");
    assert!(sa == sb, "{what}: final particle states differ");
    let (ja, jb) = (summary(a), summary(b));
    for k in STATE_KEYS.iter().chain(&["error"]) {
        assert_eq!(ja[k], jb[k], "{what}: summary `{k}`");
    }
    let (ha, hb) = (
        std::fs::read_to_string(a.join("history.csv")).unwrap(),
        std::fs::read_to_string(b.join("history.csv")).unwrap(),
    );
    assert!(ha == hb, "{what}: history.csv differs");
}

/// Every number in a JSON value, in order.
fn numbers(v: &Value, out: &mut Vec<f64>) {
    match v {
        Value::Number(n) => out.push(n.as_f64().unwrap()),
        Value::Array(a) => a.iter().for_each(|x| numbers(x, out)),
        Value::Object(o) => o.values().for_each(|x| numbers(x, out)),
        _ => {}
    }
}

/// The same final state to `tol` relative: positions against the domain size (1),
/// every other field against its largest magnitude, summary numbers against the
/// largest of their group. Returns the largest particle difference.
fn assert_close(a: &Path, b: &Path, tol: f64, what: &str) -> f64 {
    let (sa, sb) = (snapshot(&last_snapshot(a)), snapshot(&last_snapshot(b)));
    assert_eq!(sa.len(), sb.len(), "{what}: particle count");
    // Positions against the domain size, the rest against each field's largest value.
    let field = |k: usize| match k {
        0..3 => 0,
        3..6 => 1,
        6..15 => 2,
        _ => 3,
    };
    let mut scale = [1.0f64, 0.0, 0.0, 0.0];
    for (_, r) in &sa {
        for (k, x) in r.iter().enumerate().skip(3) {
            scale[field(k)] = scale[field(k)].max(x.abs());
        }
    }
    let mut worst = 0.0f64;
    for ((ia, ra), (ib, rb)) in sa.iter().zip(&sb) {
        assert_eq!(ia, ib, "{what}: ids");
        for k in 0..ra.len() {
            let sc = scale[field(k)].max(1e-300);
            worst = worst.max((ra[k] - rb[k]).abs() / sc);
        }
    }
    assert!(
        worst < tol,
        "{what}: particle state differs by {worst:e} (relative)"
    );
    let (ja, jb) = (summary(a), summary(b));
    assert_eq!(ja["steps"], jb["steps"], "{what}: steps");
    for k in ["time", "mass", "momentum", "energy", "error"] {
        let (mut x, mut y) = (Vec::new(), Vec::new());
        numbers(&ja[k], &mut x);
        numbers(&jb[k], &mut y);
        assert_eq!(x.len(), y.len(), "{what}: summary `{k}`");
        let m = x.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
        for (p, q) in x.iter().zip(&y) {
            assert!(
                (p - q).abs() <= tol * m,
                "{what}: summary `{k}`: {p} vs {q}"
            );
        }
    }
    worst
}

/// Axis-aligned MMS in 2D with GIMP: its particles carry every optional array
/// (deformation gradient, reference position, GIMP half-width), a body force does
/// external work, the benchmark errors are tracked, and particles cross block
/// boundaries. Checkpoint half-way in simulated time.
fn mms_scene() -> String {
    let base = include_str!("../inputs/axis_aligned_mms_2d.toml")
        .replace("gradient = \"mpmcg\"", "gradient = \"gimp\"");
    format!(
        "{base}\n[output]\nevery = 0.005\nfields = [\"velocity\", \"stress\", \"displacement\"]\n\n[checkpoint]\nevery = 0.01\n"
    )
}

/// Two disks crossing a periodic box diagonally (every block boundary and periodic
/// face) with MPMCG and MUSL; `cells` per axis, until `end`, with `checkpoint` as the
/// [checkpoint] table's contents.
fn crossing_scene(cells: usize, end: f64, checkpoint: &str) -> String {
    format!(
        r#"name = "crossing"
dim = 2
[time]
end = {end}
cfl = 0.3
[method]
gradient = "mpmcg"
update = "musl"
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [{cells}, {cells}]
boundary = {{ x_lower = "periodic", x_upper = "periodic", y_lower = "periodic", y_upper = "periodic" }}
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = {{ sphere = {{ center = [0.25, 0.3], radius = 0.15 }} }}
velocity = [-0.35, -0.3]
[[bodies]]
material = "m"
shape = {{ sphere = {{ center = [0.75, 0.7], radius = 0.15 }} }}
velocity = [0.3, 0.35]
[output]
every = {end}
fields = ["velocity", "stress", "displacement"]
[checkpoint]
{checkpoint}
"#
    )
}

/// (a) Restart from the half-way checkpoint: 1→1 and 2→2 bit-identical to the
/// uninterrupted run, 2→1 and 1→3 within 1e-12; for the MMS, the crossing disks (with
/// the null-space diagnostic's history column), the same disks under MPMCG's domain
/// rule (its domains follow the restarted `F` and half-widths), with the centroid
/// correction and sharpened averages as well (its offsets are formed afresh each step,
/// from the restarted positions) and the disks seeded `cut` (particles of partial kinds,
/// which the checkpoint names) and brittle (failing, so their stored σ_zz matters).
#[test]
fn restart_continues_the_run() {
    // The brittle crossing fails particles where the disks meet: their stored
    // plane-strain σ_zz (the snapshot's stress entry 8) must restart too.
    let brittle = crossing_scene(16, 1.2, "every = 0.6").replace(
        "model = \"neo_hookean\"",
        "model = \"brittle\"\ntensile_strength = 30.0",
    );
    for (tag, text) in [
        ("mms", mms_scene()),
        (
            "crossing",
            crossing_scene(16, 1.2, "every = 0.6")
                .replace("\"displacement\"]", "\"displacement\", \"null_velocity\"]"),
        ),
        (
            "domain",
            crossing_scene(16, 1.2, "every = 0.6").replace(
                "update = \"musl\"",
                "update = \"musl\"\nquadrature = \"domain\"",
            ),
        ),
        (
            "centroid",
            crossing_scene(16, 1.2, "every = 0.6").replace(
                "update = \"musl\"",
                "update = \"musl\"\nquadrature = \"domain\"\ncentroid_passes = 4\nsharpen = 2.0",
            )
            .replace("[[bodies]]", "[[bodies]]\nseeding = \"cut\""),
        ),
        ("brittle", brittle),
    ] {
        let dir = temp_dir(&format!("restart-{tag}"));
        let sc = dir.join("scene.toml");
        std::fs::write(&sc, &text).unwrap();
        let full = |n: usize| {
            let out = dir.join(format!("full{n}"));
            ok(n, &["run", s(&sc), "--out", s(&out), "--quiet"]);
            out
        };
        let (f1, f2) = (full(1), full(2));
        if tag == "crossing" {
            let h = std::fs::read_to_string(f1.join("history.csv")).unwrap();
            assert!(h.lines().next().unwrap().ends_with(",null_kinetic"));
        }
        let half = |out: &Path| {
            let c = files(out, "checkpoint_");
            assert_eq!(
                c.len(),
                1,
                "{tag}: one checkpoint half-way in {}",
                out.display()
            );
            c[0].clone()
        };
        let (c1, c2) = (half(&f1), half(&f2));
        let restart = |n: usize, ckpt: &Path, name: &str| {
            let out = dir.join(name);
            ok(
                n,
                &["run", "--restart", s(ckpt), "--out", s(&out), "--quiet"],
            );
            let j = summary(&out);
            assert_eq!(j["status"], "completed");
            assert_eq!(j["restarted_from"]["checkpoint"], s(ckpt));
            assert!(j["restarted_from"]["step"].as_u64().unwrap() > 0);
            out
        };
        assert_identical(&f1, &restart(1, &c1, "r11"), &format!("{tag} 1→1"));
        assert_identical(&f2, &restart(2, &c2, "r22"), &format!("{tag} 2→2"));
        let d21 = assert_close(&f2, &restart(1, &c2, "r21"), 1e-12, &format!("{tag} 2→1"));
        let d13 = assert_close(&f1, &restart(3, &c1, "r13"), 1e-12, &format!("{tag} 1→3"));
        eprintln!("{tag}: 2→1 differs by {d21:.1e}, 1→3 by {d13:.1e} (relative)");
        // The scene file given again with --restart must be the stored one, byte for byte.
        let again = dir.join("again");
        ok(
            1,
            &[
                "run",
                s(&sc),
                "--restart",
                s(&c1),
                "--out",
                s(&again),
                "--quiet",
            ],
        );
        assert_identical(&f1, &again, &format!("{tag} 1→1 with SCENE"));
        if tag == "brittle" {
            // Failed particles: σ_zz (row entry 14) off the intact relation ν tr σ.
            let rows = snapshot(&last_snapshot(&f1));
            let scale = rows.iter().fold(0.0f64, |m, r| m.max(r.1[6].abs()));
            let off = rows.iter().fold(0.0f64, |m, r| {
                m.max((r.1[14] - 0.3 * (r.1[6] + r.1[10])).abs())
            });
            assert!(
                off > 1e-3 * scale,
                "no failed particle: {off:e} of {scale:e}"
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// A restart on a coarser process grid reads only the rows of the writers whose blocks
/// overlap its own: from 4 ranks (2 × 2 equal blocks) onto 2 (2 × 1), each reader
/// reads exactly the rows of its two writers, half the file, every row is read once,
/// and the run continues to within 1e-12 of the uninterrupted one.
#[test]
fn restart_reads_only_overlapping_writers() {
    let dir = temp_dir("restart-overlap");
    let sc = dir.join("scene.toml");
    let text = crossing_scene(16, 1.2, "every = 0.6") + "[parallel]\nbalance = \"off\"\n";
    std::fs::write(&sc, text).unwrap();
    let full = dir.join("full4");
    ok(4, &["run", s(&sc), "--out", s(&full), "--quiet"]);
    assert_eq!(summary(&full)["blocks"], serde_json::json!([2, 2]));
    let ckpt = files(&full, "checkpoint_").remove(0);
    let out = dir.join("r42");
    ok(
        2,
        &["run", "--restart", s(&ckpt), "--out", s(&out), "--quiet"],
    );
    let j = summary(&out);
    assert_eq!(j["blocks"], serde_json::json!([2, 1]));
    let n = j["particles"].as_f64().unwrap();
    let read = &j["restarted_from"]["particle_rows_read"];
    // Each writer's rows are read by exactly one reader (sum), and no reader read the
    // whole file (max).
    assert_eq!(read["mean"].as_f64().unwrap() * 2.0, n, "{read}");
    assert!(read["max"].as_f64().unwrap() < n, "{read} of {n}");
    assert_close(&full, &out, 1e-12, "4→2");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A checkpoint of format version 3 (`tests/data/checkpoint_v3_crossing.h5`, written
/// by commit 515929c from the crossing disks at 16 cells, step 54 of 117), whose
/// records hold the neo-Hookean particles' stress, which version 4 forms from `F`:
/// a restart starts from its rows ([`starts_from_its_rows`]) and continues alike on 1
/// and 2 ranks.
#[test]
fn version_3_checkpoint_restarts() {
    let dir = temp_dir("restart-v3");
    let (v3, _) = fixture("checkpoint_v3_crossing.h5", 3);
    fixture_restarts(&dir, &crossing_scene(16, 1.2, "every = 0.6"), &v3, 54);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A checkpoint of format version 4 (`tests/data/checkpoint_v4_two_densities.h5`,
/// written by commit bf943c7 from [`two_densities_scene`], step 76 of 168), whose
/// records hold each particle's mass, which version 5 forms as density × `vol0`. The
/// masses its rows hold sum to the restarted run's mass (a mass formed from another
/// material's density, or a column read out of place, would not); a restart starts
/// from its rows and continues alike on one and two ranks ([`fixture_restarts`]); the
/// checkpoints this build writes are of version 8, without the mass.
#[test]
fn version_4_checkpoint_restarts() {
    let dir = temp_dir("restart-v4");
    let (v4, f) = fixture("checkpoint_v4_two_densities.h5", 4);
    let stored: f64 = {
        let (v, w, cols) = common::checkpoint_table(&f);
        let at = cols
            .iter()
            .position(|c| c == "mass")
            .expect("a mass column");
        v.chunks(w).map(|r| r[at]).sum()
    };
    drop(f);
    let (outs, f) = fixture_restarts(&dir, &two_densities_scene(), &v4, 76);
    for (n, out) in outs.iter().enumerate() {
        let mass = summary(out)["mass"]["final"].as_f64().unwrap();
        assert!(
            (mass - stored).abs() <= 1e-12 * stored,
            "v4 1→{}: mass {mass} against the stored {stored}",
            n + 1
        );
    }
    let (_, _, cols) = common::checkpoint_table(&f);
    assert!(!cols.iter().any(|c| c == "mass"), "{cols:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The particles a restart reads from `ckpt` (with `scene`, on one rank, as a restart
/// reads them) against the checkpoint's own rows, matched by id: every particle once,
/// its position, velocity, deformation gradient and reference position bit for bit.
/// A column read out of place shows here, whatever the build's stepping.
fn starts_from_its_rows(scene: &str, ckpt: &Path) {
    use mpmcg::mpm::particles::{Carries, Kinds};
    use mpmcg::mpm::solver::Solver;
    use mpmcg::output::checkpoint;
    let header = checkpoint::read_header(ckpt).expect("a header");
    // As a restart reads it: with the defaults its run took.
    let scene = mpmcg::input::scene::parse_with(scene, "fixture", header.scene_defaults)
        .expect("the fixture's scene");
    let geom = Solver::<2>::geometry(&scene);
    let cells = [scene.grid.cells[0], scene.grid.cells[1]];
    let layout = decomposition::Layout::choose(cells, geom.periodic, 1).expect("a layout");
    let kinds = Kinds::of_scene(&scene, &geom);
    let carries = Carries::for_scene(&scene);
    let parts = checkpoint::read::<2>(&header, 0, &layout, &geom, carries, &kinds)
        .expect("readable")
        .parts;
    let (rows, w, cols) = common::checkpoint_table(&hdf5::File::open(ckpt).unwrap());
    let at = |name: &str| {
        cols.iter()
            .position(|c| c == name)
            .unwrap_or_else(|| panic!("{}: no column {name} in {cols:?}", ckpt.display()))
    };
    let by_id: std::collections::HashMap<u64, usize> =
        (0..parts.len()).map(|p| (parts.id[p], p)).collect();
    assert_eq!(by_id.len(), rows.len() / w, "{}: particles", ckpt.display());
    for r in rows.chunks(w) {
        let p = by_id[&(r[at("id")] as u64)];
        let what = format!("{}: particle {}", ckpt.display(), parts.id[p]);
        for a in 0..2 {
            assert_eq!(parts.x[p][a], r[at(&format!("x[{a}]"))], "{what}: x[{a}]");
            assert_eq!(parts.v[p][a], r[at(&format!("v[{a}]"))], "{what}: v[{a}]");
            assert_eq!(
                parts.x0[p][a],
                r[at(&format!("x0[{a}]"))],
                "{what}: x0[{a}]"
            );
            for b in 0..2 {
                let name = format!("def_grad[{a}][{b}]");
                assert_eq!(parts.def_grad[p][(a, b)], r[at(&name)], "{what}: {name}");
            }
        }
    }
}

/// The checkpoint `tests/data/{name}`, which must be of format `version`: its path,
/// opened.
fn fixture(name: &str, version: u64) -> (PathBuf, hdf5::File) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name);
    let f = hdf5::File::open(&path).unwrap();
    let v: u64 = f.attr("version").unwrap().read_scalar().unwrap();
    assert_eq!(v, version, "{name}");
    (path, f)
}

/// A restart from fixture `ckpt` (at its step `step`) of `scene` starts from the
/// fixture's rows ([`starts_from_its_rows`]) and, restarted on 1 and 2 ranks, ends
/// alike within 1e-12, with the method of the scene defaults the fixture stores (1 in
/// the fixtures before version 7: MPMCG at the particle, no passes, no sharpening),
/// where `scene` run uninterrupted in `dir` takes this build's defaults (the domain
/// rule, 4 passes, `sharpen = 1`) and writes checkpoints of this build's format
/// (version 8, `scene_defaults` 2). Returns the restarts' folders and the
/// uninterrupted run's first checkpoint, opened.
///
/// The restarts are not compared with the uninterrupted run: the fixture's steps were
/// taken by an older build, whose stepping (the order of the scatter's sums, the
/// volume's update, the velocity's step) may differ from this one's by more than
/// round-off; the rows themselves are the test of the reading.
fn fixture_restarts(dir: &Path, scene: &str, ckpt: &Path, step: u64) -> (Vec<PathBuf>, hdf5::File) {
    starts_from_its_rows(scene, ckpt);
    let defaults = mpmcg::output::checkpoint::read_header(ckpt)
        .expect("a header")
        .scene_defaults;
    let defaults_2 = (json!("domain"), json!(4), json!(1.0));
    let expected = match defaults {
        1 => (json!("point"), Value::Null, Value::Null),
        _ => defaults_2.clone(),
    };
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, scene).unwrap();
    let full = dir.join("full");
    ok(1, &["run", s(&sc), "--out", s(&full), "--quiet"]);
    let mut outs: Vec<PathBuf> = Vec::new();
    for n in [1, 2] {
        let out = dir.join(format!("r{n}"));
        ok(
            n,
            &["run", "--restart", s(ckpt), "--out", s(&out), "--quiet"],
        );
        let sum = summary(&out);
        assert_eq!(sum["restarted_from"]["step"], step);
        let method = (&sum["quadrature"], &sum["centroid_passes"], &sum["sharpen"]);
        assert_eq!(method, (&expected.0, &expected.1, &expected.2), "{n} ranks");
        assert_eq!(sum["scene_defaults"], defaults);
        if let Some(first) = outs.first() {
            assert_close(first, &out, 1e-12, &format!("{} 1→{n}", ckpt.display()));
        }
        outs.push(out);
    }
    let sum = summary(&full);
    let method = (&sum["quadrature"], &sum["centroid_passes"], &sum["sharpen"]);
    assert_eq!(method, (&defaults_2.0, &defaults_2.1, &defaults_2.2));
    let c = files(&full, "checkpoint_");
    let f = hdf5::File::open(&c[0]).unwrap();
    let version: u64 = f.attr("version").unwrap().read_scalar().unwrap();
    assert_eq!(version, 8);
    let defaults: u64 = f.attr("scene_defaults").unwrap().read_scalar().unwrap();
    assert_eq!(defaults, 2);
    (outs, f)
}

/// A checkpoint of format version 5 (`tests/data/checkpoint_v5_kinds.h5`, written by
/// commit 114d179 from [`kinds_scene`], step 76 of 168), whose rows hold each
/// particle's material and `vol0`, which version 6 reads as the particle's kind. The
/// scene's third body is of the first material with 3 × 3 particles per cell, so its
/// kind (2) is not its material (0). Restarted on one and two ranks the run ends like
/// this build's uninterrupted run within 1e-12 (a kind found from the material alone
/// would give those particles the mass and volume of 2 × 2 per cell; not bit for bit,
/// as in `version_4_checkpoint_restarts`: the fixture's volumes were updated by each
/// step's increment, this build's are `det F · V₀`), and every particle keeps its
/// material (the snapshot's `material` by id against the stored rows); the
/// checkpoints this build writes are of version 8: no `vol0` and no `vol` (the disks
/// carry `F`), and the kinds as datasets.
#[test]
fn version_5_checkpoint_restarts_its_kinds() {
    let dir = temp_dir("restart-v5");
    let (v5, f) = fixture("checkpoint_v5_kinds.h5", 5);
    let stored: std::collections::BTreeMap<i64, f64> = {
        let (v, w, cols) = common::checkpoint_table(&f);
        let at = |name: &str| cols.iter().position(|c| c == name).unwrap();
        v.chunks(w)
            .map(|r| (r[at("id")] as i64, r[at("material")]))
            .collect()
    };
    drop(f);
    let (outs, f) = fixture_restarts(&dir, &kinds_scene(), &v5, 76);
    for (n, out) in outs.iter().enumerate() {
        let material = common::scalar_by_id(&last_snapshot(out), "material");
        assert_eq!(material.len(), stored.len());
        for (id, _, m) in material {
            assert_eq!(
                Some(&m),
                stored.get(&id),
                "v5 1→{}: particle {id}'s material",
                n + 1
            );
        }
    }
    let (_, _, cols) = common::checkpoint_table(&f);
    assert!(!cols.iter().any(|c| c == "vol0" || c == "vol"), "{cols:?}");
    let material: Vec<u64> = f.dataset("kind_material").unwrap().read_raw().unwrap();
    let vol0: Vec<f64> = f.dataset("kind_vol0").unwrap().read_raw().unwrap();
    let h2 = 1.0 / 256.0;
    assert_eq!(material, [0, 1, 0]);
    assert_eq!(vol0, [h2 / 4.0, h2 / 4.0, h2 / 9.0]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A checkpoint of format version 7 (`tests/data/checkpoint_v7_kinds.h5`, written by
/// commit f2779d0 from [`kinds_scene`], step 77 of 167, under scene defaults 2), whose
/// kinds of particle are root attributes: a restart reads them, starts from its rows
/// and continues alike on one and two ranks with the defaults it stores
/// ([`fixture_restarts`]); this build writes the same kinds as datasets.
#[test]
fn version_7_checkpoint_restarts_its_kinds() {
    let dir = temp_dir("restart-v7");
    let (v7, f) = fixture("checkpoint_v7_kinds.h5", 7);
    let kinds = |f: &hdf5::File, attribute: bool| -> (Vec<u64>, Vec<f64>) {
        if attribute {
            let m = f.attr("kind_material").unwrap().read_raw().unwrap();
            (m, f.attr("kind_vol0").unwrap().read_raw().unwrap())
        } else {
            let m = f.dataset("kind_material").unwrap().read_raw().unwrap();
            (m, f.dataset("kind_vol0").unwrap().read_raw().unwrap())
        }
    };
    let stored = kinds(&f, true);
    drop(f);
    let (_, f) = fixture_restarts(&dir, &kinds_scene(), &v7, 77);
    assert!(!f
        .attr_names()
        .unwrap()
        .iter()
        .any(|a| a.starts_with("kind_")));
    assert_eq!(kinds(&f, false), stored);
    let _ = std::fs::remove_dir_all(&dir);
}

/// [`two_densities_scene`] with a third disk, of the first material at 3 × 3 particles
/// per cell: three kinds of particle, the third's not its material's index.
fn kinds_scene() -> String {
    two_densities_scene().replace(
        "[output]",
        "[[bodies]]\nmaterial = \"m\"\nshape = { sphere = { center = [0.25, 0.75], radius = 0.1 } }\n\
         velocity = [0.2, 0.0]\nparticles_per_cell = 3\n[output]",
    )
}

/// The crossing disks at 16 cells of two densities, 1000 and 400, so that a mass
/// formed from the wrong material shows.
fn two_densities_scene() -> String {
    crossing_scene(16, 1.2, "every = 0.6")
        .replacen(
            "[[bodies]]",
            "[[materials]]\nname = \"n\"\nmodel = \"neo_hookean\"\ndensity = 400.0\n\
             youngs_modulus = 1000.0\npoisson_ratio = 0.3\n[[bodies]]",
            1,
        )
        .replace(
            "material = \"m\"\nshape = { sphere = { center = [0.75",
            "material = \"n\"\nshape = { sphere = { center = [0.75",
        )
}

/// Plastic particles restart too: the Taylor bar (J2, 3D), cut short at 20 µs with a
/// checkpoint at 10 µs. 2→2 ends bit for bit like the uninterrupted run (summary,
/// history with its plastic_work column, snapshot); 2→1 agrees to 1e-12 in positions
/// (of the bar's length) and plastic strain (of its peak).
#[test]
fn plastic_state_restarts() {
    let dir = temp_dir("restart-taylor");
    let sc = dir.join("scene.toml");
    let text = include_str!("../inputs/taylor_bar.toml")
        .replace("end = 8.0e-5", "end = 2.0e-5")
        .replace("every = 1.0e-5", "every = 2.0e-5")
        .replace(
            "\"plastic_strain\"]",
            "\"plastic_strain\", \"displacement\"]",
        )
        + "\n[checkpoint]\nevery = 1.0e-5\n";
    std::fs::write(&sc, text).unwrap();
    let full = dir.join("full");
    ok(2, &["run", s(&sc), "--out", s(&full), "--quiet"]);
    let c = files(&full, "checkpoint_");
    assert_eq!(c.len(), 1, "one checkpoint half-way: {c:?}");
    let again = |n: usize| {
        let out = dir.join(format!("r{n}"));
        ok(
            n,
            &["run", "--restart", s(&c[0]), "--out", s(&out), "--quiet"],
        );
        out
    };
    assert_identical(&full, &again(2), "taylor 2→2");
    let plastic = |out: &Path| common::scalar_by_id(&last_snapshot(out), "plastic_strain");
    let peak = common::assert_rows_close(&plastic(&full), &plastic(&again(1)), 32.4e-3);
    assert!(peak > 0.5, "plastic flow by 20 µs ({peak})");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A scene with more kinds of particle than an HDF5 attribute holds checkpoints and
/// restarts: 17 balls of 17 materials seeded `cut` in 3D are 17 × 512 kinds, 70 KB of
/// `kind_vol0` (an attribute holds 64 KB; version 7 failed to write the checkpoint).
/// On 2 ranks, with the balls thrown towards the middle, across the blocks' cut, the checkpoint holds
/// the kinds the scene makes and the restart 2→2 ends bit for bit like the
/// uninterrupted run.
#[test]
fn many_kinds_of_particle_restart() {
    let dir = temp_dir("restart-many-kinds");
    let sc = dir.join("scene.toml");
    let mut text = String::from(
        "name = \"many_kinds\"\ndim = 3\n[time]\nend = 0.04\ncfl = 0.4\n[grid]\n\
         lower = [0.0, 0.0, 0.0]\nupper = [6.0, 6.0, 1.0]\ncells = [24, 24, 4]\n\
         [output]\nevery = 0.04\nfields = [\"velocity\", \"stress\", \"displacement\"]\n\
         [checkpoint]\nevery = 0.02\n",
    );
    for m in 0..17 {
        let (x, y) = (0.5 + (m % 5) as f64 * 1.2, 0.5 + (m / 5) as f64 * 1.2);
        let toward = |c: f64| if c < 3.0 { 8.0 } else { -8.0 };
        text += &format!(
            "[[materials]]\nname = \"m{m}\"\nmodel = \"neo_hookean\"\ndensity = {}.0\n\
             youngs_modulus = 1.0e5\npoisson_ratio = 0.3\n[[bodies]]\nmaterial = \"m{m}\"\n\
             shape = {{ sphere = {{ center = [{x}, {y}, 0.5], radius = 0.4 }} }}\n\
             velocity = [{}, {}, 0.0]\nseeding = \"cut\"\n",
            1000 + 10 * m,
            toward(x),
            toward(y)
        );
    }
    std::fs::write(&sc, text).unwrap();
    let full = dir.join("full");
    ok(2, &["run", s(&sc), "--out", s(&full), "--quiet"]);
    let moved = &summary(&full)["halo"]["migration"]["bytes_per_rank_per_step"]["max"];
    assert!(
        moved.as_f64().unwrap() > 0.0,
        "particles handed over: {moved}"
    );
    let c = files(&full, "checkpoint_");
    assert_eq!(c.len(), 1, "one checkpoint half-way: {c:?}");
    let f = hdf5::File::open(&c[0]).unwrap();
    let material: Vec<u64> = f.dataset("kind_material").unwrap().read_raw().unwrap();
    let vol0: Vec<f64> = f.dataset("kind_vol0").unwrap().read_raw().unwrap();
    assert_eq!(material.len(), 17 * 512);
    assert!(8 * vol0.len() > 64 * 1024, "{} kinds", vol0.len());
    assert_eq!(material[17 * 512 - 1], 16);
    drop(f);
    let out = dir.join("r22");
    ok(
        2,
        &["run", "--restart", s(&c[0]), "--out", s(&out), "--quiet"],
    );
    assert_identical(&full, &out, "many kinds 2→2");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The scene of the interruption tests: a run of a few seconds on 2 ranks with a
/// checkpoint every 25 steps.
fn long_scene() -> String {
    crossing_scene(48, 4.0, "every_steps = 25\nkeep = 2")
}

/// The uninterrupted 2-rank run of [`long_scene`], shared by the tests that interrupt it.
fn reference() -> &'static Path {
    static REF: OnceLock<PathBuf> = OnceLock::new();
    REF.get_or_init(|| {
        let dir = temp_dir("interrupt-reference");
        let sc = dir.join("scene.toml");
        std::fs::write(&sc, long_scene()).unwrap();
        let out = dir.join("out");
        ok(2, &["run", s(&sc), "--out", s(&out), "--quiet"]);
        out
    })
}

/// PIDs of the processes whose parent is `pid` (the ranks under `mpirun`: Open MPI
/// puts each in its own process group, so signalling mpirun's group misses them).
fn children(pid: u32) -> Vec<i32> {
    let mut v = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
            continue;
        };
        // pid (comm) state ppid ...: comm may contain spaces, so split after ')'.
        let Some((head, rest)) = stat.rsplit_once(')') else {
            continue;
        };
        let ppid = rest
            .split_whitespace()
            .nth(1)
            .and_then(|x| x.parse::<u32>().ok());
        if ppid == Some(pid) {
            if let Some(p) = head.split_whitespace().next().and_then(|x| x.parse().ok()) {
                v.push(p);
            }
        }
    }
    v
}

fn signal(pid: i32, sig: i32) {
    // SAFETY: kill(2) with a pid this test started.
    unsafe {
        libc::kill(pid, sig);
    }
}

/// Start the long scene on 2 ranks in `out` (its own process group) and wait until a
/// checkpoint exists.
fn start_and_wait_for_checkpoint(out: &Path, scene: &Path) -> Child {
    use std::os::unix::process::CommandExt;
    let mut cmd = mpirun_cmd(2, &["run", s(scene), "--out", s(out), "--quiet"]);
    cmd.process_group(0)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let child = cmd.spawn().expect("start mpirun");
    let t0 = Instant::now();
    while !out.is_dir() || files(out, "checkpoint_").is_empty() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no checkpoint appeared"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    child
}

/// A run that turns unstable (a fixed step about 1.3 times the stable one) checkpoints
/// its last good state, at most ten steps before the failure, with no regular
/// checkpoint scheduled; restarting from it reproduces the run bit for bit up to the
/// same failure: the checkpoint holds the real state, not the failed one.
#[test]
fn unstable_run_checkpoints_its_last_good_state() {
    let dir = temp_dir("unstable");
    let sc = dir.join("scene.toml");
    let text = crossing_scene(16, 3.0, "")
        .replace("cfl = 0.3", "dt = 0.07")
        .replace("[checkpoint]\n", "");
    std::fs::write(&sc, text).unwrap();
    let run = |args: &[&str]| {
        let o = mpirun(2, args);
        assert_eq!(
            o.status.code(),
            Some(3),
            "exit status 3 when unstable: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let first = dir.join("first");
    let err = run(&["run", s(&sc), "--out", s(&first), "--quiet"]);
    let j = summary(&first);
    assert_eq!(j["status"], "unstable");
    let failed = j["steps"].as_u64().unwrap();
    let c = files(&first, "checkpoint_");
    assert_eq!(c.len(), 1, "one checkpoint: {c:?}");
    assert_eq!(j["last_checkpoint"], s(&c[0]));
    let name = c[0].file_name().unwrap().to_str().unwrap();
    let good: u64 = name["checkpoint_".len()..name.len() - 3].parse().unwrap();
    assert!(
        good < failed && good + 10 >= failed,
        "checkpoint at step {good}, failure at step {failed}"
    );
    let said = format!("last good state (step {good},");
    assert!(
        err.contains(&said) && err.contains(s(&c[0])),
        "stderr: {err}"
    );

    let again = dir.join("again");
    run(&["run", "--restart", s(&c[0]), "--out", s(&again), "--quiet"]);
    let k = summary(&again);
    assert_eq!(k["steps"].as_u64(), Some(failed), "fails at the same step");
    assert_eq!(k["restarted_from"]["step"].as_u64(), Some(good));
    let (ha, hb) = (
        std::fs::read_to_string(first.join("history.csv")).unwrap(),
        std::fs::read_to_string(again.join("history.csv")).unwrap(),
    );
    assert!(
        ha == hb,
        "history.csv up to the failure differs after the restart"
    );
    // Continued from the same state with a smaller step, the run completes.
    let smaller = dir.join("smaller.toml");
    std::fs::write(
        &smaller,
        std::fs::read_to_string(&sc)
            .unwrap()
            .replace("dt = 0.07", "dt = 0.02"),
    )
    .unwrap();
    let rescued = dir.join("rescued");
    ok(
        2,
        &[
            "run",
            s(&smaller),
            "--restart",
            s(&c[0]),
            "--out",
            s(&rescued),
            "--quiet",
        ],
    );
    let r = summary(&rescued);
    assert_eq!(r["status"], "completed");
    assert_eq!(r["restarted_from"]["step"].as_u64(), Some(good));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A checkpoint's content as bits: its particle table, run-state datasets and step
/// attributes (all but the lineage, which names the run that wrote it).
fn checkpoint_bits(path: &Path) -> Vec<(String, Vec<u64>)> {
    let f = hdf5::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut out = Vec::new();
    for name in ["particles", "external_work", "snapshot_times"] {
        let v: Vec<f64> = f.dataset(name).unwrap().read_raw().unwrap();
        out.push((name.to_string(), v.iter().map(|x| x.to_bits()).collect()));
    }
    for name in ["rank_rows", "checksum", "snapshot_steps"] {
        out.push((
            name.to_string(),
            f.dataset(name).unwrap().read_raw().unwrap(),
        ));
    }
    let history: Vec<u8> = f.dataset("history").unwrap().read_raw().unwrap();
    out.push((
        "history".into(),
        history.iter().map(|&b| u64::from(b)).collect(),
    ));
    for name in [
        "time",
        "dt",
        "max_speed",
        "energy_scale",
        "next_snapshot_time",
    ] {
        let v: Vec<f64> = f.attr(name).unwrap().read_raw().unwrap();
        out.push((name.to_string(), v.iter().map(|x| x.to_bits()).collect()));
    }
    for name in ["step", "rebalances"] {
        out.push((name.to_string(), f.attr(name).unwrap().read_raw().unwrap()));
    }
    out
}

/// The crossing disks (MPMCG at the particle) with a fixed step a little above the
/// stable one, so that the run fails after some 40 steps, with checkpoints every
/// `every` steps and snapshots that cut steps short.
fn failing_crossing(every: u64) -> String {
    let text = crossing_scene(16, 3.0, &format!("every_steps = {every}"))
        .replace("cfl = 0.3", "dt = 0.0596")
        .replace("every = 3\n", "every = 0.35\n")
        .replace(
            "update = \"musl\"",
            &format!("update = \"musl\"\n{}", common::POINT_RULE),
        );
    assert!(text.contains("every = 0.35") && text.contains("dt = 0.0596"));
    assert!(text.contains(common::POINT_RULE));
    text
}

/// The last good state of an unstable run is replayed, not copied: the run is set up
/// again from its newest checkpoint and stepped to the last tenth step before the
/// failure, and what it checkpoints there is bit for bit what a run that checkpoints
/// that step itself wrote (particles, history, totals, schedule), on 2 ranks and on 3
/// (more than the cores), with particles crossing between them and rebalances on the
/// way. A regular checkpoint newer than that tenth step is itself the last good state.
#[test]
fn rescue_replays_the_run_to_its_last_good_state() {
    let dir = temp_dir("replay");
    // Snapshots cut steps short, so the replay must keep their schedule too.
    let scene = |every: u64| {
        let p = dir.join(format!("every{every}.toml"));
        std::fs::write(&p, failing_crossing(every)).unwrap();
        p
    };
    let unstable = |n: usize, every: u64, out: &Path| {
        let o = mpirun(n, &["run", s(&scene(every)), "--out", s(out)]);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(
            o.status.code(),
            Some(3),
            "exit status 3 when unstable: {err}"
        );
        (summary(out), err)
    };
    let name = |out: &Path, step: u64| out.join(format!("checkpoint_{step:06}.h5"));
    for n in [2, 3] {
        // Checkpoints every 25 steps: the failure comes well after the one at 25.
        let replayed = dir.join(format!("replayed{n}"));
        let (j, err) = unstable(n, 25, &replayed);
        let failed = j["steps"].as_u64().unwrap();
        assert!(failed > 31, "{n} ranks: failed at step {failed}");
        let good = (failed - 1) / 10 * 10;
        assert_eq!(j["last_checkpoint"], s(&name(&replayed, good)));
        assert!(j["balance"]["rebalances"].as_u64().unwrap() > 0);
        assert!(
            err.contains(&format!("replaying from step 25 to step {good}"))
                && err.contains("(replayed from step 25 in"),
            "{n} ranks: {err}"
        );
        // A run that checkpoints the good step itself, which then needs no replay.
        let itself = dir.join(format!("itself{n}"));
        let (k, err) = unstable(n, good / 2, &itself);
        assert_eq!(k["steps"].as_u64(), Some(failed));
        assert_eq!(k["last_checkpoint"], s(&name(&itself, good)));
        assert!(!err.contains("replayed from"), "{n} ranks: {err}");
        assert!(
            checkpoint_bits(&name(&replayed, good)) == checkpoint_bits(&name(&itself, good)),
            "{n} ranks: the replayed state differs from the run's own at step {good}"
        );
    }
    // A regular checkpoint after the last tenth step is the last good state.
    let newer = dir.join("newer");
    let (j, _) = unstable(2, 25, &dir.join("probe"));
    let failed = j["steps"].as_u64().unwrap();
    assert!(
        failed % 10 > 1,
        "a step between the tenth and the failure: {failed}"
    );
    let (k, err) = unstable(2, failed - 1, &newer);
    assert_eq!(k["last_checkpoint"], s(&name(&newer, failed - 1)));
    assert_eq!(files(&newer, "checkpoint_").len(), 1, "{err}");
    assert!(
        err.contains(&format!("the last good state (step {}, ", failed - 1))
            && !err.contains("replayed from"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Under `balance = "time"` the cuts follow the clock, which a replay does not
/// reproduce: the replay makes the run's own moves again. On 2 ranks and on 3 (more
/// than the cores) every unstable run's replay reaches the last good state (it checks
/// the step, time, step size, work, signal speed and a hash of every rank's particles
/// to the bit) and checkpoints it;
/// runs are repeated (at most 10 times) until one moved the blocks after the checkpoint
/// its replay starts from, as the clock decides whether they move (a check every step
/// gives it the most chances).
#[test]
fn rescue_replays_the_moves_of_a_time_balanced_run() {
    let dir = temp_dir("replay-time");
    let p = dir.join("time.toml");
    let text =
        failing_crossing(25) + "[parallel]\nbalance = \"time\"\nimbalance = 1.0\ncheck_every = 1\n";
    std::fs::write(&p, text).unwrap();
    let rebalances = |path: &Path| -> u64 {
        let f = hdf5::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        f.attr("rebalances").unwrap().read_scalar().unwrap()
    };
    for n in [2, 3] {
        let covered = (0..10).any(|attempt| {
            let out = dir.join(format!("time{n}_{attempt}"));
            let o = mpirun(n, &["run", s(&p), "--out", s(&out)]);
            let err = String::from_utf8_lossy(&o.stderr).into_owned();
            assert_eq!(
                o.status.code(),
                Some(3),
                "exit status 3 when unstable: {err}"
            );
            let j = summary(&out);
            let failed = j["steps"].as_u64().unwrap();
            let good = (failed - 1) / 10 * 10;
            let last = out.join(format!("checkpoint_{good:06}.h5"));
            assert!(good > 25, "{n} ranks: failed at step {failed}");
            assert!(
                err.contains(&format!("replaying from step 25 to step {good}"))
                    && err.contains("(replayed from step 25 in"),
                "{n} ranks: {err}"
            );
            assert_eq!(j["last_checkpoint"], s(&last));
            rebalances(&last) > rebalances(&out.join("checkpoint_000025.h5"))
        });
        assert!(covered, "{n} ranks: no run moved its blocks after step 25");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A stop signal during the replay ends it: the run still ends as unstable (exit 3),
/// writes no checkpoint of a state it did not reach, and says so and where it stopped.
/// A disk drifting out through a free face fails after about 2000 steps, with no
/// checkpoint to replay from but the scene; SIGTERM reaches both ranks as the replay
/// begins.
#[test]
fn a_stop_signal_ends_the_replay() {
    use std::io::{BufRead, BufReader, Read};
    let dir = temp_dir("replay-signal");
    let sc = dir.join("scene.toml");
    std::fs::write(
        &sc,
        r#"name = "escape"
dim = 2
[time]
end = 10.0
cfl = 0.3
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [128, 128]
boundary = { x_upper = "free" }
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = { sphere = { center = [0.5, 0.5], radius = 0.3 } }
velocity = [0.05, 0.0]
"#,
    )
    .unwrap();
    let out = dir.join("out");
    let mut child = mpirun_cmd(
        2,
        &["run", s(&sc), "--out", s(&out), "--progress-every", "1000"],
    )
    .stdout(Stdio::null())
    .stderr(Stdio::piped())
    .spawn()
    .expect("start mpirun");
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    loop {
        let mut line = String::new();
        assert!(
            err.read_line(&mut line).unwrap() > 0,
            "no replay began: {seen}"
        );
        seen.push_str(&line);
        if line.starts_with("replaying from step 0 to step ") {
            break;
        }
    }
    let ranks = children(child.id());
    assert_eq!(ranks.len(), 2, "two ranks under mpirun");
    for p in ranks {
        signal(p, libc::SIGTERM);
    }
    err.read_to_string(&mut seen).unwrap();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(3), "stderr: {seen}");
    let j = summary(&out);
    assert_eq!(j["status"], "unstable");
    assert!(j["last_checkpoint"].is_null(), "{j}");
    assert!(files(&out, "checkpoint_").is_empty());
    let m = j["message"].as_str().unwrap();
    assert!(
        m.contains("material left the grid")
            && m.contains("SIGTERM stopped the replay at step ")
            && m.contains("so no checkpoint of the last good state (step ")
            && m.contains("the newest checkpoint is none (restart from the scene)"),
        "{m}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Snapshots and checkpoints are written a block of rows at a time (65 536 per
/// block), each block a collective write: with more rows on one rank than a block,
/// and fewer on the other (73 728 and 36 864 particles, the blocks left where they
/// were seeded), every particle is in the files once, the checkpoint's table holds
/// the snapshot's positions at the same step to the bit, and a restart from the
/// checkpoint ends bit for bit like the uninterrupted run.
#[test]
fn outputs_larger_than_a_block_are_whole() {
    let dir = temp_dir("blocks");
    let sc = dir.join("scene.toml");
    std::fs::write(
        &sc,
        r#"name = "blocks"
dim = 2
[time]
end = 2.0e-4
dt = 1.0e-4
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [192, 192]
[parallel]
balance = "off"
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = { box = { lower = [0.0, 0.0], upper = [0.75, 1.0] } }
velocity = [0.5, 0.2]
[output]
every = 1.0e-4
fields = ["velocity", "stress", "displacement"]
[checkpoint]
every_steps = 1
"#,
    )
    .unwrap();
    let out = dir.join("out");
    ok(2, &["run", s(&sc), "--out", s(&out), "--quiet"]);
    let snap = out.join("particles_000001.h5");
    let f = hdf5::File::open(&snap).unwrap();
    let ranks: Vec<i64> = f.dataset("rank").unwrap().read_raw().unwrap();
    let on = |r: i64| ranks.iter().filter(|&&k| k == r).count();
    assert_eq!((on(0), on(1)), (73_728, 36_864));
    let rows = snapshot(&snap);
    let ids: Vec<i64> = rows.iter().map(|r| r.0).collect();
    assert!(ids == (0..110_592).collect::<Vec<i64>>(), "every id once");
    // The checkpoint of the same step: its rows' positions are the snapshot's.
    let ckpt = out.join("checkpoint_000001.h5");
    let (cells, width, columns) = common::checkpoint_table(&hdf5::File::open(&ckpt).unwrap());
    let col = |name: &str| {
        columns
            .iter()
            .position(|c| c == name)
            .unwrap_or_else(|| panic!("no column {name}: {columns:?}"))
    };
    let (x, y, id) = (col("x[0]"), col("x[1]"), col("id"));
    let mut from_table: Vec<(i64, [u64; 2])> = cells
        .chunks(width)
        .map(|r| (r[id] as i64, [r[x].to_bits(), r[y].to_bits()]))
        .collect();
    from_table.sort_by_key(|r| r.0);
    let from_snapshot: Vec<(i64, [u64; 2])> = rows
        .iter()
        .map(|(i, r)| (*i, [r[0].to_bits(), r[1].to_bits()]))
        .collect();
    assert!(from_table == from_snapshot, "the checkpoint's positions");
    let again = dir.join("again");
    ok(
        2,
        &["run", "--restart", s(&ckpt), "--out", s(&again), "--quiet"],
    );
    assert_identical(&out, &again, "restart 2→2 from a checkpoint of 3 blocks");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A restart may run longer (and change the step size, output interval, checkpoints):
/// a run to t = 1.2 restarted from its checkpoint at 0.6 with the scene's end moved to
/// 2.4 ends bit for bit like a run straight to 2.4. Anything else that differs is
/// refused with exit 2, naming the key.
#[test]
fn restart_with_a_longer_end() {
    let dir = temp_dir("restart-longer");
    let short = crossing_scene(16, 1.2, "every = 0.6");
    let long = short.replacen("end = 1.2", "end = 2.4", 1);
    let (ss, sl) = (dir.join("short.toml"), dir.join("long.toml"));
    std::fs::write(&ss, &short).unwrap();
    std::fs::write(&sl, &long).unwrap();
    let straight = dir.join("straight");
    ok(2, &["run", s(&sl), "--out", s(&straight), "--quiet"]);
    let first = dir.join("first");
    ok(2, &["run", s(&ss), "--out", s(&first), "--quiet"]);
    let c = files(&first, "checkpoint_");
    assert_eq!(c.len(), 1, "{c:?}");
    let longer = dir.join("longer");
    ok(
        2,
        &[
            "run",
            s(&sl),
            "--restart",
            s(&c[0]),
            "--out",
            s(&longer),
            "--quiet",
        ],
    );
    let (a, b) = (
        snapshot(&last_snapshot(&straight)),
        snapshot(&last_snapshot(&longer)),
    );
    assert!(a == b, "final states differ");
    let (ja, jb) = (summary(&straight), summary(&longer));
    for k in ["steps", "time", "particles", "mass", "momentum"] {
        assert_eq!(ja[k], jb[k], "summary `{k}`");
    }
    for (name, from, to, key) in [
        (
            "stiffer",
            "youngs_modulus = 1000.0",
            "youngs_modulus = 2000.0",
            "materials[0].youngs_modulus",
        ),
        (
            "fields",
            "fields = [\"velocity\", \"stress\", \"displacement\"]",
            "fields = [\"velocity\"]",
            "output.fields",
        ),
        (
            "scheme",
            "gradient = \"mpmcg\"",
            "gradient = \"mpm\"",
            "method.gradient",
        ),
    ] {
        let f = dir.join(format!("{name}.toml"));
        std::fs::write(&f, long.replacen(from, to, 1)).unwrap();
        let words = format!("key `{key}` differs from the scene of checkpoint");
        rejected(
            &[
                "run",
                s(&f),
                "--restart",
                s(&c[0]),
                "--out",
                s(&dir.join(name)),
                "--quiet",
            ],
            &f,
            &words,
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// (b) SIGKILL to every process mid-run, then a restart from the newest complete
/// checkpoint in the same folder ends exactly like the uninterrupted run.
#[test]
fn killed_run_restarts_from_its_last_checkpoint() {
    let reference = reference();
    let dir = temp_dir("sigkill");
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, long_scene()).unwrap();
    let out = dir.join("out");
    let mut child = start_and_wait_for_checkpoint(&out, &sc);
    std::thread::sleep(Duration::from_millis(150));
    for p in children(child.id()) {
        signal(p, libc::SIGKILL);
    }
    signal(-(child.id() as i32), libc::SIGKILL);
    let _ = child.wait();
    assert!(
        !out.join("summary.json").exists(),
        "the run ended before it was killed; make the scene longer"
    );
    // Whatever the kill interrupted, every file with a checkpoint's name is complete.
    let ckpts = files(&out, "checkpoint_");
    assert!(!ckpts.is_empty());
    for c in &ckpts {
        mpmcg::output::checkpoint::read_header(c).unwrap_or_else(|e| panic!("{e}"));
    }
    let newest = ckpts.last().unwrap();
    eprintln!(
        "killed after {}; restarting from it",
        newest.file_name().unwrap().to_string_lossy()
    );
    ok(2, &["run", "--restart", s(newest), "--quiet"]);
    assert_eq!(summary(&out)["status"], "completed");
    assert_identical(reference, &out, "SIGKILL, then restart 2→2");
    // keep = 2: only the newest two checkpoints remain, and no temporary file.
    assert_eq!(files(&out, "checkpoint_").len(), 2);
    let tmp: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(tmp.is_empty(), "temporary files left: {tmp:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// (b) A crash in the middle of writing a checkpoint (every rank aborts after writing
/// the particles of step 50): the previous checkpoint is intact, the half-written file
/// keeps its temporary name, and a restart from step 25 ends like the uninterrupted run.
#[test]
fn crash_while_writing_a_checkpoint_keeps_the_previous_one() {
    let reference = reference();
    let dir = temp_dir("crash-in-write");
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, long_scene()).unwrap();
    let out = dir.join("out");
    let o = mpirun_cmd(2, &["run", s(&sc), "--out", s(&out), "--quiet"])
        .env("MPMCG_TEST_CRASH_IN_CHECKPOINT", "50")
        .output()
        .unwrap();
    assert_ne!(o.status.code(), Some(0));
    assert!(!out.join("summary.json").exists());
    assert_eq!(
        files(&out, "checkpoint_"),
        [out.join("checkpoint_000025.h5")]
    );
    assert!(out.join(".checkpoint_000050.h5.tmp").exists());
    let h = mpmcg::output::checkpoint::read_header(&out.join("checkpoint_000025.h5")).unwrap();
    assert_eq!(h.step, 25);
    ok(
        2,
        &[
            "run",
            "--restart",
            s(&out.join("checkpoint_000025.h5")),
            "--quiet",
        ],
    );
    assert_identical(
        reference,
        &out,
        "crash in a checkpoint write, then restart 2→2",
    );
    assert!(!out.join(".checkpoint_000050.h5.tmp").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// (c) SIGTERM to the ranks (what a scheduler such as Slurm sends to every task before
/// killing a job): the step is finished, a final checkpoint written, the summary says
/// "interrupted", the exit status is 4; restarting from that checkpoint ends exactly like
/// the uninterrupted run.
#[test]
fn sigterm_writes_a_final_checkpoint_and_exits_4() {
    let reference = reference();
    let dir = temp_dir("sigterm");
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, long_scene()).unwrap();
    let out = dir.join("out");
    let child = start_and_wait_for_checkpoint(&out, &sc);
    let ranks = children(child.id());
    assert_eq!(ranks.len(), 2, "two ranks under mpirun");
    for p in ranks {
        signal(p, libc::SIGTERM);
    }
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(4), "stderr: {err}");
    assert!(
        err.contains("interrupted: stopped by SIGTERM"),
        "stderr: {err}"
    );
    let j = summary(&out);
    assert_eq!(j["status"], "interrupted");
    let step = j["steps"].as_u64().unwrap();
    assert!(step < summary(reference)["steps"].as_u64().unwrap());
    let ckpt = out.join(format!("checkpoint_{step:06}.h5"));
    assert_eq!(j["last_checkpoint"], s(&ckpt));
    assert!(j["message"].as_str().unwrap().contains(s(&ckpt)));
    let h = mpmcg::output::checkpoint::read_header(&ckpt).unwrap();
    assert_eq!((h.step, h.ranks), (step, 2));
    assert!((h.time - j["time"].as_f64().unwrap()).abs() <= 1e-15 * h.time);
    assert_eq!(h.scene_text, long_scene());
    ok(2, &["run", "--restart", s(&ckpt), "--quiet"]);
    assert_identical(reference, &out, "SIGTERM, then restart 2→2");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The XDMF index of the snapshots `snaps` in `out`: every DataItem names an existing
/// dataset of the stated size (5 snapshots of 8 items), and the times are those of the
/// files.
fn check_xdmf_index(out: &Path, snaps: &[PathBuf]) {
    let xmf = std::fs::read_to_string(out.join("particles.xmf")).unwrap();
    let mut items = 0;
    for part in xmf.split("<DataItem ").skip(1) {
        let dims: Vec<usize> = part
            .split("Dimensions=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .split_whitespace()
            .map(|d| d.parse().unwrap())
            .collect();
        let target = part.split('>').nth(1).unwrap().split('<').next().unwrap();
        let (file, path) = target.split_once(":/").expect("file.h5:/path");
        let f = hdf5::File::open(out.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        let ds = f
            .dataset(path)
            .unwrap_or_else(|e| panic!("{file}:/{path}: {e}"));
        assert_eq!(ds.shape(), dims, "{target}");
        items += 1;
    }
    assert_eq!(
        items,
        5 * 8,
        "connectivity, position, id, rank, material and three fields per snapshot"
    );
    let times: Vec<f64> = xmf
        .split("<Time Value=\"")
        .skip(1)
        .map(|t| t.split('"').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times.len(), snaps.len());
    for (t, p) in times.iter().zip(snaps) {
        let f = hdf5::File::open(p).unwrap();
        assert_eq!(*t, f.attr("time").unwrap().read_scalar::<f64>().unwrap());
    }
}

/// (d) Snapshots and the XDMF index of a uniformly translating body on 2 ranks: shapes,
/// ids, positions, the exact velocity, and every `file.h5:/path` of the index exists
/// with the dimensions the index states.
#[test]
fn snapshots_and_xdmf_read_back() {
    let dir = temp_dir("snapshots");
    let sc = dir.join("scene.toml");
    let (vx, vy) = (0.5, -0.25);
    // MPMCG at the particle: its projections keep velocities that are powers of two.
    let point = common::POINT_RULE;
    std::fs::write(
        &sc,
        format!(
            r#"name = "translate"
dim = 2
[time]
end = 0.5
cfl = 0.4
[method]
{point}
[grid]
lower = [0.0, 0.0]
upper = [2.0, 1.0]
cells = [16, 8]
boundary = {{ x_lower = "periodic", x_upper = "periodic", y_lower = "periodic", y_upper = "periodic" }}
[[materials]]
name = "m"
model = "linear_elastic"
density = 1.0
youngs_modulus = 100.0
poisson_ratio = 0.25
[[bodies]]
material = "m"
shape = {{ box = {{ lower = [0.0, 0.0], upper = [2.0, 1.0] }} }}
particles_per_cell = 2
velocity = [{vx}, {vy}]
[output]
every = 0.125
fields = ["velocity", "stress", "displacement"]
"#
        ),
    )
    .unwrap();
    let out = dir.join("out");
    ok(2, &["run", s(&sc), "--out", s(&out), "--quiet"]);
    let snaps = files(&out, "particles_");
    assert_eq!(snaps.len(), 5, "t = 0, 0.125, ..., 0.5: {snaps:?}");
    let n = 16 * 8 * 4;
    let mut worst_v = 0.0f64;
    for p in &snaps {
        let f = hdf5::File::open(p).unwrap();
        let shape = |name: &str| f.dataset(name).unwrap().shape();
        assert_eq!(shape("id"), [n]);
        assert_eq!(shape("rank"), [n]);
        assert_eq!(shape("material"), [n]);
        assert_eq!(shape("position"), [n, 3]);
        assert_eq!(shape("velocity"), [n, 3]);
        assert_eq!(shape("displacement"), [n, 3]);
        assert_eq!(shape("stress"), [n, 9]);
        assert_eq!(f.attr("dim").unwrap().read_scalar::<u64>().unwrap(), 2);
        let mut id: Vec<i64> = f.dataset("id").unwrap().read_raw().unwrap();
        id.sort();
        assert_eq!(
            id,
            (0..n as i64).collect::<Vec<_>>(),
            "ids are a permutation"
        );
        let rank: Vec<i64> = f.dataset("rank").unwrap().read_raw().unwrap();
        assert!(rank.iter().all(|&r| r == 0 || r == 1) && rank.contains(&0) && rank.contains(&1));
        let x: Vec<f64> = f.dataset("position").unwrap().read_raw().unwrap();
        for r in x.chunks(3) {
            assert!(
                (0.0..2.0).contains(&r[0]) && (0.0..1.0).contains(&r[1]) && r[2] == 0.0,
                "{r:?}"
            );
        }
        let v: Vec<f64> = f.dataset("velocity").unwrap().read_raw().unwrap();
        for r in v.chunks(3) {
            worst_v = worst_v.max((r[0] - vx).abs()).max((r[1] - vy).abs());
            assert_eq!(r[2], 0.0);
        }
        let st: Vec<f64> = f.dataset("stress").unwrap().read_raw().unwrap();
        assert!(
            st.iter().all(|x| x.abs() < 1e-9),
            "a translating body stays unstressed"
        );
    }
    // Velocities that are powers of two survive every projection of MPMCG at the
    // particle exactly (the domain rule's weights reproduce them to round-off).
    assert_eq!(worst_v, 0.0, "translation velocity off by {worst_v:e}");

    check_xdmf_index(&out, &snaps);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `mpmcg run --restart FILE [SCENE]` on one process: exit status 2 and one error line
/// naming the file and saying `words`.
fn rejected(args: &[&str], file: &Path, words: &str) {
    let o = Command::new(BIN).args(args).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{args:?} panicked:\n{err}");
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    assert!(
        err.starts_with(&format!("error: {}", file.display())),
        "{args:?}: the error does not name {}:\n{err}",
        file.display()
    );
    assert!(
        err.contains(words),
        "{args:?}: the error does not say {words:?}:\n{err}"
    );
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "{args:?}: not one line:\n{err}"
    );
}

/// (e) Unusable checkpoints: each ends with exit status 2 and names the file.
#[test]
fn unusable_checkpoints_are_rejected() {
    let dir = temp_dir("corrupt");
    let sc = dir.join("scene.toml");
    let text = crossing_scene(16, 0.2, "every_steps = 10\nkeep = 1");
    std::fs::write(&sc, &text).unwrap();
    let out = dir.join("out");
    ok(1, &["run", s(&sc), "--out", s(&out), "--quiet"]);
    let good = files(&out, "checkpoint_").pop().expect("a checkpoint");
    let bytes = std::fs::read(&good).unwrap();
    let put = |name: &str, b: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, b).unwrap();
        p
    };
    let run = |ckpt: &Path, words: &str| {
        let o = dir.join("restarted");
        rejected(
            &["run", "--restart", s(ckpt), "--out", s(&o), "--quiet"],
            ckpt,
            words,
        );
        assert!(!o.join("summary.json").exists());
    };

    run(&put("empty.h5", b""), "the file is empty");
    run(
        &put("half.h5", &bytes[..bytes.len() / 2]),
        "(truncated or extended)",
    );
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let noise: Vec<u8> = (0..bytes.len())
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        })
        .collect();
    run(&put("noise.h5", &noise), "not a readable HDF5 file");
    run(&dir.join("missing.h5"), "No such file");
    run(
        &last_snapshot(&out),
        "not an mpmcg checkpoint but a particle snapshot",
    );
    // Another HDF5 file, and a checkpoint of another format version.
    let foreign = dir.join("foreign.h5");
    {
        let f = hdf5::File::create(&foreign).unwrap();
        f.new_dataset::<f64>().shape([4]).create("data").unwrap();
    }
    run(&foreign, "not an mpmcg checkpoint");
    // A copy of the good checkpoint with attribute `attr` set to `value`, edited on
    // purpose with HDF5 and sealed again, as a user would.
    let with_attr = |name: &str, attr: &str, value: u64| {
        let p = put(name, &bytes);
        {
            let f = hdf5::File::open_rw(&p).unwrap();
            f.delete_attr(attr).unwrap();
            f.new_attr::<u64>()
                .create(attr)
                .unwrap()
                .write_scalar(&value)
                .unwrap();
        }
        mpmcg::output::checkpoint::seal(&p).unwrap();
        p
    };
    run(
        &with_attr("future.h5", "version", 99),
        "checkpoint format version 99, but this mpmcg reads versions 3 to 8",
    );
    // Scene defaults of a later build: their method is unknown here.
    run(
        &with_attr("later.h5", "scene_defaults", 3),
        "attribute `scene_defaults` = 3, but this mpmcg knows scene defaults 1 to 2",
    );
    // Particle data changed in the middle of the file: the checksum notices.
    let flipped = put("flipped.h5", &bytes);
    let at = {
        let f = hdf5::File::open(&flipped).unwrap();
        let ds = f.dataset("particles").unwrap();
        ds.offset().expect("contiguous particle data") as usize + 8 * ds.shape()[1] * 7 + 3
    };
    let mut b = bytes.clone();
    b[at] ^= 0x10;
    std::fs::write(&flipped, &b).unwrap();
    run(
        &flipped,
        "its bytes do not match the checksum written with them",
    );
    // Cut inside the seal itself.
    run(
        &put("stub.h5", &bytes[..20]),
        "shorter than its header (truncated)",
    );
    // A damaged seal: refused before HDF5 parses the file.
    let mut b = bytes.clone();
    b[3] ^= 0x40;
    run(
        &put("seal.h5", &b),
        "the header that holds its checksum is damaged",
    );
    // A scene argument that changes more than a restart may change.
    let other = dir.join("other.toml");
    std::fs::write(&other, text.replace("radius = 0.15", "radius = 0.14")).unwrap();
    rejected(
        &["run", s(&other), "--restart", s(&good), "--quiet"],
        &other,
        "key `bodies[0].shape.sphere.radius` differs from the scene of checkpoint",
    );
    // Under mpirun every rank agrees: one message, exit status 2, no hang.
    let half = dir.join("half.h5");
    let o = mpirun(2, &["run", "--restart", s(&half), "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.matches("error: ").count(), 1, "{err}");
    assert!(err.contains(s(&half)), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Checkpoints mangled at random: 120 copies of a mid-run checkpoint with 1–3 bytes
/// changed (half of them in the first 4 KiB, where HDF5 keeps the superblock and most
/// object headers). Each restart ends by itself within 60 s, never with a panic or a
/// signal: either it runs to the same final state as the unchanged checkpoint (the
/// byte was one nothing reads, e.g. padding) or it ends with exit 1, 2 or 3 and an
/// error that names the checkpoint. Before checkpoints were sealed with a checksum of
/// all their bytes (`checkpoint::seal`), a flipped byte in the `time` attribute
/// restarted silently from t = 0.063 instead of 0.116, and one in an object header
/// crashed HDF5 (SIGSEGV in `H5Aopen`, exit 139).
#[test]
fn mutated_checkpoints_never_panic() {
    let dir = temp_dir("fuzz-ckpt");
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, crossing_scene(16, 0.2, "every_steps = 10\nkeep = 100")).unwrap();
    let out = dir.join("out");
    ok(1, &["run", s(&sc), "--out", s(&out), "--quiet"]);
    let all = files(&out, "checkpoint_");
    let good = all[all.len() / 2].clone();
    let bytes = std::fs::read(&good).unwrap();
    // The unchanged checkpoint restarts.
    ok(
        1,
        &[
            "run",
            "--restart",
            s(&good),
            "--out",
            s(&dir.join("r")),
            "--quiet",
        ],
    );
    let mut rng = decomposition::splitmix::Rng::new(2026);
    let mut outcomes = [0usize; 4];
    for k in 0..120 {
        let mut b = bytes.clone();
        let head = k % 2 == 0;
        for _ in 0..1 + rng.below(3) {
            let at = rng.below(if head { 4096.min(b.len()) } else { b.len() });
            b[at] ^= 1 + rng.below(255) as u8;
        }
        let ckpt = dir.join(format!("m{k}.h5"));
        std::fs::write(&ckpt, &b).unwrap();
        let o = dir.join(format!("o{k}"));
        let mut child = Command::new(BIN)
            .args(["run", "--restart", s(&ckpt), "--out", s(&o), "--quiet"])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        let status = loop {
            if let Some(st) = child.try_wait().unwrap() {
                break st;
            }
            if t0.elapsed() > Duration::from_secs(60) {
                let _ = child.kill();
                panic!("mutation {k}: the restart did not end within 60 s");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let mut err = String::new();
        use std::io::Read;
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        assert!(!err.contains("panicked"), "mutation {k} panicked:\n{err}");
        let code = status
            .code()
            .unwrap_or_else(|| panic!("mutation {k}: killed by a signal ({status:?}):\n{err}"));
        assert!(code <= 3, "mutation {k}: exit {code}:\n{err}");
        if code == 1 || code == 2 {
            assert!(
                err.contains(s(&ckpt)),
                "mutation {k}: exit {code}, the error does not name the checkpoint:\n{err}"
            );
        }
        if code == 0 {
            // Accepted: then the byte was one nothing reads, and the run is the same.
            assert!(
                snapshot(&last_snapshot(&o)) == snapshot(&last_snapshot(&dir.join("r"))),
                "mutation {k}: accepted, but the final state differs from the unchanged \
                 checkpoint's restart"
            );
        }
        outcomes[code as usize] += 1;
        let _ = std::fs::remove_file(&ckpt);
        let _ = std::fs::remove_dir_all(&o);
    }
    eprintln!("exit 0/1/2/3: {outcomes:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
