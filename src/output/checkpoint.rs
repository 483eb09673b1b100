//! Restart checkpoints: one HDF5 file per checkpoint, written by all ranks together
//! with the collective machinery of [`crate::output::io`], holding everything a run needs to
//! continue bit for bit: every particle array, time, step, step size, the solver's
//! accumulated external work, the diagnostics of the run loop, the scene text and the
//! layout.
//!
//! A checkpoint is written as `OUT/.checkpoint_NNNNNN.h5.tmp`, closed by every rank,
//! flushed to disk and only then renamed to `OUT/checkpoint_NNNNNN.h5` by rank 0, so a
//! crash during a write leaves the previous checkpoints intact. Then the oldest
//! checkpoints beyond `keep` of this run's [`Lineage`] are deleted.
//!
//! # Format (version 6; versions 3 to 5 are read too)
//!
//! Root attributes: `format` = "mpmcg-checkpoint", `version` = 6, `lineage` (the id
//! of the run and its restarts; pruning deletes only checkpoints of its own lineage),
//! `dim`, `step`,
//! `time`, `dt`, `max_speed` (fastest signal speed over all ranks after the step; the
//! next step size follows from it), `ranks` and `blocks` (the writer's process grid),
//! `cells`, `particles` (total), `record_width`, `carries_def_grad`, `carries_x0`,
//! `carries_half`, `carries_plastic`, `carries_damage`, `carries_stress_zz`,
//! `carries_stress` (0/1; absent in version 3, whose records always hold the stress),
//! `carries_mass` (0; absent before version 5, whose records hold the mass),
//! `carries_vol0` (0; absent before version 6, whose records hold the reference
//! volume, and the material where the `kind` column is), `kind_material` and
//! `kind_vol0` (per kind of particle, its material's index and reference volume; the
//! `kind` column indexes them; absent before version 6), `carries_vol` (0 where the
//! particles carry `F`, whose volume is `det F · V₀`; absent before version 6, whose
//! records always hold the volume), and
//! the run loop's diagnostics: `initial_totals` and
//! `last_totals` (mass, kinetic, strain, external work, plastic work, momentum[dim]),
//! `initial_particles`, `last_particles`, `energy_scale`, `max_energy_deviation`,
//! `max_errors` (displacement, velocity), `has_last_errors`, `last_errors`,
//! `next_history_time`, `last_history_step`, `next_snapshot_time`,
//! `next_checkpoint_time`.
//!
//! The file starts with a 512-byte user block that HDF5 leaves alone: the seal
//! ([`seal`]), `mpmcg checkpoint`, the length of the rest and a hash of every byte of
//! it, checked before HDF5 reads anything (files without it, from before, are read
//! unchecked).
//!
//! Datasets: `particles` (N × `record_width` f64): one row per particle as
//! [`Particles::pack`] lays it out (attribute `columns` names them), the rows of rank 0
//! first, each rank's in its memory order; `rank_rows` (ranks, u64): rows per writer
//! rank; `external_work` (ranks, f64): each writer rank's accumulated external work;
//! `checksum` (ranks, u64): a hash of each writer rank's rows; `scene` (u8): the scene
//! text verbatim; `history` (u8): `history.csv` up to this step; `snapshot_steps`,
//! `snapshot_times`, `snapshot_particles`: the snapshots written so far.
//!
//! Restart on the writer's rank count reads each rank's own rows back in their order
//! (bit-identical continuation). On another rank count every rank reads all rows in
//! chunks and keeps those in its cells: O(N) reading per rank, fine for the sizes of a
//! few nodes but not for thousands of ranks.

use crate::mpm::particles::{Carries, Columns, Kinds, Particles};
use crate::mpm::solver::{Solver, Totals};
use crate::output::io::{self, agree, h5err, lockstep, Entry, IoError, Writer};
use crate::physics::shape::Geom;
use crate::physics::tensor::{det, Mat};
use decomposition::splitmix::mix;
use decomposition::{Communicator, Layout};
use hdf5::types::VarLenUnicode;
use std::path::{Path, PathBuf};

/// The `format` attribute of every checkpoint.
pub const FORMAT: &str = "mpmcg-checkpoint";
/// The format version this build writes. 3: the record gained `stress_zz` (2D
/// brittle particles) and the attribute `carries_stress_zz`. 4: the stress columns
/// only where the stress is state (`carries_stress`; a neo-Hookean particle's follows
/// from `F`). 5: no mass column (`carries_mass` = 0): a particle's mass is its
/// material's density times `vol0`. 6: no `vol0` column (`carries_vol0` = 0): the
/// column `kind` holds the particle's kind (material and reference volume, the
/// attributes `kind_material` and `kind_vol0`), where before 6 it held the material;
/// and no `vol` column where the particles carry `F` (`carries_vol` = 0: the volume
/// is `det F · V₀`).
pub const VERSION: u64 = 6;
/// The oldest version this build reads: a version 3 record always has the stress
/// columns, which a scene that does not store the stress drops on reading, records
/// before version 5 the mass, dropped too, and before 6 the material and `vol0`,
/// read as the kind they make.
pub const OLDEST: u64 = 3;

