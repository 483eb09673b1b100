//! What `mpmcg run` tells users, through the binary: the help on restarts and the last
//! line naming the output folder (with `--quiet` too).

mod common;

use common::temp_dir;
use std::path::Path;
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_mpmcg");

const SCENE: &str = r#"name = "small"
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

fn mpmcg(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Write `text` to DIR/NAME.toml and run it with `--quiet` into DIR/NAME.
fn run(dir: &Path, name: &str, text: &str) -> (Output, std::path::PathBuf) {
    let sc = dir.join(format!("{name}.toml"));
    std::fs::write(&sc, text).unwrap();
    let out = dir.join(name);
    let o = mpmcg(&[
        "run",
        sc.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    (o, out)
}

#[test]
fn run_help_says_what_a_restart_may_change() {
    let o = mpmcg(&["run", "--help"]);
    assert!(o.status.success());
    // clap wraps the text: compare with the whitespace collapsed.
    let help = String::from_utf8_lossy(&o.stdout)
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ");
    assert!(!help.contains("identical"), "{help}");
    assert!(
        help.contains("may change only time.end, time.cfl, time.dt, output.every and [checkpoint]"),
        "{help}"
    );
    assert!(help.contains("names the output folder"), "{help}");
}

#[test]
fn the_last_line_names_the_output_folder_with_quiet() {
    let dir = temp_dir("cli-last-line");
    let (o, out) = run(&dir, "done", SCENE);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    let last = err.trim_end().lines().last().unwrap_or_default();
    assert!(last.contains("completed"), "{err}");
    assert!(
        last.ends_with(&format!("output in {}", out.display())),
        "{err}"
    );
    // An unstable run (a body leaving the grid through a free face) too.
    let escape = SCENE
        .replace(
            "cells = [8, 8]",
            "cells = [8, 8]\nboundary = { x_upper = \"free\" }",
        )
        .replace("end = 0.05", "end = 2.0")
        .replace("velocity = [0.5, -0.25]", "velocity = [2.0, 0.0]");
    let (o, out) = run(&dir, "escape", &escape);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    let last = err.trim_end().lines().last().unwrap_or_default();
    assert!(last.contains("outside the grid"), "{err}");
    assert!(
        last.ends_with(&format!("output in {}", out.display())),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
