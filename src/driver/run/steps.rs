//! The step loop of a run under way: start, steps with their outputs and signals,
//! checkpoints, and the end of the run.

use super::history::History;
use super::rescue::{Rescue, RESCUE_EVERY};
use super::schedules::{
    BalanceSchedule, CheckpointSchedule, HistorySchedule, Requests, SnapshotSchedule,
};
use super::setup::{initial, lineage, resumed, SetUp};
use super::summary::{write_summary, OutputSeconds, Summary};
use super::{Ending, Run, RunError, RunOptions};
use crate::driver::progress::Progress;
use crate::driver::signals;
use crate::input::scene::Scene;
use crate::output::checkpoint;
use decomposition::{Communicator, Timed};
use std::path::PathBuf;
use std::time::Instant;

impl<'a, const D: usize> Run<'a, D> {
    /// Collective: the lineage, `history.csv` and the run state, restored or (fresh run)
    /// of the initial state, whose snapshot and history row are written.
    pub(super) fn start(
        scene: &'a Scene,
        timed: &'a Timed<'a>,
        opts: &'a RunOptions,
        scene_text: String,
        (mut solver, restored, restarted_from, stored): SetUp<'a, D>,
    ) -> Result<Self, RunError> {
        let comm: &dyn Communicator = timed;
        let keep = scene.checkpoint.as_ref().map_or(2, |c| c.keep);
        let lineage = lineage(comm, &opts.out, stored, keep);
        let mut history = History::open(comm, &opts.out, &solver, restored.as_ref())?;
        let sampling = HistorySchedule::of(scene);
        let checkpoints = CheckpointSchedule::new(scene, opts.restart.as_ref(), solver.step);
        let mut snaps = SnapshotSchedule::of::<D>(scene, &opts.out);
        let start = Instant::now();
        let mut output_seconds = OutputSeconds::default();
        let st = match restored {
            Some(st) => resumed(comm, &opts.out, st, snaps.as_mut()),
            None => {
                if let Some(sn) = &mut snaps {
                    sn.write(comm, &mut solver, &mut output_seconds.snapshots)?;
                }
                let next_snapshot = snaps.as_ref().map_or(f64::INFINITY, |sn| sn.every);
                let st = initial(
                    &solver,
                    next_snapshot,
                    sampling.every,
                    checkpoints.first_time(),
                );
                let null = solver.null_kinetic();
                history.row(&solver, &st.initial, st.last_err, null);
                st
            }
        };
        let root = comm.rank() == 0;
        let progress = Progress::new(root && !opts.quiet, opts.progress_every, start, solver.t);
        let mut rescue = Rescue::default();
        rescue.keep(&solver, &st, history.text.len());
        Ok(Self {
            scene,
            comm,
            timed,
            opts,
            out: &opts.out,
            scene_text,
            e0: st.initial.total_energy(),
            step_start: solver.step,
            solver,
            st,
            history,
            sampling,
            balance: BalanceSchedule::of(scene),
            snaps,
            checkpoints,
            lineage,
            rescue,
            progress,
            start,
            output_seconds,
            timing: Default::default(),
            threads: opts.threads,
            restarted_from,
        })
    }

    /// The step loop: until the end time, an instability or a stop signal, with the
    /// diagnostics and output each step calls for.
    pub(super) fn steps(&mut self) -> Result<Ending, RunError> {
        let root = self.comm.rank() == 0;
        // The wall-clock interval counts from the first step, not from the set-up.
        self.checkpoints.clock = Instant::now();
        let (start, comm0) = (Instant::now(), self.timed.stats());
        let output0 = self.output_seconds.snapshots + self.output_seconds.checkpoints;
        let ending = self.step_loop(root);
        let t = &mut self.timing;
        t.loop_seconds = start.elapsed().as_secs_f64();
        t.loop_comm = self.timed.stats().since(&comm0);
        t.output_seconds =
            self.output_seconds.snapshots + self.output_seconds.checkpoints - output0;
        ending
    }

    /// The steps of [`Run::steps`].
    fn step_loop(&mut self, root: bool) -> Result<Ending, RunError> {
        while !self.solver.done() {
            let wall_due = root && self.checkpoints.wall_due();
            // Snapshots at exact output times: the step that would pass one is shortened.
            self.solver.stop_at = self.st.next_snapshot;
            let mut req = Requests::new(signals::pending(), wall_due, self.history.error.is_some());
            let (comm0, t0) = (self.timed.stats(), Instant::now());
            let advanced = self.solver.advance_with(&mut req.0);
            let c = self.timed.stats().since(&comm0);
            self.timing.step_comm = self.timing.step_comm.plus(&c);
            let blocked = c.collective_seconds + c.exchange_seconds;
            self.balance.worked(t0.elapsed().as_secs_f64() - blocked);
            if let Err(f) = advanced {
                return Ok(Ending::Unstable(f));
            }
            // Before anything is written, so that a checkpoint holds the layout the
            // run continues with.
            let t0 = Instant::now();
            self.balance.check(&mut self.solver);
            self.timing.balance_seconds += t0.elapsed().as_secs_f64();
            if req.history_failed() {
                return Err(RunError::Io(self.history.error.take().unwrap_or_else(
                    || format!("{}: writing failed on rank 0", self.history.path.display()),
                )));
            }
            self.track_errors();
            if self.sampling.due(&self.solver, &self.st) {
                self.sample_history();
            }
            if let Some(sn) = &mut self.snaps {
                if sn.due(&self.solver, self.st.next_snapshot) {
                    sn.write(
                        self.comm,
                        &mut self.solver,
                        &mut self.output_seconds.snapshots,
                    )?;
                    let s = &self.solver;
                    self.st.next_snapshot = sn.after(self.st.next_snapshot, s.t, s.dt);
                }
            }
            let due = self
                .checkpoints
                .due(&self.solver, self.st.next_checkpoint, &req);
            // A finished run needs no checkpoint.
            let checkpointed = due && !self.solver.done();
            if checkpointed {
                self.checkpoint()?;
            }
            // A checkpoint is a state to replay from, so the rescue is never older.
            if checkpointed || self.solver.step.is_multiple_of(RESCUE_EVERY) {
                self.rescue
                    .keep(&self.solver, &self.st, self.history.text.len());
            }
            let s = &self.solver;
            self.progress.tick(s.step, s.t, s.end, s.dt);
            if req.signal() != 0 && !self.solver.done() {
                return Ok(Ending::Stopped(req.signal()));
            }
        }
        Ok(Ending::Completed)
    }

