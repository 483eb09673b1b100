//! What ParaView opens: `particles.xmf` of a small 2D run on 2 ranks and a 3D run on
//! one. Always: the XDMF topology lists the vertices 0..N-1 of every snapshot, every
//! item's dimensions are its dataset's, and the snapshots are at exact output times. With `pvpython` on the PATH also: each of
//! ParaView's three XDMF readers loads N points, N cells and every field at every time
//! step (`scripts/check_paraview.sh`), and where a display or `xvfb-run` is there it
//! renders the last step to `paraview.png`.

#![forbid(unsafe_code)]

mod common;

use common::{files, mpirun, temp_dir};
use std::path::Path;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_mpmcg");

const SCENE_2D: &str = r#"name = "paraview_2d"
dim = 2
[time]
end = 0.05
cfl = 0.3
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [8, 8]
boundary = { x_lower = "slip", x_upper = "slip" }
[[materials]]
name = "m"
model = "neo_hookean"
density = 1.0
youngs_modulus = 100.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = { sphere = { center = [0.5, 0.5], radius = 0.3 } }
velocity = [0.5, -0.25]
seeding = "cut"
[output]
every = 0.0125
fields = ["velocity", "stress", "displacement", "volume"]
"#;

const SCENE_3D: &str = r#"name = "paraview_3d"
dim = 3
[time]
end = 0.02
cfl = 0.3
[grid]
lower = [0.0, 0.0, 0.0]
upper = [1.0, 1.0, 1.0]
cells = [4, 4, 4]
[[materials]]
name = "m"
model = "brittle"
density = 1.0
youngs_modulus = 100.0
poisson_ratio = 0.3
tensile_strength = 1.0
[[bodies]]
material = "m"
shape = { box = { lower = [0.25, 0.25, 0.25], upper = [0.75, 0.75, 0.75] } }
velocity = [0.0, 0.0, 1.0]
[output]
every = 0.01
fields = ["velocity", "stress", "damage"]
"#;

fn run(scene: &str, ranks: usize, dir: &Path) -> std::path::PathBuf {
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, scene).unwrap();
    let out = dir.join("out");
    let mut cmd = if ranks > 1 {
        let mut c = mpirun(ranks);
        c.arg(BIN);
        c
    } else {
        Command::new(BIN)
    };
    let o = cmd
        .args(["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .args(["--quiet"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// The value of `key="..."` in an XML start tag.
fn attr<'a>(tag: &'a str, key: &str) -> &'a str {
    tag.split(&format!("{key}=\""))
        .nth(1)
        .unwrap_or_else(|| panic!("no {key} in {tag}"))
        .split('"')
        .next()
        .unwrap()
}

/// The XDMF index against the files: one grid per snapshot; its topology is
/// `NumberOfElements` = N vertices whose connectivity dataset is 0..N-1 (N = rows of
/// `position`), and every DataItem's dimensions are its dataset's, with N rows.
fn check_xdmf(out: &Path, fields: &[&str]) {
    let xmf = std::fs::read_to_string(out.join("particles.xmf")).unwrap();
    let snaps = files(out, "particles_");
    let grids: Vec<&str> = xmf.split("<Grid Name=\"particles_").skip(1).collect();
    assert_eq!(grids.len(), snaps.len(), "one grid per snapshot file");
    assert!(snaps.len() >= 3, "{snaps:?}");
    for (g, path) in grids.iter().zip(&snaps) {
        let f = hdf5::File::open(path).unwrap();
        let n = f.dataset("position").unwrap().shape()[0];
        assert!(n > 0);
        let topo = g.split("<Topology ").nth(1).expect("a topology");
        assert_eq!(attr(topo, "TopologyType"), "Polyvertex");
        assert_eq!(attr(topo, "NumberOfElements"), n.to_string());
        assert_eq!(attr(topo, "NodesPerElement"), "1");
        let conn_item = topo
            .split("</Topology>")
            .next()
            .unwrap()
            .split("<DataItem ")
            .nth(1)
            .expect("the topology has a connectivity item");
        let target = conn_item
            .split('>')
            .nth(1)
            .unwrap()
            .split('<')
            .next()
            .unwrap();
        assert_eq!(
            target,
            format!(
                "{}:/connectivity",
                path.file_name().unwrap().to_string_lossy()
            )
        );
        let conn: Vec<i64> = f.dataset("connectivity").unwrap().read_raw().unwrap();
        assert_eq!(
            conn,
            (0..n as i64).collect::<Vec<_>>(),
            "{}",
            path.display()
        );
        let mut names = Vec::new();
        for item in g.split("<DataItem ").skip(1) {
            let dims: Vec<usize> = attr(item, "Dimensions")
                .split_whitespace()
                .map(|d| d.parse().unwrap())
                .collect();
            let target = item.split('>').nth(1).unwrap().split('<').next().unwrap();
            let (file, ds) = target.split_once(":/").expect("file.h5:/path");
            assert_eq!(out.join(file), *path, "a grid names its own snapshot");
            assert_eq!(f.dataset(ds).unwrap().shape(), dims, "{target}");
            assert_eq!(dims[0], n, "{target}: one row per particle");
            names.push(ds.to_string());
        }
        for want in ["connectivity", "position", "id", "rank", "material"]
            .iter()
            .chain(fields)
        {
            assert!(names.iter().any(|x| x == want), "{want} missing: {names:?}");
        }
    }
}

