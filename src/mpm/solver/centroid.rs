//! The centroid correction of MUSL's remapped grid velocity (`[method] centroid_passes`).
//!
//! The remap gives node `i` the velocity `v_i = Σ_p m_p S_i(x_p) v_p / m_i`: for a smooth
//! particle field that is the field at the node's mass centroid `x_i + d_i`, not at the
//! node, with `d_i = Σ_p m_p S_i(x_p) (x_p − x_i) / m_i` nonzero where the particles sit
//! unevenly in the node's support (half a cell or less at a flat surface of a regular
//! lattice, more at a node particles reach only from a far corner). The velocity
//! gradient then reads a field shifted by a different `d_i` at every node: a rigid
//! rotation gains a strain rate, and the spin turns into strain. Each pass moves the
//! velocity back to the node with the averaged gradient, `v_{k+1} = P (v₀ − L̄(v_k) d)`
//! from `v₀ = P v` (`P`: the walls and the empty nodes); their fixed point is exact for a
//! linear field. The grid force becomes the adjoint of the passes, `f ← Cᵀ f`, so the
//! forces' power against the grid velocity stays the stress power of the corrected
//! velocity gradient, and `Σ_i (Cᵀ f)_i = Σ_i f_i` before the walls (a uniform velocity
//! has `L̄ = 0`): momentum is kept.

use super::*;

impl<'c, const D: usize> Solver<'c, D> {
    /// The offsets `d_i` of the nodes that carry mass (zero elsewhere), owned and on the
    /// first ghost layer (whose summed records the scatter copied: the same bits as
    /// their owners'), from the first moments the step's scatter summed: every
    /// scheme's weights reproduce a linear field, so the node positions interpolated
    /// at a particle are its own where its weights reach no wall. Each moment is
    /// relative to its node, so an image across a periodic seam adds to its node what
    /// it should.
    pub(super) fn centroid_offsets(&mut self) {
        let nn = self.grid.vel.len() / VelRecord::<D>::WIDTH;
        let sw = self.grid.sw;
        let mut d = std::mem::take(&mut self.grid.centroid_d);
        d.clear();
        d.resize(nn * D, 0.0);
        let (scat, floor) = (&self.grid.scat, self.grid.mass_floor);
        self.nodes().par_near(&mut d, D, 1, |n, _, d| {
            let rec = &scat[n * sw..(n + 1) * sw];
            let m = rec[NodeRecord::<D>::MASS];
            if m > floor {
                for a in 0..D {
                    d[a] = rec[NodeRecord::<D>::moment(a)] / m;
                }
            }
        });
        self.grid.centroid_d = d;
    }

