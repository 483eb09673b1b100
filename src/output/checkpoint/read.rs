//! Reading a checkpoint: opening and checking it, its header, and the particles and
//! run state a restart continues with.

use super::access::{attr_f64, attr_u64, attr_vec, dataset, dataset_any, finite, F64_INTEGERS};
use super::rows::{RowCheck, Rows, Writers};
use super::seal::check_seal;
use super::{totals_from, Header, RunState, SolverState, FORMAT, OLDEST, VERSION};
use crate::input::scene;
use crate::mpm::particles::{Carries, Kinds, Particles};
use crate::output::io::Entry;
use crate::physics::shape::Geom;
use decomposition::Layout;
use hdf5::types::VarLenUnicode;
use std::path::Path;

/// A checkpoint's `lineage` attribute.
/// Whether the root has attribute `name` (one added in a later version).
fn has_attr(f: &hdf5::File, name: &str) -> bool {
    f.attr_names().is_ok_and(|n| n.iter().any(|x| x == name))
}

pub(super) fn lineage_of(f: &hdf5::File) -> Option<String> {
    f.attr("lineage")
        .and_then(|a| a.read_scalar::<VarLenUnicode>())
        .ok()
        .map(|s| s.as_str().to_string())
}

/// An HDF5 file that is an mpmcg checkpoint of this format version, opened for reading.
pub(super) fn open(path: &Path) -> Result<hdf5::File, String> {
    let p = path.display();
    let meta =
        std::fs::metadata(path).map_err(|e| format!("{p}: cannot read the checkpoint: {e}"))?;
    if meta.is_dir() {
        return Err(format!("{p}: is a folder, not a checkpoint file"));
    }
    if meta.len() == 0 {
        return Err(format!("{p}: the file is empty, not an mpmcg checkpoint"));
    }
    check_seal(path)?;
    let file = hdf5::File::open(path).map_err(|e| {
        format!("{p}: not a readable HDF5 file (truncated, corrupt or not HDF5): {e}")
    })?;
    let format = file
        .attr("format")
        .and_then(|a| a.read_scalar::<VarLenUnicode>())
        .map(|s| s.as_str().to_string());
    match format {
        Ok(f) if f == FORMAT => {}
        Ok(f) => {
            return Err(format!(
                "{p}: not an mpmcg checkpoint (its format is {f:?}, expected {FORMAT:?})"
            ))
        }
        Err(_) if file.link_exists("position") => {
            return Err(format!(
                "{p}: not an mpmcg checkpoint but a particle snapshot; restart from a checkpoint_NNNNNN.h5 file"
            ))
        }
        Err(_) => {
            return Err(format!(
                "{p}: not an mpmcg checkpoint (an HDF5 file without the attribute format = {FORMAT:?})"
            ))
        }
    }
    let version = file
        .attr("version")
        .and_then(|a| a.read_scalar::<u64>())
        .map_err(|e| format!("{p}: damaged checkpoint: attribute `version`: {e}"))?;
    if !(OLDEST..=VERSION).contains(&version) {
        return Err(format!(
            "{p}: checkpoint format version {version}, but this mpmcg reads versions {OLDEST} to {VERSION}"
        ));
    }
    Ok(file)
}

