//! Writing a checkpoint: collectively into a temporary file, then sealed, renamed and
//! the oldest of the lineage pruned (rank 0).

use super::seal::{seal, SEAL_BYTES};
use super::{
    checkpoint_name, columns, row_hash, step_of, temp_name, totals_vec, Lineage, RunState, FORMAT,
    VERSION,
};
use crate::mpm::particles::{Carries, Kinds, Particles};
use crate::mpm::solver::Solver;
use crate::output::io::{self, agree, h5err, lockstep, IoError, Writer};
use decomposition::Communicator;
use hdf5::types::VarLenUnicode;
use std::path::{Path, PathBuf};

/// The scene a checkpoint stores: its text as given and the version of the scene
/// defaults its absent keys took, so that a restart reads it as the run did.
#[derive(Clone, Copy)]
pub struct Stored<'a> {
    pub text: &'a str,
    pub defaults: u32,
}

/// Collective: write a checkpoint of the solver and run state after the current step,
/// then delete the oldest checkpoints beyond `keep`. Returns the checkpoint's path.
/// Every rank returns the same result.
pub fn write<const D: usize>(
    comm: &dyn Communicator,
    out: &Path,
    solver: &Solver<D>,
    run: &RunState,
    scene: Stored,
    lineage: &mut Lineage,
) -> Result<PathBuf, IoError> {
    let step = solver.step;
    let tmp = out.join(temp_name(step));
    let path = out.join(checkpoint_name(step));
    let root = comm.rank() == 0;
    let (external_work, local_speed) = solver.local_state();
    let mut speed = [local_speed];
    comm.max_f64(&mut speed);
    let n = solver.parts.len() as u64;
    let offset = comm.exclusive_scan_u64(n);
    let mut sums = [n, if root { run.history.len() as u64 } else { 0 }];
    comm.sum_u64(&mut sums);
    let (total, history_len) = (sums[0], sums[1]);

    let file = io::create_with_userblock(comm, &tmp, SEAL_BYTES as u64)?;
    let o = Out {
        comm,
        file: &file,
        path: &tmp,
    };
    let result = (|| -> Result<(), IoError> {
        write_header(&o, solver, &lineage.id, speed[0], total)?;
        write_kinds(&o, &solver.kinds)?;
        write_run_state(&o, run)?;
        let hash = write_particles(&o, solver, offset, total)?;
        // One value per writer rank.
        let per_rank = o.rows(comm.rank() as u64, 1, comm.size() as u64);
        per_rank.u64s("rank_rows", &[n])?;
        per_rank.floats("external_work", &[external_work], 0)?;
        per_rank.u64s("checksum", &[hash])?;
        write_root_data(&o, scene, run, history_len)
    })();
    // Closing is collective: after it every rank's rows are in the file. On failure
    // the partial file is gone and the earlier checkpoints are untouched.
    io::close(comm, file, &tmp, result).map_err(|e| {
        IoError(format!(
            "cannot write checkpoint {}: {e}; its partial file is deleted",
            path.display()
        ))
    })?;
    // Rank 0 makes the complete file durable, then gives it its name.
    let renamed = if root {
        finish(&tmp, &path, lineage).err()
    } else {
        None
    };
    match agree(comm, renamed) {
        Some(m) => Err(IoError(m)),
        None => Ok(path),
    }
}

/// A checkpoint file being written by every rank: each attribute and dataset is a
/// step all ranks take and agree on (see `io::lockstep`).
struct Out<'a> {
    comm: &'a dyn Communicator,
    file: &'a hdf5::File,
    path: &'a Path,
}

