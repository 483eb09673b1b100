//! The phases of one step, as data: each update order's list, and the list a run resolves for its scheme and transfer.

use super::*;

/// One phase of a time step. A step is one of the lists in [`Update::phases`], without
/// the MPMCG node-to-node steps (`AveragedForce`, `AveragedGradient`) for one-step
/// schemes (MPM, GIMP): [`Solver::two_step`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Phase {
    /// Particle → grid: mass, momentum, the domain fill and, if `forces`, the forces
    /// and the averaged stress sums; `moved`: the particles moved since the last scatter
    /// (rebuild the slab order). Ends with the ghost sum and the domain weights.
    Scatter { forces: bool, moved: bool },
    /// MPMCG node → node step of the internal force, `f_i −= Σ_j σ̄_j ∫ w S_j ∇S_i`.
    AveragedForce,
    /// Grid velocities from momentum (slot 0) and, if `forces`, after the force update
    /// (slot 1); walls; copy to the ghosts.
    GridUpdate { forces: bool },
    /// MPMCG node → node step of the velocity gradient, `L̄_j`, from velocity `slot`.
    AveragedGradient { slot: usize },
    /// Grid → particle: velocity (FLIP/PIC), position if `move_now` (else the `Stress`
    /// pass moves), and if `stress` the deformation and stress; `speed`: the step's
    /// last particle pass.
    Gather {
        stress: bool,
        move_now: bool,
        speed: bool,
    },
    /// Deformation and stress from velocity `slot` at the current positions.
    /// `moves` (MUSL): then move each particle with the velocity that deformed it, the
    /// remapped one: a two-step scheme's with its reconstruction
    /// ([`kernel::moving_velocity`]), a one-step scheme's with its grid interpolation.
    Stress {
        slot: usize,
        speed: bool,
        moves: bool,
    },
    /// MUSL: the particles' new velocities from the grid and the grid momentum of them,
    /// at the positions of the step's scatter, in one pass (`mpm::remap`); mass, cover
    /// and domain weights stay the scatter's. The same numbers as a `Gather` (no
    /// stress, no move) followed by a `Scatter` without forces.
    Remap,
    /// XPIC(m) only, just before the `Gather`: the grid field of its velocity update
    /// from the velocity before the force update, by m − 1 grid → particle → grid
    /// passes ([`Solver::xpic_field`]).
    XpicField,
    /// The centroid correction only, right after the step's first scatter, which
    /// summed the first moments: the offsets `d_i` of the nodes' mass centroids
    /// ([`Solver::centroid_offsets`]).
    CentroidOffsets,
    /// The centroid correction only, after the `AveragedForce`: the grid force becomes
    /// the adjoint of the correction applied to it ([`Solver::centroid_force`]).
    CentroidForce,
    /// The centroid correction only, before the `AveragedGradient` of velocity `slot`:
    /// that velocity moved from the mass centroids to the nodes
    /// ([`Solver::centroid_velocity`]).
    CentroidVelocity { slot: usize },
}

impl Update {
    /// The phases of one step of this update order for a two-step scheme.
    pub fn phases(self) -> &'static [Phase] {
        use Phase::*;
        match self {
            // Update stress last: forces from the old stress, then the new velocity
            // deforms the particles in the same pass that moves them.
            Update::Usl => &[
                Scatter {
                    forces: true,
                    moved: true,
                },
                AveragedForce,
                GridUpdate { forces: true },
                AveragedGradient { slot: UPDATED },
                Gather {
                    stress: true,
                    move_now: true,
                    speed: true,
                },
            ],
            // Update stress first, from the grid velocity of the old momentum.
            Update::Usf => &[
                Scatter {
                    forces: false,
                    moved: true,
                },
                GridUpdate { forces: false },
                AveragedGradient {
                    slot: FROM_MOMENTUM,
                },
                Stress {
                    slot: FROM_MOMENTUM,
                    speed: false,
                    moves: false,
                },
                Scatter {
                    forces: true,
                    moved: false,
                },
                AveragedForce,
                GridUpdate { forces: true },
                // The reconstruction the particles move with (two-step schemes).
                AveragedGradient { slot: UPDATED },
                Gather {
                    stress: false,
                    move_now: true,
                    speed: true,
                },
            ],
            // Modified USL: the new particle momentum is remapped to the grid, still at
            // the old positions, and that velocity deforms the particles; then they move.
            Update::Musl => &[
                Scatter {
                    forces: true,
                    moved: true,
                },
                AveragedForce,
                GridUpdate { forces: true },
                Remap,
                GridUpdate { forces: false },
                AveragedGradient {
                    slot: FROM_MOMENTUM,
                },
                Stress {
                    slot: FROM_MOMENTUM,
                    speed: true,
                    moves: true,
                },
            ],
        }
    }
}

