//! Checkpoints edited on purpose with HDF5 and sealed again (`checkpoint::seal`), as a
//! user who edits a file would do: structurally valid HDF5 whose content is wrong, one
//! named case per dataset and attribute the reader uses. Particle rows are edited with
//! their writer's checksum recomputed (else the checksum alone refuses them, see
//! `particle_rows_edited_without_their_checksum`), so each check on the values is
//! reached.
//!
//! Every case must end with exit status 2 (the checkpoint is the run's input, like the
//! scene: exit 1 is for files the run cannot write) and one `error:` line that names
//! the checkpoint and what is wrong, never a panic or a signal, and no summary.json.

mod common;
use common::{checkpoint_table, files, temp_dir};
use decomposition::splitmix::mix;
use hdf5::types::VarLenUnicode;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::Mutex;

const BIN: &str = env!("CARGO_BIN_EXE_mpmcg");

/// Held while this process has a checkpoint open for editing and while it starts a
/// child: HDF5 opens files without close-on-exec, so a child started by another test
/// thread meanwhile would inherit the file and its lock, and a restart from that file
/// would fail with "unable to lock file".
static FILES: Mutex<()> = Mutex::new(());

/// Run `c` to its end, started under [`FILES`].
fn output(mut c: Command) -> Output {
    let child = {
        let _held = FILES.lock().unwrap_or_else(|e| e.into_inner());
        c.stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    child.wait_with_output().unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// A 2D disk of one neo-Hookean material with GIMP (its records carry `def_grad` and
/// `half`) on 8 × 8 periodic cells; a checkpoint every 5 steps, the last one kept.
const SCENE: &str = r#"name = "block"
dim = 2
[time]
end = 0.5
cfl = 0.3
[method]
gradient = "gimp"
update = "musl"
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [8, 8]
boundary = { x_lower = "periodic", x_upper = "periodic", y_lower = "periodic", y_upper = "periodic" }
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = { sphere = { center = [0.5, 0.5], radius = 0.2 } }
velocity = [0.1, -0.2]
[output]
every = 0.5
[checkpoint]
every_steps = 5
keep = 1
"#;

/// A J2-plastic and a brittle disk (their records carry `be`, `eps_p`, `damage` and
/// `stress_zz`), otherwise like [`SCENE`].
const STATES: &str = r#"name = "states"
dim = 2
[time]
end = 0.5
cfl = 0.3
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [8, 8]
boundary = { x_lower = "periodic", x_upper = "periodic", y_lower = "periodic", y_upper = "periodic" }
[[materials]]
name = "p"
model = "j2_plastic"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
yield_stress = 5.0
hardening = 1.0
[[materials]]
name = "b"
model = "brittle"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
tensile_strength = 5.0
[[bodies]]
material = "p"
shape = { sphere = { center = [0.3, 0.3], radius = 0.15 } }
velocity = [0.2, 0.2]
[[bodies]]
material = "b"
shape = { sphere = { center = [0.7, 0.7], radius = 0.15 } }
velocity = [-0.2, -0.2]
[output]
every = 0.5
[checkpoint]
every_steps = 5
keep = 1
"#;

/// `mpmcg run` of `scene` text on `ranks` ranks (a plain process for one); returns the
/// last checkpoint it wrote.
fn checkpoint_of(dir: &Path, scene: &str, ranks: usize) -> PathBuf {
    let sc = dir.join("scene.toml");
    std::fs::write(&sc, scene).unwrap();
    let out = dir.join("out");
    let args = ["run", s(&sc), "--out", s(&out), "--quiet"];
    let o = if ranks == 1 {
        let mut c = Command::new(BIN);
        c.args(args);
        output(c)
    } else {
        let mut c = common::mpirun(ranks);
        c.arg(BIN).args(args);
        output(c)
    };
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    files(&out, "checkpoint_").pop().expect("a checkpoint")
}

/// A checkpoint of [`SCENE`].
fn checkpoint(dir: &Path, ranks: usize) -> PathBuf {
    checkpoint_of(dir, SCENE, ranks)
}

/// The checksum the writer stores for its rows (`checkpoint::row_hash`, summed over the
/// rows of one writer rank, counted from 0).
fn rows_hash(rows: &[f64], width: usize) -> u64 {
    let w = width as u64;
    let mut h = 0u64;
    for (k, row) in rows.chunks_exact(width).enumerate() {
        for (c, x) in row.iter().enumerate() {
            h = h.wrapping_add(mix(x.to_bits() ^ mix(k as u64 * w + c as u64)));
        }
    }
    h
}

/// Replace root attribute `name` with `v`.
fn attr<T: hdf5::H5Type>(f: &hdf5::File, name: &str, v: &[T]) {
    let _ = f.delete_attr(name);
    f.new_attr_builder().with_data(v).create(name).unwrap();
}

/// Replace root attribute `name` with a scalar `v`.
fn scalar<T: hdf5::H5Type>(f: &hdf5::File, name: &str, v: T) {
    let _ = f.delete_attr(name);
    f.new_attr::<T>()
        .create(name)
        .unwrap()
        .write_scalar(&v)
        .unwrap();
}

/// Replace dataset `name` with the 1D `v`.
fn data<T: hdf5::H5Type>(f: &hdf5::File, name: &str, v: &[T]) {
    let _ = f.unlink(name);
    f.new_dataset_builder().with_data(v).create(name).unwrap();
}

/// Edit the particle table in place with `edit(rows, column index)` and store each
/// writer rank's checksum of the edited rows, as a determined editor would.
fn rows(f: &hdf5::File, edit: impl FnOnce(&mut [f64], &dyn Fn(&str) -> usize)) {
    let (mut v, width, cols) = checkpoint_table(f);
    let col = |name: &str| cols.iter().position(|c| c == name).expect(name);
    edit(&mut v, &col);
    f.dataset("particles").unwrap().write_raw(&v).unwrap();
    let counts: Vec<u64> = f.dataset("rank_rows").unwrap().read_raw().unwrap();
    let mut at = 0;
    let sums: Vec<u64> = counts
        .iter()
        .map(|&n| {
            let n = n as usize * width;
            at += n;
            rows_hash(&v[at - n..at], width)
        })
        .collect();
    f.dataset("checksum").unwrap().write_raw(&sums).unwrap();
}

/// Set column `name` of row `row` to `x` (checksum recomputed).
fn cell(f: &hdf5::File, row: usize, name: &str, x: f64) {
    let width = checkpoint_table(f).1;
    rows(f, |v, col| v[row * width + col(name)] = x);
}

/// A copy of `good` named `name`, edited with `edit` and sealed again.
fn edited(good: &Path, dir: &Path, name: &str, edit: &dyn Fn(&hdf5::File)) -> PathBuf {
    let p = dir.join(format!("{name}.h5"));
    std::fs::copy(good, &p).unwrap();
    let _held = FILES.lock().unwrap_or_else(|e| e.into_inner());
    edit(&hdf5::File::open_rw(&p).unwrap());
    mpmcg::output::checkpoint::seal(&p).unwrap();
    p
}

/// What is wrong with the outcome of restarting from `ckpt` (`None`: exit 2, one error
/// line naming the file and saying `words`, no summary). Under mpirun its own notice of
/// the exit status follows the error line.
fn fault(o: &Output, ckpt: &Path, out: &Path, words: &str, mpirun: bool) -> Option<String> {
    let err = String::from_utf8_lossy(&o.stderr);
    let errors = err.lines().filter(|l| l.starts_with("error: ")).count();
    let wrong = if err.contains("panicked") {
        Some("panicked")
    } else if o.status.code() != Some(2) {
        Some("exit status is not 2")
    } else if errors != 1 || (!mpirun && err.trim_end().lines().count() != 1) {
        Some("not one error line")
    } else if !err.contains(s(ckpt)) {
        Some("the error does not name the checkpoint")
    } else if !err.contains(words) {
        Some("the error does not say what is wrong")
    } else if out.join("summary.json").exists() {
        Some("summary.json written")
    } else {
        None
    };
    wrong.map(|w| format!("{w} ({:?}; expected {words:?}):\n{err}", o.status))
}

/// One process: `mpmcg run --restart CKPT`.
fn restart(ckpt: &Path, out: &Path) -> Output {
    let mut c = Command::new(BIN);
    c.args(["run", "--restart", s(ckpt), "--out", s(out), "--quiet"]);
    output(c)
}

/// Restarting from `ckpt` (unedited) into `out` succeeds.
fn restarts(ckpt: &Path, out: &Path) {
    let o = restart(ckpt, out);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

type Edit = Box<dyn Fn(&hdf5::File)>;

/// A named case: the edit and the words its error must contain.
fn case(
    name: &'static str,
    words: &'static str,
    edit: impl Fn(&hdf5::File) + 'static,
) -> (&'static str, &'static str, Edit) {
    (name, words, Box::new(edit))
}

/// Each case (name, words the error must say, edit) applied to a copy of `good` and
/// restarted on one process: every one must be refused ([`fault`]); all failures are
/// reported together.
fn refused_on_one_rank(
    good: &Path,
    dir: &Path,
    cases: impl IntoIterator<Item = (&'static str, &'static str, Edit)>,
) {
    let mut failed = Vec::new();
    for (name, words, edit) in cases {
        let ckpt = edited(good, dir, name, &*edit);
        let out = dir.join(format!("out-{name}"));
        if let Some(m) = fault(&restart(&ckpt, &out), &ckpt, &out, words, false) {
            failed.push(format!("{name}: {m}"));
        }
    }
    assert!(
        failed.is_empty(),
        "{} case(s) failed:\n{}",
        failed.len(),
        failed.join("\n")
    );
}

/// The particle table's cases (every row value the solver consumes).
fn particle_cases() -> Vec<(&'static str, &'static str, Edit)> {
    vec![
        case("particles_deleted", "dataset `particles`", |f| {
            f.unlink("particles").unwrap()
        }),
        case(
            "particles_one_column_short",
            "dataset `particles` has shape",
            |f| {
                let (v, w, _) = checkpoint_table(f);
                let short: Vec<f64> = v
                    .chunks_exact(w)
                    .flat_map(|r| r[..w - 1].to_vec())
                    .collect();
                f.unlink("particles").unwrap();
                let n = v.len() / w;
                let ds = f
                    .new_dataset::<f64>()
                    .shape([n, w - 1])
                    .create("particles")
                    .unwrap();
                ds.write_raw(&short).unwrap();
            },
        ),
        case("particles_as_integers", "dataset `particles` holds", |f| {
            let (v, w, _) = checkpoint_table(f);
            f.unlink("particles").unwrap();
            let ds = f
                .new_dataset::<i32>()
                .shape([v.len() / w, w])
                .create("particles")
                .unwrap();
            let ints: Vec<i32> = v.iter().map(|&x| x as i32).collect();
            ds.write_raw(&ints).unwrap();
        }),
        case("position_nan", "`x` holds NaN", |f| {
            cell(f, 3, "x[0]", f64::NAN)
        }),
        case("position_outside_grid", "outside the grid on axis 1", |f| {
            cell(f, 3, "x[1]", 1.5)
        }),
        case(
            "position_on_periodic_upper_face",
            "outside the grid on axis 0",
            |f| cell(f, 3, "x[0]", 1.0),
        ),
        case("velocity_infinite", "`v` holds inf", |f| {
            cell(f, 2, "v[1]", f64::INFINITY)
        }),
        // The disk's volume is det F · V₀ (checkpoint version 6): an inverted `F` is
        // a volume that is not positive.
        case("def_grad_inverted", "`def_grad` has determinant -", |f| {
            cell(f, 1, "def_grad[0][0]", -1.0)
        }),
        // The mass and reference volume are the kind's (checkpoint version 6).
        case(
            "kind_out_of_range",
            "kind index 1 is not one of the scene's 1 kinds of particle",
            |f| cell(f, 5, "kind", 1.0),
        ),
        case("kind_fractional", "kind index 0.5 is not one of", |f| {
            cell(f, 5, "kind", 0.5)
        }),
        case("id_negative", "particle id -1 is not an integer id", |f| {
            cell(f, 4, "id", -1.0)
        }),
        case("id_duplicate", "is in more than one row", |f| {
            let w = checkpoint_table(f).1;
            rows(f, |v, col| v[4 * w + col("id")] = v[7 * w + col("id")]);
        }),
        case("def_grad_nan", "`def_grad` holds NaN", |f| {
            cell(f, 6, "def_grad[1][1]", f64::NAN)
        }),
        case("half_width_zero", "`half` = 0 is not positive", |f| {
            cell(f, 6, "half[0]", 0.0)
        }),
    ]
}

/// The cases of every other dataset and attribute the reader uses.
#[rustfmt::skip]
fn other_cases() -> Vec<(&'static str, &'static str, Edit)> {
    vec![
        // Header.
        case("dim_deleted", "attribute `dim`", |f| f.delete_attr("dim").unwrap()),
        case("dim_5", "dim = 5", |f| scalar(f, "dim", 5u64)),
        case("dim_3", "attribute `blocks` has 2 values, expected 3", |f| scalar(f, "dim", 3u64)),
        case("ranks_0", "do not match 0 ranks", |f| scalar(f, "ranks", 0u64)),
        case("ranks_2", "blocks [1, 1] do not match 2 ranks", |f| scalar(f, "ranks", 2u64)),
        case("blocks_overflow", "do not match 1 ranks", |f| attr(f, "blocks", &[1u64 << 40, 1 << 40])),
        case("blocks_huge", "do not match", |f| {
            attr(f, "blocks", &[u64::MAX, 1]);
            scalar(f, "ranks", u64::MAX);
        }),
        case("blocks_too_narrow", "are not a division of the [8, 8] cells", |f| {
            scalar(f, "ranks", 2u64);
            attr(f, "blocks", &[2u64, 1]);
            attr(f, "cuts", &[0u64, 1, 8, 0, 8]);
        }),
        case("cuts_not_increasing", "attribute `cuts` [0, 8, 4] on axis 0", |f| {
            scalar(f, "ranks", 2u64);
            attr(f, "blocks", &[2u64, 1]);
            attr(f, "cuts", &[0u64, 8, 4, 0, 8]);
        }),
        case("cuts_short_of_the_grid", "attribute `cuts` [0, 6] on axis 1", |f| attr(f, "cuts", &[0u64, 8, 0, 6])),
        case("cuts_wrong_length", "attribute `cuts` has 2 values, expected 4", |f| attr(f, "cuts", &[0u64, 8])),
        case("cells_other_grid", "cells [16, 8] differ from the stored scene's [8, 8]", |f| {
            attr(f, "cells", &[16u64, 8]);
            attr(f, "cuts", &[0u64, 16, 0, 8]);
        }),
        case("cells_deleted", "attribute `cells`", |f| f.delete_attr("cells").unwrap()),
        case("particles_count_more", "dataset `particles` has shape [32, 12], expected [33, 12]", |f| scalar(f, "particles", 33u64)),
        case("record_width", "are not those the stored scene needs", |f| scalar(f, "record_width", 18u64)),
        case("carries_half_off", "are not those the stored scene needs", |f| scalar(f, "carries_half", 0u64)),
        case("carries_deleted", "attribute `carries_def_grad`", |f| f.delete_attr("carries_def_grad").unwrap()),
        case("carries_vol0_on", "are not those the stored scene needs", |f| scalar(f, "carries_vol0", 1u64)),
        case("kind_material_deleted", "dataset `kind_material`", |f| f.unlink("kind_material").unwrap()),
        case("kind_material_two", "dataset `kind_material` has 2 values, expected 1", |f| data(f, "kind_material", &[0u64, 0])),
        case("kind_material_other", "kind 0 is material 1 of reference volume", |f| data(f, "kind_material", &[1u64])),
        case("kind_vol0_other", "are not the kinds of particle of the stored scene: kind 0 is material 0 of reference volume 5e-1", |f| data(f, "kind_vol0", &[0.5f64])),
        // Versions 6 and 7 hold them as attributes, which are read when present.
        case("kind_vol0_attribute_other", "attributes `kind_material` and `kind_vol0` are not the kinds", |f| {
            attr(f, "kind_material", &[0u64]);
            attr(f, "kind_vol0", &[0.5f64]);
        }),
        case("step_deleted", "attribute `step`", |f| f.delete_attr("step").unwrap()),
        case("step_max", "is beyond any run's step count", |f| scalar(f, "step", u64::MAX)),
        case("time_nan", "attribute `time` = NaN is not a finite time", |f| scalar(f, "time", f64::NAN)),
        case("time_negative", "attribute `time` = -1 is not a finite time", |f| scalar(f, "time", -1.0f64)),
        case("time_as_text", "attribute `time`", |f| scalar(f, "time", "0.4".parse::<VarLenUnicode>().unwrap())),
        case("dt_nan", "attribute `dt` = NaN", |f| scalar(f, "dt", f64::NAN)),
        case("dt_negative", "attribute `dt` = -0.01", |f| scalar(f, "dt", -0.01f64)),
        case("dt_zero", "attribute `dt` = 0", |f| scalar(f, "dt", 0.0f64)),
        case("max_speed_nan", "attribute `max_speed` = NaN", |f| scalar(f, "max_speed", f64::NAN)),
        case("max_speed_infinite", "attribute `max_speed` = inf", |f| scalar(f, "max_speed", f64::INFINITY)),
        case("rebalances_as_text", "attribute `rebalances`", |f| scalar(f, "rebalances", "1".parse::<VarLenUnicode>().unwrap())),
        case("lineage_not_text", "attribute `lineage` is not text", |f| scalar(f, "lineage", 7u64)),
        case("scene_deleted", "dataset `scene`", |f| f.unlink("scene").unwrap()),
        case("scene_not_utf8", "the stored scene is not UTF-8 text", |f| data(f, "scene", &[0xffu8, 0xfe, 0x41])),
        case("scene_not_toml", ":/scene", |f| data(f, "scene", b"name = [")),
        // Per writer rank.
        case("rank_rows_deleted", "dataset `rank_rows`", |f| f.unlink("rank_rows").unwrap()),
        case("rank_rows_short", "rank_rows [31] do not add up to 32 particles", |f| data(f, "rank_rows", &[31u64])),
        case("rank_rows_two", "dataset `rank_rows` has 2 values, expected 1", |f| data(f, "rank_rows", &[16u64, 16])),
        case("rank_rows_overflow", "do not add up to 32 particles", |f| {
            scalar(f, "ranks", 2u64);
            attr(f, "blocks", &[2u64, 1]);
            attr(f, "cuts", &[0u64, 4, 8, 0, 8]);
            data(f, "rank_rows", &[u64::MAX, 33]);
            data(f, "external_work", &[0.0f64, 0.0]);
            data(f, "checksum", &[0u64, 0]);
        }),
        case("external_work_deleted", "dataset `external_work`", |f| f.unlink("external_work").unwrap()),
        case("external_work_nan", "dataset `external_work` holds NaN", |f| data(f, "external_work", &[f64::NAN])),
        case("checksum_deleted", "dataset `checksum`", |f| f.unlink("checksum").unwrap()),
        case("checksum_two", "dataset `checksum` has 2 values, expected 1", |f| data(f, "checksum", &[1u64, 2])),
        // The run loop's state.
        case("initial_totals_nan", "attribute `initial_totals` holds NaN", |f| attr(f, "initial_totals", &[f64::NAN; 7])),
        case("last_totals_short", "attribute `last_totals` has 6 values, expected 7", |f| attr(f, "last_totals", &[1.0f64; 6])),
        case("initial_particles_deleted", "attribute `initial_particles`", |f| f.delete_attr("initial_particles").unwrap()),
        case("energy_scale_negative", "attribute `energy_scale` holds -1 (must be >= 0)", |f| scalar(f, "energy_scale", -1.0f64)),
        case("max_energy_deviation_nan", "attribute `max_energy_deviation` holds NaN", |f| scalar(f, "max_energy_deviation", f64::NAN)),
        case("max_errors_infinite", "attribute `max_errors` holds inf", |f| attr(f, "max_errors", &[f64::INFINITY, 0.0])),
        case("last_errors_nan_but_present", "attribute `last_errors` holds NaN", |f| scalar(f, "has_last_errors", 1u64)),
        case("next_history_time_nan", "attribute `next_history_time` is NaN", |f| scalar(f, "next_history_time", f64::NAN)),
        case("next_snapshot_time_nan", "attribute `next_snapshot_time` is NaN", |f| scalar(f, "next_snapshot_time", f64::NAN)),
        case("next_checkpoint_time_nan", "attribute `next_checkpoint_time` is NaN", |f| scalar(f, "next_checkpoint_time", f64::NAN)),
        case("last_history_step_after", "step 99 of its history or snapshots is after its step 15", |f| scalar(f, "last_history_step", 99u64)),
        case("snapshot_steps_after", "step 99 of its history or snapshots is after its step 15", |f| data(f, "snapshot_steps", &[99u64])),
        case("snapshot_steps_deleted", "dataset `snapshot_steps`", |f| f.unlink("snapshot_steps").unwrap()),
        case("snapshot_times_long", "dataset `snapshot_times` has 2 values, expected 1", |f| data(f, "snapshot_times", &[0.0f64, 0.1])),
        case("snapshot_times_nan", "dataset `snapshot_times` holds NaN", |f| data(f, "snapshot_times", &[f64::NAN])),
        case("snapshot_particles_deleted", "dataset `snapshot_particles`", |f| f.unlink("snapshot_particles").unwrap()),
        case("history_deleted", "dataset `history`", |f| f.unlink("history").unwrap()),
    ]
}

/// Each dataset and attribute of a checkpoint edited and sealed again, restarted on one
/// process. Before these checks (`checkpoint::read_header`, `checkpoint::read` and its
/// `RowCheck`, `read_run_state`), the cases ended as follows:
///
/// - panic: `kind_out_of_range` (then `material_out_of_range`: index out of bounds in
///   `Solver::with_particles`),
///   `position_outside_grid` (`SlabOrder::push`), `blocks_overflow`, `blocks_huge`,
///   `rank_rows_overflow` (arithmetic overflow of stored counts), `step_max` (overflow
///   of the step count);
/// - hang: `time_nan` ran on at t = NaN (1.4 million steps until killed);
/// - exit 3, reported as a numerical instability after one step (and the damaged state
///   checkpointed again): `velocity_infinite`, `stress_nan`, `mass_negative`,
///   `volume_zero`, `def_grad_nan`, `max_speed_infinite`;
/// - silent, the run completed: `position_nan`, `position_on_periodic_upper_face`,
///   `mass_zero`, `reference_volume_negative`, `kind_fractional` (truncated to 0),
///   `id_negative` (saturated to 0), `id_duplicate`, `half_width_zero`,
///   `cuts_short_of_the_grid` (read as uniform blocks), `time_negative` (71 steps from
///   t = -1), `dt_*`, `max_speed_nan` (steps as long as the CFL allows at speed 0),
///   `lineage_not_text` (a fresh lineage), `external_work_nan`, and every run-state case
///   but the deleted and wrong-length ones (NaN totals and schedules into the summary);
/// - refused, by another check than now: `particles_as_integers` (by the checksum,
///   because conversion changed the values), `blocks_too_narrow` and
///   `cuts_not_increasing` (by the length of `rank_rows`);
/// - already refused as now: the deleted and wrong-length datasets and attributes,
///   `dim_*`, `ranks_*`, `cells_*`, `particles_count_more`, `record_width`, `carries_*`,
///   `time_as_text`, `rebalances_as_text`, `scene_*`, `rank_rows_short`.
///
/// (Since version 5 a checkpoint holds no mass, and since version 6 no reference
/// volume: both are the particle's kind's. The cases of the mass and `vol0` columns
/// of older versions are `version_5_rows_are_checked`'s.)
#[test]
fn each_dataset_edited_and_resealed_is_refused() {
    let dir = temp_dir("ckpt-datasets");
    let good = checkpoint(&dir, 1);
    // The unchanged checkpoint restarts.
    restarts(&good, &dir.join("ok"));
    refused_on_one_rank(
        &good,
        &dir,
        particle_cases().into_iter().chain(other_cases()),
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The material-state columns (J2 plasticity, brittle damage and plane-strain σ_zz)
/// and a kind index past the scene's two. Before: `kind_index_2` panicked (as
/// `kind_out_of_range`), `eps_p_negative`, `damage_above_1` and
/// `stress_zz_infinite` ran on silently, `be_nan` and `stress_nan` ended as
/// "numerically unstable" (exit 3).
#[test]
fn material_state_columns_are_checked() {
    let dir = temp_dir("ckpt-states");
    let good = checkpoint_of(&dir, STATES, 1);
    restarts(&good, &dir.join("ok"));
    let cases = [
        // These materials need no `F`: the particles store their volume.
        case("volume_zero", "`vol` = 0 is not positive", |f| {
            cell(f, 1, "vol", 0.0)
        }),
        case("eps_p_negative", "`eps_p` = -0.1 is negative", |f| {
            cell(f, 2, "eps_p", -0.1)
        }),
        case("be_nan", "`be` holds NaN", |f| {
            cell(f, 2, "be[2][2]", f64::NAN)
        }),
        case("damage_above_1", "`damage` = 2 is not in [0, 1]", |f| {
            cell(f, 3, "damage", 2.0)
        }),
        case("stress_zz_infinite", "`stress_zz` holds -inf", |f| {
            cell(f, 3, "stress_zz", f64::NEG_INFINITY)
        }),
        // The neo-Hookean disks of `SCENE` store no stress (it follows from `F`).
        case("stress_nan", "`stress` holds NaN", |f| {
            cell(f, 2, "stress[1][0]", f64::NAN)
        }),
        case(
            "kind_index_2",
            "kind index 2 is not one of the scene's 2 kinds of particle",
            |f| cell(f, 4, "kind", 2.0),
        ),
    ];
    refused_on_one_rank(&good, &dir, cases);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The rows of a version 5 checkpoint (`tests/data/checkpoint_v5_kinds.h5`, three kinds
/// of particle: `tests/restart.rs`'s `version_5_checkpoint_restarts_its_kinds`) hold
/// the material and `vol0`, read as the particle's kind: a `vol0` that is not positive,
/// or a material and `vol0` that make no kind of the stored scene (another volume, a
/// material past its two, a fraction), is refused with its row. Without the check, a
/// `vol0` of no kind panicked (`Kinds::find`'s `expect` in `checkpoint::read`).
#[test]
fn version_5_rows_are_checked() {
    let dir = temp_dir("ckpt-v5-rows");
    let v5 = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/checkpoint_v5_kinds.h5");
    restarts(&v5, &dir.join("ok"));
    let cases = [
        case("reference_volume_zero", "`vol0` = 0 is not positive", |f| {
            cell(f, 0, "vol0", 0.0)
        }),
        case(
            "reference_volume_negative",
            "`vol0` = -0.5 is not positive",
            |f| cell(f, 1, "vol0", -0.5),
        ),
        case(
            "reference_volume_of_no_kind",
            "material index 1 with `vol0` = 0.0001 is not a kind of particle of the stored scene",
            |f| {
                rows(f, |v, col| {
                    v[col("material")] = 1.0;
                    v[col("vol0")] = 1e-4;
                })
            },
        ),
        case("material_of_no_kind", "material index 2 with `vol0`", |f| {
            cell(f, 2, "material", 2.0)
        }),
        case(
            "material_fractional",
            "material index 0.5 with `vol0`",
            |f| cell(f, 2, "material", 0.5),
        ),
    ];
    refused_on_one_rank(&v5, &dir, cases);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Particle rows edited and sealed again without their writer's checksum: refused by
/// the checksum (already so before the value checks).
#[test]
fn particle_rows_edited_without_their_checksum() {
    let dir = temp_dir("ckpt-rows-sum");
    let good = checkpoint(&dir, 1);
    let ckpt = edited(&good, &dir, "v", &|f| {
        let (mut v, w, cols) = checkpoint_table(f);
        v[w + cols.iter().position(|c| c == "v[0]").unwrap()] *= 2.0;
        f.dataset("particles").unwrap().write_raw(&v).unwrap();
    });
    let out = dir.join("out-v");
    let words = "the particle rows of writer rank 0 do not match their checksum";
    if let Some(m) = fault(&restart(&ckpt, &out), &ckpt, &out, words, false) {
        panic!("{m}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The particle-table cases on a checkpoint of 2 ranks restarted under `mpirun -n 2`
/// (each rank reads its own rows: a bad row is found by one rank, and all agree), and
/// two on 1 rank (which reads every writer's rows): one error line, exit status 2, no
/// hang (mpirun's timeout), no summary. Before, they ended as on one process, except
/// `position_on_periodic_upper_face`, which panicked (`activate_tiles`). Plus a row
/// moved into the other writer's block, which only the same-layout reading can notice
/// (before: silently stepped by a rank that does not hold its cell).
#[test]
fn particle_cases_under_mpirun_agree() {
    let dir = temp_dir("ckpt-datasets-mpi");
    let good = checkpoint(&dir, 2);
    let mut failed = Vec::new();
    let mut cases = particle_cases();
    cases.push(case(
        "row_in_the_other_block",
        "lies in the block of rank",
        |f| {
            // The first row of writer 0 gets the position of writer 1's first row.
            let n0: Vec<u64> = f.dataset("rank_rows").unwrap().read_raw().unwrap();
            let w = checkpoint_table(f).1;
            rows(f, |v, col| {
                let b = n0[0] as usize * w;
                v[col("x[0]")] = v[b + col("x[0]")];
                v[col("x[1]")] = v[b + col("x[1]")];
            });
        },
    ));
    for (name, words, edit) in cases {
        let ckpt = edited(&good, &dir, name, &*edit);
        let out = dir.join(format!("out-{name}"));
        let mut c = common::mpirun(2);
        c.arg(BIN)
            .args(["run", "--restart", s(&ckpt), "--out", s(&out), "--quiet"]);
        let o = output(c);
        if let Some(m) = fault(&o, &ckpt, &out, words, true) {
            failed.push(format!("mpirun -n 2, {name}: {m}"));
        }
        if matches!(name, "position_nan" | "kind_out_of_range") {
            let out = dir.join(format!("one-{name}"));
            if let Some(m) = fault(&restart(&ckpt, &out), &ckpt, &out, words, false) {
                failed.push(format!("1 rank, {name}: {m}"));
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} case(s) failed:\n{}",
        failed.len(),
        failed.join("\n")
    );
    let _ = std::fs::remove_dir_all(&dir);
}
