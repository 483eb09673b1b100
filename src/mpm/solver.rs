//! The explicit MPM step on one rank's block, for every gradient scheme and update
//! order. Physics never sees MPI: it calls the decomposition layer at fixed points
//! (ghost sum after particle→grid, ghost copy before grid→particle and before the
//! node→node stencils, migration after the position update).

use crate::input::scene::{Face, Scene, Update};
use crate::mpm::kernel::lanes::LANES;
use crate::mpm::kernel::{
    self, AvgRecord, NodeRecord, SlabOrder, VelRecord, FROM_MOMENTUM, UPDATED,
};
use crate::mpm::particles::{self, Carries, Kinds, Particles};
use crate::mpm::remap::remap;
use crate::physics::benchmark::{Benchmark, Memo};
use crate::physics::material::Material;
use crate::physics::shape::{Alpha, Geom, GradientScheme};
use crate::physics::tensor::{vector, Mat, Vector};
use decomposition::tiles::TILE_LOG;
use decomposition::{Block, Communicator, Layout, Migrator, Tiles, Traffic, TILE};
use rayon::prelude::*;
use std::mem::MaybeUninit;

/// The read-only context of the particle loops, borrowed field by field from a solver.
macro_rules! ctx {
    ($s:ident) => {
        kernel::Ctx {
            geom: &$s.geom,
            node_lo: $s.block.node_lo,
            tiles: &$s.tiles,
            gimp: $s.scheme.gimp,
            alpha: $s.scheme.alpha,
            materials: &$s.materials,
            kind_mass: &$s.kinds.mass,
            kind_vol0: &$s.kinds.vol0,
            gravity: $s.gravity,
            body_force: $s
                .benchmark
                .as_ref()
                .filter(|b| b.has_body_force())
                .map(|b| b.at($s.t).with_memo(&$s.memo)),
            faces: $s.faces,
            walls: false,
        }
    };
}

/// The particle arrays of a solver as splittable slices.
macro_rules! slices {
    ($s:ident) => {
        kernel::Slices {
            parts: $s.parts.slices(),
            dx: &mut $s.dx,
            tile: &$s.ptile,
            accel: &$s.accel,
        }
    };
}

/// Call a particle loop monomorphised for the nodes a particle touches: 2 per axis for
/// hat functions, 3 for GIMP.
macro_rules! by_nodes {
    ($gimp:expr, $f:ident, $($arg:expr),*) => {
        match ($gimp, D) {
            (false, 1) => kernel::$f::<D, 2, 2>($($arg),*),
            (false, 2) => kernel::$f::<D, 2, 4>($($arg),*),
            (false, _) => kernel::$f::<D, 2, 8>($($arg),*),
            (true, 1) => kernel::$f::<D, 3, 3>($($arg),*),
            (true, 2) => kernel::$f::<D, 3, 9>($($arg),*),
            (true, _) => kernel::$f::<D, 3, 27>($($arg),*),
        }
    };
}

/// Why a run cannot go on.
#[derive(Debug, Clone, PartialEq)]
pub enum Failure {
    /// Non-finite or non-physical state (NaN, J <= 0): the run became unstable.
    Unstable(String),
    /// A particle left a bounded grid.
    LeftGrid(String),
    /// Another rank failed; its own message says why.
    Elsewhere(String),
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::Unstable(m) => write!(f, "numerically unstable: {m}"),
            Failure::LeftGrid(m) => write!(f, "material left the grid: {m}"),
            Failure::Elsewhere(m) => write!(f, "{m}"),
        }
    }
}

/// Conserved and diagnostic totals over all ranks.
#[derive(Clone, Debug, Default)]
pub struct Totals {
    pub mass: f64,
    pub momentum: Vec<f64>,
    pub kinetic: f64,
    pub strain: f64,
    pub external_work: f64,
    /// Work dissipated by plastic flow.
    pub plastic_work: f64,
    pub particles: u64,
}

impl Totals {
    /// Kinetic plus stored energy minus the work done by external forces: constant for
    /// an exact integrator.
    pub fn total_energy(&self) -> f64 {
        self.kinetic + self.strain + self.plastic_work - self.external_work
    }
}

/// Corner offsets of a cell's 2^D nodes (bit `a` of the index = offset along axis `a`).
const CORNERS: usize = 8;

pub struct Solver<'c, const D: usize> {
    comm: &'c dyn Communicator,
    pub geom: Geom<D>,
    pub layout: Layout<D>,
    pub block: Block<D>,
    faces: [[Face; 2]; D],
    pub parts: Particles<D>,
    /// Per kind of particle: its material.
    pub materials: Vec<Material>,
    /// The kinds of particle: with `materials`, what each particle's kind index
    /// stands for (its reference volume and mass, [`particles::mass_of`]).
    pub kinds: Kinds,
    pub benchmark: Option<Benchmark<D>>,
    gravity: Vector<D>,
    /// The gradient scheme, resolved once: shape functions, α, two-step or not.
    pub scheme: GradientScheme,
    pub update: Update,
    /// The phases of a step: the update order's, resolved for the scheme.
    phases: Vec<Phase>,
    flip: f64,
    cfl: Option<f64>,
    fixed_dt: Option<f64>,
    pub end: f64,
    /// A time before `end` to land on exactly, like `end` (the next snapshot): the step
    /// that would pass it is shortened. Ignored unless `t < stop_at < end`.
    pub stop_at: f64,
    pub t: f64,
    pub step: u64,
    pub dt: f64,
    /// Times the block boundaries moved ([`Solver::relayout`]), restarts included.
    pub rebalances: u64,
    /// Halo and migration traffic of the blocks and migrators a rebalance replaced.
    traffic_before: (Traffic, Traffic),
    /// The particle imbalance [`Solver::rebalance`] found, or left if it moved the
    /// blocks.
    pub last_imbalance: f64,
    /// Accumulated work of gravity, body forces and walls (this rank's particles).
    external_work: f64,
    /// Maximum of wave speed + particle speed after the last update (this rank).
    max_speed: f64,
    // Grid fields, node-major over the storage of the active tiles (`tiles`): memory
    // and every grid pass follow the tiles the particles touch, not the box.
    /// Which tiles of the local node box are stored, and where.
    pub tiles: Tiles<D>,
    /// Per particle: storage index of its cell's lower corner node (set by a scatter
    /// of moved particles, valid until they move again). The particle loops form the
    /// local coordinate in that cell from the position ([`kernel::Ctx::local`]).
    ptile: Vec<u32>,
    /// Scatter records, `sw` numbers per node laid out as [`NodeRecord`] says; once
    /// the grid velocities are formed, two-step schemes' L̄ and v̄ ([`avg_of`]).
    scat: Vec<f64>,
    sw: usize,
    /// Per node: velocity before (D) and after (D) the force update; before the grid
    /// update, two-step schemes' σ̄ ([`Solver::averaged_force`]).
    vel: Vec<f64>,
    /// XPIC's order m, if the scene asks for it (else FLIP/PIC by `flip`).
    xpic: Option<usize>,
    /// Per node (D), XPIC only: the field `(m − 1) v − m v*` the gather adds to the
    /// updated grid velocity ([`Solver::xpic_field`]), and the recursion's current term.
    xpic_add: Vec<f64>,
    xpic_term: Vec<f64>,
    /// Per node: its fill fraction `φ_k` (see [`Solver::domain_weights`]), copied to
    /// the ghosts.
    fill: Vec<f64>,
    /// Per node: the domain weight `w_c` of the cell whose lower corner it is.
    cell_w: Vec<f64>,
    /// Per owned node: `V_j = ∫ w S_j dv`.
    node_vol: Vec<f64>,
    /// `∫_c S_j ∇S_i dv` over one cell for its corners j (first index) and i (second).
    cell_k: [[[f64; D]; CORNERS]; CORNERS],
    /// `∫_c S_j S_i dv` over one cell for its corners j and i.
    cell_m: [[f64; CORNERS]; CORNERS],
    /// `Σ_i ∫_c S_j S_i dv (x_j − x_i)` over one cell for its corner j.
    cell_md: [[f64; D]; CORNERS],
    /// Node mass below which a node is treated as empty.
    mass_floor: f64,
    // Scratch reused every step (no allocation in the loop once grown).
    slabs: SlabOrder,
    migrator: Migrator<D>,
    carries: Carries,
    keep: Vec<bool>,
    /// Per chunk of [`LOCATE_CHUNK`] particles, whether one left the grid or its block
    /// ([`Solver::wrap_and_flag`]).
    flagged: Vec<bool>,
    /// Whether the slab order's slabs and `cell_runs` hold the tile pass's
    /// location of every particle as it is now: `relocate` locates them with the wrap
    /// (one read of the positions, not two) and keeps it if none left or arrived; the
    /// sort, a new layout and the next tile pass, which uses it, end it.
    located: bool,
    record: Vec<f64>,
    dx: Vec<Vector<D>>,
    /// The sort's permutation and its in-place application's marks.
    perm: Vec<u32>,
    permuted: Vec<u64>,
    scratch: Vec<f64>,
    /// Each particle's external force per unit mass, kept by the step's scatter of
    /// forces for the work counted after it, where the scene has a body force (else
    /// empty: gravity is one vector).
    accel: Vec<Vector<D>>,
    /// The benchmark's factors of each particle's reference position (benchmarks
    /// only), refreshed at the start of a step.
    memo: Memo<D>,
    /// Per chunk of particles, the sums of [`Solver::errors_keeping_forces`].
    error_sums: Vec<[f64; 3]>,
    /// The tile pass's runs of particles in one cell, per chunk of [`LOCATE_CHUNK`]
    /// particles.
    cell_runs: Vec<Vec<CellRun<D>>>,
    /// How far this rank's particles are from their order by cell after the step's
    /// move: the runs whose cell comes before the previous run's, and the particles
    /// that arrived (appended at the end). A function of the particles' positions
    /// and order alone, so a restart sorts where the uninterrupted run did.
    disorder: usize,
    /// Sorts since the start (or the restart): what the tests ask of the criterion.
    sorts: u64,
    /// Per chunk of [`Solver::cell_runs`], the keys of the tiles its runs' nodes lie
    /// in (each once per chunk, mostly), gathered on threads and touched after.
    run_keys: Vec<Vec<u64>>,
}

/// One phase of a time step. A step is one of the lists in [`Update::phases`], without
/// the MPMCG node-to-node steps (`AveragedForce`, `AveragedGradient`) for one-step
/// schemes (MPM, GIMP): [`Solver::two_step`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Phase {
    /// Particle → grid: mass, momentum, the domain fill and, if `forces`, the forces
    /// and the averaged stress sums; `moved`: the particles moved since the last scatter
    /// (rebuild the slab order). Ends with the ghost sum and the domain weights.
    Scatter { forces: bool, moved: bool },
    /// MPMCG node → node step of the internal force, `f_i −= Σ_j σ̄_j ∫ w S_j ∇S_i`.
    AveragedForce,
    /// Grid velocities from momentum (slot 0) and, if `forces`, after the force update
    /// (slot 1); walls; copy to the ghosts.
    GridUpdate { forces: bool },
    /// MPMCG node → node step of the velocity gradient, `L̄_j`, from velocity `slot`.
    AveragedGradient { slot: usize },
    /// Grid → particle: velocity (FLIP/PIC), position (now, or the increment kept for
    /// the `Stress` pass that moves), and if `stress` the deformation and stress;
    /// `speed`: the step's last particle pass.
    Gather {
        stress: bool,
        move_now: bool,
        speed: bool,
    },
    /// Deformation and stress from velocity `slot` at the current positions.
    /// `moves` (MUSL): then move each particle, a two-step scheme's with the remapped
    /// velocity's reconstruction ([`kernel::moving_velocity`]), a one-step scheme's by
    /// the increment its `Remap` or `Gather` kept.
    Stress {
        slot: usize,
        speed: bool,
        moves: bool,
    },
    /// MUSL: the particles' new velocities from the grid and the grid momentum of them,
    /// at the positions of the step's scatter, in one pass (`mpm::remap`); mass, cover
    /// and domain weights stay the scatter's. The same numbers as a `Gather` (no
    /// stress, no move) followed by a `Scatter` without forces.
    Remap,
    /// XPIC(m) only, just before the `Gather`: the grid field of its velocity update
    /// from the velocity before the force update, by m − 1 grid → particle → grid
    /// passes ([`Solver::xpic_field`]).
    XpicField,
}

/// Nodes per axis of a tile with the layer one node wide around it ([`NodeView::par_tiles`]).
const PAD: usize = TILE + 2;

/// `$nodes.$f::<NP>(args)` with `NP = PAD^D`, the padded tile's node count (array
/// lengths cannot be computed from a const generic on stable Rust).
macro_rules! by_pad {
    ($d:expr, $nodes:expr, $f:ident, $($arg:expr),* $(,)?) => {
        match $d {
            1 => $nodes.$f::<6>($($arg),*),
            2 => $nodes.$f::<36>($($arg),*),
            _ => $nodes.$f::<216>($($arg),*),
        }
    };
}

/// Padded index offset of corner `r` of a cell from its lower corner: a table
/// ([`PAD_OFFS`]), since the stencils' loops over corners are not unrolled, and formed
/// there it was a loop with `pow` per corner (7 % of the 3D stencils' instructions).
#[inline(always)]
fn pad_off<const D: usize>(r: usize) -> usize {
    PAD_OFFS[D][r & 7]
}

/// A node stencil's per-tile table of pairs along each axis: entry `[b][a][k]` is
/// `op(src(a, b)[k], src(a, b)[k + PAD^b])` for `k < NP − PAD^b`, and 0 for the last
/// `PAD^b` (which no cell reads), written into `t` and returned as `f64`s. Built in
/// place from `MaybeUninit`: an initialised array is zeroed first (a `memset` of
/// 15.5 kB per tile and stencil in 3D, about 0.5 % of the 3D step).
#[inline(always)]
fn pair_table<'t, const D: usize, const NP: usize>(
    t: &'t mut [[[MaybeUninit<f64>; NP]; D]; D],
    src: impl Fn(usize, usize) -> &'t [f64; NP],
    op: impl Fn(f64, f64) -> f64,
) -> &'t [[[f64; NP]; D]; D] {
    for (b, tb) in t.iter_mut().enumerate() {
        let st = PAD.pow(b as u32);
        for (a, row) in tb.iter_mut().enumerate() {
            let s = src(a, b);
            for k in 0..NP - st {
                row[k].write(op(s[k], s[k + st]));
            }
            for x in &mut row[NP - st..] {
                x.write(0.0);
            }
        }
    }
    // SAFETY: `MaybeUninit<f64>` has the size, alignment and bit validity of `f64`
    // where initialised, so nested arrays of it have the layout of the same arrays of
    // `f64`; the loops above wrote every entry of every `[b][a]` (`0 .. NP − PAD^b`,
    // then the rest), so all are initialised. The result borrows `t` for as long as
    // the mutable borrow it came from, so `t` is not written again meanwhile.
    unsafe { &*(t as *const [[[MaybeUninit<f64>; NP]; D]; D]).cast::<[[[f64; NP]; D]; D]>() }
}

/// A node stencil's per-tile table of `rows` numbers per padded node: entry `[i][k]`
/// is `value(k, i)` for `i < rows` (a padded node's numbers read together, `k`
/// outer), written into `t` and its first `rows` rows returned as `f64`s. Built in
/// place from `MaybeUninit`, as [`pair_table`]: an initialised array is zeroed first
/// (`memset`s of 17 kB per tile in the two 3D stencils).
#[inline(always)]
fn pad_table<const R: usize, const NP: usize>(
    t: &mut [[MaybeUninit<f64>; NP]; R],
    rows: usize,
    value: impl Fn(usize, usize) -> f64,
) -> &[[f64; NP]] {
    let t = &mut t[..rows];
    for k in 0..NP {
        for (i, row) in t.iter_mut().enumerate() {
            row[k].write(value(k, i));
        }
    }
    // SAFETY: `MaybeUninit<f64>` has the size, alignment and bit validity of `f64`
    // where initialised, so `[MaybeUninit<f64>; NP]` has the layout of `[f64; NP]`;
    // `t` is the first `rows` rows (the slicing checked `rows <= R`), and the loops
    // wrote every entry `k < NP` of each of them, so all are initialised. The result
    // borrows `t` for as long as the mutable borrow it came from.
    unsafe { std::slice::from_raw_parts(t.as_ptr().cast::<[f64; NP]>(), t.len()) }
}

/// Per lane of a row, all ones where the cell weight `w` is positive, else zero: the
/// mask [`kept`] applies.
#[inline(always)]
fn keep_mask(w: &[f64; TILE]) -> [u64; TILE] {
    std::array::from_fn(|x| if w[x] > 0.0 { u64::MAX } else { 0 })
}

/// `x` where `mask` is all ones, `+0` where it is zero: `if keep { x } else { 0.0 }`,
/// bit for bit, as an `and` of the bits; both node stencils add a cell's terms through
/// it. Written as a select over a row, the compiler made the averaged velocity
/// gradient's sums single numbers on the stack with a branch per lane (a third of its
/// time in 3D); the `and` stays one vector operation over the row.
#[inline(always)]
fn kept(x: f64, mask: u64) -> f64 {
    f64::from_bits(x.to_bits() & mask)
}