/// Rows read at a time when every rank scans the whole file.
const CHUNK_ROWS: usize = 1 << 16;

/// `checkpoint_NNNNNN.h5`.
pub fn checkpoint_name(step: u64) -> String {
    format!("checkpoint_{step:06}.h5")
}

fn temp_name(step: u64) -> String {
    format!(".checkpoint_{step:06}.h5.tmp")
}

/// The step of a file named `checkpoint_NNNNNN.h5`.
pub fn step_of(name: &str) -> Option<u64> {
    let n = name.strip_prefix("checkpoint_")?.strip_suffix(".h5")?;
    if n.len() < 6 || !n.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    n.parse().ok()
}

/// The state of the run loop (`run.rs`) that a restart continues with.
#[derive(Clone, Debug)]
pub struct RunState {
    /// Totals at t = 0.
    pub initial: Totals,
    /// Totals of the latest history sample.
    pub last: Totals,
    /// Energy drift normalisation, `max(|E(0)|, max_t (kinetic + strain))`.
    pub energy_scale: f64,
    /// `max_t |E(t) − E(0)|` over the history samples.
    pub max_energy_dev: f64,
    /// Maximum displacement and velocity error norms so far (benchmarks).
    pub max_err: (f64, f64),
    /// The latest error norms (benchmarks).
    pub last_err: Option<(f64, f64)>,
    pub next_history: f64,
    pub last_history_step: u64,
    pub next_snapshot: f64,
    pub next_checkpoint: f64,
    /// Snapshots written so far.
    pub snapshots: Vec<Entry>,
    /// `history.csv` so far (rank 0 only; empty elsewhere).
    pub history: Vec<u8>,
}

/// Solver state besides the particles, for [`Solver::restore`].
#[derive(Clone, Copy, Debug, Default)]
pub struct SolverState {
    pub t: f64,
    pub step: u64,
    pub dt: f64,
    /// This rank's share of the accumulated external work.
    pub external_work: f64,
    /// The fastest signal speed over all ranks.
    pub max_speed: f64,
}

/// What every rank learns from a checkpoint's attributes before reading particles.
#[derive(Clone, Debug)]
pub struct Header {
    pub path: PathBuf,
    pub scene_text: String,
    pub dim: usize,
    pub step: u64,
    pub time: f64,
    pub ranks: usize,
    pub blocks: Vec<usize>,
    /// The writer's block boundaries, per axis `blocks[a] + 1` cells from 0 to the
    /// axis' cells, back to back; `None` in checkpoints from before they moved.
    pub cuts: Option<Vec<usize>>,
    /// Rebalances of the blocks up to the checkpoint (0 before the count existed).
    pub rebalances: u64,
    pub particles: u64,
    /// The run (and its restarts) that wrote it; `None` in checkpoints from before
    /// the attribute existed.
    pub lineage: Option<String>,
}

impl Header {
    /// The writer's layout if it is one of `base`'s grid and process grid (uniform
    /// blocks for a checkpoint without cuts); `None` for another rank count or
    /// process grid, or cuts that do not fit the grid.
    pub fn layout<const D: usize>(&self, base: &Layout<D>) -> Option<Layout<D>> {
        if self.ranks != base.ranks() || self.blocks[..] != base.procs[..] {
            return None;
        }
        self.writer_layout(base)
    }

    /// The writer's layout of `base`'s grid, whatever its process grid; `None` if the
    /// stored blocks or cuts do not fit the grid.
    pub fn writer_layout<const D: usize>(&self, base: &Layout<D>) -> Option<Layout<D>> {
        let procs: [usize; D] = self.blocks.as_slice().try_into().ok()?;
        let uniform = Layout::new(base.cells, base.periodic, procs).ok()?;
        let Some(flat) = &self.cuts else {
            return Some(uniform);
        };
        let mut at = 0;
        let cuts: [Vec<usize>; D] = std::array::from_fn(|a| {
            let n = procs[a] + 1;
            let c = flat
                .get(at..at + n)
                .map_or_else(Vec::new, <[usize]>::to_vec);
            at += n;
            c
        });
        uniform.with_cuts(cuts).ok()
    }
}

fn totals_vec(t: &Totals) -> Vec<f64> {
    let mut v = vec![t.mass, t.kinetic, t.strain, t.external_work, t.plastic_work];
    v.extend_from_slice(&t.momentum);
    v
}

fn totals_from(v: &[f64], particles: u64) -> Totals {
    Totals {
        mass: v[0],
        kinetic: v[1],
        strain: v[2],
        external_work: v[3],
        plastic_work: v[4],
        momentum: v[5..].to_vec(),
        particles,
    }
}

/// Hash contribution of row `k` (counted within its writer rank) of a record matrix.
fn row_hash(k: u64, row: &[f64]) -> u64 {
    let w = row.len() as u64;
    let mut h = 0u64;
    for (c, x) in row.iter().enumerate() {
        h = h.wrapping_add(mix(x.to_bits() ^ mix(k * w + c as u64)));
    }
    h
}

