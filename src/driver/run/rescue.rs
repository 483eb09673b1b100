//! The rescue of an unstable run: the newest state known good, kept every few steps,
//! replayed and checkpointed when a step fails.

use super::schedules::Requests;
use super::setup::set_up;
use super::{layout_for, Run, RunError, RunOptions};
use crate::driver::signals;
use crate::mpm::particles::Particles;
use crate::mpm::solver::{Failure, Solver};
use crate::output::checkpoint::{RunState, SolverState};
use std::time::Instant;

/// Steps between the states kept for [`Rescue`].
pub(super) const RESCUE_EVERY: u64 = 10;

/// The newest state known good (at most [`RESCUE_EVERY`] steps old, never older than
/// the newest checkpoint): a run that turns unstable checkpoints this, since the
/// failed step's own state is non-finite or outside the grid and can be neither
/// continued nor usefully inspected. Only what is not in the particles: those are
/// replayed ([`Run::replay`]), and the solver's state here checks the replay.
#[derive(Default)]
pub(super) struct Rescue {
    solver: SolverState,
    /// This rank's [`Solver::fingerprint`] at the kept step: the replay must reach it.
    fingerprint: u64,
    run: Option<RunState>,
    history_len: usize,
}

impl Rescue {
    /// Keep the state after the current step; no allocation once the buffers have grown.
    pub(super) fn keep<const D: usize>(
        &mut self,
        solver: &Solver<D>,
        st: &RunState,
        history_len: usize,
    ) {
        let (external_work, max_speed) = solver.local_state();
        self.solver = SolverState {
            t: solver.t,
            step: solver.step,
            dt: solver.dt,
            external_work,
            max_speed,
        };
        self.fingerprint = solver.fingerprint();
        match &mut self.run {
            Some(r) => r.clone_from(st),
            None => self.run = Some(st.clone()),
        }
        self.history_len = history_len;
    }

    /// Put the kept run state and `history.csv`'s text back (the solver has been
    /// replayed to the kept step).
    fn restore(&mut self, st: &mut RunState, history: &mut Vec<u8>) {
        if let Some(r) = &self.run {
            st.clone_from(r);
        }
        history.truncate(self.history_len);
        st.history = std::mem::take(history);
    }
}

impl<'a, const D: usize> Run<'a, D> {
    /// Collective, after an instability: the failing rank's own reason on rank 0 (not
    /// "failed elsewhere"), and a checkpoint of the last state known good, since the
    /// failed state can be neither continued nor usefully inspected (unless a regular
    /// checkpoint already holds it). Returns the message.
    pub(super) fn rescue(&mut self, failure: &Failure) -> Result<String, RunError> {
        let mine = match failure {
            Failure::Elsewhere(_) => String::new(),
            f => format!("rank {}: {f}", self.comm.rank()),
        };
        let all = self.comm.gather_bytes(mine.as_bytes());
        let reason = match all.iter().find(|m| !m.is_empty()) {
            Some(m) => String::from_utf8_lossy(m).into_owned(),
            None => failure.to_string(),
        };
        let good = self.rescue.solver;
        let mut how = String::new();
        if self.checkpoints.last_step != Some(good.step) {
            let t0 = Instant::now();
            let from = self.checkpoints.last_step.unwrap_or(0);
            let fingerprint = self.rescue.fingerprint;
            if let Err(why) = self.replay(&good, fingerprint) {
                return Ok(format!(
                    "{reason}; {why}, so no checkpoint of the last good state (step {}) was \
                     written; the newest checkpoint is {}",
                    good.step,
                    match self.checkpoints.last_name() {
                        n if n.is_empty() => "none (restart from the scene)".to_string(),
                        n => n,
                    }
                ));
            }
            let history = &mut self.history.text;
            self.rescue.restore(&mut self.st, history);
            self.st.snapshots = self.snapshot_entries();
            self.st.snapshots.retain(|e| e.step <= good.step);
            self.checkpoints.last = Some(self.write_checkpoint()?);
            how = format!(
                " (replayed from step {from} in {:.1} s)",
                t0.elapsed().as_secs_f64()
            );
        }
        Ok(format!(
            "{reason}; the last good state (step {}, t = {:.6e}) is checkpointed in {}{how}",
            good.step,
            good.t,
            self.checkpoints.last_name()
        ))
    }

