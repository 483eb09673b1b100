//! The generalized vortex (Kamojjala, Brannon, Sadeghirad & Guilkey 2015) from
//! `inputs/generalized_vortex.toml`: a neo-Hookean ring whose circles rotate by
//! `α = A sin(πt) h(R)` under a manufactured body force, at the amplitude A = 0.1 where
//! point-particle schemes converge (the published A = 1 is out of their reach; the
//! input file has the numbers).
//!
//! Measured (displacement L2 error, maximum over the run; MUSL, FLIP, 2 particles per
//! cell, CFL 0.4 — CFL 0.2 gives the same errors to 1 %):
//!
//! | cells |   mpm    |   gimp   |  mpmcg   | mpmcg, domain rule | domain rule, sharpened |
//! |-------|----------|----------|----------|--------------------|------------------------|
//! |  32   | 2.13e-2  | 1.86e-2  | 1.91e-2  | 2.05e-2            | 1.78e-2                |
//! |  64   | 1.02e-2  | 8.76e-3  | 8.94e-3  | 8.96e-3            | 8.84e-3                |
//! |  128  | 1.39e-2  | 2.38e-3  | 2.16e-3  | 2.05e-3            | 1.99e-3                |
//!
//! MPMCG converges at order 1.09 then 2.05; MPM stalls (order −0.45 from 64 to 128
//! cells) as particles cross cells.

#![forbid(unsafe_code)]

mod common;
use common::temp_dir;
use mpmcg::driver::run::{run, RunOptions};
use mpmcg::input::scene::{parse, Gradient, Quadrature};

const SCENE: &str = include_str!("../inputs/generalized_vortex.toml");

/// Maximum displacement error of the input scene with `gradient` on `cells`² cells.
fn error(gradient: Gradient, cells: usize) -> f64 {
    errors(gradient, cells, 0.0).0
}

/// Maximum displacement and velocity errors of the input scene with `gradient` on
/// `cells`² cells; with `sharpen > 0`, MPMCG's domain rule with its averages sharpened.
fn errors(gradient: Gradient, cells: usize, sharpen: f64) -> (f64, f64) {
    let mut scene = parse(SCENE, "inputs/generalized_vortex.toml").expect("input parses");
    scene.method.gradient = gradient;
    if sharpen > 0.0 {
        scene.method.quadrature = Quadrature::Domain;
        scene.method.sharpen = sharpen;
    }
    scene.grid.cells = vec![cells, cells];
    scene.time.cfl = Some(0.4);
    let opts = RunOptions {
        out: temp_dir(&format!("vortex-{}-{cells}-{sharpen}", gradient.name())),
        quiet: true,
        threads: 1,
        ..RunOptions::default()
    };
    let s = run(&scene, &decomposition::SerialComm, &opts).expect("run");
    assert_eq!(
        s.status,
        "completed",
        "{} at {cells} cells",
        gradient.name()
    );
    let e = s.error.expect("benchmark errors");
    println!(
        "{} {cells} cells, sharpen {sharpen}: displacement error {:.4e}, velocity error {:.4e}",
        gradient.name(),
        e.displacement_l2,
        e.velocity_l2
    );
    (e.displacement_l2, e.velocity_l2)
}

/// MPMCG converges where MPM stalls: order ≥ 1.9 from 64 to 128 cells, and at every
/// resolution no less accurate than these runs are with the centred velocity step
/// (1.9080e-2, 8.9414e-3, 2.1606e-3; deterministic runs, so the bound is exact); it
/// ends four times more accurate than MPM at 128 cells. The order from 32 to 64 cells
/// is not asserted: 32 cells is before the asymptotic range. (The centred velocity
/// step moved these errors from 2.2766e-2, 8.8363e-3 and 2.1948e-3: 16 % and 2 % lower
/// at 32 and 128 cells, 1.2 % higher at 64.)
#[test]
fn mpmcg_converges_where_mpm_stalls() {
    let cg: Vec<f64> = [32, 64, 128]
        .iter()
        .map(|&n| error(Gradient::Mpmcg, n))
        .collect();
    let order = |a: f64, b: f64| (a / b).log2();
    for (e, committed) in cg.iter().zip([1.9080e-2, 8.9414e-3, 2.1606e-3]) {
        assert!(
            *e <= committed,
            "mpmcg errors {cg:?}, committed {committed}"
        );
    }
    let o2 = order(cg[1], cg[2]);
    assert!(o2 > 1.9, "mpmcg order {o2} from 64 to 128 cells ({cg:?})");
    let (m64, m128) = (error(Gradient::Mpm, 64), error(Gradient::Mpm, 128));
    assert!(
        order(m64, m128) < 0.5,
        "mpm no longer stalls: {m64} -> {m128}"
    );
    assert!(
        m128 > 4.0 * cg[2],
        "mpm {m128} vs mpmcg {} at 128 cells",
        cg[2]
    );
}

/// Sharpened (`quadrature = "domain"`, `sharpen = 2`), MPMCG's averages no longer lag
/// the ring's motion as they did behind GIMP at 32 and 64 cells: its displacement error
/// is below GIMP's at 32 and 128 cells, and its velocity error below GIMP's at 32, 64
/// and 128 cells. At 64 cells the displacement errors are within 2 % of each other:
/// there the ring's rigid turn from its seeding, the same in every scheme, is most of
/// them (docs/verification.md, Notes).
#[test]
fn sharpened_mpmcg_is_ahead_of_gimp() {
    for n in [32, 64, 128] {
        let (su, sv) = errors(Gradient::Mpmcg, n, 2.0);
        let (gu, gv) = errors(Gradient::Gimp, n, 0.0);
        assert!(
            sv < gv,
            "{n} cells: velocity errors, sharpened {sv:e}, gimp {gv:e}"
        );
        let bound = if n == 64 { 1.02 * gu } else { gu };
        assert!(
            su < bound,
            "{n} cells: displacement errors, sharpened {su:e}, gimp {gu:e}"
        );
    }
}