/// Column names of a particle record, in [`Particles::pack`] order.
fn columns<const D: usize>(c: Carries) -> String {
    let mut cols: Vec<String> = Vec::new();
    for f in Particles::<D>::fields(c) {
        match f.columns {
            Columns::Scalar => cols.push(f.column.into()),
            Columns::Vector => (0..f.width).for_each(|a| cols.push(format!("{}[{a}]", f.column))),
            Columns::Matrix => {
                // Square, column-major like nalgebra's storage.
                let n = f.width.isqrt();
                for j in 0..n {
                    for i in 0..n {
                        cols.push(format!("{}[{i}][{j}]", f.column));
                    }
                }
            }
        }
    }
    cols.join(" ")
}

/// Collective: write a checkpoint of the solver and run state after the current step,
/// then delete the oldest checkpoints beyond `keep`. Returns the checkpoint's path.
/// Every rank returns the same result.
pub fn write<const D: usize>(
    comm: &dyn Communicator,
    out: &Path,
    solver: &Solver<D>,
    run: &RunState,
    scene_text: &str,
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
        write_run_state(&o, run)?;
        let hash = write_particles(&o, solver, offset, total)?;
        // One value per writer rank.
        let per_rank = o.rows(comm.rank() as u64, 1, comm.size() as u64);
        per_rank.u64s("rank_rows", &[n])?;
        per_rank.floats("external_work", &[external_work], 0)?;
        per_rank.u64s("checksum", &[hash])?;
        write_root_data(&o, scene_text, run, history_len)
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
    let kinds = &solver.kinds;
    let material: Vec<u64> = kinds.material.iter().map(|&m| u64::from(m)).collect();
    o.u64s("kind_material", &material)?;
    o.f64s("kind_vol0", &kinds.vol0)?;
    Ok(())
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
    scene_text: &str,
    run: &RunState,
    history_len: u64,
) -> Result<(), IoError> {
    let root = o.comm.rank() == 0;
    let only_root = |len: u64| o.rows(0, if root { len } else { 0 }, len);
    let pick = |b: &[u8]| if root { b.to_vec() } else { Vec::new() };
    only_root(scene_text.len() as u64).bytes("scene", &pick(scene_text.as_bytes()))?;
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

/// Bytes at the start of a checkpoint that HDF5 leaves alone (its user block), where
/// [`seal`] puts the checksum of the rest.
const SEAL_BYTES: usize = 512;
/// What a seal starts with.
const SEAL_MAGIC: &[u8; 16] = b"mpmcg checkpoint";
/// Where a plain HDF5 file (no user block) starts.
const HDF5_SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

/// The length and a hash of the bytes of `path` after its first [`SEAL_BYTES`], 8 at
/// a time (a short tail zero-padded), read in 1 MiB pieces (a checkpoint may be larger
/// than memory).
fn hash_after_seal(path: &Path) -> std::io::Result<(u64, u64)> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(path)?;
    f.seek(SeekFrom::Start(SEAL_BYTES as u64))?;
    let mut buf = vec![0u8; 1 << 20];
    let (mut len, mut h) = (0u64, mix(0x6d70_6d63_6773_6561));
    loop {
        // Fill the buffer (a read may return less), so that words never straddle reads.
        let mut n = 0;
        while n < buf.len() {
            match f.read(&mut buf[n..])? {
                0 => break,
                k => n += k,
            }
        }
        for c in buf[..n].chunks(8) {
            let mut w = [0u8; 8];
            w[..c.len()].copy_from_slice(c);
            h = mix(h ^ u64::from_le_bytes(w));
        }
        len += n as u64;
        if n < buf.len() {
            return Ok((len, mix(h ^ len)));
        }
    }
}

/// Rank 0, after the collective close: write into the user block the magic, the length
/// and the hash of everything after it ([`hash_after_seal`]). A restart checks it
/// before HDF5 parses anything: HDF5 itself crashes (SIGSEGV in `H5Aopen`) on some
/// damaged object headers, and took flipped bytes in attribute values (the time, the
/// step) as valid (`restart::mutated_checkpoints_never_panic`).
///
/// Public so that a checkpoint edited on purpose with HDF5 tools can be sealed again.
pub fn seal(path: &Path) -> std::io::Result<()> {
    use std::io::{Seek, SeekFrom, Write};
    let (len, hash) = hash_after_seal(path)?;
    let mut block = [0u8; 32];
    block[..16].copy_from_slice(SEAL_MAGIC);
    block[16..24].copy_from_slice(&len.to_le_bytes());
    block[24..].copy_from_slice(&hash.to_le_bytes());
    let mut f = std::fs::OpenOptions::new().write(true).open(path)?;
    f.seek(SeekFrom::Start(0))?;
    f.write_all(&block)
}