    /// Velocity `slot` of the owned nodes, and then of the ghosts, moved from the mass
    /// centroids to the nodes: `centroid_passes` passes of `v ← P (v₀ − L̄(v) d)`, each
    /// forming `L̄` in the storage of the scatter records as the `AveragedGradient`
    /// after it does.
    ///
    /// The passes go in pairs over the two ghost layers: the first of a pair forms `L̄`
    /// and `v` on the first ghost layer too, from the second layer's velocities, the
    /// same bits as the owners' (as `AveragedGradient` does), and the second reads them
    /// there for the owned nodes; then one ghost copy. So a ghost copy per two passes.
    pub(super) fn centroid_velocity(&mut self, slot: usize) {
        let (aw, vw) = (AvgRecord::<D>::WIDTH, VelRecord::<D>::WIDTH);
        let nn = self.grid.vel.len() / vw;
        let mut base = std::mem::take(&mut self.grid.centroid_base);
        base.clear();
        base.resize(nn * D, 0.0);
        for (n, b) in base.chunks_exact_mut(D).enumerate() {
            let at = VelRecord::<D>::at(n, slot);
            b.copy_from_slice(&self.grid.vel[at..at + D]);
        }
        let passes = self.centroid_passes;
        for k in 0..passes {
            // The first of a pair reaches the first ghost layer; the last pass (or the
            // second of a pair) copies.
            let reach = usize::from(k % 2 == 0 && k + 1 < passes);
            let mut scat = std::mem::take(&mut self.grid.scat);
            let mut vel = std::mem::take(&mut self.grid.vel);
            let nodes = self.nodes();
            by_pad!(
                D,
                nodes,
                gradient_tiles,
                &mut scat[..nn * aw],
                &vel,
                slot,
                &self.grid.node_vol,
                reach
            );
            let d = &self.grid.centroid_d;
            nodes.par_near(&mut vel, vw, reach, |n, c, v| {
                let l = &scat[n * aw..n * aw + D * D];
                let mut u = [0.0; 6];
                for a in 0..D {
                    let mut x = base[n * D + a];
                    for b in 0..D {
                        x -= l[a * D + b] * d[n * D + b];
                    }
                    u[a] = x;
                    u[D + a] = x;
                }
                nodes.apply_bc(c, &mut u[..vw]);
                v[slot * D..(slot + 1) * D].copy_from_slice(&u[..D]);
            });
            if reach == 0 {
                self.block.ghost_copy(self.comm, &mut vel, vw);
            }
            self.grid.scat = scat;
            self.grid.vel = vel;
        }
        self.grid.centroid_base = base;
    }

    /// The grid force of the owned nodes replaced by the adjoint of the passes of
    /// [`centroid_velocity`](Solver::centroid_velocity): with `u` the force,
    /// `w ← u − Mᵀ P w` as often, `(Mᵀ y)_i = Σ_j (y_j ⊗ d_j / V_j) · ∫ w S_j ∇S_i dv`
    /// (the averaged force's stencil on a tensor that is not symmetric); the grid
    /// update's walls are the last `P`.
    pub(super) fn centroid_force(&mut self) {
        let (sw, vw, dd) = (self.grid.sw, VelRecord::<D>::WIDTH, D * D);
        let nn = self.grid.vel.len() / vw;
        let force = |a: usize| NodeRecord::<D>::force(a);
        let mut base = std::mem::take(&mut self.grid.centroid_base);
        base.clear();
        base.resize(nn * D, 0.0);
        let mut tensor = std::mem::take(&mut self.grid.centroid_tensor);
        tensor.clear();
        tensor.resize(nn * dd, 0.0);
        let mut scat = std::mem::take(&mut self.grid.scat);
        {
            let rec = &scat;
            self.nodes().par_owned(&mut base, D, |n, _, u| {
                for a in 0..D {
                    u[a] = rec[n * sw + force(a)];
                }
            });
        }
        for _ in 0..self.centroid_passes {
            let nodes = self.nodes();
            let (d, vol, rec) = (&self.grid.centroid_d, &self.grid.node_vol, &scat);
            nodes.par_owned(&mut tensor, dd, |n, c, t| {
                let v = vol[n];
                let mut w = [0.0; 6];
                for a in 0..D {
                    w[a] = rec[n * sw + force(a)];
                    w[D + a] = w[a];
                }
                nodes.apply_bc(c, &mut w[..vw]);
                for a in 0..D {
                    for b in 0..D {
                        t[a * D + b] = if v > 0.0 {
                            w[a] * d[n * D + b] / v
                        } else {
                            0.0
                        };
                    }
                }
            });
            self.block.ghost_copy(self.comm, &mut tensor, dd);
            let nodes = self.nodes();
            nodes.par_owned(&mut scat, sw, |n, _, rec| {
                for a in 0..D {
                    rec[force(a)] = base[n * D + a];
                }
            });
            by_pad!(D, nodes, full_force_tiles, &mut scat, sw, &tensor);
        }
        self.grid.scat = scat;
        self.grid.centroid_base = base;
        self.grid.centroid_tensor = tensor;
    }
}

