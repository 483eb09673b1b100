//! Input: scene files, parsed and validated before anything runs.

pub mod scene;
