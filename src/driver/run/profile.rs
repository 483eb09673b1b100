//! Where a run's time went on each rank: the parts of the step, the driver's work
//! between steps, the set-up, and the time blocked in collectives and exchanges.
//! `summary.json`'s `profile`, and the table `mpmcg run --profile` prints.

use super::spread::Spread;
use super::Run;
use decomposition::CommStats;
use serde::Serialize;
use std::fmt::Write as _;

/// What the driver measures besides the solver's [`crate::mpm::solver::Clock`].
#[derive(Clone, Debug, Default)]
pub(super) struct Timing {
    /// Seeding and the first balance, or reading the checkpoint.
    pub setup_seconds: f64,
    /// The step loop's wall time.
    pub loop_seconds: f64,
    /// The balance checks and moves between steps.
    pub balance_seconds: f64,
    /// Snapshots and checkpoints written by the step loop.
    pub output_seconds: f64,
    /// Collectives and exchanges inside the solver's steps.
    pub step_comm: CommStats,
    /// Collectives and exchanges of the whole step loop.
    pub loop_comm: CommStats,
}

/// One part of the step: seconds per step, spread over ranks.
#[derive(Serialize, Debug, Clone)]
pub struct PartSeconds {
    pub part: String,
    pub min: f64,
    pub mean: f64,
    pub max: f64,
}

/// Time blocked in communication per step, spread over ranks.
#[derive(Serialize, Debug, Clone)]
pub struct Blocked {
    pub collectives: Spread,
    pub exchanges: Spread,
}

/// `summary.json`'s `profile`: over this run's steps (since its restart, if restarted).
#[derive(Serialize, Debug, Clone)]
pub struct ProfileSummary {
    pub steps: u64,
    /// Seeding and the first balance, or reading the checkpoint.
    pub setup_seconds: Spread,
    /// Per part: the solver's time step, its phases (a part sums its phase's repeats
    /// within a step), check, migration and sort, then the driver's `balance`,
    /// `output` and `other` (history, error norms, progress); the parts add up to the
    /// step loop's wall time on each rank.
    pub seconds_per_step: Vec<PartSeconds>,
    /// Collectives (reductions, scans) in one solver step, the same on every rank.
    pub step_collectives: f64,
    /// Exchanges with the peers in one solver step (grid halo and migration).
    pub step_exchanges: f64,
    /// Collectives per step between the solver's steps (balance checks, history rows).
    pub driver_collectives: f64,
    /// Seconds per step a rank waited in the solver's collectives and exchanges: the
    /// time it waited for slower ranks included.
    pub blocked_seconds_per_step: Blocked,
}

impl<const D: usize> Run<'_, D> {
    /// Collective: the profile of the steps of this run; three reductions.
    pub(super) fn profile(&self) -> ProfileSummary {
        let (comm, solver, t) = (self.comm, &self.solver, &self.timing);
        let steps = solver.step - self.step_start;
        let per_step = |x: f64| x / steps.max(1) as f64;
        let parts = solver.parts();
        let mut names: Vec<&str> = parts.iter().map(|a| a.name()).collect();
        let mut mine: Vec<f64> = parts.iter().map(|&a| solver.clock.seconds(a)).collect();
        let solver_total: f64 = mine.iter().sum();
        let other = t.loop_seconds - solver_total - t.balance_seconds - t.output_seconds;
        names.extend(["balance", "output", "other"]);
        mine.extend([t.balance_seconds, t.output_seconds, other.max(0.0)]);
        let k = mine.len();
        mine.extend([
            t.setup_seconds,
            t.step_comm.collective_seconds,
            t.step_comm.exchange_seconds,
        ]);
        let per = 1.0 / steps.max(1) as f64;
        let seconds = Spread::over_ranks(comm, &mine);
        let spread = |i: usize, scale: f64| Spread {
            min: seconds[i].min * scale,
            mean: seconds[i].mean * scale,
            max: seconds[i].max * scale,
        };
        ProfileSummary {
            steps,
            setup_seconds: spread(k, 1.0),
            seconds_per_step: names
                .iter()
                .enumerate()
                .map(|(i, name)| {
                    let s = spread(i, per);
                    PartSeconds {
                        part: name.to_string(),
                        min: s.min,
                        mean: s.mean,
                        max: s.max,
                    }
                })
                .collect(),
            step_collectives: per_step(t.step_comm.collectives as f64),
            step_exchanges: per_step(t.step_comm.exchanges as f64),
            driver_collectives: per_step(
                (t.loop_comm.collectives - t.step_comm.collectives) as f64,
            ),
            blocked_seconds_per_step: Blocked {
                collectives: spread(k + 1, per),
                exchanges: spread(k + 2, per),
            },
        }
    }
}

/// The profile as a table (`mpmcg run --profile`), milliseconds per step.
pub fn table(p: &ProfileSummary, ranks: usize) -> String {
    let ms = |x: f64| x * 1e3;
    let total: f64 = p.seconds_per_step.iter().map(|s| s.mean).sum();
    let mut t = String::new();
    let _ = writeln!(
        t,
        "profile: milliseconds per step over {} steps, min / mean / max over {ranks} rank{}",
        p.steps,
        if ranks == 1 { "" } else { "s" }
    );
    let _ = writeln!(
        t,
        "  {:<20} {:>10} {:>10} {:>10} {:>7}",
        "part", "min", "mean", "max", "share"
    );
    for s in &p.seconds_per_step {
        let _ = writeln!(
            t,
            "  {:<20} {:>10.4} {:>10.4} {:>10.4} {:>6.1}%",
            s.part,
            ms(s.min),
            ms(s.mean),
            ms(s.max),
            100.0 * s.mean / total.max(1e-300)
        );
    }
    let _ = writeln!(t, "  {:<20} {:>21.4}", "step", ms(total));
    let b = &p.blocked_seconds_per_step;
    for (what, s) in [("collectives", &b.collectives), ("exchanges", &b.exchanges)] {
        let _ = writeln!(
            t,
            "  blocked in {:<9} {:>10.4} {:>10.4} {:>10.4} {:>6.1}%",
            what,
            ms(s.min),
            ms(s.mean),
            ms(s.max),
            100.0 * s.mean / total.max(1e-300)
        );
    }
    let _ = writeln!(
        t,
        "  per step: {:.2} collectives and {:.2} exchanges in the solver, {:.2} collectives between steps",
        p.step_collectives, p.step_exchanges, p.driver_collectives
    );
    let s = &p.setup_seconds;
    let _ = write!(t, "  set-up: {:.3} / {:.3} / {:.3} s", s.min, s.mean, s.max);
    t
}
