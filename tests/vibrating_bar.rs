//! The vibrating bar (Bardenhagen & Kober 2004): E = 100, ρ = 1, L = 25, v0 = 0.1,
//! 2 particles per cell, t = 40 (four periods), fixed at x = 0, free at x = L.
//! Exact centre-of-mass velocity `v0/(βL) cos(ωt)`, β = π/2L, ω = β sqrt(E/ρ).

#![forbid(unsafe_code)]

mod common;
use common::{history, run_text};
use std::f64::consts::PI;

const AMP: f64 = 0.1 / (PI / 50.0 * 25.0);
const OMEGA: f64 = PI / 50.0 * 10.0;

/// The bar in `dim` dimensions along x, `cells` cells along it, with slip sides
/// `across` cells wide.
fn bar(dim: usize, cells: usize, across: usize, gradient: &str, update: &str, cfl: f64) -> String {
    let h = 25.0 / cells as f64;
    let w = h * across as f64;
    let (lo, up, ce, bd) = match dim {
        1 => (
            "[0.0]".to_string(),
            "[25.0]".to_string(),
            format!("[{cells}]"),
            r#"{ x_lower = "fixed", x_upper = "free" }"#.to_string(),
        ),
        2 => (
            "[0.0, 0.0]".into(),
            format!("[25.0, {w}]"),
            format!("[{cells}, {across}]"),
            r#"{ x_lower = "fixed", x_upper = "free", y_lower = "slip", y_upper = "slip" }"#.into(),
        ),
        _ => (
            "[0.0, 0.0, 0.0]".into(),
            format!("[25.0, {w}, {w}]"),
            format!("[{cells}, {across}, {across}]"),
            r#"{ x_lower = "fixed", x_upper = "free", y_lower = "slip", y_upper = "slip", z_lower = "slip", z_upper = "slip" }"#.into(),
        ),
    };
    format!(
        r#"
name = "bar"
dim = {dim}
[time]
end = 40.0
cfl = {cfl}
[method]
gradient = "{gradient}"
update = "{update}"
flip = 1.0
[grid]
lower = {lo}
upper = {up}
cells = {ce}
boundary = {bd}
[[materials]]
name = "bar"
model = "linear_elastic"
strain = "small"
density = 1.0
youngs_modulus = 100.0
poisson_ratio = 0.0
[[bodies]]
material = "bar"
shape = {{ box = {{ lower = {lo}, upper = {up} }} }}
particles_per_cell = 2
[benchmark]
kind = "vibrating_bar"
amplitude = 0.1
"#
    )
}

/// Largest |v_cm − exact| over the run, relative to the exact amplitude.
fn vcm_error(out: &std::path::Path) -> f64 {
    history(out)
        .iter()
        .map(|r| (r["velocity_cm_0"] - AMP * (OMEGA * r["time"]).cos()).abs() / AMP)
        .fold(0.0, f64::max)
}

/// v_cm follows the exact solution for USL, USF and MUSL, converging at second order.
///
/// At 16 cells our deviation is 2.4 % (USF) to 3.5 % (USL, MUSL), not the 2.5 % quoted
/// for public codes: it is a phase lag, the bar's period comes out 0.13 % long. FLIP–MPM
/// projects particle velocities to the grid and back every step; for the mode sin(βx)
/// each projection smooths by about (βh)²·3/32 (second moment of the weights at
/// 2 particles per cell), so ω_h ≈ ω (1 − c (βh)²) with c ≈ 0.14 instead of 1/24 for
/// lumped-mass finite elements; over four periods that lag is ω t c (βh)² ≈ 3.4 % of
/// the amplitude. It is spatial (halving dt leaves it, doubling the cells quarters it),
/// so we assert the 2.5 % bound where the discretisation allows it, at 32 cells, and
/// the second-order fall from 16 to 32.
#[test]
fn centre_of_mass_velocity_matches_exact_for_all_update_orders() {
    for update in ["usl", "usf", "musl"] {
        let (_, o16) = run_text(
            &bar(1, 16, 1, "mpm", update, 0.1),
            &format!("vcm16-{update}"),
        );
        let (_, o32) = run_text(
            &bar(1, 32, 1, "mpm", update, 0.1),
            &format!("vcm32-{update}"),
        );
        let (e16, e32) = (vcm_error(&o16), vcm_error(&o32));
        println!("{update}: v_cm error {e16:.4} at 16 cells, {e32:.4} at 32 cells");
        assert!(e16 < 0.036, "{update}: v_cm error {e16} at 16 cells");
        assert!(e32 < 0.025, "{update}: v_cm error {e32} at 32 cells");
        assert!(
            e16 / e32 > 3.0,
            "{update}: v_cm error not second order: {e16} -> {e32}"
        );
    }
}