#[cfg(test)]
mod tests {
    use super::super::null_space::tests::periodic_box;
    use super::super::stencils::adjoint_tests::{
        beam, gradient_at_3d, jittered_box_3d, powers, stressed_beam,
    };
    use super::*;
    use crate::physics::gradient::tests::Rng;

    /// Owned nodes' grid forces, in storage order.
    fn forces(s: &Solver<'static, 2>) -> Vec<[f64; 2]> {
        let mut f = Vec::new();
        s.for_owned(|n, _| {
            let r = n * s.grid.sw;
            f.push([
                s.grid.scat[r + NodeRecord::<2>::force(0)],
                s.grid.scat[r + NodeRecord::<2>::force(1)],
            ]);
        });
        f
    }

    /// The corrected force is the adjoint of the corrected velocity gradient: for
    /// random particle stresses on the jittered beam, a random grid velocity `v` (walls
    /// applied) and four passes, `Σ_i (Cᵀ f)_i · v_i = −Σ_p V_p σ_p : L_p(C v)` to
    /// round-off, where `f` is the force of MPMCG's scatter and node step; the
    /// correction keeps `Σ_i f_i` (momentum) and changes the force by more than a
    /// thousandth, so the identity is not the uncorrected one. At the particle and
    /// with the domain rule.
    #[test]
    fn force_is_the_adjoint_of_the_corrected_gradient_and_keeps_momentum() {
        for (g, face, jitter) in ["mpmcg", "mpmcg-domain"]
            .into_iter()
            .flat_map(|g| ["fixed", "slip", "free"].map(|f| (g, f)))
            .flat_map(|(g, f)| [0.0, 0.6].map(|j| (g, f, j)))
        {
            let (fv, work) = powers(g, face, (jitter, true), 2024, (4, 0.0));
            let rel = (fv - work).abs() / fv.abs().max(work.abs());
            assert!(
                rel < 1e-12,
                "{g} {face} jitter {jitter}: Σ f·v {fv} vs {work}"
            );
            let (mut s, _) = stressed_beam(g, face, jitter, 2024);
            s.set_centroid_passes(4);
            s.scatter(true, true);
            s.centroid_offsets();
            s.averaged_force();
            let f0 = forces(&s);
            s.centroid_force();
            let f1 = forces(&s);
            let total = |f: &[[f64; 2]], a: usize| f.iter().map(|x| x[a]).sum::<f64>();
            let size = f0.iter().map(|x| x[0].abs() + x[1].abs()).sum::<f64>();
            let change = f0
                .iter()
                .zip(&f1)
                .map(|(a, b)| (a[0] - b[0]).abs() + (a[1] - b[1]).abs())
                .sum::<f64>();
            for a in 0..2 {
                let (p, q) = (total(&f0, a), total(&f1, a));
                assert!(
                    (p - q).abs() < 1e-12 * size,
                    "{g} {face} jitter {jitter}: Σ f_{a} {p} → {q}"
                );
            }
            assert!(
                change > 1e-3 * size,
                "{g} {face} jitter {jitter}: change {change:e}"
            );
        }
    }

