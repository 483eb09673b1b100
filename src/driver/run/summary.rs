//! What a run reports: the summary (`summary.json`) and how it is gathered from the
//! ranks at the end of the run.

use super::profile::ProfileSummary;
use super::spread::Spread;
use super::{Run, RunError};
use crate::mpm::solver::Totals;
use crate::output::io::{agree, Labels};
use decomposition::Communicator;
use serde::Serialize;
use std::path::Path;

#[derive(Serialize, Debug, Clone)]
pub struct MassSummary {
    pub initial: f64,
    pub r#final: f64,
}

#[derive(Serialize, Debug, Clone)]
pub struct MomentumSummary {
    pub initial: Vec<f64>,
    pub r#final: Vec<f64>,
}

#[derive(Serialize, Debug, Clone)]
pub struct EnergySummary {
    pub initial_total: f64,
    pub final_total: f64,
    /// max_t |E(t) − E(0)| / max(|E(0)|, max_t (kinetic + strain)), E = kinetic + strain
    /// + plastic work − external work.
    pub max_relative_drift: f64,
    pub final_kinetic: f64,
    pub final_strain: f64,
    pub external_work: f64,
    /// Work dissipated by plastic flow (scenes with a `j2_plastic` material).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plastic_work: Option<f64>,
}

#[derive(Serialize, Debug, Clone)]
pub struct ErrorSummary {
    /// Maximum over all steps of the volume-weighted particle L2 norm.
    pub displacement_l2: f64,
    pub velocity_l2: f64,
    pub final_displacement_l2: f64,
    pub final_velocity_l2: f64,
}

/// Particles per rank at the end of the run (load balance).
#[derive(Serialize, Debug, Clone)]
pub struct RankLoad {
    pub min: u64,
    pub mean: f64,
    pub max: u64,
}

/// Collective: `min`, `mean` and `max` of a count over ranks.
pub(super) fn rank_load(comm: &dyn Communicator, x: f64) -> RankLoad {
    let (mut lo, mut hi, mut sum) = ([x], [x], [x]);
    comm.min_f64(&mut lo);
    comm.max_f64(&mut hi);
    comm.sum_f64(&mut sum);
    RankLoad {
        min: lo[0] as u64,
        mean: sum[0] / comm.size() as f64,
        max: hi[0] as u64,
    }
}

/// The sparse grid at the end of the run: active tiles of `tile_nodes` nodes each,
/// summed over ranks and per rank, and what a dense grid would have needed.
#[derive(Serialize, Debug, Clone)]
pub struct GridSummary {
    pub tile_nodes: usize,
    pub active_tiles: u64,
    pub active_tiles_per_rank: RankLoad,
    /// Tiles that would cover the whole grid (a dense grid's storage, in tiles).
    pub box_tiles: f64,
}

/// How the blocks followed the load: the `[parallel]` settings, the rebalances
/// (the one at the start of a balanced run included), the block boundaries at the end
/// and the particle imbalance there (largest rank over the mean).
#[derive(Serialize, Debug, Clone)]
pub struct BalanceSummary {
    pub mode: String,
    pub threshold: f64,
    pub rebalances: u64,
    pub cuts: Vec<Vec<usize>>,
    pub imbalance: f64,
    /// Imbalance samples of this run (every `check_every` steps, after any move).
    pub checks: u64,
    pub imbalance_mean: f64,
    pub imbalance_max: f64,
    /// The share of the samples at most 1.10.
    pub within_10_percent: f64,
}

/// Where a restarted run began.
#[derive(Serialize, Debug, Clone)]
pub struct RestartSummary {
    pub checkpoint: String,
    pub step: u64,
    pub time: f64,
    /// Particle rows of the checkpoint each rank read (all of its own writer's on
    /// the writer's process grid, else those of the writers whose blocks overlap).
    pub particle_rows_read: RankLoad,
}

#[derive(Serialize, Debug, Clone)]
pub struct Summary {
    pub scene: String,
    pub dim: usize,
    pub gradient: String,
    /// MPMCG's quadrature (`point` or `domain`), for MPMCG only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quadrature: Option<String>,
    pub update: String,
    pub flip: f64,
    /// The XPIC order, when XPIC replaced the FLIP/PIC blend.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub xpic: Option<u32>,
    /// Passes of the centroid correction, when it is on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub centroid_passes: Option<u32>,
    /// β of the sharpening of the nodal averages, when it is on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sharpen: Option<f64>,
    /// `domain` when a benchmark's body force is averaged over each particle's box.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub body_force: Option<String>,
    /// The version of the scene defaults the absent `[method]` keys took (a restart
    /// keeps its checkpoint's).
    pub scene_defaults: u32,
    /// `SI`, or `dimensionless` for benchmark scenes (as in the snapshots).
    pub units: String,
    /// `completed`, `unstable` or `interrupted`.
    pub status: String,
    pub message: Option<String>,
    pub ranks: usize,
    pub threads: usize,
    pub blocks: Vec<usize>,
    pub particles_per_rank: RankLoad,
    pub balance: BalanceSummary,
    pub grid: GridSummary,
    pub particles: u64,
    pub cells: Vec<usize>,
    pub steps: u64,
    pub time: f64,
    pub end_time: f64,
    /// Wall time of this run (since its restart, if it was restarted).
    pub wall_seconds: f64,
    /// Over the steps of this run.
    pub particle_updates_per_second: f64,
    pub mass: MassSummary,
    pub momentum: MomentumSummary,
    pub energy: EnergySummary,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorSummary>,
    /// The newest checkpoint (written by this run, or the one it restarted from): what
    /// to restart from after an interruption or instability.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_checkpoint: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub restarted_from: Option<RestartSummary>,
    /// Wall time spent writing files, part of `wall_seconds`.
    pub output_seconds: OutputSeconds,
    /// Bytes and messages sent between ranks per step.
    pub halo: HaloSummary,
    /// Where the steps' time went, per rank.
    pub profile: ProfileSummary,
}