/// Snapshots at t = 0, k·every and the end, each time exact to round-off: the step
/// that would pass an output time is shortened to land on it.
fn check_times(out: &Path, every: f64, end: f64) {
    let times: Vec<f64> = files(out, "particles_")
        .iter()
        .map(|p| {
            let f = hdf5::File::open(p).unwrap();
            f.attr("time").unwrap().read_scalar().unwrap()
        })
        .collect();
    let k_end = (end / every).round() as usize;
    assert_eq!(times.len(), k_end + 1, "{times:?}");
    for (k, t) in times.iter().enumerate() {
        let want = k as f64 * every;
        assert!(
            (t - want).abs() <= 1e-12 * want,
            "snapshot {k} at t = {t:e}, not {want:e}: {times:?}"
        );
    }
}

/// The 2D disk is seeded `cut`: the first snapshot's `volume`s are whole shares of a
/// particle's box (`k/256` of `(h/2)²`, `k` in 1..=256: the sub-lattice's 16 × 16
/// points), some of them partial, and they add up to the disk's area within what the
/// sub-lattice can miss (√2 times the perimeter times the sub-spacing).
fn check_cut_volumes(out: &Path) {
    let first = &files(out, "particles_")[0];
    let f = hdf5::File::open(first).unwrap();
    let vol: Vec<f64> = f.dataset("volume").unwrap().read_raw().unwrap();
    let whole = (1.0f64 / 16.0).powi(2);
    let mut partial = 0;
    for v in &vol {
        let k = v / whole * 256.0;
        assert!(
            (k - k.round()).abs() < 1e-9 && (1.0..=256.0).contains(&k.round()),
            "{v}"
        );
        partial += usize::from(k.round() < 256.0);
    }
    assert!(partial > 0, "no particle of a cut box");
    let area = std::f64::consts::PI * 0.09;
    let slack = 2f64.sqrt() * 2.0 * std::f64::consts::PI * 0.3 * (1.0 / 256.0);
    let sum: f64 = vol.iter().sum();
    assert!(
        (sum - area).abs() <= slack,
        "volumes {sum}, disk {area}, slack {slack:e}"
    );
}

#[test]
fn paraview_reads_every_particle_in_2d_and_3d() {
    let dir = temp_dir("paraview");
    let d2 = dir.join("2d");
    let d3 = dir.join("3d");
    std::fs::create_dir_all(&d2).unwrap();
    std::fs::create_dir_all(&d3).unwrap();
    let out2 = run(SCENE_2D, 2, &d2);
    let out3 = run(SCENE_3D, 1, &d3);
    check_xdmf(&out2, &["velocity", "stress", "displacement", "volume"]);
    check_cut_volumes(&out2);
    check_xdmf(&out3, &["velocity", "stress", "damage"]);
    check_times(&out2, 0.0125, 0.05);
    check_times(&out3, 0.01, 0.02);

    let has_pvpython = Command::new("sh")
        .args(["-c", "command -v pvpython"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_pvpython {
        eprintln!("pvpython is not on the PATH: skipped the check with ParaView's readers");
    } else {
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/check_paraview.sh");
        let o = Command::new(script).arg(&out2).arg(&out3).output().unwrap();
        let log = format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(o.status.success(), "check_paraview.sh failed:\n{log}");
        // Without a display or xvfb-run the script checks the readers only and says so.
        let picture = !log.contains("no picture made");
        for out in [&out2, &out3] {
            for reader in ["XDMFReader", "Xdmf3ReaderS", "Xdmf3ReaderT"] {
                assert!(
                    log.contains(&format!("{}: {reader}: ", out.display())),
                    "{reader} did not check {}:\n{log}",
                    out.display()
                );
            }
            assert_eq!(out.join("paraview.png").is_file(), picture, "{log}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
