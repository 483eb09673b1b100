//! Node passes: domain weights, the averaged force, grid velocities with their boundary conditions, and the time step.

use super::*;

/// The smallest CFL step as a share of the time left: below it the run would need more
/// than 1e12 steps, which no real scene asks for; the signal speed has blown up.
pub(super) const MIN_STEP_SHARE: f64 = 1e-12;

/// The share θ of a node's support that counts as full in the fill fraction
/// `φ_k = min(1, Σ_p S_k(x_p) v_p / (θ ∫ S_k dv))`, the fraction of the support the
/// particles cover. Below 1 by the particle quadrature's error in `Σ_p S_k v_p`, so
/// that interior nodes stay full: with θ = 1 they dip below 1 as particles cross cells
/// and the 1D MMS error at 128 cells grows by 18 %; with θ = 0.9 it is unchanged. A node
/// on a flat surface is about half full. θ = ½ (surface nodes count as full) was 3 %
/// less accurate on the vortex at 128 cells; no θ from ¼ to 1 keeps the 2 × 2
/// cantilevers whole (README, Hard cases).
pub const FULL_FILL: f64 = 0.9;

impl<'c, const D: usize> Solver<'c, D> {
    /// Iterate the owned nodes of the active tiles: storage index and local coordinates.
    pub(super) fn for_owned(&self, mut f: impl FnMut(usize, [usize; D])) {
        let b = &self.block;
        let tn = self.tiles.tile_nodes();
        for slot in 1..self.tiles.slots() {
            for o in 0..tn {
                if let Some(c) = self.tiles.local(slot, o) {
                    if (0..D).all(|a| c[a] >= b.own_lo[a] && c[a] < b.own_hi[a]) {
                        f(slot * tn + o, c);
                    }
                }
            }
        }
    }