    /// The offsets the step's scatter sums equal their definition,
    /// `d_i = Σ_p m_p S_ip (x̂_p − x_i) / m_i` with `x̂_p = Σ_k S_kp x_k`, formed here
    /// particle by particle from each one's weights and nodes: at the particle and under
    /// the domain rule (whose domains are cut at the face, so that `x̂_p ≠ x_p` there),
    /// the beam jittered by up to 0.6 cells against a fixed, a slip and a free face, to
    /// 1e-12 of a cell.
    #[test]
    fn offsets_are_the_mass_weighted_moments_of_the_interpolated_positions() {
        use std::collections::HashMap;
        for g in ["mpmcg", "mpmcg-domain"] {
            for face in ["fixed", "slip", "free"] {
                let mut s = beam(g, face, 0.6, &mut Rng(11));
                s.set_centroid_passes(4);
                s.scatter(false, true);
                s.centroid_offsets();
                let mut position = HashMap::new();
                s.for_owned(|n, c| {
                    let node = std::array::from_fn(|a| s.block.node_lo[a] + c[a] as i64);
                    position.insert(n, s.geom.node_position(node));
                });
                let ctx = ctx!(s);
                let mut sums: HashMap<usize, (f64, [f64; 2])> = HashMap::new();
                let mut cut = 0;
                for p in 0..s.parts.len() {
                    let (x, tile) = (&s.parts.x[p], s.place.ptile[p]);
                    let (w, idx): (Vec<f64>, Vec<usize>) =
                        match ctx.half_width(&s.parts.half, &s.parts.def_grad, p) {
                            Some(half) => {
                                let (k, idx) = ctx.kern::<3, 9>(x, Some(&half), tile);
                                (k.s.to_vec(), idx.to_vec())
                            }
                            None => {
                                let (k, idx) = ctx.kern::<2, 4>(x, None, tile);
                                (k.s.to_vec(), idx.to_vec())
                            }
                        };
                    let at = |n: usize| position[&n];
                    let mut xh = [0.0; 2];
                    for (w, &n) in w.iter().zip(&idx) {
                        if *w != 0.0 {
                            for a in 0..2 {
                                xh[a] += w * at(n)[a];
                            }
                        }
                    }
                    cut += usize::from((xh[0] - x[0]).abs() > 1e-9 * s.geom.h[0]);
                    let m = s.kinds.mass[s.parts.kind[p] as usize];
                    for (w, &n) in w.iter().zip(&idx) {
                        if *w != 0.0 {
                            let e = sums.entry(n).or_insert((0.0, [0.0; 2]));
                            e.0 += m * w;
                            for a in 0..2 {
                                e.1[a] += m * w * (xh[a] - at(n)[a]);
                            }
                        }
                    }
                }
                let domain = g.ends_with("domain");
                assert_eq!(cut > 0, domain, "{g} {face}: {cut} particles with x̂ ≠ x");
                let mut checked = 0;
                for (&n, &(m, mom)) in &sums {
                    if m > s.grid.mass_floor {
                        for a in 0..2 {
                            let (got, want) = (s.grid.centroid_d[2 * n + a], mom[a] / m);
                            assert!(
                                (got - want).abs() < 1e-12 * s.geom.h[a],
                                "{g} {face}: node {n} axis {a}: d {got} against {want}"
                            );
                        }
                        checked += 1;
                    }
                }
                assert!(checked > 100, "{g} {face}: {checked} nodes");
            }
        }
    }

