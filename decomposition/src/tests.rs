//! Multi-rank tests of the decomposition, run in-process with [`LocalComm`] (and
//! [`SerialComm`] for the 1-rank case): every expectation is computed independently by
//! brute force over the global grid.

use std::collections::HashMap;

use crate::block::Block;
use crate::comm::{Communicator, SerialComm};
use crate::layout::{Layout, Profile, GHOST};
use crate::local::LocalComm;
use crate::migrate::Migrator;
use crate::splitmix::Rng;
use crate::Error;

fn layouts1() -> Vec<Layout<1>> {
    [
        (7, false, 1),
        (7, true, 1),
        (7, false, 2),
        (7, true, 3),
        (9, false, 4),
        (4, true, 2),
        (13, true, 6),
        (13, false, 6),
    ]
    .into_iter()
    .map(|(c, p, n)| Layout::new([c], [p], [n]).unwrap())
    .chain(uneven([13], [true], [3], 1))
    .chain(uneven([13], [false], [4], 2))
    .collect()
}

/// A layout with the process grid `procs` and random cuts (seeded), blocks of the
/// minimum width included: every property test runs on uneven blocks too, as a
/// rebalance leaves them.
fn uneven<const D: usize>(
    cells: [usize; D],
    periodic: [bool; D],
    procs: [usize; D],
    seed: u64,
) -> Option<Layout<D>> {
    let base = Layout::new(cells, periodic, procs).ok()?;
    let mut rng = Rng::new(seed);
    let cost: [Profile; D] = std::array::from_fn(|a| Profile {
        start: 0,
        cost: (0..cells[a])
            .map(|_| {
                if rng.below(3) == 0 {
                    0.0
                } else {
                    rng.below(100) as f64
                }
            })
            .collect(),
    });
    Some(base.balanced(&cost))
}

fn layouts2() -> Vec<Layout<2>> {
    let mut v = Vec::new();
    for per in [[false, false], [true, false], [false, true], [true, true]] {
        for (cells, procs) in [
            ([5, 6], [1, 1]),
            ([9, 7], [2, 3]),
            ([4, 4], [2, 2]),
            ([7, 5], [3, 1]),
            ([4, 9], [1, 4]),
            ([11, 5], [3, 2]),
        ] {
            v.push(Layout::new(cells, per, procs).unwrap());
        }
        v.extend(uneven([11, 9], per, [3, 2], 3));
        v.extend(uneven([9, 13], per, [2, 4], 4));
    }
    v
}

fn layouts3() -> Vec<Layout<3>> {
    let mut v = Vec::new();
    for per in [
        [true, false, true],
        [true, true, true],
        [false, false, false],
    ] {
        for (cells, procs) in [
            ([4, 5, 4], [1, 1, 1]),
            ([5, 6, 7], [2, 1, 3]),
            ([4, 4, 5], [2, 2, 1]),
            ([6, 5, 4], [1, 2, 2]),
        ] {
            v.push(Layout::new(cells, per, procs).unwrap());
        }
        v.extend(uneven([7, 5, 9], per, [3, 1, 2], 5));
    }
    v
}

/// Wrapped global node of a block's local node.
fn wrapped<const D: usize>(layout: &Layout<D>, b: &Block<D>, i: usize) -> [usize; D] {
    layout
        .wrap_node(b.global(b.coords(i)))
        .expect("box inside the grid on bounded axes")
}

/// A distinct, exactly representable value per global node.
fn f<const D: usize>(w: [usize; D]) -> f64 {
    let mut v = 1.0;
    for (a, &x) in w.iter().enumerate() {
        v += (x as f64) * 100f64.powi(a as i32);
    }
    v
}

/// How many copies of each global node exist over all ranks' boxes.
fn copies<const D: usize>(layout: &Layout<D>) -> HashMap<[usize; D], usize> {
    let mut m = HashMap::new();
    for r in 0..layout.ranks() {
        let b = Block::new(layout, r);
        for i in 0..b.num_nodes() {
            *m.entry(wrapped(layout, &b, i)).or_insert(0) += 1;
        }
    }
    m
}

/// Every global node of the grid.
fn all_nodes<const D: usize>(layout: &Layout<D>) -> Vec<[usize; D]> {
    let dims: [usize; D] = std::array::from_fn(|a| layout.nodes(a));
    let total: usize = dims.iter().product();
    (0..total)
        .map(|mut i| {
            std::array::from_fn(|a| {
                let c = i % dims[a];
                i /= dims[a];
                c
            })
        })
        .collect()
}

fn on_every_layout(
    check1: impl Fn(&Layout<1>),
    check2: impl Fn(&Layout<2>),
    check3: impl Fn(&Layout<3>),
) {
    layouts1().iter().for_each(check1);
    layouts2().iter().for_each(check2);
    layouts3().iter().for_each(check3);
}

// ---------------------------------------------------------------- ownership

fn check_ownership<const D: usize>(layout: &Layout<D>) {
    let mut owners: HashMap<[usize; D], Vec<usize>> = HashMap::new();
    for r in 0..layout.ranks() {
        let b = Block::new(layout, r);
        for i in 0..b.num_nodes() {
            if b.is_owned(b.coords(i)) {
                owners.entry(wrapped(layout, &b, i)).or_default().push(r);
            }
        }
    }
    let nodes = all_nodes(layout);
    assert_eq!(
        owners.len(),
        nodes.len(),
        "{layout:?}: owned nodes outside the grid"
    );
    for w in nodes {
        assert_eq!(
            owners.get(&w).map(Vec::as_slice),
            Some(&[layout.node_owner(w)][..]),
            "{layout:?}: node {w:?} must have exactly one owner, layout.node_owner"
        );
    }
}

#[test]
fn every_node_has_exactly_one_owner() {
    on_every_layout(check_ownership, check_ownership, check_ownership);
}

// ---------------------------------------------------------------- halo