/// [`pad_off`] per dimension (0 to 3) and corner (bit `a` of `r`: the upper side
/// along axis `a`): `Σ_a r_a PAD^a`.
const PAD_OFFS: [[usize; 8]; 4] = {
    let mut t = [[0; 8]; 4];
    let mut d = 0;
    while d < 4 {
        let mut r = 0;
        while r < 8 {
            let (mut a, mut pow) = (0, 1);
            while a < d {
                t[d][r] += ((r >> a) & 1) * pow;
                pow *= PAD;
                a += 1;
            }
            r += 1;
        }
        d += 1;
    }
    t
};

/// Per padded position of a tile ([`NodeView::par_tiles`]), the same for every tile:
/// the neighbouring tile (index `Σ_a t_a 3^a`, `t_a` 0 below, 1 this, 2 above) and
/// the node's offset within it.
fn pad_map<const D: usize, const NP: usize>() -> [(usize, usize); NP] {
    debug_assert_eq!(NP, PAD.pow(D as u32));
    let mut map = [(0usize, 0usize); NP];
    for (k, m) in map.iter_mut().enumerate() {
        let (mut t, mut within, mut rest, mut pow) = (0, 0, k, 1);
        for a in 0..D {
            let pa = rest % PAD;
            rest /= PAD;
            t += (usize::from(pa > 0) + usize::from(pa > TILE)) * pow;
            within |= ((pa + TILE - 1) & (TILE - 1)) << (TILE_LOG * a as u32);
            pow *= 3;
        }
        *m = (t, within);
    }
    map
}

/// The padded positions' `(neighbour tile, offset within it)` pairs ([`NodeView::par_tiles`])
/// as runs `(tile, first offset, length)` of consecutive offsets in one tile, the same
/// for every tile: the first `count` entries of the array returned with `count`. A
/// tile's nodes are stored in order of their offsets, so each run is a range of
/// storage.
fn prefetch_runs<const NP: usize>(
    map: &[(usize, usize); NP],
) -> ([(usize, usize, usize); NP], usize) {
    let mut sorted = *map;
    sorted.sort_unstable();
    let mut runs = [(0, 0, 0); NP];
    let mut count = 0;
    for &(t, within) in &sorted {
        match runs[..count].last_mut() {
            Some((rt, rw, len)) if *rt == t && *rw + *len == within => *len += 1,
            _ => {
                runs[count] = (t, within, 1);
                count += 1;
            }
        }
    }
    (runs, count)
}

/// The grid fields a node pass reads, borrowed from the solver so that the pass can run
/// on several threads (the solver itself holds a communicator, which is not `Sync`).
struct NodeView<'a, const D: usize> {
    tiles: &'a Tiles<D>,
    geom: &'a Geom<D>,
    own_lo: [usize; D],
    own_hi: [usize; D],
    node_lo: [i64; D],
    faces: [[Face; 2]; D],
    cell_w: &'a [f64],
    /// The cell integrals of [`Solver::cell_k`], [`Solver::cell_m`], [`Solver::cell_md`].
    cell_k: &'a [[[f64; D]; CORNERS]; CORNERS],
    cell_m: &'a [[f64; CORNERS]; CORNERS],
    cell_md: &'a [[f64; D]; CORNERS],
}

impl<const D: usize> NodeView<'_, D> {
    /// `f(n, c, record)` for every owned node of the active tiles, with its record of
    /// `width` numbers in `out` (storage order), in parallel over tiles. For the passes
    /// that write their own node's record only: each node's result depends only on what
    /// it reads, so it is the same on any number of threads.
    fn par_owned(
        &self,
        out: &mut [f64],
        width: usize,
        f: impl Fn(usize, [usize; D], &mut [f64]) + Sync,
    ) {
        self.each_tile(out, width, |slot, recs| {
            self.pad_nodes(slot, recs, width, |n, c, _, rec| f(n, c, rec));
        });
    }

    /// `f(slot, recs)` for every active tile with its records of `width` numbers in
    /// `out`, on rayon threads (in order on one).
    fn each_tile(&self, out: &mut [f64], width: usize, f: impl Fn(usize, &mut [f64]) + Sync) {
        let tn = self.tiles.tile_nodes();
        let len = self.tiles.slots() * tn * width;
        let tile = |(slot, recs): (usize, &mut [f64])| f(slot, recs);
        if rayon::current_num_threads() == 1 {
            out[..len]
                .chunks_mut(tn * width)
                .enumerate()
                .skip(1)
                .for_each(tile);
            return;
        }
        out[..len]
            .par_chunks_mut(tn * width)
            .enumerate()
            .skip(1)
            .with_min_len(4)
            .for_each(tile);
    }

    /// `f(slot, pad, recs)` for every active tile, in parallel over tiles, with the
    /// tile's records of `width` numbers in `recs` and in `pad[k]` the storage index
    /// of the node at padded tile coordinates `p` (`k = Σ_a p_a PAD^a`, `p_a` in
    /// `0..PAD`): the tile's nodes and the layer one node wide around them, node
    /// `p − 1` of the tile, in the zero tile where that tile is not active. A node
    /// stencil reads what it needs of its neighbours into tile-local arrays once per
    /// tile instead of looking every neighbour up for every node ([`NodeView::pad_rows`],
    /// [`NodeView::row_cells`]). Each node's result depends only on what it reads, so
    /// it is the same on any number of threads.
    ///
    /// `ahead(n, len)` is called for the storage indices `n .. n + len` of the padded
    /// nodes of the next slot's tile before `f` works on this one, to prefetch what `f`
    /// will read of them: the padded nodes lie in up to `3^D` tiles scattered over the
    /// storage, and the stencils' fills of their arrays waited on those loads (a third
    /// of the 3D averaged force's time). The padded nodes go by runs of consecutive
    /// storage indices ([`prefetch_runs`]; 87 in 3D, the tile itself one of them), not
    /// one by one: a call per padded node and array was 2.4 % of the 3D step's
    /// instructions, for the same cache lines.
    fn par_tiles<const NP: usize>(
        &self,
        out: &mut [f64],
        width: usize,
        ahead: impl Fn(usize, usize) + Sync,
        f: impl Fn(usize, &[usize; NP], &mut [f64]) + Sync,
    ) {
        let map = pad_map::<D, NP>();
        let (runs, nruns) = prefetch_runs(&map);
        self.each_tile(out, width, |slot, recs| {
            if slot + 1 < self.tiles.slots() {
                let nbr = self.tiles.neighbours(slot + 1);
                for &(t, within, len) in &runs[..nruns] {
                    ahead(nbr[t] + within, len);
                }
            }
            let nbr = self.tiles.neighbours(slot);
            let mut pad = [0; NP];
            for (p, &(t, within)) in pad.iter_mut().zip(&map) {
                *p = nbr[t] + within;
            }
            f(slot, &pad, recs);
        });
    }

    /// The local coordinates of the first node of tile `slot` when every node of the
    /// tile is owned and has a cell below it along every axis (local coordinates at
    /// least 1), as in the body's interior; else `None`. Such a tile's nodes need no
    /// per-node test ([`NodeView::pad_rows`], [`NodeView::pad_nodes`]): those tests
    /// were about 1.5 % of the 3D step's instructions.
    #[inline]
    fn inner_first(&self, slot: usize) -> Option<[usize; D]> {
        let first = self.tiles.local_first(slot)?;
        (0..D)
            .all(|a| first[a] >= self.own_lo[a].max(1) && first[a] + TILE <= self.own_hi[a])
            .then_some(first)
    }

    /// [`Tiles::local_row`] of the row at offset `o0` of a tile whose first node is at
    /// local coordinates `first` and which lies wholly in the box.
    #[inline(always)]
    fn inner_row(first: [usize; D], o0: usize) -> [Option<[usize; D]>; TILE] {
        let mut c = first;
        for (a, c) in c.iter_mut().enumerate().skip(1) {
            *c += (o0 >> (TILE_LOG * a as u32)) & (TILE - 1);
        }
        std::array::from_fn(|x| {
            let mut c = c;
            c[0] += x;
            Some(c)
        })
    }

    /// `f(n, c, p, record)` for every owned node of tile `slot`, with `p` its index in
    /// the tile's padded arrays ([`NodeView::par_tiles`]).
    #[inline]
    fn pad_nodes(
        &self,
        slot: usize,
        recs: &mut [f64],
        width: usize,
        mut f: impl FnMut(usize, [usize; D], usize, &mut [f64]),
    ) {
        let tn = self.tiles.tile_nodes();
        let inner = self.inner_first(slot);
        // A row along the first axis at a time (`Tiles::local_row`), nodes in order.
        for (row, recs) in recs.chunks_exact_mut(width * TILE).enumerate() {
            let (locs, owned) = match inner {
                Some(first) => (Self::inner_row(first, row * TILE), true),
                None => (self.tiles.local_row(slot, row * TILE), false),
            };
            for (x, rec) in recs.chunks_exact_mut(width).enumerate() {
                let o = row * TILE + x;
                if let Some(c) = locs[x] {
                    if owned || (0..D).all(|a| c[a] >= self.own_lo[a] && c[a] < self.own_hi[a]) {
                        let p = (0..D)
                            .map(|a| {
                                (((o >> (TILE_LOG * a as u32)) & (TILE - 1)) + 1)
                                    * PAD.pow(a as u32)
                            })
                            .sum();
                        f(slot * tn + o, c, p, rec);
                    }
                }
            }
        }
    }

    /// For every row of [`TILE`] nodes along the first axis of tile `slot` that holds
    /// an owned node: `f(o0, p0, own, cs, low)`, with `o0` the tile offset of the row's
    /// first node, `p0` its index in the tile's padded arrays ([`NodeView::par_tiles`];
    /// the row's node `x` is at `p0 + x`), which of the row's nodes are owned, their
    /// local coordinates, and per node the axes (bit `a`) along which it has no cell
    /// below ([`NodeView::row_cells`]). The node stencils work a row at a time, one node
    /// per lane.
    #[inline]
    fn pad_rows(
        &self,
        slot: usize,
        mut f: impl FnMut(usize, usize, &[bool; TILE], &[[usize; D]; TILE], &[usize; TILE]),
    ) {
        let inner = self.inner_first(slot);
        for row in 0..TILE.pow(D as u32 - 1) {
            let o0 = row * TILE;
            let mut own = [false; TILE];
            let mut cs = [[0usize; D]; TILE];
            // Per node, the axes along which it has no cell below (local coordinate
            // 0, or outside the box): [`NodeView::row_cells`]' test per corner.
            let mut low = [0usize; TILE];
            if let Some(first) = inner {
                // Every node owned, none at local coordinate 0.
                own = [true; TILE];
                cs = Self::inner_row(first, o0).map(|c| c.unwrap_or([0; D]));
            } else {
                let locs = self.tiles.local_row(slot, o0);
                for x in 0..TILE {
                    if let Some(c) = locs[x] {
                        own[x] = (0..D).all(|a| c[a] >= self.own_lo[a] && c[a] < self.own_hi[a]);
                        cs[x] = c;
                    }
                }
                for x in 0..TILE {
                    for a in 0..D {
                        low[x] |= usize::from(cs[x][a] == 0) << a;
                    }
                }
            }
            if own.iter().any(|&o| o) {
                let p0 = (0..D)
                    .map(|a| (((o0 >> (TILE_LOG * a as u32)) & (TILE - 1)) + 1) * PAD.pow(a as u32))
                    .sum();
                f(o0, p0, &own, &cs, &low);
            }
        }
    }

    /// The cells around a row of [`pad_rows`](NodeView::pad_rows), one corner `q` at a
    /// time (corners in order, as every node loop visits them): the
    /// padded index of the lower corner of the cell whose corner `q` is the row's
    /// first node (node `x`'s is `x` further on), and per node that cell's weight from
    /// `cw` (cell weights by padded index), 0 where there is no cell (below a bounded
    /// grid face). A stencil adds a cell's terms where its weight is positive.
    #[inline(always)]
    fn row_cells<const NP: usize>(
        cw: &[f64; NP],
        low: &[usize; TILE],
        p0: usize,
        q: usize,
    ) -> (usize, [f64; TILE]) {
        let cell = p0 - pad_off::<D>(q);
        let mut w = [0.0; TILE];
        for x in 0..TILE {
            // The cell is there unless corner q is on the upper side along an axis
            // where the node has no cell below.
            if q & low[x] == 0 {
                w[x] = cw[cell + x];
            }
        }
        (cell, w)
    }

    /// The node → node force of [`Solver::averaged_force`] on every owned node, from
    /// `sigma` (σ̄'s upper triangle per node, [`kernel::sym_index`]) into the force
    /// slots of `scat`.
    ///
    /// A row of [`TILE`] nodes along the first axis at a time, one node per lane: the
    /// row's neighbours are side by side in the padded arrays, so every product below
    /// is one vector operation over the row. Each lane does its node's operations in
    /// the node's order (`t` per cell, then `f += w_c t` over the cells in order), and a
    /// cell the one-node loop skips (no cell there, or weight 0) adds an exact zero to
    /// `f`, which never holds −0 (it starts at +0, and a sum of finite numbers is −0
    /// only if both are): the same bits as one node at a time.
    fn force_tiles<const NP: usize>(&self, scat: &mut [f64], sw: usize, sigma: &[f64]) {
        let sym = NodeRecord::<D>::SYM;
        let cell_k = self.cell_k;
        let ahead = |n: usize, len: usize| {
            kernel::prefetch(sigma, n * sym, len * sym);
            kernel::prefetch(self.cell_w, n, len);
        };
        self.par_tiles::<NP>(scat, sw, ahead, |slot, pad, recs| {
            // Filled in place, component by component: a row's lanes are the
            // neighbouring entries of one component. (`array::from_fn` built these in
            // a temporary and copied it, a `memcpy` of 15 kB per tile in 3D.)
            // σ̄ is symmetric to the bit (both entries are the same sum over the same
            // volume, `averaged_force`): its upper triangle only, a third fewer numbers
            // to transpose in 3D, and the stencil reads `σ̄_ba` where it needs `σ̄_ab`.
            let mut sp = [[MaybeUninit::uninit(); NP]; 6];
            let sp = pad_table(&mut sp, sym, |k, i| sigma[pad[k] * sym + i]);
            let mut cw = [[MaybeUninit::uninit(); NP]; 1];
            let cw = &pad_table(&mut cw, 1, |k, _| self.cell_w[pad[k]])[0];
            // The sums of σ̄_ab over padded neighbours along b,
            // `ssp[b][a][k] = σ̄_ab(k) + σ̄_ab(k + e_b)`, once per tile: each cell's pair
            // of corners along b enters the force of each of its corners' nodes, which
            // added them each time. The same addition, so the same bits. (The last
            // PAD^b entries, which no cell reads, are 0; the array is not zeroed
            // first: [`pair_table`].)
            let mut ssp = [[[MaybeUninit::uninit(); NP]; D]; D];
            let ssp = pair_table(
                &mut ssp,
                |a, b| &sp[kernel::sym_index::<D>(a, b)],
                |lo, hi| lo + hi,
            );
            self.pad_rows(slot, |o0, p0, own, _, low| {
                let mut f = [[0.0; TILE]; D];
                // Kept whole in memory (as the scatter's run sums): in registers the
                // compiler split the sums into pieces and put them together again for
                // every corner.
                let f = std::hint::black_box(&mut f);
                for q in 0..(1 << D) {
                    let (cell, w) = Self::row_cells(cw, low, p0, q);
                    // `∫_c S_r ∂_b S_q` does not depend on `r_b` (a hat's derivative
                    // along b is constant across the cell): the corners r and r + e_b
                    // share it, so their stresses are added first (`ssp`), half the products.
                    // One component at a time, so that its sum over the pairs is one
                    // vector the whole way (over all three at once, the compiler kept
                    // the sums as pieces and reassembled them for every pair, about
                    // fifteen shuffles each); each sum takes its terms in the same
                    // order, b then i.
                    let mut t = [[0.0; TILE]; D];
                    for (a, t) in t.iter_mut().enumerate() {
                        for (b, ssp) in ssp.iter().enumerate() {
                            for i in 0..(1 << (D - 1)) {
                                let r = kernel::pair(b, i).0;
                                let k = cell_k[r][q][b];
                                let c0 = cell + pad_off::<D>(r);
                                let s = &ssp[a][c0..c0 + TILE];
                                for x in 0..TILE {
                                    t[x] += k * s[x];
                                }
                            }
                        }
                    }
                    let keep = keep_mask(&w);
                    for a in 0..D {
                        for x in 0..TILE {
                            f[a][x] += kept(w[x] * t[a][x], keep[x]);
                        }
                    }
                }
                for x in 0..TILE {
                    if own[x] {
                        let rec = &mut recs[(o0 + x) * sw..(o0 + x + 1) * sw];
                        for a in 0..D {
                            rec[NodeRecord::<D>::force(a)] -= f[a][x];
                        }
                    }
                }
            });
        });
    }

    /// `L̄_j` and `v̄_j` of [`Solver::averaged_velocity_gradient`] on every owned node
    /// into `avg`, from velocity slot `slot` of `grid_vel`.
    fn gradient_tiles<const NP: usize>(
        &self,
        avg: &mut [f64],
        grid_vel: &[f64],
        slot: usize,
        node_vol: &[f64],
    ) {
        let aw = AvgRecord::<D>::WIDTH;
        let (cell_k, cell_m, cell_md) = (self.cell_k, self.cell_m, self.cell_md);
        // A run's velocity records are contiguous; slot `slot`'s numbers are their
        // first or last `D` of `2 D`.
        let ahead = |n: usize, len: usize| {
            kernel::prefetch(
                grid_vel,
                VelRecord::<D>::at(n, slot),
                (len - 1) * VelRecord::<D>::WIDTH + D,
            );
            kernel::prefetch(self.cell_w, n, len);
        };
        self.par_tiles::<NP>(avg, aw, ahead, |tile, pad, recs| {
            // Filled in place, component by component (see `force_tiles`).
            let mut vp = [[MaybeUninit::uninit(); NP]; D];
            let vp = pad_table(&mut vp, D, |k, a| {
                grid_vel[VelRecord::<D>::at(pad[k], slot) + a]
            });
            let mut cw = [[MaybeUninit::uninit(); NP]; 1];
            let cw = &pad_table(&mut cw, 1, |k, _| self.cell_w[pad[k]])[0];
            // The velocity's differences along each axis b between padded neighbours,
            // `dvp[b][a][k] = v_a(k + e_b) − v_a(k)`, once per tile: every cell's
            // edge along b enters the gradient of each of its corners' nodes (eight
            // times in 3D), which formed the difference each time. The same
            // subtraction, so the same bits. (The last PAD^b entries, which no cell
            // reads, are 0; the array is not zeroed first: [`pair_table`].)
            let mut dvp = [[[MaybeUninit::uninit(); NP]; D]; D];
            let dvp = pair_table(&mut dvp, |a, _| &vp[a], |lo, hi| hi - lo);
            // A row of TILE nodes at a time, one per lane, as in `force_tiles`: each
            // lane does its node's operations in its order, and a skipped cell adds an
            // exact zero to sums that never hold −0, so the same bits.
            self.pad_rows(tile, |o0, p0, own, cs, low| {
                // One visit of the cells: with m_ji = w_c ∫_c S_j S_i dv,
                // Σ m_ji (v_i + L̄ (x_j − x_i)) = Σ m_ji v_i + L̄ Σ m_ji (x_j − x_i), and
                // the last sum is Σ_c w_c `cell_md` of the node's corner: it needs no
                // velocity, so v̄ needs no second visit once L̄ is known.
                let mut l = [[0.0; TILE]; 9];
                let mut mv = [[0.0; TILE]; D];
                let mut md = [[0.0; TILE]; D];
                for q in 0..(1 << D) {
                    let (cell, w) = Self::row_cells(cw, low, p0, q);
                    let mut mc = [[0.0; TILE]; D];
                    for r in 0..(1 << D) {
                        let (m, at) = (cell_m[q][r], cell + pad_off::<D>(r));
                        for a in 0..D {
                            let v = &vp[a][at..at + TILE];
                            for x in 0..TILE {
                                mc[a][x] += m * v[x];
                            }
                        }
                    }
                    // `∫_c S_q ∂_b S_r` changes only its sign with `r_b`: the corners
                    // r and r + e_b enter as the velocity's difference along b.
                    let mut lc = [[0.0; TILE]; 9];
                    for (b, dvp) in dvp.iter().enumerate() {
                        for i in 0..(1 << (D - 1)) {
                            let (r, r1) = kernel::pair(b, i);
                            let k = cell_k[q][r1][b];
                            let c0 = cell + pad_off::<D>(r);
                            for (a, dv) in dvp.iter().enumerate() {
                                let d = &dv[c0..c0 + TILE];
                                for x in 0..TILE {
                                    lc[a * D + b][x] += k * d[x];
                                }
                            }
                        }
                    }
                    let keep = keep_mask(&w);
                    for a in 0..D {
                        for x in 0..TILE {
                            mv[a][x] += kept(w[x] * mc[a][x], keep[x]);
                            md[a][x] += kept(w[x] * cell_md[q][a], keep[x]);
                        }
                        for b in 0..D {
                            for x in 0..TILE {
                                l[a * D + b][x] += kept(w[x] * lc[a * D + b][x], keep[x]);
                            }
                        }
                    }
                }
                for x in 0..TILE {
                    if !own[x] {
                        continue;
                    }
                    let rec = &mut recs[(o0 + x) * aw..(o0 + x + 1) * aw];
                    let vol = node_vol[tile * self.tiles.tile_nodes() + o0 + x];
                    let l: [f64; 9] = std::array::from_fn(|c| l[c][x]);
                    let mv: [f64; D] = std::array::from_fn(|a| mv[a][x]);
                    let md: [f64; D] = std::array::from_fn(|a| md[a][x]);
                    self.gradient_record(rec, cs[x], vol, &l, &mv, &md);
                }
            });
        });
    }

    /// A node's [`AvgRecord`] `rec` from its cell sums (`gradient_tiles`): `L̄ = l / V`
    /// and `v̄ = (mv + L̄ md) / V` with the walls of local node `c`; zero where the
    /// node's volume `vol` is not positive.
    #[inline(always)]
    fn gradient_record(
        &self,
        rec: &mut [f64],
        c: [usize; D],
        vol: f64,
        l: &[f64; 9],
        mv: &[f64; D],
        md: &[f64; D],
    ) {
        let dd = D * D;
        if vol <= 0.0 {
            rec.iter_mut().for_each(|x| *x = 0.0);
            return;
        }
        let mut ln = [0.0; 9];
        for k in 0..dd {
            ln[k] = l[k] / vol;
        }
        let mut vb = [0.0; 6];
        for a in 0..D {
            let mut u = mv[a];
            for b in 0..D {
                u += ln[a * D + b] * md[b];
            }
            vb[a] = u / vol;
            vb[D + a] = vb[a];
        }
        self.apply_bc(c, &mut vb[..2 * D]);
        rec[..dd].copy_from_slice(&ln[..dd]);
        rec[dd..].copy_from_slice(&vb[..D]);
    }

    /// Fixed and slip faces on both velocity slots of a node.
    #[inline]
    fn apply_bc(&self, c: [usize; D], v: &mut [f64]) {
        for a in 0..D {
            let g = self.node_lo[a] + c[a] as i64;
            let side = self.geom.end(a, g);
            if side == 0 {
                continue;
            }
            match self.faces[a][usize::from(side > 0)] {
                Face::Fixed => v.iter_mut().for_each(|x| *x = 0.0),
                Face::Slip => {
                    v[a] = 0.0;
                    v[D + a] = 0.0;
                }
                Face::Free | Face::Periodic => {}
            }
        }
    }
}

