//! Where particles are: the tile pass (each particle's cell, runs of one cell, the slab order), the active nodes, and the sort by cell.

use super::*;

/// Wrap the coordinates of `x` along periodic axes into the period.
#[inline(always)]
pub(super) fn wrap_periodic<const D: usize>(geom: &Geom<D>, x: &mut Vector<D>) {
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
pub(super) fn block_coordinates<const D: usize>(
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
pub(super) fn on_grid<const D: usize>(geom: &Geom<D>, a: usize, x: f64) -> bool {
    geom.periodic[a] | ((x >= geom.lower[a]) & (x <= geom.upper[a]))
}

/// Whether position `x` lies in the cells `[lo, hi)` of a block, by a test that needs
/// no cell lookup: `s` in `[lo, hi)` is `Geom::locate`'s cell in the block (its floor
/// of the same `s`, which the clamp at bounded faces leaves in the block). Most
/// particles stay in their block; the others are looked up.
#[inline]
pub(super) fn in_block<const D: usize>(
    geom: &Geom<D>,
    lo: &[usize; D],
    hi: &[usize; D],
    x: &Vector<D>,
) -> bool {
    block_coordinates(geom, lo, hi, x).1
}

/// The sort by cell runs when more than this fraction of a rank's particles are out
/// of order ([`Placement::disorder`]). Particles that cross cells break their cells' runs,
/// and every particle pass pays per run: on the vortex, whose ring turns through the
/// cells, a step costs 1.3 % more for each step since the last sort, while a sort
/// (keys, order, the arrays moved and the next tile pass's locating) costs about
/// two fifths of a step. One in twenty out of order is about every five steps of the
/// vortex (0.93 of its time sorted every 20 steps; one in ten: 0.97, one in 33:
/// 0.96); a body at rest is not sorted again.
pub(super) const SORT_DISORDER: f64 = 0.05;

/// A run of particles in one cell, as the tile pass finds it.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct CellRun<const D: usize> {
    /// The run's first particle.
    pub(super) first: u32,
    /// The storage index of its cell's lower corner node ([`Solver::run_nodes`]).
    pub(super) node: u32,
    /// Its cell, as the locator found it: the later passes over the runs need not
    /// locate their first particles again. 32-bit: the scene allows at most
    /// `i32::MAX` cells per axis ([`crate::input::scene::MAX_CELLS_PER_AXIS`]), and a run of 3D
    /// particles that move between sorts is one per particle or so (20 bytes each,
    /// not 32).
    pub(super) cell: [i32; D],
}

impl<const D: usize> CellRun<D> {
    pub(super) fn new(first: usize, cell: [i64; D]) -> Self {
        debug_assert!(cell.iter().all(|&c| (0..=i32::MAX as i64).contains(&c)));
        CellRun {
            first: first as u32,
            node: 0,
            cell: cell.map(|c| c as i32),
        }
    }

    /// Its cell.
    #[inline(always)]
    pub(super) fn cell(&self) -> [i64; D] {
        self.cell.map(i64::from)
    }
}

/// The tile pass's location of the particles of one chunk, in order: in `runs`, where
/// a run of particles in one cell starts (the chunk's first particle starts one).
pub(super) struct ChunkLocator<'a, const D: usize> {
    pub(super) geom: &'a Geom<D>,
    /// The chunk's first particle.
    pub(super) base: usize,
    /// The cell of the particle located last (none at first).
    pub(super) prev: [i64; D],
    pub(super) runs: &'a mut Vec<CellRun<D>>,
    /// With 3 nodes per axis (GIMP, the domain rule), whose particles are sorted by
    /// window ([`Solver::sort`]): the window of the particle located last, and how many
    /// particles' windows came before the previous one's in that order (the chunk's
    /// disorder, [`Placement::window_descents`]).
    pub(super) wide: bool,
    pub(super) prev_window: [i64; D],
    pub(super) window_descents: usize,
}