fn ghost_sum_on<const D: usize>(
    layout: &Layout<D>,
    count: &HashMap<[usize; D], usize>,
    comm: &dyn Communicator,
) {
    let mut b = Block::new(layout, comm.rank());
    let n = b.num_nodes();
    let mut field = vec![0.0; 2 * n];
    for i in 0..n {
        let w = wrapped(layout, &b, i);
        field[2 * i] = 1.0;
        field[2 * i + 1] = f(w);
    }
    b.ghost_sum(comm, &mut field, 2);
    for i in 0..n {
        if b.is_owned(b.coords(i)) {
            let w = wrapped(layout, &b, i);
            let c = count[&w] as f64;
            assert_eq!(field[2 * i], c, "{layout:?} rank {}: node {w:?}", b.rank);
            assert_eq!(field[2 * i + 1], c * f(w), "{layout:?}: node {w:?}");
        }
    }
}

/// After a ghost sum, each owned node holds one contribution per copy of it in any box:
/// corners, edges and periodic images (of itself, too) are all counted exactly once.
fn check_ghost_sum<const D: usize>(layout: &Layout<D>) {
    let count = copies(layout);
    LocalComm::run(layout.ranks(), |comm| ghost_sum_on(layout, &count, comm));
    if layout.ranks() == 1 {
        ghost_sum_on(layout, &count, &SerialComm);
    }
}

#[test]
fn ghost_sum_counts_every_copy() {
    on_every_layout(check_ghost_sum, check_ghost_sum, check_ghost_sum);
}

/// The ghost sum of slots 1..3 of 4-number records: those slots as `ghost_sum` of a
/// field of their own leaves them (the same bits), the other two untouched.
fn check_ghost_sum_slots<const D: usize>(layout: &Layout<D>) {
    LocalComm::run(layout.ranks(), |comm| {
        let mut b = Block::new(layout, comm.rank());
        let n = b.num_nodes();
        let node: Vec<f64> = (0..n).map(|i| f(wrapped(layout, &b, i))).collect();
        let value = |i: usize, c: usize| node[i] * (c as f64 + 0.5);
        let mut rec: Vec<f64> = (0..4 * n).map(|k| value(k / 4, k % 4)).collect();
        let mut own: Vec<f64> = (0..2 * n).map(|k| value(k / 2, 1 + k % 2)).collect();
        b.ghost_sum_slots(comm, &mut rec, 4, 1..3);
        b.ghost_sum(comm, &mut own, 2);
        for i in 0..n {
            for c in [0, 3] {
                assert_eq!(
                    rec[4 * i + c],
                    value(i, c),
                    "{layout:?}: slot {c} of node {i}"
                );
            }
            for c in 0..2 {
                assert_eq!(rec[4 * i + 1 + c].to_bits(), own[2 * i + c].to_bits());
            }
        }
    });
}

#[test]
fn ghost_sum_of_slots_is_that_of_their_own_field() {
    on_every_layout(
        check_ghost_sum_slots,
        check_ghost_sum_slots,
        check_ghost_sum_slots,
    );
}

fn ghost_copy_on<const D: usize>(layout: &Layout<D>, comm: &dyn Communicator) {
    let mut b = Block::new(layout, comm.rank());
    let n = b.num_nodes();
    let mut field = vec![f64::NAN; 3 * n];
    for i in 0..n {
        if b.is_owned(b.coords(i)) {
            let v = f(wrapped(layout, &b, i));
            field[3 * i..3 * i + 3].copy_from_slice(&[v, -v, 0.5 * v]);
        }
    }
    // Twice: the second call must reuse the buffers and give the same.
    for _ in 0..2 {
        b.ghost_copy(comm, &mut field, 3);
        for i in 0..n {
            let v = f(wrapped(layout, &b, i));
            assert_eq!(
                &field[3 * i..3 * i + 3],
                &[v, -v, 0.5 * v],
                "{layout:?} rank {}: local node {:?}",
                b.rank,
                b.coords(i)
            );
        }
    }
}

/// The ghost copy of slots 1..3 of 4-number records: the ghosts' slots as
/// `ghost_copy` of a field of their own gives them, the other two untouched.
fn check_ghost_copy_slots<const D: usize>(layout: &Layout<D>) {
    LocalComm::run(layout.ranks(), |comm| {
        let mut b = Block::new(layout, comm.rank());
        let n = b.num_nodes();
        let node: Vec<f64> = (0..n).map(|i| f(wrapped(layout, &b, i))).collect();
        let value = |i: usize, c: usize| node[i] * (c as f64 + 0.5);
        let mut rec = vec![f64::NAN; 4 * n];
        let mut own = vec![f64::NAN; 2 * n];
        for i in 0..n {
            for c in [0, 3] {
                rec[4 * i + c] = -(i as f64);
            }
            if b.is_owned(b.coords(i)) {
                for c in 1..3 {
                    rec[4 * i + c] = value(i, c);
                    own[2 * i + c - 1] = value(i, c);
                }
            }
        }
        b.ghost_copy_slots(comm, &mut rec, 4, 1..3);
        b.ghost_copy(comm, &mut own, 2);
        for i in 0..n {
            for c in [0, 3] {
                assert_eq!(
                    rec[4 * i + c],
                    -(i as f64),
                    "{layout:?}: slot {c} of node {i}"
                );
            }
            for c in 1..3 {
                assert_eq!(
                    rec[4 * i + c],
                    value(i, c),
                    "{layout:?}: slot {c} of node {i}"
                );
                assert_eq!(rec[4 * i + c].to_bits(), own[2 * i + c - 1].to_bits());
            }
        }
    });
}

#[test]
fn ghost_copy_of_slots_is_that_of_their_own_field() {
    on_every_layout(
        check_ghost_copy_slots,
        check_ghost_copy_slots,
        check_ghost_copy_slots,
    );
}

fn check_ghost_copy<const D: usize>(layout: &Layout<D>) {
    LocalComm::run(layout.ranks(), |comm| ghost_copy_on(layout, comm));
    if layout.ranks() == 1 {
        ghost_copy_on(layout, &SerialComm);
    }
}

#[test]
fn ghost_copy_fills_every_ghost() {
    on_every_layout(check_ghost_copy, check_ghost_copy, check_ghost_copy);
}