impl Update {
    /// The phases of one step of this update order for a two-step scheme.
    pub fn phases(self) -> &'static [Phase] {
        use Phase::*;
        match self {
            // Update stress last: forces from the old stress, then the new velocity
            // deforms the particles in the same pass that moves them.
            Update::Usl => &[
                Scatter {
                    forces: true,
                    moved: true,
                },
                AveragedForce,
                GridUpdate { forces: true },
                AveragedGradient { slot: UPDATED },
                Gather {
                    stress: true,
                    move_now: true,
                    speed: true,
                },
            ],
            // Update stress first, from the grid velocity of the old momentum.
            Update::Usf => &[
                Scatter {
                    forces: false,
                    moved: true,
                },
                GridUpdate { forces: false },
                AveragedGradient {
                    slot: FROM_MOMENTUM,
                },
                Stress {
                    slot: FROM_MOMENTUM,
                    speed: false,
                    moves: false,
                },
                Scatter {
                    forces: true,
                    moved: false,
                },
                AveragedForce,
                GridUpdate { forces: true },
                // The reconstruction the particles move with (two-step schemes).
                AveragedGradient { slot: UPDATED },
                Gather {
                    stress: false,
                    move_now: true,
                    speed: true,
                },
            ],
            // Modified USL: the new particle momentum is remapped to the grid, still at
            // the old positions, and that velocity deforms the particles; then they move.
            Update::Musl => &[
                Scatter {
                    forces: true,
                    moved: true,
                },
                AveragedForce,
                GridUpdate { forces: true },
                Remap,
                GridUpdate { forces: false },
                AveragedGradient {
                    slot: FROM_MOMENTUM,
                },
                Stress {
                    slot: FROM_MOMENTUM,
                    speed: true,
                    moves: true,
                },
            ],
        }
    }
}

/// The sort by cell runs when more than this fraction of a rank's particles are out
/// of order ([`Solver::disorder`]). Particles that cross cells break their cells' runs,
/// and every particle pass pays per run: on the vortex, whose ring turns through the
/// cells, a step costs 1.3 % more for each step since the last sort, while a sort
/// (keys, order, the arrays moved and the next tile pass's locating) costs about
/// two fifths of a step. One in twenty out of order is about every five steps of the
/// vortex (0.93 of its time sorted every 20 steps; one in ten: 0.97, one in 33:
/// 0.96); a body at rest is not sorted again.
const SORT_DISORDER: f64 = 0.05;

/// L̄ and v̄ per node ([`AvgRecord`]) as [`Solver::averaged_velocity_gradient`] left
/// them in `scat` (two-step schemes, `nodes` of them; else empty): in the scatter
/// records' storage, whose values no phase reads after the grid velocities are formed
/// from them and before the next scatter (`resolve_phases` puts XPIC's scatters before
/// L̄), so the grid holds no field of its own for them (`AvgRecord::WIDTH` is at most
/// the record's width).
fn avg_of<const D: usize>(scat: &[f64], nodes: usize) -> &[f64] {
    &scat[..nodes * AvgRecord::<D>::WIDTH]
}

/// A run of particles in one cell, as the tile pass finds it.
#[derive(Clone, Debug, PartialEq)]
struct CellRun<const D: usize> {
    /// The run's first particle.
    first: u32,
    /// The storage index of its cell's lower corner node ([`Solver::run_nodes`]).
    node: u32,
    /// Its cell, as the locator found it: the later passes over the runs need not
    /// locate their first particles again. 32-bit: the scene allows at most
    /// `i32::MAX` cells per axis ([`crate::input::scene::MAX_CELLS_PER_AXIS`]), and a run of 3D
    /// particles that move between sorts is one per particle or so (20 bytes each,
    /// not 32).
    cell: [i32; D],
}

impl<const D: usize> CellRun<D> {
    fn new(first: usize, cell: [i64; D]) -> Self {
        debug_assert!(cell.iter().all(|&c| (0..=i32::MAX as i64).contains(&c)));
        CellRun {
            first: first as u32,
            node: 0,
            cell: cell.map(|c| c as i32),
        }
    }

    /// Its cell.
    #[inline(always)]
    fn cell(&self) -> [i64; D] {
        self.cell.map(i64::from)
    }
}

/// The tile pass's location of the particles of one chunk, in order: in `runs`, where
/// a run of particles in one cell starts (the chunk's first particle starts one).
struct ChunkLocator<'a, const D: usize> {
    geom: &'a Geom<D>,
    /// The chunk's first particle.
    base: usize,
    /// The cell of the particle located last (none at first).
    prev: [i64; D],
    runs: &'a mut Vec<CellRun<D>>,
}

/// The tile pass's runs of one cell as [`kernel::SlabRuns`]: the slab order sorts
/// them, not the particles one by one.
struct RunSlabs<'a, const D: usize> {
    /// Per chunk of [`LOCATE_CHUNK`] particles, its runs.
    runs: &'a [Vec<CellRun<D>>],
    count: usize,
    index: kernel::SlabIndex,
}

const _: () = assert!(LOCATE_CHUNK == kernel::SlabOrder::CHUNK);

// SAFETY: `each` only reads the runs, which it borrows: the same every call. (They
// cover the chunk: its first particle starts a run, later ones start at increasing
// particles within it (`ChunkLocator`), and run k ends where run k + 1 starts.)
unsafe impl<const D: usize> kernel::SlabRuns for RunSlabs<'_, D> {
    fn count(&self) -> usize {
        self.count
    }

    #[inline]
    fn each(&self, c: usize, mut f: impl FnMut(u32, std::ops::Range<usize>)) {
        let end = self.count.min((c + 1) * LOCATE_CHUNK);
        let runs = &self.runs[c];
        for (k, run) in runs.iter().enumerate() {
            let next = runs.get(k + 1).map_or(end, |r| r.first as usize);
            // Asserts that the cell is in the block, which the scatter's threads rely on.
            let s = self.index.slab(i64::from(run.cell[D - 1]));
            f(s, run.first as usize..next);
        }
    }
}

impl<'a, const D: usize> ChunkLocator<'a, D> {
    fn new(geom: &'a Geom<D>, chunk: usize, runs: &'a mut Vec<CellRun<D>>) -> Self {
        runs.clear();
        ChunkLocator {
            geom,
            base: chunk * LOCATE_CHUNK,
            prev: [i64::MIN; D],
            runs,
        }
    }

    /// Locate the chunk's particle `p`, at `x`.
    #[inline(always)]
    fn locate(&mut self, p: usize, x: &Vector<D>) {
        let (c, _) = self.geom.locate(&std::array::from_fn(|a| x[a]));
        self.store(p, c);
    }

    /// [`ChunkLocator::locate`] of a particle whose grid coordinates `s` (per axis
    /// `(x − lower) / h`, as `Geom::locate` forms them) lie in the block's cells
    /// ([`block_coordinates`]): they are then at least 0 and below the cell count,
    /// where `Geom::locate`'s floor is the truncation and its clamp changes nothing,
    /// so this is its cell without either (a fifth of the tile pass's instructions).
    #[inline(always)]
    fn locate_inside(&mut self, p: usize, s: &[f64; D]) {
        let mut c = [0i64; D];
        for a in 0..D {
            debug_assert!(s[a] >= 0.0 && s[a] < self.geom.cells[a] as f64);
            c[a] = s[a] as i64;
        }
        self.store(p, c);
    }

    /// [`block_coordinates`] and [`ChunkLocator::locate_inside`] of the `L` particles
    /// from the chunk's `p0`, at `xs`, as vector operations over them: `false`, with
    /// nothing stored, unless all of them lie in the block `[lo, hi)`. The same
    /// arithmetic per lane, so the same bits and runs as one at a time.
    #[inline(always)]
    fn locate_lanes<const L: usize>(
        &mut self,
        p0: usize,
        xs: &[Vector<D>; L],
        (lo, hi): (&[usize; D], &[usize; D]),
    ) -> bool {
        let geom = self.geom;
        let mut s = [[0.0; L]; D];
        let mut inside = true;
        for a in 0..D {
            let (lower, inv_h) = (geom.lower[a], geom.inv_h[a]);
            let (lo, hi) = (lo[a] as f64, hi[a] as f64);
            for l in 0..L {
                s[a][l] = (xs[l][a] - lower) * inv_h;
                inside &= (s[a][l] >= lo) & (s[a][l] < hi);
            }
        }
        if !inside {
            return false;
        }
        // Truncation, as `locate_inside` casts. `as` would also saturate and map NaN
        // to 0, which per lane takes scalar compares and moves (they were half of
        // this function); here no lane needs it.
        let mut c = [[0i64; L]; D];
        for a in 0..D {
            for l in 0..L {
                // SAFETY: every lane passed `lo[a] <= s < hi[a]` above (a NaN fails
                // it), so `s` is finite and truncates to an integer in `[0, hi[a])`,
                // which an i64 holds: `to_int_unchecked`'s condition.
                c[a][l] = unsafe { s[a][l].to_int_unchecked::<i64>() };
            }
        }
        // A run starts where a lane's cell differs from the one before it: a bit per
        // lane (a mask register), visited bit by bit only where one is set.
        let mut starts = 0u32;
        for l in 0..L {
            let mut differs = false;
            for a in 0..D {
                let before = if l == 0 { self.prev[a] } else { c[a][l - 1] };
                differs |= c[a][l] != before;
            }
            starts |= u32::from(differs) << l;
        }
        while starts != 0 {
            let l = starts.trailing_zeros() as usize;
            starts &= starts - 1;
            self.runs.push(CellRun::new(
                self.base + p0 + l,
                std::array::from_fn(|a| c[a][l]),
            ));
        }
        self.prev = std::array::from_fn(|a| c[a][L - 1]);
        true
    }

    /// Start a run where particle `p`'s cell `c` differs from the last particle's.
    #[inline(always)]
    fn store(&mut self, p: usize, c: [i64; D]) {
        if c != self.prev {
            self.prev = c;
            self.runs.push(CellRun::new(self.base + p, c));
        }
    }
}

/// The runs (in order, over all chunks) whose cell comes before the previous run's in
/// the sort's order (the last axis first): none right after a sort, and about one per
/// particle that crossed into another cell since (it breaks its old cell's run).
fn descents<const D: usize>(runs: &[Vec<CellRun<D>>]) -> usize {
    let mut prev = None;
    let mut n = 0;
    for r in runs.iter().flatten() {
        let c = r.cell;
        let key = std::array::from_fn::<i32, D, _>(|a| c[D - 1 - a]);
        n += usize::from(prev.is_some_and(|p| key < p));
        prev = Some(key);
    }
    n
}

/// Wrap the coordinates of `x` along periodic axes into the period.
#[inline(always)]
fn wrap_periodic<const D: usize>(geom: &Geom<D>, x: &mut Vector<D>) {
    for a in 0..D {
        let (lo, hi) = (geom.lower[a], geom.upper[a]);
        if geom.periodic[a] && (x[a] < lo || x[a] >= hi) {
            x[a] = lo + (x[a] - lo).rem_euclid(hi - lo);
            if x[a] >= hi {
                x[a] = lo; // rem_euclid can round up to the period
            }
        }
    }
}

