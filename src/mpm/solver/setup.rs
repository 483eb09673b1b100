//! Building a solver: the geometry, seeding a block's particles, the grid's fields and the tiles a body occupies.

use super::*;

impl<'c, const D: usize> Solver<'c, D> {
    /// The grid geometry of a scene.
    pub fn geometry(scene: &Scene) -> Geom<D> {
        let g = &scene.grid;
        let periodic: [bool; D] =
            std::array::from_fn(|a| g.boundary.face(a, false) == Face::Periodic);
        Geom::new(
            std::array::from_fn(|a| g.lower[a]),
            std::array::from_fn(|a| g.upper[a]),
            std::array::from_fn(|a| g.cells[a]),
            periodic,
        )
    }

    /// A solver at t = 0 on the given particles of this rank's block (they must lie in
    /// its cells and carry the arrays of [`Carries::for_scene`]).
    pub fn with_particles(
        scene: &Scene,
        comm: &'c dyn Communicator,
        layout: Layout<D>,
        mut parts: Particles<D>,
    ) -> Self {
        parts.fit();
        let g = &scene.grid;
        let faces: [[Face; 2]; D] =
            std::array::from_fn(|a| [g.boundary.face(a, false), g.boundary.face(a, true)]);
        let geom = Self::geometry(scene);
        let (block, tiles) = Self::block_and_tiles(&layout, comm.rank());
        let kinds = Kinds::of_scene(scene, &geom);
        let materials = kinds.materials(&Material::all(&scene.plan.materials));
        let benchmark = Benchmark::<D>::new(scene);
        let carries = Carries::for_scene(scene);
        let migrator = Migrator::new(&layout, &block, Particles::<D>::record_width(carries));
        let mut s = Self {
            comm,
            geom,
            layout,
            block,
            faces,
            parts,
            materials,
            kinds,
            benchmark,
            gravity: scene
                .gravity
                .as_ref()
                .map_or(Vector::<D>::zeros(), |gr| vector::<D>(&gr.value)),
            scheme: GradientScheme::of(scene.method.gradient, scene.method.quadrature),
            update: scene.method.update,
            phases: Vec::new(),
            flip: scene.method.flip,
            cfl: match (scene.time.cfl, scene.time.dt) {
                (None, None) => Some(0.2),
                (c, _) => c,
            },
            fixed_dt: scene.time.dt,
            end: scene.time.end,
            stop_at: f64::INFINITY,
            t: 0.0,
            step: 0,
            dt: 0.0,
            rebalances: 0,
            clock: Clock::default(),
            traffic_before: Default::default(),
            last_imbalance: 1.0,
            speeds: Vec::new(),
            external_work: 0.0,
            max_speed: 0.0,
            speed_agreed: false,
            tiles,
            xpic: scene.method.xpic.map(|m| m as usize),
            centroid_passes: scene.method.centroid_passes as usize,
            body_force_over_domain: scene.plan.body_force_over_domain,
            sharpen: scene.method.sharpen,
            null_space: scene
                .snapshot_plan()
                .filter(|o| o.fields.contains(&crate::input::scene::Field::NullVelocity))
                .map(|_| NullSpace::new()),
            grid: GridFields::new(),
            place: Placement::new(),
            migrator,
            carries,
            scratch: Scratch::new(),
        };
        s.resolve_phases();
        s.setup_grid();
        let mut mmin = [(0..s.parts.len())
            .map(|p| s.particle_mass(p))
            .fold(f64::INFINITY, f64::min)];
        s.comm.min_f64(&mut mmin);
        s.grid.mass_floor = if mmin[0].is_finite() {
            1e-12 * mmin[0]
        } else {
            0.0
        };
        s.max_speed = s.compute_max_speed();
        s
    }

    /// The cells `[lo, hi)` along the last axis that the slab order spans: the block's,
    /// trimmed to the particles' runs in whole pairs of slabs (a slab's colour is its
    /// parity, so every slab keeps its colour and its particles' order, and the nodal
    /// sums are unchanged), so that a huge box around a small body costs the body's
    /// slabs. The parallel split's tie-break counts slabs, so where two splits are
    /// equally good a pass's reductions may group differently than over the whole
    /// block (deterministic either way). Trimmed within the block: a run outside it
    /// still fails the slab order's check.
    fn occupied_slabs(&self, thick: usize) -> (usize, usize) {
        let last = D - 1;
        let (lo, hi) = (self.block.cell_lo[last], self.block.cell_hi[last]);
        let (mut first, mut end) = (i64::MAX, i64::MIN);
        for run in self.place.cell_runs.iter().flatten() {
            let c = i64::from(run.cell[last]);
            first = first.min(c);
            end = end.max(c + 1);
        }
        if first > end {
            return (lo, lo + 1); // no particles: one empty slab
        }
        if first < lo as i64 || end > hi as i64 {
            return (lo, hi); // a run outside the block, which the order's check stops
        }
        let pair = 2 * thick;
        let from = lo + (first as usize - lo) / pair * pair;
        (from, end as usize)
    }