/// Open a checkpoint and read what every rank needs before anything else: the scene,
/// dimension, step, time and the writer's layout. Errors name the file.
pub fn read_header(path: &Path) -> Result<Header, String> {
    let f = open(path)?;
    let p = path.display();
    let dim = attr_u64(&f, path, "dim")? as usize;
    if !(1..=3).contains(&dim) {
        return Err(format!("{p}: damaged checkpoint: dim = {dim}"));
    }
    let ranks = attr_u64(&f, path, "ranks")?;
    let blocks: Vec<u64> = attr_vec(&f, path, "blocks", dim)?;
    // Checked: an edited count must not overflow (a panic in a debug build).
    let product = blocks.iter().try_fold(1u64, |acc, &b| acc.checked_mul(b));
    if !(1..=MAX_RANKS).contains(&ranks) || blocks.contains(&0) || product != Some(ranks) {
        return Err(format!(
            "{p}: damaged checkpoint: blocks {blocks:?} do not match {ranks} ranks"
        ));
    }
    let cells: Vec<u64> = attr_vec(&f, path, "cells", dim)?;
    let cuts = if has_attr(&f, "cuts") {
        let len = blocks.iter().map(|&b| b as usize + 1).sum();
        let c: Vec<u64> = attr_vec(&f, path, "cuts", len)?;
        check_cuts(path, &c, &blocks, &cells)?;
        Some(c.into_iter().map(|c| c as usize).collect())
    } else {
        None
    };
    let scene: Vec<u8> = dataset_any(&f, path, "scene")?;
    let scene_text = String::from_utf8(scene)
        .map_err(|_| format!("{p}: damaged checkpoint: the stored scene is not UTF-8 text"))?;
    let scene_defaults = if has_attr(&f, "scene_defaults") {
        let v = attr_u64(&f, path, "scene_defaults")?;
        if !(u64::from(scene::PLAIN_DEFAULTS)..=u64::from(scene::DEFAULTS)).contains(&v) {
            return Err(format!(
                "{p}: attribute `scene_defaults` = {v}, but this mpmcg knows scene defaults {} to {}",
                scene::PLAIN_DEFAULTS,
                scene::DEFAULTS
            ));
        }
        v as u32
    } else {
        scene::PLAIN_DEFAULTS
    };
    let step = attr_u64(&f, path, "step")?;
    // Steps count up by one from 0, and the history stores them as numbers.
    if step >= F64_INTEGERS {
        return Err(format!(
            "{p}: damaged checkpoint: attribute `step` = {step} is beyond any run's step count"
        ));
    }
    let time = attr_f64(&f, path, "time")?;
    if !(time.is_finite() && time >= 0.0) {
        return Err(format!(
            "{p}: damaged checkpoint: attribute `time` = {time} is not a finite time >= 0"
        ));
    }
    // Absent in checkpoints from before lineages; present, it must be text.
    let lineage = if has_attr(&f, "lineage") {
        let id = lineage_of(&f);
        Some(id.ok_or_else(|| format!("{p}: damaged checkpoint: attribute `lineage` is not text"))?)
    } else {
        None
    };
    Ok(Header {
        path: path.to_path_buf(),
        scene_text,
        scene_defaults,
        dim,
        step,
        time,
        ranks: ranks as usize,
        blocks: blocks.iter().map(|&b| b as usize).collect(),
        cuts,
        rebalances: if has_attr(&f, "rebalances") {
            attr_u64(&f, path, "rebalances")?
        } else {
            0
        },
        particles: attr_u64(&f, path, "particles")?,
        lineage,
    })
}

/// More writer ranks than any machine runs: refused before sizes are computed from them.
const MAX_RANKS: u64 = 1 << 32;
/// The stored block boundaries, per axis `blocks[a] + 1` increasing cell indices from
/// 0 to the axis' cells (whether the blocks are wide enough for the scene's ghost
/// layers is [`read`]'s check, which knows the boundaries).
fn check_cuts(path: &Path, cuts: &[u64], blocks: &[u64], cells: &[u64]) -> Result<(), String> {
    let mut at = 0;
    for (a, (&b, &n)) in blocks.iter().zip(cells).enumerate() {
        let c = &cuts[at..at + b as usize + 1];
        at += c.len();
        if c[0] != 0 || c[c.len() - 1] != n || c.windows(2).any(|w| w[1] <= w[0]) {
            return Err(format!(
                "{}: damaged checkpoint: attribute `cuts` {c:?} on axis {a} are not increasing block boundaries from 0 to its {n} cells",
                path.display()
            ));
        }
    }
    Ok(())
}

/// Everything a restart reads on one rank.
pub struct Restored<const D: usize> {
    pub parts: Particles<D>,
    pub solver: SolverState,
    pub run: RunState,
    /// Particle rows this rank read from the file.
    pub rows_read: u64,
}

