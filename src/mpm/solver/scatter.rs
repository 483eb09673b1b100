//! Particle to grid: the scatter pass (mass, momentum, forces) and the XPIC field.

use super::*;

/// Numbers (or node records) per task of the parallel fills of grid fields.
pub(super) const ZERO_CHUNK: usize = 1 << 14;

/// Set a grid field to zero, in parallel.
pub(super) fn zero(v: &mut [f64]) {
    v.par_chunks_mut(ZERO_CHUNK).for_each(|c| c.fill(0.0));
}

impl<'c, const D: usize> Solver<'c, D> {
    /// Particle → grid: mass, momentum and, if `forces`, external and internal forces.
    /// `moved`: the particles moved since the last scatter, so their slab order must
    /// be rebuilt (the second scatter of a USF or MUSL step sees the same positions).
    pub(super) fn scatter(&mut self, forces: bool, moved: bool) {
        let two = self.scheme.two_step();
        if moved {
            self.activate_tiles();
        }
        self.scatter_pass(forces, kernel::Sums::Particles);
        if two {
            // The ghosts get the summed averaged-stress sums and cover (and the moments
            // between them), from which they form their own fill and σ̄ as their owners
            // do: one exchange where copying the fill and then σ̄ took two. Under the
            // centroid correction the whole record, whose mass and moments give the
            // first ghost layer its own offsets ([`Solver::centroid_offsets`]).
            let sw = self.grid.sw;
            let first = if self.centroid_passes > 0 {
                NodeRecord::<D>::MASS
            } else {
                NodeRecord::<D>::stress_sum(0, 0)
            };
            self.block
                .ghost_copy_slots(self.comm, &mut self.grid.scat, sw, first..sw);
            self.domain_weights();
        }
    }

    /// The scatter proper, into `scat`, summed over ranks, of `sums` (the field it
    /// takes from the grid is `xpic_term`).
    pub(super) fn scatter_pass(&mut self, forces: bool, sums: kernel::Sums) {
        self.scatter_local(forces, sums);
        self.block
            .ghost_sum(self.comm, &mut self.grid.scat, self.grid.sw);
    }

    /// [`scatter_pass`](Solver::scatter_pass) into this rank's stored nodes, before
    /// the sum over ranks and periodic images.
    pub(super) fn scatter_local(&mut self, forces: bool, sums: kernel::Sums) {
        let two = self.scheme.two_step() && sums == kernel::Sums::Particles;
        zero(&mut self.grid.scat);
        let ctx = ctx!(self);
        // The forces' scatter has each particle's body force formed before it, and it
        // is kept for the gather or remap after it (every update order has one between
        // them); other scatters leave it.
        if forces {
            let keep = ctx.body_force.is_some();
            self.scratch.accel.resize(
                if keep { self.parts.len() } else { 0 },
                Vector::<D>::zeros(),
            );
            if keep {
                let over = self.body_force_over_domain.then_some(&self.parts.half[..]);
                kernel::external_accel(&ctx, &self.parts.x0, over, &mut self.scratch.accel);
            }
        }
        let parts = kernel::ScatterParts {
            x: &self.parts.x,
            v: &self.parts.v,
            stress: &self.parts.stress,
            def_grad: &self.parts.def_grad,
            kind: &self.parts.kind,
            vol: particles::Volumes::of(&self.kinds, &self.parts),
            mass: particles::Masses::of(&self.kinds, &self.parts.kind),
            x0: &self.parts.x0,
            half: &self.parts.half,
            tile: &self.place.ptile,
            src: &self.grid.xpic_term,
            accel: if forces { &self.scratch.accel } else { &[] },
        };
        let m = kernel::ScatterMode {
            sw: self.grid.sw,
            forces,
            two_step: two,
            sums,
            moments: two && self.centroid_passes > 0,
        };
        by_nodes!(
            self.scheme.wide(),
            scatter,
            &ctx,
            &parts,
            &self.place.slabs,
            &mut self.grid.scat,
            m
        );
    }

