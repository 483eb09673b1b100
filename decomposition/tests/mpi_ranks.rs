//! [`MpiComm`] on real MPI ranks, with the same properties the unit tests check on
//! `LocalComm`: exchanges, ghost sum, ghost copy, collectives and particle migration.
//! A process initialises MPI once, so the checks are one ignored test that this file's
//! other tests run under mpirun on 2 ranks and on 4 (more ranks than this machine's
//! cores, so that ranks wait for ranks that are not running):
//!
//! ```sh
//! cargo test -p decomposition --test mpi_ranks
//! ```

use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use std::collections::HashMap;

use decomposition::{Block, Communicator, Layout, Migrator, MpiComm, GHOST};

thread_local! {
    /// Allocations made by this thread so far ([`Counting`]).
    static ALLOCATIONS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// The system allocator, counting each thread's allocations, so that a check can
/// show an exchange allocates nothing.
struct Counting;

// SAFETY: every call is passed on to `System` with the same arguments, so the memory
// handed out and its layout are `System`'s; the count is a const-initialised
// thread-local `Cell`, which neither allocates nor needs a destructor.
unsafe impl std::alloc::GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        std::alloc::System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        std::alloc::System.dealloc(ptr, layout)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn wrapped<const D: usize>(l: &Layout<D>, b: &Block<D>, i: usize) -> [usize; D] {
    l.wrap_node(b.global(b.coords(i))).unwrap()
}

fn f<const D: usize>(w: [usize; D]) -> f64 {
    w.iter()
        .enumerate()
        .map(|(a, &x)| x as f64 * 100f64.powi(a as i32))
        .sum::<f64>()
        + 1.0
}

fn check<const D: usize>(comm: &MpiComm, cells: [usize; D], periodic: [bool; D]) {
    let Ok(layout) = Layout::choose(cells, periodic, comm.size()) else {
        if comm.rank() == 0 {
            println!("skip {cells:?}: too small for {} ranks", comm.size());
        }
        return;
    };
    let me = comm.rank();
    let mut b = Block::new(&layout, me);
    let n = b.num_nodes();

    // Copies of each node over all boxes, counted by brute force on every rank.
    let mut copies: HashMap<[usize; D], usize> = HashMap::new();
    for r in 0..layout.ranks() {
        let o = Block::new(&layout, r);
        for i in 0..o.num_nodes() {
            *copies.entry(wrapped(&layout, &o, i)).or_insert(0) += 1;
        }
    }
    let mut field: Vec<f64> = (0..n).map(|i| f(wrapped(&layout, &b, i))).collect();
    b.ghost_sum(comm, &mut field, 1);
    for (i, v) in field.iter_mut().enumerate() {
        if b.is_owned(b.coords(i)) {
            let w = wrapped(&layout, &b, i);
            assert_eq!(*v, copies[&w] as f64 * f(w), "ghost_sum {layout:?} {w:?}");
        } else {
            *v = f64::NAN;
        }
    }
    b.ghost_copy(comm, &mut field, 1);
    for (i, v) in field.iter().enumerate() {
        let w = wrapped(&layout, &b, i);
        assert_eq!(*v, copies[&w] as f64 * f(w), "ghost_copy {layout:?} {w:?}");
    }

    // Migration: each owned cell's lower corner holds one particle moving by a fixed
    // pattern of up to GHOST cells per axis.
    let mut mig = Migrator::new(&layout, &b, 1 + D);
    let mut kept = 0u64;
    let mut sent = 0u64;
    let mut rec = vec![0.0; 1 + D];
    for i in 0..n {
        let l = b.coords(i);
        if !b.is_owned(l) || (0..D).any(|a| l[a] - b.own_lo[a] >= b.cell_hi[a] - b.cell_lo[a]) {
            continue;
        }
        let g = b.global(l);
        let h = g.iter().fold(0i64, |h, &x| h * 31 + x);
        let to: [i64; D] = std::array::from_fn(|a| {
            let c = g[a] + (h * 7 + 3 * a as i64).rem_euclid(2 * GHOST as i64 + 1) - GHOST as i64;
            if layout.periodic[a] {
                c
            } else {
                c.clamp(0, layout.cells[a] as i64 - 1)
            }
        });
        let d = mig.destination(to).unwrap();
        if d.rank == me {
            kept += 1;
        } else {
            rec[0] = i as f64;
            for a in 0..D {
                rec[1 + a] = to[a] as f64;
            }
            mig.push(d.rank, &rec);
            sent += 1;
        }
    }
    let got = mig.exchange(comm).unwrap();
    for r in got {
        let cell: [usize; D] =
            std::array::from_fn(|a| (r[1 + a] as i64).rem_euclid(layout.cells[a] as i64) as usize);
        assert_eq!(layout.cell_owner(cell), me, "migrated to the wrong rank");
    }
    let mut totals = [kept + got.len() as u64, sent, got.len() as u64];
    comm.sum_u64(&mut totals);
    let all_cells: usize = cells.iter().product();
    assert_eq!(totals[0], all_cells as u64, "particles lost or duplicated");
    assert_eq!(totals[1], totals[2], "sent != received");
    if me == 0 {
        println!("ok {layout:?}: {} particles migrated", totals[1]);
    }
}

/// What rank `from` sends rank `to` in exchange `round`: a length from 0 to 4 that
/// differs between pairs and rounds, and values that name all three.
fn message(from: usize, to: usize, round: usize) -> Vec<f64> {
    let len = (from * 7 + to * 3 + round) % 5;
    (0..len)
        .map(|i| (from * 1_000_000 + to * 10_000 + round * 10 + i) as f64)
        .collect()
}

/// Many exchanges in a row with every rank (itself included), without a collective
/// between them, in an order that differs between ranks, empty messages among them,
/// and one rank late to each (long enough that the others nap while they wait):
/// each receive holds what its peer sent it in the same exchange, and the exchange
/// allocates nothing once the receive buffers have room. `spill`: through
/// [`MpiComm::exchange_inline`] with room for one peer on the stack, so that more than
/// one other rank takes the heap's bookkeeping.
fn check_exchange(comm: &MpiComm, spill: bool) {
    let (me, n) = (comm.rank(), comm.size());
    let mut peers: Vec<usize> = (0..n).collect();
    if me % 2 == 1 {
        peers.reverse();
    }
    let rounds = 40;
    let sends: Vec<Vec<Vec<f64>>> = (0..rounds)
        .map(|round| peers.iter().map(|&p| message(me, p, round)).collect())
        .collect();
    let mut recvs: Vec<Vec<f64>> = (0..n).map(|_| Vec::with_capacity(4)).collect();
    let mut allocations = 0;
    for (round, sends) in sends.iter().enumerate() {
        if round % n == me {
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        let before = ALLOCATIONS.with(|c| c.get());
        if spill {
            comm.exchange_inline::<1>(&peers, sends, &mut recvs);
        } else {
            comm.exchange(&peers, sends, &mut recvs);
        }
        allocations += ALLOCATIONS.with(|c| c.get()) - before;
        for (k, &p) in peers.iter().enumerate() {
            assert_eq!(recvs[k], message(p, me, round), "from {p} in round {round}");
        }
    }
    if !spill {
        assert_eq!(
            allocations, 0,
            "allocations in {rounds} exchanges on rank {me}"
        );
    }
}

/// Every check, on each rank of the mpirun that started this process (on its own, one
/// rank). Panics on any mismatch, which makes mpirun end the job with an error.
#[test]
#[ignore = "runs on each rank under mpirun, started by the tests below"]
fn on_each_rank() {
    let universe = mpi::initialize().expect("MPI initialises once per process");
    let comm = MpiComm::new(universe.world());
    let r = comm.rank() as u64;
    assert_eq!(comm.exclusive_scan_u64(r + 1), r * (r + 1) / 2);
    let mut x = [r as f64];
    comm.sum_f64(&mut x);
    let s = comm.size() as f64;
    assert_eq!(x[0], s * (s - 1.0) / 2.0);
    assert!(comm.any(r == 0));
    let bytes = comm.broadcast_bytes(b"from rank 0");
    assert_eq!(bytes, b"from rank 0");
    let g = comm.gather_bytes(&vec![r as u8; r as usize]);
    if r == 0 {
        assert_eq!(g.len(), comm.size());
    }
    check_exchange(&comm, false);
    check_exchange(&comm, true);

    check(&comm, [24], [true]);
    check(&comm, [24], [false]);
    check(&comm, [12, 9], [true, false]);
    check(&comm, [8, 8], [true, true]);
    check(&comm, [6, 8, 5], [true, false, true]);
    if comm.rank() == 0 {
        println!("mpi_check passed on {} ranks", comm.size());
    }
}

/// Run [`on_each_rank`] of this test binary under `mpirun -n ranks`.
fn run(ranks: usize) {
    let mut c = Command::new("mpirun");
    c.args([
        "--oversubscribe",
        "--timeout",
        "120",
        "-n",
        &ranks.to_string(),
    ]);
    if Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
    {
        c.arg("--allow-run-as-root");
    }
    let me = std::env::current_exe().expect("a test knows its binary");
    let mut child = c
        .arg(Path::new(&me))
        .args(["on_each_rank", "--exact", "--ignored", "--nocapture"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("mpirun starts");
    // mpirun's own timeout has been seen to hang with its ranks ended, so the test
    // keeps the time itself: a check that deadlocks fails instead of stalling the suite.
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("mpirun can be waited for") {
            break Some(status);
        }
        if start.elapsed() > Duration::from_secs(180) {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let (mut stdout, mut stderr) = (String::new(), String::new());
    let _ = child
        .stdout
        .take()
        .map(|mut o| o.read_to_string(&mut stdout));
    let _ = child
        .stderr
        .take()
        .map(|mut e| e.read_to_string(&mut stderr));
    assert!(
        status.is_some_and(|s| s.success())
            && stdout.contains(&format!("mpi_check passed on {ranks} ranks")),
        "{ranks} ranks ({status:?}):\n{stdout}\n{stderr}"
    );
}

#[test]
fn exchanges_collectives_halo_and_migration_on_two_ranks() {
    run(2);
}

#[test]
fn exchanges_collectives_halo_and_migration_on_more_ranks_than_cores() {
    run(4);
}
