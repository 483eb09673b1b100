//! The driver: the command line, the run loop with its schedules (output,
//! checkpoints, rebalancing, signals, progress) and the speed-against-error sweep.

pub mod cli;
pub mod cpu;
pub mod progress;
pub mod run;
pub mod signals;
pub mod sweep;
