//! Particle velocities at slip walls. A slip wall zeroes the grid's normal velocity on
//! its nodes before and after the force update alike, so FLIP's increment never told a
//! particle about it: a body thrown at a wall kept its velocity into the wall. Now a
//! particle that touches a slip wall's node moves into the wall no faster than the
//! grid's velocity at its position, the velocity it moves with, which vanishes at the
//! wall: its normal component is clipped to the grid's. (Fixed walls keep FLIP's
//! velocity: clipping at a clamp pushed cantilevers out through it, see `kernel.rs`.)
//!
//! A block resting on the lower face of its last axis is thrown at it (normal speed 1,
//! tangential 0.5 and 0.25), in 2D and 3D.

#![forbid(unsafe_code)]

use decomposition::{Layout, SerialComm};
use mpmcg::input::scene::{self, Face};
use mpmcg::mpm::solver::Solver;
use std::collections::HashMap;

const H: f64 = 0.125;
const U: [f64; 3] = [0.5, 0.25, -1.0];

fn scene_text(dim: usize, wall: &str, gradient: &str, update: &str) -> String {
    let v = |x: f64| vec![format!("{x:?}"); dim].join(", ");
    let mut faces = Vec::new();
    let (mut lo, mut hi, mut u) = (Vec::new(), Vec::new(), Vec::new());
    for (a, ax) in ["x", "y", "z"].iter().take(dim).enumerate() {
        let last = a == dim - 1;
        let low = if last { wall } else { "free" };
        faces.push(format!("{ax}_lower = \"{low}\", {ax}_upper = \"free\""));
        lo.push(if last { "0.0" } else { "0.25" });
        hi.push(if last { "0.5" } else { "0.75" });
        u.push(format!("{:?}", if last { U[2] } else { U[a] }));
    }
    format!(
        r#"
name = "wall"
dim = {dim}
[time]
end = 1.0
cfl = 0.2
[method]
gradient = "{gradient}"
update = "{update}"
[grid]
lower = [{}]
upper = [{}]
cells = [{}]
boundary = {{ {} }}
[[materials]]
name = "m"
model = "linear_elastic"
density = 1.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = {{ box = {{ lower = [{}], upper = [{}] }} }}
particles_per_cell = 2
velocity = [{}]
"#,
        v(0.0),
        v(1.0),
        vec!["8"; dim].join(", "),
        faces.join(", "),
        lo.join(", "),
        hi.join(", "),
        u.join(", ")
    )
}

fn solver<const D: usize>(text: &str) -> Solver<'static, D> {
    let scene = scene::parse(text, "wall").expect("valid scene");
    let cells: [usize; D] = std::array::from_fn(|a| scene.grid.cells[a]);
    let periodic: [bool; D] =
        std::array::from_fn(|a| scene.grid.boundary.face(a, false) == Face::Periodic);
    let layout = Layout::choose(cells, periodic, 1).expect("layout");
    Solver::<D>::new(&scene, &SerialComm, layout)
}

/// The first step, in closed form. The block is stress-free, so every node with mass
/// moves at the block's velocity u except the wall's nodes (normal component zero); a
/// particle at distance d < h from the wall gives the wall's nodes weight 1 − d/h, so
/// the grid moves it towards the wall at u_n·d/h, and that is now its normal velocity
/// (before: u_n, kept by FLIP). Its tangential components stay u. Under MUSL the
/// particle then moves with the remapped velocity and is clipped to it again: the first
/// node off the wall gets the momentum of the wall cell's particles (at h/4 and 3h/4,
/// normal velocities u_n/4 and 3u_n/4, weights 1/4 and 3/4) and of the next cell's
/// (u_n, weights 3/4 and 1/4), so its normal velocity is (10/16 + 1)/2 u_n = 13/16 u_n,
/// and the particle's becomes 13/16 u_n·d/h. Standard MPM: the two-step schemes move
/// particles with a reconstruction of their nodal averages, not with this piecewise
/// linear grid velocity, and `through_impact` checks them against what they moved with.
fn first_step<const D: usize>(wall: &str) {
    for update in ["musl", "usl"] {
        let mut s = solver::<D>(&scene_text(D, wall, "mpm", update));
        let d0: HashMap<u64, f64> = (0..s.parts.len())
            .map(|p| (s.parts.id[p], s.parts.x[p][D - 1]))
            .collect();
        s.advance().unwrap();
        let mut touching = 0;
        for p in 0..s.parts.len() {
            let d = d0[&s.parts.id[p]];
            let remapped = if update == "musl" { 13.0 / 16.0 } else { 1.0 };
            let w = if d < H { remapped * d / H } else { 1.0 };
            touching += usize::from(d < H);
            for (a, &got) in s.parts.v[p].iter().enumerate() {
                let want = if a == D - 1 { U[2] * w } else { U[a] };
                assert!(
                    (got - want).abs() < 1e-13,
                    "{D}D {wall} {update}, d = {d}, axis {a}: {got} vs {want}"
                );
            }
        }
        // Two particle layers in the wall's cells under the block.
        assert_eq!(
            touching,
            2 * 8usize.pow(D as u32 - 1),
            "{D}D {wall} {update}"
        );
    }
}

#[test]
fn first_step_at_a_wall_in_closed_form() {
    first_step::<2>("slip");
    first_step::<3>("slip");
}

/// Through the impact (40 steps, while the compression wave crosses the block and
/// back): after every step, no particle that touches a wall node has a normal velocity
/// into the wall above the one it moved with in that step (its displacement over dt,
/// the grid's velocity, which vanishes at the wall); those clipped have exactly it.
/// For every scheme.
fn through_impact<const D: usize>(wall: &str, gradient: &str) {
    let mut s = solver::<D>(&scene_text(D, wall, gradient, "musl"));
    // A GIMP particle (half-width h/4 at 2 per cell) reaches a node h + h/4 away.
    let reach = if gradient == "gimp" { 1.25 * H } else { H };
    let mut clipped = 0;
    for _ in 0..40 {
        let before: HashMap<u64, Vec<f64>> = (0..s.parts.len())
            .map(|p| (s.parts.id[p], s.parts.x[p].iter().copied().collect()))
            .collect();
        s.advance().unwrap();
        let mut touching = 0;
        for p in 0..s.parts.len() {
            let x0 = &before[&s.parts.id[p]];
            if x0[D - 1] >= reach {
                continue;
            }
            touching += 1;
            let moved = (s.parts.x[p][D - 1] - x0[D - 1]) / s.dt;
            let v = s.parts.v[p][D - 1];
            assert!(
                v >= moved - 1e-11,
                "{D}D {wall} {gradient} step {}: v {v} into the wall, moved at {moved}",
                s.step
            );
            clipped += usize::from((v - moved).abs() < 1e-11);
        }
        assert!(touching >= 2 * 8usize.pow(D as u32 - 1));
    }
    assert!(clipped > 0, "{D}D {wall} {gradient}: the clip never acted");
}

#[test]
fn wall_particles_move_with_the_grid_through_the_impact() {
    for g in ["mpm", "gimp", "mpmcg"] {
        through_impact::<2>("slip", g);
        through_impact::<3>("slip", g);
    }
}