// ---------------------------------------------------------------- rank-count identity

/// A particle-to-grid scatter reaching one node past the particle's cell on each side
/// (as MPMCG's wider support does), with per-axis weights summing to one.
fn scatter<const D: usize>(x: [f64; D], mut add: impl FnMut([i64; D], f64)) {
    let cell: [i64; D] = std::array::from_fn(|a| x[a].floor() as i64);
    let w: [[f64; 4]; D] = std::array::from_fn(|a| {
        let t = x[a] - x[a].floor();
        [0.25 * (1.0 - t), 0.75 * (1.0 - t), 0.75 * t, 0.25 * t]
    });
    let mut k = [0usize; D];
    loop {
        let node: [i64; D] = std::array::from_fn(|a| cell[a] - 1 + k[a] as i64);
        add(node, (0..D).map(|a| w[a][k[a]]).product());
        let mut a = 0;
        while a < D {
            k[a] += 1;
            if k[a] < 4 {
                break;
            }
            k[a] = 0;
            a += 1;
        }
        if a == D {
            return;
        }
    }
}

fn particles<const D: usize>(cells: [usize; D], n: usize, seed: u64) -> Vec<([f64; D], f64)> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let x = std::array::from_fn(|a| rng.f64() * cells[a] as f64);
            (x, 0.5 + rng.f64())
        })
        .collect()
}

/// The same scatter, ghost-summed on 1, 2, 3, 4 and 6 ranks, gives every node the
/// serial value to round-off, and the sum over owned nodes equals the serial total.
fn check_rank_count_identity<const D: usize>(cells: [usize; D], periodic: [bool; D]) {
    let parts = particles(cells, 300, 11);
    let probe = Layout::new(cells, periodic, [1; D]).unwrap();
    let mut serial: HashMap<[usize; D], f64> = HashMap::new();
    for (x, m) in &parts {
        scatter(*x, |node, w| {
            if let Some(g) = probe.wrap_node(node) {
                *serial.entry(g).or_insert(0.0) += m * w;
            }
        });
    }
    let total: f64 = all_nodes(&probe)
        .iter()
        .map(|g| serial.get(g).unwrap_or(&0.0))
        .sum();
    for ranks in [1, 2, 3, 4, 6] {
        let Ok(layout) = Layout::choose(cells, periodic, ranks) else {
            continue;
        };
        let sums = LocalComm::run(ranks, |comm| {
            let mut b = Block::new(&layout, comm.rank());
            let mut field = vec![0.0; b.num_nodes()];
            for (x, m) in &parts {
                let cell: [usize; D] = std::array::from_fn(|a| x[a].floor() as usize);
                if layout.cell_owner(cell) != comm.rank() {
                    continue;
                }
                scatter(*x, |node, w| {
                    if layout.wrap_node(node).is_none() {
                        return; // past a bounded boundary, as in the serial scatter
                    }
                    let local: [usize; D] =
                        std::array::from_fn(|a| (node[a] - b.node_lo[a]) as usize);
                    assert!(
                        (0..D).all(|a| local[a] < b.node_dims[a]),
                        "scatter left the box"
                    );
                    field[b.index(local)] += m * w;
                });
            }
            b.ghost_sum(comm, &mut field, 1);
            let mut sum = [0.0];
            for i in 0..b.num_nodes() {
                if b.is_owned(b.coords(i)) {
                    let w = wrapped(&layout, &b, i);
                    let s = serial.get(&w).copied().unwrap_or(0.0);
                    assert!(
                        (field[i] - s).abs() <= 1e-12 * s.abs().max(1.0),
                        "{layout:?}: node {w:?}: {} vs serial {s}",
                        field[i]
                    );
                    sum[0] += field[i];
                }
            }
            comm.sum_f64(&mut sum);
            sum[0]
        });
        assert!(
            sums.iter().all(|s| s.to_bits() == sums[0].to_bits()),
            "ranks disagree"
        );
        assert!(
            (sums[0] - total).abs() <= 1e-12 * total,
            "{layout:?}: {} vs serial {total}",
            sums[0]
        );
    }
}

#[test]
fn owned_sum_of_ghost_summed_field_matches_serial() {
    check_rank_count_identity([12], [false]);
    check_rank_count_identity([12], [true]);
    check_rank_count_identity([12, 9], [true, false]);
    check_rank_count_identity([8, 12], [false, false]);
    check_rank_count_identity([6, 6, 6], [true, false, true]);
    check_rank_count_identity([6, 8, 4], [true, true, true]);
}

// ---------------------------------------------------------------- Layout::choose

#[test]
fn choose_minimises_ghost_volume() {
    let procs = |cells: [usize; 2], per, n| Layout::choose(cells, per, n).unwrap().procs;
    assert_eq!(procs([64, 64], [false, false], 4), [2, 2]);
    assert_eq!(procs([64, 64], [true, true], 4), [2, 2]);
    assert_eq!(procs([256, 16], [false, false], 4), [4, 1]);
    assert_eq!(procs([16, 256], [false, false], 4), [1, 4]);
    assert_eq!(procs([60, 40], [false, false], 6), [3, 2]);
    // Splitting the bounded axis exchanges one face per cut, the periodic one two per
    // block (the periodic images of a one-block axis are a local copy).
    assert_eq!(procs([100, 100], [true, false], 2), [1, 2]);
    // Ties go to splitting the first axis.
    assert_eq!(procs([10, 10], [false, false], 2), [2, 1]);
    assert_eq!(
        Layout::choose([32, 32, 32], [false; 3], 8).unwrap().procs,
        [2, 2, 2]
    );
    assert_eq!(Layout::choose([7], [true], 3).unwrap().procs, [3]);
    assert_eq!(
        Layout::choose([64, 64], [false; 2], 1).unwrap().procs,
        [1, 1]
    );
}