impl<'c, const D: usize> Solver<'c, D> {
    /// The step's phases for this scheme ([`resolve`]).
    pub(super) fn resolve_phases(&mut self) {
        let centroid = self.centroid_passes > 0;
        debug_assert!(
            !centroid
                || (self.scheme.two_step() && self.update == Update::Musl && self.xpic.is_none())
        );
        self.phases = resolve(
            self.update,
            self.scheme.two_step(),
            self.xpic.is_some(),
            centroid,
        );
    }
}

/// The phases of a step of update order `update` for a two-step scheme (`two`) or a
/// one-step one, which skips the grid averages; with XPIC (`xpic`) and the centroid
/// correction (`centroid`, MUSL only, checked with the scene).
fn resolve(update: Update, two: bool, xpic: bool, centroid: bool) -> Vec<Phase> {
    let mut phases: Vec<Phase> = update
        .phases()
        .iter()
        .copied()
        .filter(|p| two || !matches!(p, Phase::AveragedForce | Phase::AveragedGradient { .. }))
        .flat_map(|p| match p {
            // XPIC's field is computed right before the gather that updates the
            // particle velocities; its passes overwrite the scatter records, so
            // MUSL's remap is then a gather and a full second scatter.
            Phase::Remap if xpic => vec![
                Phase::XpicField,
                Phase::Gather {
                    stress: false,
                    move_now: false,
                    speed: false,
                },
                Phase::Scatter {
                    forces: false,
                    moved: false,
                },
            ],
            Phase::Gather { .. } if xpic => vec![Phase::XpicField, p],
            // The correction follows the scatter of moved particles, the averaged
            // force and the gradient the particles deform and move with.
            Phase::Scatter { moved: true, .. } if centroid => vec![p, Phase::CentroidOffsets],
            Phase::AveragedForce if centroid => vec![p, Phase::CentroidForce],
            Phase::AveragedGradient { slot } if centroid => {
                vec![Phase::CentroidVelocity { slot }, p]
            }
            _ => vec![p],
        })
        .collect();
    // XPIC's scatters overwrite the scatter records, where L̄ and v̄ are kept (`avg`):
    // its field first, then theirs (neither reads what the other writes).
    for i in 1..phases.len() {
        if phases[i] == Phase::XpicField && matches!(phases[i - 1], Phase::AveragedGradient { .. })
        {
            phases.swap(i - 1, i);
        }
    }
    phases
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every configuration a scene can ask for: update order × one- or two-step scheme
    /// × XPIC × the centroid correction (MUSL, two-step, no XPIC only).
    fn configurations() -> Vec<(Update, bool, bool, bool)> {
        let mut all = Vec::new();
        for update in [Update::Usl, Update::Usf, Update::Musl] {
            for two in [false, true] {
                for xpic in [false, true] {
                    all.push((update, two, xpic, false));
                    if update == Update::Musl && two && !xpic {
                        all.push((update, two, xpic, true));
                    }
                }
            }
        }
        all
    }

    /// What each phase reads and leaves, checked in order over every resolved list: a
    /// step starts with the scatter of moved particles; the grid velocity is formed
    /// after the scatter whose momentum it divides; a node → node gradient reads a
    /// velocity slot a grid update formed; a particle pass reads a gradient formed from
    /// the grid velocity since the last scatter (two-step schemes); one particle pass
    /// moves the particles and the step's last reports the signal speed; XPIC's field
    /// is formed from the updated grid velocity right before the gather that uses it,
    /// or before the gradient that precedes that gather (its scatters overwrite the
    /// records the gradient is kept in); the correction's offsets follow the first
    /// scatter, its force the averaged force, its velocity precedes the gradient of the
    /// same slot; a one-step scheme has no node → node phase.
    #[test]
    fn every_resolved_step_reads_what_an_earlier_phase_left() {
        for (update, two, xpic, centroid) in configurations() {
            let phases = resolve(update, two, xpic, centroid);
            let what =
                format!("{update:?} two-step {two} xpic {xpic} centroid {centroid}: {phases:?}");
            assert!(
                matches!(phases[0], Phase::Scatter { moved: true, .. }),
                "{what}"
            );
            let (mut velocity, mut gradient) = ([false; 2], false);
            let (mut moves, mut speed) = (0, 0);
            for (k, &p) in phases.iter().enumerate() {
                let next = phases.get(k + 1).copied();
                match p {
                    Phase::Scatter { moved, .. } => {
                        assert_eq!(moved, k == 0, "{what}");
                        velocity = [false; 2];
                        gradient = false;
                    }
                    Phase::Remap => {
                        assert!(velocity[UPDATED], "{what}");
                        velocity = [false; 2];
                        gradient = false;
                    }
                    Phase::GridUpdate { forces } => {
                        velocity[FROM_MOMENTUM] = true;
                        velocity[UPDATED] = forces;
                    }
                    Phase::AveragedGradient { slot } => {
                        assert!(two && velocity[slot], "{what}");
                        gradient = true;
                    }
                    Phase::AveragedForce => assert!(two, "{what}"),
                    Phase::XpicField => {
                        assert!(xpic && velocity[UPDATED], "{what}");
                        let then = match next {
                            Some(Phase::AveragedGradient { .. }) => phases.get(k + 2).copied(),
                            other => other,
                        };
                        assert!(matches!(then, Some(Phase::Gather { .. })), "{what}");
                        // Its passes overwrite the records a gradient is kept in.
                        gradient = false;
                    }
                    Phase::Gather {
                        stress, move_now, ..
                    } => {
                        assert!(velocity[UPDATED], "{what}");
                        assert!(!two || !(stress || move_now) || gradient, "{what}");
                        moves += usize::from(move_now);
                    }
                    Phase::Stress { slot, moves: m, .. } => {
                        assert!(velocity[slot] && (!two || gradient), "{what}");
                        moves += usize::from(m);
                    }
                    Phase::CentroidOffsets => {
                        assert!(centroid && k == 1, "{what}");
                    }
                    Phase::CentroidForce => {
                        assert!(centroid && phases[k - 1] == Phase::AveragedForce, "{what}");
                    }
                    Phase::CentroidVelocity { slot } => {
                        assert!(centroid && velocity[slot], "{what}");
                        assert_eq!(next, Some(Phase::AveragedGradient { slot }), "{what}");
                    }
                }
                let reports = match p {
                    Phase::Gather { speed, .. } | Phase::Stress { speed, .. } => speed,
                    _ => false,
                };
                assert_eq!(
                    reports,
                    next.is_none(),
                    "{what}: the last pass reports the speed"
                );
                speed += usize::from(reports);
            }
            assert_eq!((moves, speed), (1, 1), "{what}");
            let has = |f: fn(&Phase) -> bool| phases.iter().any(f);
            assert_eq!(
                has(|p| matches!(p, Phase::AveragedForce | Phase::AveragedGradient { .. })),
                two,
                "{what}"
            );
            assert_eq!(has(|p| *p == Phase::XpicField), xpic, "{what}");
            assert_eq!(has(|p| *p == Phase::CentroidOffsets), centroid, "{what}");
            if centroid {
                assert!(has(|p| *p == Phase::CentroidForce), "{what}");
                assert!(
                    has(|p| matches!(p, Phase::CentroidVelocity { .. })),
                    "{what}"
                );
            }
        }
    }
}
