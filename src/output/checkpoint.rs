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
//! # Format (version 8; versions 3 to 7 are read too)
//!
//! Root attributes: `format` = "mpmcg-checkpoint", `version` = 8, `lineage` (the id
//! of the run and its restarts; pruning deletes only checkpoints of its own lineage),
//! `dim`, `step`,
//! `time`, `dt`, `max_speed` (fastest signal speed over all ranks after the step; the
//! next step size follows from it), `ranks` and `blocks` (the writer's process grid),
//! `cells`, `particles` (total), `record_width`, `carries_def_grad`, `carries_x0`,
//! `carries_half`, `carries_plastic`, `carries_damage`, `carries_stress_zz`,
//! `carries_stress` (0/1; absent in version 3, whose records always hold the stress),
//! `carries_mass` (0; absent before version 5, whose records hold the mass),
//! `carries_vol0` (0; absent before version 6, whose records hold the reference
//! volume, and the material where the `kind` column is), `carries_vol` (0 where the
//! particles carry `F`, whose volume is `det F · V₀`; absent before version 6, whose
//! records always hold the volume), and
//! the run loop's diagnostics: `initial_totals` and
//! `last_totals` (mass, kinetic, strain, external work, plastic work, momentum[dim]),
//! `initial_particles`, `last_particles`, `energy_scale`, `max_energy_deviation`,
//! `max_errors` (displacement, velocity), `has_last_errors`, `last_errors`,
//! `next_history_time`, `last_history_step`, `next_snapshot_time`,
//! `next_checkpoint_time`, `scene_defaults` (the version of the scene defaults the
//! stored scene was read with; absent before version 7).
//!
//! The file starts with a 512-byte user block that HDF5 leaves alone: the seal
//! ([`seal`](fn@seal)), `mpmcg checkpoint`, the length of the rest and a hash of every byte of
//! it, checked before HDF5 reads anything (files without it, from before, are read
//! unchecked).
//!
//! Datasets: `particles` (N × `record_width` f64): one row per particle as
//! [`Particles::pack`] lays it out (attribute `columns` names them), the rows of rank 0
//! first, each rank's in its memory order; `rank_rows` (ranks, u64): rows per writer
//! rank; `external_work` (ranks, f64): each writer rank's accumulated external work;
//! `checksum` (ranks, u64): a hash of each writer rank's rows; `scene` (u8): the scene
//! text verbatim; `history` (u8): `history.csv` up to this step; `snapshot_steps`,
//! `snapshot_times`, `snapshot_particles`: the snapshots written so far;
//! `kind_material` (u64) and `kind_vol0` (f64): per kind of particle, its material's
//! index and reference volume, which the `kind` column indexes (root attributes in
//! versions 6 and 7, absent before).
//!
//! Restart on the writer's rank count reads each rank's own rows back in their order
//! (bit-identical continuation). On another rank count every rank reads, in chunks,
//! the rows of the writers whose blocks overlap its own and keeps those in its cells:
//! from few writers onto many ranks that is most of the file per rank, fine for the
//! sizes of a few nodes but not for thousands of ranks.

mod access;
mod lineage;
mod read;
mod rows;
mod seal;
mod write;

pub use lineage::Lineage;
pub use read::{read, read_header, Restored};
pub use seal::seal;
pub use write::{write, Stored};

use crate::mpm::particles::{Carries, Columns, Particles};
use crate::mpm::solver::Totals;
use crate::output::io::Entry;
use decomposition::splitmix::mix;
use decomposition::Layout;
use std::path::PathBuf;

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
/// is `det F · V₀`). 7: the attribute `scene_defaults`, the version of the scene
/// defaults the stored scene was read with (1 when absent). 8: `kind_material` and
/// `kind_vol0` are datasets, not attributes (which hold at most 64 KB: a few bodies
/// seeded `cut` have more kinds).
pub const VERSION: u64 = 8;
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

/// Solver state besides the particles, for [`Solver::restore`](crate::mpm::solver::Solver::restore).
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
    /// The scene defaults the run read `scene_text` with (1 before version 7).
    pub scene_defaults: u32,
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
