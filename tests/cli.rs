//! What `mpmcg run` tells users and which snapshots it writes, through the binary:
//! the help on restarts, the last line naming the output folder (with `--quiet` too),
//! snapshots of the initial and final states by default, and `snapshots = false`.

#![forbid(unsafe_code)]

mod common;

use common::{files, temp_dir};
use std::path::Path;
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_mpmcg");

const SCENE: &str = common::SMALL_DISK;

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

fn time_of(path: &Path) -> f64 {
    let f = hdf5::File::open(path).unwrap();
    f.attr("time").unwrap().read_scalar().unwrap()
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

/// Without `[output]` a run writes its initial and final states (velocity and stress)
/// and takes the same steps as with `snapshots = false`, which writes none.
#[test]
fn snapshots_by_default_and_none_on_request() {
    let dir = temp_dir("cli-snapshots");
    let (o, plain) = run(&dir, "plain", SCENE);
    assert!(o.status.success(), "{}", stderr(&o));
    let snaps = files(&plain, "particles_");
    assert_eq!(snaps.len(), 2, "{snaps:?}");
    assert_eq!(time_of(&snaps[0]), 0.0);
    assert!((time_of(&snaps[1]) - 0.05).abs() < 1e-12 * 0.05);
    let f = hdf5::File::open(&snaps[1]).unwrap();
    let n = f.dataset("position").unwrap().shape()[0];
    assert_eq!(f.dataset("velocity").unwrap().shape(), [n, 3]);
    assert_eq!(f.dataset("stress").unwrap().shape(), [n, 9]);
    let xmf = std::fs::read_to_string(plain.join("particles.xmf")).unwrap();
    assert_eq!(xmf.matches("<Time Value=").count(), 2);

    let (o, none) = run(
        &dir,
        "none",
        &format!("{SCENE}[output]\nsnapshots = false\n"),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(files(&none, "particles_").is_empty());
    assert!(!none.join("particles.xmf").exists());
    assert_eq!(
        std::fs::read(plain.join("history.csv")).unwrap(),
        std::fs::read(none.join("history.csv")).unwrap(),
        "the final snapshot must not change the steps"
    );

    // `snapshots = false` with an interval or fields contradicts itself: exit 2, and
    // the message names the key.
    for (key, extra) in [
        ("every", "every = 0.01"),
        ("fields", "fields = [\"stress\"]"),
    ] {
        let (o, out) = run(
            &dir,
            key,
            &format!("{SCENE}[output]\nsnapshots = false\n{extra}\n"),
        );
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(&format!("key `output.{key}`")), "{err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every scene in inputs/ writes at least its final state (none says otherwise).
#[test]
fn every_input_scene_writes_snapshots() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/inputs");
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            let (s, _) = mpmcg::input::scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
            assert!(
                s.snapshot_plan().is_some(),
                "{} writes no snapshots",
                p.display()
            );
            n += 1;
        }
    }
    assert!(n >= 11, "{n} scenes");
}

/// A restart may add a snapshot interval to a scene without `[output]` (which meant
/// the initial and final states), but not other fields or `snapshots = false`.
#[test]
fn a_restart_may_add_an_interval_to_a_scene_without_output() {
    use mpmcg::input::scene::{parse, restart_difference};
    let base = parse(SCENE, "base").unwrap();
    let with = |extra: &str| parse(&format!("{SCENE}[output]\n{extra}\n"), "edited").unwrap();
    assert_eq!(restart_difference(&base, &with("every = 0.01")), None);
    assert_eq!(restart_difference(&with("every = 0.01"), &base), None);
    assert_eq!(
        restart_difference(&base, &with("fields = [\"velocity\"]")).as_deref(),
        Some("output.fields")
    );
    assert_eq!(
        restart_difference(&base, &with("snapshots = false")).as_deref(),
        Some("output.snapshots")
    );
}