/// Wall time (rank 0's clock) spent writing snapshots and checkpoints.
#[derive(Serialize, Debug, Clone, Default)]
pub struct OutputSeconds {
    pub snapshots: f64,
    pub checkpoints: f64,
}

/// Point-to-point traffic between ranks per step, averaged over the steps of this run:
/// what the network would carry. A rank's exchange with itself (a periodic face it
/// owns both sides of) is a local copy and not counted, so one rank reports zeros.
#[derive(Serialize, Debug, Clone)]
pub struct HaloSummary {
    /// The steps averaged over.
    pub steps: u64,
    /// The grid's halo: ghost sums and copies of nodal fields.
    pub grid: TrafficSummary,
    /// Particles moving to the rank that owns their new cell.
    pub migration: TrafficSummary,
    /// Other ranks each rank shares grid nodes with (its halo and migration peers).
    pub peers_per_rank: Spread,
}

/// One kind of exchange, per step.
#[derive(Serialize, Debug, Clone)]
pub struct TrafficSummary {
    /// Exchanges per step, the same on every rank (each is a round of messages).
    pub exchanges_per_step: f64,
    /// Payload bytes a rank sent to other ranks per step.
    pub bytes_per_rank_per_step: Spread,
    /// Non-empty messages a rank sent to other ranks per step.
    pub messages_per_rank_per_step: Spread,
}

/// Collective: rank 0 writes `summary.json`, unless writing `history.csv` `failed`.
/// No rank leaves before rank 0 has written everything: mpirun ends the whole job as
/// soon as one rank exits with a non-zero status.
pub(super) fn write_summary(
    comm: &dyn Communicator,
    out: &Path,
    summary: &Summary,
    failed: Option<String>,
) -> Result<(), RunError> {
    let mut written = failed;
    if comm.rank() == 0 && written.is_none() {
        let path = out.join("summary.json");
        let text = serde_json::to_string_pretty(summary).expect("summary serialises");
        // Via a temporary file: a full disk leaves the previous summary (or none), never
        // a truncated one.
        let tmp = out.join(".summary.json.tmp");
        written = std::fs::write(&tmp, text + "\n")
            .and_then(|()| std::fs::rename(&tmp, &path))
            .err()
            .map(|e| {
                let _ = std::fs::remove_file(&tmp);
                format!("{}: {e}", path.display())
            });
    }
    if let Some(m) = agree(comm, written) {
        return Err(RunError::Io(m));
    }
    Ok(())
}

impl<'a, const D: usize> Run<'a, D> {
    /// Collective: the summary of the run that ended at `end` (step, time) with the
    /// totals `last`, after `wall` seconds; its status and message are the caller's.
    pub(super) fn summary(
        &mut self,
        last: &Totals,
        (steps, time): (u64, f64),
        wall: f64,
    ) -> Summary {
        let (particles_per_rank, grid) = self.loads(last.particles);
        let imbalance = self.solver.imbalance();
        let halo = self.traffic();
        let profile = self.profile();
        self.history.flush();
        let (scene, solver, tot0) = (self.scene, &self.solver, &self.st.initial);
        Summary {
            scene: scene.name.clone(),
            dim: D,
            gradient: scene.method.gradient.name().into(),
            quadrature: (scene.method.gradient == crate::input::scene::Gradient::Mpmcg)
                .then(|| scene.method.quadrature.name().into()),
            update: scene.method.update.name().into(),
            flip: scene.method.flip,
            xpic: scene.method.xpic,
            centroid_passes: (scene.method.centroid_passes > 0)
                .then_some(scene.method.centroid_passes),
            sharpen: (scene.method.sharpen > 0.0).then_some(scene.method.sharpen),
            body_force: scene.plan.body_force_over_domain.then(|| "domain".into()),
            scene_defaults: scene.defaults,
            units: Labels::of::<D>(scene).units,
            status: String::new(),
            message: None,
            ranks: self.comm.size(),
            threads: self.threads,
            blocks: solver.layout.procs.to_vec(),
            particles_per_rank,
            balance: BalanceSummary {
                mode: scene.parallel.balance.name().into(),
                threshold: scene.parallel.imbalance,
                rebalances: solver.rebalances,
                cuts: (0..D).map(|a| solver.layout.cuts(a).to_vec()).collect(),
                imbalance,
                checks: self.balance.checks,
                imbalance_mean: self.balance.sum / self.balance.checks.max(1) as f64,
                imbalance_max: self.balance.max,
                within_10_percent: self.balance.within as f64 / self.balance.checks.max(1) as f64,
            },
            grid,
            particles: tot0.particles,
            cells: scene.grid.cells.clone(),
            steps,
            time,
            end_time: scene.time.end,
            wall_seconds: wall,
            particle_updates_per_second: tot0.particles as f64
                * (solver.step - self.step_start) as f64
                / wall.max(1e-9),
            mass: MassSummary {
                initial: tot0.mass,
                r#final: last.mass,
            },
            momentum: MomentumSummary {
                initial: tot0.momentum.clone(),
                r#final: last.momentum.clone(),
            },
            energy: self.energy(last),
            error: self.errors(),
            last_checkpoint: self
                .checkpoints
                .last
                .as_ref()
                .map(|p| p.display().to_string()),
            restarted_from: self.restarted_from.clone(),
            output_seconds: self.output_seconds.clone(),
            halo,
            profile,
        }
    }

