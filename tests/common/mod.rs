//! Helpers shared by the integration tests: run a scene in-process on one rank and
//! read the files it writes.
#![allow(dead_code)]

/// `[method]` keys for MPMCG at the particle (no centroid passes, no sharpening), which
/// MPMCG's defaults would otherwise add: for tests of what that method does.
pub const POINT_RULE: &str = "quadrature = \"point\"\nsharpen = 0.0\ncentroid_passes = 0";

use mpmcg::driver::run::{run, RunError, RunOptions, Summary};
use mpmcg::input::scene::parse;
use std::collections::HashMap;
use std::path::PathBuf;

/// A fresh, empty folder under the system temp dir. Tests leave their folders for a
/// look after a failure; the first call in a process removes those of test processes
/// that have ended, so repeated runs do not fill `/tmp`.
pub fn temp_dir(tag: &str) -> PathBuf {
    static SWEEP: std::sync::Once = std::sync::Once::new();
    SWEEP.call_once(remove_ended_runs_folders);
    let d = std::env::temp_dir().join(format!("mpmcg-test-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Remove `mpmcg-test-<pid>-*` folders whose process is gone. Only where `/proc`
/// tells which processes run (Linux); elsewhere nothing is removed.
fn remove_ended_runs_folders() {
    let proc_fs = std::path::Path::new("/proc/self");
    if !proc_fs.exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix("mpmcg-test-")) else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if !std::path::Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// Run scene text on one rank; returns the run's result (an unstable run's error
/// too) and the output folder.
pub fn run_scene(text: &str, tag: &str) -> (Result<Summary, RunError>, PathBuf) {
    let scene = parse(text, tag).unwrap_or_else(|e| panic!("scene {tag}: {e}"));
    let out = temp_dir(tag);
    let opts = RunOptions {
        out: out.clone(),
        quiet: true,
        threads: 1,
        ..RunOptions::default()
    };
    (run(&scene, &decomposition::SerialComm, &opts), out)
}

/// Run scene text on one rank, which must complete; returns the summary and the
/// output folder.
pub fn run_text(text: &str, tag: &str) -> (Summary, PathBuf) {
    let (r, out) = run_scene(text, tag);
    (r.unwrap_or_else(|e| panic!("run {tag}: {e}")), out)
}

/// The rows of `history.csv` as column name → value.
pub fn history(out: &std::path::Path) -> Vec<HashMap<String, f64>> {
    let text = std::fs::read_to_string(out.join("history.csv")).unwrap();
    let mut lines = text.lines();
    let head: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|l| {
            head.iter()
                .cloned()
                .zip(l.split(',').map(|x| x.parse::<f64>().unwrap()))
                .collect()
        })
        .collect()
}

/// `mpirun -n N` with the flags every multi-rank test needs: more ranks than cores,
/// ranks that yield while waiting (spinning ranks starve the others on 2 cores), a
/// timeout so a hang fails, and permission to run as root (CI does).
pub fn mpirun(n: usize) -> std::process::Command {
    let mut c = std::process::Command::new("mpirun");
    c.args([
        "--oversubscribe",
        "--mca",
        "mpi_yield_when_idle",
        "1",
        "--timeout",
        "120",
        "-n",
        &n.to_string(),
    ]);
    let root = std::process::Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false);
    if root {
        c.arg("--allow-run-as-root");
    }
    c
}

/// The files in `out` named `PREFIX*.h5`, sorted (by step: the names are zero-padded).
pub fn files(out: &std::path::Path, prefix: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let n = p.file_name().unwrap().to_string_lossy();
            n.starts_with(prefix) && n.ends_with(".h5")
        })
        .collect();
    v.sort();
    v
}

/// One snapshot: its time, and per particle (in file order) id, position, and the
/// named 3-vector field if asked for.
pub struct Snapshot {
    pub time: f64,
    pub id: Vec<i64>,
    pub x: Vec<[f64; 3]>,
    pub field: Vec<[f64; 3]>,
}

