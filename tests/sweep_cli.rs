//! `mpmcg sweep` as users call it: exit status and message for bad input, and runs on
//! two ranks under mpirun (skipped when there is no `mpirun`).

#![forbid(unsafe_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const EXE: &str = env!("CARGO_BIN_EXE_mpmcg");

fn input(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("inputs")
        .join(name)
        .display()
        .to_string()
}

fn temp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mpmcg_sweep_cli_{tag}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn sweep(args: &[&str], out: &Path) -> Output {
    Command::new(EXE)
        .arg("sweep")
        .args(args)
        .arg("--out")
        .arg(out)
        .arg("--quiet")
        .output()
        .unwrap()
}

#[test]
fn bad_input_exits_2_with_a_message_and_runs_nothing() {
    let out = temp("bad");
    let bar = input("vibrating_bar.toml");
    let cases: [(&[&str], &str); 7] = [
        (&[&input("default.toml")], "has no [benchmark] table"),
        (&[&bar, "--cells", ""], "--cells: the list is empty"),
        (
            &[&bar, "--cells", "8,sixteen"],
            "\"sixteen\" is not a whole number",
        ),
        (&[&bar, "--cells", "8,0"], "must be >= 1"),
        (
            &[&bar, "--gradient", "mpm,bspline"],
            "unknown gradient \"bspline\"",
        ),
        (&[&bar, "--ppc", "0"], "--ppc must be >= 1"),
        (&[&bar, "--ranks", "0"], "--ranks must be >= 1"),
    ];
    for (args, message) in cases {
        let o = sweep(args, &out);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.starts_with("error: ") && err.contains(message),
            "{args:?}: {err}"
        );
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
}

fn mpirun_available() -> bool {
    Command::new("mpirun")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Fields of `results.csv` by column name.
fn table(out: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let mut lines = text.lines();
    let head: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|l| {
            head.iter()
                .cloned()
                .zip(l.split(',').map(String::from))
                .collect()
        })
        .collect()
}

/// Two ranks give the one-rank answers (the decomposition does not change the
/// arithmetic beyond round-off); a run that cannot start on two ranks is recorded as
/// failed, the sweep goes on, and the exit status says so.
#[test]
fn runs_on_two_ranks_under_mpirun() {
    if !mpirun_available() {
        eprintln!("skipped: no mpirun");
        return;
    }
    let bar = input("vibrating_bar.toml");
    let one = temp("one");
    let o = sweep(&[&bar, "--cells", "8,16", "--gradient", "mpmcg"], &one);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let two = temp("two");
    let o = sweep(
        &[
            &bar,
            "--cells",
            "2,8,16",
            "--gradient",
            "mpmcg",
            "--ranks",
            "2",
        ],
        &two,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("1 of 3 runs failed"), "{err}");
    let (r1, r2) = (table(&one), table(&two));
    assert_eq!(r2.len(), 3);
    assert_eq!(r2[0]["cells"], "2");
    assert_eq!(r2[0]["status"], "failed");
    assert!(two.join("mpmcg_2/mpirun.log").is_file());
    let report = std::fs::read_to_string(two.join("report.md")).unwrap();
    assert!(report.contains("2 cells, failed: mpirun exit status: 2: error: cannot run on 2 ranks"));
    for (a, b) in r1.iter().zip(&r2[1..]) {
        assert_eq!(b["status"], "completed");
        assert_eq!(b["ranks"], "2");
        assert_eq!(b["threads"], "1");
        for k in ["cells", "particles", "steps"] {
            assert_eq!(a[k], b[k], "{k}");
        }
        for k in ["displacement_l2", "velocity_l2"] {
            let (x, y): (f64, f64) = (a[k].parse().unwrap(), b[k].parse().unwrap());
            assert!(
                (x - y).abs() <= 1e-10 * x,
                "{k}: {x} on one rank, {y} on two"
            );
        }
    }
    std::fs::remove_dir_all(&one).unwrap();
    std::fs::remove_dir_all(&two).unwrap();
}