/// Read this rank's particles and the run state (no collectives: the caller agrees on
/// the outcome). With the writer's rank count and process grid each rank reads its own
/// rows in their order; otherwise it scans the rows of the writers whose blocks overlap
/// its own and keeps those in its cells (a rank of a finer process grid reads a few
/// writers' rows, not the whole file).
///
/// Every value the run consumes is checked (a checkpoint may have been edited with
/// HDF5 tools and sealed again): each particle row must be one the solver can step
/// (see [`RowCheck`]), of one of the scene's `kinds` (its material and `vol0` before
/// version 6).
pub fn read<const D: usize>(
    header: &Header,
    rank: usize,
    layout: &Layout<D>,
    geom: &Geom<D>,
    carries: Carries,
    kinds: &Kinds,
) -> Result<Restored<D>, String> {
    let path = &header.path;
    let p = path.display();
    let f = open(path)?;
    let rows = Rows::open::<D>(&f, header, layout, carries)?;
    if !rows.carries.vol0 {
        same_kinds(&f, path, kinds)?;
    }
    // Blocks the grid cannot have (too narrow for the ghost layers) were not written
    // by a run: refused rather than silently read as uniform blocks.
    let Some(writer) = header.writer_layout(layout) else {
        return Err(format!(
            "{p}: damaged checkpoint: attributes `blocks` {:?} and `cuts` {:?} are not a division of the {:?} cells",
            header.blocks,
            header.cuts.as_deref().unwrap_or_default(),
            layout.cells
        ));
    };
    let writers = Writers::read(&f, path, header)?;
    let stored = rows.carries;
    let check = RowCheck::new(geom, stored, kinds);
    let same = header.layout(layout).as_ref() == Some(layout);
    let (mut parts, external_work, rows_read) = if same {
        let (p, w) = rows.own(&writers, rank, layout, &check, stored)?;
        let n = p.len() as u64;
        (p, w, n)
    } else {
        // Only the writers whose blocks overlap this rank's hold its particles.
        let (lo, hi) = layout.block_cells(rank);
        let overlaps = |w: usize| {
            let (wlo, whi) = writer.block_cells(w);
            (0..D).all(|a| wlo[a] < hi[a] && lo[a] < whi[a])
        };
        rows.all(&writers, rank, layout, &check, stored, overlaps)?
    };
    if !carries.stress {
        // A version 3 record's stress of a material whose stress follows from `F`.
        parts.stress = Vec::new();
    }
    // A record's mass before version 5: density × vol0 as seeded, formed where used.
    parts.mass = Vec::new();
    if !carries.vol {
        // A record's volume before version 6, where the particles carry `F`: det F · V₀.
        parts.vol = Vec::new();
    }
    if stored.vol0 {
        // Before version 6: the material and `vol0` make the kind (checked per row).
        for (k, &v) in parts.kind.iter_mut().zip(&parts.vol0) {
            *k = kinds.find(*k, v).expect("a row's kind is checked");
        }
        parts.vol0 = Vec::new();
    }
    rows.unique_ids(&parts)?;
    let run = read_run_state::<D>(&f, path, rank, header.step)?;
    let dt = attr_f64(&f, path, "dt")?;
    // Every checkpoint follows a step (a state at step 0 has not taken one).
    let dt_ok = dt.is_finite() && (dt > 0.0 || (dt == 0.0 && header.step == 0));
    if !dt_ok {
        return Err(format!(
            "{p}: damaged checkpoint: attribute `dt` = {dt} is not a positive step size"
        ));
    }
    // The next step size follows from it: NaN would give a step to the end at once,
    // infinity a step of 0.
    let max_speed = attr_f64(&f, path, "max_speed")?;
    if !(max_speed.is_finite() && max_speed >= 0.0) {
        return Err(format!(
            "{p}: damaged checkpoint: attribute `max_speed` = {max_speed} is not a finite speed >= 0"
        ));
    }
    let solver = SolverState {
        t: header.time,
        step: header.step,
        dt,
        external_work,
        max_speed,
    };
    Ok(Restored {
        parts,
        solver,
        run,
        rows_read,
    })
}

