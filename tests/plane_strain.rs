//! Plane strain σ_zz in the snapshot's `stress` (entry 8 of 9): four 2D blocks, one per
//! material model, start stress-free with the same uniform velocity gradient G and
//! take one step of dt. Particles at least three cells inside a block see exactly
//! `L = G` (the grid reproduces a linear velocity field where a node's support is full
//! and the particle lattice is symmetric about it, and no stress has acted yet), so
//! with `f = I + G dt`, `J = det f`:
//! linear elastic and brittle `σ_zz = λ tr M / J` with the step's midpoint gradient
//! `M = G dt (I + ½ G dt)⁻¹` (Hughes–Winget, on the Kirchhoff stress); neo-Hookean
//! `σ_zz = λ ln J / J`;
//! J2 (elastic here) `τ_zz = λ ln J + 2μ ε_zz` with `ε_zz = 0`, the same `λ ln J / J`.

#![forbid(unsafe_code)]

mod common;

const DT: f64 = 1e-3;
/// The uniform velocity gradient, row-major: stretch, shear and some volume change.
const G: [[f64; 2]; 2] = [[20.0, 10.0], [-4.0, -5.0]];
const E: f64 = 1.0e6;
const NU: f64 = 0.3;

fn scene() -> String {
    let models = [
        ("linear_elastic", ""),
        ("neo_hookean", ""),
        ("j2_plastic", "yield_stress = 1.0e9\n"),
        ("brittle", "tensile_strength = 1.0e9\n"),
    ];
    let mut s = format!(
        r#"name = "plane_strain"
dim = 2
[time]
end = {DT:e}
dt = {DT:e}
[method]
gradient = "mpmcg"
update = "musl"
[grid]
lower = [0.0, 0.0]
upper = [50.0, 14.0]
cells = [50, 14]
boundary = {{ x_lower = "free", x_upper = "free", y_lower = "free", y_upper = "free" }}
[output]
every = {DT:e}
fields = ["stress"]
"#
    );
    for (k, (model, extra)) in models.iter().enumerate() {
        let x0 = 2.0 + 12.0 * k as f64;
        s += &format!(
            r#"
[[materials]]
name = "m{k}"
model = "{model}"
density = 1000.0
youngs_modulus = {E:e}
poisson_ratio = {NU}
{extra}
[[bodies]]
material = "m{k}"
shape = {{ box = {{ lower = [{x0:?}, 2.0], upper = [{:?}, 12.0] }} }}
velocity_gradient = {{ value = [[{:?}, {:?}], [{:?}, {:?}]], about = [{:?}, 7.0] }}
"#,
            x0 + 10.0,
            G[0][0],
            G[0][1],
            G[1][0],
            G[1][1],
            x0 + 5.0
        );
    }
    s
}

#[test]
fn snapshot_sigma_zz_is_the_closed_form_for_a_uniform_strain() {
    let (_, out) = common::run_text(&scene(), "plane-strain");
    let last = common::files(&out, "particles_").pop().unwrap();
    let sn = common::read_snapshot(&last, None);
    assert!((sn.time - DT).abs() < 1e-15);
    let stress = common::read_stress(&last);
    let lambda = E * NU / ((1.0 + NU) * (1.0 - 2.0 * NU));
    let g = G.map(|r| r.map(|x| x * DT));
    let j = (1.0 + g[0][0]) * (1.0 + g[1][1]) - g[0][1] * g[1][0];
    // tr M = tr(g A⁻¹), A = I + g/2: A⁻¹ is the adjugate over det A.
    let a = [
        [1.0 + 0.5 * g[0][0], 0.5 * g[0][1]],
        [0.5 * g[1][0], 1.0 + 0.5 * g[1][1]],
    ];
    let det_a = a[0][0] * a[1][1] - a[0][1] * a[1][0];
    let tr_m =
        (g[0][0] * a[1][1] - g[0][1] * a[1][0] - g[1][0] * a[0][1] + g[1][1] * a[0][0]) / det_a;
    let rate = lambda * tr_m / j;
    let finite = lambda * j.ln() / j;
    // The two closed forms agree to third order in the strain (`tr M ≈ ln J`); they
    // still differ by a million times the tolerance, so the test tells them apart.
    assert!((rate - finite).abs() > 1e-6 * rate.abs());
    let mut seen = [0usize; 4];
    for (p, x) in sn.x.iter().enumerate() {
        // Which block, and is the particle at least three cells inside it?
        let k = ((x[0] - 1.0) / 12.0).floor() as usize;
        let x0 = 2.0 + 12.0 * k as f64;
        let inside = |v: f64, lo: f64, hi: f64| v > lo + 3.0 && v < hi - 3.0;
        if !(inside(x[0], x0, x0 + 10.0) && inside(x[1], 2.0, 12.0)) {
            continue;
        }
        let s = stress[p];
        let want = if k == 0 || k == 3 { rate } else { finite };
        assert!(
            (s[8] - want).abs() < 1e-11 * want.abs(),
            "block {k}, particle at {x:?}: σ_zz {} vs {want}",
            s[8]
        );
        // The out-of-plane shear entries are zero in plane strain.
        for c in [2, 5, 6, 7] {
            assert_eq!(s[c], 0.0);
        }
        seen[k] += 1;
    }
    // A 4 × 4 cell core at 2 × 2 particles per cell in every block.
    assert_eq!(seen, [64; 4], "interior particles per block");
    let _ = std::fs::remove_dir_all(&out);
}
