//! `history.csv`: the run's totals and errors, one row per sample.

use super::RunError;
use crate::mpm::solver::{Solver, Totals};
use crate::output::checkpoint::RunState;
use crate::output::io::agree;
use decomposition::Communicator;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Fewest steps between two history samples.
pub(super) const DIAG_MIN_STEPS: u64 = 10;

/// `history.csv` on rank 0: the file, and its whole text so far (checkpoints carry it,
/// so that a restart continues the same file). Write errors are kept, not returned, so
/// that rank 0 does not leave the others waiting in a collective; the run loop agrees
/// on them.
pub(super) struct History {
    file: Option<std::io::BufWriter<std::fs::File>>,
    pub(super) path: PathBuf,
    pub(super) text: Vec<u8>,
    pub(super) error: Option<String>,
}

impl History {
    /// Collective: `history.csv` on rank 0, a new file with its header or, after a
    /// restart, the restored text up to the checkpoint; every rank learns of a failure.
    pub(super) fn open<const D: usize>(
        comm: &dyn Communicator,
        out: &Path,
        solver: &Solver<D>,
        restored: Option<&RunState>,
    ) -> Result<Self, RunError> {
        let path = out.join("history.csv");
        let mut h = History {
            file: None,
            path: path.clone(),
            text: Vec::new(),
            error: None,
        };
        if comm.rank() == 0 {
            match std::fs::File::create(&path) {
                Ok(f) => h.file = Some(std::io::BufWriter::new(f)),
                Err(e) => h.error = Some(format!("{}: {e}", path.display())),
            }
            match restored {
                Some(st) => h.write(&String::from_utf8_lossy(&st.history)),
                None => h.write(&Self::header(solver)),
            }
        }
        if let Some(m) = agree(comm, h.error.clone()) {
            return Err(RunError::Io(m));
        }
        Ok(h)
    }

    /// The column names of a fresh file.
    fn header<const D: usize>(solver: &Solver<D>) -> String {
        let mut head = String::from("step,time,dt,kinetic,strain,external_work,total");
        for a in 0..D {
            head += &format!(",momentum_{a}");
        }
        for a in 0..D {
            head += &format!(",velocity_cm_{a}");
        }
        if solver.benchmark.is_some() {
            head += ",displacement_l2,velocity_l2";
        }
        if solver.carries().plastic {
            head += ",plastic_work";
        }
        if solver.null_space.is_some() {
            head += ",null_kinetic";
        }
        head + "\n"
    }

    fn write(&mut self, s: &str) {
        if let Some(f) = &mut self.file {
            self.text.extend_from_slice(s.as_bytes());
            if let Err(e) = f.write_all(s.as_bytes()) {
                self.error
                    .get_or_insert(format!("{}: {e}", self.path.display()));
            }
        }
    }

    pub(super) fn flush(&mut self) {
        if let Some(f) = &mut self.file {
            if let Err(e) = f.flush() {
                self.error
                    .get_or_insert(format!("{}: {e}", self.path.display()));
            }
        }
    }

    /// The row of the totals `tot`, the error norms `err` (benchmarks) and the
    /// kinetic energy the grid cannot see `null` (scenes that ask for it).
    pub(super) fn row<const D: usize>(
        &mut self,
        s: &Solver<D>,
        tot: &Totals,
        err: Option<(f64, f64)>,
        null: Option<f64>,
    ) {
        if self.file.is_none() {
            return;
        }
        use std::fmt::Write as _;
        let mut l = String::new();
        let _ = write!(
            l,
            "{},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e}",
            s.step,
            s.t,
            s.dt,
            tot.kinetic,
            tot.strain,
            tot.external_work,
            tot.total_energy()
        );
        for a in 0..D {
            let _ = write!(l, ",{:.17e}", tot.momentum[a]);
        }
        for a in 0..D {
            let _ = write!(l, ",{:.17e}", tot.momentum[a] / tot.mass);
        }
        if let Some((u, v)) = err {
            let _ = write!(l, ",{u:.17e},{v:.17e}");
        }
        if s.carries().plastic {
            let _ = write!(l, ",{:.17e}", tot.plastic_work);
        }
        if let Some(e) = null {
            let _ = write!(l, ",{e:.17e}");
        }
        l.push('\n');
        self.write(&l);
    }
}