    /// This rank's block and the tile storage of its grid. Which halo nodes are stored
    /// and exchanged is agreed with the peers every time the tiles are activated
    /// ([`Block::activate_halo`]).
    pub(super) fn block_and_tiles(layout: &Layout<D>, rank: usize) -> (Block<D>, Tiles<D>) {
        let block = Block::new(layout, rank);
        let tiles = Tiles::new(block.node_dims, block.own_lo);
        (block, tiles)
    }

    /// Replace the number of centroid passes (tests), with the step and the scatter
    /// records that go with it.
    #[cfg(test)]
    pub(super) fn set_centroid_passes(&mut self, passes: usize) {
        self.centroid_passes = passes;
        self.resolve_phases();
        self.setup_grid();
    }

    /// Replace the sharpening's β (tests), with the scratch that goes with it.
    #[cfg(test)]
    pub(super) fn set_sharpen(&mut self, beta: f64) {
        self.sharpen = beta;
        self.setup_grid();
    }

    /// Replace the scheme's α (tests: α ≡ 0 is `averaged`, α ≡ 1 is `mpm`).
    pub fn set_alpha(&mut self, alpha: Alpha) {
        self.scheme.alpha = alpha;
        self.resolve_phases();
        self.setup_grid();
    }

    /// Replace the node mass below which a node counts as empty (tests: with 0 every
    /// node a particle touches takes its force, and momentum is kept to round-off).
    pub fn set_mass_floor(&mut self, floor: f64) {
        self.grid.mass_floor = floor;
    }

    pub(super) fn setup_grid(&mut self) {
        let two = self.scheme.two_step();
        self.grid.sw = NodeRecord::<D>::width(two, two && self.centroid_passes > 0);
        if two {
            for q in 0..(1 << D) {
                for r in 0..(1 << D) {
                    self.grid.cell_k[r][q] = cell_integral::<D>(&self.geom.h, r, q);
                    // ∫_c S_r S_q dv: h/3 per axis on which the corners agree, h/6 else.
                    self.grid.cell_m[r][q] = (0..D)
                        .map(|a| {
                            let same = (r >> a) & 1 == (q >> a) & 1;
                            self.geom.h[a] / if same { 3.0 } else { 6.0 }
                        })
                        .product();
                }
            }
            for q in 0..(1 << D) {
                for b in 0..D {
                    let bit = |c: usize| ((c >> b) & 1) as f64;
                    self.grid.cell_md[q][b] = (0..1 << D)
                        .map(|r| self.grid.cell_m[q][r] * (bit(q) - bit(r)) * self.geom.h[b])
                        .sum();
                }
            }
        }
        self.size_fields();
    }

    /// Size the grid fields to the storage of the active tiles, all zero. Vectors keep
    /// their capacity, so storage grows amortised and a step allocates only when the
    /// active set outgrows every earlier one.
    pub(super) fn size_fields(&mut self) {
        let nn = self.tiles.nodes();
        // Particles name their cell's node by a u32 (`ptile`); 2^32 nodes of grid
        // storage would take at least 32 GiB per field component anyway.
        assert!(
            nn <= u32::MAX as usize,
            "{nn} stored grid nodes on one rank: more than a 32-bit node index can name"
        );
        let two = self.scheme.two_step();
        let fit = |v: &mut Vec<f64>, len: usize| {
            v.clear();
            v.resize(len, 0.0);
        };
        fit(&mut self.grid.scat, nn * self.grid.sw);
        fit(&mut self.grid.vel, nn * VelRecord::<D>::WIDTH);
        let n2 = if two { nn } else { 0 };
        // σ̄ lives in `vel` and L̄, v̄ in `scat` for part of a step (`averaged_force`,
        // `avg`).
        const {
            assert!(NodeRecord::<D>::SYM <= VelRecord::<D>::WIDTH);
            assert!(AvgRecord::<D>::WIDTH <= NodeRecord::<D>::width(true, false));
        }
        let nx = if self.xpic.is_some() { nn * D } else { 0 };
        fit(&mut self.grid.xpic_add, nx);
        fit(&mut self.grid.xpic_term, nx);
        fit(&mut self.grid.fill, n2);
        fit(&mut self.grid.cell_w, n2);
        fit(&mut self.grid.node_vol, n2);
        let ns = if two && self.sharpen > 0.0 {
            nn * (D * D).max(NodeRecord::<D>::SYM)
        } else {
            0
        };
        fit(&mut self.grid.sharp, ns);
    }

