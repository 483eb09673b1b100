//! When a run writes and checks things: the schedules of snapshots, checkpoints,
//! history samples and load balancing.

use super::history::DIAG_MIN_STEPS;
use super::RunError;
use crate::input::plan::CheckpointEvery;
use crate::input::scene::{Balance, Scene};
use crate::mpm::solver::{Load, Solver};
use crate::output::checkpoint::RunState;
use crate::output::io::{Labels, Snapshots};
use decomposition::Communicator;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Every `check_every` steps: the imbalance is measured (one reduction), and under
/// `auto` or `time` the blocks move if it passes the threshold. The samples (after any
/// move) are the summary's record of how balanced the run was: of the particles, or
/// under `time` of the ranks' measured work.
pub(super) struct BalanceSchedule {
    every: u64,
    auto: Option<f64>,
    /// Under `time`: this rank's seconds of work since the last check.
    busy: Option<f64>,
    /// The moves since the newest checkpoint: the step and the new cuts per axis, which
    /// a replay ([`super::Run::rescue`]) makes again instead of deciding anew (under
    /// `time` the decisions follow the clock, which a replay does not reproduce).
    pub(super) moves: Vec<(u64, Vec<Vec<usize>>)>,
    pub(super) checks: u64,
    pub(super) sum: f64,
    pub(super) max: f64,
    pub(super) within: u64,
}

/// The imbalance the summary counts as balanced: the 10 %.
const BALANCED: f64 = 1.10;

impl BalanceSchedule {
    pub(super) fn of(scene: &Scene) -> Self {
        let p = &scene.parallel;
        Self {
            every: p.check_every,
            auto: matches!(p.balance, Balance::Auto | Balance::Time).then_some(p.imbalance),
            busy: (p.balance == Balance::Time).then_some(0.0),
            moves: Vec::new(),
            checks: 0,
            sum: 0.0,
            max: 0.0,
            within: 0,
        }
    }

    /// Under `time`: a step's seconds of work on this rank (its wall time less the
    /// time blocked in collectives and exchanges).
    pub(super) fn worked(&mut self, seconds: f64) {
        if let Some(b) = &mut self.busy {
            *b += seconds.max(0.0);
        }
    }

    /// Collective at a check step: measure, rebalance under `auto` or `time`. Returns
    /// whether the blocks moved.
    pub(super) fn check<const D: usize>(&mut self, solver: &mut Solver<D>) -> bool {
        if !solver.step.is_multiple_of(self.every) {
            return false;
        }
        let load = match &mut self.busy {
            Some(b) => Load::Seconds(std::mem::take(b)),
            None => Load::Particles,
        };
        let moved = match self.auto {
            Some(threshold) => solver.rebalance(threshold, load),
            None => {
                solver.last_imbalance = solver.imbalance();
                false
            }
        };
        if moved {
            let cuts = (0..D).map(|a| solver.layout.cuts(a).to_vec()).collect();
            self.moves.push((solver.step, cuts));
        }
        let i = solver.last_imbalance;
        self.checks += 1;
        self.sum += i;
        self.max = self.max.max(i);
        self.within += u64::from(i <= BALANCED);
        moved
    }
}

/// Snapshots at multiples of `every` in simulated time, which the steps land on; an
/// infinite `every` writes the initial and final states only.
pub(super) struct SnapshotSchedule {
    pub(super) writer: Snapshots,
    pub(super) every: f64,
}

impl SnapshotSchedule {
    /// The scene's snapshots, `None` if it asks for none.
    pub(super) fn of<const D: usize>(scene: &Scene, out: &Path) -> Option<Self> {
        scene.snapshot_plan().map(|o| Self {
            writer: Snapshots::new(out, &o.fields, Labels::of::<D>(scene)),
            every: o.every,
        })
    }

    /// Whether the step just taken reached the output time `next` (it landed on it, to
    /// round-off) or ended the run.
    pub(super) fn due<const D: usize>(&self, solver: &Solver<D>, next: f64) -> bool {
        solver.t >= next - 1e-3 * solver.dt || solver.done()
    }

    /// The first output time after time `t` (step `dt`), from the current one `next`:
    /// k·every by one multiplication, since a sum of intervals would drift.
    pub(super) fn after(&self, mut next: f64, t: f64, dt: f64) -> f64 {
        while next <= t + 1e-3 * dt {
            let k = ((next / self.every).round() + 1.0) * self.every;
            next = past(next, k, t, self.every);
        }
        next
    }

    /// Collective: write the particles now, adding the time taken to `seconds`.
    pub(super) fn write<const D: usize>(
        &mut self,
        comm: &dyn Communicator,
        solver: &mut Solver<D>,
        seconds: &mut f64,
    ) -> Result<(), RunError> {
        let t0 = Instant::now();
        solver.null_kinetic();
        let null = solver
            .null_space
            .as_ref()
            .map_or(&[][..], |n| &n.velocity[..]);
        self.writer
            .write(
                comm,
                &solver.parts,
                (&solver.kinds, &solver.materials),
                null,
                (solver.step, solver.t),
            )
            .map_err(|e| RunError::Io(e.to_string()))?;
        *seconds += t0.elapsed().as_secs_f64();
        Ok(())
    }
}