/// Check a checkpoint's seal before HDF5 opens it. A file that starts with the HDF5
/// signature has no user block (written before seals existed) and is let through, as
/// is one that is not HDF5 at all (HDF5's own message then says so).
fn check_seal(path: &Path) -> Result<(), String> {
    use std::io::Read;
    let p = path.display();
    let cannot = |e: std::io::Error| format!("{p}: cannot read the checkpoint: {e}");
    let mut head = Vec::with_capacity(SEAL_BYTES + 8);
    std::fs::File::open(path)
        .map_err(cannot)?
        .take(SEAL_BYTES as u64 + 8)
        .read_to_end(&mut head)
        .map_err(cannot)?;
    if head.starts_with(HDF5_SIGNATURE) {
        return Ok(());
    }
    if !head.starts_with(SEAL_MAGIC) {
        if head.len() == SEAL_BYTES + 8 && head[SEAL_BYTES..].starts_with(HDF5_SIGNATURE) {
            return Err(format!(
                "{p}: corrupt checkpoint: the header that holds its checksum is damaged"
            ));
        }
        return Ok(());
    }
    if head.len() < SEAL_BYTES {
        return Err(format!(
            "{p}: corrupt checkpoint: {} bytes, shorter than its header (truncated)",
            head.len()
        ));
    }
    let word = |at: usize| u64::from_le_bytes(head[at..at + 8].try_into().expect("8 bytes"));
    let (len, hash) = hash_after_seal(path).map_err(cannot)?;
    if word(16) != len {
        return Err(format!(
            "{p}: corrupt checkpoint: {len} bytes after its header, {} when written (truncated or extended)",
            word(16)
        ));
    }
    if word(24) != hash {
        return Err(format!(
            "{p}: corrupt checkpoint: its bytes do not match the checksum written with them"
        ));
    }
    Ok(())
}

/// The checkpoints one run and its restarts wrote (their attribute `lineage`), which
/// are the only ones pruning deletes: an output folder may also hold checkpoints of an
/// earlier, unrelated run, which are left alone. The list is kept on rank 0.
#[derive(Debug, Clone)]
pub struct Lineage {
    /// Written into every checkpoint: the same on every rank.
    pub id: String,
    /// How many of the newest to keep.
    pub keep: usize,
    /// This lineage's checkpoints in the output folder, by step (rank 0).
    ours: Vec<(u64, PathBuf)>,
}

impl Lineage {
    /// A new lineage (a fresh run): host, pid and time make it unique.
    pub fn fresh(keep: usize) -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        Self::continued(
            format!(
                "{}-{}-{nanos}",
                crate::output::lock::hostname(),
                std::process::id()
            ),
            keep,
        )
    }

    /// The lineage of the checkpoint a restart continues.
    pub fn continued(id: String, keep: usize) -> Self {
        Self {
            id,
            keep,
            ours: Vec::new(),
        }
    }

    /// Rank 0: adopt this lineage's checkpoints in `out` (after a restart, those of the
    /// run it continues). Returns the names of the others, which are never deleted.
    pub fn scan(&mut self, out: &Path) -> Vec<String> {
        let mut others = Vec::new();
        for e in std::fs::read_dir(out).into_iter().flatten().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(step) = step_of(&name) else { continue };
            // A damaged file is nobody's: HDF5 must not parse it (it may crash).
            let id = check_seal(&e.path())
                .ok()
                .and_then(|()| hdf5::File::open(e.path()).ok())
                .and_then(|f| lineage_of(&f));
            if id.as_deref() == Some(self.id.as_str()) {
                self.ours.push((step, e.path()));
            } else {
                others.push(name);
            }
        }
        self.ours.sort();
        others.sort();
        others
    }

    /// Rank 0: `path` (step `step`) was written; delete this lineage's checkpoints older
    /// than the newest `keep` with step <= `step` (later ones, left by an earlier run of
    /// a restarted job, are not touched).
    fn prune(&mut self, path: &Path, step: u64) -> Result<(), (PathBuf, std::io::Error)> {
        self.ours.retain(|(s, _)| *s != step);
        self.ours.push((step, path.to_path_buf()));
        self.ours.sort();
        let older = self.ours.iter().filter(|(s, _)| *s <= step).count();
        let drop = older.saturating_sub(self.keep);
        let gone: Vec<(u64, PathBuf)> = self.ours.drain(..drop).collect();
        for (_, p) in gone {
            match std::fs::remove_file(&p) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err((p, e)),
            }
        }
        Ok(())
    }
}

/// A checkpoint's `lineage` attribute.
/// Whether the root has attribute `name` (one added in a later version).
fn has_attr(f: &hdf5::File, name: &str) -> bool {
    f.attr_names().is_ok_and(|n| n.iter().any(|x| x == name))
}

fn lineage_of(f: &hdf5::File) -> Option<String> {
    f.attr("lineage")
        .and_then(|a| a.read_scalar::<VarLenUnicode>())
        .ok()
        .map(|s| s.as_str().to_string())
}