#[test]
fn choose_and_new_reject_impossible_grids() {
    assert_eq!(
        Layout::choose([8, 8], [false; 2], 17),
        Err(Error::TooManyRanks {
            ranks: 17,
            cells: vec![8, 8]
        })
    );
    assert!(matches!(
        Layout::choose([4, 4], [true; 2], 5),
        Err(Error::TooManyRanks { .. })
    ));
    assert_eq!(Layout::choose([4, 4], [true; 2], 4).unwrap().procs, [2, 2]);
    assert_eq!(Layout::choose([8], [false], 0), Err(Error::NoRanks));
    assert!(matches!(
        Layout::new([8, 5], [false; 2], [2, 3]),
        Err(Error::BlocksTooSmall { axis: 1, .. })
    ));
    assert!(Layout::new([8, 5], [false; 2], [0, 1]).is_err());
}

// ---------------------------------------------------------------- migration

/// Cell of particle `id` after `step` moves: each move is up to GHOST cells along every
/// axis (so diagonal and across periodic faces), kept inside bounded axes. Returned
/// unwrapped relative to the previous (wrapped) cell, as a solver would compute it.
fn moved<const D: usize>(layout: &Layout<D>, from: [usize; D], id: u64, step: u64) -> [i64; D] {
    let mut rng = Rng::new(id * 7919 + step * 104_729 + 1);
    std::array::from_fn(|a| {
        let c = from[a] as i64 + rng.int(-(GHOST as i64), GHOST as i64);
        if layout.periodic[a] {
            c
        } else {
            c.clamp(0, layout.cells[a] as i64 - 1)
        }
    })
}

/// Random particles on every rank but `empty` move for a few steps; after each
/// migration every particle sits on the owner of its cell, none is lost or duplicated,
/// and records arrive ordered by source rank, then send order.
fn check_migration<const D: usize>(layout: &Layout<D>, empty: Option<usize>, seed: u64) {
    let ranks = layout.ranks();
    let nparts = 40 * ranks as u64;
    let mut rng = Rng::new(seed);
    let start: Vec<(u64, [usize; D])> = (0..nparts)
        .filter_map(|id| {
            let cell: [usize; D] = std::array::from_fn(|a| rng.below(layout.cells[a]));
            (Some(layout.cell_owner(cell)) != empty).then_some((id, cell))
        })
        .collect();
    let steps = 4;
    // Record: id, source rank, cell (unwrapped).
    let width = 2 + D;
    let finals = LocalComm::run(ranks, |comm| {
        let me = comm.rank();
        let block = Block::new(layout, me);
        let mut mig = Migrator::new(layout, &block, width);
        let mut mine: Vec<(u64, [usize; D])> = start
            .iter()
            .copied()
            .filter(|(_, c)| layout.cell_owner(*c) == me)
            .collect();
        if Some(me) == empty {
            assert!(mine.is_empty());
        }
        let mut rec = vec![0.0; width];
        for step in 0..steps {
            let mut kept = Vec::new();
            let mut sent = Vec::new();
            for &(id, cell) in &mine {
                let to = moved(layout, cell, id, step);
                let d = mig.destination(to).unwrap();
                // Wrapping first must not change the answer.
                let w: [i64; D] = std::array::from_fn(|a| d.cell[a] as i64);
                assert_eq!(mig.destination(w), Ok(d));
                assert_eq!(d.rank, layout.cell_owner(d.cell));
                if d.rank == me {
                    kept.push((id, d.cell));
                } else {
                    assert!(
                        block.peers().contains(&d.rank),
                        "destination not a halo peer"
                    );
                    rec[0] = id as f64;
                    rec[1] = me as f64;
                    for a in 0..D {
                        rec[2 + a] = to[a] as f64;
                    }
                    mig.push(d.rank, &rec);
                    sent.push(id);
                }
            }
            assert_eq!(mig.queued(), sent.len());
            let arrived = mig.exchange(comm).unwrap();
            assert_eq!(arrived.len() * width, arrived.as_slice().len());
            let mut last: Option<(usize, u64)> = None;
            for r in arrived {
                let (id, src) = (r[0] as u64, r[1] as usize);
                assert_ne!(src, me);
                // Sources ascending; within one source, its send order (ids ascending,
                // as every rank walks its particles in id order).
                if let Some((s, i)) = last {
                    assert!(src > s || (src == s && id > i), "delivery order");
                }
                last = Some((src, id));
                let cell: [usize; D] = std::array::from_fn(|a| {
                    (r[2 + a] as i64).rem_euclid(layout.cells[a] as i64) as usize
                });
                assert_eq!(layout.cell_owner(cell), me, "arrived at the wrong rank");
                kept.push((id, cell));
            }
            kept.sort_by_key(|p| p.0);
            mine = kept;
            // No particle lost or duplicated after this step.
            let mut count = vec![0u64; nparts as usize];
            for (id, _) in &mine {
                count[*id as usize] += 1;
            }
            comm.sum_u64(&mut count);
            for (id, _) in &start {
                assert_eq!(count[*id as usize], 1, "particle {id} after step {step}");
            }
            assert_eq!(count.iter().sum::<u64>(), start.len() as u64);
        }
        mine
    });
    let mut ids: Vec<u64> = finals.iter().flatten().map(|p| p.0).collect();
    ids.sort_unstable();
    let mut want: Vec<u64> = start.iter().map(|p| p.0).collect();
    want.sort_unstable();
    assert_eq!(ids, want, "{layout:?}: multiset of ids");
}

fn check_migration_all<const D: usize>(layout: &Layout<D>) {
    check_migration(layout, None, 5);
    check_migration(layout, Some(0), 6);
    check_migration(layout, Some(layout.ranks() - 1), 7);
}

#[test]
fn migration_delivers_every_particle_to_its_owner() {
    on_every_layout(
        check_migration_all,
        check_migration_all,
        check_migration_all,
    );
}