    /// Collective: per-step traffic between ranks over this run's steps, spread over
    /// ranks. Three reductions of five numbers, once per run.
    fn traffic(&self) -> HaloSummary {
        let (comm, solver) = (self.comm, &self.solver);
        let steps = solver.step - self.step_start;
        let (halo, mig) = solver.traffic();
        let me = comm.rank();
        let peers = solver.block.peers().iter().filter(|&&p| p != me).count();
        let per_step = |x: u64| x as f64 / steps.max(1) as f64;
        let mine = [
            per_step(halo.bytes),
            per_step(halo.messages),
            per_step(mig.bytes),
            per_step(mig.messages),
            peers as f64,
        ];
        let spread = Spread::over_ranks(comm, &mine);
        HaloSummary {
            steps,
            grid: TrafficSummary {
                exchanges_per_step: per_step(halo.exchanges),
                bytes_per_rank_per_step: spread[0].clone(),
                messages_per_rank_per_step: spread[1].clone(),
            },
            migration: TrafficSummary {
                exchanges_per_step: per_step(mig.exchanges),
                bytes_per_rank_per_step: spread[2].clone(),
                messages_per_rank_per_step: spread[3].clone(),
            },
            peers_per_rank: spread[4].clone(),
        }
    }

    /// Collective: particles and active grid tiles per rank; `particles` in all.
    fn loads(&self, particles: u64) -> (RankLoad, GridSummary) {
        let (comm, solver) = (self.comm, &self.solver);
        let mut lo = [solver.parts.len() as f64, solver.tiles.active() as f64];
        let mut hi = lo;
        let mut sum = [solver.tiles.active() as u64];
        comm.min_f64(&mut lo);
        comm.max_f64(&mut hi);
        comm.sum_u64(&mut sum);
        let ranks = comm.size() as f64;
        let particles = RankLoad {
            min: lo[0] as u64,
            mean: particles as f64 / ranks,
            max: hi[0] as u64,
        };
        let grid = GridSummary {
            tile_nodes: solver.tiles.tile_nodes(),
            active_tiles: sum[0],
            active_tiles_per_rank: RankLoad {
                min: lo[1] as u64,
                mean: sum[0] as f64 / ranks,
                max: hi[1] as u64,
            },
            box_tiles: self
                .scene
                .grid
                .cells
                .iter()
                .map(|&c| (c + 1).div_ceil(decomposition::TILE) as f64)
                .product(),
        };
        (particles, grid)
    }

    /// The energy balance, from the initial state to `last`.
    fn energy(&self, last: &Totals) -> EnergySummary {
        let st = &self.st;
        EnergySummary {
            initial_total: self.e0,
            final_total: last.total_energy(),
            max_relative_drift: if st.energy_scale > 0.0 {
                st.max_energy_dev / st.energy_scale
            } else {
                0.0
            },
            final_kinetic: last.kinetic,
            final_strain: last.strain,
            external_work: last.external_work,
            plastic_work: self.solver.carries().plastic.then_some(last.plastic_work),
        }
    }

    /// Benchmarks: the largest and the final error norms.
    fn errors(&self) -> Option<ErrorSummary> {
        let st = &self.st;
        self.solver.benchmark.is_some().then(|| {
            let (fu, fv) = st.last_err.unwrap_or((f64::NAN, f64::NAN));
            ErrorSummary {
                displacement_l2: st.max_err.0,
                velocity_l2: st.max_err.1,
                final_displacement_l2: fu,
                final_velocity_l2: fv,
            }
        })
    }
}