    /// Activate the tiles the particles' nodes lie in (GIMP reaches one node below
    /// the cell and two above), give each particle its cell's node in the storage,
    /// and group the particles by slab for the scatter.
    pub(super) fn activate_tiles(&mut self) {
        self.tiles.begin();
        // Located by `relocate` if nothing moved, left or arrived since.
        let located = std::mem::take(&mut self.place.located);
        if !located {
            self.locate_all();
        } else if cfg!(debug_assertions) {
            // The tests' builds check that claim: locating again changes nothing.
            let runs = self.place.cell_runs.clone();
            self.locate_all();
            assert!(
                runs == self.place.cell_runs,
                "the particles' location kept from the wrap is stale at step {}",
                self.step
            );
        }
        // The slab order first: it checks that every run's cell is in the block.
        let thick = kernel::slab_thickness_for(self.scheme.wide());
        let (lo, hi) = self.occupied_slabs(thick);
        let index = self.place.slabs.begin(lo, hi, thick);
        self.place.slabs.finish(&RunSlabs {
            runs: &self.place.cell_runs,
            count: self.parts.len(),
            index,
        });
        // The tiles of the runs' cells.
        self.touch_runs();
        // The halo nodes any rank's particles come near, stored on every rank that
        // holds them (a neighbour's particles may need nodes this rank's do not).
        self.block.activate_halo(self.comm, &mut self.tiles);
        let changed = self.tiles.finish();
        self.block.map_active_halo(&self.tiles);
        if changed {
            // New tiles have new slots.
            self.size_fields();
        }
        self.run_nodes();
        // Every particle gets its run's node.
        self.place
            .ptile
            .par_chunks_mut(LOCATE_CHUNK)
            .zip(self.place.cell_runs.par_iter())
            .enumerate()
            .for_each(|(k, (tile, runs))| {
                let base = k * LOCATE_CHUNK;
                for (r, run) in runs.iter().enumerate() {
                    let end = runs
                        .get(r + 1)
                        .map_or(tile.len(), |e| (e.first as usize) - base);
                    let a = run.first as usize - base;
                    // Runs are short where particles cross cells (the vortex between
                    // sorts: 1 to 3), and `fill`'s set-up per run cost more than its
                    // stores. Four stores instead, past the run's end if it is
                    // shorter: the next run, in order, writes at least its own first
                    // four.
                    match tile.get_mut(a..a + 4) {
                        Some(t) if end - a <= 4 => t.fill(run.node),
                        _ => tile[a..end].fill(run.node),
                    }
                }
            });
    }
}

