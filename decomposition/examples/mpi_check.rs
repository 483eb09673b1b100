//! Checks [`MpiComm`] on real MPI ranks with the same properties the unit tests check on
//! `LocalComm`: ghost sum, ghost copy, collectives and particle migration. Unit tests
//! cannot own MPI (it initialises once per process), so this runs under mpirun:
//!
//! ```sh
//! cargo build -p decomposition --example mpi_check
//! mpirun --oversubscribe --timeout 60 -n 4 target/debug/examples/mpi_check
//! ```
//!
//! Exits non-zero (via a panic, which makes mpirun abort the job) on any mismatch.

#![forbid(unsafe_code)]

use std::collections::HashMap;

use decomposition::{Block, Communicator, Layout, Migrator, MpiComm, GHOST};

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

fn main() {
    let universe = mpi::initialize().expect("MPI initialises once");
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

    check(&comm, [24], [true]);
    check(&comm, [24], [false]);
    check(&comm, [12, 9], [true, false]);
    check(&comm, [8, 8], [true, true]);
    check(&comm, [6, 8, 5], [true, false, true]);
    if comm.rank() == 0 {
        println!("mpi_check passed on {} ranks", comm.size());
    }
}