    /// XPIC(m) (Hammerquist & Nairn 2017): the particles' new velocities are
    /// `V = S v⁺ + S ((m − 1) v − m v*)`, with `v` and `v⁺` the grid velocity before and
    /// after the force update, `S` the interpolation to the particles, and
    /// `v* = Σ_{r=2..m} (−1)^r v*_r`, `v*_1 = v`, `v*_r = (m − r + 1)/r · S⁺S v*_{r−1}`
    /// (`S⁺`: mass-weighted projection to the grid). FLIP is `V + S (v⁺ − v)`: it keeps
    /// the part of the particle velocities the grid cannot see, which gathers noise;
    /// PIC (m = 1) drops it and smooths every step; XPIC(m) removes the invisible part
    /// and damps the rest as little as its order allows. Each `S⁺S` is one scatter of
    /// the field interpolated at the particles (walls applied as on grid velocities).
    /// Leaves `(m − 1) v − m v*` in `xpic_add` (ghosts included) for the gather; the
    /// scatter records are overwritten (no later phase of the step reads them before
    /// the next scatter).
    pub(super) fn xpic_field(&mut self) {
        let m = self.xpic.expect("XPIC phase only in XPIC runs");
        let mf = m as f64;
        let sw = self.grid.sw;
        let d2 = VelRecord::<D>::WIDTH;
        let nn = self.grid.vel.len() / d2;
        for n in 0..nn {
            for a in 0..D {
                let v = self.grid.vel[VelRecord::<D>::at(n, FROM_MOMENTUM) + a];
                self.grid.xpic_term[n * D + a] = v;
                self.grid.xpic_add[n * D + a] = (mf - 1.0) * v;
            }
        }
        for r in 2..=m {
            self.scatter_pass(false, kernel::Sums::FromGrid);
            let f = (mf - r as f64 + 1.0) / r as f64;
            let mut term = std::mem::take(&mut self.grid.xpic_term);
            self.for_owned(|n, c| {
                let rec = &self.grid.scat[n * sw..(n + 1) * sw];
                let mass = rec[NodeRecord::<D>::MASS];
                let mut v = [0.0; 6];
                if mass > self.grid.mass_floor {
                    for a in 0..D {
                        v[a] = f * rec[NodeRecord::<D>::momentum(a)] / mass;
                        v[D + a] = v[a];
                    }
                    self.apply_bc(c, &mut v[..d2]);
                }
                term[n * D..(n + 1) * D].copy_from_slice(&v[..D]);
            });
            self.block.ghost_copy(self.comm, &mut term, D);
            // v* gains (−1)^r v*_r, so the field gains −m (−1)^r v*_r.
            let sign = if r % 2 == 0 { -mf } else { mf };
            for (x, t) in self.grid.xpic_add.iter_mut().zip(&term) {
                *x += sign * t;
            }
            self.grid.xpic_term = term;
        }
    }
}

#[cfg(test)]
pub(super) mod xpic_tests {
    //! XPIC(m)'s velocity update against its definition, written here with dense
    //! interpolation weights, and the conservation of momentum it inherits from the
    //! mass-weighted projection.
    use super::*;
    use crate::input::scene;
    use crate::physics::gradient::tests::Rng;
    use decomposition::{Layout, SerialComm};
    use std::collections::HashMap;

