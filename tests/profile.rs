//! `summary.json`'s `profile` and `mpmcg run --profile`: the parts of the scheme's
//! step, spreads over ranks, and the count of synchronisations per step, which does
//! not depend on the rank count. Counts and orderings, not timings.

#![forbid(unsafe_code)]

mod common;
use common::temp_dir;
use serde_json::Value;
use std::path::Path;

/// A body crossing the block boundary of a 2-rank split. Balancing off: a rebalance
/// migrates particles between steps, which the halo's count includes and the step's
/// does not. MPMCG at the particle, whose parts and counts docs/scaling.md gives.
fn scene(gradient: &str, update: &str) -> String {
    let point = if gradient == "mpmcg" {
        common::POINT_RULE
    } else {
        ""
    };
    format!(
        r#"
name = "profile"
dim = 2
[time]
end = 0.2
cfl = 0.3
[method]
gradient = "{gradient}"
update = "{update}"
{point}
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [16, 16]
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = {{ sphere = {{ center = [0.4, 0.5], radius = 0.2 }} }}
velocity = [0.5, 0.2]
[parallel]
balance = "off"
"#
    )
}

/// Run `scene` on `n` ranks with `--profile`: the summary and rank 0's stderr.
fn run(n: usize, scene: &Path, out: &Path) -> (Value, String) {
    let o = common::mpirun(n)
        .arg(env!("CARGO_BIN_EXE_mpmcg"))
        .args(["run", "--quiet", "--profile", "--out"])
        .arg(out)
        .arg(scene)
        .output()
        .expect("mpirun runs");
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{n} ranks: {err}");
    let s = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap());
    (s.unwrap(), err)
}

fn spread(v: &Value) -> [f64; 3] {
    ["min", "mean", "max"].map(|k| v[k].as_f64().unwrap_or_else(|| panic!("{k} in {v}")))
}

fn parts(p: &Value) -> Vec<String> {
    let parts = p["seconds_per_step"].as_array().expect("seconds_per_step");
    parts
        .iter()
        .map(|x| x["part"].as_str().unwrap().to_string())
        .collect()
}

/// The spreads are ordered, equal on one rank, and the parts do not add up to more
/// than the run's wall time.
fn check_spreads(s: &Value, ranks: usize) {
    let p = &s["profile"];
    let mut total = 0.0;
    let mut all: Vec<[f64; 3]> = p["seconds_per_step"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| {
            let v = spread(x);
            total += v[1];
            v
        })
        .collect();
    all.push(spread(&p["setup_seconds"]));
    all.push(spread(&p["blocked_seconds_per_step"]["collectives"]));
    all.push(spread(&p["blocked_seconds_per_step"]["exchanges"]));
    for [lo, mean, hi] in all {
        assert!(
            0.0 <= lo && lo <= mean * (1.0 + 1e-12) && mean <= hi * (1.0 + 1e-12),
            "{p}"
        );
        if ranks == 1 {
            assert_eq!(lo, hi, "{p}");
        }
    }
    let steps = p["steps"].as_u64().unwrap();
    assert_eq!(
        Some(steps),
        s["steps"].as_u64(),
        "a fresh run profiles all its steps"
    );
    // Each rank's parts add up to its step loop, which lies within the run's wall time
    // on rank 0's clock, up to how much later than rank 0 another rank reads its clock
    // after the last synchronisation (a descheduled rank on a loaded machine: 0.1 s).
    let wall = s["wall_seconds"].as_f64().unwrap();
    assert!(
        total * steps as f64 <= wall + 0.1,
        "{total} × {steps} > {wall}"
    );
}

#[test]
fn the_profile_names_the_schemes_parts_and_counts_the_same_synchronisations_on_any_rank_count() {
    let dir = temp_dir("profile");
    let mut counts = Vec::new();
    for (gradient, update, expected) in [
        (
            "mpmcg",
            "musl",
            &[
                "time_step",
                "scatter",
                "averaged_force",
                "grid_update",
                "averaged_gradient",
                "remap",
                "stress",
                "check",
                "migrate",
                "sort",
                "balance",
                "output",
                "other",
            ][..],
        ),
        (
            "mpm",
            "usl",
            &[
                "time_step",
                "scatter",
                "grid_update",
                "gather",
                "check",
                "migrate",
                "sort",
                "balance",
                "output",
                "other",
            ][..],
        ),
    ] {
        let sc = dir.join(format!("{gradient}-{update}.toml"));
        std::fs::write(&sc, scene(gradient, update)).unwrap();
        let mut per_rank_count = Vec::new();
        for ranks in [1, 2] {
            let out = dir.join(format!("{gradient}-{update}-{ranks}"));
            let (s, err) = run(ranks, &sc, &out);
            let p = &s["profile"];
            assert_eq!(parts(p), expected, "{gradient}/{update} on {ranks}: {p}");
            check_spreads(&s, ranks);
            // Two counters, the communicator's and the halo's, see the same exchanges.
            let h = &s["halo"];
            let halo = h["grid"]["exchanges_per_step"].as_f64().unwrap()
                + h["migration"]["exchanges_per_step"].as_f64().unwrap();
            let ex = p["step_exchanges"].as_f64().unwrap();
            assert!((ex - halo).abs() < 1e-9, "{ex} against {halo}: {s}");
            // One collective a step: the step's check, which carries the signal speed
            // of the next step size and the migration's verdict; the first step size
            // needs one more.
            let coll = p["step_collectives"].as_f64().unwrap();
            let steps = p["steps"].as_f64().unwrap();
            assert_eq!(coll, (steps + 1.0) / steps, "{p}");
            per_rank_count.push((coll, ex));
            // The table, then the last line naming the output folder.
            for part in expected {
                assert!(err.contains(&format!("\n  {part} ")), "{part} in {err}");
            }
            let last = err.trim_end().lines().last().unwrap();
            assert!(
                last.contains("completed") && last.contains("output in"),
                "{err}"
            );
        }
        // Ranks add messages, not synchronisations.
        assert_eq!(per_rank_count[0], per_rank_count[1], "{gradient}/{update}");
        counts.push(per_rank_count[0]);
    }
    // MPMCG's node-to-node steps need ghosts of their own: more exchanges than MPM.
    assert!(counts[0].1 > counts[1].1, "{counts:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