#[cfg(test)]
pub(super) mod sparse_tests {
    //! The sparse grid: storage follows the body, not the box.
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, SerialComm};

    /// The prefetch runs of a padded tile name each padded node exactly once, each run
    /// a range of consecutive offsets in one tile: the tile itself one run of all its
    /// nodes, and 15 runs in 2D, 87 in 3D where there were 36 and 216 nodes.
    #[test]
    pub(super) fn prefetch_runs_cover_the_padded_tile_once() {
        fn check<const D: usize, const NP: usize>() -> usize {
            let map = pad_map::<D, NP>();
            let (runs, count) = prefetch_runs(&map);
            let mut named: Vec<(usize, usize)> = runs[..count]
                .iter()
                .flat_map(|&(t, w, len)| (w..w + len).map(move |o| (t, o)))
                .collect();
            let mut want = map.to_vec();
            named.sort_unstable();
            want.sort_unstable();
            assert_eq!(named, want, "{D}D: the runs are the padded nodes");
            let centre = (0..D).map(|a| 3usize.pow(a as u32)).sum::<usize>();
            assert!(runs[..count].contains(&(centre, 0, TILE.pow(D as u32))));
            count
        }
        assert_eq!(check::<2, 36>(), 15);
        assert_eq!(check::<3, 216>(), 87);
    }

    /// A spinning, drifting neo-Hookean box body [0.25, 0.75]^D in a box [0, upper]^D
    /// with `cells` cells per axis (the scenes below all have h = 1/16).
    pub(in crate::mpm::solver) fn text(
        dim: usize,
        upper: f64,
        cells: usize,
        gradient: &str,
    ) -> String {
        let v = |x: f64| format!("[{}]", vec![format!("{x:?}"); dim].join(", "));
        let faces: Vec<String> = ["x", "y", "z"][..dim]
            .iter()
            .flat_map(|a| {
                [
                    format!("{a}_lower = \"slip\""),
                    format!("{a}_upper = \"slip\""),
                ]
            })
            .collect();
        let cells_list = format!("[{}]", vec![cells.to_string(); dim].join(", "));
        let (vel, grad) = if dim == 2 {
            ("[0.5, -0.3]", "[[0.0, -1.0], [1.0, 0.0]]")
        } else {
            (
                "[0.5, -0.3, 0.2]",
                "[[0.0, -1.0, 0.0], [1.0, 0.0, 0.5], [0.0, -0.5, 0.0]]",
            )
        };
        format!(
            r#"
name = "sparse"
dim = {dim}
[time]
end = 1.0
dt = 2.0e-4
[method]
gradient = "{gradient}"
update = "musl"
[grid]
lower = {lo}
upper = {up}
cells = {cells}
boundary = {{ {faces} }}
[[materials]]
name = "rubber"
model = "neo_hookean"
density = 1.0
youngs_modulus = 1.0e3
poisson_ratio = 0.3
[[bodies]]
material = "rubber"
shape = {{ box = {{ lower = {blo}, upper = {bhi} }} }}
particles_per_cell = 2
velocity = {vel}
velocity_gradient = {{ value = {grad}, about = {c} }}
"#,
            lo = v(0.0),
            up = v(upper),
            cells = cells_list,
            faces = faces.join(", "),
            blo = v(0.25),
            bhi = v(0.75),
            c = v(0.5),
        )
    }

    pub(super) fn run<const D: usize>(
        upper: f64,
        cells: usize,
        gradient: &str,
        steps: usize,
    ) -> (Solver<'static, D>, Vec<Vector<D>>) {
        let sc = scene::parse(&text(D, upper, cells, gradient), "sparse").unwrap();
        let layout = Layout::choose([cells; D], [false; D], 1).unwrap();
        let mut s = Solver::<D>::new(&sc, &SerialComm, layout);
        // Initial positions by particle id.
        let mut x0 =
            vec![Vector::<D>::zeros(); s.parts.id.iter().max().map_or(0, |&m| m + 1) as usize];
        for p in 0..s.parts.len() {
            x0[s.parts.id[p] as usize] = s.parts.x[p];
        }
        for _ in 0..steps {
            s.advance().unwrap();
        }
        (s, x0)
    }

    /// The same body in a 16^D box and in a 65536² (2D) or 4096³ (3D) box, at the same
    /// cells: the huge box stores exactly the tiles of the tight one (memory follows
    /// the body; the box's node count would overflow a 32-bit index), and every
    /// particle ends bit-identical after 25 steps (a sort included), for every scheme
    /// in 2D and MPMCG in 3D.
    #[test]
    pub(super) fn huge_box_stores_only_the_body_and_gives_the_same_result() {
        for g in ["mpmcg", "mpm", "gimp", "averaged"] {
            let tight = run::<2>(1.0, 16, g, 25);
            let huge = run::<2>(4096.0, 65536, g, 25);
            compare(&tight, &huge, g);
        }
        let tight = run::<3>(1.0, 16, "mpmcg", 25);
        let huge = run::<3>(256.0, 4096, "mpmcg", 25);
        compare(&tight, &huge, "mpmcg 3D");
        let tight = run::<3>(1.0, 16, "gimp", 25);
        let huge = run::<3>(256.0, 4096, "gimp", 25);
        compare(&tight, &huge, "gimp 3D");
    }

    /// The particle loops form the hat functions' local coordinate from the position
    /// and the cell of the tile pass's corner node (`CellAt`, `Ctx::local`):
    /// that cell is `Geom::locate`'s and that coordinate its ξ, to the bit, for every
    /// particle after steps that moved them across cells and a sort, in a tight
    /// box and in a huge one (a block of more than 2^32 cells in 3D, whose sort forms
    /// its keys where it asks for them).
    #[test]
    pub(super) fn the_loops_local_coordinate_is_geom_locate_s() {
        fn check<const D: usize>(upper: f64, cells: usize) {
            let (mut s, _) = run::<D>(upper, cells, "mpmcg", 25);
            s.sort();
            s.activate_tiles();
            let ctx = ctx!(s);
            // As the loops ask: one `CellAt` over the particles in order.
            let mut at = kernel::CellAt::<D>::new();
            for (p, x) in s.parts.x.iter().enumerate() {
                let (c, xi) = s.geom.locate(&std::array::from_fn(|a| x[a]));
                let cell = *at.of(&ctx, s.place.ptile[p]);
                assert_eq!(cell, ctx.cell_of(s.place.ptile[p]));
                assert_eq!(
                    cell,
                    c.map(|c| c as f64),
                    "{D}D, {cells} cells, particle {p}"
                );
                assert_eq!(
                    ctx.local(x, &cell).map(f64::to_bits),
                    xi.map(f64::to_bits),
                    "{D}D, {cells} cells, particle {p}"
                );
            }
        }
        check::<2>(1.0, 16);
        check::<2>(4096.0, 65536);
        check::<3>(1.0, 16);
        check::<3>(256.0, 4096);
    }

    pub(super) fn compare<const D: usize>(
        (tight, x0): &(Solver<'static, D>, Vec<Vector<D>>),
        (huge, _): &(Solver<'static, D>, Vec<Vector<D>>),
        what: &str,
    ) {
        let box_nodes: f64 = huge.geom.cells.iter().map(|&c| c as f64 + 1.0).product();
        assert!(
            box_nodes > u32::MAX as f64,
            "{what}: the box is meant to be huge"
        );
        assert_eq!(
            tight.tiles.active(),
            huge.tiles.active(),
            "{what}: active tiles"
        );
        assert_eq!(
            tight.grid.scat.len(),
            huge.grid.scat.len(),
            "{what}: grid storage"
        );
        // The body covers 8^D of the 16^D cells; its tiles with their margin stay
        // below the whole tight box's tiles.
        let all_tiles = 17usize.div_ceil(decomposition::TILE).pow(D as u32);
        assert!(
            huge.tiles.active() <= all_tiles,
            "{what}: {} tiles",
            huge.tiles.active()
        );
        assert_eq!(tight.parts.len(), huge.parts.len());
        for p in 0..tight.parts.len() {
            assert_eq!(tight.parts.id[p], huge.parts.id[p]);
            assert_eq!(
                tight.parts.x[p], huge.parts.x[p],
                "{what}: particle {p} position"
            );
            assert_eq!(
                tight.parts.v[p], huge.parts.v[p],
                "{what}: particle {p} velocity"
            );
            assert_eq!(
                tight.parts.stress_of(p, &tight.materials),
                huge.parts.stress_of(p, &huge.materials),
                "{what}: stress"
            );
        }
        // The body moved: the comparison is not between two states at rest.
        // (Particles are sorted by cell as they cross cells: match them by id.)
        let start = |id: u64| x0[id as usize];
        let moved = (0..tight.parts.len())
            .any(|p| (tight.parts.x[p] - start(tight.parts.id[p])).norm() > 1e-3);
        assert!(moved, "{what}: the body did not move");
    }

    /// The active set follows the material: a body that travels several tiles keeps
    /// about the same number of active tiles, which never covers the box.
    #[test]
    pub(super) fn active_tiles_follow_a_travelling_body() {
        let sc = scene::parse(&text(2, 8.0, 128, "mpmcg"), "sparse").unwrap();
        let layout = Layout::choose([128; 2], [false; 2], 1).unwrap();
        let mut s = Solver::<2>::new(&sc, &SerialComm, layout);
        for p in 0..s.parts.len() {
            s.parts.v[p] = Vector::<2>::new(40.0, 25.0);
        }
        s.advance().unwrap();
        let x0 = s.parts.x[0];
        let id0 = s.parts.id[0];
        let first = s.tiles.active();
        let mut changes = 0;
        let mut last = s.tiles.active();
        for _ in 0..200 {
            s.advance().unwrap();
            changes += usize::from(s.tiles.active() != last);
            last = s.tiles.active();
            // 8 × 8 cells of body: at most 4 × 4 tiles plus one row and column.
            assert!(last <= 25, "{last} active tiles");
        }
        let p = (0..s.parts.len()).find(|&p| s.parts.id[p] == id0).unwrap();
        let shift = s.parts.x[p] - x0;
        assert!(shift[0] > 1.0, "the body travelled {shift:?}");
        assert!(first <= 25 && changes > 0);
        let box_tiles = 129usize.div_ceil(decomposition::TILE).pow(2);
        assert!(last * 20 < box_tiles);
    }
}
