//! The progress line of `mpmcg run`, printed on stderr by rank 0 only.
//!
//! On a terminal it is rewritten in place (`\r`); otherwise (a batch log, a pipe) it is
//! a plain line every 10 s (`--progress-every` changes either interval). Under `mpirun` a rank's
//! stderr is always a pipe to the launcher, even when the user watches a terminal, so a
//! rank started by an MPI launcher looks at the launcher's stderr instead (see
//! [`launcher_on_terminal`]).
//!
//! The ETA divides the simulated time left by the simulated time per wall second over
//! the last [`WINDOW`] seconds: a run's speed changes (the step shrinks as material
//! compresses, snapshots pause it), and the average since the start would lag behind.
//!
//! Not `indicatif`: it hides its bars when stderr is not a terminal, which under
//! `mpirun` is always, so the batch-log lines would still be ours; its ETA counts
//! integer positions, ours is simulated time.

use std::collections::VecDeque;
use std::io::{IsTerminal, Write};
use std::time::Instant;

/// Wall seconds over which the ETA measures the run's speed.
pub const WINDOW: f64 = 60.0;

/// Seconds between updates on a terminal and in a log, unless `--progress-every` says
/// otherwise.
const TERMINAL_EVERY: f64 = 0.5;
const LOG_EVERY: f64 = 10.0;

/// Simulated time per wall second over a recent window of (wall, simulated time)
/// samples.
#[derive(Debug, Default)]
pub struct Speed {
    samples: VecDeque<(f64, f64)>,
}

impl Speed {
    /// Add a sample (wall seconds since the run started, simulated time); samples that
    /// fell out of the window go, but the window keeps the newest sample at least
    /// [`WINDOW`] old, so that it always spans [`WINDOW`] once the run is that long.
    pub fn push(&mut self, wall: f64, t: f64) {
        self.samples.push_back((wall, t));
        while self.samples.len() > 2 && self.samples[1].0 <= wall - WINDOW {
            self.samples.pop_front();
        }
    }

    /// Simulated time per wall second across the window (`None` before two samples
    /// or while no wall time has passed).
    pub fn rate(&self) -> Option<f64> {
        let (&(w0, t0), &(w1, t1)) = (self.samples.front()?, self.samples.back()?);
        (w1 > w0).then(|| (t1 - t0) / (w1 - w0))
    }

    /// Wall seconds to reach `end` at the window's rate (`None` if it made no progress).
    pub fn eta(&self, end: f64) -> Option<f64> {
        let &(_, t) = self.samples.back()?;
        self.rate()
            .filter(|&r| r > 0.0)
            .map(|r| (end - t).max(0.0) / r)
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Off,
    InPlace,
    Lines,
}

pub struct Progress {
    mode: Mode,
    every: f64,
    start: Instant,
    last: Option<Instant>,
    speed: Speed,
}

impl Progress {
    /// `on`: rank 0 and not `--quiet`; `every`: seconds between updates.
    /// `t0`: the simulated time the run starts from (after a restart, the checkpoint's).
    pub fn new(on: bool, every: Option<f64>, start: Instant, t0: f64) -> Self {
        let mode = if !on {
            Mode::Off
        } else if std::io::stderr().is_terminal() || launcher_on_terminal() {
            Mode::InPlace
        } else {
            Mode::Lines
        };
        let every = every.unwrap_or(if mode == Mode::InPlace {
            TERMINAL_EVERY
        } else {
            LOG_EVERY
        });
        let mut speed = Speed::default();
        speed.push(0.0, t0);
        Self {
            mode,
            every,
            start,
            last: None,
            speed,
        }
    }

    /// Called after every step; prints when the interval has passed.
    pub fn tick(&mut self, step: u64, t: f64, end: f64, dt: f64) {
        if self.mode == Mode::Off {
            return;
        }
        let now = Instant::now();
        let since = now.duration_since(self.last.unwrap_or(self.start));
        if since.as_secs_f64() < self.every {
            return;
        }
        self.last = Some(now);
        let el = now.duration_since(self.start).as_secs_f64();
        self.speed.push(el, t);
        let rate = self
            .speed
            .rate()
            .map_or_else(|| "?".to_string(), |r| format!("{r:.3e}/s"));
        let eta = self.speed.eta(end).map_or_else(|| "?".to_string(), hms);
        let line = format!(
            "step {step:>8}  t = {t:.4e} / {end:.4e} ({:5.1}%)  dt = {dt:.3e}  elapsed {}  rate {rate}  ETA {eta}",
            100.0 * (t / end).clamp(0.0, 1.0),
            hms(el),
        );
        // In place: back to the line's start, then clear what a longer line left. One
        // write, so that the launcher's forwarding never splits it (see `say!`).
        let text = match self.mode {
            Mode::InPlace => format!("\r{line}\x1b[K"),
            _ => format!("{line}\n"),
        };
        let _ = std::io::stderr().lock().write_all(text.as_bytes());
    }

    /// End the line rewritten in place, so that what follows starts on its own line.
    pub fn finish(&mut self) {
        if self.mode == Mode::InPlace && self.last.is_some() {
            eprintln!();
        }
    }
}

/// Whether this process was started by an MPI launcher (OpenMPI's `mpirun`, MPICH's
/// Hydra, PMIx) whose own stderr is a terminal: the launcher forwards a rank's output
/// as it comes, `\r` included, so the line can be rewritten in place. Linux only
/// (`/proc`); elsewhere, or without permission, progress falls back to plain lines.
fn launcher_on_terminal() -> bool {
    let launched = ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"]
        .iter()
        .any(|v| std::env::var_os(v).is_some());
    if !launched {
        return false;
    }
    let parent = std::os::unix::process::parent_id();
    std::fs::read_link(format!("/proc/{parent}/fd/2")).is_ok_and(|p| {
        let p = p.to_string_lossy();
        p.starts_with("/dev/pts/") || p.starts_with("/dev/tty")
    })
}

/// `1h02m03s`, `2m03s`, `3s`.
pub fn hms(s: f64) -> String {
    let s = s.round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m{:02}s", s / 3600, s / 60 % 60, s % 60)
    } else if s >= 60 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{s}s")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eta_follows_the_recent_speed_not_the_average() {
        let mut s = Speed::default();
        s.push(0.0, 0.0);
        s.push(10.0, 1.0);
        assert_eq!(s.rate(), Some(0.1));
        // The run slows down: 0.5 in the next 60 s, then 2.5 in 30 s.
        s.push(70.0, 1.5);
        s.push(100.0, 4.0);
        // The window starts at the newest sample at least WINDOW (60 s) old, (10, 1).
        let r = s.rate().unwrap();
        assert!((r - 3.0 / 90.0).abs() < 1e-15, "{r}");
        let eta = s.eta(10.0).unwrap();
        assert!((eta - 6.0 / r).abs() < 1e-9, "{eta}");
        // The average since the start (0.04) would give 150 s.
        assert!((eta - 150.0).abs() > 10.0);
    }

    #[test]
    fn no_eta_without_progress_or_wall_time() {
        let mut s = Speed::default();
        s.push(0.0, 0.5);
        assert_eq!(s.rate(), None);
        assert_eq!(s.eta(1.0), None);
        s.push(5.0, 0.5);
        assert_eq!(s.rate(), Some(0.0));
        assert_eq!(s.eta(1.0), None);
    }

    #[test]
    fn hms_formats() {
        assert_eq!(hms(3.4), "3s");
        assert_eq!(hms(123.0), "2m03s");
        assert_eq!(hms(3723.0), "1h02m03s");
    }
}
