//! The hard cases of the README ("Hard cases"), each a scene in `inputs/`, run for
//! MPMCG and the schemes it is compared with; every test asserts the stability property
//! and prints what it measured (`cargo test --test hard_cases -- --nocapture`).

#![forbid(unsafe_code)]

mod common;
use common::{history, run_scene, snapshots, Snapshot, POINT_RULE};
use mpmcg::driver::run::RunError;
use std::collections::HashMap;

/// MPMCG at the particle: `text` with `[method]` setting the point rule, no sharpening
/// and no centroid passes, which MPMCG's defaults would otherwise add.
fn at_the_particle(text: &str) -> String {
    let out = text.replacen("[method]", &format!("[method]\n{POINT_RULE}"), 1);
    assert!(out.contains(POINT_RULE), "the scene has a [method] table");
    out
}

fn with_gradient(text: &str, g: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let k = lines
        .iter()
        .position(|l| l.starts_with("gradient = "))
        .expect("the scene names its gradient");
    lines[k] = format!("gradient = \"{g}\"");
    lines.join("\n") + "\n"
}

/// Connectivity of a particle cloud (2D clouds have z = 0): particles closer than `r`
/// are neighbours. Returns the number of connected groups and the largest distance from
/// a particle to its nearest neighbour (capped at `r`: a particle with none closer is
/// cut off). Bins of width `r` make it linear in the particle count.
fn connectivity(x: &[[f64; 3]], r: f64) -> (usize, f64) {
    let key = |p: &[f64; 3]| p.map(|c| (c / r).floor() as i64);
    let mut bins: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in x.iter().enumerate() {
        bins.entry(key(p)).or_default().push(i);
    }
    // Union–find over neighbour pairs.
    let mut parent: Vec<usize> = (0..x.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut max_nn = 0.0f64;
    for (i, p) in x.iter().enumerate() {
        let b = key(p);
        let mut nn = r;
        for o in 0..27 {
            let off = [o % 3 - 1, o / 3 % 3 - 1, o / 9 - 1];
            let k = [b[0] + off[0], b[1] + off[1], b[2] + off[2]];
            for &j in bins.get(&k).map_or(&[][..], |v| v) {
                let d = (0..3).map(|a| (p[a] - x[j][a]).powi(2)).sum::<f64>().sqrt();
                if j != i && d < r {
                    nn = nn.min(d);
                    let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                    parent[a] = b;
                }
            }
        }
        max_nn = max_nn.max(nn);
    }
    let groups = (0..x.len()).filter(|&i| root(&mut parent, i) == i).count();
    (groups, max_nn)
}

/// Cantilever under gravity at 4 × 4 particles per cell: MPMCG's material stays in one
/// piece with no particle farther than a cell from its nearest neighbour, in every
/// snapshot (every 0.05 s for 3 s); the tip deflection history and MPM's figures are
/// printed. (At 2 × 2 and 3 × 3 particles per cell both schemes separate at the clamp:
/// README, Hard cases.)
#[test]
fn cantilever_does_not_separate() {
    let text = include_str!("../inputs/cantilever.toml");
    let h = 0.25;
    for g in ["mpmcg", "mpm"] {
        let (r, out) = run_scene(&with_gradient(text, g), &format!("cantilever-{g}"));
        let s = r.unwrap_or_else(|e| panic!("cantilever {g}: {e}"));
        let snaps = snapshots(&out, Some("displacement"));
        assert!(snaps.len() > 50, "{} snapshots", snaps.len());
        // The tip: the particle nearest the end of the beam's axis.
        let first = &snaps[0];
        let d2 = |p: &[f64; 3]| (p[0] - 4.0).powi(2) + (p[1] - 0.5).powi(2);
        let k = (0..first.x.len())
            .min_by(|&a, &b| d2(&first.x[a]).total_cmp(&d2(&first.x[b])))
            .unwrap();
        let tip = first.id[k];
        let mut worst = (1usize, 0.0f64, 0.0f64);
        let mut deflection = Vec::new();
        for sn in &snaps {
            let (groups, nn) = connectivity(&sn.x, h);
            if (groups, nn) > (worst.0, worst.1) {
                worst = (groups, nn, sn.time);
            }
            let i = sn.id.iter().position(|&i| i == tip).unwrap();
            deflection.push((sn.time, sn.field[i][1]));
        }
        let lowest = deflection.iter().map(|d| d.1).fold(f64::INFINITY, f64::min);
        eprintln!(
            "cantilever {g}: {} particles; largest gap to a nearest neighbour {:.3} cells, {} group(s) (worst at t = {:.2}); tip deflection min {lowest:.3} m; energy drift {:.2e}",
            s.particles, worst.1 / h, worst.0, worst.2, s.energy.max_relative_drift
        );
        let hist: Vec<String> = deflection
            .iter()
            .step_by(6)
            .map(|(t, u)| format!("{t:.2}:{u:.3}"))
            .collect();
        eprintln!("  tip deflection (t:u_y) {}", hist.join(" "));
        if g == "mpmcg" {
            assert_eq!(worst.0, 1, "mpmcg: the beam separated (t = {})", worst.2);
            assert!(worst.1 < h, "mpmcg: a particle was cut off");
            // The beam sags by metres, then swings back up by more than a metre.
            let k = deflection.iter().position(|d| d.1 == lowest).unwrap();
            let rebound = deflection[k..].iter().map(|d| d.1).fold(lowest, f64::max);
            assert!(lowest < -3.0 && rebound > lowest + 1.0, "{hist:?}");
        }
    }
}

/// The cantilever of `inputs/cantilever.toml` with another length, Young's modulus and
/// particles per cell; the grid grows with the length so that the beam can hang down.
fn cantilever_variant(length: f64, youngs: f64, ppc: usize) -> String {
    shifted_cantilever(length, youngs, ppc, 0.0)
}

/// The same with the grid moved up by `shift` (half a cell, 0.125 m, puts the beam's
/// top and bottom faces inside cells instead of on grid lines).
fn shifted_cantilever(length: f64, youngs: f64, ppc: usize, shift: f64) -> String {
    let h = 0.25;
    let text = include_str!("../inputs/cantilever.toml");
    let cells_x = ((length + 1.0) / h).round() as usize;
    let depth = length + 0.5;
    let cells_y = ((depth + 1.5) / h).round() as usize;
    let edits = [
        (
            "youngs_modulus = 1.0e6",
            format!("youngs_modulus = {youngs:e}"),
        ),
        ("upper = [4.0, 1.0]", format!("upper = [{length:.1}, 1.0]")),
        (
            "lower = [0.0, -4.0]",
            format!("lower = [0.0, {:?}]", -depth + shift),
        ),
        (
            "upper = [5.0, 1.5]",
            format!("upper = [{:.1}, {:?}]", length + 1.0, 1.5 + shift),
        ),
        (
            "cells = [20, 22]",
            format!("cells = [{cells_x}, {cells_y}]"),
        ),
        (
            "particles_per_cell = 4",
            format!("particles_per_cell = {ppc}"),
        ),
    ];
    let mut out = text.to_string();
    for (from, to) in edits {
        assert!(out.contains(from), "cantilever.toml has no `{from}`");
        out = out.replacen(from, &to, 1);
    }
    out
}

/// The 3D version of a cantilever scene: 1 m wide (z from 0 to 1) on 8 cells from
/// −0.5 to 1.5, slip faces in z (as `scripts/cantilever_family.sh` makes it).
fn in_3d(text: &str) -> String {
    let mut out = text.replacen("dim = 2", "dim = 3", 1);
    let mut lines = Vec::new();
    for line in out.lines() {
        let l = if let Some(rest) = line.strip_prefix("lower = [") {
            format!("lower = [{}, -0.5]", rest.trim_end_matches(']'))
        } else if let Some(rest) = line.strip_prefix("upper = [") {
            format!("upper = [{}, 1.5]", rest.trim_end_matches(']'))
        } else if let Some(rest) = line.strip_prefix("cells = [") {
            let (list, tail) = rest.split_once(']').expect("cells list");
            format!("cells = [{list}, 8]{tail}")
        } else {
            line.to_string()
        };
        lines.push(l);
    }
    out = lines.join("\n");
    for (from, to) in [
        (
            "y_upper = \"slip\" }",
            "y_upper = \"slip\", z_lower = \"slip\", z_upper = \"slip\" }",
        ),
        ("value = [0.0, -10.0]", "value = [0.0, -10.0, 0.0]"),
        (
            "lower = [0.0, 0.0], upper = [",
            "lower = [0.0, 0.0, 0.0], upper = [",
        ),
        (", 1.0] } }", ", 1.0, 1.0] } }"),
    ] {
        assert!(out.contains(from), "cantilever scene has no `{from}`");
        out = out.replacen(from, to, 1);
    }
    out
}

/// The cantilever family at 3 × 3 particles per cell (h = 0.25 m, 4 cells through the
/// thickness): beams of 3, 4, 5 and 6 m, E = 1–2 MPa, sagging by metres under gravity,
/// stay in one piece under MPMCG at the particle with MUSL in every snapshot (particles closer than a
/// cell are neighbours) and complete, with the beam's faces on grid lines and with the
/// grid shifted by half a cell; so does the 4 m beam in 3D (3 × 3 × 3, both grids).
/// Before particles moved with the reconstruction of MPMCG's nodal averages
/// (`kernel::moving_velocity`) the shifted 5 m beam broke in 4 pieces and the 3D beam
/// in 3 and 6; before the continuous domain weights the aligned 4 m beam broke in two.
/// MPM keeps them all whole too (README, The cantilever family;
/// `scripts/cantilever_family.sh` measures both schemes at 2 × 2 and 3 × 3, USL, a
/// finer grid and a hanging bar).
#[test]
fn cantilever_family_stays_whole_at_3x3() {
    let h = 0.25;
    let mut cases: Vec<(String, String)> = Vec::new();
    for shift in [0.0, 0.125] {
        for (length, youngs) in [(3.0, 2.0e6), (4.0, 1.0e6), (5.0, 1.0e6), (6.0, 2.0e6)] {
            cases.push((
                format!("family-{length}-{youngs:e}-shift{shift}"),
                shifted_cantilever(length, youngs, 3, shift),
            ));
        }
        cases.push((
            format!("family-3d-shift{shift}"),
            in_3d(&shifted_cantilever(4.0, 1.0e6, 3, shift)),
        ));
    }
    for (tag, text) in cases {
        let (r, out) = run_scene(&at_the_particle(&text), &tag);
        let s = r.unwrap_or_else(|e| panic!("{tag}: {e}"));
        let snaps = snapshots(&out, None);
        assert!(snaps.len() > 50, "{} snapshots", snaps.len());
        let mut worst = (1usize, 0.0f64, 0.0f64);
        let mut lowest = f64::INFINITY;
        for sn in &snaps {
            let (groups, nn) = connectivity(&sn.x, h);
            if (groups, nn) > (worst.0, worst.1) {
                worst = (groups, nn, sn.time);
            }
            lowest = sn.x.iter().map(|p| p[1]).fold(lowest, f64::min);
        }
        eprintln!(
            "{tag}, 3x3: {} group(s), largest gap {:.2} cells (t = {:.2}); lowest particle {lowest:.2} m; energy drift {:.2e}",
            worst.0,
            worst.1 / h,
            worst.2,
            s.energy.max_relative_drift
        );
        assert_eq!(worst.0, 1, "{tag}: the beam separated (t = {})", worst.2);
        // A real large-deflection case: the beam hangs metres below its clamp.
        assert!(lowest < -1.0, "{tag}: lowest particle at {lowest}");
    }
}

/// Worst number of pieces over a run's snapshots (particles closer than a cell, `h`,
/// are neighbours).
fn worst_pieces(out: &std::path::Path, h: f64) -> usize {
    snapshots(out, None)
        .iter()
        .map(|sn| connectivity(&sn.x, h).0)
        .max()
        .unwrap_or(0)
}

/// The family at 2 × 2 particles per cell (MUSL, both grids, and the 4 m beam in 3D at
/// 2 × 2 × 2) under MPMCG's defaults (the domain rule, `sharpen = 1`, four centroid
/// passes): every beam whole and its motion kept, the energy balance at 3 s (kinetic +
/// strain − gravity's work) within 5 % of gravity's work (measured −0.2 … +0.7 %).
/// MPMCG at the particle tears the aligned 4 and 5 m beams and the 3D beam at the clamp
/// (its first cell column comes off late in the run); MPM keeps the 4 m beam whole on
/// both grids and the 3D beam, which it broke in 3 and 4 pieces while its particles
/// moved with the grid velocity before MUSL's remap: neighbours then drifted a cell
/// apart while their deformation gradients stayed below 1.6 (docs/hard-cases.md, Why
/// beams tear).
#[test]
fn cantilever_family_at_2x2() {
    let h = 0.25;
    // (tag, scene, whether MPM is run)
    let mut cases: Vec<(String, String, bool)> = Vec::new();
    for shift in [0.0, 0.125] {
        for (length, youngs) in [(3.0, 2.0e6), (4.0, 1.0e6), (5.0, 1.0e6), (6.0, 2.0e6)] {
            cases.push((
                format!("family2-{length}-shift{shift}"),
                shifted_cantilever(length, youngs, 2, shift),
                length == 4.0,
            ));
        }
    }
    cases.push((
        "family2-3d".to_string(),
        in_3d(&shifted_cantilever(4.0, 1.0e6, 2, 0.0)),
        true,
    ));
    for (tag, text, mpm) in cases {
        if mpm {
            let (r, out) = run_scene(&with_gradient(&text, "mpm"), &format!("{tag}-mpm"));
            r.unwrap_or_else(|e| panic!("{tag}, mpm: {e}"));
            let pieces = worst_pieces(&out, h);
            eprintln!("{tag}: mpm {pieces} piece(s)");
            assert_eq!(pieces, 1, "{tag}: MPM separated the beam");
        }
        let (r, out) = run_scene(&with_gradient(&text, "mpmcg"), &format!("{tag}-mpmcg"));
        let s = r.unwrap_or_else(|e| panic!("{tag}, mpmcg: {e}"));
        let pieces = worst_pieces(&out, h);
        let balance = energy_balance(&out);
        eprintln!(
            "{tag}: mpmcg (defaults) {pieces} piece(s) to t = {}, energy balance {:+.2} % of the work",
            s.time,
            100.0 * balance
        );
        assert_eq!(pieces, 1, "{tag}: MPMCG separated the beam");
        assert!((s.time - 3.0).abs() < 1e-9, "{tag}: ended at {}", s.time);
        assert!(
            balance.abs() < 0.05,
            "{tag}: energy balance {balance:.3e} of the work"
        );
    }
}

/// The energy balance at the end of a run (kinetic + strain − the work of gravity) as a
/// share of the largest work done: about 0 for a run that neither gains nor damps.
fn energy_balance(out: &std::path::Path) -> f64 {
    let rows = history(out);
    let work = rows.iter().map(|r| r["external_work"]).fold(0.0, f64::max);
    rows.last().unwrap()["total"] / work
}

/// The three 2 × 2 cells of the family that MPMCG breaks with FLIP and its point rule
/// (the 4 and 5 m beams on the aligned grid, the 3D beam at 2 × 2 × 2) run under MPMCG
/// with `line` added to `[method]`, tags starting with `tag`: per cell its tag, the time
/// it reached, the worst number of pieces over its snapshots and its output folder.
fn run_torn_cells_with(tag: &str, line: &str) -> Vec<(String, f64, usize, std::path::PathBuf)> {
    let cells = [
        ("4", shifted_cantilever(4.0, 1.0e6, 2, 0.0)),
        ("5", shifted_cantilever(5.0, 1.0e6, 2, 0.0)),
        ("3d", in_3d(&shifted_cantilever(4.0, 1.0e6, 2, 0.0))),
    ];
    cells
        .into_iter()
        .map(|(cell, text)| {
            let tag = format!("{tag}-{cell}");
            let text = text.replacen("[method]", &format!("[method]\n{line}"), 1);
            assert!(text.contains(line));
            let (r, out) = run_scene(&with_gradient(&text, "mpmcg"), &tag);
            let s = r.unwrap_or_else(|e| panic!("{tag}: {e}"));
            let pieces = worst_pieces(&out, 0.25);
            (tag, s.time, pieces, out)
        })
        .collect()
}

/// The three 2 × 2 cells of the family that MPMCG at the particle breaks with FLIP (the
/// 4 and 5 m beams on the aligned grid, the 3D beam at 2 × 2 × 2) with `xpic = 2`: whole. What
/// broke them is velocity noise at the clamp's top corner, in the part of the particle
/// velocities the grid cannot see, which FLIP keeps and lets grow (up to 7 m/s at
/// the root by 0.96 s, under MPM too); XPIC removes it every step (README, The
/// cantilever family, which also gives its price: the swing is damped).
#[test]
fn cantilever_family_with_xpic_stays_whole_at_2x2() {
    let line = format!("xpic = 2\n{POINT_RULE}");
    for (tag, time, pieces, _) in run_torn_cells_with("xpic", &line) {
        eprintln!("{tag}: MPMCG with XPIC(2) to t = {time}: {pieces} piece(s)");
        assert_eq!(pieces, 1, "{tag}: MPMCG with XPIC(2) separated the beam");
    }
}

/// The same three cells under MPMCG's domain rule alone (`quadrature = "domain"`, no
/// sharpening, no centroid passes), whose
/// particles move with the reconstruction averaged over the domain their gradient is
/// averaged over: whole, and not damped: the energy balance at 3 s (kinetic + strain −
/// gravity's work) within 3 % of gravity's work (measured −0.5 … +0.9 %; XPIC(2)'s
/// −48 … −54 %). With the move at the particle's centre the domain rule tore all three
/// (2, 2 and 4 pieces): where the domain is cut at the clamp, its centre is not the
/// point whose neighbourhood the gradient describes (docs/hard-cases.md).
#[test]
fn cantilever_family_with_domain_rule_stays_whole_at_2x2() {
    let line = "quadrature = \"domain\"\nsharpen = 0.0\ncentroid_passes = 0";
    for (tag, time, pieces, out) in run_torn_cells_with("domain", line) {
        let balance = energy_balance(&out);
        eprintln!(
            "{tag}: MPMCG, domain rule, to t = {time}: {pieces} piece(s), energy balance {:+.2} % of the work",
            100.0 * balance
        );
        assert_eq!(pieces, 1, "{tag}: MPMCG's domain rule separated the beam");
        assert!(
            balance.abs() < 0.03,
            "{tag}: energy balance {balance:.3e} of the work"
        );
    }
}

/// The same family at 3 × 3 per cell with USL, the update that applies the grid's new
/// velocity without remapping it: nodes that a particle barely touches get a sliver of
/// mass and, under MPM, the full force of that particle's stress gradient, and MPM inverts
/// a particle (J <= 0) on every beam within the first second. MPMCG's averaged part (here
/// at the particle) gives
/// such a node a force in proportion to its fill (the cell weights are the corners'
/// smallest fill), and it completes every beam in one piece (before particles moved
/// with the reconstruction of the nodal averages, the 5 m beam ended in 2 pieces).
#[test]
fn cantilever_family_under_usl_mpmcg_completes_where_mpm_inverts() {
    let h = 0.25;
    for (length, youngs) in [(3.0, 2.0e6), (4.0, 1.0e6), (5.0, 1.0e6), (6.0, 2.0e6)] {
        let text = cantilever_variant(length, youngs, 3).replacen(
            "update = \"musl\"",
            "update = \"usl\"",
            1,
        );
        assert!(text.contains("update = \"usl\""));
        let tag = format!("family-usl-{length}");
        let (mpm, _) = run_scene(&with_gradient(&text, "mpm"), &format!("{tag}-mpm"));
        match mpm {
            Err(RunError::Unstable(m)) => eprintln!("{tag}, mpm: {m}"),
            other => panic!("{tag}: MPM with USL was expected to invert a particle, got {other:?}"),
        }
        let (r, out) = run_scene(&at_the_particle(&text), &format!("{tag}-mpmcg"));
        let s = r.unwrap_or_else(|e| panic!("{tag}, mpmcg: {e}"));
        let snaps = snapshots(&out, None);
        let worst = snaps
            .iter()
            .map(|sn| connectivity(&sn.x, h).0)
            .max()
            .unwrap_or(0);
        eprintln!(
            "{tag}, mpmcg: completed to t = {}, worst {worst} piece(s), energy drift {:.2e}",
            s.time, s.energy.max_relative_drift
        );
        assert!(snaps.len() > 50, "{tag}: {} snapshots", snaps.len());
        assert_eq!(worst, 1, "{tag}: MPMCG with USL separated the beam");
    }
}

/// Total energy lost, as a fraction of the initial kinetic energy, averaged over the
/// last third of the run (a single sample would depend on the phase of the swing).
fn energy_loss(out: &std::path::Path) -> f64 {
    let h = history(out);
    let k0 = h[0]["kinetic"];
    let end = h.last().unwrap()["time"];
    let late: Vec<f64> = h
        .iter()
        .filter(|r| r["time"] >= end * 2.0 / 3.0)
        .map(|r| r["total"])
        .collect();
    1.0 - late.iter().sum::<f64>() / late.len() as f64 / k0
}

/// The beam bent by a prescribed velocity field, at large and at 1 % amplitude: MPMCG
/// keeps the total energy within 1 % of the initial kinetic energy for two periods,
/// and loses less than MPM at both amplitudes (the slides' claim). MPM's largest
/// excursion is reported, not bounded: at large amplitude it sits near the bound (0.79 %
/// with its particles moving with the remapped velocity, 1.01 % before), moved by a
/// tenth by round-off-level changes to its cell crossings.
#[test]
fn bent_beam_energy() {
    for (tag, text) in [
        ("large", include_str!("../inputs/bent_beam.toml")),
        ("small", include_str!("../inputs/bent_beam_small.toml")),
    ] {
        let mut loss = HashMap::new();
        for g in ["mpmcg", "mpm"] {
            let (r, out) = run_scene(&with_gradient(text, g), &format!("beam-{tag}-{g}"));
            r.unwrap_or_else(|e| panic!("beam {tag} {g}: {e}"));
            let h = history(&out);
            let k0 = h[0]["kinetic"];
            let dev = h
                .iter()
                .map(|r| (r["total"] - h[0]["total"]).abs())
                .fold(0.0, f64::max);
            let l = energy_loss(&out);
            eprintln!(
                "bent beam {tag} {g}: energy lost {:.4} % of the initial kinetic energy (last third), largest excursion {:.3} %",
                100.0 * l,
                100.0 * dev / k0
            );
            if g == "mpmcg" {
                assert!(dev < 0.01 * k0, "{tag} {g}: energy excursion {dev} of {k0}");
            }
            loss.insert(g, l);
        }
        assert!(
            loss["mpmcg"] < loss["mpm"],
            "{tag}: MPMCG lost {} vs MPM {}",
            loss["mpmcg"],
            loss["mpm"]
        );
    }
}

/// Relative roughness of the particle velocity field on its lattice: the second
/// difference along each axis between lattice neighbours, `sqrt(Σ|Δ²v|² / Σ|v|²)`.
/// A smooth field gives O((k h)²); the grid's odd–even mode gives O(1). `lattice` maps
/// a particle id to its (i, j) position in the initial particle lattice.
fn roughness(sn: &Snapshot, lattice: &HashMap<i64, (usize, usize)>, n: (usize, usize)) -> f64 {
    let mut v = vec![[0.0; 2]; n.0 * n.1];
    for (k, id) in sn.id.iter().enumerate() {
        let (i, j) = lattice[id];
        v[i * n.1 + j] = [sn.field[k][0], sn.field[k][1]];
    }
    let at = |i: usize, j: usize| v[i * n.1 + j];
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..n.0 {
        for j in 0..n.1 {
            for c in 0..2 {
                den += at(i, j)[c].powi(2);
                if i > 0 && i + 1 < n.0 {
                    num += (at(i + 1, j)[c] - 2.0 * at(i, j)[c] + at(i - 1, j)[c]).powi(2);
                }
                if j > 0 && j + 1 < n.1 {
                    num += (at(i, j + 1)[c] - 2.0 * at(i, j)[c] + at(i, j - 1)[c]).powi(2);
                }
            }
        }
    }
    (num / den).sqrt()
}

/// The averaged gradient (α ≡ 0) at large deformation: its odd–even velocity mode grows
/// by more than two orders of magnitude, until a particle inverts or with a
/// displacement error ten times MPMCG's bound at the end; MPMCG's roughness stays below a quarter of the averaged scheme's
/// and the run completes with a displacement error below 2e-3.
#[test]
fn averaged_zigzag_grows_mpmcg_stays_bounded() {
    let text = include_str!("../inputs/zigzag.toml");
    let mut peak = HashMap::new();
    for g in ["averaged", "mpmcg", "mpm"] {
        let (r, out) = run_scene(&with_gradient(text, g), &format!("zigzag-{g}"));
        let snaps = snapshots(&out, Some("velocity"));
        // The initial lattice: particles sorted by position.
        let first = &snaps[0];
        let coord = |a: usize| {
            let mut c: Vec<f64> = first.x.iter().map(|p| p[a]).collect();
            c.sort_by(f64::total_cmp);
            c.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
            c
        };
        let (cx, cy) = (coord(0), coord(1));
        let find = |c: &[f64], v: f64| c.iter().position(|&u| (u - v).abs() < 1e-9).unwrap();
        let lattice: HashMap<i64, (usize, usize)> = first
            .id
            .iter()
            .zip(&first.x)
            .map(|(&id, p)| (id, (find(&cx, p[0]), find(&cy, p[1]))))
            .collect();
        let n = (cx.len(), cy.len());
        assert_eq!(n.0 * n.1, first.id.len(), "a full lattice");
        let rough: Vec<f64> = snaps.iter().map(|s| roughness(s, &lattice, n)).collect();
        let max = rough.iter().cloned().fold(0.0, f64::max);
        let outcome = match &r {
            Ok(s) => format!(
                "completed, displacement error {:.2e}",
                s.error.as_ref().unwrap().displacement_l2
            ),
            Err(e) => format!("{e}"),
        };
        eprintln!(
            "zigzag {g}: roughness {:.2e} at t = 0, max {max:.2e}; {} snapshots; {outcome}",
            rough[0],
            snaps.len()
        );
        match g {
            "averaged" => {
                // The mode grows until a particle inverts, or the run ends far off the
                // exact solution (with continuous domain weights it may complete).
                let wrecked = match &r {
                    Err(RunError::Unstable(m)) => m.contains("J <= 0"),
                    Ok(s) => s.error.as_ref().unwrap().displacement_l2 > 2e-2,
                    Err(_) => false,
                };
                assert!(wrecked, "averaged: {outcome}");
                assert!(max > 100.0 * rough[0], "averaged: no growth");
            }
            "mpmcg" => {
                let s = r.as_ref().expect("mpmcg completes");
                assert!(
                    s.error.as_ref().unwrap().displacement_l2 < 2e-3,
                    "{outcome}"
                );
            }
            _ => {}
        }
        peak.insert(g, max);
    }
    assert!(peak["mpmcg"] < 0.25 * peak["averaged"], "{peak:?}");
}

/// Largest principal value of the in-plane part of a 3 × 3 stress row.
fn max_principal_2d(s: &[f64; 9]) -> f64 {
    let (a, b, d) = (s[0], s[1], s[4]);
    0.5 * (a + d) + (0.25 * (a - d).powi(2) + b * b).sqrt()
}

/// A brittle bar loaded to at most two thirds of its strength (a closed-form bound)
/// while every particle crosses cells: MPMCG fails no particle, and its largest
/// principal stress in any snapshot (every millisecond) stays below the exact bound
/// ρ c v0. MPM's figures are printed: it does not fail the bar either (README).
#[test]
fn brittle_bar_below_strength_stays_intact() {
    let text = include_str!("../inputs/brittle_bar.toml");
    let (lambda, mu) = mpmcg::physics::material::lame(1.0e6, 0.3);
    let bound = 1000.0 * ((lambda + 2.0 * mu) / 1000.0).sqrt() * 0.5;
    for g in ["mpmcg", "mpm"] {
        let (r, out) = run_scene(&with_gradient(text, g), &format!("brittle-{g}"));
        r.unwrap_or_else(|e| panic!("brittle {g}: {e}"));
        let (mut peak, mut damaged, mut crossed) = (0.0f64, 0.0f64, f64::INFINITY);
        let files = common::files(&out, "particles_");
        let first = common::read_snapshot(&files[0], None);
        let x0: HashMap<i64, [f64; 3]> = first.id.iter().copied().zip(first.x).collect();
        for f in &files {
            let s = common::read_stress(f);
            peak = s.iter().map(max_principal_2d).fold(peak, f64::max);
            damaged = damaged.max(common::read_scalar(f, "damage").iter().sum());
        }
        let end = common::read_snapshot(files.last().unwrap(), None);
        // The body translates: every particle crosses many cells along x (h = 1/16;
        // along the periodic y it wraps, so x alone is counted).
        for (id, b) in end.id.iter().zip(&end.x) {
            crossed = crossed.min(((b[0] - x0[id][0]) * 16.0).abs());
        }
        eprintln!(
            "brittle bar {g}: largest principal stress {:.3} of the exact bound ({:.0} Pa; strength 1.5 bounds); damaged particles {damaged}",
            peak / bound,
            bound
        );
        if g == "mpmcg" {
            assert_eq!(damaged, 0.0, "mpmcg failed particles");
            assert!(peak < bound, "mpmcg: {peak} above the exact bound {bound}");
        }
        assert!(crossed > 10.0, "a particle crossed only {crossed} cells");
    }
}

/// Taylor bar impact, coarse (0.8 mm cells, 4 across the radius): at 80 µs the final
/// length is within 2 % of the reference 21.45 mm, the largest particle radius at the
/// wall (centres) within 5 % of 7.05 mm, the peak plastic strain in the reference's
/// 2.5–3 range, and kinetic + stored energy + plastic work balance to 1 % (the wall's
/// work counted: the kinetic energy it takes from particles at impact). Particles in
/// the wall's cells (z < h) approach it no faster than the grid there: vz is clipped to
/// the grid's, interpolated from the wall's nodes (zero) and the next layer's, so
/// `−vz ≤ (z/h) · 227 m/s` with the impact speed bounding the nodes' (before the fix,
/// particles 0.1 mm from the wall kept −176 m/s).
#[test]
fn taylor_bar_matches_the_reference() {
    let (r, out) = run_scene(include_str!("../inputs/taylor_bar.toml"), "taylor");
    let s = r.unwrap_or_else(|e| panic!("taylor bar: {e}"));
    let last = common::files(&out, "particles_").pop().unwrap();
    let sn = common::read_snapshot(&last, Some("velocity"));
    assert!((sn.time - 8.0e-5).abs() < 1e-9);
    let h = 0.8e-3;
    let mut at_wall = (0, 0.0f64);
    for (x, v) in sn.x.iter().zip(&sn.field) {
        if x[2] < h {
            at_wall.0 += 1;
            at_wall.1 = at_wall.1.max(-v[2]);
            assert!(
                -v[2] <= x[2] / h * 227.0,
                "into the wall: z = {}, vz = {}",
                x[2],
                v[2]
            );
        }
    }
    assert!(at_wall.0 > 100, "particles at the wall: {}", at_wall.0);
    // Particle centres lie a quarter cell inside the surface (2 per cell).
    let half = 0.8e-3 / 4.0;
    let length = sn.x.iter().map(|p| p[2]).fold(0.0, f64::max) + half;
    let radius = sn.x.iter().map(|p| p[0].hypot(p[1])).fold(0.0, f64::max);
    let eps = common::read_scalar(&last, "plastic_strain")
        .into_iter()
        .fold(0.0, f64::max);
    let w = s.energy.plastic_work.unwrap();
    eprintln!(
        "taylor bar: length {:.2} mm, radius (centres) {:.2} mm (+ half spacing {:.2} mm), peak plastic strain {eps:.2}, plastic work {w:.1} J of {:.1} J, kinetic {:.3} J, wall work {:.2} J, energy drift {:.1e}; fastest approach to the wall in its cells {:.2} m/s ({} particles)",
        length * 1e3,
        radius * 1e3,
        (radius + half) * 1e3,
        s.energy.initial_total,
        s.energy.final_kinetic,
        s.energy.external_work,
        s.energy.max_relative_drift,
        at_wall.1,
        at_wall.0
    );
    assert!(
        (length - 21.45e-3).abs() < 0.02 * 21.45e-3,
        "length {length}"
    );
    assert!((radius - 7.05e-3).abs() < 0.05 * 7.05e-3, "radius {radius}");
    assert!((2.5..=3.0).contains(&eps), "peak plastic strain {eps}");
    assert!(s.energy.max_relative_drift < 0.01);
    assert!(
        w > 0.9 * s.energy.initial_total,
        "most of the impact energy is dissipated"
    );
}

/// The freely spinning disk of docs/hard-cases.md (radius 0.3 in a unit box of 20²
/// cells, neo-Hookean, ω = 0.2 rad/s, 2 × 2 per cell, MUSL, touching no wall), to 10 s
/// with `line` in `[method]`: the strain energy at the end and the largest change of
/// the total energy, each as a share of the initial kinetic energy.
fn spinning_disk(line: &str, tag: &str) -> (f64, f64) {
    let text = format!(
        r#"
name = "spinning_disk"
dim = 2
[time]
end = 10.0
dt = 1.0e-3
[method]
gradient = "mpmcg"
update = "musl"
{line}
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [20, 20]
boundary = {{ x_lower = "slip", x_upper = "slip", y_lower = "slip", y_upper = "slip" }}
[[materials]]
name = "disk"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "disk"
shape = {{ sphere = {{ center = [0.5, 0.5], radius = 0.3 }} }}
particles_per_cell = 2
velocity_gradient = {{ value = [[0.0, -0.2], [0.2, 0.0]], about = [0.5, 0.5] }}
"#
    );
    let (r, out) = run_scene(&text, tag);
    let s = r.unwrap_or_else(|e| panic!("{tag}: {e}"));
    assert!((s.time - 10.0).abs() < 1e-9, "{tag} ended at {}", s.time);
    let rows = history(&out);
    let (k0, e0) = (rows[0]["kinetic"], rows[0]["total"]);
    let drift = rows
        .iter()
        .map(|r| (r["total"] - e0).abs())
        .fold(0.0, f64::max);
    (rows.last().unwrap()["strain"] / k0, drift / k0)
}

/// A rigid rotation has no strain, yet the grid velocity of a node at the rim is the
/// rotation's at its particles' mass centroid, not at the node, and the disk's spin
/// turns into strain (1.8 % of its kinetic energy in 10 s under MPMCG at the particle). The centroid
/// correction's four passes move that velocity to the node: under 0.2 % with either
/// quadrature (measured 0.09 % with the point rule, 0.15 % with the domain rule, 0.13 %
/// with MPMCG's defaults, which sharpen as well), with the total energy kept to 1e-4
/// (the force is the passes' adjoint).
#[test]
fn centroid_correction_keeps_a_spinning_disk_rigid() {
    let (plain, drift) = spinning_disk(POINT_RULE, "disk-plain");
    eprintln!(
        "no correction: strain {:.3} %, energy {drift:.1e}",
        100.0 * plain
    );
    assert!(
        plain > 0.01,
        "the uncorrected disk's strain share: {plain:e}"
    );
    for (what, line, tag) in [
        (
            "point rule, 4 passes",
            "quadrature = \"point\"\nsharpen = 0.0\ncentroid_passes = 4",
            "disk-centroid",
        ),
        (
            "domain rule, 4 passes",
            "quadrature = \"domain\"\nsharpen = 0.0\ncentroid_passes = 4",
            "disk-centroid-domain",
        ),
        ("MPMCG's defaults", "", "disk-defaults"),
    ] {
        let (strain, drift) = spinning_disk(line, tag);
        eprintln!("{what}: strain {:.3} %, energy {drift:.1e}", 100.0 * strain);
        assert!(strain < 0.002, "{what}: strain share {strain:e}");
        assert!(drift < 1e-4, "{what}: total energy changed by {drift:e}");
    }
}
