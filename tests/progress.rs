//! The progress line of `mpmcg run` under `mpirun`: printed by rank 0 only, plain
//! lines with the ETA fields when the output goes to a pipe (a batch log), rewritten
//! in place when the launcher's output is a terminal.

#![forbid(unsafe_code)]

mod common;

use common::temp_dir;
use std::path::Path;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_mpmcg");

fn scene() -> String {
    format!("{}[output]\nsnapshots = false\n", common::SMALL_DISK)
}

fn steps(out: &Path) -> u64 {
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    s["steps"].as_u64().unwrap()
}

#[test]
fn under_mpirun_rank_0_alone_prints_plain_lines_with_an_eta() {
    let dir = temp_dir("progress-lines");
    let sc = dir.join("small.toml");
    std::fs::write(&sc, scene()).unwrap();
    let out = dir.join("out");
    // A line after every step: each rank that printed would add one per step.
    let o = common::mpirun(2)
        .arg(BIN)
        .args(["run", sc.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .args(["--progress-every", "0"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains('\r'), "a pipe gets plain lines: {err:?}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("step ")).collect();
    assert_eq!(lines.len() as u64, steps(&out), "{err}");
    for l in &lines {
        for field in ["t = ", "dt = ", "elapsed ", "rate ", "ETA "] {
            assert!(l.contains(field), "{field:?} missing in {l:?}");
        }
        // Every line after a step has a measured speed, hence an ETA.
        assert!(!l.contains('?'), "{l}");
    }
    let last = lines.last().unwrap();
    assert!(
        last.contains("(100.0%)") && last.ends_with("ETA 0s"),
        "{last}"
    );
}

#[test]
fn under_mpirun_on_a_terminal_the_line_is_rewritten_in_place() {
    // util-linux `script` gives mpirun a terminal; skip where it is missing.
    if Command::new("script").arg("--version").output().is_err() {
        eprintln!("skipped: no `script` command");
        return;
    }
    let dir = temp_dir("progress-tty");
    let sc = dir.join("small.toml");
    std::fs::write(&sc, scene()).unwrap();
    let out = dir.join("out");
    let mpirun = common::mpirun(2);
    let mut cmd: Vec<String> = vec![mpirun.get_program().to_string_lossy().into_owned()];
    cmd.extend(mpirun.get_args().map(|a| a.to_string_lossy().into_owned()));
    cmd.extend(
        [
            BIN,
            "run",
            sc.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]
        .map(String::from),
    );
    cmd.extend(["--progress-every", "0"].map(String::from));
    let o = Command::new("script")
        .args(["-qec", &cmd.join(" "), "/dev/null"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{text}");
    // Every update returns to the line's start and clears its rest; then one newline
    // before the last line.
    let updates = text.matches("\rstep ").count() as u64;
    assert_eq!(updates, steps(&out), "{text:?}");
    assert_eq!(text.matches("\x1b[K").count() as u64, updates);
    assert!(text.contains("completed"), "{text:?}");
}

#[test]
fn a_negative_or_infinite_interval_is_a_usage_error() {
    for bad in [
        "--progress-every=-1",
        "--progress-every=nan",
        "--progress-every=inf",
    ] {
        let o = Command::new(BIN).args(["run", bad]).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--progress-every must be"), "{bad}: {err}");
    }
}