    /// Benchmarks: the error norms after this step, and their maxima so far.
    fn track_errors(&mut self) {
        if self.solver.benchmark.is_none() {
            return;
        }
        self.st.last_err = self.solver.errors_keeping_forces();
        if let Some((u, v)) = self.st.last_err {
            self.st.max_err.0 = self.st.max_err.0.max(u);
            self.st.max_err.1 = self.st.max_err.1.max(v);
        }
    }

    /// Collective: the totals now, into the energy bounds and a row of `history.csv`.
    fn sample_history(&mut self) {
        let null = self.solver.null_kinetic();
        let (s, st) = (&self.solver, &mut self.st);
        st.next_history = s.t + self.sampling.every;
        st.last_history_step = s.step;
        st.last = s.totals();
        st.energy_scale = st.energy_scale.max(st.last.kinetic + st.last.strain);
        st.max_energy_dev = st
            .max_energy_dev
            .max((st.last.total_energy() - self.e0).abs());
        self.history.row(s, &st.last, st.last_err, null);
    }

    /// Collective: a regular checkpoint of the state after this step.
    fn checkpoint(&mut self) -> Result<(), RunError> {
        let s = &self.solver;
        self.st.next_checkpoint = self.checkpoints.after(self.st.next_checkpoint, s.t, s.dt);
        self.history.flush();
        self.st.history = std::mem::take(&mut self.history.text);
        self.st.snapshots = self.snapshot_entries();
        let path = self.write_checkpoint()?;
        self.checkpoints.written(path, self.solver.step);
        // A replay starts from this checkpoint, which holds the cuts of the moves so far.
        self.balance.moves.clear();
        Ok(())
    }

    /// The snapshots written so far.
    pub(super) fn snapshot_entries(&self) -> Vec<crate::output::io::Entry> {
        self.snaps
            .as_ref()
            .map_or_else(Vec::new, |sn| sn.writer.entries().to_vec())
    }

    /// Collective: write the solver and `self.st` to a checkpoint; `self.st.history`
    /// holds `history.csv`'s text for the time of the write and gives it back.
    pub(super) fn write_checkpoint(&mut self) -> Result<PathBuf, RunError> {
        let t0 = Instant::now();
        let written = checkpoint::write(
            self.comm,
            self.out,
            &self.solver,
            &self.st,
            checkpoint::Stored {
                text: &self.scene_text,
                defaults: self.scene.defaults,
            },
            &mut self.lineage,
        );
        self.output_seconds.checkpoints += t0.elapsed().as_secs_f64();
        self.history.text = std::mem::take(&mut self.st.history);
        written.map_err(|e| RunError::Io(e.to_string()))
    }

    /// After a stop signal: where to continue from.
    fn stop_message(&self, signal: i32) -> String {
        let last = self.checkpoints.last_name();
        let restart = match self.checkpoints.last {
            Some(_) => last.clone(),
            None => "CHECKPOINT".to_string(),
        };
        format!(
            "stopped by {} after step {} (t = {:.6e}); the last checkpoint is {last}: continue with `mpmcg run --restart {restart}`",
            signals::name(signal),
            self.solver.step,
            self.solver.t,
        )
    }

    /// Collective: the rescue checkpoint of an unstable run, the summary (written by
    /// rank 0) and the outcome.
    pub(super) fn finish(mut self, ending: Ending) -> Result<Summary, RunError> {
        // The final totals: the last sample's, unless the loop broke off.
        let last = match ending {
            Ending::Completed => self.st.last.clone(),
            _ => self.solver.totals(),
        };
        // Of the run as it ended: the rescue replaces the solver.
        let end = (self.solver.step, self.solver.t);
        let wall = self.start.elapsed().as_secs_f64();
        let mut summary = self.summary(&last, end, wall);
        let (status, message) = match &ending {
            Ending::Completed => ("completed", None),
            Ending::Unstable(f) => ("unstable", Some(self.rescue(f)?)),
            Ending::Stopped(signal) => ("interrupted", Some(self.stop_message(*signal))),
        };
        self.progress.finish();
        summary.status = status.into();
        summary.message.clone_from(&message);
        summary.last_checkpoint = self
            .checkpoints
            .last
            .as_ref()
            .map(|p| p.display().to_string());
        summary.output_seconds = self.output_seconds.clone();
        let failed = self.history.error.take();
        write_summary(self.comm, self.out, &summary, failed)?;
        match ending {
            Ending::Completed => Ok(summary),
            Ending::Unstable(_) => Err(RunError::Unstable(message.unwrap_or_default())),
            Ending::Stopped(_) => Err(RunError::Interrupted(message.unwrap_or_default())),
        }
    }
}