/// When to write checkpoints (the scene's `[checkpoint]` interval in simulated time,
/// steps or wall-clock seconds, or a stop signal) and which one is the newest.
pub(super) struct CheckpointSchedule {
    every: Option<CheckpointEvery>,
    /// Wall clock since the last checkpoint, for `every_seconds`.
    pub(super) clock: Instant,
    /// The newest checkpoint: written by this run, or the one it restarted from.
    pub(super) last: Option<PathBuf>,
    /// The step of `last`.
    pub(super) last_step: Option<u64>,
}

impl CheckpointSchedule {
    pub(super) fn new(scene: &Scene, restart: Option<&PathBuf>, step: u64) -> Self {
        Self {
            every: scene.plan.checkpoint,
            clock: Instant::now(),
            last: restart.cloned(),
            last_step: restart.map(|_| step),
        }
    }

    /// The first checkpoint time of a fresh run (infinite unless the interval is in
    /// simulated time).
    pub(super) fn first_time(&self) -> f64 {
        match self.every {
            Some(CheckpointEvery::Time(t)) => t,
            _ => f64::INFINITY,
        }
    }

    /// On rank 0: whether the wall-clock interval has passed. The ranks agree on it
    /// through [`Requests`].
    pub(super) fn wall_due(&self) -> bool {
        matches!(self.every, Some(CheckpointEvery::Seconds(s))
            if self.clock.elapsed().as_secs_f64() >= s)
    }

    /// Whether to checkpoint after the step just taken: a stop signal asks for one, or
    /// the interval is reached (simulated time `next`, a multiple of the steps, or the
    /// agreed wall clock).
    pub(super) fn due<const D: usize>(
        &self,
        solver: &Solver<D>,
        next: f64,
        req: &Requests,
    ) -> bool {
        req.signal() != 0
            || match self.every {
                Some(CheckpointEvery::Time(_)) => solver.t >= next - 1e-3 * solver.dt,
                Some(CheckpointEvery::Steps(n)) => solver.step.is_multiple_of(n),
                Some(CheckpointEvery::Seconds(_)) => req.wall_checkpoint(),
                None => false,
            }
    }

    /// The first checkpoint time after time `t` (step `dt`), from the current one
    /// `next`; unchanged unless the interval is in simulated time.
    pub(super) fn after(&self, mut next: f64, t: f64, dt: f64) -> f64 {
        if let Some(CheckpointEvery::Time(every)) = self.every {
            while next <= t + 1e-3 * dt {
                next = past(next, next + every, t, every);
            }
        }
        next
    }

    /// A regular checkpoint of step `step` was written to `path`.
    pub(super) fn written(&mut self, path: PathBuf, step: u64) {
        self.last = Some(path);
        self.last_step = Some(step);
        self.clock = Instant::now();
    }

    /// The newest checkpoint's path, or `""`.
    pub(super) fn last_name(&self) -> String {
        self.last
            .as_ref()
            .map_or_else(String::new, |p| p.display().to_string())
    }
}

/// Requests every rank must agree on after a step. They travel with the step's own
/// reduction (a maximum): a stop signal (any rank), a wall-clock checkpoint (rank 0's
/// clock), a failed history write (rank 0).
pub(super) struct Requests(pub(super) [f64; 3]);

impl Requests {
    pub(super) fn new(signal: i32, wall_checkpoint: bool, history_failed: bool) -> Self {
        Self([
            f64::from(signal),
            f64::from(u8::from(wall_checkpoint)),
            f64::from(u8::from(history_failed)),
        ])
    }

    /// The stop signal some rank received (0: none).
    pub(super) fn signal(&self) -> i32 {
        self.0[0] as i32
    }

    fn wall_checkpoint(&self) -> bool {
        self.0[1] > 0.0
    }

    pub(super) fn history_failed(&self) -> bool {
        self.0[2] > 0.0
    }
}

/// History samples every thousandth of the run, but no closer than [`DIAG_MIN_STEPS`]
/// steps (each costs a pass over the particles), and one at the end.
pub(super) struct HistorySchedule {
    pub(super) every: f64,
}

impl HistorySchedule {
    pub(super) fn of(scene: &Scene) -> Self {
        Self {
            every: scene.time.end / 1000.0,
        }
    }

    pub(super) fn due<const D: usize>(&self, solver: &Solver<D>, st: &RunState) -> bool {
        (solver.t >= st.next_history && solver.step >= st.last_history_step + DIAG_MIN_STEPS)
            || solver.done()
    }
}

/// The next output time `next` after `last` on a grid of `every`, or, where `every`
/// is too small against the time to advance it in floating point (scene validation
/// bounds the number of outputs, so only a hand-made checkpoint gets here), the first
/// representable time after `t`: the schedule loops always end.
fn past(last: f64, next: f64, t: f64, every: f64) -> f64 {
    if next > last {
        next
    } else {
        (t + every).max(t.next_up())
    }
}