/// A position's grid coordinates `s_a = (x_a − lower_a) / h_a` (the expression of
/// `Geom::locate`) and whether they lie in the cells `[lo, hi)` of a block
/// ([`in_block`], which a NaN fails). Inside a block a position is on the grid, so
/// no separate test of the grid's faces is needed.
#[inline(always)]
fn block_coordinates<const D: usize>(
    geom: &Geom<D>,
    lo: &[usize; D],
    hi: &[usize; D],
    x: &Vector<D>,
) -> ([f64; D], bool) {
    let mut s = [0.0; D];
    // `&`, not `&&` or `all`: no branch per axis in the per-particle check.
    let mut inside = true;
    for a in 0..D {
        s[a] = (x[a] - geom.lower[a]) * geom.inv_h[a];
        inside &= (s[a] >= lo[a] as f64) & (s[a] < hi[a] as f64);
    }
    (s, inside)
}

/// Whether coordinate `x` along axis `a` lies on the grid: always on a periodic axis
/// (positions are wrapped), within the faces on a bounded one (never if NaN).
#[inline]
fn on_grid<const D: usize>(geom: &Geom<D>, a: usize, x: f64) -> bool {
    geom.periodic[a] | ((x >= geom.lower[a]) & (x <= geom.upper[a]))
}

/// Whether position `x` lies in the cells `[lo, hi)` of a block, by a test that needs
/// no cell lookup: `s` in `[lo, hi)` is `Geom::locate`'s cell in the block (its floor
/// of the same `s`, which the clamp at bounded faces leaves in the block). Most
/// particles stay in their block; the others are looked up.
#[inline]
fn in_block<const D: usize>(
    geom: &Geom<D>,
    lo: &[usize; D],
    hi: &[usize; D],
    x: &Vector<D>,
) -> bool {
    block_coordinates(geom, lo, hi, x).1
}

/// Numbers (or node records) per task of the parallel fills of grid fields.
const ZERO_CHUNK: usize = 1 << 14;

/// Set a grid field to zero, in parallel.
fn zero(v: &mut [f64]) {
    v.par_chunks_mut(ZERO_CHUNK).for_each(|c| c.fill(0.0));
}

/// The sum of `f(k)` over `k` in `lo..hi`, in parallel, added in a tree fixed by the
/// range (halves), so that the result does not depend on the threads.
fn tree_sum<const N: usize>(
    lo: usize,
    hi: usize,
    f: &(impl Fn(usize) -> [f64; N] + Sync),
) -> [f64; N] {
    match hi - lo {
        0 => [0.0; N],
        1 => f(lo),
        n => {
            let mid = lo + n / 2;
            let (a, b) = rayon::join(|| tree_sum(lo, mid, f), || tree_sum(mid, hi, f));
            std::array::from_fn(|i| a[i] + b[i])
        }
    }
}

/// Add particle `p`'s volume-weighted squared errors against the exact displacement
/// and velocity `(u, v)`, and its volume, into the sums `s` of [`Solver::errors`].
#[inline(always)]
fn add_errors<const D: usize>(
    s: &mut [f64; 3],
    (parts, kind_vol0): (&Particles<D>, &[f64]),
    p: usize,
    (u, v): (Vector<D>, Vector<D>),
) {
    let eu = parts.x[p] - parts.x0[p] - u;
    let ev = parts.v[p] - v;
    let w = parts.volume(p, kind_vol0);
    s[0] += w * eu.norm_squared();
    s[1] += w * ev.norm_squared();
    s[2] += w;
}

/// Particles per chunk of the tile pass's parallel locate (fixed, so that its runs do
/// not depend on the thread count).
const LOCATE_CHUNK: usize = 4096;