pub fn read_snapshot(path: &std::path::Path, field: Option<&str>) -> Snapshot {
    let f = hdf5::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let rows = |name: &str| -> Vec<[f64; 3]> {
        let v: Vec<f64> = f.dataset(name).unwrap().read_raw().unwrap();
        v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    };
    Snapshot {
        time: f.attr("time").unwrap().read_scalar().unwrap(),
        id: f.dataset("id").unwrap().read_raw().unwrap(),
        x: rows("position"),
        field: field.map_or_else(Vec::new, rows),
    }
}

/// Every snapshot a run wrote, in time order.
pub fn snapshots(out: &std::path::Path, field: Option<&str>) -> Vec<Snapshot> {
    files(out, "particles_")
        .iter()
        .map(|p| read_snapshot(p, field))
        .collect()
}

/// A scalar dataset of a snapshot (one value per particle, in file order).
pub fn read_scalar(path: &std::path::Path, name: &str) -> Vec<f64> {
    let f = hdf5::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    f.dataset(name).unwrap().read_raw().unwrap()
}

/// The 3 × 3 stress rows of a snapshot (row-major, padded with zeros below 3D).
pub fn read_stress(path: &std::path::Path) -> Vec<[f64; 9]> {
    let f = hdf5::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: Vec<f64> = f.dataset("stress").unwrap().read_raw().unwrap();
    v.chunks_exact(9)
        .map(|c| std::array::from_fn(|i| c[i]))
        .collect()
}

/// A snapshot's particles sorted by id: (id, position row, the scalar `field`).
pub fn scalar_by_id(path: &std::path::Path, field: &str) -> Vec<(i64, [f64; 3], f64)> {
    let sn = read_snapshot(path, None);
    let s = read_scalar(path, field);
    let mut rows: Vec<_> = (0..sn.id.len())
        .map(|i| (sn.id[i], sn.x[i], s[i]))
        .collect();
    rows.sort_by_key(|r| r.0);
    rows
}

/// Two runs' [`scalar_by_id`] rows agree: the same ids, positions within 1e-12 of
/// `length`, the scalar within 1e-12 of its peak (returned) in `a`.
pub fn assert_rows_close(
    a: &[(i64, [f64; 3], f64)],
    b: &[(i64, [f64; 3], f64)],
    length: f64,
) -> f64 {
    assert_eq!(a.len(), b.len(), "particle count");
    let peak = a.iter().map(|r| r.2).fold(0.0, f64::max);
    for (p, q) in a.iter().zip(b) {
        assert_eq!(p.0, q.0);
        for k in 0..3 {
            assert!((p.1[k] - q.1[k]).abs() < 1e-12 * length, "{p:?} vs {q:?}");
        }
        assert!((p.2 - q.2).abs() < 1e-12 * peak, "{p:?} vs {q:?}");
    }
    peak
}

/// A small elastic disk moving across an 8 × 8 box for a few dozen steps, with no
/// `[output]` table (tests append one): for command-line behaviour, not numerics.
pub const SMALL_DISK: &str = r#"name = "small"
dim = 2
[time]
end = 0.05
cfl = 0.3
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [8, 8]
[[materials]]
name = "m"
model = "linear_elastic"
density = 1.0
youngs_modulus = 100.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = { sphere = { center = [0.5, 0.5], radius = 0.3 } }
velocity = [0.5, -0.25]
"#;

/// A checkpoint's particle table: its values row by row, the row width and the column
/// names (the dataset's `columns` attribute).
pub fn checkpoint_table(f: &hdf5::File) -> (Vec<f64>, usize, Vec<String>) {
    let ds = f.dataset("particles").unwrap();
    let cols: hdf5::types::VarLenUnicode = ds.attr("columns").unwrap().read_scalar().unwrap();
    let cols: Vec<String> = cols.as_str().split(' ').map(String::from).collect();
    (ds.read_raw().unwrap(), ds.shape()[1], cols)
}