    /// Particles carrying a linear velocity `W x + c`: the remap gives each node the
    /// field at its mass centroid, `W (x_i + d_i) + c`, and the passes move it to the
    /// node. On the beam's lattice every offset is within half a cell, the passes'
    /// fixed point is the field at the nodes (L̄ of a linear field is `W` at every
    /// node), and each pass divides the largest error by more than 2 until it is
    /// round-off (32 passes). With the particles jittered by up to 0.6 and 0.9 cells, a node that particles reach only
    /// from a far corner of its support has its centroid up to 1.4 cells away, and the
    /// series does not converge there (after 32 passes the largest error is a thousand
    /// times the first): up to the 8 passes a scene may ask for, the mass-weighted error
    /// still falls, by more than 3 times in four passes.
    #[test]
    fn a_linear_particle_velocity_is_moved_to_the_nodes() {
        let w = Mat::<2>::new(0.3, -1.1, 0.7, 0.2);
        let c = Vector::<2>::new(2.0, -3.0);
        for jitter in [0.0, 0.6, 0.9] {
            // On the lattice, 32 passes too: the fixed point, to round-off.
            let passes: &[usize] = if jitter == 0.0 {
                &[0, 1, 2, 4, 8, 32]
            } else {
                &[0, 1, 2, 4, 8]
            };
            // Per pass count: the largest error and the mass-weighted RMS error.
            let mut errors = Vec::new();
            for &k in passes {
                let mut s = beam("mpmcg", "free", jitter, &mut Rng(7));
                for p in 0..s.parts.len() {
                    let x = s.parts.x[p];
                    s.parts.v[p] = w * Vector::<2>::new(x[0], x[1]) + c;
                }
                s.set_centroid_passes(k);
                s.scatter(false, true);
                if k > 0 {
                    s.centroid_offsets();
                }
                s.grid_velocity(0.0);
                let mass: Vec<f64> = (0..s.grid.node_vol.len())
                    .map(|n| s.grid.scat[n * s.grid.sw + NodeRecord::<2>::MASS])
                    .collect();
                s.centroid_velocity(FROM_MOMENTUM);
                let (mut worst, mut sums) = (0.0f64, [0.0f64; 2]);
                s.for_owned(|n, ci| {
                    if mass[n] > s.grid.mass_floor {
                        let node = std::array::from_fn(|a| s.block.node_lo[a] + ci[a] as i64);
                        let x = s.geom.node_position(node);
                        let exact = w * Vector::<2>::new(x[0], x[1]) + c;
                        for a in 0..2 {
                            let e = s.grid.vel[VelRecord::<2>::at(n, FROM_MOMENTUM) + a] - exact[a];
                            worst = worst.max(e.abs());
                            sums[0] += mass[n] * e * e;
                        }
                        sums[1] += mass[n];
                    }
                });
                errors.push((worst, (sums[0] / sums[1]).sqrt()));
            }
            eprintln!(
                "jitter {jitter}: (largest, mass-weighted) error by passes {passes:?}: {errors:?}"
            );
            if jitter == 0.0 {
                assert!(
                    errors[0].0 > 0.05,
                    "the lattice's surface offsets: {errors:?}"
                );
                for (i, k) in passes.iter().enumerate().skip(1) {
                    let bound = errors[0].0 / 2f64.powi(*k as i32);
                    assert!(errors[i].0 < bound.max(1e-12), "{k} passes: {errors:?}");
                }
            } else {
                for i in 1..passes.len() {
                    assert!(
                        errors[i].1 < errors[0].1 / 2.0,
                        "jitter {jitter}: {errors:?}"
                    );
                }
                assert!(
                    errors[3].1 < errors[0].1 / 3.0,
                    "jitter {jitter}: {errors:?}"
                );
            }
        }
    }

