//! Which checkpoints in an output folder belong to this run and its restarts, and the
//! pruning of the oldest of them.

use super::read::lineage_of;
use super::seal::check_seal;
use super::step_of;
use std::path::{Path, PathBuf};

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
    pub(super) fn prune(
        &mut self,
        path: &Path,
        step: u64,
    ) -> Result<(), (PathBuf, std::io::Error)> {
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