/// An HDF5 file that is an mpmcg checkpoint of this format version, opened for reading.
fn open(path: &Path) -> Result<hdf5::File, String> {
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

fn attr_u64(f: &hdf5::File, p: &Path, name: &str) -> Result<u64, String> {
    f.attr(name)
        .and_then(|a| a.read_scalar::<u64>())
        .map_err(|e| {
            format!(
                "{}: damaged checkpoint: attribute `{name}`: {e}",
                p.display()
            )
        })
}

fn attr_f64(f: &hdf5::File, p: &Path, name: &str) -> Result<f64, String> {
    f.attr(name)
        .and_then(|a| a.read_scalar::<f64>())
        .map_err(|e| {
            format!(
                "{}: damaged checkpoint: attribute `{name}`: {e}",
                p.display()
            )
        })
}

fn attr_vec<T: hdf5::H5Type>(
    f: &hdf5::File,
    p: &Path,
    name: &str,
    len: usize,
) -> Result<Vec<T>, String> {
    let v: Vec<T> = f.attr(name).and_then(|a| a.read_raw::<T>()).map_err(|e| {
        format!(
            "{}: damaged checkpoint: attribute `{name}`: {e}",
            p.display()
        )
    })?;
    if v.len() != len {
        return Err(format!(
            "{}: damaged checkpoint: attribute `{name}` has {} values, expected {len}",
            p.display(),
            v.len()
        ));
    }
    Ok(v)
}

fn dataset<T: hdf5::H5Type>(
    f: &hdf5::File,
    p: &Path,
    name: &str,
    len: usize,
) -> Result<Vec<T>, String> {
    let v: Vec<T> = f
        .dataset(name)
        .and_then(|d| d.read_raw::<T>())
        .map_err(|e| format!("{}: damaged checkpoint: dataset `{name}`: {e}", p.display()))?;
    if v.len() != len {
        return Err(format!(
            "{}: damaged checkpoint: dataset `{name}` has {} values, expected {len}",
            p.display(),
            v.len()
        ));
    }
    Ok(v)
}

fn dataset_any<T: hdf5::H5Type>(f: &hdf5::File, p: &Path, name: &str) -> Result<Vec<T>, String> {
    f.dataset(name)
        .and_then(|d| d.read_raw::<T>())
        .map_err(|e| format!("{}: damaged checkpoint: dataset `{name}`: {e}", p.display()))
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
/// From here on not every integer is exact in f64 (the particle record, the history):
/// no step count or particle id reaches it.
const F64_INTEGERS: u64 = 1 << 53;

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

/// A checkpoint of version 6 or later names the stored scene's kinds of particle
/// (`kind_material`, `kind_vol0`), which its `kind` column indexes.
fn same_kinds(f: &hdf5::File, path: &Path, kinds: &Kinds) -> Result<(), String> {
    let n = kinds.material.len();
    let material: Vec<u64> = attr_vec(f, path, "kind_material", n)?;
    let vol0: Vec<f64> = attr_vec(f, path, "kind_vol0", n)?;
    let same = material
        .iter()
        .zip(&kinds.material)
        .all(|(&a, &b)| a == u64::from(b))
        && vol0
            .iter()
            .zip(&kinds.vol0)
            .all(|(a, b)| a.to_bits() == b.to_bits());
    if same {
        return Ok(());
    }
    Err(format!(
        "{}: damaged checkpoint: attributes `kind_material` {material:?} and `kind_vol0` {vol0:?} are not the kinds of particle of the stored scene ({:?}, {:?})",
        path.display(),
        kinds.material,
        kinds.vol0
    ))
}

/// The `particles` dataset of a checkpoint whose records are those `carries` needs.
struct Rows<'a> {
    ds: hdf5::Dataset,
    path: &'a Path,
    /// Values per row.
    width: usize,
    /// The arrays its records hold (more than the scene's for a version 3 file).
    carries: Carries,
}

impl<'a> Rows<'a> {
    /// Check that the checkpoint's grid and particle records are the scene's (`layout`,
    /// `carries`), and open its particle rows.
    fn open<const D: usize>(
        f: &hdf5::File,
        header: &'a Header,
        layout: &Layout<D>,
        carries: Carries,
    ) -> Result<Self, String> {
        let path = &header.path;
        let p = path.display();
        if header.dim != D {
            return Err(format!(
                "{p}: damaged checkpoint: dim {} != {D}",
                header.dim
            ));
        }
        let cells: Vec<u64> = attr_vec(f, path, "cells", D)?;
        if cells
            .iter()
            .zip(&layout.cells)
            .any(|(&a, &b)| a != b as u64)
        {
            return Err(format!(
                "{p}: damaged checkpoint: cells {cells:?} differ from the stored scene's {:?}",
                layout.cells
            ));
        }
        let version = attr_u64(f, path, "version")?;
        let flags = Carries::NAMES
            .iter()
            .map(|&name| match name {
                "stress" if version == 3 => Ok(true),
                "mass" if version <= 4 => Ok(true),
                "vol0" | "vol" if version <= 5 => Ok(true),
                _ => Ok(attr_u64(f, path, &format!("carries_{name}"))? != 0),
            })
            .collect::<Result<Vec<bool>, String>>()?;
        let stored = Carries::from_flags(&flags);
        let width = Particles::<D>::record_width(stored);
        // The stored stress of a version 3 file and the mass of a version 3 or 4 file
        // are read and then dropped, `vol0` before version 6 read into the kind, and
        // the volume before version 6 dropped where the particles carry `F` (`read`).
        let needed = Carries {
            stress: carries.stress || version == 3,
            mass: version <= 4,
            vol0: version <= 5,
            vol: carries.vol || version <= 5,
            ..carries
        };
        if stored != needed || attr_u64(f, path, "record_width")? != width as u64 {
            return Err(format!(
                "{p}: damaged checkpoint: its particle arrays ({stored:?}) are not those the stored scene needs ({carries:?})"
            ));
        }
        let n = header.particles as usize;
        let ds = f
            .dataset("particles")
            .map_err(|e| format!("{p}: damaged checkpoint: dataset `particles`: {e}"))?;
        // HDF5 would convert other numbers on reading (integers, f32) and lose values.
        let f64s = hdf5::types::TypeDescriptor::Float(hdf5::types::FloatSize::U8);
        match ds.dtype().and_then(|t| t.to_descriptor()) {
            Ok(t) if t == f64s => {}
            Ok(t) => {
                return Err(format!(
                "{p}: damaged checkpoint: dataset `particles` holds {t} values, not 64-bit floats"
            ))
            }
            Err(e) => return Err(format!("{p}: damaged checkpoint: dataset `particles`: {e}")),
        }
        if ds.shape() != [n, width] {
            return Err(format!(
                "{p}: damaged checkpoint: dataset `particles` has shape {:?}, expected [{n}, {width}]",
                ds.shape()
            ));
        }
        Ok(Self {
            ds,
            path,
            width,
            carries: stored,
        })
    }

    /// Rows `r0..r1`, back to back.
    fn read(&self, r0: usize, r1: usize) -> Result<Vec<f64>, String> {
        if r0 == r1 {
            return Ok(Vec::new());
        }
        self.ds
            .read_slice_2d::<f64, _>((r0..r1, ..))
            .map(|a| a.iter().copied().collect())
            .map_err(|e| {
                format!(
                    "{}: cannot read particles {r0}..{r1}: {e}",
                    self.path.display()
                )
            })
    }

    /// The rows of writer rank `w` do not match their checksum.
    fn corrupt(&self, w: usize) -> String {
        format!(
            "{}: corrupt checkpoint: the particle rows of writer rank {w} do not match their checksum",
            self.path.display()
        )
    }

    /// The rank of `layout` whose cells hold row `r`, or an error naming the row and
    /// what `check` finds wrong with it.
    fn row<const D: usize>(
        &self,
        check: &RowCheck<D>,
        layout: &Layout<D>,
        r: usize,
        rec: &[f64],
    ) -> Result<usize, String> {
        check.owner(layout, rec).map_err(|what| {
            format!(
                "{}: damaged checkpoint: dataset `particles`, row {r}: {what}",
                self.path.display()
            )
        })
    }

    /// No particle id twice among `parts` (this rank's): ids order particles within a
    /// cell (the bit-for-bit continuation) and name them in the snapshots.
    fn unique_ids<const D: usize>(&self, parts: &Particles<D>) -> Result<(), String> {
        let mut ids = parts.id.clone();
        ids.sort_unstable();
        match ids.windows(2).find(|w| w[0] == w[1]) {
            Some(w) => Err(format!(
                "{}: damaged checkpoint: dataset `particles`: particle id {} is in more than one row",
                self.path.display(),
                w[0]
            )),
            None => Ok(()),
        }
    }

    /// Same rank count and process grid as the writer's: this rank's own rows, in the
    /// writer's memory order, and its external work.
    fn own<const D: usize>(
        &self,
        writers: &Writers,
        rank: usize,
        layout: &Layout<D>,
        check: &RowCheck<D>,
        carries: Carries,
    ) -> Result<(Particles<D>, f64), String> {
        let mut parts = Particles::<D>::default();
        let r0 = writers.starts[rank];
        let r1 = r0 + writers.rows[rank] as usize;
        let mut hash = 0u64;
        let mut k = 0u64;
        let mut at = r0;
        while at < r1 {
            let end = (at + CHUNK_ROWS).min(r1);
            let buf = self.read(at, end)?;
            for rec in buf.chunks_exact(self.width) {
                hash = hash.wrapping_add(row_hash(k, rec));
                // The writer's rows lie in its block, which is this rank's.
                let r = r0 + k as usize;
                let owner = self.row(check, layout, r, rec)?;
                if owner != rank {
                    return Err(format!(
                        "{}: damaged checkpoint: dataset `particles`, row {r}: a particle of writer rank {rank} lies in the block of rank {owner}",
                        self.path.display()
                    ));
                }
                k += 1;
                parts.unpack(rec, carries);
            }
            at = end;
        }
        if hash != writers.sums[rank] {
            return Err(self.corrupt(rank));
        }
        Ok((parts, writers.work[rank]))
    }

    /// Another rank count, process grid or cuts: the rows of the writers for which
    /// `overlaps` holds (those whose blocks overlap this rank's), keeping those in
    /// this rank's cells, each writer's checksum checked; rank 0 carries the external
    /// work of all writers. Returns the particles, the work and the rows read.
    fn all<const D: usize>(
        &self,
        writers: &Writers,
        rank: usize,
        layout: &Layout<D>,
        check: &RowCheck<D>,
        carries: Carries,
        overlaps: impl Fn(usize) -> bool,
    ) -> Result<(Particles<D>, f64, u64), String> {
        let mut parts = Particles::<D>::default();
        let (rows, starts) = (&writers.rows, &writers.starts);
        let mut read = 0u64;
        for w in (0..rows.len()).filter(|&w| overlaps(w)) {
            let (r0, r1) = (starts[w], starts[w] + rows[w] as usize);
            let mut hash = 0u64;
            let mut at = r0;
            while at < r1 {
                let end = (at + CHUNK_ROWS).min(r1);
                let buf = self.read(at, end)?;
                for (i, rec) in buf.chunks_exact(self.width).enumerate() {
                    hash = hash.wrapping_add(row_hash((at + i - r0) as u64, rec));
                    if self.row(check, layout, at + i, rec)? == rank {
                        parts.unpack(rec, carries);
                    }
                }
                at = end;
            }
            if hash != writers.sums[w] {
                return Err(self.corrupt(w));
            }
            read += rows[w];
        }
        let external_work = if rank == 0 {
            writers.work.iter().sum()
        } else {
            0.0
        };
        Ok((parts, external_work, read))
    }
}

/// What a particle row must hold for the solver to step it: finite values, positive
/// mass, volumes and GIMP half-widths, a kind of the scene (before version 6: a
/// material and `vol0` that make one), an integer id,
/// damage in [0, 1], plastic strain >= 0, and a position on the grid (where a step
/// leaves every particle: below the upper face on periodic axes). A row that breaks
/// one made the solver index out of its materials or grid (a panic), or run on with
/// NaN.
struct RowCheck<'a, const D: usize> {
    geom: &'a Geom<D>,
    kinds: &'a Kinds,
    /// Per array of the record: column name, first value, values.
    fields: Vec<(&'static str, usize, usize)>,
    /// Where a record before version 6 holds `vol0` (its `kind` column then holds the
    /// material).
    vol0_at: Option<usize>,
    /// The record holds `F` and no volume: the volume is `det F · V₀`.
    volume_of_f: bool,
}

impl<'a, const D: usize> RowCheck<'a, D> {
    fn new(geom: &'a Geom<D>, carries: Carries, kinds: &'a Kinds) -> Self {
        let mut at = 0;
        let fields: Vec<_> = Particles::<D>::fields(carries)
            .iter()
            .map(|f| {
                at += f.width;
                (f.column, at - f.width, f.width)
            })
            .collect();
        let vol0_at = fields.iter().find(|f| f.0 == "vol0").map(|f| f.1);
        Self {
            geom,
            kinds,
            fields,
            vol0_at,
            volume_of_f: carries.def_grad && !carries.vol,
        }
    }

    /// What is wrong with `rec`, if anything.
    fn fault(&self, rec: &[f64]) -> Option<String> {
        let g = self.geom;
        for &(name, at, w) in &self.fields {
            let v = &rec[at..at + w];
            if let Some(x) = v.iter().find(|x| !x.is_finite()) {
                return Some(format!("`{name}` holds {x}"));
            }
            let fault = match name {
                "mass" | "vol" | "vol0" | "half" => v
                    .iter()
                    .find(|&&x| x <= 0.0)
                    .map(|x| format!("`{name}` = {x} is not positive")),
                "kind" => self.kind_fault(v[0], rec),
                "def_grad" if self.volume_of_f => {
                    let j = det(&Mat::<D>::from_column_slice(v));
                    (j <= 0.0).then(|| {
                        format!(
                            "`def_grad` has determinant {j}: the volume det F · V₀ is not positive"
                        )
                    })
                }
                "id" => (v[0] < 0.0 || v[0].fract() != 0.0 || v[0] >= F64_INTEGERS as f64)
                    .then(|| format!("particle id {} is not an integer id", v[0])),
                "eps_p" => (v[0] < 0.0).then(|| format!("`eps_p` = {} is negative", v[0])),
                "damage" => (!(0.0..=1.0).contains(&v[0]))
                    .then(|| format!("`damage` = {} is not in [0, 1]", v[0])),
                "x" => (0..D)
                    .find(|&a| {
                        let (lo, hi) = (g.lower[a], g.upper[a]);
                        v[a] < lo || v[a] > hi || (g.periodic[a] && v[a] == hi)
                    })
                    .map(|a| {
                        format!(
                            "position {v:?} is outside the grid on axis {a} ([{}, {}])",
                            g.lower[a], g.upper[a]
                        )
                    }),
                _ => None,
            };
            if fault.is_some() {
                return fault;
            }
        }
        None
    }

    /// What is wrong with a row's `kind` column `k` (`rec` the row): a kind index of
    /// the scene, or before version 6 a material index that makes one with `vol0`.
    fn kind_fault(&self, k: f64, rec: &[f64]) -> Option<String> {
        let n = self.kinds.material.len();
        let index = (k >= 0.0 && k.fract() == 0.0 && k <= f64::from(u16::MAX)).then_some(k as u16);
        match self.vol0_at {
            None => (index.is_none_or(|i| usize::from(i) >= n))
                .then(|| format!("kind index {k} is not one of the scene's {n} kinds of particle")),
            Some(at) => {
                let vol0 = rec[at];
                (index.and_then(|m| self.kinds.find(m, vol0)).is_none()).then(|| {
                    format!(
                        "material index {k} with `vol0` = {vol0} is not a kind of particle of \
                         the stored scene (a body's material with its particles per cell)"
                    )
                })
            }
        }
    }

    /// The rank of `layout` whose cells hold the particle of `rec`, or what is wrong
    /// with it.
    fn owner(&self, layout: &Layout<D>, rec: &[f64]) -> Result<usize, String> {
        if let Some(m) = self.fault(rec) {
            return Err(m);
        }
        let x: [f64; D] = std::array::from_fn(|a| rec[a]);
        let (c, _) = self.geom.locate(&x);
        let cell: [usize; D] =
            std::array::from_fn(|a| c[a].rem_euclid(layout.cells[a] as i64) as usize);
        Ok(layout.cell_owner(cell))
    }
}

/// Per writer rank: its rows, where they start, its external work and its checksum.
struct Writers {
    rows: Vec<u64>,
    starts: Vec<usize>,
    work: Vec<f64>,
    sums: Vec<u64>,
}

impl Writers {
    fn read(f: &hdf5::File, path: &Path, header: &Header) -> Result<Self, String> {
        let (writers, n) = (header.ranks, header.particles);
        let rows: Vec<u64> = dataset(f, path, "rank_rows", writers)?;
        // Checked: edited counts must not overflow (a panic in a debug build).
        if rows.iter().try_fold(0u64, |s, &r| s.checked_add(r)) != Some(n) {
            return Err(format!(
                "{}: damaged checkpoint: rank_rows {rows:?} do not add up to {n} particles",
                path.display()
            ));
        }
        let work: Vec<f64> = dataset(f, path, "external_work", writers)?;
        finite(path, "dataset `external_work`", &work, false)?;
        let sums: Vec<u64> = dataset(f, path, "checksum", writers)?;
        let starts: Vec<usize> = rows
            .iter()
            .scan(0usize, |acc, &r| {
                let s = *acc;
                *acc += r as usize;
                Some(s)
            })
            .collect();
        Ok(Self {
            rows,
            starts,
            work,
            sums,
        })
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

/// `values` of `what` (an attribute or dataset) are finite and, if `nonneg`, >= 0.
fn finite(path: &Path, what: &str, values: &[f64], nonneg: bool) -> Result<(), String> {
    match values
        .iter()
        .find(|x| !x.is_finite() || (nonneg && **x < 0.0))
    {
        Some(x) => Err(format!(
            "{}: damaged checkpoint: {what} holds {x}{}",
            path.display(),
            if nonneg && x.is_finite() {
                " (must be >= 0)"
            } else {
                ""
            }
        )),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all(flags: u32) -> Carries {
        let f: Vec<bool> = (0..Carries::NAMES.len())
            .map(|k| flags >> k & 1 == 1)
            .collect();
        Carries::from_flags(&f)
    }

    /// The record layout of format 3, as written before the fields were declared in one
    /// place: a reordered declaration would make old checkpoints unreadable. Format 4
    /// is the same with the stress columns only where `carries.stress`, format 5 with
    /// the mass only where `carries.mass` (read from formats 3 and 4), format 6 with
    /// `vol0` only where `carries.vol0` and `vol` only where `carries.vol` (both read
    /// from formats 3 to 5) and the column `material` named `kind` (it holds the
    /// material before format 6).
    #[test]
    fn columns_keep_the_format_3_layout() {
        assert_eq!(
            columns::<2>(all(!0)),
            "x[0] x[1] v[0] v[1] mass vol vol0 stress[0][0] stress[1][0] stress[0][1] \
             stress[1][1] kind id def_grad[0][0] def_grad[1][0] def_grad[0][1] \
             def_grad[1][1] x0[0] x0[1] half[0] half[1] be[0][0] be[1][0] be[2][0] be[0][1] \
             be[1][1] be[2][1] be[0][2] be[1][2] be[2][2] eps_p damage stress_zz"
        );
        assert_eq!(
            columns::<1>(all(0b11_1100_0010)),
            "x[0] v[0] mass vol vol0 stress[0][0] kind id x0[0]"
        );
        assert_eq!(
            columns::<1>(all(0b11_1000_0010)),
            "x[0] v[0] mass vol vol0 kind id x0[0]"
        );
        assert_eq!(
            columns::<1>(all(0b11_0000_0010)),
            "x[0] v[0] vol vol0 kind id x0[0]"
        );
        assert_eq!(
            columns::<1>(all(0b10_0000_0010)),
            "x[0] v[0] vol kind id x0[0]"
        );
        assert_eq!(columns::<1>(all(0b10)), "x[0] v[0] kind id x0[0]");
        assert_eq!(
            Carries::NAMES,
            [
                "def_grad",
                "x0",
                "half",
                "plastic",
                "damage",
                "stress_zz",
                "stress",
                "mass",
                "vol0",
                "vol"
            ]
        );
    }

    #[test]
    fn one_column_per_record_value() {
        fn check<const D: usize>() {
            for flags in 0..1 << Carries::NAMES.len() {
                let c = all(flags);
                let n = columns::<D>(c).split(' ').count();
                assert_eq!(n, Particles::<D>::record_width(c), "D = {D}, {c:?}");
            }
        }
        check::<1>();
        check::<2>();
        check::<3>();
    }
}
