//! The driver: the command line, the run loop with its schedules (output,
//! checkpoints, rebalancing, signals, progress) and the speed-against-error sweep.

/// `eprintln!` in one write. `eprintln!` writes each formatted piece apart, and under
/// mpirun a rank's stderr is a pipe the launcher forwards: when another rank ends
/// first, the launcher's own notice can land between the pieces (seen in CI:
/// `error: s0.toml`, mpirun's notice, then `:47:9: key ...`). One write of fewer than
/// PIPE_BUF (4096) bytes reaches the pipe whole.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let mut line = format!($($arg)*);
        line.push('\n');
        let _ = std::io::stderr().lock().write_all(line.as_bytes());
    }};
}

pub mod affinity;
#[allow(unsafe_code)] // `_exit` after a failed write of the help text.
pub mod cli;
#[allow(unsafe_code)] // `xgetbv`: the OS's saved vector registers.
pub mod cpu;
pub mod memory;
#[allow(unsafe_code)] // The global allocator, and `write` and `_exit` where it is refused.
pub mod out_of_memory;
pub mod progress;
pub mod run;
#[allow(unsafe_code)] // Signal handlers.
pub mod signals;
pub mod sweep;
