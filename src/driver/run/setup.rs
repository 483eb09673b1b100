//! Setting a run up: the output folder claimed and cleared, the solver built fresh or
//! restored from a checkpoint, and the lineage and run state it starts with.

use super::schedules::SnapshotSchedule;
use super::summary::{rank_load, RestartSummary};
use super::{RunError, RunOptions};
use crate::driver::memory;
use crate::input::plan::CheckpointEvery;
use crate::input::scene::{Balance, Scene};
use crate::mpm::particles::{Carries, Particles};
use crate::mpm::solver::{Load, Solver};
use crate::output::checkpoint::{self, RunState};
use crate::output::io::agree;
use decomposition::{Communicator, Layout};
use std::path::Path;

/// The solver and, after a restart, the run state, where it came from and the
/// checkpoint's lineage.
pub(super) type SetUp<'c, const D: usize> = (
    Solver<'c, D>,
    Option<RunState>,
    Option<RestartSummary>,
    Option<String>,
);

/// A fresh solver, or one continuing from `opts.restart` (every rank agrees on errors).
pub(super) fn set_up<'c, const D: usize>(
    scene: &Scene,
    comm: &'c dyn Communicator,
    layout: &Layout<D>,
    opts: &RunOptions,
) -> Result<SetUp<'c, D>, RunError> {
    let balance = scene.parallel.balance;
    let Some(path) = &opts.restart else {
        check_memory(scene, comm, layout)?;
        let mut solver = Solver::new(scene, comm, layout.clone());
        // Seeded in equal blocks, then cut for an equal share of the particles.
        if balance != Balance::Off {
            solver.rebalance(1.0, Load::Particles);
        }
        return Ok((solver, None, None, None));
    };
    let geom = Solver::<D>::geometry(scene);
    let carries = crate::mpm::particles::Carries::for_scene(scene);
    let header = checkpoint::read_header(path);
    if let Some(m) = agree(comm, header.as_ref().err().cloned()) {
        return Err(RunError::Input(m));
    }
    let header = header.expect("agreed: no rank failed");
    check_restart_memory(comm, header.particles, Particles::<D>::state_bytes(carries))?;
    // The writer's blocks when it ran on this process grid (so each rank reads its own
    // rows and the run continues bit for bit), unless balancing is off.
    let layout = match header.layout(layout) {
        Some(l) if balance != Balance::Off => l,
        _ => layout.clone(),
    };
    let r = checkpoint::read::<D>(
        &header,
        comm.rank(),
        &layout,
        &geom,
        carries,
        &crate::mpm::particles::Kinds::of_scene(scene, &geom),
    );
    if let Some(m) = agree(comm, r.as_ref().err().cloned()) {
        return Err(RunError::Input(m));
    }
    let restored = r.expect("agreed: no rank failed");
    // Every rank read the same header, so every rank decides alike.
    if header.time >= scene.time.end {
        return Err(RunError::Input(format!(
            "time.end = {:e} is not after the time of checkpoint {} (t = {:e}, step {}): nothing to run; restart with a scene whose time.end is later",
            scene.time.end,
            path.display(),
            header.time,
            header.step
        )));
    }
    let mut count = [restored.parts.len() as u64];
    comm.sum_u64(&mut count);
    if count[0] != header.particles {
        return Err(RunError::Input(format!(
            "{}: damaged checkpoint: {} of its {} particles lie in this run's cells",
            path.display(),
            count[0],
            header.particles
        )));
    }
    let rebalanced = Some(&layout) != header.layout(&layout).as_ref();
    let mut solver = Solver::with_particles(scene, comm, layout, restored.parts);
    let s = restored.solver;
    solver.restore(s.t, s.step, s.dt, s.external_work, s.max_speed);
    solver.rebalances = header.rebalances;
    // Another rank count or process grid: read in equal blocks, now cut to the load.
    if rebalanced && balance != Balance::Off {
        solver.rebalance(1.0, Load::Particles);
    }
    let info = RestartSummary {
        checkpoint: path.display().to_string(),
        step: s.step,
        time: s.t,
        particle_rows_read: rank_load(comm, restored.rows_read as f64),
    };
    let mut run = restored.run;
    // A restart with an edited scene (longer, other step size, other output or
    // checkpoint intervals: see scene::restart_difference) reschedules its output from
    // the checkpoint's time; an unchanged scene keeps the stored schedule bit for bit.
    if opts.scene_text.as_deref() != Some(header.scene_text.as_str()) {
        let next = |every: f64| ((s.t / every + 1e-9).floor() + 1.0) * every;
        run.next_snapshot = scene
            .snapshot_plan()
            .filter(|o| o.every.is_finite())
            .map_or(f64::INFINITY, |o| next(o.every));
        run.next_checkpoint = match scene.plan.checkpoint {
            Some(CheckpointEvery::Time(every)) => next(every),
            _ => f64::INFINITY,
        };
    }
    Ok((solver, Some(run), Some(info), header.lineage))
}