    /// The grid fields the node passes read, shareable between threads.
    pub(super) fn nodes(&self) -> NodeView<'_, D> {
        NodeView {
            tiles: &self.tiles,
            geom: &self.geom,
            own_lo: self.block.own_lo,
            own_hi: self.block.own_hi,
            node_lo: self.block.node_lo,
            faces: self.faces,
            cell_w: &self.grid.cell_w,
            cell_k: &self.grid.cell_k,
            cell_m: &self.grid.cell_m,
            cell_md: &self.grid.cell_md,
        }
    }

    /// The domain of MPMCG's grid integrals as a weight `w_c ∈ [0, 1]` per cell that
    /// changes continuously as particles move, and the node volumes `V_j = ∫ w S_j dv`.
    ///
    /// A node's fill fraction `φ_k = min(1, Σ_p S_k(x_p) v_p / (θ ∫ S_k dv))` measures
    /// how much of its support the material covers (θ = [`FULL_FILL`]); a cell weighs
    /// the smallest fill of its corners. Why the minimum: a cell with a corner that no
    /// particle touches gets weight 0, so every node of the stencil of `∫ w S_j ∇S_i`
    /// carries mass and a velocity, and a uniform or linear velocity field gives its
    /// exact gradient at free surfaces (a weight that reached one cell beyond the
    /// material, such as `Σ_k φ_k S_k`, would read the zero velocity of massless nodes
    /// and strain a translating body). It also bounds the force a nearly empty node
    /// receives through the grid step by its own fill. `Σ_i G_i = 0` and
    /// `Σ_i x_i ⊗ G_i = I` hold for any weights, because the same `w` enters `V_j` and
    /// `∫ w S_j ∇S_i`.
    pub(super) fn domain_weights(&mut self) {
        let sw = self.grid.sw;
        let col = NodeRecord::<D>::cover(sw);
        let mut fill = std::mem::take(&mut self.grid.fill);
        let (nodes, scat) = (self.nodes(), &self.grid.scat);
        // On the ghosts too, from the summed cover the scatter copied to them.
        nodes.par_near(&mut fill, 1, decomposition::GHOST, |n, c, fill| {
            let g: [i64; D] = std::array::from_fn(|a| nodes.node_lo[a] + c[a] as i64);
            let support = nodes.geom.node_volume(g);
            fill[0] = (scat[n * sw + col] / (FULL_FILL * support)).min(1.0);
        });
        self.grid.fill = fill;
        // Cells whose corners all lie in the local box (the others are never visited),
        // over the active tiles: a cell with its lower corner in a tile that is not
        // active has an untouched corner, so weight 0, which its zero tile reads.
        let dims = self.block.node_dims;
        let tn = self.tiles.tile_nodes();
        let mut cw = std::mem::take(&mut self.grid.cell_w);
        let (tiles, fill) = (&self.tiles, &self.grid.fill);
        cw[..tiles.slots() * tn]
            .par_chunks_mut(tn)
            .enumerate()
            .skip(1)
            .with_min_len(4)
            .for_each(|(slot, cw)| {
                let mut corners = [0; 8];
                // A tile whose every cell has its corners in the box needs no test per
                // node (as `NodeView::inner_first`).
                let whole = tiles
                    .local_first(slot)
                    .is_some_and(|l| (0..D).all(|a| l[a] + TILE < dims[a]));
                for (o, w) in cw.iter_mut().enumerate() {
                    let n = slot * tn + o;
                    let inside = whole
                        || tiles
                            .local(slot, o)
                            .is_some_and(|l| (0..D).all(|a| l[a] + 1 < dims[a]));
                    *w = if inside {
                        tiles.octant(n, true, &mut corners);
                        corners[..1 << D]
                            .iter()
                            .map(|&c| fill[c])
                            .fold(1.0, f64::min)
                    } else {
                        0.0
                    };
                }
            });
        self.grid.cell_w = cw;
        let share = self.geom.cell_volume() / (1 << D) as f64;
        let mut vol = std::mem::take(&mut self.grid.node_vol);
        let (nodes, cell_w) = (self.nodes(), &self.grid.cell_w);
        // Out to the first ghost layer, whose σ̄ the averaged force reads.
        nodes.par_near(&mut vol, 1, 1, |n, c, vol| {
            // The cells around the node, corners in order (as `NodeView::row_cells`).
            let mut cells = [0; 8];
            nodes.tiles.octant(n, false, &mut cells);
            let mut v = 0.0;
            for (q, &cell) in cells[..1 << D].iter().enumerate() {
                if (0..D).all(|a| c[a] >= (q >> a) & 1) && cell_w[cell] > 0.0 {
                    v += cell_w[cell];
                }
            }
            vol[0] = v * share;
        });
        self.grid.node_vol = vol;
    }

    /// Node → node step of the internal force: `f_i −= Σ_j σ̄_j · ∫ w S_j ∇S_i dv`,
    /// assembled cell by cell over the weighted cells around each owned node.
    pub(super) fn averaged_force(&mut self) {
        let (sw, sym) = (self.grid.sw, NodeRecord::<D>::SYM);
        // σ̄_j = T_j / V_j on the owned nodes and the first ghost layer (the ghosts hold
        // the summed T_j and their own V_j, so the same bits as the owner's): its upper
        // triangle, in the grid velocities' storage, which the grid update after this
        // rewrites (SYM numbers fit in its 2 D a node).
        let mut vel = std::mem::take(&mut self.grid.vel);
        let sigma = &mut vel[..self.grid.node_vol.len() * sym];
        let (nodes, scat, node_vol) = (self.nodes(), &self.grid.scat, &self.grid.node_vol);
        nodes.par_near(sigma, sym, 1, |n, _, rec| {
            let v = node_vol[n];
            // One division per entry: σ̄ is symmetric to the bit, which `force_tiles`
            // relies on.
            for a in 0..D {
                for b in a..D {
                    rec[kernel::sym_index::<D>(a, b)] = if v > 0.0 {
                        scat[n * sw + NodeRecord::<D>::stress_sum(a, b)] / v
                    } else {
                        0.0
                    };
                }
            }
        });
        // (The force reads σ̄ on the first ghost layer, which the sharpening's ghost copy
        // refills.)
        self.sharpen_averages((sigma, sym, sym));
        let mut scat = std::mem::take(&mut self.grid.scat);
        let nodes = self.nodes();
        by_pad!(D, nodes, force_tiles, &mut scat, sw, sigma);
        self.grid.scat = scat;
        self.grid.vel = vel;
    }

    /// Under `[method] sharpen`, the first `comps` numbers of each record of `width` in
    /// `field` (nodal averages whose ghosts hold theirs) sharpened on the owned nodes
    /// ([`NodeView::sharpen`]) and then copied to the ghosts; else nothing.
    fn sharpen_averages(&mut self, (field, width, comps): (&mut [f64], usize, usize)) {
        if self.sharpen <= 0.0 {
            return;
        }
        let mut sharp = std::mem::take(&mut self.grid.sharp);
        let nodes = self.nodes();
        let node_vol = &self.grid.node_vol;
        nodes.sharpen((field, width, comps), self.sharpen, node_vol, &mut sharp);
        self.grid.sharp = sharp;
        self.block.ghost_copy(self.comm, field, width);
    }

    /// Grid velocities from momentum (and, if `dt > 0`, forces), with boundary
    /// conditions, on owned nodes; then copied to ghosts.
    pub(super) fn grid_velocity(&mut self, dt: f64) {
        let sw = self.grid.sw;
        let mut vel = std::mem::take(&mut self.grid.vel);
        let (nodes, scat, floor) = (self.nodes(), &self.grid.scat, self.grid.mass_floor);
        // Both slots of a node's record (`VelRecord`).
        nodes.par_owned(&mut vel, VelRecord::<D>::WIDTH, |n, c, v| {
            let rec = &scat[n * sw..(n + 1) * sw];
            let m = rec[NodeRecord::<D>::MASS];
            if m > floor {
                for a in 0..D {
                    v[a] = rec[NodeRecord::<D>::momentum(a)] / m;
                    v[D + a] = v[a] + dt * rec[NodeRecord::<D>::force(a)] / m;
                }
                nodes.apply_bc(c, v);
            } else {
                v.iter_mut().for_each(|x| *x = 0.0);
            }
        });
        self.block.ghost_copy(self.comm, &mut vel, 2 * D);
        self.grid.vel = vel;
    }

    /// Fixed and slip faces on both velocity slots of a node ([`NodeView::apply_bc`]).
    pub(super) fn apply_bc(&self, c: [usize; D], v: &mut [f64]) {
        self.nodes().apply_bc(c, v);
    }

    /// `L̄_j = (1/V_j) Σ_i v_i ⊗ ∫ w S_j ∇S_i dv` on owned nodes from velocity slot
    /// `slot`, then the smoothed velocity
    /// `v̄_j = (1/V_j) Σ_i (v_i + L̄_j (x_j − x_i)) ∫ w S_j S_i dv` (the weighted mean of the
    /// grid velocity over the node's support, corrected by L̄_j to the node, so that a
    /// linear field gives its own nodal value; walls as on the grid velocity), both in
    /// `avg` ([`AvgRecord`]), out to the ghosts the particles read. The particles'
    /// velocity gradient and the velocity they move with ([`kernel::moving_velocity`])
    /// are built from these.
    ///
    /// A particle's hat functions reach the first ghost layer, where the ghosts form
    /// their own L̄ and v̄ from the velocities of the second (the same bits as their
    /// owners', as σ̄ in [`Solver::averaged_force`]), and so does the sharpening, whose
    /// ghost copy follows: no copy of their own. Only the domain rule's particles, which
    /// reach the second layer, need it.
    pub(super) fn averaged_velocity_gradient(&mut self, slot: usize) {
        let aw = AvgRecord::<D>::WIDTH;
        let copy = self.scheme.wide() && self.sharpen <= 0.0;
        let mut scat = std::mem::take(&mut self.grid.scat);
        let avg = &mut scat[..self.grid.node_vol.len() * aw];
        let nodes = self.nodes();
        by_pad!(
            D,
            nodes,
            gradient_tiles,
            avg,
            &self.grid.vel,
            slot,
            &self.grid.node_vol,
            usize::from(!copy)
        );
        if copy {
            self.block.ghost_copy(self.comm, avg, aw);
        }
        self.sharpen_averages((avg, aw, D * D));
        self.grid.scat = scat;
    }

    /// Largest wave speed plus particle speed on this rank.
    pub(super) fn compute_max_speed(&self) -> f64 {
        let mut m = 0.0f64;
        for p in 0..self.parts.len() {
            let kind = self.parts.kind[p] as usize;
            let j = self.parts.volume_ratio(p, &self.kinds.vol0);
            m = m.max(self.materials[kind].wave_speed(j) + self.parts.v[p].norm());
        }
        m
    }

    /// Pick the step size: fixed, or the CFL number over the fastest signal anywhere.
    pub(super) fn choose_dt(&mut self) -> Result<f64, Failure> {
        let mut s = [self.max_speed];
        if !self.speed_agreed {
            self.comm.max_f64(&mut s);
        }
        let dt = match (self.fixed_dt, self.cfl) {
            (Some(dt), _) => dt,
            (None, Some(c)) => c * self.geom.min_h() / s[0].max(1e-300),
            (None, None) => unreachable!("a CFL number is always set without dt"),
        };
        // A signal speed that overflowed (or a blown-up velocity) gives a CFL step of 0
        // or one so small that the run would never end: that is an instability, not a
        // run to wait for. The speed is the maximum over ranks, so all agree. (Checked
        // before the step is shortened to land on an output or end time, which may
        // legitimately leave a sliver.)
        let collapsed = self.fixed_dt.is_none() && dt < MIN_STEP_SHARE * (self.end - self.t);
        if dt.is_nan() || dt <= 0.0 || collapsed {
            return Err(Failure::Unstable(format!(
                "the time step fell to {dt:e} at step {}, t = {:.6e} (more than {:e} steps to the end): the signal speed has blown up",
                self.step,
                self.t,
                1.0 / MIN_STEP_SHARE
            )));
        }
        // Land exactly on the end time (or the next snapshot's) rather than overshoot it.
        let target = if self.stop_at > self.t && self.stop_at < self.end {
            self.stop_at
        } else {
            self.end
        };
        let left = target - self.t;
        Ok(if dt > left || (left - dt) < 1e-9 * dt {
            left
        } else {
            dt
        })
    }
}
