//! The checks a parsed scene passes before anything runs: every key in range, and what
//! the run reads resolved into a typed [`Plan`].

mod bodies;

use super::schema::{variants, Boundary, Face, Field, Gradient, Model, Quadrature, Scene, Update};
use crate::input::plan::{CheckpointEvery, Plan};
use bodies::{kinds_of, validate_benchmark_table, validate_bodies, validate_materials};

type Invalid = (String, String);

/// The highest XPIC order accepted: each order costs one particle → grid pass per step,
/// and past a few the filter differs from FLIP only in the exact null space.
pub const MAX_XPIC: u32 = 8;
/// The most passes of the centroid correction: on a regular lattice each divides a
/// linear field's error at the nodes by about 3 (four leave under 2 % of it), and at a
/// node whose centroid is more than a cell away the series does not converge, so many
/// more passes would only let that node's error grow.
pub const MAX_CENTROID_PASSES: u32 = 8;
/// The largest sharpening `[method] sharpen` takes: beyond about 2.5 it over-corrects
/// the phase error it removes (docs/schemes.md, "Sharpening").
pub const MAX_SHARPEN: f64 = 4.0;

fn finite(key: &str, x: f64) -> Result<(), Invalid> {
    if x.is_finite() {
        Ok(())
    } else {
        Err((key.into(), format!("must be a finite number, got {x}")))
    }
}

fn positive(key: &str, x: f64) -> Result<(), Invalid> {
    finite(key, x)?;
    if x > 0.0 {
        Ok(())
    } else {
        Err((key.into(), format!("must be > 0, got {x}")))
    }
}

fn vector(key: &str, v: &[f64], dim: usize) -> Result<(), Invalid> {
    if v.len() != dim {
        return Err((
            key.into(),
            format!("must have dim = {dim} components, got {} ({v:?})", v.len()),
        ));
    }
    for (i, &x) in v.iter().enumerate() {
        finite(&format!("{key}[{i}]"), x)?;
    }
    Ok(())
}

/// The largest grid a scene may ask for, in nodes: 2^40, about 10^12. Only the tiles
/// near the bodies are stored, so the bound is not memory: node and cell numbers are
/// formed as products of per-axis counts (the particles' sort keys, tile keys, halo
/// chunk keys), which it keeps within 64 bits with room to spare.
const MAX_GRID_NODES: u64 = 1 << 40;

/// The most cells a grid axis may have: the tile pass keeps a cell per run of
/// particles as 32-bit numbers.
pub const MAX_CELLS_PER_AXIS: usize = i32::MAX as usize;

/// The most snapshots or time-interval checkpoints a scene may ask for over its run:
/// each is a file, and an interval far below the step size makes every step write one.
pub const MAX_OUTPUTS: f64 = 1e6;
/// The most steps a fixed `time.dt` may ask for.
pub const MAX_STEPS: f64 = 1e12;

/// An output interval gives at most [`MAX_OUTPUTS`] outputs up to `end`.
fn interval(key: &str, every: f64, end: f64, what: &str) -> Result<(), Invalid> {
    positive(key, every)?;
    let n = end / every;
    if n > MAX_OUTPUTS {
        return Err((
            key.into(),
            format!(
                "{every:e} would write {n:.3e} {what} up to time.end = {end:e}; at most {MAX_OUTPUTS:e} (an interval >= {:.3e})",
                end / MAX_OUTPUTS
            ),
        ));
    }
    Ok(())
}