impl Out<'_> {
    /// One step's outcome, agreed over all ranks.
    fn agree(&self, r: hdf5::Result<()>) -> Result<(), IoError> {
        lockstep(self.comm, r.map_err(|e| h5err(self.path, e)))
    }

    fn u64(&self, name: &str, v: u64) -> Result<(), IoError> {
        let a = self.file.new_attr::<u64>().create(name);
        self.agree(a.and_then(|a| a.write_scalar(&v)))
    }

    fn f64(&self, name: &str, v: f64) -> Result<(), IoError> {
        let a = self.file.new_attr::<f64>().create(name);
        self.agree(a.and_then(|a| a.write_scalar(&v)))
    }

    fn f64s(&self, name: &str, v: &[f64]) -> Result<(), IoError> {
        let a = self.file.new_attr_builder().with_data(v).create(name);
        self.agree(a.map(|_| ()))
    }

    fn u64s(&self, name: &str, v: &[u64]) -> Result<(), IoError> {
        let a = self.file.new_attr_builder().with_data(v).create(name);
        self.agree(a.map(|_| ()))
    }

    fn text(&self, name: &str, v: &VarLenUnicode) -> Result<(), IoError> {
        let a = self.file.new_attr::<VarLenUnicode>().create(name);
        self.agree(a.and_then(|a| a.write_scalar(v)))
    }

    /// A writer of this rank's `count` rows at `offset` of datasets of `total` rows.
    fn rows(&self, offset: u64, count: u64, total: u64) -> Writer<'_> {
        Writer {
            comm: self.comm,
            file: self.file,
            path: self.path,
            offset,
            count,
            total,
        }
    }
}

/// The root attributes that say what the file is and what its particle records hold.
fn write_header<const D: usize>(
    o: &Out,
    solver: &Solver<D>,
    lineage: &str,
    max_speed: f64,
    total: u64,
) -> Result<(), IoError> {
    let carries = solver.carries();
    o.text("format", &FORMAT.parse().expect("ASCII"))?;
    let id: VarLenUnicode = lineage
        .parse()
        .map_err(|_| IoError(format!("{}: lineage id is not text", o.path.display())))?;
    o.text("lineage", &id)?;
    o.u64("version", VERSION)?;
    o.u64("dim", D as u64)?;
    o.u64("step", solver.step)?;
    o.f64("time", solver.t)?;
    o.f64("dt", solver.dt)?;
    o.f64("max_speed", max_speed)?;
    o.u64("ranks", o.comm.size() as u64)?;
    o.u64s("blocks", &solver.layout.procs.map(|p| p as u64))?;
    let cuts: Vec<u64> = (0..D)
        .flat_map(|a| solver.layout.cuts(a).iter().map(|&c| c as u64))
        .collect();
    o.u64s("cuts", &cuts)?;
    o.u64("rebalances", solver.rebalances)?;
    o.u64s("cells", &solver.layout.cells.map(|c| c as u64))?;
    o.u64("particles", total)?;
    o.u64("record_width", Particles::<D>::record_width(carries) as u64)?;
    for (name, on) in Carries::NAMES.iter().zip(carries.flags()) {
        o.u64(&format!("carries_{name}"), u64::from(on))?;
    }
    Ok(())
}

/// The kinds of particle the `kind` column indexes, `kind_material` and `kind_vol0`,
/// as datasets of rank 0's rows: a body seeded `cut` adds hundreds of kinds, more than
/// the 64 KB an HDF5 attribute holds.
fn write_kinds(o: &Out, kinds: &Kinds) -> Result<(), IoError> {
    let root = o.comm.rank() == 0;
    let n = kinds.material.len() as u64;
    let rows = o.rows(0, if root { n } else { 0 }, n);
    let (material, vol0): (Vec<u64>, &[f64]) = if root {
        (
            kinds.material.iter().map(|&m| u64::from(m)).collect(),
            &kinds.vol0,
        )
    } else {
        (Vec::new(), &[])
    };
    rows.u64s("kind_material", &material)?;
    rows.floats("kind_vol0", vol0, 0)
}

/// The run loop's diagnostics and schedule as root attributes.
fn write_run_state(o: &Out, run: &RunState) -> Result<(), IoError> {
    o.f64s("initial_totals", &totals_vec(&run.initial))?;
    o.u64("initial_particles", run.initial.particles)?;
    o.f64s("last_totals", &totals_vec(&run.last))?;
    o.u64("last_particles", run.last.particles)?;
    o.f64("energy_scale", run.energy_scale)?;
    o.f64("max_energy_deviation", run.max_energy_dev)?;
    o.f64s("max_errors", &[run.max_err.0, run.max_err.1])?;
    o.u64("has_last_errors", u64::from(run.last_err.is_some()))?;
    let le = run.last_err.unwrap_or((f64::NAN, f64::NAN));
    o.f64s("last_errors", &[le.0, le.1])?;
    o.f64("next_history_time", run.next_history)?;
    o.u64("last_history_step", run.last_history_step)?;
    o.f64("next_snapshot_time", run.next_snapshot)?;
    o.f64("next_checkpoint_time", run.next_checkpoint)
}