/// The smallest CFL step as a share of the time left: below it the run would need more
/// than 1e12 steps, which no real scene asks for; the signal speed has blown up.
const MIN_STEP_SHARE: f64 = 1e-12;

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
    /// A solver at t = 0 with the scene's particles seeded in this rank's block.
    pub fn new(scene: &Scene, comm: &'c dyn Communicator, layout: Layout<D>) -> Self {
        let geom = Self::geometry(scene);
        let block = Block::new(&layout, comm.rank());
        let kinds = Kinds::of_scene(scene, &geom);
        let materials = kinds.materials(&Material::all(&scene.plan.materials));
        let benchmark = Benchmark::<D>::new(scene);
        let parts = Particles::seed(
            scene,
            &geom,
            (&kinds, &materials),
            benchmark.as_ref(),
            block.cell_lo,
            block.cell_hi,
        );
        Self::with_particles(scene, comm, layout, parts)
    }

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
            scheme: GradientScheme::of(scene.method.gradient),
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
            traffic_before: Default::default(),
            last_imbalance: 1.0,
            external_work: 0.0,
            max_speed: 0.0,
            tiles,
            ptile: Vec::new(),
            scat: Vec::new(),
            sw: 0,
            vel: Vec::new(),
            xpic: scene.method.xpic.map(|m| m as usize),
            xpic_add: Vec::new(),
            xpic_term: Vec::new(),
            fill: Vec::new(),
            cell_w: Vec::new(),
            node_vol: Vec::new(),
            cell_k: [[[0.0; D]; CORNERS]; CORNERS],
            cell_m: [[0.0; CORNERS]; CORNERS],
            cell_md: [[0.0; D]; CORNERS],
            mass_floor: 0.0,
            slabs: SlabOrder::default(),
            migrator,
            carries,
            keep: Vec::new(),
            record: Vec::new(),
            dx: Vec::new(),
            perm: Vec::new(),
            cell_runs: Vec::new(),
            run_keys: Vec::new(),
            accel: Vec::new(),
            memo: Memo::default(),
            error_sums: Vec::new(),
            flagged: Vec::new(),
            located: false,
            disorder: 0,
            sorts: 0,
            permuted: Vec::new(),
            scratch: Vec::new(),
        };
        s.resolve_phases();
        s.setup_grid();
        let mut mmin = [(0..s.parts.len())
            .map(|p| s.particle_mass(p))
            .fold(f64::INFINITY, f64::min)];
        s.comm.min_f64(&mut mmin);
        s.mass_floor = if mmin[0].is_finite() {
            1e-12 * mmin[0]
        } else {
            0.0
        };
        s.max_speed = s.compute_max_speed();
        s
    }

    /// This rank's block and the tile storage of its grid. Which halo nodes are stored
    /// and exchanged is agreed with the peers every time the tiles are activated
    /// ([`Block::activate_halo`]).
    fn block_and_tiles(layout: &Layout<D>, rank: usize) -> (Block<D>, Tiles<D>) {
        let block = Block::new(layout, rank);
        let tiles = Tiles::new(block.node_dims, block.own_lo);
        (block, tiles)
    }

    /// Replace the scheme's α (tests: α ≡ 0 is `averaged`, α ≡ 1 is `mpm`).
    pub fn set_alpha(&mut self, alpha: Alpha) {
        self.scheme.alpha = alpha;
        self.resolve_phases();
        self.setup_grid();
    }

    /// The step's phases for this scheme: one-step schemes skip the grid averages.
    fn resolve_phases(&mut self) {
        let two = self.scheme.two_step();
        self.phases = self
            .update
            .phases()
            .iter()
            .copied()
            .filter(|p| two || !matches!(p, Phase::AveragedForce | Phase::AveragedGradient { .. }))
            .flat_map(|p| match p {
                // XPIC's field is computed right before the gather that updates the
                // particle velocities; its passes overwrite the scatter records, so
                // MUSL's remap is then a gather and a full second scatter.
                Phase::Remap if self.xpic.is_some() => vec![
                    Phase::XpicField,
                    Phase::Gather {
                        stress: false,
                        move_now: false,
                        speed: false,
                    },
                    Phase::Scatter {
                        forces: false,
                        moved: false,
                    },
                ],
                Phase::Gather { .. } if self.xpic.is_some() => vec![Phase::XpicField, p],
                _ => vec![p],
            })
            .collect();
        // XPIC's scatters overwrite the scatter records, where L̄ and v̄ are kept
        // (`avg`): its field first, then theirs (neither reads what the other writes).
        for i in 1..self.phases.len() {
            if self.phases[i] == Phase::XpicField
                && matches!(self.phases[i - 1], Phase::AveragedGradient { .. })
            {
                self.phases.swap(i - 1, i);
            }
        }
    }

    fn setup_grid(&mut self) {
        let two = self.scheme.two_step();
        self.sw = NodeRecord::<D>::width(two);
        if two {
            for q in 0..(1 << D) {
                for r in 0..(1 << D) {
                    self.cell_k[r][q] = cell_integral::<D>(&self.geom.h, r, q);
                    // ∫_c S_r S_q dv: h/3 per axis on which the corners agree, h/6 else.
                    self.cell_m[r][q] = (0..D)
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
                    self.cell_md[q][b] = (0..1 << D)
                        .map(|r| self.cell_m[q][r] * (bit(q) - bit(r)) * self.geom.h[b])
                        .sum();
                }
            }
        }
        self.size_fields();
    }

    /// Size the grid fields to the storage of the active tiles, all zero. Vectors keep
    /// their capacity, so storage grows amortised and a step allocates only when the
    /// active set outgrows every earlier one.
    fn size_fields(&mut self) {
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
        fit(&mut self.scat, nn * self.sw);
        fit(&mut self.vel, nn * VelRecord::<D>::WIDTH);
        let n2 = if two { nn } else { 0 };
        // σ̄ lives in `vel` and L̄, v̄ in `scat` for part of a step (`averaged_force`,
        // `avg`).
        const {
            assert!(NodeRecord::<D>::SYM <= VelRecord::<D>::WIDTH);
            assert!(AvgRecord::<D>::WIDTH <= NodeRecord::<D>::width(true));
        }
        let nx = if self.xpic.is_some() { nn * D } else { 0 };
        fit(&mut self.xpic_add, nx);
        fit(&mut self.xpic_term, nx);
        fit(&mut self.fill, n2);
        fit(&mut self.cell_w, n2);
        fit(&mut self.node_vol, n2);
    }

    /// Activate the tiles the particles' nodes lie in (GIMP reaches one node below
    /// the cell and two above), give each particle its cell's node in the storage,
    /// and group the particles by slab for the scatter.
    fn activate_tiles(&mut self) {
        self.tiles.begin();
        // Located by `relocate` if nothing moved, left or arrived since.
        let located = std::mem::take(&mut self.located);
        if !located {
            self.locate_all();
        } else if cfg!(debug_assertions) {
            // The tests' builds check that claim: locating again changes nothing.
            let runs = self.cell_runs.clone();
            self.locate_all();
            assert!(
                runs == self.cell_runs,
                "the particles' location kept from the wrap is stale at step {}",
                self.step
            );
        }
        // The slab order first: it checks that every run's cell is in the block.
        let last = D - 1;
        let (lo, hi) = (self.block.cell_lo[last], self.block.cell_hi[last]);
        let thick = kernel::slab_thickness(self.scheme.gimp);
        let index = self.slabs.begin(lo, hi, thick);
        self.slabs.finish(&RunSlabs {
            runs: &self.cell_runs,
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
        self.ptile
            .par_chunks_mut(LOCATE_CHUNK)
            .zip(self.cell_runs.par_iter())
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

    /// The tile pass's parallel part: locate every particle and list per chunk of
    /// particles where a run of particles in one cell starts (the chunk's first
    /// particle starts one). Chunks are fixed, so the runs do not depend on the thread
    /// count.
    fn locate_all(&mut self) {
        let chunks = self.begin_locate();
        let geom = &self.geom;
        self.parts
            .x
            .par_chunks(LOCATE_CHUNK)
            .zip(self.cell_runs.par_iter_mut())
            .enumerate()
            .for_each(|(k, (x, runs))| {
                let mut loc = ChunkLocator::new(geom, k, runs);
                for (p, x) in x.iter().enumerate() {
                    loc.locate(p, x);
                }
            });
        self.cell_runs.truncate(chunks);
    }

    /// The tile pass's arrays sized for this rank's particles: the chunk count.
    fn begin_locate(&mut self) -> usize {
        let n = self.parts.len();
        // As much room as the particles' arrays have (which grow with a sixteenth to
        // spare, [`particles::reserve`]): no more, and it grows when they do.
        let room = self.parts.x.capacity().max(n);
        particles::reserve_exact(&mut self.ptile, room);
        // Every entry is written below: only new ones need a value (no serial fill).
        self.ptile.resize(n, 0);
        let chunks = n.div_ceil(LOCATE_CHUNK);
        if self.cell_runs.len() < chunks {
            self.cell_runs.resize_with(chunks, Vec::new);
        }
        chunks
    }

    /// The local cell of a run.
    #[inline]
    fn run_cell(node_lo: &[i64; D], run: &CellRun<D>) -> [i64; D] {
        let c = run.cell();
        std::array::from_fn(|a| c[a] - node_lo[a])
    }

    /// Touch the tiles every run's nodes lie in: their keys gathered per chunk on
    /// threads (consecutive runs mostly share their tiles, so a small cache keeps the
    /// lists short), then touched in chunk order.
    fn touch_runs(&mut self) {
        let (below, above) = if self.scheme.gimp { (1, 2) } else { (0, 1) };
        let chunks = self.cell_runs.len();
        if self.run_keys.len() < chunks {
            self.run_keys.resize_with(chunks, Vec::new);
        }
        let tiles = &self.tiles;
        let node_lo = &self.block.node_lo;
        self.cell_runs
            .par_iter()
            .zip(self.run_keys.par_iter_mut())
            .for_each(|(runs, keys)| {
                keys.clear();
                let mut recent = [u64::MAX; 16];
                let mut buf = [0u64; 8];
                for run in runs {
                    let l = Self::run_cell(node_lo, run);
                    let n =
                        tiles.keys_of_nodes(l.map(|v| v - below), l.map(|v| v + above), &mut buf);
                    for &k in &buf[..n] {
                        let r = &mut recent[k as usize % recent.len()];
                        if *r != k {
                            *r = k;
                            keys.push(k);
                        }
                    }
                }
            });
        for &k in self.run_keys[..chunks].iter().flatten() {
            self.tiles.touch_key(k);
        }
    }

    /// The storage index of each run's cell's lower corner node ([`Solver::cell_runs`]),
    /// on threads, once the active set holds every run's tile ([`Solver::touch_runs`],
    /// [`Tiles::finish`]).
    fn run_nodes(&mut self) {
        let tiles = &self.tiles;
        let node_lo = &self.block.node_lo;
        self.cell_runs.par_iter_mut().for_each(|runs| {
            let mut tile = (u64::MAX, 0u32);
            for run in runs.iter_mut() {
                let l = Self::run_cell(node_lo, run).map(|v| v as usize);
                let k = tiles.key_of(l);
                if k != tile.0 {
                    tile = (k, tiles.slot_of_key(k));
                    assert!(tile.1 != 0, "a particle's cell's tile was touched");
                }
                run.node = tiles.index_in(tile.1, l) as u32;
            }
        });
    }

    /// Particle → grid: mass, momentum and, if `forces`, external and internal forces.
    /// `moved`: the particles moved since the last scatter, so their slab order must
    /// be rebuilt (the second scatter of a USF or MUSL step sees the same positions).
    fn scatter(&mut self, forces: bool, moved: bool) {
        let two = self.scheme.two_step();
        if moved {
            self.activate_tiles();
        }
        self.scatter_pass(forces, false);
        if two {
            self.domain_weights();
        }
    }

    /// The scatter proper, into `scat`, summed over ranks. `from_grid`: momentum of the
    /// field `xpic_term` interpolated at the particles instead of their velocities.
    fn scatter_pass(&mut self, forces: bool, from_grid: bool) {
        let two = self.scheme.two_step() && !from_grid;
        zero(&mut self.scat);
        let ctx = ctx!(self);
        // The forces' scatter has each particle's body force formed before it, and it
        // is kept for the gather or remap after it (every update order has one between
        // them); other scatters leave it.
        if forces {
            let keep = ctx.body_force.is_some();
            self.accel.resize(
                if keep { self.parts.len() } else { 0 },
                Vector::<D>::zeros(),
            );
            if keep {
                kernel::external_accel(&ctx, &self.parts.x0, &mut self.accel);
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
            tile: &self.ptile,
            src: &self.xpic_term,
            accel: if forces { &self.accel } else { &[] },
        };
        let m = kernel::ScatterMode {
            sw: self.sw,
            forces,
            two_step: two,
            from_grid,
        };
        by_nodes!(
            self.scheme.gimp,
            scatter,
            &ctx,
            &parts,
            &self.slabs,
            &mut self.scat,
            m
        );
        self.block.ghost_sum(self.comm, &mut self.scat, self.sw);
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
    fn xpic_field(&mut self) {
        let m = self.xpic.expect("XPIC phase only in XPIC runs");
        let mf = m as f64;
        let sw = self.sw;
        let d2 = VelRecord::<D>::WIDTH;
        let nn = self.vel.len() / d2;
        for n in 0..nn {
            for a in 0..D {
                let v = self.vel[VelRecord::<D>::at(n, FROM_MOMENTUM) + a];
                self.xpic_term[n * D + a] = v;
                self.xpic_add[n * D + a] = (mf - 1.0) * v;
            }
        }
        for r in 2..=m {
            self.scatter_pass(false, true);
            let f = (mf - r as f64 + 1.0) / r as f64;
            let mut term = std::mem::take(&mut self.xpic_term);
            self.for_owned(|n, c| {
                let rec = &self.scat[n * sw..(n + 1) * sw];
                let mass = rec[NodeRecord::<D>::MASS];
                let mut v = [0.0; 6];
                if mass > self.mass_floor {
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
            for (x, t) in self.xpic_add.iter_mut().zip(&term) {
                *x += sign * t;
            }
            self.xpic_term = term;
        }
    }

    /// Iterate the owned nodes of the active tiles: storage index and local coordinates.
    fn for_owned(&self, mut f: impl FnMut(usize, [usize; D])) {
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
    fn nodes(&self) -> NodeView<'_, D> {
        NodeView {
            tiles: &self.tiles,
            geom: &self.geom,
            own_lo: self.block.own_lo,
            own_hi: self.block.own_hi,
            node_lo: self.block.node_lo,
            faces: self.faces,
            cell_w: &self.cell_w,
            cell_k: &self.cell_k,
            cell_m: &self.cell_m,
            cell_md: &self.cell_md,
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
    fn domain_weights(&mut self) {
        let sw = self.sw;
        let col = NodeRecord::<D>::cover(sw);
        let mut fill = std::mem::take(&mut self.fill);
        let (nodes, scat) = (self.nodes(), &self.scat);
        nodes.par_owned(&mut fill, 1, |n, c, fill| {
            let g: [i64; D] = std::array::from_fn(|a| nodes.node_lo[a] + c[a] as i64);
            let support = nodes.geom.node_volume(g);
            fill[0] = (scat[n * sw + col] / (FULL_FILL * support)).min(1.0);
        });
        self.block.ghost_copy(self.comm, &mut fill, 1);
        self.fill = fill;
        // Cells whose corners all lie in the local box (the others are never visited),
        // over the active tiles: a cell with its lower corner in a tile that is not
        // active has an untouched corner, so weight 0, which its zero tile reads.
        let dims = self.block.node_dims;
        let tn = self.tiles.tile_nodes();
        let mut cw = std::mem::take(&mut self.cell_w);
        let (tiles, fill) = (&self.tiles, &self.fill);
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
        self.cell_w = cw;
        let share = self.geom.cell_volume() / (1 << D) as f64;
        let mut vol = std::mem::take(&mut self.node_vol);
        let (nodes, cell_w) = (self.nodes(), &self.cell_w);
        nodes.par_owned(&mut vol, 1, |n, c, vol| {
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
        self.node_vol = vol;
    }

    /// Node → node step of the internal force: `f_i −= Σ_j σ̄_j · ∫ w S_j ∇S_i dv`,
    /// assembled cell by cell over the weighted cells around each owned node.
    fn averaged_force(&mut self) {
        let (sw, sym) = (self.sw, NodeRecord::<D>::SYM);
        // σ̄_j = T_j / V_j on owned nodes, then to the ghosts: its upper triangle, in
        // the grid velocities' storage, which the grid update after this rewrites
        // (SYM numbers fit in its 2 D a node).
        let mut vel = std::mem::take(&mut self.vel);
        let sigma = &mut vel[..self.node_vol.len() * sym];
        let (nodes, scat, node_vol) = (self.nodes(), &self.scat, &self.node_vol);
        nodes.par_owned(sigma, sym, |n, _, rec| {
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
        self.block.ghost_copy(self.comm, sigma, sym);
        let mut scat = std::mem::take(&mut self.scat);
        let nodes = self.nodes();
        by_pad!(D, nodes, force_tiles, &mut scat, sw, sigma);
        self.scat = scat;
        self.vel = vel;
    }

    /// Grid velocities from momentum (and, if `dt > 0`, forces), with boundary
    /// conditions, on owned nodes; then copied to ghosts.
    fn grid_velocity(&mut self, dt: f64) {
        let sw = self.sw;
        let mut vel = std::mem::take(&mut self.vel);
        let (nodes, scat, floor) = (self.nodes(), &self.scat, self.mass_floor);
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
        self.vel = vel;
    }

    /// Fixed and slip faces on both velocity slots of a node ([`NodeView::apply_bc`]).
    fn apply_bc(&self, c: [usize; D], v: &mut [f64]) {
        self.nodes().apply_bc(c, v);
    }

    /// `L̄_j = (1/V_j) Σ_i v_i ⊗ ∫ w S_j ∇S_i dv` on owned nodes from velocity slot
    /// `slot`, then the smoothed velocity
    /// `v̄_j = (1/V_j) Σ_i (v_i + L̄_j (x_j − x_i)) ∫ w S_j S_i dv` (the weighted mean of the
    /// grid velocity over the node's support, corrected by L̄_j to the node, so that a
    /// linear field gives its own nodal value; walls as on the grid velocity), both to
    /// the ghosts in `avg` ([`AvgRecord`]). The particles' velocity gradient and the
    /// velocity they move with ([`kernel::moving_velocity`]) are built from these.
    fn averaged_velocity_gradient(&mut self, slot: usize) {
        let aw = AvgRecord::<D>::WIDTH;
        let mut scat = std::mem::take(&mut self.scat);
        let avg = &mut scat[..self.node_vol.len() * aw];
        let nodes = self.nodes();
        by_pad!(
            D,
            nodes,
            gradient_tiles,
            avg,
            &self.vel,
            slot,
            &self.node_vol
        );
        self.block.ghost_copy(self.comm, avg, aw);
        self.scat = scat;
    }

    /// Largest wave speed plus particle speed on this rank.
    fn compute_max_speed(&self) -> f64 {
        let mut m = 0.0f64;
        for p in 0..self.parts.len() {
            let kind = self.parts.kind[p] as usize;
            let j = self.parts.volume_ratio(p, &self.kinds.vol0);
            m = m.max(self.materials[kind].wave_speed(j) + self.parts.v[p].norm());
        }
        m
    }

    /// Pick the step size: fixed, or the CFL number over the fastest signal anywhere.
    fn choose_dt(&mut self) -> Result<f64, Failure> {
        let mut s = [self.max_speed];
        self.comm.max_f64(&mut s);
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

    /// What a restart needs besides the particles: this rank's accumulated external
    /// work and its fastest signal speed after the last step.
    pub fn local_state(&self) -> (f64, f64) {
        (self.external_work, self.max_speed)
    }

    /// Continue from a checkpoint: time, step, last step size, this rank's share of the
    /// external work and the fastest signal speed the next step size derives from
    /// (any value that is the maximum over ranks gives the same step).
    pub fn restore(&mut self, t: f64, step: u64, dt: f64, external_work: f64, max_speed: f64) {
        // Located afresh at the next step.
        self.located = false;
        self.t = t;
        self.step = step;
        self.dt = dt;
        self.external_work = external_work;
        self.max_speed = max_speed;
    }

    /// The mass of particle `p` ([`particles::mass_of`]).
    pub fn particle_mass(&self, p: usize) -> f64 {
        particles::mass_of(&self.kinds.mass, &self.parts.kind, p)
    }

    /// Which optional particle arrays this solver's particles carry.
    pub fn carries(&self) -> Carries {
        self.carries
    }

    /// What this rank has sent to other ranks since the solver was made: by the halo
    /// operations (ghost sums and copies, and the agreement on the halo chunks in use)
    /// and by particle migration, rebalances included (their blocks and migrators are
    /// replaced, so their counts are carried over).
    pub fn traffic(&self) -> (Traffic, Traffic) {
        let (mut halo, mut mig) = self.traffic_before;
        halo += self.block.traffic();
        mig += self.migrator.traffic();
        (halo, mig)
    }

    /// Advance one step. On failure the particle state is that of the failed step.
    pub fn advance(&mut self) -> Result<(), Failure> {
        self.advance_with(&mut [])
    }

    /// Advance one step and agree on up to three caller flags (values >= 0, e.g. "a
    /// signal arrived", "a checkpoint is due"): on success each holds its maximum over
    /// all ranks. They travel in the reduction every step makes anyway, so agreeing
    /// costs no extra message.
    pub fn advance_with(&mut self, flags: &mut [f64]) -> Result<(), Failure> {
        assert!(flags.len() <= 3, "at most three flags per step");
        let dt = self.choose_dt()?;
        self.dt = dt;
        if let Some(b) = &self.benchmark {
            self.memo.refresh(b, &self.parts.x0);
        }
        let mut ok = true;
        for k in 0..self.phases.len() {
            ok &= self.run_phase(self.phases[k], dt);
        }
        // Valid for this step only (and the particle count may change below).
        self.accel.clear();
        self.t += dt;
        self.step += 1;
        let mut agree = [0.0; 4];
        agree[0] = if ok { 0.0 } else { 1.0 };
        agree[1..1 + flags.len()].copy_from_slice(flags);
        self.comm.max_f64(&mut agree[..1 + flags.len()]);
        flags.copy_from_slice(&agree[1..1 + flags.len()]);
        if agree[0] > 0.0 {
            return Err(Failure::Unstable(format!(
                "non-finite or inverted (J <= 0) particle state at step {}, t = {:.6e}",
                self.step, self.t
            )));
        }
        self.relocate()?;
        if self.disorder as f64 > SORT_DISORDER * self.parts.len() as f64 {
            self.sort();
        }
        Ok(())
    }

    /// Carry out one phase of a step (see [`Phase`]). Returns whether the particle state
    /// stayed physical.
    fn run_phase(&mut self, phase: Phase, dt: f64) -> bool {
        match phase {
            Phase::Scatter { forces, moved } => self.scatter(forces, moved),
            Phase::AveragedForce => self.averaged_force(),
            Phase::GridUpdate { forces } => self.grid_velocity(if forces { dt } else { 0.0 }),
            Phase::AveragedGradient { slot } => self.averaged_velocity_gradient(slot),
            Phase::Gather {
                stress,
                move_now,
                speed,
            } => return self.gather(dt, stress, move_now, speed),
            Phase::Stress { slot, speed, moves } => {
                return self.update_stress_from(slot, dt, speed, moves)
            }
            Phase::XpicField => self.xpic_field(),
            Phase::Remap => return self.remap(dt),
        }
        true
    }

    /// MUSL's remap ([`Phase::Remap`]): new particle velocities, and their momentum
    /// summed over ranks into the scatter records' momentum (the rest of the records,
    /// mass and cover among them, is the step's scatter's).
    fn remap(&mut self, dt: f64) -> bool {
        let n = self.parts.len();
        let keep_dx = !self.scheme.two_step();
        // A one-step scheme moves by the increment kept here, at the end of the
        // stress pass; a two-step scheme's stress pass moves with the reconstruction.
        self.dx
            .resize(if keep_dx { n } else { 0 }, Vector::<D>::zeros());
        // Summed into the records' momentum slots in place: no field of its own.
        let (sw, mom) = (self.sw, NodeRecord::<D>::momentum(0));
        self.scat.par_chunks_mut(sw * ZERO_CHUNK).for_each(|recs| {
            for rec in recs.chunks_exact_mut(sw) {
                rec[mom..mom + D].fill(0.0);
            }
        });
        let mut ctx = ctx!(self);
        ctx.walls = self.has_walls();
        let parts = crate::mpm::remap::RemapParts {
            x: &self.parts.x,
            mass: particles::Masses::of(&self.kinds, &self.parts.kind),
            x0: &self.parts.x0,
            half: &self.parts.half,
            tile: &self.ptile,
            accel: &self.accel,
        };
        let m = crate::mpm::remap::RemapMode {
            dt,
            flip: self.flip,
            keep_dx,
            record: (sw, mom),
        };
        let t = match (self.scheme.gimp, D) {
            (false, 1) => remap::<D, 2, 2>,
            (false, 2) => remap::<D, 2, 4>,
            (false, _) => remap::<D, 2, 8>,
            (true, 1) => remap::<D, 3, 3>,
            (true, 2) => remap::<D, 3, 9>,
            (true, _) => remap::<D, 3, 27>,
        }(
            &ctx,
            &parts,
            &mut self.parts.v,
            &mut self.dx,
            &self.slabs,
            &self.vel,
            &mut self.scat,
            m,
        );
        self.block
            .ghost_sum_slots(self.comm, &mut self.scat, sw, mom..mom + D);
        self.external_work += t.work;
        t.ok
    }

    /// Whether a grid face is a wall (slip or fixed): the passes that clip or blend
    /// velocities there need each particle's wall ends.
    fn has_walls(&self) -> bool {
        self.faces
            .iter()
            .flatten()
            .any(|f| matches!(f, Face::Slip | Face::Fixed))
    }

    /// Grid → particle: velocities (FLIP/PIC blend) and positions from slot 1, and if
    /// `stress` the velocity gradient, deformation and stress. If `!move_now`, the
    /// position increments are kept in `dx` for later (MUSL).
    /// `speed`: this is the step's last particle pass, which sets the signal speed the
    /// next step size follows.
    fn gather(&mut self, dt: f64, stress: bool, move_now: bool, speed: bool) -> bool {
        let n = self.parts.len();
        self.dx
            .resize(if move_now { 0 } else { n }, Vector::<D>::zeros());
        let mode = kernel::GatherMode {
            dt,
            flip: self.flip,
            stress,
            move_now,
            two_step: self.scheme.two_step(),
            recon: self.scheme.two_step() && move_now,
            speed,
        };
        let mut ctx = ctx!(self);
        ctx.walls = self.has_walls();
        let parts = slices!(self);
        let t = by_nodes!(
            self.scheme.gimp,
            gather,
            &ctx,
            parts,
            &self.vel,
            avg_of::<D>(&self.scat, self.node_vol.len()),
            self.xpic.map(|_| &self.xpic_add[..]),
            mode
        );
        self.external_work += t.work;
        if speed {
            self.max_speed = t.max_speed;
        }
        t.ok
    }

    /// Stress update from grid velocity slot `slot` at the current positions.
    fn update_stress_from(&mut self, slot: usize, dt: f64, speed: bool, moves: bool) -> bool {
        let m = kernel::StressMode {
            slot,
            dt,
            two_step: self.scheme.two_step(),
            moves: moves && self.scheme.two_step(),
            moves_kept: moves && !self.scheme.two_step(),
            speed,
        };
        let mut ctx = ctx!(self);
        ctx.walls = m.moves && self.has_walls();
        let parts = slices!(self);
        let t = by_nodes!(
            self.scheme.gimp,
            update_stress,
            &ctx,
            parts,
            &self.vel,
            avg_of::<D>(&self.scat, self.node_vol.len()),
            m
        );
        self.external_work += t.work;
        if speed {
            self.max_speed = t.max_speed;
        }
        t.ok
    }

    /// In parallel over fixed chunks of particles: wrap periodic coordinates into the
    /// period, and flag the chunks ([`Solver::flagged`]) that hold a particle outside
    /// the grid or its block, the only ones [`Solver::relocate`] then visits. The
    /// others' particles are located for the next tile pass as in
    /// [`Solver::locate_all`], while their positions are at hand.
    fn wrap_and_flag(&mut self) {
        let chunks = self.begin_locate();
        self.flagged.clear();
        self.flagged.resize(chunks, false);
        let (geom, lo, hi) = (&self.geom, &self.block.cell_lo, &self.block.cell_hi);
        let periodic = geom.periodic.contains(&true);
        self.parts
            .x
            .par_chunks_mut(LOCATE_CHUNK)
            .zip(self.flagged.par_iter_mut())
            .zip(self.cell_runs.par_iter_mut())
            .enumerate()
            .for_each(|(k, ((xs, flag), runs))| {
                let mut loc = ChunkLocator::new(geom, k, runs);
                // One particle: whether it left the block.
                let one = |loc: &mut ChunkLocator<'_, D>, p: usize, x: &mut Vector<D>| {
                    wrap_periodic(geom, x);
                    // In the block is on the grid: one test for both.
                    let (s, inside) = block_coordinates(geom, lo, hi, x);
                    // A flagged chunk is located again after the exchange.
                    if inside {
                        loc.locate_inside(p, &s);
                    }
                    !inside
                };
                // Eight at a time where all eight stay in the block (nearly all of
                // them), one by one where one left it and at the chunk's end.
                let mut p = 0;
                while p < xs.len() {
                    let b = (xs.len() - p).min(LANES);
                    if b == LANES {
                        let r = p..p + LANES;
                        if periodic {
                            xs[r.clone()]
                                .iter_mut()
                                .for_each(|x| wrap_periodic(geom, x));
                        }
                        let batch = <&[Vector<D>; LANES]>::try_from(&xs[r]).unwrap();
                        if loc.locate_lanes(p, batch, (lo, hi)) {
                            p += LANES;
                            continue;
                        }
                    }
                    for q in p..p + b {
                        *flag |= one(&mut loc, q, &mut xs[q]);
                    }
                    p += b;
                }
            });
        self.cell_runs.truncate(chunks);
    }

    /// Wrap periodic coordinates, check bounded ones, and hand particles that left the
    /// block to their new owner.
    fn relocate(&mut self) -> Result<(), Failure> {
        let mut left = None;
        let me = self.comm.rank();
        let n = self.parts.len();
        self.keep.clear();
        self.keep.resize(n, true);
        self.wrap_and_flag();
        let mut leaving = 0usize;
        let flagged = self.flagged.iter().enumerate().filter(|f| *f.1);
        for p in flagged.flat_map(|(k, _)| k * LOCATE_CHUNK..n.min((k + 1) * LOCATE_CHUNK)) {
            let x = &self.parts.x[p];
            for a in 0..D {
                let (lo, hi) = (self.geom.lower[a], self.geom.upper[a]);
                if !on_grid(&self.geom, a, x[a]) && left.is_none() {
                    left = Some(format!(
                        "particle {} at {:?} is outside the grid on axis {a} ([{lo}, {hi}]) at t = {:.6e}; \
                         close the face (fixed/slip) or enlarge the grid",
                        self.parts.id[p],
                        x.as_slice(),
                        self.t
                    ));
                }
            }
            if left.is_some() {
                continue;
            }
            let (lo, hi) = (&self.block.cell_lo, &self.block.cell_hi);
            if in_block(&self.geom, lo, hi, x) {
                continue;
            }
            let (cell, _) = self.geom.locate(&std::array::from_fn(|a| x[a]));
            if (0..D).all(|a| cell[a] >= lo[a] as i64 && cell[a] < hi[a] as i64) {
                continue;
            }
            match self.migrator.destination(cell) {
                Ok(d) if d.rank == me => {}
                Ok(d) => {
                    self.parts.pack(p, self.carries, &mut self.record);
                    self.migrator.push(d.rank, &self.record);
                    self.keep[p] = false;
                    leaving += 1;
                }
                Err(e) => self.migrator.fail(e),
            }
        }
        // Every rank takes part in the exchange, so an error anywhere reaches all.
        if left.is_some() {
            self.migrator.fail(decomposition::Error::OutsideGrid {
                rank: me,
                cell: vec![],
                cells: self.geom.cells.to_vec(),
            });
        }
        if leaving > 0 {
            self.parts.retain(&self.keep);
        }
        let carries = self.carries;
        let parts = &mut self.parts;
        match self.migrator.exchange(self.comm) {
            Ok(recs) => {
                // The tile pass's location of every particle, done with the wrap, holds
                // if none left (none was flagged) and none arrived.
                self.located = !self.flagged.contains(&true) && recs.is_empty();
                self.disorder = descents(&self.cell_runs) + recs.len();
                parts.reserve_total(parts.len() + recs.len(), carries);
                for r in recs.iter() {
                    parts.unpack(r, carries);
                }
                Ok(())
            }
            Err(e) => Err(match (left, e) {
                (Some(m), _) => Failure::LeftGrid(m),
                (None, e @ decomposition::Error::ParticleTooFast { .. }) => {
                    Failure::Unstable(e.to_string())
                }
                (None, e) => Failure::Elsewhere(e.to_string()),
            }),
        }
    }

    /// This rank's wrapped cell of particle `p` (positions are wrapped by `relocate`;
    /// the remainder guards a coordinate that rounded onto the period).
    fn cell_of(&self, p: usize) -> [usize; D] {
        let (c, _) = self
            .geom
            .locate(&std::array::from_fn(|a| self.parts.x[p][a]));
        std::array::from_fn(|a| c[a].rem_euclid(self.geom.cells[a] as i64) as usize)
    }

    /// Collective: the particle imbalance over ranks, the largest rank's particles over
    /// the mean (1 when there are none).
    pub fn imbalance(&self) -> f64 {
        let n = self.parts.len() as f64;
        let (mut most, mut sum) = ([n], [n]);
        self.comm.max_f64(&mut most);
        self.comm.sum_f64(&mut sum);
        let mean = sum[0] / self.comm.size() as f64;
        if mean > 0.0 {
            most[0] / mean
        } else {
            1.0
        }
    }

    /// Collective: if the particle imbalance is above `threshold`, move the block
    /// boundaries so that every slab of blocks holds an equal share of the particles
    /// ([`Layout::balanced`]), provided that removes at least a fifth of the excess
    /// over a perfect balance (the cuts of a process grid cannot balance every
    /// distribution, and a rebalance that gains little is not worth its particle
    /// exchange). Returns whether the layout changed. Deterministic: every rank takes
    /// the same decision from the same sums.
    ///
    /// The cost is the particle count: the grid nodes a rank stores are those of the
    /// tiles its particles touch, so their share of a step follows the particles.
    pub fn rebalance(&mut self, threshold: f64) -> bool {
        let ranks = self.comm.size();
        if ranks == 1 {
            return false;
        }
        let now = self.imbalance();
        self.last_imbalance = now;
        if now <= threshold {
            return false;
        }
        // Particles per cell slab along every axis, summed over ranks.
        let cells = self.geom.cells;
        let total: usize = cells.iter().sum();
        let mut slab = std::mem::take(&mut self.scratch);
        slab.clear();
        slab.resize(total + ranks, 0.0);
        for p in 0..self.parts.len() {
            let c = self.cell_of(p);
            let mut at = 0;
            for a in 0..D {
                slab[at + c[a]] += 1.0;
                at += cells[a];
            }
        }
        self.comm.sum_f64(&mut slab[..total]);
        let mut at = 0;
        let cost: [Vec<f64>; D] = std::array::from_fn(|a| {
            let v = slab[at..at + cells[a]].to_vec();
            at += cells[a];
            v
        });
        let next = self.layout.balanced(&cost);
        // Particles per rank under the new cuts.
        let per_rank = &mut slab[total..];
        for p in 0..self.parts.len() {
            per_rank[next.cell_owner(self.cell_of(p))] += 1.0;
        }
        self.comm.sum_f64(per_rank);
        let mean = per_rank.iter().sum::<f64>() / ranks as f64;
        let then = per_rank.iter().cloned().fold(0.0, f64::max) / mean;
        self.scratch = slab;
        if next == self.layout || then - 1.0 > 0.8 * (now - 1.0) {
            return false;
        }
        self.relayout(next);
        self.last_imbalance = then;
        true
    }

    /// Collective: hand every particle to its owner under `layout` (another layout of
    /// the same grid and rank count) and rebuild this rank's block, halo, tiles and
    /// migration for it. The grid fields are rebuilt by the next step's scatter.
    pub fn relayout(&mut self, layout: Layout<D>) {
        self.located = false;
        let me = self.comm.rank();
        let n = self.parts.len();
        let mut mig = Migrator::everywhere(&layout, &self.block, self.migrator.width());
        self.keep.clear();
        self.keep.resize(n, true);
        for p in 0..n {
            let to = layout.cell_owner(self.cell_of(p));
            if to != me {
                self.parts.pack(p, self.carries, &mut self.record);
                mig.push(to, &self.record);
                self.keep[p] = false;
            }
        }
        self.parts.retain(&self.keep);
        let recs = mig
            .exchange(self.comm)
            .expect("no rank records a routing error in a relayout");
        self.parts
            .reserve_total(self.parts.len() + recs.len(), self.carries);
        for r in recs.iter() {
            self.parts.unpack(r, self.carries);
        }
        self.traffic_before.0 += self.block.traffic();
        self.traffic_before.1 += self.migrator.traffic();
        self.traffic_before.1 += mig.traffic();
        let (block, tiles) = Self::block_and_tiles(&layout, me);
        self.migrator = Migrator::new(&layout, &block, self.migrator.width());
        self.layout = layout;
        self.block = block;
        self.tiles = tiles;
        self.ptile.clear();
        particles::reserve(&mut self.ptile, self.parts.len());
        self.size_fields();
        self.rebalances += 1;
        // Arrival order depends on the old owners: sort for the same order as a run
        // that never had them.
        self.sort();
    }

    /// Reorder particles by cell (then id, for determinism) for cache locality.
    pub fn sort(&mut self) {
        // The wrap's location, if it holds, names every particle's cell; after the
        // sort it is stale.
        let located = std::mem::take(&mut self.located);
        self.sorts += 1;
        let n = self.parts.len();
        // Each particle's cell as one number, the last axis first as the order by
        // cell is (a number in mixed radix whose digits are the cell's coordinates).
        // Counted from the block's first cell it mostly fits 32 bits, and is then
        // kept in `ptile`, with the slab order's array as the radix sort's room: both
        // are stale once particles move and rebuilt by the next tile pass before any
        // read, so the keys need no memory of their own.
        // (A scene's grid has at most 2^40 nodes, `MAX_GRID_NODES`: the products fit.)
        let (lo, hi) = (&self.block.cell_lo, &self.block.cell_hi);
        let mut stride = [0u64; D];
        let mut span = 1u64;
        for a in 0..D {
            stride[a] = span;
            span *= (hi[a] - lo[a]) as u64;
        }
        let geom = &self.geom;
        let block_key = |c: &[i64; D]| {
            let mut key = 0;
            for a in 0..D {
                let digit = c[a] - lo[a] as i64;
                assert!(
                    (0..(hi[a] - lo[a]) as i64).contains(&digit),
                    "a particle in cell {c:?} is outside its block {lo:?} .. {hi:?}"
                );
                key += digit as u64 * stride[a];
            }
            key
        };
        let cell_of = |p: usize| geom.locate(&std::array::from_fn(|a| self.parts.x[p][a])).0;
        if span <= 1 << 32 {
            let keys = &mut self.ptile;
            particles::reserve(keys, n);
            keys.resize(n, 0);
            let runs = &self.cell_runs;
            keys.par_chunks_mut(LOCATE_CHUNK)
                .enumerate()
                .for_each(|(k, keys)| {
                    let base = k * LOCATE_CHUNK;
                    if !located {
                        for (p, key) in keys.iter_mut().enumerate() {
                            *key = block_key(&cell_of(base + p)) as u32;
                        }
                        return;
                    }
                    // A key per run, not a location per particle.
                    for (r, run) in runs[k].iter().enumerate() {
                        let end = runs[k]
                            .get(r + 1)
                            .map_or(keys.len(), |e| e.first as usize - base);
                        keys[run.first as usize - base..end].fill(block_key(&run.cell()) as u32);
                    }
                });
            let keys = &self.ptile;
            let key = |p: u32| u64::from(keys[p as usize]);
            particles::order_by_key_then_id(
                key,
                &self.parts.id,
                &mut self.perm,
                &mut self.slabs.order,
            );
        } else {
            // A block of more than 2^32 cells (sparse): each key formed where the sort
            // asks for it, `ptile` the room.
            let key = |p: u32| block_key(&cell_of(p as usize));
            particles::order_by_key_then_id(key, &self.parts.id, &mut self.perm, &mut self.ptile);
        }
        let perm = std::mem::take(&mut self.perm);
        // A benchmark's memo goes with its particles where it has one entry each:
        // formed again, its factors cost an `atan2` and sines per particle (the
        // vortex), and a sort moves most particles.
        let memo = self.memo.entries_mut();
        let memo = if memo.len() == perm.len() {
            memo
        } else {
            &mut []
        };
        self.parts.permute_with(&perm, &mut self.permuted, memo);
        self.perm = perm;
    }

    /// Totals over all ranks.
    pub fn totals(&self) -> Totals {
        let (parts, materials, kinds) = (&self.parts, &self.materials, &self.kinds);
        // Summed per fixed chunk, then in a fixed tree (as `errors`): on threads, and
        // the same on any thread count. Slots: mass, kinetic, strain, (external work),
        // plastic work, momentum per axis.
        // The arrays every particle has, as long as the positions (one index check
        // per particle), and each kind's values looked up when the kind changes.
        let len = parts.len();
        let (vs, kind_of) = (&parts.v[..len], &parts.kind[..len]);
        let chunk = |k: usize| {
            let mut sums = [0.0; 8];
            let mut cache = particles::KindCache::new(&kinds.mass, &kinds.vol0, materials);
            for p in k * LOCATE_CHUNK..len.min((k + 1) * LOCATE_CHUNK) {
                let at = cache.get(kind_of[p]);
                let m = at.mass;
                let v = vs[p];
                sums[0] += m;
                sums[1] += 0.5 * m * v.norm_squared();
                let mat = at.material;
                let f = if parts.def_grad.is_empty() {
                    Mat::<D>::identity()
                } else {
                    parts.def_grad[p]
                };
                // The energy of a material whose stress is not stored is a function of
                // `F` alone: no need to form its stress.
                let stress = parts.stress.get(p).copied().unwrap_or_else(Mat::<D>::zeros);
                let vol0 = at.vol0;
                let vol = || parts.volume(p, &kinds.vol0);
                sums[2] += mat.strain_energy(&stress, &f, parts.be.get(p), vol, vol0);
                if let Some(&e) = parts.eps_p.get(p) {
                    sums[4] += mat.plastic_work(e, vol0);
                }
                for a in 0..D {
                    sums[5 + a] += m * v[a];
                }
            }
            sums
        };
        let mut all = tree_sum(0, parts.len().div_ceil(LOCATE_CHUNK), &chunk);
        let sums = &mut all[..5 + D];
        sums[3] = self.external_work;
        self.comm.sum_f64(sums);
        let mut n = [self.parts.len() as u64];
        self.comm.sum_u64(&mut n);
        Totals {
            mass: sums[0],
            kinetic: sums[1],
            strain: sums[2],
            external_work: sums[3],
            plastic_work: sums[4],
            momentum: sums[5..].to_vec(),
            particles: n[0],
        }
    }

    /// Volume-weighted L2 norms of the displacement and velocity errors against the
    /// benchmark's exact solution at the current time (over all ranks).
    pub fn errors(&self) -> Option<(f64, f64)> {
        let b = self.benchmark.as_ref()?;
        let b = b.at(self.t).with_memo(&self.memo);
        let (parts, vol0) = (&self.parts, &self.kinds.vol0[..]);
        // Summed per fixed chunk, then in a fixed tree: the same on any thread count.
        let chunk = |k: usize| {
            let mut s = [0.0; 3];
            for p in k * LOCATE_CHUNK..parts.len().min((k + 1) * LOCATE_CHUNK) {
                add_errors(&mut s, (parts, vol0), p, b.exact_of(&parts.x0, p));
            }
            s
        };
        let s = tree_sum(0, parts.len().div_ceil(LOCATE_CHUNK), &chunk);
        Some(self.error_norms(s))
    }

    /// The L2 norms of [`Solver::errors`] from this rank's sums (`add_errors`), over
    /// all ranks.
    fn error_norms(&self, mut s: [f64; 3]) -> (f64, f64) {
        self.comm.sum_f64(&mut s);
        ((s[0] / s[2]).sqrt(), (s[1] / s[2]).sqrt())
    }

    /// [`Solver::errors`], the same numbers, in a pass that also keeps in the memo
    /// each particle's body force at the current time where it shares the exact
    /// solution's work ([`crate::physics::benchmark::At::exact_keeping_force`]):
    /// after a step, that is the next step's body force, which its scatter then
    /// reads. Collective.
    pub fn errors_keeping_forces(&mut self) -> Option<(f64, f64)> {
        let b = self.benchmark.as_ref()?;
        let at = b.at(self.t);
        let (parts, vol0) = (&self.parts, &self.kinds.vol0[..]);
        let n = parts.len();
        let chunks = n.div_ceil(LOCATE_CHUNK);
        self.error_sums.resize(chunks, [0.0; 3]);
        // Each chunk's sums as `errors` forms them, then the same tree.
        self.memo
            .entries_for(n)
            .par_chunks_mut(LOCATE_CHUNK)
            .zip(self.error_sums.par_iter_mut())
            .enumerate()
            .for_each(|(k, (memo, sums))| {
                let mut s = [0.0; 3];
                let first = k * LOCATE_CHUNK;
                let x0 = &parts.x0[first..first + memo.len()];
                at.exact_keeping_forces(x0, memo, |i, out| {
                    // The sums in registers over the batch (the closure's `s` is
                    // kept in memory: each particle's adds waited on the last's).
                    let mut acc = s;
                    for (k, &exact) in out.iter().enumerate() {
                        add_errors(&mut acc, (parts, vol0), first + i + k, exact);
                    }
                    s = acc;
                });
                *sums = s;
            });
        let sums = &self.error_sums;
        let s = tree_sum(0, chunks, &|k| sums[k]);
        Some(self.error_norms(s))
    }

    pub fn done(&self) -> bool {
        self.t >= self.end * (1.0 - 1e-12)
    }
}

/// `∫_c S_j ∂S_i/∂x_d dv` over one cell, for corners `j` and `i` (bit `a` = upper side
/// along axis `a`): a tensor product of the 1D integrals `∫N_j N_i' = ±1/2` (sign of
/// `i`'s side) and `∫N_j N_i = h/3` (same node) or `h/6`.
pub fn cell_integral<const D: usize>(h: &[f64; D], j: usize, i: usize) -> [f64; D] {
    std::array::from_fn(|d| {
        let mut p = if (i >> d) & 1 == 1 { 0.5 } else { -0.5 };
        for (e, he) in h.iter().enumerate() {
            if e != d {
                p *= if (i >> e) & 1 == (j >> e) & 1 {
                    he / 3.0
                } else {
                    he / 6.0
                };
            }
        }
        p
    })
}

#[cfg(test)]
mod adjoint_tests {
    //! Energy consistency: `Σ_i f_int,i · v_i = −Σ_p V_p σ_p : L_p` for any grid
    //! velocity `v` and particle stresses `σ_p`, with `f_int` from the scatter and the
    //! node→node step and `L_p` from the gather's velocity gradient at the same
    //! positions. It holds for MPMCG's two steps because the force and the averaged
    //! velocity gradient use the same cell tables (transposed) and the same `V_j`
    //! (swapping the table's indices in one of them fails this test).
    use super::*;
    use crate::input::scene;
    use crate::physics::gradient::tests::Rng;
    use decomposition::{Layout, SerialComm};

    /// A 4 m × 1 m beam against the `x_lower` face, 3 × 3 particles per cell; linear
    /// elastic, a material that stores its stress, so the tests can set any stress.
    fn scene_text(gradient: &str, x_lower: &str) -> String {
        format!(
            r#"
name = "adj"
dim = 2
[time]
end = 1.0
[method]
gradient = "{gradient}"
[grid]
lower = [0.0, -4.0]
upper = [5.0, 1.5]
cells = [20, 22]
boundary = {{ x_lower = "{x_lower}", x_upper = "slip", y_lower = "slip", y_upper = "slip" }}
[[materials]]
name = "rubber"
model = "linear_elastic"
density = 1050.0
youngs_modulus = 1.0e6
poisson_ratio = 0.3
[[bodies]]
material = "rubber"
shape = {{ box = {{ lower = [0.0, 0.0], upper = [4.0, 1.0] }} }}
particles_per_cell = 3
"#
        )
    }

    /// (Σ f·v, −Σ V σ:L) for random stresses and volumes, positions jittered by up to
    /// `jitter` cells (partly filled cells, an irregular Ω) and a random grid velocity,
    /// with the boundary conditions applied to it if `bc`.
    fn powers(gradient: &str, x_lower: &str, jitter: f64, bc: bool, seed: u64) -> (f64, f64) {
        let mut rng = Rng(seed);
        let mut s = beam(gradient, x_lower, jitter, &mut rng);
        for p in 0..s.parts.len() {
            let (a, b, c) = (rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
            s.parts.stress[p] = Mat::<2>::new(a, c, c, b) * 1e3;
            s.parts.vol[p] *= 0.5 + rng.f64();
        }
        s.scatter(true, true);
        if s.scheme.two_step() {
            s.averaged_force();
        }
        let mut vel = vec![0.0; s.tiles.nodes() * 4];
        let mut owned = Vec::new();
        s.for_owned(|n, c| owned.push((n, c)));
        for &(n, c) in &owned {
            let v = &mut vel[n * 4..n * 4 + 4];
            if s.scat[n * s.sw + NodeRecord::<2>::MASS] > s.mass_floor {
                v[0] = rng.f64() - 0.5;
                v[1] = rng.f64() - 0.5;
                v[2] = v[0];
                v[3] = v[1];
                if bc {
                    s.apply_bc(c, v);
                }
            }
        }
        s.block.ghost_copy(s.comm, &mut vel, 4);
        s.vel = vel;
        let mut fv = 0.0;
        for &(n, _) in &owned {
            for a in 0..2 {
                fv += s.scat[n * s.sw + NodeRecord::<2>::force(a)] * s.vel[n * 4 + 2 + a];
            }
        }
        if s.scheme.two_step() {
            s.averaged_velocity_gradient(1);
        }
        let mut work = 0.0;
        for p in 0..s.parts.len() {
            let l = gradient_at(&s, p);
            work -= s.parts.vol[p] * s.parts.stress[p].component_mul(&l).sum();
        }
        (fv, work)
    }

    /// A solver on the beam of [`scene_text`] with 3 × 3 particles per cell, positions
    /// jittered by up to `jitter` cells (partly filled surface cells).
    /// Particle `p`'s velocity gradient from velocity slot 1 (with L̄ where the scheme
    /// has it), as the particle passes form it.
    fn gradient_at(s: &Solver<'_, 2>, p: usize) -> Mat<2> {
        let ctx = ctx!(s);
        let (k, idx) = ctx.kern::<2, 4>(&s.parts.x[p], None, s.ptile[p]);
        let avg = avg_of::<2>(&s.scat, s.node_vol.len());
        kernel::velocity_gradient(&k, &idx, &s.vel, avg, 1, s.scheme.two_step())
    }

    fn beam(gradient: &str, x_lower: &str, jitter: f64, rng: &mut Rng) -> Solver<'static, 2> {
        let sc = scene::parse(&scene_text(gradient, x_lower), "adj").unwrap();
        let layout = Layout::choose([20, 22], [false, false], 1).unwrap();
        let mut s = Solver::<2>::new(&sc, &SerialComm, layout);
        let h = s.geom.h;
        for p in 0..s.parts.len() {
            for a in 0..2 {
                let x = s.parts.x[p][a] + jitter * h[a] * (rng.f64() - 0.5);
                s.parts.x[p][a] = x.clamp(s.geom.lower[a], s.geom.upper[a]);
            }
        }
        s
    }

    /// A linear grid velocity `v = W x + c` on every node that carries mass: every
    /// scheme's particle velocity gradient is `W` to round-off, at the free surfaces
    /// too. This holds because a cell weighs 0 as soon as one of its corners carries
    /// no mass; a domain reaching one cell beyond the material (e.g. the weight
    /// `Σ_k φ_k S_k`) would read the zero velocity of massless nodes there and strain a
    /// translating body.
    #[test]
    fn linear_velocity_fields_are_differentiated_exactly() {
        let w = [[0.3, -1.1], [0.7, 0.2]];
        let c = [2.0, -3.0];
        for g in ["mpm", "averaged", "mpmcg"] {
            for jitter in [0.0, 0.9] {
                let mut s = beam(g, "free", jitter, &mut Rng(99));
                s.scatter(false, true);
                let mut vel = vec![0.0; s.tiles.nodes() * 4];
                let mut owned = Vec::new();
                s.for_owned(|n, c| owned.push((n, c)));
                for &(n, ci) in &owned {
                    if s.scat[n * s.sw + NodeRecord::<2>::MASS] > s.mass_floor {
                        let node = std::array::from_fn(|a| s.block.node_lo[a] + ci[a] as i64);
                        let x = s.geom.node_position(node);
                        for a in 0..2 {
                            let v = w[a][0] * x[0] + w[a][1] * x[1] + c[a];
                            vel[n * 4 + a] = v;
                            vel[n * 4 + 2 + a] = v;
                        }
                    }
                }
                s.block.ghost_copy(s.comm, &mut vel, 4);
                s.vel = vel;
                if s.scheme.two_step() {
                    s.averaged_velocity_gradient(1);
                }
                let mut worst = 0.0f64;
                for p in 0..s.parts.len() {
                    let l = gradient_at(&s, p);
                    for a in 0..2 {
                        for b in 0..2 {
                            worst = worst.max((l[(a, b)] - w[a][b]).abs());
                        }
                    }
                }
                assert!(worst < 1e-12, "{g} jitter {jitter}: |L − W| = {worst:e}");
            }
        }
    }

    /// Owned nodes' internal forces (scatter and, for two-step schemes, the node →
    /// node step) for the solver's current particles.
    /// (The nodes in local coordinates, ordered: which tiles are stored, hence the
    /// storage order, changes when a particle enters a new tile.)
    fn internal_forces(s: &mut Solver<'static, 2>) -> Vec<f64> {
        s.scatter(true, true);
        if s.scheme.two_step() {
            s.averaged_force();
        }
        let mut f = std::collections::BTreeMap::new();
        s.for_owned(|n, c| {
            let r = n * s.sw;
            let force = [
                s.scat[r + NodeRecord::<2>::force(0)],
                s.scat[r + NodeRecord::<2>::force(1)],
            ];
            f.insert([c[1], c[0]], force);
        });
        // Every owned node of the box, zero where no tile is stored.
        let mut out = Vec::new();
        for y in s.block.own_lo[1]..s.block.own_hi[1] {
            for x in s.block.own_lo[0]..s.block.own_hi[0] {
                out.extend_from_slice(f.get(&[y, x]).unwrap_or(&[0.0; 2]));
            }
        }
        out
    }

    /// A particle of the beam's bottom surface moved across the cell face below it, by
    /// 2e-9 cells: MPMCG's nodal forces change by O(1e-9), because the domain weights
    /// follow the particle continuously (with Ω switching whole cells on, the change
    /// was 2.3 times MPM's own jump at a face). MPM's jump is printed for comparison.
    #[test]
    fn surface_crossing_changes_forces_continuously() {
        for g in ["mpmcg", "averaged", "mpm"] {
            let mut s = beam(g, "free", 0.0, &mut Rng(5));
            let mut rng = Rng(17);
            for p in 0..s.parts.len() {
                let (a, b, c) = (rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
                s.parts.stress[p] = Mat::<2>::new(a, c, c, b) * 1e3;
            }
            // The bottom-row particle nearest x = 2.
            let p = (0..s.parts.len())
                .min_by(|&a, &b| {
                    let k = |q: usize| (s.parts.x[q][1], (s.parts.x[q][0] - 2.0).abs());
                    k(a).partial_cmp(&k(b)).unwrap()
                })
                .unwrap();
            let eps = 1e-9 * s.geom.h[1];
            s.parts.x[p][1] = eps;
            let above = internal_forces(&mut s);
            s.parts.x[p][1] = -eps;
            let below = internal_forces(&mut s);
            let scale = above.iter().map(|v| v.abs()).fold(0.0, f64::max);
            let jump = above
                .iter()
                .zip(&below)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
                / scale;
            eprintln!("{g}: largest nodal force change {jump:.2e} of the largest force");
            if g != "mpm" {
                assert!(jump < 1e-7, "{g}: forces jump by {jump:e}");
            }
        }
    }

    #[test]
    fn internal_force_is_adjoint_of_velocity_gradient() {
        for g in ["mpm", "averaged", "mpmcg"] {
            for face in ["fixed", "slip", "free"] {
                for (jitter, bc) in [(0.0, false), (0.0, true), (0.6, false), (0.6, true)] {
                    let (a, b) = powers(g, face, jitter, bc, 12345);
                    let rel = (a - b).abs() / a.abs().max(b.abs());
                    assert!(
                        rel < 1e-12,
                        "{g} {face} jitter {jitter} bc {bc}: {a} vs {b}"
                    );
                }
            }
        }
    }

    /// MPMCG's node stencils in 3D (`force_tiles`, `gradient_tiles`: a row of four
    /// nodes at a time) on the spinning box of the sparse-grid tests, its particles
    /// jittered by up to 0.9 cells so that surface cells are partly filled: a linear
    /// grid velocity gives every particle its gradient `W` to round-off, and the nodal
    /// forces are the adjoint of the particles' velocity gradients for random
    /// deformation gradients (neo-Hookean stress) and a random grid velocity.
    #[test]
    fn stencils_in_3d_are_exact_and_adjoint() {
        let sc = scene::parse(&super::sparse_tests::text(3, 1.0, 16, "mpmcg"), "s3").unwrap();
        let layout = Layout::choose([16; 3], [false; 3], 1).unwrap();
        let mut s = Solver::<3>::new(&sc, &SerialComm, layout);
        let mut rng = Rng(31);
        let h = s.geom.h;
        for p in 0..s.parts.len() {
            for a in 0..3 {
                s.parts.x[p][a] += 0.9 * h[a] * (rng.f64() - 0.5);
            }
            s.parts.def_grad[p] =
                Mat::<3>::from_fn(|i, k| f64::from(u8::from(i == k)) + 0.2 * (rng.f64() - 0.5));
        }
        s.scatter(true, true);
        s.averaged_force();
        // The records as the grid update reads them: L̄ is formed in their storage.
        let records = s.scat.clone();
        let mut owned = Vec::new();
        s.for_owned(|n, c| owned.push((n, c)));
        let w = [[0.3, -1.1, 0.4], [0.7, 0.2, -0.5], [-0.6, 0.9, 0.1]];
        let mut worst = 0.0f64;
        let mut sides = [0.0; 2];
        for linear in [true, false] {
            let mut vel = vec![0.0; s.tiles.nodes() * 6];
            for &(n, ci) in &owned {
                if records[n * s.sw + NodeRecord::<3>::MASS] > s.mass_floor {
                    let node = std::array::from_fn(|a| s.block.node_lo[a] + ci[a] as i64);
                    let x = s.geom.node_position(node);
                    for a in 0..3 {
                        let v = if linear {
                            w[a][0] * x[0] + w[a][1] * x[1] + w[a][2] * x[2] + 0.5
                        } else {
                            rng.f64() - 0.5
                        };
                        vel[n * 6 + a] = v;
                        vel[n * 6 + 3 + a] = v;
                    }
                }
            }
            s.block.ghost_copy(s.comm, &mut vel, 6);
            s.vel = vel;
            s.averaged_velocity_gradient(1);
            let ctx = ctx!(s);
            let mut work = 0.0;
            for p in 0..s.parts.len() {
                let (k, idx) = ctx.kern::<2, 8>(&s.parts.x[p], None, s.ptile[p]);
                let l = kernel::velocity_gradient(
                    &k,
                    &idx,
                    &s.vel,
                    avg_of::<3>(&s.scat, s.node_vol.len()),
                    1,
                    true,
                );
                if linear {
                    for a in 0..3 {
                        for b in 0..3 {
                            worst = worst.max((l[(a, b)] - w[a][b]).abs());
                        }
                    }
                } else {
                    let sigma = s.materials[0].stress_of_def_grad(&s.parts.def_grad[p]);
                    let vol = s.parts.volume(p, &s.kinds.vol0);
                    work -= vol * sigma.component_mul(&l).sum();
                }
            }
            if !linear {
                let mut fv = 0.0;
                for &(n, _) in &owned {
                    for a in 0..3 {
                        fv += records[n * s.sw + NodeRecord::<3>::force(a)] * s.vel[n * 6 + 3 + a];
                    }
                }
                sides = [fv, work];
            }
        }
        assert!(worst < 1e-12, "|L − W| = {worst:e}");
        let [fv, work] = sides;
        let rel = (fv - work).abs() / fv.abs().max(work.abs());
        assert!(rel < 1e-12, "Σ f·v = {fv}, −Σ V σ:L = {work}");
        assert!(fv.abs() > 1e-3, "a test with work in it: {fv}");
    }
}

#[cfg(test)]
mod sparse_tests {
    //! The sparse grid: storage follows the body, not the box.
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, SerialComm};

    /// The prefetch runs of a padded tile name each padded node exactly once, each run
    /// a range of consecutive offsets in one tile: the tile itself one run of all its
    /// nodes, and 15 runs in 2D, 87 in 3D where there were 36 and 216 nodes.
    #[test]
    fn prefetch_runs_cover_the_padded_tile_once() {
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
    pub(super) fn text(dim: usize, upper: f64, cells: usize, gradient: &str) -> String {
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

    fn run<const D: usize>(
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
    fn huge_box_stores_only_the_body_and_gives_the_same_result() {
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
    fn the_loops_local_coordinate_is_geom_locate_s() {
        fn check<const D: usize>(upper: f64, cells: usize) {
            let (mut s, _) = run::<D>(upper, cells, "mpmcg", 25);
            s.sort();
            s.activate_tiles();
            let ctx = ctx!(s);
            // As the loops ask: one `CellAt` over the particles in order.
            let mut at = kernel::CellAt::<D>::new();
            for (p, x) in s.parts.x.iter().enumerate() {
                let (c, xi) = s.geom.locate(&std::array::from_fn(|a| x[a]));
                let cell = *at.of(&ctx, s.ptile[p]);
                assert_eq!(cell, ctx.cell_of(s.ptile[p]));
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

    fn compare<const D: usize>(
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
        assert_eq!(tight.scat.len(), huge.scat.len(), "{what}: grid storage");
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
    fn active_tiles_follow_a_travelling_body() {
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

#[cfg(test)]
mod sparse_multirank_tests {
    //! The sparse grid on several ranks (in-process): a body that crosses every block
    //! boundary, whose nodes on one rank are often stored only because a neighbour's
    //! particles touch them through the halo.
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, LocalComm};

    type State = Vec<(u64, [f64; 2], [f64; 2])>;

    /// Positions and velocities by id after `steps` steps on `ranks` ranks, with the
    /// largest and smallest active tile count of a rank, and whether particles
    /// changed rank.
    fn run(ranks: usize, gradient: &str, steps: usize) -> (State, usize, bool) {
        let text = super::sparse_tests::text(2, 4.0, 64, gradient);
        let sc = scene::parse(&text, "sparse").unwrap();
        let out = LocalComm::run(ranks, |comm| {
            let layout = Layout::choose([64; 2], [false; 2], ranks).unwrap();
            let mut s = Solver::<2>::new(&sc, comm, layout);
            for p in 0..s.parts.len() {
                s.parts.v[p] += Vector::<2>::new(60.0, 60.0);
            }
            let mine: std::collections::BTreeSet<u64> = s.parts.id.iter().copied().collect();
            let mut most = 0;
            for _ in 0..steps {
                s.advance().unwrap();
                most = most.max(s.tiles.active());
            }
            let moved = s.parts.id.iter().any(|i| !mine.contains(i));
            let st: State = (0..s.parts.len())
                .map(|p| {
                    let (x, v) = (s.parts.x[p], s.parts.v[p]);
                    (s.parts.id[p], [x[0], x[1]], [v[0], v[1]])
                })
                .collect();
            (st, most, moved)
        });
        let mut all: State = out.iter().flat_map(|o| o.0.clone()).collect();
        all.sort_by_key(|r| r.0);
        let most = out.iter().map(|o| o.1).max().unwrap();
        (all, most, out.iter().any(|o| o.2))
    }

    /// 1, 2, 3 and 4 ranks agree to 1e-12 (positions relative to the box, velocities
    /// relative to the speed) after the body crossed the block boundaries, and no
    /// rank ever stores more than a fraction of the box's tiles.
    #[test]
    fn ranks_agree_on_a_body_crossing_blocks() {
        for g in ["mpmcg", "gimp"] {
            let (one, _, _) = run(1, g, 200);
            for n in [2, 3, 4] {
                let (got, most, moved) = run(n, g, 200);
                assert!(moved, "{g} on {n} ranks: no particle changed rank");
                assert_eq!(got.len(), one.len());
                let mut worst = 0.0f64;
                for (a, b) in got.iter().zip(&one) {
                    assert_eq!(a.0, b.0);
                    for k in 0..2 {
                        worst = worst.max((a.1[k] - b.1[k]).abs() / 4.0);
                        worst = worst.max((a.2[k] - b.2[k]).abs() / 85.0);
                    }
                }
                assert!(worst < 1e-12, "{g} on {n} ranks: difference {worst:e}");
                // 17 × 17 tiles cover the box; a rank holds the body's and its halo's.
                assert!(
                    most < 17 * 17 / 2,
                    "{g} on {n} ranks: {most} tiles on a rank"
                );
            }
            // The body travelled across the middle of the box, where the blocks meet.
            let x = one.iter().map(|r| r.1[0]).fold(f64::INFINITY, f64::min);
            assert!(x > 2.0, "{g}: the body's left edge is at {x}");
        }
    }
}

#[cfg(test)]
mod xpic_tests {
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
    fn block(gradient: &str, xpic: &str, rng: &mut Rng) -> Solver<'static, 2> {
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
        let sc = scene::parse(&text, "xpic").unwrap();
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
    fn weights(s: &Solver<'_, 2>) -> Vec<Vec<(usize, f64)>> {
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
    fn reference(s: &Solver<'_, 2>, m: usize, dt: f64) -> Vec<Vector<2>> {
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
                g[n] = if mass[n] > s.mass_floor {
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
                if mass[n] > s.mass_floor {
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
    fn update(s: &mut Solver<'_, 2>, dt: f64) {
        s.scatter(true, true);
        if s.scheme.two_step() {
            s.averaged_force();
        }
        s.grid_velocity(dt);
        if s.xpic.is_some() {
            s.xpic_field();
        }
        s.gather(dt, false, false, false);
    }

    #[test]
    fn xpic_update_matches_its_definition_and_conserves_momentum() {
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
    fn xpic_leaves_the_motion_to_the_grid() {
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
    fn xpic_of_order_one_is_pic() {
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
    fn xpic_removes_what_the_grid_cannot_see() {
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

#[cfg(test)]
mod balance_tests {
    //! Cost-based block boundaries: an off-centre body seeded on one rank of an equal
    //! split is shared out by one rebalance.
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, LocalComm};

    /// A box body in one corner of the unit box (`cells` per axis), away from the
    /// middle where equal blocks meet.
    fn corner_body(dim: usize, cells: usize) -> String {
        let v = |x: &[f64]| {
            let s: Vec<String> = x[..dim].iter().map(|c| format!("{c:?}")).collect();
            format!("[{}]", s.join(", "))
        };
        format!(
            r#"
name = "corner"
dim = {dim}
[time]
end = 1.0
[grid]
lower = {lo}
upper = {hi}
cells = [{cells}]
[[materials]]
name = "m"
model = "neo_hookean"
density = 1.0
youngs_modulus = 1.0e3
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = {{ box = {{ lower = {blo}, upper = {bhi} }} }}
particles_per_cell = 2
"#,
            lo = v(&[0.0; 3]),
            hi = v(&[1.0; 3]),
            cells = vec![cells.to_string(); dim].join(", "),
            blo = v(&[0.05, 0.1, 0.2]),
            bhi = v(&[0.3, 0.45, 0.4]),
        )
    }

    /// (imbalance before, imbalance after, rebalanced, whether every particle sits in
    /// its rank's cells, particles in all, a second call's verdict).
    fn balance<const D: usize>(
        ranks: usize,
        cells: usize,
    ) -> Vec<(f64, f64, bool, bool, u64, bool)> {
        let sc = scene::parse(&corner_body(D, cells), "corner").unwrap();
        LocalComm::run(ranks, |comm| {
            let layout = Layout::choose([cells; D], [false; D], ranks).unwrap();
            let mut s = Solver::<D>::new(&sc, comm, layout);
            let before = s.imbalance();
            let moved = s.rebalance(1.0);
            let after = s.imbalance();
            let home = (0..s.parts.len()).all(|p| s.layout.cell_owner(s.cell_of(p)) == comm.rank());
            let total = s.totals().particles;
            // Balanced now: a threshold above the imbalance leaves the blocks alone.
            let again = s.rebalance(after + 1e-9);
            (before, after, moved, home, total, again)
        })
    }

    /// An equal split leaves three of four ranks (seven of eight in 3D) empty; one
    /// rebalance brings the largest rank within 10 % of the mean, every particle to
    /// the owner of its cell, and keeps them all. A second call below its threshold
    /// changes nothing.
    #[test]
    fn a_corner_body_is_shared_out() {
        let check = |what: &str, r: Vec<(f64, f64, bool, bool, u64, bool)>, ranks: f64| {
            let (before, after, moved, _, total, again) = r[0];
            assert_eq!(before, ranks, "{what}: one rank held every particle");
            assert!(moved, "{what}: no rebalance");
            assert!(
                after <= 1.10,
                "{what}: imbalance {after} after the rebalance"
            );
            assert!(
                r.iter().all(|x| x.3),
                "{what}: a particle outside its rank's cells"
            );
            assert!(r.iter().all(|x| x.4 == total && x.1 == after && !x.5));
            assert!(!again);
        };
        check("2D", balance::<2>(4, 64), 4.0);
        check("3D", balance::<3>(8, 40), 8.0);
    }
}

#[cfg(test)]
mod locate_tests {
    //! The tile pass's shortcut ([`block_coordinates`], [`ChunkLocator::locate_inside`])
    //! against what it replaced: the grid test and the block test, then
    //! `Geom::locate` ([`ChunkLocator::locate`]).
    use super::*;
    use decomposition::splitmix::Rng;

    /// Inside the block is exactly "on the grid and in the block" (NaN, the grid's
    /// faces and beyond, the block's faces included), and an inside particle gets
    /// `Geom::locate`'s cell, particle by particle, and the same runs, on bounded and
    /// periodic axes, for a block at the grid's edge and one inside it.
    #[test]
    fn inside_particles_locate_as_geom_locate() {
        let mut rng = Rng::new(0x5eed);
        for periodic in [[false, false], [true, false], [false, true]] {
            let geom = Geom::<2>::new([-0.3, 0.1], [1.7, 2.6], [40, 25], periodic);
            for (lo, hi) in [([5usize, 0usize], [31usize, 25usize]), ([0, 7], [40, 19])] {
                // Random positions over the grid and a margin beyond it, every cell
                // face and block face exactly, the grid's faces, and NaN.
                let mut xs: Vec<Vector<2>> = (0..4000)
                    .map(|_| {
                        Vector::<2>::from_fn(|a, _| {
                            let w = geom.upper[a] - geom.lower[a];
                            geom.lower[a] - 0.1 * w + 1.2 * w * rng.f64()
                        })
                    })
                    .collect();
                for k in 0..=40 {
                    for j in 0..=25 {
                        let f = |a: usize, c: usize| geom.lower[a] + c as f64 * geom.h[a];
                        xs.push(Vector::<2>::new(f(0, k), f(1, j)));
                    }
                }
                xs.push(Vector::<2>::new(f64::NAN, 1.0));
                xs.push(Vector::<2>::new(0.5, f64::NAN));
                let (mut runs_a, mut runs_b) = (Vec::new(), Vec::new());
                let mut la = ChunkLocator::new(&geom, 0, &mut runs_a);
                let mut lb = ChunkLocator::new(&geom, 0, &mut runs_b);
                let mut inside_count = 0;
                for (p, x) in xs.iter().enumerate() {
                    let (s, inside) = block_coordinates(&geom, &lo, &hi, x);
                    let on_grid = (0..2).all(|a| on_grid(&geom, a, x[a]));
                    assert_eq!(inside, on_grid && in_block(&geom, &lo, &hi, x), "{x:?}");
                    if !inside {
                        continue;
                    }
                    inside_count += 1;
                    la.locate(p, x);
                    lb.locate_inside(p, &s);
                    assert_eq!(la.prev, lb.prev, "{x:?}");
                }
                assert!(inside_count > 1000, "{inside_count} inside");
                assert_eq!(runs_a, runs_b);
            }
        }
    }

    /// Eight particles at a time ([`ChunkLocator::locate_lanes`]) give what one at a
    /// time gives ([`block_coordinates`], [`ChunkLocator::locate_inside`]): the same
    /// cells and runs, in 2D and 3D, with
    /// runs that start at any lane and span batches; and a batch with a particle
    /// outside the block (beyond a face, on the upper face, NaN) is refused whole,
    /// with nothing stored.
    #[test]
    fn lanes_locate_as_one_at_a_time() {
        fn check<const D: usize>(cells: [usize; D], lo: [usize; D], hi: [usize; D], seed: u64) {
            let mut rng = Rng::new(seed);
            let geom = Geom::<D>::new([0.1; D], [1.3; D], cells, [false; D]);
            // Runs of 1 to 12 particles in one cell, the cells at random in the block.
            let mut xs: Vec<Vector<D>> = Vec::new();
            while xs.len() < 4096 {
                let c: [f64; D] = std::array::from_fn(|a| {
                    (lo[a] + (rng.f64() * (hi[a] - lo[a]) as f64) as usize).min(hi[a] - 1) as f64
                });
                for _ in 0..1 + (rng.f64() * 12.0) as usize {
                    xs.push(Vector::<D>::from_fn(|a, _| {
                        geom.lower[a] + (c[a] + rng.f64()) * geom.h[a]
                    }));
                }
            }
            xs.truncate(4096);
            // Cell corners exactly.
            for k in 0..8 {
                xs[8 * 100 + k] = Vector::<D>::from_fn(|a, _| {
                    geom.lower[a] + (lo[a] + k % (hi[a] - lo[a])) as f64 * geom.h[a]
                });
            }
            // One particle out of the block in some batches.
            let outside = [8 * 200 + 3, 8 * 300, 8 * 400 + 7];
            xs[outside[0]][0] = geom.lower[0] + hi[0] as f64 * geom.h[0];
            xs[outside[1]][D - 1] = f64::NAN;
            xs[outside[2]][0] = geom.lower[0] - 0.01;
            let (mut runs_a, mut runs_b) = (Vec::new(), Vec::new());
            let mut la = ChunkLocator::new(&geom, 1, &mut runs_a);
            let mut lb = ChunkLocator::new(&geom, 1, &mut runs_b);
            let mut refused = 0;
            for p0 in (0..xs.len()).step_by(LANES) {
                let batch: &[Vector<D>; LANES] = xs[p0..p0 + LANES].try_into().unwrap();
                let (runs, prev) = (la.runs.len(), la.prev);
                let ok = la.locate_lanes(p0, batch, (&lo, &hi));
                let mut all = true;
                for (l, x) in batch.iter().enumerate() {
                    let (s, inside) = block_coordinates(&geom, &lo, &hi, x);
                    all &= inside;
                    if ok {
                        lb.locate_inside(p0 + l, &s);
                    }
                }
                assert_eq!(ok, all, "batch at {p0}");
                if ok {
                    assert_eq!(la.prev, lb.prev, "batch at {p0}");
                } else {
                    refused += 1;
                    assert_eq!((la.runs.len(), la.prev), (runs, prev));
                }
            }
            // The planted ones (random positions at a cell's upper face may round
            // onto the block's upper face too).
            for &p in &outside {
                assert!(!block_coordinates(&geom, &lo, &hi, &xs[p]).1);
            }
            assert!(
                refused >= outside.len() && refused < 10,
                "{refused} refused"
            );
            assert!(runs_a.len() > 400, "{} runs", runs_a.len());
            assert_eq!(runs_a, runs_b);
        }
        check::<2>([40, 25], [5, 3], [31, 22], 0x1a9e);
        check::<3>([9, 10, 11], [0, 2, 4], [9, 8, 11], 0x3d);
    }
}

#[cfg(test)]
mod kept_force_tests {
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, SerialComm};

    /// The error pass that keeps the vortex's body force for the next step
    /// (`errors_keeping_forces`) gives `errors`' norms to the bit after every step, and
    /// the steps that read the kept forces (a sort among them, which moves them with
    /// their particles) end with the same particles, bit for bit, as steps that formed
    /// their forces in the scatter.
    #[test]
    fn kept_body_forces_change_no_bit() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/inputs/generalized_vortex.toml"
        ))
        .unwrap()
        .replace("cells = [64, 64]", "cells = [24, 24]");
        let sc = scene::parse(&text, "vortex").unwrap();
        let layout = Layout::choose([24; 2], [false; 2], 1).unwrap();
        let mut kept = Solver::<2>::new(&sc, &SerialComm, layout.clone());
        let mut formed = Solver::<2>::new(&sc, &SerialComm, layout);
        for step in 0..25 {
            kept.advance().unwrap();
            formed.advance().unwrap();
            let (a, b) = (kept.errors_keeping_forces(), formed.errors());
            let bits = |e: Option<(f64, f64)>| e.map(|(u, v)| (u.to_bits(), v.to_bits()));
            assert_eq!(bits(a), bits(b), "step {step}");
            // The forces are kept, for this time, and only where asked for.
            let t = kept.t.to_bits();
            assert!(kept.memo.entries_mut().iter().all(|e| e.2.to_bits() == t));
            assert!(formed.memo.entries_mut().iter().all(|e| e.2.is_nan()));
        }
        assert!(kept.sorts > 0, "a sort among the steps");
        assert_eq!(kept.parts.len(), formed.parts.len());
        for p in 0..kept.parts.len() {
            for (a, b) in [
                (kept.parts.x[p], formed.parts.x[p]),
                (kept.parts.v[p], formed.parts.v[p]),
            ] {
                assert!(
                    a.iter()
                        .zip(b.iter())
                        .all(|(x, y)| x.to_bits() == y.to_bits()),
                    "particle {p}: {a:?} vs {b:?}"
                );
            }
        }
        let turned = (0..kept.parts.len())
            .map(|p| (kept.parts.x[p] - kept.parts.x0[p]).norm())
            .fold(0.0, f64::max);
        assert!(turned > 1e-4, "the ring turned ({turned:e})");
    }
}

#[cfg(test)]
mod sort_tests {
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, SerialComm};

    fn vortex(amplitude: &str) -> Solver<'static, 2> {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/inputs/generalized_vortex.toml"
        ))
        .unwrap()
        .replace("cells = [64, 64]", "cells = [24, 24]")
        .replace("amplitude = 0.1", &format!("amplitude = {amplitude}"));
        let sc = scene::parse(&text, "vortex").unwrap();
        let layout = Layout::choose([24; 2], [false; 2], 1).unwrap();
        Solver::<2>::new(&sc, &SerialComm, layout)
    }

    /// The turning ring falls out of cell order and is sorted back: after a sort the
    /// tile pass finds no run whose cell comes before the previous run's, each cell's
    /// particles in one run per chunk, in id order; and the criterion sorted, only
    /// when more than `SORT_DISORDER` of the particles were out of order.
    #[test]
    fn a_sort_restores_cell_order() {
        let mut s = vortex("0.1");
        let mut most = 0.0f64;
        for _ in 0..25 {
            let sorts = s.sorts;
            s.advance().unwrap();
            let out_of_order = s.disorder as f64 / s.parts.len() as f64;
            assert_eq!(s.sorts > sorts, out_of_order > SORT_DISORDER);
            most = most.max(out_of_order);
        }
        assert!(s.sorts > 0, "the turning ring was sorted");
        // Out of order again, then sorted by hand.
        while s.disorder == 0 {
            s.advance().unwrap();
        }
        s.sort();
        s.locate_all();
        assert_eq!(descents(&s.cell_runs), 0);
        let mut seen = std::collections::HashSet::new();
        for (k, runs) in s.cell_runs.iter().enumerate() {
            for (r, run) in runs.iter().enumerate() {
                assert!(
                    seen.insert((k, run.cell)),
                    "cell {:?} in two runs",
                    run.cell
                );
                let end = runs
                    .get(r + 1)
                    .map_or(((k + 1) * LOCATE_CHUNK).min(s.parts.len()), |e| {
                        e.first as usize
                    });
                let ids = &s.parts.id[run.first as usize..end];
                assert!(ids.windows(2).all(|w| w[0] < w[1]), "ids in order");
            }
        }
        assert!(most > 0.0);
    }

    /// A body at rest stays in the order of its first sort: no particle is ever out
    /// of order, and none is sorted again.
    #[test]
    fn a_body_at_rest_is_not_sorted_again() {
        let mut s = vortex("0.0");
        for _ in 0..30 {
            s.advance().unwrap();
            assert_eq!(s.disorder, 0);
        }
        assert_eq!(s.sorts, 0);
    }
}