#[test]
fn migration_on_one_rank_wraps_through_periodic_faces() {
    let layout = Layout::new([6, 5], [true, false], [1, 1]).unwrap();
    let block = Block::new(&layout, 0);
    let mut mig = Migrator::new(&layout, &block, 1);
    let d = mig.destination([-1, 4]).unwrap();
    assert_eq!((d.rank, d.cell), (0, [5, 4]));
    assert_eq!(mig.destination([7, 0]).unwrap().cell, [1, 0]);
    mig.push(0, &[3.0]);
    let got: Vec<&[f64]> = mig.exchange(&SerialComm).unwrap().into_iter().collect();
    assert_eq!(got, vec![&[3.0][..]]);
    assert!(mig.exchange(&SerialComm).unwrap().is_empty());
    assert!(matches!(
        mig.destination([2, 5]),
        Err(Error::OutsideGrid { rank: 0, .. })
    ));
}

#[test]
fn particle_too_fast_is_named_and_reaches_every_rank() {
    // 1D bounded, blocks [0,6) and [6,12): rank 1 may reach cells 4..12.
    let layout = Layout::new([12], [false], [2]).unwrap();
    let out = LocalComm::run(2, |comm| {
        let block = Block::new(&layout, comm.rank());
        let mut mig = Migrator::new(&layout, &block, 1);
        if comm.rank() == 1 {
            assert_eq!(mig.destination([4]).unwrap().rank, 0);
            match mig.destination([3]) {
                Err(e) => mig.fail(e),
                Ok(_) => panic!("a 3-cell move must fail"),
            }
        } else {
            mig.push(1, &[1.0]); // dropped: nothing is exchanged after an error
        }
        let first = mig.exchange(comm).map(|r| r.len());
        // The failure does not stick: the next step exchanges normally.
        let second = mig.exchange(comm).map(|r| r.len());
        (first, second)
    });
    assert_eq!(
        out[1].0,
        Err(Error::ParticleTooFast {
            rank: 1,
            cell: vec![3],
            lo: vec![6],
            hi: vec![12]
        })
    );
    assert_eq!(out[0].0, Err(Error::MigrationFailedElsewhere { rank: 1 }));
    assert_eq!(out[0].1, Ok(0));
    assert_eq!(out[1].1, Ok(0));
    let msg = out[1].0.clone().unwrap_err().to_string();
    assert!(msg.contains("rank 1") && msg.contains("[3]"), "{msg}");
}

#[test]
fn too_fast_and_outside_grid_in_2d_and_across_periodic_faces() {
    let layout = Layout::new([12, 8], [true, false], [3, 2]).unwrap();
    let block = Block::new(&layout, 0); // cells [0,4) x [0,4)
    let mig = Migrator::new(&layout, &block, 1);
    // Diagonal by two cells, across the periodic face: fine.
    let d = mig.destination([-2, 5]).unwrap();
    assert_eq!(d.cell, [10, 5]);
    assert_eq!(d.rank, layout.cell_owner([10, 5]));
    // Three cells: too fast, whichever image is given.
    for cell in [[-3, 0], [9, 0], [7, 0], [0, 6]] {
        assert!(
            matches!(
                mig.destination(cell),
                Err(Error::ParticleTooFast { rank: 0, .. })
            ),
            "{cell:?}"
        );
    }
    assert!(matches!(
        mig.destination([0, -1]),
        Err(Error::OutsideGrid { rank: 0, .. })
    ));
    assert!(matches!(
        mig.destination([0, 8]),
        Err(Error::OutsideGrid { .. })
    ));
}

#[test]
#[should_panic(expected = "not a migration peer")]
fn pushing_to_a_non_peer_panics() {
    let layout = Layout::new([20], [false], [5]).unwrap();
    let block = Block::new(&layout, 0);
    let mut mig = Migrator::new(&layout, &block, 1);
    mig.push(4, &[0.0]);
}

// ---------------------------------------------------------------- LocalComm

#[test]
fn local_collectives_are_deterministic_and_complete() {
    let out = LocalComm::run(4, |c| {
        let r = c.rank();
        assert_eq!(c.size(), 4);
        // Order matters for these values; every rank must get the rank-order sum.
        let mut x = [[1e16, 1.0, -1e16, 1.0][r], r as f64];
        c.sum_f64(&mut x);
        let mut mx = [r as f64, -(r as f64)];
        c.max_f64(&mut mx);
        let mut mn = [r as f64, -(r as f64)];
        c.min_f64(&mut mn);
        let mut u = [r as u64 + 1, 10];
        c.sum_u64(&mut u);
        let scan = c.exclusive_scan_u64(r as u64 + 1);
        let any = (c.any(r == 2), c.any(false));
        let gathered = c.gather_bytes(&vec![r as u8; r]);
        let bcast = c.broadcast_bytes(if r == 0 { b"hello" } else { b"ignored" });
        (x, mx, mn, u, scan, any, gathered, bcast)
    });
    let rank_order = ((1e16 + 1.0) + -1e16) + 1.0;
    for (r, (x, mx, mn, u, scan, any, gathered, bcast)) in out.into_iter().enumerate() {
        assert_eq!(x[0].to_bits(), f64::to_bits(rank_order));
        assert_eq!(x[1], 6.0);
        assert_eq!(mx, [3.0, 0.0]);
        assert_eq!(mn, [0.0, -3.0]);
        assert_eq!(u, [10, 40]);
        assert_eq!(scan, (r * (r + 1) / 2) as u64);
        assert_eq!(any, (true, false));
        if r == 0 {
            assert_eq!(gathered, vec![vec![], vec![1], vec![2, 2], vec![3, 3, 3]]);
        } else {
            assert!(gathered.is_empty());
        }
        assert_eq!(bcast, b"hello");
    }
}

#[test]
fn local_exchange_matches_messages_in_order() {
    // A ring with a self-peer, messages of varying lengths, many rounds.
    let n = 3;
    LocalComm::run(n, |c| {
        let r = c.rank();
        let peers = [(r + n - 1) % n, r, (r + 1) % n];
        let mut peers_sorted = peers.to_vec();
        peers_sorted.sort_unstable();
        let mut recvs = vec![Vec::new(); 3];
        for round in 0..50 {
            let sends: Vec<Vec<f64>> = peers_sorted
                .iter()
                .map(|&p| vec![(r * 1000 + p * 10 + round) as f64; (round + r + p) % 5])
                .collect();
            c.exchange(&peers_sorted, &sends, &mut recvs);
            for (k, &p) in peers_sorted.iter().enumerate() {
                let want = vec![(p * 1000 + r * 10 + round) as f64; (round + r + p) % 5];
                assert_eq!(recvs[k], want, "rank {r} from {p} round {round}");
            }
        }
    });
}

