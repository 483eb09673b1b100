//! Faults a run must end cleanly from, tried as a user would: each case runs the
//! binary (on 1 rank and under `mpirun -n 2`) and asserts the exit status and the one
//! message it names.

mod common;
use common::temp_dir;
use std::process::Output;

const BIN: &str = env!("CARGO_BIN_EXE_mpmcg");

/// Run `mpmcg ARGS` on `ranks` ranks (1: no mpirun).
fn mpmcg(ranks: usize, args: &[&str]) -> Output {
    if ranks == 1 {
        std::process::Command::new(BIN).args(args).output().unwrap()
    } else {
        common::mpirun(ranks).arg(BIN).args(args).output().unwrap()
    }
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
    }
}