/// Particle masses never change, so the total is exactly constant.
#[test]
fn mass_is_exactly_constant() {
    let (s, out) = run_text(&bar(1, 16, 1, "mpmcg", "usl", 0.1), "mass");
    assert_eq!(s.mass.initial, 25.0);
    assert_eq!(s.mass.r#final, s.mass.initial);
    // And momentum / v_cm is consistent with the mass at every output row.
    for r in history(&out) {
        assert!((r["momentum_0"] / 25.0 - r["velocity_cm_0"]).abs() < 1e-15);
    }
}

/// Energy drift: explicit FLIP–MPM loses a little energy each step (the USL/MUSL
/// splitting is first order in dt) plus a dt-independent part from the grid projection.
/// Bounds: below 1.5 % at CFL 0.2 and 1 % at CFL 0.1, and falling as dt halves.
#[test]
fn energy_drift_is_small_and_falls_with_dt() {
    for update in ["usl", "usf", "musl"] {
        let d: Vec<f64> = [0.2, 0.1, 0.05]
            .iter()
            .map(|&c| {
                run_text(
                    &bar(1, 16, 1, "mpm", update, c),
                    &format!("drift-{update}-{c}"),
                )
                .0
                .energy
                .max_relative_drift
            })
            .collect();
        println!("{update}: drift at CFL 0.2, 0.1, 0.05: {d:?}");
        assert!(d[0] < 0.015 && d[1] < 0.01, "{update}: {d:?}");
        assert!(d[1] < 0.75 * d[0] && d[2] < 0.75 * d[1], "{update}: {d:?}");
    }
}

/// The same bar in 2D and 3D (slip sides, one or two cells across) reproduces the 1D
/// run to round-off: every v_cm sample and the error norms agree to 1e-12 relative.
/// Holds for `mpm`, `gimp` and `averaged`; `mpmcg` differs by design, since its
/// α = Π_d 4ξ_d(1 − ξ_d) takes a factor from every axis (0.75 at the particles across).
#[test]
fn bar_in_2d_and_3d_matches_1d() {
    for g in ["mpm", "gimp", "averaged"] {
        let (s1, o1) = run_text(&bar(1, 16, 1, g, "usl", 0.1), &format!("dim1-{g}"));
        let h1 = history(&o1);
        for dim in [2, 3] {
            let (s, o) = run_text(&bar(dim, 16, 2, g, "usl", 0.1), &format!("dim{dim}-{g}"));
            let h = history(&o);
            assert_eq!(h.len(), h1.len(), "{g} {dim}D: different sample count");
            assert_eq!(s.steps, s1.steps);
            for (a, b) in h.iter().zip(&h1) {
                assert!((a["time"] - b["time"]).abs() <= 1e-12 * b["time"]);
                let d = (a["velocity_cm_0"] - b["velocity_cm_0"]).abs() / AMP;
                assert!(
                    d < 1e-12,
                    "{g} {dim}D: v_cm differs by {d} at t = {}",
                    a["time"]
                );
                for ax in 1..dim {
                    assert!(a[&format!("velocity_cm_{ax}")].abs() < 1e-14);
                }
            }
            let (e, e1) = (s.error.unwrap(), s1.error.clone().unwrap());
            assert!((e.displacement_l2 - e1.displacement_l2).abs() < 1e-12 * e1.displacement_l2);
            assert!((e.velocity_l2 - e1.velocity_l2).abs() < 1e-12 * e1.velocity_l2);
        }
    }
}

/// The committed scene file runs and meets the bounds above (at its 16 cells, CFL 0.1).
#[test]
fn input_scene_meets_bounds() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/inputs/vibrating_bar.toml"
    ))
    .unwrap();
    let (s, out) = run_text(&text, "input-bar");
    assert_eq!(s.status, "completed");
    assert_eq!(s.mass.r#final, s.mass.initial);
    assert!(s.energy.max_relative_drift < 0.01);
    assert!(vcm_error(&out) < 0.036);
    // Displacement error: a phase lag of ~0.05 time units on an amplitude v0/ω.
    let e = s.error.unwrap();
    assert!(
        e.displacement_l2 < 0.03 * 0.1 / OMEGA,
        "{}",
        e.displacement_l2
    );
}

/// Two bars collide in the middle of a grid with free faces: internal forces only, so
/// total momentum stays at its initial value to round-off for every scheme.
#[test]
fn free_flying_momentum_is_constant() {
    for g in ["mpm", "gimp", "averaged", "mpmcg"] {
        let text = format!(
            r#"
name = "two_bars"
dim = 1
[time]
end = 2.0
cfl = 0.2
[method]
gradient = "{g}"
update = "musl"
[grid]
lower = [0.0]
upper = [10.0]
cells = [40]
boundary = {{ x_lower = "free", x_upper = "free" }}
[[materials]]
name = "m"
model = "linear_elastic"
density = 2.0
youngs_modulus = 50.0
poisson_ratio = 0.0
[[bodies]]
material = "m"
shape = {{ box = {{ lower = [3.0], upper = [4.9] }} }}
velocity = [0.7]
[[bodies]]
material = "m"
shape = {{ box = {{ lower = [5.0], upper = [6.0] }} }}
velocity = [-0.4]
"#
        );
        let (s, out) = run_text(&text, &format!("momentum-{g}"));
        let p0 = s.momentum.initial[0];
        let scale = s.mass.initial * 0.7;
        for r in history(&out) {
            assert!(
                (r["momentum_0"] - p0).abs() < 1e-13 * scale,
                "{g}: momentum {} vs {p0}",
                r["momentum_0"]
            );
        }
        // The bars did interact: strain energy was stored at some point.
        assert!(
            history(&out)
                .iter()
                .any(|r| r["strain"] > 1e-3 * s.energy.initial_total),
            "{g}: no collision"
        );
    }
}