/// Collective: create the output folder and lock it (rank 0); every rank learns of a
/// failure. Returns rank 0's lock (`None` elsewhere).
pub(super) fn claim_output(
    comm: &dyn Communicator,
    out: &Path,
) -> Result<Option<crate::output::lock::Lock>, RunError> {
    let root = comm.rank() == 0;
    let made = if root {
        std::fs::create_dir_all(out)
            .err()
            .map(|e| format!("{}: {e}", out.display()))
    } else {
        None
    };
    if let Some(m) = agree(comm, made) {
        return Err(RunError::Io(m));
    }
    let (lock, locked) = match root.then(|| crate::output::lock::acquire(out)) {
        Some(Ok(l)) => (Some(l), None),
        Some(Err(e)) => (None, Some(e)),
        None => (None, None),
    };
    let held = matches!(locked, Some(crate::output::lock::LockError::Held(_)));
    let message = locked.map(|e| match e {
        crate::output::lock::LockError::Held(m) | crate::output::lock::LockError::Io(m) => m,
    });
    if let Some(m) = agree(comm, message) {
        return Err(if comm.any(held) {
            RunError::Input(m)
        } else {
            RunError::Io(m)
        });
    }
    Ok(lock)
}

/// Collective: rank 0 of a fresh run removes an earlier run's snapshots from the
/// locked output folder ([`crate::output::io::remove_old_snapshots`]) and says so (even under
/// `--quiet`: files were deleted); every rank
/// learns of a failure.
pub(super) fn clear_old_snapshots(comm: &dyn Communicator, out: &Path) -> Result<(), RunError> {
    let failed = if comm.rank() == 0 {
        match crate::output::io::remove_old_snapshots(out) {
            Ok(0) => None,
            Ok(n) => {
                // Even with --quiet: files were deleted.
                say!(
                    "note: removed {n} snapshot(s) of an earlier run from {}",
                    out.display()
                );
                None
            }
            Err(m) => Some(format!("removing an earlier run's snapshots: {m}")),
        }
    } else {
        None
    };
    match agree(comm, failed) {
        Some(m) => Err(RunError::Io(m)),
        None => Ok(()),
    }
}

/// Collective: the checkpoint lineage of this run, `stored` (a restart's) or a fresh
/// one, which rank 0 makes and every rank receives. Pruning deletes only checkpoints of
/// this run and the runs it continues; rank 0 warns of the others in `out`.
pub(super) fn lineage(
    comm: &dyn Communicator,
    out: &Path,
    stored: Option<String>,
    keep: usize,
) -> checkpoint::Lineage {
    let id = match stored {
        Some(id) => id,
        None => {
            let fresh = checkpoint::Lineage::fresh(keep).id;
            String::from_utf8_lossy(&comm.broadcast_bytes(fresh.as_bytes())).into_owned()
        }
    };
    let mut lineage = checkpoint::Lineage::continued(id, keep);
    if comm.rank() == 0 {
        let others = lineage.scan(out);
        if let (Some(first), Some(last)) = (others.first(), others.last()) {
            say!(
                "warning: {} holds {} checkpoint(s) of another run ({first} ... {last}); this run does not delete them",
                out.display(),
                others.len()
            );
        }
    }
    lineage
}

/// Collective: a restored run state, keeping the earlier snapshots that are in this
/// output folder (rank 0 decides, every rank keeps the same list).
pub(super) fn resumed(
    comm: &dyn Communicator,
    out: &Path,
    mut st: RunState,
    snaps: Option<&mut SnapshotSchedule>,
) -> RunState {
    if let Some(sn) = snaps {
        let root = comm.rank() == 0;
        let mask: Vec<u8> = st
            .snapshots
            .iter()
            .map(|e| u8::from(root && out.join(e.file()).is_file()))
            .collect();
        let mask = comm.broadcast_bytes(&mask);
        let mut k = 0;
        st.snapshots.retain(|_| {
            k += 1;
            mask[k - 1] == 1
        });
        sn.writer.set_entries(st.snapshots.clone());
    }
    st
}