#[test]
fn local_run_returns_results_in_rank_order() {
    assert_eq!(
        LocalComm::run(5, |c| c.rank() * 10),
        vec![0, 10, 20, 30, 40]
    );
    assert!(LocalComm::run(0, |c| c.rank()).is_empty());
}

#[test]
#[should_panic(expected = "boom")]
fn a_panicking_rank_releases_the_others_in_a_collective() {
    LocalComm::run(3, |c| {
        if c.rank() == 1 {
            panic!("boom");
        }
        let mut x = [1.0];
        c.sum_f64(&mut x);
    });
}

#[test]
#[should_panic(expected = "boom")]
fn a_panicking_rank_releases_the_others_in_an_exchange() {
    LocalComm::run(2, |c| {
        if c.rank() == 1 {
            panic!("boom");
        }
        let mut recv = vec![Vec::new()];
        c.exchange(&[1], &[vec![1.0]], &mut recv);
    });
}

// ---------------------------------------------------------------- cuts

/// Balanced cuts give each block of an axis the same share of the cost, to within
/// the cost of one cell slab (the cuts fall on slab boundaries), keep blocks at least
/// the minimum width, and the owner of every cell is the block whose range holds it;
/// with unequal shares each block gets its fraction of the cost, to the same slab.
#[test]
fn balanced_cuts_share_the_cost() {
    let mut rng = Rng::new(11);
    for case in 0..200 {
        let cells = 8 + rng.below(60);
        let procs = 1 + rng.below(cells / GHOST).min(7);
        let periodic = rng.below(2) == 0;
        let base = Layout::new([cells], [periodic], [procs]).unwrap();
        // A body somewhere: zero cost outside [lo, hi).
        let lo = rng.below(cells);
        let hi = lo + 1 + rng.below(cells - lo);
        let cost: Vec<f64> = (0..cells)
            .map(|i| {
                if (lo..hi).contains(&i) {
                    1.0 + rng.below(4) as f64
                } else {
                    0.0
                }
            })
            .collect();
        let whole = Profile {
            start: 0,
            cost: cost.clone(),
        };
        let l = base.balanced(std::array::from_ref(&whole));
        // The body's slabs alone, the empty ones left out, give the same cuts.
        let body = Profile {
            start: lo,
            cost: cost[lo..hi].to_vec(),
        };
        assert_eq!(base.balanced(&[body]), l, "case {case}");
        let c = l.cuts(0);
        let min = if procs > 1 || periodic { GHOST } else { 1 };
        assert!(
            c.windows(2).all(|w| w[1] >= w[0] + min),
            "case {case}: {c:?}"
        );
        let total: f64 = cost.iter().sum();
        let biggest = cost.iter().cloned().fold(0.0, f64::max);
        // Where the minimum width does not bind, each share is within one slab's cost
        // of the mean (a cut rounds to the nearest slab boundary on either side).
        if (hi - lo) >= procs * (min + 1) && lo >= min * procs && cells - hi >= min * procs {
            for k in 0..procs {
                let share: f64 = cost[c[k]..c[k + 1]].iter().sum();
                assert!(
                    (share - total / procs as f64).abs() <= biggest + 1e-9,
                    "case {case}: block {k} has {share} of {total} (cuts {c:?})"
                );
            }
        }
        for i in 0..cells {
            let k = l.cell_owner([i]);
            assert!(
                c[k] <= i && i < c[k + 1],
                "case {case}: cell {i} -> block {k}"
            );
        }
        // Unequal shares: each block's cost is within one slab's of its share of the
        // total where the minimum width does not bind.
        let shares: Vec<f64> = (0..procs).map(|_| 1.0 + rng.below(4) as f64).collect();
        let all: f64 = shares.iter().sum();
        let u = base.balanced_shares(std::array::from_ref(&whole), std::array::from_ref(&shares));
        let c = u.cuts(0);
        assert!(c.windows(2).all(|w| w[1] >= w[0] + min));
        let least = shares.iter().cloned().fold(f64::INFINITY, f64::min);
        let width = (total * least / all / biggest).floor() as usize;
        if width > min && lo >= min * procs && cells - hi >= min * procs {
            for k in 0..procs {
                let got: f64 = cost[c[k]..c[k + 1]].iter().sum();
                let want = total * shares[k] / all;
                assert!(
                    (got - want).abs() <= biggest + 1e-9,
                    "case {case}: block {k} has {got}, its share {want} (shares {shares:?}, cuts {c:?})"
                );
            }
        }
    }
}

/// Cuts that are not ascending, do not span the axis, or leave a block narrower than
/// its ghost layer are refused with the error that names them.
#[test]
fn bad_cuts_are_refused() {
    let l = Layout::new([10, 6], [false, true], [2, 2]).unwrap();
    assert!(l.with_cuts([vec![0, 3, 10], vec![0, 2, 6]]).is_ok());
    for (cuts, axis) in [
        ([vec![0, 1, 10], vec![0, 3, 6]], 0),
        ([vec![0, 5, 9], vec![0, 3, 6]], 0),
        ([vec![0, 5], vec![0, 3, 6]], 0),
        ([vec![0, 5, 10], vec![0, 5, 6]], 1),
        ([vec![1, 5, 10], vec![0, 3, 6]], 0),
    ] {
        match l.with_cuts(cuts.clone()) {
            Err(Error::BadCuts { axis: a, min, .. }) => {
                assert_eq!((a, min), (axis, GHOST), "{cuts:?}")
            }
            other => panic!("{cuts:?}: {other:?}"),
        }
    }
}