/// A scene name is a plain file name (it names the output folder).
fn plain_name(name: &str) -> Result<(), Invalid> {
    // A plain file name: `.` and `..` would put the output folder on `out/` itself or
    // outside it, and a leading dot hides it.
    if name.trim().is_empty()
        || name.starts_with('.')
        || name
            .chars()
            .any(|c| !(c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.'))
    {
        return Err((
            "name".into(),
            format!(
                "must be a plain file name of letters, digits, `_`, `-` and `.`, not starting with `.` (it names the output folder), got {:?}",
                name
            ),
        ));
    }
    Ok(())
}

/// The grid is small enough to number.
fn grid_size(cells: &[usize]) -> Result<(), Invalid> {
    // A node count whose product overflows, or passes the bound the index products
    // need, is an input error, not a crash or a wrapped index.
    let nodes = cells.iter().try_fold(1u64, |n, &c| {
        (c as u64).checked_add(1).and_then(|c1| n.checked_mul(c1))
    });
    if nodes.is_none_or(|n| n > MAX_GRID_NODES) {
        let approx: f64 = cells.iter().map(|&c| c as f64 + 1.0).product();
        return Err((
            "grid.cells".into(),
            format!(
                "{approx:.3e} grid nodes is more than mpmcg numbers: at most 2^40 (about {MAX_GRID_NODES:.1e}) nodes in all; use fewer cells or a smaller box"
            ),
        ));
    }
    Ok(())
}

/// Check every key and resolve what the run reads in typed form.
pub(super) fn validate(s: &Scene) -> Result<Plan, Invalid> {
    let d = s.dim;
    if !(1..=3).contains(&d) {
        return Err(("dim".into(), format!("must be 1, 2 or 3, got {d}")));
    }
    plain_name(&s.name)?;
    validate_time(s)?;
    validate_method(s)?;
    validate_grid(s)?;
    let materials = validate_materials(s)?;
    let body_material = validate_bodies(s)?;
    let bodies::BodyKinds {
        kinds,
        body_kind,
        body_cut_kinds,
    } = kinds_of(s, &body_material)?;
    let benchmark = validate_benchmark_table(s)?;
    if let Some(gr) = &s.gravity {
        vector("gravity.value", &gr.value, s.dim)?;
    }
    validate_output(s)?;
    let checkpoint = validate_checkpoint(s)?;
    validate_parallel(s)?;
    Ok(Plan {
        materials,
        kinds,
        body_kind,
        body_cut_kinds,
        benchmark,
        body_force_over_domain: s
            .benchmark
            .as_ref()
            .is_some_and(|b| b.body_force == Some(Quadrature::Domain)),
        checkpoint,
    })
}

/// `[parallel]`: an imbalance threshold of at least 1 and a positive check interval.
fn validate_parallel(s: &Scene) -> Result<(), Invalid> {
    let p = &s.parallel;
    finite("parallel.imbalance", p.imbalance)?;
    if p.imbalance < 1.0 {
        return Err((
            "parallel.imbalance".into(),
            format!(
                "is the largest rank's particles over the mean, so it must be >= 1, got {}",
                p.imbalance
            ),
        ));
    }
    if p.check_every == 0 {
        return Err((
            "parallel.check_every".into(),
            "must be >= 1 (steps between imbalance checks), got 0".into(),
        ));
    }
    Ok(())
}

/// `[time]`: a positive end, and either a CFL number in (0, 1] or a step that does not
/// make more than [`MAX_STEPS`] steps.
fn validate_time(s: &Scene) -> Result<(), Invalid> {
    positive("time.end", s.time.end)?;
    match (s.time.cfl, s.time.dt) {
        (Some(_), Some(_)) => {
            return Err((
                "time.dt".into(),
                "give either `cfl` or `dt`, not both".into(),
            ))
        }
        (Some(c), None) => {
            positive("time.cfl", c)?;
            if c > 1.0 {
                return Err(("time.cfl".into(), format!("must be <= 1, got {c}")));
            }
        }
        (None, Some(dt)) => {
            positive("time.dt", dt)?;
            let n = s.time.end / dt;
            if n > MAX_STEPS {
                return Err((
                    "time.dt".into(),
                    format!(
                        "{dt:e} makes {n:.3e} steps up to time.end = {:e}; at most {MAX_STEPS:e}",
                        s.time.end
                    ),
                ));
            }
        }
        (None, None) => {}
    }
    Ok(())
}

/// `[method]`: the FLIP fraction, the XPIC order, the quadrature and the centroid
/// correction.
fn validate_method(s: &Scene) -> Result<(), Invalid> {
    validate_centroid(s)?;
    validate_sharpen(s)?;
    if s.method.quadrature == Quadrature::Domain && s.method.gradient != Gradient::Mpmcg {
        return Err((
            "method.quadrature".into(),
            format!(
                "the domain rule is MPMCG's quadrature: use it with gradient = \"mpmcg\" (got \"{}\")",
                s.method.gradient.name()
            ),
        ));
    }
    finite("method.flip", s.method.flip)?;
    if !(0.0..=1.0).contains(&s.method.flip) {
        return Err((
            "method.flip".into(),
            format!(
                "must be in [0, 1] (1 = FLIP, 0 = PIC), got {}",
                s.method.flip
            ),
        ));
    }
    if let Some(m) = s.method.xpic {
        if !(1..=MAX_XPIC).contains(&m) {
            return Err((
                "method.xpic".into(),
                format!("the XPIC order must be an integer in [1, {MAX_XPIC}], got {m}"),
            ));
        }
        if s.method.flip != 1.0 {
            return Err((
                "method.xpic".into(),
                format!(
                    "XPIC replaces the FLIP/PIC blend: leave method.flip at 1 (got {})",
                    s.method.flip
                ),
            ));
        }
    }
    Ok(())
}

/// `[method] centroid_passes`: it corrects the remapped velocity with the averaged
/// gradient L̄, so it needs a two-step scheme and MUSL (the other orders' particle
/// updates read the grid velocity it would change); XPIC's passes reuse the buffers it
/// fills.
fn validate_centroid(s: &Scene) -> Result<(), Invalid> {
    let n = s.method.centroid_passes;
    if n == 0 {
        return Ok(());
    }
    let key = || "method.centroid_passes".to_string();
    if n > MAX_CENTROID_PASSES {
        return Err((
            key(),
            format!("must be an integer in [0, {MAX_CENTROID_PASSES}] (0 = off), got {n}"),
        ));
    }
    if !matches!(s.method.gradient, Gradient::Mpmcg | Gradient::Averaged) {
        return Err((
            key(),
            format!(
                "the centroid correction uses the averaged gradient L̄: use it with gradient = \"mpmcg\" or \"averaged\" (got \"{}\")",
                s.method.gradient.name()
            ),
        ));
    }
    if s.method.update != Update::Musl {
        return Err((
            key(),
            format!(
                "the centroid correction corrects MUSL's remapped velocity: use it with update = \"musl\" (got \"{}\")",
                s.method.update.name()
            ),
        ));
    }
    if s.method.xpic.is_some() {
        return Err((
            key(),
            "the centroid correction and XPIC cannot be combined: drop one of method.xpic and method.centroid_passes".into(),
        ));
    }
    Ok(())
}

/// `[method] sharpen`: it acts on the averaged gradient's nodal averages, so it needs a
/// two-step scheme.
fn validate_sharpen(s: &Scene) -> Result<(), Invalid> {
    let b = s.method.sharpen;
    let key = || "method.sharpen".to_string();
    if !(0.0..=MAX_SHARPEN).contains(&b) {
        return Err((
            key(),
            format!("must be a number in [0, {MAX_SHARPEN}] (0 = off), got {b}"),
        ));
    }
    if b > 0.0 && !matches!(s.method.gradient, Gradient::Mpmcg | Gradient::Averaged) {
        return Err((
            key(),
            format!(
                "sharpening acts on the averaged gradient's nodal averages: use it with gradient = \"mpmcg\" or \"averaged\" (got \"{}\")",
                s.method.gradient.name()
            ),
        ));
    }
    Ok(())
}

/// `[grid]`: bounds and cells per axis, paired periodic faces, no face beyond `dim`.
fn validate_grid(s: &Scene) -> Result<(), Invalid> {
    let d = s.dim;
    let g = &s.grid;
    vector("grid.lower", &g.lower, d)?;
    vector("grid.upper", &g.upper, d)?;
    if g.cells.len() != d {
        return Err((
            "grid.cells".into(),
            format!("must have dim = {d} components, got {}", g.cells.len()),
        ));
    }
    grid_size(&g.cells)?;
    for a in 0..d {
        if g.cells[a] == 0 {
            return Err((format!("grid.cells[{a}]"), "must be >= 1, got 0".into()));
        }
        if g.cells[a] > MAX_CELLS_PER_AXIS {
            return Err((
                format!("grid.cells[{a}]"),
                format!(
                    "must be at most {MAX_CELLS_PER_AXIS} cells per axis, got {}",
                    g.cells[a]
                ),
            ));
        }
        if g.lower[a] >= g.upper[a] {
            return Err((
                "grid.upper".into(),
                format!(
                    "must be greater than grid.lower on every axis; axis {a}: lower {} >= upper {}",
                    g.lower[a], g.upper[a]
                ),
            ));
        }
        let lo = g.boundary.face(a, false);
        let hi = g.boundary.face(a, true);
        if (lo == Face::Periodic) != (hi == Face::Periodic) {
            let (p, other, face) = if lo == Face::Periodic {
                (2 * a, 2 * a + 1, hi)
            } else {
                (2 * a + 1, 2 * a, lo)
            };
            let given = if g.boundary.get(other).is_some() {
                ""
            } else {
                " (the default)"
            };
            return Err((
                format!("grid.boundary.{}", Boundary::KEYS[p]),
                format!(
                    "periodic faces come in pairs, but `{}` is `{}`{given}: set both to `periodic`",
                    Boundary::KEYS[other],
                    face.name()
                ),
            ));
        }
        if lo == Face::Periodic && g.cells[a] < 2 {
            return Err((
                format!("grid.cells[{a}]"),
                "a periodic axis needs at least 2 cells".into(),
            ));
        }
    }
    for k in 2 * d..6 {
        if g.boundary.get(k).is_some() {
            return Err((
                format!("grid.boundary.{}", Boundary::KEYS[k]),
                format!("this face does not exist in a {d}D scene"),
            ));
        }
    }
    Ok(())
}

/// `[output]`: no snapshot keys with `snapshots = false`, an interval that makes a
/// bounded number of snapshots, fields that some material carries.
fn validate_output(s: &Scene) -> Result<(), Invalid> {
    if let Some(o) = &s.output {
        if o.snapshots == Some(false) {
            if let Some(k) = [("every", o.every.is_some()), ("fields", o.fields.is_some())]
                .iter()
                .find(|k| k.1)
            {
                return Err((
                    format!("output.{}", k.0),
                    "is given, but `snapshots = false` writes no snapshots: remove one of the two"
                        .into(),
                ));
            }
        }
        if let Some(every) = o.every {
            interval("output.every", every, s.time.end, "snapshots")?;
        }
        for (i, f) in o.fields.iter().flatten().enumerate() {
            let needs = match f {
                Field::PlasticStrain => Some(Model::J2Plastic),
                Field::Damage => Some(Model::Brittle),
                _ => None,
            };
            if let Some(m) = needs.filter(|m| !s.materials.iter().any(|x| x.model == *m)) {
                return Err((
                    format!("output.fields[{i}]"),
                    format!(
                        "{:?} needs a material with model = \"{}\"; this scene has none",
                        variants::<Field>()[*f as usize],
                        variants::<Model>()[m as usize]
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// `[checkpoint]`: exactly one schedule, each in range, and `keep >= 1`.
fn validate_checkpoint(s: &Scene) -> Result<Option<CheckpointEvery>, Invalid> {
    let Some(c) = &s.checkpoint else {
        return Ok(None);
    };
    {
        let given: Vec<&str> = [
            ("every", c.every.is_some()),
            ("every_steps", c.every_steps.is_some()),
            ("every_seconds", c.every_seconds.is_some()),
        ]
        .iter()
        .filter(|k| k.1)
        .map(|k| k.0)
        .collect();
        if given.len() > 1 {
            return Err((
                format!("checkpoint.{}", given[1]),
                format!(
                    "give only one of `every`, `every_steps`, `every_seconds`, not both `{}` and `{}`",
                    given[0], given[1]
                ),
            ));
        }
        if let Some(t) = c.every {
            interval("checkpoint.every", t, s.time.end, "checkpoints")?;
        }
        if c.every_steps == Some(0) {
            return Err((
                "checkpoint.every_steps".into(),
                "must be >= 1, got 0".into(),
            ));
        }
        if let Some(t) = c.every_seconds {
            positive("checkpoint.every_seconds", t)?;
        }
        if c.keep == 0 {
            return Err((
                "checkpoint.keep".into(),
                "must be >= 1 (the newest checkpoint is always kept), got 0".into(),
            ));
        }
    }
    Ok(Some(match (c.every, c.every_steps, c.every_seconds) {
        (Some(t), _, _) => CheckpointEvery::Time(t),
        (_, Some(n), _) => CheckpointEvery::Steps(n),
        (_, _, Some(s)) => CheckpointEvery::Seconds(s),
        (None, None, None) => return Err((
            "checkpoint".into(),
            "give one of `every` (simulated time), `every_steps` or `every_seconds` (wall clock)"
                .into(),
        )),
    }))
}