/// The `particles` dataset: one packed record per row, this rank's rows at `offset`
/// of `total`, with the attribute `columns`. Returns the hash of this rank's rows.
fn write_particles<const D: usize>(
    o: &Out,
    solver: &Solver<D>,
    offset: u64,
    total: u64,
) -> Result<u64, IoError> {
    let (parts, carries) = (&solver.parts, solver.carries());
    let width = Particles::<D>::record_width(carries);
    let mut rec = Vec::with_capacity(width);
    let mut hash = 0u64;
    let rows = o.rows(offset, parts.len() as u64, total);
    rows.blocks("particles", width, &mut Vec::new(), |r, buf| {
        for p in r {
            parts.pack(p, carries, &mut rec);
            debug_assert_eq!(rec.len(), width);
            hash = hash.wrapping_add(row_hash(p as u64, &rec));
            buf.extend_from_slice(&rec);
        }
    })?;
    crash_for_tests(solver.step);
    o.agree(o.file.dataset("particles").and_then(|ds| {
        let cols: VarLenUnicode = columns::<D>(carries).parse().expect("ASCII");
        ds.new_attr::<VarLenUnicode>()
            .create("columns")
            .and_then(|a| a.write_scalar(&cols))
    }))?;
    Ok(hash)
}

/// The data rank 0 writes alone (the others take part with empty selections): the
/// scene text, `history.csv` so far (`history_len` bytes) and the snapshot list.
fn write_root_data(
    o: &Out,
    scene: Stored,
    run: &RunState,
    history_len: u64,
) -> Result<(), IoError> {
    let root = o.comm.rank() == 0;
    let only_root = |len: u64| o.rows(0, if root { len } else { 0 }, len);
    let pick = |b: &[u8]| if root { b.to_vec() } else { Vec::new() };
    only_root(scene.text.len() as u64).bytes("scene", &pick(scene.text.as_bytes()))?;
    o.u64("scene_defaults", u64::from(scene.defaults))?;
    only_root(history_len).bytes("history", &pick(&run.history))?;
    let k = run.snapshots.len() as u64;
    let steps: Vec<u64> = run.snapshots.iter().map(|s| s.step).collect();
    let times: Vec<f64> = run.snapshots.iter().map(|s| s.time).collect();
    let counts: Vec<u64> = run.snapshots.iter().map(|s| s.particles).collect();
    let mine = |v: Vec<u64>| if root { v } else { Vec::new() };
    only_root(k).u64s("snapshot_steps", &mine(steps))?;
    only_root(k).floats("snapshot_times", &if root { times } else { Vec::new() }, 0)?;
    only_root(k).u64s("snapshot_particles", &mine(counts))
}

/// Test hook: `MPMCG_TEST_CRASH_IN_CHECKPOINT=STEP` aborts every rank in the middle of
/// writing the checkpoint of step STEP (particles written, the rest not), to show that a
/// crash during a write leaves the earlier checkpoints intact.
fn crash_for_tests(step: u64) {
    if std::env::var("MPMCG_TEST_CRASH_IN_CHECKPOINT").is_ok_and(|v| v == step.to_string()) {
        eprintln!("MPMCG_TEST_CRASH_IN_CHECKPOINT: aborting while writing step {step}");
        std::process::abort();
    }
}

/// Rank 0: fsync the temporary file, rename it, fsync the folder, delete old ones.
fn finish(tmp: &Path, path: &Path, lineage: &mut Lineage) -> Result<(), String> {
    let io = |p: &Path, e: std::io::Error| format!("{}: {e}", p.display());
    // A file system may report a full disk only when the data is flushed: then the
    // temporary file goes too.
    let renamed = seal(tmp)
        .and_then(|()| std::fs::File::open(tmp))
        .and_then(|f| f.sync_all())
        .map_err(|e| io(tmp, e))
        .and_then(|()| std::fs::rename(tmp, path).map_err(|e| io(path, e)));
    if let Err(m) = renamed {
        let _ = std::fs::remove_file(tmp);
        return Err(m);
    }
    if let Some(d) = path.parent().and_then(|d| std::fs::File::open(d).ok()) {
        let _ = d.sync_all();
    }
    let step = step_of(&path.file_name().unwrap_or_default().to_string_lossy()).unwrap_or(0);
    lineage.prune(path, step).map_err(|(p, e)| io(&p, e))
}