/// A rebalance's migration: every particle goes from its owner under one layout to
/// its owner under another, whether or not the two ranks are halo peers; none is lost
/// or duplicated, and records arrive ordered by source rank.
#[test]
fn migration_to_any_rank_follows_the_new_cuts() {
    let old = Layout::new([24, 8], [false, true], [4, 1]).unwrap();
    // Everything moves: the new blocks are far from the old ones' halos.
    let new = old.with_cuts([vec![0, 2, 4, 6, 24], vec![0, 8]]).unwrap();
    let mut rng = Rng::new(5);
    let parts: Vec<(u64, [usize; 2])> = (0..300)
        .map(|id| (id, [rng.below(24), rng.below(8)]))
        .collect();
    let got = LocalComm::run(4, |comm| {
        let me = comm.rank();
        let block = Block::new(&old, me);
        let mut mig = Migrator::everywhere(&new, &block, 3);
        let mut kept = Vec::new();
        for &(id, c) in parts.iter().filter(|(_, c)| old.cell_owner(*c) == me) {
            let to = new.cell_owner(c);
            if to == me {
                kept.push(id);
            } else {
                mig.push(to, &[id as f64, c[0] as f64, c[1] as f64]);
            }
        }
        let recs = mig.exchange(comm).unwrap();
        let mut last_src = 0;
        for r in recs.iter() {
            let c = [r[1] as usize, r[2] as usize];
            assert_eq!(new.cell_owner(c), me, "record sent to the wrong rank");
            let src = old.cell_owner(c);
            assert!(src >= last_src, "records not ordered by source rank");
            last_src = src;
            kept.push(r[0] as u64);
        }
        kept
    });
    let mut all: Vec<u64> = got.iter().flatten().copied().collect();
    all.sort_unstable();
    assert_eq!(
        all,
        (0..300).collect::<Vec<_>>(),
        "lost or duplicated particles"
    );
    for (r, ids) in got.iter().enumerate() {
        for id in ids {
            assert_eq!(new.cell_owner(parts[*id as usize].1), r);
        }
    }
}

// ---------------------------------------------------------------- sparse halo

/// Linear-hat weights of a point `x` (cell units) on its cell's corner nodes: the
/// corners as global (unwrapped) nodes and their weights.
fn corners<const D: usize>(x: [f64; D]) -> Vec<([i64; D], f64)> {
    (0..1usize << D)
        .map(|q| {
            let mut w = 1.0;
            let node: [i64; D] = std::array::from_fn(|a| {
                let c = x[a].floor();
                let xi = x[a] - c;
                let up = (q >> a) & 1 == 1;
                w *= if up { xi } else { 1.0 - xi };
                c as i64 + i64::from(up)
            });
            (node, w)
        })
        .collect()
}

/// The particles (position in cell units, mass) of each round: a cluster 5 cells wide
/// somewhere (across block boundaries and periodic faces when it falls there), the same
/// cluster thinned out (nodes lose their mass while their tiles may stay stored), and
/// the cluster moved by up to two cells per axis.
fn cluster_rounds<const D: usize>(layout: &Layout<D>, seed: u64) -> Vec<Vec<([f64; D], f64)>> {
    let mut rng = Rng::new(seed);
    let lo: [usize; D] = std::array::from_fn(|a| rng.below(layout.cells[a]));
    cluster_rounds_at(layout, lo, &mut rng)
}

/// [`cluster_rounds`] with the cluster's lower corner at cell `lo`.
fn cluster_rounds_at<const D: usize>(
    layout: &Layout<D>,
    lo: [usize; D],
    rng: &mut Rng,
) -> Vec<Vec<([f64; D], f64)>> {
    let lo: [f64; D] = lo.map(|c| c as f64);
    let shift: [f64; D] = std::array::from_fn(|_| rng.int(-2, 2) as f64);
    let pts: Vec<([f64; D], f64)> = (0..30)
        .map(|_| {
            let x = std::array::from_fn(|a| {
                let span = (layout.cells[a] as f64 - 1e-9).min(5.0);
                lo[a] + rng.below(1000) as f64 / 1000.0 * span
            });
            (x, 1.0 + rng.below(7) as f64)
        })
        .collect();
    let wrap = |x: [f64; D]| -> Option<[f64; D]> {
        let mut y = x;
        for a in 0..D {
            let n = layout.cells[a] as f64;
            if layout.periodic[a] {
                y[a] = x[a].rem_euclid(n);
            } else if !(0.0..n).contains(&x[a]) {
                return None;
            }
        }
        Some(y)
    };
    let first: Vec<_> = pts
        .iter()
        .filter_map(|(x, m)| wrap(*x).map(|y| (y, *m)))
        .collect();
    let second: Vec<_> = pts
        .iter()
        .filter_map(|(x, m)| wrap(std::array::from_fn(|a| x[a] + shift[a])).map(|y| (y, *m)))
        .collect();
    // The first round's cluster thinned out: some nodes lose their mass while
    // their tiles may stay stored.
    let thinned: Vec<_> = first.iter().copied().step_by(3).collect();
    vec![first, thinned, second]
}

/// The nodal sums of the points' masses with linear weights, on one rank: what every
/// rank's stored nodes must hold after the ghost sum and copy.
fn serial_sums<const D: usize>(
    layout: &Layout<D>,
    pts: &[([f64; D], f64)],
) -> HashMap<[usize; D], f64> {
    let mut m = HashMap::new();
    for (x, mass) in pts {
        for (g, w) in corners(*x) {
            if let Some(wn) = layout.wrap_node(g) {
                *m.entry(wn).or_insert(0.0) += mass * w;
            }
        }
    }
    m
}

/// Three rounds ([`cluster_rounds`]) of: touch the tiles of this rank's
/// particles' corners, agree on the halo, scatter, ghost sum, ghost copy. After each
/// round every node any rank stores holds the serial sum of its wrapped node (owned
/// and ghost alike, zero where no particle reaches, including ghosts stored for an
/// earlier round), every node with a nonzero sum is stored on its owner, and a small
/// cluster stores a few tiles, not the block faces.
fn check_sparse_halo<const D: usize>(layout: &Layout<D>, seed: u64) {
    check_sparse_halo_of(layout, &cluster_rounds(layout, seed));
}