/// The tile pass's runs of one cell as [`kernel::SlabRuns`]: the slab order sorts
/// them, not the particles one by one.
pub(super) struct RunSlabs<'a, const D: usize> {
    /// Per chunk of [`LOCATE_CHUNK`] particles, its runs.
    pub(super) runs: &'a [Vec<CellRun<D>>],
    pub(super) count: usize,
    pub(super) index: kernel::SlabIndex,
}

const _: () = assert!(LOCATE_CHUNK == kernel::SlabOrder::CHUNK);

// `each` only reads the runs, which it borrows: the same every call. (They
// cover the chunk: its first particle starts a run, later ones start at increasing
// particles within it (`ChunkLocator`), and run k ends where run k + 1 starts.)
impl<const D: usize> kernel::SlabRuns for RunSlabs<'_, D> {
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
    pub(super) fn new(
        geom: &'a Geom<D>,
        chunk: usize,
        runs: &'a mut Vec<CellRun<D>>,
        wide: bool,
    ) -> Self {
        runs.clear();
        ChunkLocator {
            geom,
            base: chunk * LOCATE_CHUNK,
            prev: [i64::MIN; D],
            runs,
            wide,
            prev_window: [i64::MIN; D],
            window_descents: 0,
        }
    }

    /// Count a particle in cell `c` at local coordinate `xi` whose window
    /// ([`crate::physics::shape::window`]) comes before the last one's in the sort's
    /// order (the last axis first).
    #[inline(always)]
    fn note_window(&mut self, c: &[i64; D], xi: &[f64; D]) {
        let w = crate::physics::shape::window(self.geom, c, xi);
        let key = |w: &[i64; D]| std::array::from_fn::<i64, D, _>(|a| w[D - 1 - a]);
        self.window_descents += usize::from(key(&w) < key(&self.prev_window));
        self.prev_window = w;
    }

    /// Locate the chunk's particle `p`, at `x`, by `Geom::locate` (its floor clamped
    /// to the grid): for a particle on a bounded grid's upper face, which
    /// [`ChunkLocator::locate`] refuses.
    #[inline(always)]
    pub(super) fn locate_clamped(&mut self, p: usize, x: &Vector<D>) {
        let (c, xi) = self.geom.locate(&std::array::from_fn(|a| x[a]));
        if self.wide {
            self.note_window(&c, &xi);
        }
        self.store(p, c);
    }

    /// Locate the `L` particles from the chunk's `p0`, at `xs`, if all of them lie in
    /// the block's cells `[lo, hi)` ([`block_coordinates`]); else return `false` and
    /// store nothing. Their grid coordinates `s` (per axis `(x − lower) / h`, as
    /// `Geom::locate` forms them) are then at least 0 and below the cell count, where
    /// `Geom::locate`'s floor is the truncation and its clamp changes nothing, so this
    /// is its cell without either; over `L` particles as vector operations, the same
    /// arithmetic per lane, so the same cells and runs at every `L`.
    #[inline(always)]
    pub(super) fn locate<const L: usize>(
        &mut self,
        p0: usize,
        xs: &[Vector<D>; L],
        (lo, hi): (&[usize; D], &[usize; D]),
    ) -> bool {
        let geom = self.geom;
        let mut s = [[0.0; L]; D];
        // `&`, not `&&` or `all`: no branch per axis and lane.
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
        // Truncation: every lane passed `lo[a] <= s < hi[a]` (a NaN fails it), so
        // `t = trunc(s)` is an integer in `[0, 2³¹)`, `t + 2⁵²` is exact, and its bits
        // are those of 2⁵² plus `t`. Unlike `as`, which saturates lane by lane in
        // scalar code, this is three vector operations.
        const TWO_52: f64 = 4_503_599_627_370_496.0;
        let mut c = [[0i64; L]; D];
        for a in 0..D {
            for l in 0..L {
                c[a][l] = ((s[a][l].trunc() + TWO_52).to_bits() - TWO_52.to_bits()) as i64;
            }
        }
        if self.wide {
            for l in 0..L {
                let cl: [i64; D] = std::array::from_fn(|a| c[a][l]);
                self.note_window(&cl, &std::array::from_fn(|a| s[a][l] - cl[a] as f64));
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
    pub(super) fn store(&mut self, p: usize, c: [i64; D]) {
        if c != self.prev {
            self.prev = c;
            self.runs.push(CellRun::new(self.base + p, c));
        }
    }
}

/// The runs (in order, over all chunks) whose cell comes before the previous run's in
/// the sort's order (the last axis first): none right after a sort, and about one per
/// particle that crossed into another cell since (it breaks its old cell's run).
pub(super) fn descents<const D: usize>(runs: &[Vec<CellRun<D>>]) -> usize {
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

/// Particles per chunk of the tile pass's parallel locate (fixed, so that its runs do
/// not depend on the thread count).
pub(super) const LOCATE_CHUNK: usize = 4096;

/// The order of [`Solver::sort`]: a cell (with 3 nodes per axis a window,
/// [`sort_place`]) as one number, the last axis first (a number in mixed radix whose
/// digits are its coordinates counted from the block's first, or one below it for a
/// window, which starts at most one cell below the block). (A scene's grid has at most
/// 2^40 nodes, `MAX_GRID_NODES`: the products fit.)
struct SortKey<'a, const D: usize> {
    lo: &'a [usize; D],
    hi: &'a [usize; D],
    first: [i64; D],
    stride: [u64; D],
    /// How many keys there are.
    span: u64,
}

impl<'a, const D: usize> SortKey<'a, D> {
    fn new(lo: &'a [usize; D], hi: &'a [usize; D], wide: bool) -> Self {
        let first = std::array::from_fn(|a| lo[a] as i64 - i64::from(wide));
        let mut stride = [0u64; D];
        let mut span = 1u64;
        for a in 0..D {
            stride[a] = span;
            span *= (hi[a] as i64 - first[a]) as u64;
        }
        SortKey {
            lo,
            hi,
            first,
            stride,
            span,
        }
    }

    /// The key of place `c`, which must lie in the block.
    #[inline]
    fn of(&self, c: &[i64; D]) -> u64 {
        let mut key = 0;
        for a in 0..D {
            let digit = c[a] - self.first[a];
            assert!(
                (0..self.hi[a] as i64 - self.first[a]).contains(&digit),
                "a particle in cell {c:?} is outside its block {:?} .. {:?}",
                self.lo,
                self.hi
            );
            key += digit as u64 * self.stride[a];
        }
        key
    }
}

/// Where [`Solver::sort`] puts a particle at `x`: its cell, or with 3 nodes per axis
/// (`wide`: GIMP, the domain rule) its window of nodes ([`crate::physics::shape::window`]),
/// so that the particles of one window, in up to 2^D cells, come in a row and the passes
/// read and write their nodes once for all of them.
#[inline]
fn sort_place<const D: usize>(geom: &Geom<D>, x: &Vector<D>, wide: bool) -> [i64; D] {
    let (c, xi) = geom.locate(&std::array::from_fn(|a| x[a]));
    if wide {
        crate::physics::shape::window(geom, &c, &xi)
    } else {
        c
    }
}

impl<'c, const D: usize> Solver<'c, D> {
    /// The tile pass's parallel part: locate every particle and list per chunk of
    /// particles where a run of particles in one cell starts (the chunk's first
    /// particle starts one). Chunks are fixed, so the runs do not depend on the thread
    /// count.
    pub(super) fn locate_all(&mut self) {
        let chunks = self.begin_locate();
        let (geom, lo, hi) = (&self.geom, &self.block.cell_lo, &self.block.cell_hi);
        let wide = self.scheme.wide();
        self.parts
            .x
            .par_chunks(LOCATE_CHUNK)
            .zip(self.place.cell_runs.par_iter_mut())
            .zip(self.place.window_descents.par_iter_mut())
            .enumerate()
            .for_each(|(k, ((xs, runs), descents))| {
                let mut loc = ChunkLocator::new(geom, k, runs, wide);
                // Eight at a time where all eight lie in the block's cells, else one
                // by one (one on the grid's upper face by `Geom::locate`).
                let mut p = 0;
                while p < xs.len() {
                    if let Some(batch) = xs.get(p..p + LANES) {
                        let batch = <&[Vector<D>; LANES]>::try_from(batch).expect("a batch");
                        if loc.locate(p, batch, (lo, hi)) {
                            p += LANES;
                            continue;
                        }
                    }
                    let one = std::array::from_ref(&xs[p]);
                    if !loc.locate(p, one, (lo, hi)) {
                        loc.locate_clamped(p, &xs[p]);
                    }
                    p += 1;
                }
                *descents = loc.window_descents;
            });
        self.place.cell_runs.truncate(chunks);
    }

    /// The tile pass's arrays sized for this rank's particles: the chunk count.
    pub(super) fn begin_locate(&mut self) -> usize {
        let n = self.parts.len();
        // As much room as the particles' arrays have (which grow with a sixteenth to
        // spare, [`particles::reserve`]): no more, and it grows when they do.
        let room = self.parts.x.capacity().max(n);
        particles::reserve_exact(&mut self.place.ptile, room);
        // Every entry is written below: only new ones need a value (no serial fill).
        self.place.ptile.resize(n, 0);
        let chunks = n.div_ceil(LOCATE_CHUNK);
        if self.place.cell_runs.len() < chunks {
            self.place.cell_runs.resize_with(chunks, Vec::new);
        }
        self.place.window_descents.resize(chunks, 0);
        chunks
    }

    /// The local cell of a run.
    #[inline]
    pub(super) fn run_cell(node_lo: &[i64; D], run: &CellRun<D>) -> [i64; D] {
        let c = run.cell();
        std::array::from_fn(|a| c[a] - node_lo[a])
    }

    /// Touch the tiles every run's nodes lie in: their keys gathered per chunk on
    /// threads (consecutive runs mostly share their tiles, so a small cache keeps the
    /// lists short), then touched in chunk order.
    pub(super) fn touch_runs(&mut self) {
        let (below, above) = if self.scheme.wide() { (1, 2) } else { (0, 1) };
        let chunks = self.place.cell_runs.len();
        if self.place.run_keys.len() < chunks {
            self.place.run_keys.resize_with(chunks, Vec::new);
        }
        let tiles = &self.tiles;
        let node_lo = &self.block.node_lo;
        self.place
            .cell_runs
            .par_iter()
            .zip(self.place.run_keys.par_iter_mut())
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
        for &k in self.place.run_keys[..chunks].iter().flatten() {
            self.tiles.touch_key(k);
        }
    }

    /// The storage index of each run's cell's lower corner node ([`Placement::cell_runs`]),
    /// on threads, once the active set holds every run's tile ([`Solver::touch_runs`],
    /// [`Tiles::finish`]).
    pub(super) fn run_nodes(&mut self) {
        let tiles = &self.tiles;
        let node_lo = &self.block.node_lo;
        self.place.cell_runs.par_iter_mut().for_each(|runs| {
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

    /// This rank's wrapped cell of particle `p` (positions are wrapped by `relocate`;
    /// the remainder guards a coordinate that rounded onto the period).
    pub(super) fn cell_of(&self, p: usize) -> [usize; D] {
        let (c, _) = self
            .geom
            .locate(&std::array::from_fn(|a| self.parts.x[p][a]));
        std::array::from_fn(|a| c[a].rem_euclid(self.geom.cells[a] as i64) as usize)
    }

    /// Reorder particles by cell (with 3 nodes per axis by window,
    /// [`crate::physics::shape::window`]; then by id, for determinism), so that the
    /// particle loops meet those that share their nodes in a row.
    pub fn sort(&mut self) {
        // The wrap's location, if it holds, names every particle's cell; after the
        // sort it is stale.
        let located = std::mem::take(&mut self.place.located);
        self.place.sorts += 1;
        let n = self.parts.len();
        // Each particle's place as one number ([`SortKey`]). Counted from the block's
        // first cell it mostly fits 32 bits, and is then kept in `ptile`, with the slab
        // order's array as the radix sort's room: both are stale once particles move
        // and rebuilt by the next tile pass before any read, so the keys need no memory
        // of their own.
        let wide = self.scheme.wide();
        let order = SortKey::new(&self.block.cell_lo, &self.block.cell_hi, wide);
        let geom = &self.geom;
        let place_of = |p: usize| sort_place(geom, &self.parts.x[p], wide);
        if order.span <= 1 << 32 {
            let keys = &mut self.place.ptile;
            particles::reserve(keys, n);
            keys.resize(n, 0);
            let runs = &self.place.cell_runs;
            keys.par_chunks_mut(LOCATE_CHUNK)
                .enumerate()
                .for_each(|(k, keys)| {
                    let base = k * LOCATE_CHUNK;
                    if !located || wide {
                        for (p, key) in keys.iter_mut().enumerate() {
                            *key = order.of(&place_of(base + p)) as u32;
                        }
                        return;
                    }
                    // A key per run, not a location per particle.
                    for (r, run) in runs[k].iter().enumerate() {
                        let end = runs[k]
                            .get(r + 1)
                            .map_or(keys.len(), |e| e.first as usize - base);
                        keys[run.first as usize - base..end].fill(order.of(&run.cell()) as u32);
                    }
                });
            let keys = &self.place.ptile;
            let key = |p: u32| u64::from(keys[p as usize]);
            particles::order_by_key_then_id(
                key,
                &self.parts.id,
                &mut self.scratch.perm,
                self.place.slabs.lend_scratch(),
            );
        } else {
            // A block of more than 2^32 cells (sparse): each key formed where the sort
            // asks for it, `ptile` the room.
            let key = |p: u32| order.of(&place_of(p as usize));
            particles::order_by_key_then_id(
                key,
                &self.parts.id,
                &mut self.scratch.perm,
                &mut self.place.ptile,
            );
        }
        let perm = std::mem::take(&mut self.scratch.perm);
        // A benchmark's memo goes with its particles where it has one entry each:
        // formed again, its factors cost an `atan2` and sines per particle (the
        // vortex), and a sort moves most particles.
        let memo = self.scratch.memo.entries_mut();
        let memo = if memo.len() == perm.len() {
            memo
        } else {
            &mut []
        };
        self.parts
            .permute_with(&perm, &mut self.scratch.permuted, memo);
        self.scratch.perm = perm;
    }
}

#[cfg(test)]
mod locate_tests {
    //! The tile pass's shortcut ([`block_coordinates`], [`ChunkLocator::locate`])
    //! against what it replaced: the grid test and the block test, then
    //! `Geom::locate` ([`ChunkLocator::locate_clamped`]).
    use super::*;
    use decomposition::splitmix::Rng;

    /// Inside the block is exactly "on the grid and in the block" (NaN, the grid's
    /// faces and beyond, the block's faces included), and an inside particle gets
    /// `Geom::locate`'s cell, particle by particle, and the same runs, on bounded and
    /// periodic axes, for a block at the grid's edge and one inside it.
    #[test]
    pub(super) fn inside_particles_locate_as_geom_locate() {
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
                let mut la = ChunkLocator::new(&geom, 0, &mut runs_a, true);
                let mut lb = ChunkLocator::new(&geom, 0, &mut runs_b, true);
                let mut inside_count = 0;
                // The windows' descents in the sort's order (the last axis first),
                // counted here from `Geom::locate` and `shape::window`.
                let (mut descents, mut last) = (0, [i64::MIN; 2]);
                for (p, x) in xs.iter().enumerate() {
                    let inside = block_coordinates(&geom, &lo, &hi, x).1;
                    let on_grid = (0..2).all(|a| on_grid(&geom, a, x[a]));
                    assert_eq!(inside, on_grid && in_block(&geom, &lo, &hi, x), "{x:?}");
                    if !inside {
                        continue;
                    }
                    inside_count += 1;
                    la.locate_clamped(p, x);
                    assert!(lb.locate(p, std::array::from_ref(x), (&lo, &hi)));
                    assert_eq!(la.prev, lb.prev, "{x:?}");
                    let (c, xi) = geom.locate(&[x[0], x[1]]);
                    let w = crate::physics::shape::window(&geom, &c, &xi);
                    descents += usize::from([w[1], w[0]] < [last[1], last[0]]);
                    last = w;
                    assert_eq!((la.prev_window, lb.prev_window), (w, w), "{x:?}");
                }
                assert!(descents > 100, "{descents} descents");
                assert_eq!(
                    (la.window_descents, lb.window_descents),
                    (descents, descents)
                );
                assert!(inside_count > 1000, "{inside_count} inside");
                assert_eq!(runs_a, runs_b);
            }
        }
    }

    /// Eight particles at a time ([`ChunkLocator::locate`]) give what one at a time
    /// gives (the same at width 1, and [`block_coordinates`]): the same
    /// cells and runs, in 2D and 3D, with
    /// runs that start at any lane and span batches; and a batch with a particle
    /// outside the block (beyond a face, on the upper face, NaN) is refused whole,
    /// with nothing stored.
    #[test]
    pub(super) fn lanes_locate_as_one_at_a_time() {
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
            let mut la = ChunkLocator::new(&geom, 1, &mut runs_a, true);
            let mut lb = ChunkLocator::new(&geom, 1, &mut runs_b, true);
            let mut refused = 0;
            for p0 in (0..xs.len()).step_by(LANES) {
                let batch: &[Vector<D>; LANES] = xs[p0..p0 + LANES].try_into().unwrap();
                let (runs, prev) = (la.runs.len(), la.prev);
                let ok = la.locate(p0, batch, (&lo, &hi));
                let mut all = true;
                for (l, x) in batch.iter().enumerate() {
                    let inside = block_coordinates(&geom, &lo, &hi, x).1;
                    all &= inside;
                    if ok {
                        assert!(lb.locate(p0 + l, std::array::from_ref(x), (&lo, &hi)));
                    }
                }
                assert_eq!(ok, all, "batch at {p0}");
                if ok {
                    assert_eq!(la.prev, lb.prev, "batch at {p0}");
                    assert_eq!(la.prev_window, lb.prev_window, "batch at {p0}");
                } else {
                    refused += 1;
                    assert_eq!((la.runs.len(), la.prev), (runs, prev));
                    assert_eq!(la.window_descents, lb.window_descents);
                }
            }
            assert!(la.window_descents > 100, "{} descents", la.window_descents);
            assert_eq!(la.window_descents, lb.window_descents);
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
            // Each run's cell is `Geom::locate`'s (its floor and clamp) for its first.
            for r in &runs_a {
                let x = &xs[r.first as usize - LOCATE_CHUNK];
                let (c, _) = geom.locate(&std::array::from_fn(|a| x[a]));
                assert_eq!(r.cell(), c, "run from {}", r.first);
            }
        }
        check::<2>([40, 25], [5, 3], [31, 22], 0x1a9e);
        check::<3>([9, 10, 11], [0, 2, 4], [9, 8, 11], 0x3d);
    }
}

#[cfg(test)]
mod sort_tests {
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, SerialComm};

    pub(super) fn vortex(amplitude: &str) -> Solver<'static, 2> {
        vortex_with(amplitude, "gradient = \"mpmcg\"")
    }

    /// The vortex with `gradient` in place of its gradient line.
    fn vortex_with(amplitude: &str, gradient: &str) -> Solver<'static, 2> {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/inputs/generalized_vortex.toml"
        ))
        .unwrap()
        .replace("cells = [64, 64]", "cells = [24, 24]")
        .replace("amplitude = 0.1", &format!("amplitude = {amplitude}"))
        .replace("gradient = \"mpmcg\"", gradient);
        // Plain defaults: absent keys give MPMCG at the particle, the path tested.
        let sc = scene::parse_with(&text, "vortex", scene::PLAIN_DEFAULTS).unwrap();
        let layout = Layout::choose([24; 2], [false; 2], 1).unwrap();
        Solver::<2>::new(&sc, &SerialComm, layout)
    }

    /// 25 steps of the turning ring, each sorted exactly when more than
    /// `SORT_DISORDER` of the particles were out of order, then more until some are:
    /// the largest share out of order after a step.
    fn turn(s: &mut Solver<'_, 2>) -> f64 {
        let mut most = 0.0f64;
        for _ in 0..25 {
            let sorts = s.place.sorts;
            s.advance().unwrap();
            let out_of_order = s.place.disorder as f64 / s.parts.len() as f64;
            assert_eq!(s.place.sorts > sorts, out_of_order > SORT_DISORDER);
            most = most.max(out_of_order);
        }
        while s.place.disorder == 0 {
            s.advance().unwrap();
        }
        most
    }

    /// The turning ring falls out of cell order and is sorted back: after a sort the
    /// tile pass finds no run whose cell comes before the previous run's, each cell's
    /// particles in one run per chunk, in id order; and the criterion sorted, only
    /// when more than `SORT_DISORDER` of the particles were out of order.
    #[test]
    pub(super) fn a_sort_restores_cell_order() {
        let mut s = vortex("0.1");
        let most = turn(&mut s);
        assert!(s.place.sorts > 0, "the turning ring was sorted");
        s.sort();
        s.locate_all();
        assert_eq!(descents(&s.place.cell_runs), 0);
        let mut seen = std::collections::HashSet::new();
        for (k, runs) in s.place.cell_runs.iter().enumerate() {
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
    pub(super) fn a_body_at_rest_is_not_sorted_again() {
        let mut s = vortex("0.0");
        for _ in 0..30 {
            s.advance().unwrap();
            assert_eq!(s.place.disorder, 0);
        }
        assert_eq!(s.place.sorts, 0);
    }

    /// The windows of particles with 3 nodes per axis, in the sort's order (the last
    /// axis first), and their ids.
    fn windows(s: &Solver<'_, 2>) -> Vec<([i64; 2], u64)> {
        (0..s.parts.len())
            .map(|p| {
                let w = sort_place(&s.geom, &s.parts.x[p], true);
                ([w[1], w[0]], s.parts.id[p])
            })
            .collect()
    }

    /// With 3 nodes per axis (the domain rule, GIMP) particles are sorted by window, so
    /// that those sharing their nodes come in a row: seeded, then after the turning
    /// ring fell out of order, a sort leaves them in order by window and by id within
    /// one, which the tile pass counts as no descent; the criterion sorts exactly when
    /// more than `SORT_DISORDER` of them are out of window order; a ring at rest is
    /// never sorted after its first sort.
    #[test]
    pub(super) fn a_sort_restores_window_order() {
        let methods = [
            "gradient = \"mpmcg\"\nquadrature = \"domain\"",
            "gradient = \"gimp\"",
        ];
        for method in methods {
            let in_order = |s: &Solver<'_, 2>| windows(s).windows(2).all(|p| p[0] < p[1]);
            let mut s = vortex_with("0.1", method);
            assert!(s.scheme.wide(), "{method}");
            assert!(in_order(&s), "{method}: seeded particles sorted by window");
            assert_eq!(s.place.sorts, 1);
            let most = turn(&mut s);
            assert!(s.place.sorts > 1, "{method}: the turning ring was sorted");
            assert!(!in_order(&s));
            s.sort();
            assert!(in_order(&s), "{method}");
            s.locate_all();
            assert_eq!(s.place.window_descents.iter().sum::<usize>(), 0, "{method}");
            assert!(most > 0.0);
            // At rest: sorted once, when seeded.
            let mut s = vortex_with("0.0", method);
            for _ in 0..30 {
                s.advance().unwrap();
                assert_eq!(s.place.disorder, 0, "{method}");
            }
            assert_eq!(s.place.sorts, 1, "{method}");
        }
    }
}
