//! Input: scene files, parsed and validated before anything runs.

pub mod plan;
pub mod scene;