    /// In 3D (the full-tensor stencil's `D × D = 9` entries, a row of four nodes at a
    /// time), on the spinning box of the sparse-grid tests jittered by up to 0.9 cells
    /// with random deformation gradients: with four passes, `Σ_i (Cᵀ f)_i · v_i =
    /// −Σ_p V_p σ_p : L_p(C v)` for a random grid velocity, and `Σ_i f_i` is kept while
    /// the force changes by more than a thousandth.
    #[test]
    fn force_is_the_adjoint_of_the_corrected_gradient_in_3d() {
        let (mut s, mut rng) = jittered_box_3d(41);
        s.set_centroid_passes(4);
        s.scatter(true, true);
        s.centroid_offsets();
        s.averaged_force();
        let sum = |s: &Solver<'_, 3>| {
            let mut t = [0.0f64; 3];
            s.for_owned(|n, _| {
                for (a, t) in t.iter_mut().enumerate() {
                    *t += s.grid.scat[n * s.grid.sw + NodeRecord::<3>::force(a)];
                }
            });
            t
        };
        let before = sum(&s);
        let uncorrected = s.grid.scat.clone();
        s.centroid_force();
        let after = sum(&s);
        let forces = s.grid.scat.clone();
        let mut owned = Vec::new();
        s.for_owned(|n, c| owned.push((n, c)));
        let size: f64 = owned
            .iter()
            .map(|&(n, _)| {
                (0..3)
                    .map(|a| forces[n * s.grid.sw + NodeRecord::<3>::force(a)].abs())
                    .sum::<f64>()
            })
            .sum();
        for a in 0..3 {
            assert!(
                (before[a] - after[a]).abs() < 1e-12 * size,
                "Σ f_{a}: {before:?} → {after:?}"
            );
        }
        let change: f64 = owned
            .iter()
            .map(|&(n, _)| {
                (0..3)
                    .map(|a| {
                        let r = n * s.grid.sw + NodeRecord::<3>::force(a);
                        (forces[r] - uncorrected[r]).abs()
                    })
                    .sum::<f64>()
            })
            .sum();
        assert!(
            change > 1e-3 * size,
            "the passes changed the force by {change:e} of {size:e}"
        );
        let mut vel = vec![0.0; s.tiles.nodes() * 6];
        for &(n, c) in &owned {
            if s.grid.centroid_d[n * 3..n * 3 + 3] != [0.0; 3] {
                for a in 0..3 {
                    vel[n * 6 + a] = rng.f64() - 0.5;
                    vel[n * 6 + 3 + a] = vel[n * 6 + a];
                }
                s.apply_bc(c, &mut vel[n * 6..n * 6 + 6]);
            }
        }
        s.block.ghost_copy(s.comm, &mut vel, 6);
        s.grid.vel = vel;
        let mut fv = 0.0f64;
        for &(n, _) in &owned {
            for a in 0..3 {
                fv += forces[n * s.grid.sw + NodeRecord::<3>::force(a)] * s.grid.vel[n * 6 + 3 + a];
            }
        }
        s.centroid_velocity(1);
        s.averaged_velocity_gradient(1);
        let mut work = 0.0f64;
        for p in 0..s.parts.len() {
            let l = gradient_at_3d(&s, p);
            let sigma = s.materials[0].stress_of_def_grad(&s.parts.def_grad[p]);
            work -= s.parts.volume(p, &s.kinds.vol0) * sigma.component_mul(&l).sum();
        }
        let rel = (fv - work).abs() / fv.abs().max(work.abs());
        assert!(rel < 1e-12, "Σ f·v = {fv}, −Σ V σ:L = {work}");
        assert!(fv.abs() > 1e-3, "a test with work in it: {fv}");
    }

    /// A regular lattice of 2 × 2 per cell filling a periodic box, as seeded and with
    /// every particle moved by the same 0.3 of a cell: a hat's weighted sum of the
    /// offsets over such a lattice vanishes for any shift, so `d = 0` at every node,
    /// those on the seam included, to round-off. Offsets measured from one lower
    /// corner would put the seam's nodes a box length off.
    #[test]
    fn offsets_are_continuous_across_a_periodic_seam() {
        for shift in [0.0, 0.3 * 0.25] {
            let mut s = periodic_box("gradient = \"mpmcg\"\ncentroid_passes = 4", "");
            for p in 0..s.parts.len() {
                for (a, len) in [2.0, 1.0].into_iter().enumerate() {
                    s.parts.x[p][a] = (s.parts.x[p][a] + shift).rem_euclid(len);
                }
            }
            s.scatter(false, true);
            s.centroid_offsets();
            let mut offsets = Vec::new();
            let mut seam = 0;
            s.for_owned(|n, c| {
                offsets.push([s.grid.centroid_d[2 * n], s.grid.centroid_d[2 * n + 1]]);
                seam += usize::from(s.block.node_lo[0] + c[0] as i64 == 0);
            });
            assert_eq!(offsets.len(), 8 * 4);
            assert_eq!(seam, 4, "the seam's nodes are owned");
            let worst = offsets
                .iter()
                .map(|d| d[0].abs().max(d[1].abs()))
                .fold(0.0, f64::max);
            assert!(worst < 1e-12, "shift {shift}: |d| up to {worst:e}");
        }
    }
}