/// Collective: the run state of a fresh run, from the initial totals and errors, with
/// the first snapshot, history sample and checkpoint at these times.
pub(super) fn initial<const D: usize>(
    solver: &Solver<D>,
    next_snapshot: f64,
    next_history: f64,
    next_checkpoint: f64,
) -> RunState {
    let tot0 = solver.totals();
    let err0 = solver.errors();
    RunState {
        energy_scale: tot0.total_energy().abs().max(tot0.kinetic + tot0.strain),
        max_energy_dev: 0.0,
        max_err: err0.unwrap_or((0.0, 0.0)),
        last_err: err0,
        next_history,
        last_history_step: 0,
        next_snapshot,
        next_checkpoint,
        snapshots: Vec::new(),
        history: Vec::new(),
        last: tot0.clone(),
        initial: tot0,
    }
}

/// Collective: refuse (exit 2) a scene whose particles cannot fit, before seeding them.
/// Each rank counts the particles its block will seed; their state alone (a particle's
/// checkpoint record, less than a run holds per particle) must fit in what the node has
/// available, summed over the node's ranks, and in what each process's address-space
/// limit leaves. Otherwise the run would end in an allocation failure or at the hands of
/// the kernel's OOM killer, after the queue wait and the set-up.
fn check_memory<const D: usize>(
    scene: &Scene,
    comm: &dyn Communicator,
    layout: &Layout<D>,
) -> Result<(), RunError> {
    let bytes = Particles::<D>::state_bytes(Carries::for_scene(scene));
    let (node, mine) = (memory::node_available(), memory::address_space_left());
    // Counting stops once the count alone is too many.
    let stop = [node, mine]
        .into_iter()
        .flatten()
        .min()
        .map_or(0, |b| b / bytes + 1);
    let block = decomposition::Block::new(layout, comm.rank());
    let n = super::count_seeded_in::<D>(scene, (block.cell_lo, block.cell_hi), stop);
    // Where a count stopped, it is a lower bound, and so is the node's sum.
    let stopped = n == stop;
    let mut on_node = [n, u64::from(stopped)];
    comm.node_sum_u64(&mut on_node);
    let advice = "run on more nodes, or with fewer particles per cell or a coarser grid";
    let err = if let Some(room) = node.filter(|&a| on_node[0].saturating_mul(bytes) > a) {
        Some(format!(
            "the particles do not fit in memory: this node's ranks would seed {}; {advice}",
            memory::particles_over(
                on_node[0],
                bytes,
                room,
                "the node has available",
                on_node[1] > 0
            )
        ))
    } else {
        mine.filter(|&a| n.saturating_mul(bytes) > a).map(|room| {
            let what = "its address-space limit (ulimit -v) leaves";
            format!(
                "the particles do not fit in memory: rank {} would seed {}; {advice}",
                comm.rank(),
                memory::particles_over(n, bytes, room, what, stopped)
            )
        })
    };
    match agree(comm, err) {
        Some(m) => Err(RunError::Input(m)),
        None => Ok(()),
    }
}

/// Collective, on a restart: the checkpoint's `total` particles of `bytes` each against
/// the memory of the whole job. A rank's share is known only once it has read the
/// rows, but past what all the job's nodes have available, or all its ranks'
/// address-space limits leave, some node or rank is sure to run out: refused then,
/// before any row is read. Every rank forms the same sums, so all decide alike.
fn check_restart_memory(comm: &dyn Communicator, total: u64, bytes: u64) -> Result<(), RunError> {
    let (node, mine) = (memory::node_available(), memory::address_space_left());
    let mut ranks_on_node = [1u64];
    comm.node_sum_u64(&mut ranks_on_node);
    // Each node counted once, a share of it per rank; a rank's figure capped at
    // 2^44 bytes (16 TiB), so that a sum over fewer than 2^20 ranks cannot wrap. The
    // second and fourth sums count the ranks that could not tell.
    let cap = |b: u64| b.min(1 << 44);
    let mut sums = [
        node.map_or(0, |a| cap(a / ranks_on_node[0])),
        u64::from(node.is_none()),
        mine.map_or(0, cap),
        u64::from(mine.is_none()),
    ];
    comm.sum_u64(&mut sums);
    let need = total.saturating_mul(bytes);
    let over = |room: u64, what: &str| {
        RunError::Input(format!(
            "the checkpoint's particles do not fit in memory: {}; restart on more nodes (a checkpoint restarts on any rank count)",
            memory::particles_over(total, bytes, room, what, false)
        ))
    };
    if sums[1] == 0 && need > sums[0] {
        return Err(over(sums[0], "the job's nodes have available"));
    }
    if sums[3] == 0 && need > sums[2] {
        let what = "the ranks' address-space limits (ulimit -v) leave";
        return Err(over(sums[2], what));
    }
    Ok(())
}