/// A checkpoint of version 6 or later names the stored scene's kinds of particle,
/// which its `kind` column indexes: `kind_material` and `kind_vol0`, datasets from
/// version 8 and root attributes before.
fn same_kinds(f: &hdf5::File, path: &Path, kinds: &Kinds) -> Result<(), String> {
    let n = kinds.material.len();
    let (material, vol0, what): (Vec<u64>, Vec<f64>, _) = if has_attr(f, "kind_vol0") {
        let m = attr_vec(f, path, "kind_material", n)?;
        (m, attr_vec(f, path, "kind_vol0", n)?, "attributes")
    } else {
        let m = dataset(f, path, "kind_material", n)?;
        (m, dataset(f, path, "kind_vol0", n)?, "datasets")
    };
    let other = (0..n).find(|&k| {
        material[k] != u64::from(kinds.material[k]) || vol0[k].to_bits() != kinds.vol0[k].to_bits()
    });
    match other {
        None => Ok(()),
        Some(k) => Err(format!(
            "{}: damaged checkpoint: {what} `kind_material` and `kind_vol0` are not the kinds of particle of the stored scene: kind {k} is material {} of reference volume {:e}, where the scene's is material {} of {:e}",
            path.display(),
            material[k],
            vol0[k],
            kinds.material[k],
            kinds.vol0[k]
        )),
    }
}

/// The run loop's state (`history.csv` on rank 0 only) of a checkpoint at `step`. Its
/// totals, energy figures and error norms must be finite (they end up in the summary)
/// and its schedule a number of steps and times (NaN would silently stop the history,
/// snapshots or checkpoints).
fn read_run_state<const D: usize>(
    f: &hdf5::File,
    path: &Path,
    rank: usize,
    step: u64,
) -> Result<RunState, String> {
    let p = path.display();
    let nt = 5 + D;
    let floats = |name: &str, len: usize, nonneg: bool| -> Result<Vec<f64>, String> {
        let v: Vec<f64> = attr_vec(f, path, name, len)?;
        finite(path, &format!("attribute `{name}`"), &v, nonneg)?;
        Ok(v)
    };
    let float = |name: &str, nonneg: bool| -> Result<f64, String> {
        let x = attr_f64(f, path, name)?;
        finite(path, &format!("attribute `{name}`"), &[x], nonneg)?;
        Ok(x)
    };
    let me = floats("max_errors", 2, true)?;
    let last_err = if attr_u64(f, path, "has_last_errors")? != 0 {
        let le = floats("last_errors", 2, true)?;
        Some((le[0], le[1]))
    } else {
        attr_vec::<f64>(f, path, "last_errors", 2)?;
        None
    };
    let steps: Vec<u64> = dataset_any(f, path, "snapshot_steps")?;
    let times: Vec<f64> = dataset(f, path, "snapshot_times", steps.len())?;
    finite(path, "dataset `snapshot_times`", &times, true)?;
    let counts: Vec<u64> = dataset(f, path, "snapshot_particles", steps.len())?;
    let last_history_step = attr_u64(f, path, "last_history_step")?;
    if let Some(s) = steps
        .iter()
        .chain([&last_history_step])
        .find(|&&s| s > step)
    {
        return Err(format!(
            "{p}: damaged checkpoint: step {s} of its history or snapshots is after its step {step}"
        ));
    }
    let when = |name: &str| -> Result<f64, String> {
        let t = attr_f64(f, path, name)?;
        if t.is_nan() {
            return Err(format!(
                "{p}: damaged checkpoint: attribute `{name}` is NaN"
            ));
        }
        Ok(t)
    };
    Ok(RunState {
        initial: totals_from(
            &floats("initial_totals", nt, false)?,
            attr_u64(f, path, "initial_particles")?,
        ),
        last: totals_from(
            &floats("last_totals", nt, false)?,
            attr_u64(f, path, "last_particles")?,
        ),
        energy_scale: float("energy_scale", true)?,
        max_energy_dev: float("max_energy_deviation", true)?,
        max_err: (me[0], me[1]),
        last_err,
        next_history: when("next_history_time")?,
        last_history_step,
        next_snapshot: when("next_snapshot_time")?,
        next_checkpoint: when("next_checkpoint_time")?,
        snapshots: (0..steps.len())
            .map(|k| Entry {
                step: steps[k],
                time: times[k],
                particles: counts[k],
            })
            .collect(),
        history: if rank == 0 {
            dataset_any(f, path, "history")?
        } else {
            Vec::new()
        },
    })
}
