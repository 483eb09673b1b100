//! Where a step's time goes on this rank: each phase, the time step's choice, the
//! check that every rank's particles stayed physical, migration and the sort.

use super::Phase;
use std::time::Instant;

/// A part of the step that [`Clock`] times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    Scatter,
    AveragedForce,
    GridUpdate,
    AveragedGradient,
    XpicField,
    Gather,
    Remap,
    Stress,
    /// The stable time step: the signal speeds' maximum over ranks.
    TimeStep,
    /// Every rank's verdict on its particles' state, agreed over ranks.
    Check,
    /// Particles moved to the ranks that own their cells ([`super::Solver::route`], [`super::Solver::hand_over`]).
    Migrate,
    /// The sort by cell, when the particles fell out of order.
    Sort,
    CentroidOffsets,
    CentroidForce,
    CentroidVelocity,
}

impl Part {
    /// Every part: the time step, the phases (each part sums its phase's repeats in a
    /// step, such as MUSL's two grid updates), then the step's end.
    pub const ALL: [Part; 15] = [
        Part::TimeStep,
        Part::Scatter,
        Part::AveragedForce,
        Part::GridUpdate,
        Part::AveragedGradient,
        Part::XpicField,
        Part::Gather,
        Part::Remap,
        Part::Stress,
        Part::CentroidOffsets,
        Part::CentroidForce,
        Part::CentroidVelocity,
        Part::Check,
        Part::Migrate,
        Part::Sort,
    ];

    /// Its name in `summary.json`'s `profile`.
    pub fn name(self) -> &'static str {
        match self {
            Part::Scatter => "scatter",
            Part::AveragedForce => "averaged_force",
            Part::GridUpdate => "grid_update",
            Part::AveragedGradient => "averaged_gradient",
            Part::XpicField => "xpic_field",
            Part::Gather => "gather",
            Part::Remap => "remap",
            Part::Stress => "stress",
            Part::TimeStep => "time_step",
            Part::Check => "check",
            Part::Migrate => "migrate",
            Part::Sort => "sort",
            Part::CentroidOffsets => "centroid_offsets",
            Part::CentroidForce => "centroid_force",
            Part::CentroidVelocity => "centroid_velocity",
        }
    }

    /// The part a phase of the step belongs to.
    pub fn of(phase: Phase) -> Part {
        match phase {
            Phase::Scatter { .. } => Part::Scatter,
            Phase::AveragedForce => Part::AveragedForce,
            Phase::GridUpdate { .. } => Part::GridUpdate,
            Phase::AveragedGradient { .. } => Part::AveragedGradient,
            Phase::Gather { .. } => Part::Gather,
            Phase::Stress { .. } => Part::Stress,
            Phase::Remap => Part::Remap,
            Phase::XpicField => Part::XpicField,
            Phase::CentroidOffsets => Part::CentroidOffsets,
            Phase::CentroidForce => Part::CentroidForce,
            Phase::CentroidVelocity { .. } => Part::CentroidVelocity,
        }
    }
}

impl<const D: usize> super::Solver<'_, D> {
    /// The parts of this run's step: those of its phases, and the time step, the
    /// check, migration and the sort.
    pub fn parts(&self) -> Vec<Part> {
        let phase_part =
            |a: &Part| !matches!(a, Part::TimeStep | Part::Check | Part::Migrate | Part::Sort);
        Part::ALL
            .into_iter()
            .filter(|a| !phase_part(a) || self.phases.iter().any(|&p| Part::of(p) == *a))
            .collect()
    }
}

/// Seconds per [`Part`] on this rank since the run (or its restart) began: two clock
/// reads per part and step, against the milliseconds of a step.
#[derive(Clone, Debug, Default)]
pub struct Clock {
    seconds: [f64; Part::ALL.len()],
}

impl Clock {
    /// Add the time since `t0` to `part`.
    #[inline]
    pub fn add(&mut self, part: Part, t0: Instant) {
        self.seconds[part as usize] += t0.elapsed().as_secs_f64();
    }

    /// The seconds of `part` so far.
    pub fn seconds(&self, part: Part) -> f64 {
        self.seconds[part as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_phase_has_its_own_part_and_every_part_a_name() {
        let phases = [
            Phase::Scatter {
                forces: true,
                moved: true,
            },
            Phase::AveragedForce,
            Phase::GridUpdate { forces: true },
            Phase::AveragedGradient { slot: 0 },
            Phase::XpicField,
            Phase::Gather {
                stress: true,
                move_now: true,
                speed: true,
            },
            Phase::Remap,
            Phase::Stress {
                slot: 0,
                speed: true,
                moves: true,
            },
            Phase::CentroidOffsets,
            Phase::CentroidForce,
            Phase::CentroidVelocity { slot: 0 },
        ];
        let parts: Vec<Part> = phases.iter().map(|&p| Part::of(p)).collect();
        for (i, a) in parts.iter().enumerate() {
            assert!(!parts[..i].contains(a), "{a:?} twice");
        }
        for (i, a) in Part::ALL.iter().enumerate() {
            assert!(
                !Part::ALL[..i].iter().any(|b| b.name() == a.name()),
                "{}",
                a.name()
            );
        }
        // `ALL` holds each part once, so `seconds` has a slot per part.
        let mut seen = [false; Part::ALL.len()];
        for a in Part::ALL {
            assert!(!seen[a as usize]);
            seen[a as usize] = true;
        }
        let mut c = Clock::default();
        c.add(Part::Sort, Instant::now());
        assert!(c.seconds(Part::Sort) >= 0.0 && c.seconds(Part::Scatter) == 0.0);
    }
}
