//! The traffic between ranks that `summary.json` reports under `halo`: nothing on one
//! rank (periodic faces are local copies there), something on two, under `mpirun`.
//! Byte counts, not timings: they do not depend on the machine or its load.

#![forbid(unsafe_code)]

mod common;
use common::temp_dir;
use serde_json::Value;
use std::path::Path;

/// A body crossing the periodic x faces and the block boundary of a 2-rank split.
const SCENE: &str = r#"
name = "halo"
dim = 2
[time]
end = 0.4
cfl = 0.3
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [16, 16]
boundary = { x_lower = "periodic", x_upper = "periodic", y_lower = "periodic", y_upper = "periodic" }
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = { sphere = { center = [0.45, 0.5], radius = 0.2 } }
velocity = [0.5, 0.2]
"#;

fn run(n: usize, scene: &Path, out: &Path) -> Value {
    let o = common::mpirun(n)
        .arg(env!("CARGO_BIN_EXE_mpmcg"))
        .arg("run")
        .arg(scene)
        .arg("--out")
        .arg(out)
        .arg("--quiet")
        .output()
        .expect("mpirun runs");
    assert!(
        o.status.success(),
        "{n} ranks: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

fn spread(v: &Value) -> [f64; 3] {
    ["min", "mean", "max"].map(|k| v[k].as_f64().unwrap_or_else(|| panic!("{k} in {v}")))
}

#[test]
fn halo_traffic_is_zero_on_one_rank_and_positive_on_two() {
    let dir = temp_dir("halo-traffic");
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, SCENE).unwrap();

    let s1 = run(1, &sc, &dir.join("r1"));
    let h = &s1["halo"];
    assert!(h["steps"].as_u64().unwrap() > 10, "{h}");
    assert_eq!(
        h["steps"], s1["steps"],
        "a fresh run averages over all its steps"
    );
    // The ghost sum and copies still happen (to the periodic images), locally.
    assert!(
        h["grid"]["exchanges_per_step"].as_f64().unwrap() >= 2.0,
        "{h}"
    );
    assert_eq!(h["migration"]["exchanges_per_step"].as_f64(), Some(1.0));
    for kind in ["grid", "migration"] {
        for f in ["bytes_per_rank_per_step", "messages_per_rank_per_step"] {
            assert_eq!(spread(&h[kind][f]), [0.0; 3], "1 rank, {kind} {f}: {h}");
        }
    }
    assert_eq!(spread(&h["peers_per_rank"]), [0.0; 3]);

    let s2 = run(2, &sc, &dir.join("r2"));
    let h2 = &s2["halo"];
    assert_eq!(h2["steps"], h["steps"], "same steps on 2 ranks");
    // The same step sequence does the same halo operations.
    assert_eq!(
        h2["grid"]["exchanges_per_step"],
        h["grid"]["exchanges_per_step"]
    );
    // Two blocks along a periodic axis meet on both sides: one peer each. A halo
    // operation sends it at most one message, and none when no particle of either
    // rank is near their shared faces (the halo is sparse), so fewer than one per
    // operation on average, but some every step.
    assert_eq!(spread(&h2["peers_per_rank"]), [1.0; 3]);
    let ex = h2["grid"]["exchanges_per_step"].as_f64().unwrap();
    let msgs = spread(&h2["grid"]["messages_per_rank_per_step"]);
    assert!(msgs[0] > 0.0 && msgs[2] <= ex, "{h2}");
    let bytes = spread(&h2["grid"]["bytes_per_rank_per_step"]);
    assert!(
        bytes[0] > 0.0 && bytes[0] <= bytes[1] && bytes[1] <= bytes[2],
        "{h2}"
    );
    // The body crosses the block boundary: particles travelled.
    let mig = spread(&h2["migration"]["bytes_per_rank_per_step"]);
    assert!(mig[2] > 0.0, "{h2}");
    let _ = std::fs::remove_dir_all(&dir);
}