    /// A free 2 m × 1 m block under gravity, 2 × 2 particles per cell jittered by up to
    /// 0.9 cells, random velocities, zero stress (so the grid's force is gravity alone).
    pub(in crate::mpm::solver) fn block(
        gradient: &str,
        xpic: &str,
        rng: &mut Rng,
    ) -> Solver<'static, 2> {
        let text = format!(
            r#"
name = "xpic"
dim = 2
[time]
end = 1.0
[method]
gradient = "{gradient}"
{xpic}
[grid]
lower = [0.0, 0.0]
upper = [3.0, 2.0]
cells = [12, 8]
[gravity]
value = [0.0, -10.0]
[[materials]]
name = "rubber"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1.0e6
poisson_ratio = 0.3
[[bodies]]
material = "rubber"
shape = {{ box = {{ lower = [0.5, 0.5], upper = [2.5, 1.5] }} }}
particles_per_cell = 2
"#
        );
        // Plain defaults: absent keys give MPMCG at the particle, the path tested.
        let sc = scene::parse_with(&text, "xpic", scene::PLAIN_DEFAULTS).unwrap();
        let layout = Layout::choose([12, 8], [false, false], 1).unwrap();
        let mut s = Solver::<2>::new(&sc, &SerialComm, layout);
        for p in 0..s.parts.len() {
            for a in 0..2 {
                s.parts.x[p][a] += 0.9 * s.geom.h[a] * (rng.f64() - 0.5);
                s.parts.v[p][a] = rng.f64() - 0.5;
            }
        }
        s
    }

    /// Interpolation weights `S_ip` of the linear hats, by node index.
    pub(in crate::mpm::solver) fn weights(s: &Solver<'_, 2>) -> Vec<Vec<(usize, f64)>> {
        let mut nodes = HashMap::new();
        let h = s.geom.h;
        s.parts
            .x
            .iter()
            .map(|x| {
                let base: [i64; 2] =
                    std::array::from_fn(|a| ((x[a] - s.geom.lower[a]) / h[a]).floor() as i64);
                let mut w = Vec::new();
                for (i, j) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let node = [base[0] + i, base[1] + j];
                    let xn = s.geom.node_position(node);
                    let sw: f64 = (0..2)
                        .map(|a| 1.0 - ((x[a] - xn[a]) / h[a]).abs())
                        .product();
                    let n = nodes.len();
                    w.push((*nodes.entry(node).or_insert(n), sw));
                }
                w
            })
            .collect()
    }

    /// `V = S v⁺ + S ((m − 1) v − m v*)` from the definition: `v = S⁺V`, `v⁺ = v + g dt`
    /// on nodes with mass, `v*_1 = v`, `v*_r = (m − r + 1)/r S⁺S v*_{r−1}`,
    /// `v* = Σ_{r=2..m} (−1)^r v*_r`.
    pub(super) fn reference(s: &Solver<'_, 2>, m: usize, dt: f64) -> Vec<Vector<2>> {
        let w = weights(s);
        let nn = w.iter().flatten().map(|&(n, _)| n + 1).max().unwrap();
        let mut mass = vec![0.0; nn];
        for (p, wp) in w.iter().enumerate() {
            for &(n, sw) in wp {
                mass[n] += s.particle_mass(p) * sw;
            }
        }
        let to_particles = |g: &[Vector<2>]| -> Vec<Vector<2>> {
            w.iter()
                .map(|wp| wp.iter().map(|&(n, sw)| g[n] * sw).sum())
                .collect()
        };
        let to_grid = |u: &[Vector<2>]| -> Vec<Vector<2>> {
            let mut g = vec![Vector::<2>::zeros(); nn];
            for (p, wp) in w.iter().enumerate() {
                for &(n, sw) in wp {
                    g[n] += u[p] * (s.particle_mass(p) * sw);
                }
            }
            for n in 0..nn {
                g[n] = if mass[n] > s.grid.mass_floor {
                    g[n] / mass[n]
                } else {
                    Vector::<2>::zeros()
                };
            }
            g
        };
        let v = to_grid(&s.parts.v);
        let vplus: Vec<Vector<2>> = (0..nn)
            .map(|n| {
                if mass[n] > s.grid.mass_floor {
                    v[n] + s.gravity * dt
                } else {
                    v[n]
                }
            })
            .collect();
        let mut term = v.clone();
        let mut star = vec![Vector::<2>::zeros(); nn];
        for r in 2..=m {
            let f = (m - r + 1) as f64 / r as f64;
            term = to_grid(&to_particles(&term))
                .iter()
                .map(|t| t * f)
                .collect();
            let sign = if r % 2 == 0 { 1.0 } else { -1.0 };
            for n in 0..nn {
                star[n] += term[n] * sign;
            }
        }
        let field: Vec<Vector<2>> = (0..nn)
            .map(|n| vplus[n] + v[n] * (m as f64 - 1.0) - star[n] * m as f64)
            .collect();
        to_particles(&field)
    }

    /// One velocity update as a step does it: scatter, grid update, XPIC field, gather.
    pub(super) fn update(s: &mut Solver<'_, 2>, dt: f64) {
        s.scatter(true, true);
        if s.scheme.two_step() {
            s.averaged_force();
        }
        s.grid_velocity(dt);
        if s.xpic.is_some() {
            s.xpic_field();
        }
        s.gather((dt, dt), false, false, false);
    }

    #[test]
    pub(super) fn xpic_update_matches_its_definition_and_conserves_momentum() {
        let dt = 1e-3;
        for g in ["mpm", "mpmcg"] {
            for m in [1usize, 2, 3, 5] {
                let mut s = block(g, &format!("xpic = {m}"), &mut Rng(7 + m as u64));
                let want = reference(&s, m, dt);
                let momentum = |s: &Solver<'_, 2>| -> Vector<2> {
                    (0..s.parts.len())
                        .map(|p| s.parts.v[p] * s.particle_mass(p))
                        .sum()
                };
                let total: f64 = (0..s.parts.len()).map(|p| s.particle_mass(p)).sum();
                let before = momentum(&s) + s.gravity * (total * dt);
                update(&mut s, dt);
                let scale = want.iter().map(|v| v.norm()).fold(0.0, f64::max);
                let worst = (0..s.parts.len())
                    .map(|p| (s.parts.v[p] - want[p]).norm())
                    .fold(0.0, f64::max);
                assert!(
                    worst <= 1e-12 * scale,
                    "{g}, XPIC({m}): particle velocities off the definition by {worst:e} \
                     (largest {scale:e})"
                );
                let drift = (momentum(&s) - before).norm() / (total * scale);
                assert!(
                    drift < 1e-13,
                    "{g}, XPIC({m}): momentum drifts by {drift:e}"
                );
            }
        }
    }

    /// XPIC changes the particle velocities only: under USL and USF the particles
    /// move and deform with the grid's fields alone, so a step with XPIC(m) leaves
    /// the same positions and `F`, to the bit, as one without. (MPMCG moves them with
    /// L̄ and v̄, kept in the scatter records' storage that XPIC's scatters overwrite:
    /// with its field formed after them, not before, this fails.)
    #[test]
    pub(super) fn xpic_leaves_the_motion_to_the_grid() {
        for update in ["usl", "usf"] {
            for m in [2, 3] {
                let u = format!("update = \"{update}\"");
                let mut a = block("mpmcg", &format!("{u}\nxpic = {m}"), &mut Rng(11));
                let mut b = block("mpmcg", &u, &mut Rng(11));
                a.advance().expect("a step with XPIC");
                b.advance().expect("a step without");
                assert_eq!(
                    a.parts.id, b.parts.id,
                    "{update}, XPIC({m}): the order (sorted by position)"
                );
                let what = format!("{update}, XPIC({m})");
                for p in 0..a.parts.len() {
                    assert_eq!(a.parts.x[p], b.parts.x[p], "{what}: position {p}");
                    assert_eq!(a.parts.def_grad[p], b.parts.def_grad[p], "{what}: F {p}");
                }
                let dv = (0..a.parts.len())
                    .map(|p| (a.parts.v[p] - b.parts.v[p]).norm())
                    .fold(0.0, f64::max);
                assert!(dv > 1e-3, "{what}: XPIC changed the velocities ({dv:e})");
            }
        }
    }

    /// XPIC(1) is PIC: the same velocities as `flip = 0` without XPIC.
    #[test]
    pub(super) fn xpic_of_order_one_is_pic() {
        let dt = 1e-3;
        let mut a = block("mpmcg", "xpic = 1", &mut Rng(3));
        let mut b = block("mpmcg", "flip = 0.0", &mut Rng(3));
        update(&mut a, dt);
        update(&mut b, dt);
        for p in 0..a.parts.len() {
            let d = (a.parts.v[p] - b.parts.v[p]).norm();
            assert!(
                d <= 1e-14 * (1.0 + b.parts.v[p].norm()),
                "particle {p}: {d:e}"
            );
        }
    }

    /// The part of the particle velocities the grid cannot see (its momentum on every
    /// node is zero) is kept by FLIP and removed by XPIC(2) in one update.
    #[test]
    pub(super) fn xpic_removes_what_the_grid_cannot_see() {
        use nalgebra::{DMatrix, DVector};
        let dt = 1e-3;
        for (xpic, kept) in [("", true), ("xpic = 2", false)] {
            let mut s = block("mpmcg", xpic, &mut Rng(11));
            s.gravity = Vector::<2>::zeros();
            // V − S (Sᵀ M S)⁻¹ Sᵀ M V: no momentum on any node (M: particle masses).
            let w = weights(&s);
            let nn = w.iter().flatten().map(|&(n, _)| n + 1).max().unwrap();
            let np = s.parts.len();
            let mut sm = DMatrix::<f64>::zeros(np, nn);
            for (p, wp) in w.iter().enumerate() {
                for &(n, sw) in wp {
                    sm[(p, n)] += sw;
                }
            }
            let masses: Vec<f64> = (0..s.parts.len()).map(|p| s.particle_mass(p)).collect();
            let mp = DMatrix::from_diagonal(&DVector::from_row_slice(&masses));
            let st_m = sm.transpose() * &mp;
            let lu = (&st_m * &sm).lu();
            for a in 0..2 {
                let v = DVector::from_iterator(np, s.parts.v.iter().map(|v| v[a]));
                let c = lu.solve(&(&st_m * &v)).expect("consistent mass matrix");
                let null = &v - &sm * c;
                for p in 0..np {
                    s.parts.v[p][a] = null[p];
                }
            }
            let size: f64 = s.parts.v.iter().map(|v| v.norm()).fold(0.0, f64::max);
            let before = s.parts.v.clone();
            update(&mut s, dt);
            if kept {
                let d: f64 = (0..np)
                    .map(|p| (s.parts.v[p] - before[p]).norm())
                    .fold(0.0, f64::max);
                assert!(
                    d < 1e-12 * size,
                    "FLIP changed the invisible velocities by {d:e}"
                );
            } else {
                let after = s.parts.v.iter().map(|v| v.norm()).fold(0.0, f64::max);
                assert!(after < 1e-12 * size, "XPIC(2) left {after:e} of {size:e}");
            }
        }
    }
}