/// [`check_sparse_halo`] for the given rounds of points.
fn check_sparse_halo_of<const D: usize>(layout: &Layout<D>, rounds: &[Vec<([f64; D], f64)>]) {
    let serial: Vec<HashMap<[usize; D], f64>> =
        rounds.iter().map(|pts| serial_sums(layout, pts)).collect();
    LocalComm::run(layout.ranks(), |comm| {
        let me = comm.rank();
        let mut b = Block::new(layout, me);
        let mut tiles = crate::Tiles::<D>::new(b.node_dims, b.own_lo);
        let mut field: Vec<f64> = Vec::new();
        // A field computed on owned nodes and copied to the ghosts (like the grid
        // velocity): kept between rounds and zeroed only when the stored tiles change,
        // as the solver does.
        let mut copied: Vec<f64> = Vec::new();
        for (round, pts) in rounds.iter().enumerate() {
            let mine: Vec<&([f64; D], f64)> = pts
                .iter()
                .filter(|(x, _)| {
                    layout.cell_owner(std::array::from_fn(|a| x[a].floor() as usize)) == me
                })
                .collect();
            let node_lo = b.node_lo;
            let local = |g: [i64; D]| -> [usize; D] {
                std::array::from_fn(|a| (g[a] - node_lo[a]) as usize)
            };
            tiles.begin();
            for (x, _) in &mine {
                // A stencil a node wider than the cell on each side, as the solver's
                // are: a rank then needs ghost nodes below its owned range too.
                let c: [i64; D] = std::array::from_fn(|a| x[a].floor() as i64 - b.node_lo[a]);
                tiles.touch(c.map(|v| v - 1), c.map(|v| v + 2));
            }
            b.activate_halo(comm, &mut tiles);
            if tiles.finish() || round == 0 {
                copied.clear();
                copied.resize(tiles.nodes(), 0.0);
            }
            b.map_active_halo(&tiles);
            field.clear();
            field.resize(tiles.nodes(), 0.0);
            for (x, m) in &mine {
                for (g, w) in corners(*x) {
                    if layout.wrap_node(g).is_some() {
                        let i = tiles
                            .index(local(g))
                            .expect("a particle's nodes are stored");
                        field[i] += m * w;
                    }
                }
            }
            b.ghost_sum(comm, &mut field, 1);
            for slot in 1..tiles.slots() {
                for o in 0..tiles.tile_nodes() {
                    if tiles.local(slot, o).is_some_and(|l| b.is_owned(l)) {
                        let n = slot * tiles.tile_nodes() + o;
                        copied[n] = field[n];
                    }
                }
            }
            b.ghost_copy(comm, &mut copied, 1);
            let field = &copied;
            let mut stored_owned = Vec::new();
            for slot in 1..tiles.slots() {
                for o in 0..tiles.tile_nodes() {
                    let Some(l) = tiles.local(slot, o) else {
                        continue;
                    };
                    let w = layout
                        .wrap_node(b.global(l))
                        .expect("stored nodes lie in the grid");
                    let want = serial[round].get(&w).copied().unwrap_or(0.0);
                    let got = field[slot * tiles.tile_nodes() + o];
                    assert!(
                        (got - want).abs() <= 1e-12 * want.abs().max(1.0),
                        "{layout:?} rank {me} round {round}: node {w:?} holds {got}, serial {want}"
                    );
                    if b.is_owned(l) {
                        stored_owned.push(w);
                    }
                }
            }
            // Every node with mass that this rank owns is stored here.
            for (w, v) in &serial[round] {
                if *v != 0.0 && layout.node_owner(*w) == me {
                    assert!(
                        stored_owned.contains(w),
                        "{layout:?} round {round}: {w:?} not stored"
                    );
                }
            }
            // Sparse: the cluster's tiles and a ring around them, not the faces.
            let cluster_tiles = 3usize.pow(D as u32) * 4usize.pow(D as u32);
            assert!(
                tiles.active() <= cluster_tiles,
                "{layout:?} rank {me}: {} tiles stored",
                tiles.active()
            );
        }
    });
}

#[test]
fn sparse_halo_delivers_every_sum_and_stores_little() {
    let mut seed = 1;
    let mut next = || {
        seed += 1;
        seed
    };
    for l in layouts2() {
        for _ in 0..3 {
            check_sparse_halo(&l, next());
        }
    }
    for l in layouts3() {
        check_sparse_halo(&l, next());
    }
    // Big boxes, where the faces are long: the stored tiles follow the cluster.
    for (cells, per, procs) in [
        ([64, 48], [true, false], [2, 2]),
        ([40, 40], [false, true], [3, 1]),
    ] {
        let l = Layout::new(cells, per, procs).unwrap();
        for _ in 0..4 {
            check_sparse_halo(&l, next());
        }
    }
}

/// A cluster at the corner of four (2D) or eight (3D) blocks of a box 2^30 (2D) or
/// 2^20 (3D) cells per axis: the halo's plan and its work follow the cluster, so the
/// faces' length costs nothing (a list per face node would take gigabytes here).
#[test]
fn sparse_halo_of_a_huge_box_costs_the_cluster() {
    fn at_corner<const D: usize>(cells: usize, periodic: [bool; D], seed: u64) {
        let base = Layout::new([cells; D], periodic, [2; D]).unwrap();
        // The corner at cell 1000 on every axis, so that blocks differ in size.
        let layout = base
            .with_cuts(std::array::from_fn(|_| vec![0, 1000, cells]))
            .unwrap();
        let mut rng = Rng::new(seed);
        let lo: [usize; D] = std::array::from_fn(|_| 997 + rng.below(3));
        check_sparse_halo_of(&layout, &cluster_rounds_at(&layout, lo, &mut rng));
    }
    for seed in 0..4 {
        at_corner::<2>(1 << 30, [false, true], seed);
        at_corner::<3>(1 << 20, [true, false, true], seed);
    }
}