    /// Collective: the solver set up again from the newest checkpoint (or the scene)
    /// and stepped, writing nothing, to the rescue's state `good`. A run is
    /// deterministic on a given rank and thread count once its block moves are made
    /// again as they were (under `balance = "time"` they follow the clock), and a
    /// restart continues it bit for bit, so this is the state the run had: kept this
    /// way rather than as a copy, which held as much memory as the particles
    /// themselves, and checked against `good` and this rank's particle `fingerprint`.
    /// `Err` says why the state was not reached (a stop signal, or a replay that did
    /// not reproduce the run, which would be a bug, or a set-up that failed).
    fn replay(&mut self, good: &SolverState, fingerprint: u64) -> Result<(), String> {
        let from = self.checkpoints.last.clone();
        let opts = RunOptions {
            // A checkpoint of this run holds this scene text: none of its output is
            // rescheduled, as a restart from it would keep the stored schedule.
            scene_text: match &from {
                Some(p) if Some(p) != self.opts.restart.as_ref() => Some(self.scene_text.clone()),
                _ => self.opts.scene_text.clone(),
            },
            restart: from,
            ..self.opts.clone()
        };
        if self.comm.rank() == 0 && !opts.quiet {
            eprintln!(
                "replaying from step {} to step {} to checkpoint the last good state",
                self.checkpoints.last_step.unwrap_or(0),
                good.step
            );
        }
        // The failed particles go before the replay's are seeded or read; the rest of
        // the failed solver goes when the replay's replaces it, before its first step
        // (measured: the replay's peak is then below the failed run's).
        self.solver.parts = Particles::default();
        // Every rank reaches the same error (a checkpoint removed since, say).
        let set = layout_for::<D>(self.scene, self.comm.size())
            .and_then(|layout| set_up::<D>(self.scene, self.comm, &layout, &opts));
        let (solver, restored, _, _) = match set {
            Ok(s) => s,
            Err(e) => return Err(format!("setting the run up again to replay it failed: {e}")),
        };
        self.solver = solver;
        let mut next_snapshot = match (&restored, &self.snaps) {
            (Some(st), _) => st.next_snapshot,
            (None, Some(sn)) => sn.every,
            (None, None) => f64::INFINITY,
        };
        while self.solver.step < good.step {
            // The loop of `steps`, for what changes the state: the steps cut at
            // snapshot times, and the rebalancing.
            self.solver.stop_at = next_snapshot;
            let mut req = Requests::new(signals::pending(), false, false);
            if let Err(f) = self.solver.advance_with(&mut req.0) {
                return Err(format!(
                    "replaying the run failed at step {} ({f})",
                    self.solver.step
                ));
            }
            // The run's own moves, not new decisions: under `time` those would follow
            // the replay's clock.
            let step = self.solver.step;
            if let Some((_, cuts)) = self.balance.moves.iter().find(|m| m.0 == step) {
                let next = self
                    .solver
                    .layout
                    .with_cuts(std::array::from_fn(|a| cuts[a].clone()))
                    .expect("the cuts of one of this run's layouts");
                self.solver.relayout(next);
            }
            if let Some(sn) = &self.snaps {
                if sn.due(&self.solver, next_snapshot) {
                    let s = &self.solver;
                    next_snapshot = sn.after(next_snapshot, s.t, s.dt);
                }
            }
            if req.signal() != 0 {
                return Err(format!(
                    "{} stopped the replay at step {}",
                    signals::name(req.signal()),
                    self.solver.step
                ));
            }
        }
        let s = &self.solver;
        let (external_work, max_speed) = s.local_state();
        let same = s.step == good.step
            && s.t.to_bits() == good.t.to_bits()
            && s.dt.to_bits() == good.dt.to_bits()
            && external_work.to_bits() == good.external_work.to_bits()
            && max_speed.to_bits() == good.max_speed.to_bits()
            && s.fingerprint() == fingerprint;
        let mut differs = [f64::from(u8::from(!same))];
        self.comm.max_f64(&mut differs);
        if differs[0] > 0.0 {
            return Err(format!(
                "replaying the run did not reproduce its state at step {}",
                good.step
            ));
        }
        Ok(())
    }
}
