//! The coloured slab order that lets rayon tasks write the grid at once: slabs of cells along the last axis in two colours, same-coloured slabs never sharing a node; and the raw pointers those writes go through.

/// Slab thickness in cells for the coloured scatter of a stencil of `NA` nodes per
/// axis (see [`scatter`] for why same-coloured slabs never share a node). A particle
/// in cell `c` writes the nodes of at most `c − below ..= c + above` along an axis,
/// `below = (NA − 1) / 2`, `above = NA − 1` (hats: `c ..= c + 1`; GIMP and quadratic
/// B-splines, three nodes chosen by the half of the cell: `c − 1 ..= c + 2`); slabs
/// `s` and `s + 2` then write disjoint node rows when `T ≥ below + above`. Thin slabs
/// are many, so that two threads get equal shares of a colour.
pub const fn slab_thickness<const NA: usize>() -> usize {
    let (below, above) = ((NA - 1) / 2, NA - 1);
    below + above
}

/// [`slab_thickness`] for the stencil a run uses: hats (`NA = 2`) or 3 nodes per axis.
/// The passes that write through the order check it against their own `NA`
/// ([`SlabOrder::check_reach`]), so a mismatch stops the run instead of racing.
pub fn slab_thickness_for(wide: bool) -> usize {
    if wide {
        slab_thickness::<3>()
    } else {
        slab_thickness::<2>()
    }
}

/// A particle's slab from its cell along the last axis ([`SlabOrder::begin`]).
#[derive(Clone, Copy, Debug)]
pub struct SlabIndex {
    pub(super) lo: usize,
    pub(super) hi: usize,
    pub(super) thick: usize,
}

impl SlabIndex {
    /// The slab of a particle in cell `c` along the last axis (as `Geom::locate`
    /// gives it, so that the kern's nodes agree with the slab).
    #[inline]
    pub fn slab(self, c: i64) -> u32 {
        // The scatter's threads rely on this (see `scatter`): a particle outside its
        // block would write outside its slab's rows.
        assert!(
            (self.lo as i64..self.hi as i64).contains(&c),
            "a particle in cell {c} along the last axis is outside its block [{}, {})",
            self.lo,
            self.hi
        );
        ((c as usize - self.lo) / self.thick) as u32
    }

    /// [`SlabIndex::slab`] of `L` cells at once: one range test for all of them, and
    /// no division for slabs one cell thick (hat functions), so that the lanes of the
    /// tile pass ([`slab_thickness`]) stay vector operations.
    #[inline(always)]
    pub fn slabs<const L: usize>(self, c: &[i64; L]) -> [u32; L] {
        let (lo, hi) = (self.lo as i64, self.hi as i64);
        let mut ok = true;
        for &c in c {
            ok &= (c >= lo) & (c < hi);
        }
        if !ok {
            // The same message as one at a time, for the first cell out of range.
            return c.map(|c| self.slab(c));
        }
        if self.thick == 1 {
            c.map(|c| (c - lo) as u32)
        } else {
            c.map(|c| ((c - lo) as usize / self.thick) as u32)
        }
    }
}

/// A rank's particles in runs of one slab, chunk by chunk of [`SlabOrder::CHUNK`]:
/// what [`SlabOrder::finish`] sorts. The tile pass's runs of one cell are such runs,
/// so the order needs no slab stored per particle (4 bytes each).
///
/// `each(c, …)`'s runs must cover chunk `c`'s particles (`c · CHUNK ..`, up to
/// `count`) exactly, in order, the same runs every call. [`SlabOrder::finish`] checks
/// what its soundness needs whatever an implementation does: its parallel writes stay
/// within the places each chunk counted for each slab (else it stops the run), and the
/// order it builds lists every particle exactly once, which the parallel writes of the
/// scatter and the remap rely on.
pub trait SlabRuns: Sync {
    /// The particle count.
    fn count(&self) -> usize;

    /// `f(s, particles)` for the runs of chunk `c` in order: together they cover its
    /// particles `c · CHUNK ..` exactly, each run in slab `s`.
    fn each(&self, c: usize, f: impl FnMut(u32, std::ops::Range<usize>));
}

/// One slab's particles, as [`SlabOrder::for_each_slab`] hands them to a task.
pub struct Slab<'a> {
    pub particles: &'a [u32],
    index: SlabIndex,
    slab: u32,
}

impl Slab<'_> {
    /// Stops the pass unless cell `c` along the last axis (a run's, before the pass
    /// writes its nodes) lies in this slab: the writes then stay within the slab's
    /// reach, which no slab of its colour shares, whatever positions and cells the
    /// pass was given.
    #[inline]
    pub fn check_cell(&self, c: i64) {
        let s = self.index.slab(c);
        assert!(
            s == self.slab,
            "a run in cell {c} along the last axis is in slab {s}, not in the slab {} that lists it",
            self.slab
        );
    }
}

/// The particle order of the coloured scatter: particle indices grouped by slab.
/// Its fields are private and only [`SlabOrder::finish`] fills them, after which the
/// order lists every particle of the runs exactly once: the property that lets the
/// scatter's and the remap's tasks write what their particles own without a lock.
#[derive(Debug)]
pub struct SlabOrder {
    /// `start[s]..start[s + 1]` indexes `order` for slab `s`.
    start: Vec<usize>,
    order: Vec<u32>,
    /// Per chunk of [`SlabOrder::CHUNK`] particles, its particles per slab (chunk-major),
    /// then where its first particle of each slab goes in `order`.
    counts: Vec<usize>,
    /// Per chunk and slab, the end of its places in `order`.
    ends: Vec<usize>,
    /// `below[s]`: the particles of the slabs `s − 2, s − 4, …` (same colour, below).
    below: Vec<usize>,
    /// Owned cells along the last axis, `[lo, hi)`, in slabs of `thick` cells.
    lo: usize,
    hi: usize,
    thick: usize,
    /// Whether each particle has been seen, for [`SlabOrder::finish`]'s check.
    seen: Vec<u64>,
}

/// Where the chunks of a parallel counting sort write `order`.
#[derive(Clone, Copy)]
struct OrderPtr(*mut u32, usize);

// SAFETY: made in `SlabOrder::count_in_chunks` from `&mut self.order`, held for its
// whole use; every write is bounds-checked (`OrderPtr::write`). Chunk `c` writes its
// particles of slab `s` into `order[counts[c][s] .. ends[c][s]]`, checked per run; the
// ranges are an exclusive prefix sum over (slab, chunk) of the counts, so those of
// different (chunk, slab) pairs are disjoint. No two threads write one element and no
// element is read while they run.
unsafe impl Send for OrderPtr {}

unsafe impl Sync for OrderPtr {}

impl OrderPtr {
    /// Write `order[k] = p`. Safety: `k` lies in `order` and no other thread reads or
    /// writes `order[k]` (see the type's safety note).
    #[inline(always)]
    unsafe fn write(self, k: usize, p: u32) {
        assert!(k < self.1, "slab order written past its end");
        // SAFETY: in bounds (checked above); no other thread touches `order[k]`, the
        // caller's contract.
        unsafe { *self.0.add(k) = p };
    }
}

impl SlabOrder {
    /// Particles per chunk of the parallel passes that fill the order (fixed, so the
    /// order does not depend on the thread count).
    pub const CHUNK: usize = 4096;

    /// An order of no slab, to be filled by [`SlabOrder::begin`] and
    /// [`SlabOrder::finish`]. (No `Default`: an order is made here or built, never
    /// filled in field by field.)
    #[allow(clippy::new_without_default)]
    pub fn new() -> Self {
        SlabOrder {
            start: vec![0],
            order: Vec::new(),
            counts: Vec::new(),
            ends: Vec::new(),
            below: vec![0, 0],
            lo: 0,
            hi: 0,
            thick: 1,
            seen: Vec::new(),
        }
    }

    /// The particles of slab `s`, in order.
    #[inline]
    pub fn slab(&self, s: usize) -> &[u32] {
        &self.order[self.start[s]..self.start[s + 1]]
    }

    /// The whole order, slab after slab.
    #[cfg(test)]
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Stops a pass whose stencil of `NA` nodes per axis reaches further than the
    /// slabs are thick: its same-coloured slabs would write the same nodes.
    #[inline]
    pub fn check_reach<const NA: usize>(&self) {
        assert!(
            self.thick >= slab_thickness::<NA>(),
            "slabs {} cells thick for a stencil of {NA} nodes per axis",
            self.thick
        );
    }

    /// The order's storage lent as scratch (the sort's permutation): the order is
    /// emptied to no slab first, so nothing can read it stale; the next
    /// [`SlabOrder::begin`] and [`SlabOrder::finish`] build it anew.
    pub fn lend_scratch(&mut self) -> &mut Vec<u32> {
        self.start.clear();
        self.start.push(0);
        self.below.clear();
        self.below.extend([0, 0]);
        &mut self.order
    }

    /// Start grouping particles by slab (of `thick` cells, [`slab_thickness`]) along the
    /// last axis of the owned cells `[cell_lo, cell_hi)`; the returned index finds a
    /// cell's slab. Then [`SlabOrder::finish`] with the particles' runs.
    pub fn begin(&mut self, cell_lo: usize, cell_hi: usize, thick: usize) -> SlabIndex {
        let nslab = (cell_hi - cell_lo).div_ceil(thick).max(1);
        self.lo = cell_lo;
        self.hi = cell_hi;
        self.thick = thick;
        self.start.clear();
        self.start.resize(nslab + 1, 0);
        self.index()
    }

    /// How to find a cell's slab (the last [`SlabOrder::begin`]'s).
    pub fn index(&self) -> SlabIndex {
        SlabIndex {
            lo: self.lo,
            hi: self.hi,
            thick: self.thick,
        }
    }

    /// Order the particles of `runs` by slab, stably (within a slab, particles keep
    /// their array order): a counting sort over runs, its counting and placing in
    /// parallel over chunks where the per-chunk counts are few (a slab count per
    /// chunk, no more numbers than particles), else serially (many slabs, as in a huge
    /// box, with few particles). The order is the same either way.
    pub fn finish(&mut self, runs: &impl SlabRuns) {
        let nslab = self.start.len() - 1;
        let n = runs.count();
        let nchunk = n.div_ceil(Self::CHUNK);
        if nchunk * nslab <= n {
            self.count_in_chunks(nchunk, runs);
        } else {
            self.start.fill(0);
            for c in 0..nchunk {
                runs.each(c, |s, run| self.start[s as usize + 1] += run.len());
            }
            for s in 0..nslab {
                self.start[s + 1] += self.start[s];
            }
            self.order.resize(n, 0);
            let mut at = self.start.clone();
            for c in 0..nchunk {
                runs.each(c, |s, run| {
                    let k = at[s as usize];
                    for (o, p) in self.order[k..k + run.len()].iter_mut().zip(run.clone()) {
                        *o = p as u32;
                    }
                    at[s as usize] += run.len();
                });
            }
        }
        assert_eq!(self.start[nslab], n, "the runs cover every particle once");
        self.check_each_once();
        // Per colour, the particles of the slabs below each slab ([`SlabOrder::split`]).
        self.below.clear();
        self.below.resize(nslab + 2, 0);
        for s in 0..nslab {
            self.below[s + 2] = self.below[s] + self.start[s + 1] - self.start[s];
        }
    }

    /// Stops the run unless `order` lists each of its `n` particles `0..n` exactly
    /// once (it has `n` entries: a repeat would leave another particle out).
    fn check_each_once(&mut self) {
        let n = self.order.len();
        self.seen.clear();
        self.seen.resize(n.div_ceil(64), 0);
        let mut twice = false;
        for &p in &self.order {
            let p = p as usize;
            assert!(p < n, "slab order names particle {p} of {n}");
            let (word, bit) = (p / 64, 1u64 << (p % 64));
            twice |= self.seen[word] & bit != 0;
            self.seen[word] |= bit;
        }
        assert!(!twice, "slab order lists a particle twice");
    }

    /// [`SlabOrder::finish`]'s parallel counting sort.
    pub(super) fn count_in_chunks(&mut self, nchunk: usize, runs: &impl SlabRuns) {
        use rayon::prelude::*;
        let nslab = self.start.len() - 1;
        self.counts.clear();
        self.counts.resize(nchunk * nslab, 0);
        self.counts
            .par_chunks_mut(nslab)
            .enumerate()
            .for_each(|(c, count)| {
                runs.each(c, |s, run| count[s as usize] += run.len());
            });
        // Offsets: slab by slab, chunk by chunk within a slab (so within a slab the
        // particles keep their array order). Walked chunk by chunk (the counts' own
        // order, not a stride of a slab count per step): first each slab's total, whose
        // prefix sums start the slabs, then each chunk's place after the chunks before.
        self.start.fill(0);
        for count in self.counts.chunks_exact(nslab) {
            for (t, &c) in self.start[1..].iter_mut().zip(count) {
                *t += c;
            }
        }
        for s in 0..nslab {
            self.start[s + 1] += self.start[s];
        }
        self.ends.clear();
        self.ends.resize(nchunk * nslab, 0);
        for c in 0..nchunk {
            let (next, row, ends) = (
                &mut self.start[..nslab],
                &mut self.counts[c * nslab..][..nslab],
                &mut self.ends[c * nslab..][..nslab],
            );
            for ((k, at), end) in row.iter_mut().zip(next.iter_mut()).zip(ends) {
                let count = *k;
                *k = *at;
                *at += count;
                *end = *at;
            }
        }
        let total = self.start[nslab];
        // `start` was advanced past each slab: back to the slabs' starts.
        for s in (1..=nslab).rev() {
            self.start[s] = self.start[s - 1];
        }
        self.start[0] = 0;
        // Every entry is written below.
        // As long as the runs counted (which the writes below stay within).
        self.order.resize(total, 0);
        let out = OrderPtr(self.order.as_mut_ptr(), self.order.len());
        self.counts
            .par_chunks_mut(nslab)
            .zip(self.ends.par_chunks(nslab))
            .enumerate()
            .for_each(|(c, (cursor, ends))| {
                runs.each(c, |s, run| {
                    // In a local, not through `cursor`, which the writes might alias
                    // as far as the compiler knows.
                    let mut k = cursor[s as usize];
                    assert!(
                        k + run.len() <= ends[s as usize],
                        "a chunk's runs differ from those it counted"
                    );
                    for p in run {
                        // SAFETY: see `OrderPtr`: `k` stays within this chunk's range
                        // for slab `s` (checked above), which lies in `order` and no
                        // other thread writes.
                        unsafe { out.write(k, p as u32) };
                        k += 1;
                    }
                    cursor[s as usize] = k;
                });
            });
    }

    pub fn slabs(&self) -> usize {
        self.start.len() - 1
    }

    /// `f` over every slab ([`Slab`]), colour by colour: first the slabs
    /// `0, 2, 4, …`, then `1, 3, …`, the slabs of one colour in parallel (never
    /// sharing a node, [`slab_thickness`]). The slabs of a colour are halved where they
    /// hold half of their particles ([`SlabOrder::split`]), so the same slabs go
    /// together whatever the thread count, and their results are joined by `join` in
    /// that fixed tree, from `zero()`: the same sums every run.
    pub fn for_each_slab<T: Send>(
        &self,
        zero: &(impl Fn() -> T + Sync),
        f: &(impl Fn(Slab<'_>) -> T + Sync),
        join: &(impl Fn(T, T) -> T + Sync),
    ) -> T {
        let ns = self.slabs();
        let mut t = zero();
        for colour in 0..2.min(ns) {
            let count = (ns - colour).div_ceil(2);
            t = join(t, self.same_colour(colour, count, zero, f, join));
        }
        t
    }

    /// [`SlabOrder::for_each_slab`] over the slabs `first, first + 2, …` (`count`).
    fn same_colour<T: Send>(
        &self,
        first: usize,
        count: usize,
        zero: &(impl Fn() -> T + Sync),
        f: &(impl Fn(Slab<'_>) -> T + Sync),
        join: &(impl Fn(T, T) -> T + Sync),
    ) -> T {
        if count == 1 {
            return f(Slab {
                particles: self.slab(first),
                index: self.index(),
                slab: first as u32,
            });
        }
        let Some(half) = self.split(first, count) else {
            return zero();
        };
        let (a, b) = rayon::join(
            || self.same_colour(first, half, zero, f, join),
            || self.same_colour(first + 2 * half, count - half, zero, f, join),
        );
        join(a, b)
    }

    /// How the same-coloured slabs `first, first + 2, …` (`count` of them, at least 2)
    /// split between two tasks: `None` if they hold no particle, else how many go to
    /// the first task, at least one each, so that its particles come nearest to half
    /// of theirs; of two such splits, the one nearer the middle slab. Depends on the
    /// particles, not the threads. The recursion of the coloured loops thus halves
    /// the particles, or the slabs where a slab holds no particle, or ends at a slab
    /// that holds more than the rest: it is O(log) deep (a huge box has many empty
    /// slabs: always splitting off one slab recursed once per slab, and overflowed
    /// the stack).
    pub fn split(&self, first: usize, count: usize) -> Option<usize> {
        // The particles of the first h slabs.
        let share = |h: usize| self.below[first + 2 * h] - self.below[first];
        let total = share(count);
        if total == 0 {
            return None;
        }
        // The first h in 1..count whose share reaches half, by bisection (the shares
        // grow with h); the best split is it or the one before.
        let (mut lo, mut hi) = (1, count - 1);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if 2 * share(mid) >= total {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        let key = |h: usize| ((2 * share(h)).abs_diff(total), (2 * h).abs_diff(count));
        Some(if lo > 1 && key(lo - 1) < key(lo) {
            lo - 1
        } else {
            lo
        })
    }
}

/// The scatter's view of the node records, shared by its threads.
#[derive(Clone, Copy)]
pub(crate) struct GridPtr {
    pub(super) ptr: *mut f64,
    pub(super) len: usize,
}

impl GridPtr {
    pub(crate) fn new(field: &mut [f64]) -> Self {
        GridPtr {
            ptr: field.as_mut_ptr(),
            len: field.len(),
        }
    }

    /// The `width` numbers at `at` (bounds checked).
    ///
    /// # Safety
    /// The field the pointer was made from is still borrowed exclusively by the caller's
    /// caller, and no other thread reads or writes these numbers while the slice lives.
    #[inline(always)]
    pub(crate) unsafe fn record<'a>(self, at: usize, width: usize) -> &'a mut [f64] {
        assert!(
            at + width <= self.len,
            "node record outside the grid storage"
        );
        // SAFETY: in bounds (checked above); exclusive by the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(at), width) }
    }

    /// Ask for the cache lines of the `width` numbers at `at` ahead of their use: a
    /// hint, no access (an address outside the storage is never touched).
    #[inline(always)]
    pub(crate) fn prefetch(self, at: usize, width: usize) {
        prefetch_lines(self.ptr.wrapping_add(at).cast(), width * size_of::<f64>());
    }
}

/// A particle array that the remap's threads write, each the particles of its own
/// slabs (the slab order lists every particle once and gives each slab to one task).
#[derive(Clone, Copy)]
pub(crate) struct RowPtr<T> {
    ptr: *mut T,
    len: usize,
}

impl<T> RowPtr<T> {
    pub(crate) fn new(rows: &mut [T]) -> Self {
        RowPtr {
            ptr: rows.as_mut_ptr(),
            len: rows.len(),
        }
    }

    /// Row `p` (bounds checked).
    ///
    /// # Safety
    /// The array the pointer was made from is still borrowed exclusively by the
    /// caller's caller, and no other thread reads or writes row `p` while the
    /// reference lives.
    #[inline(always)]
    pub(crate) unsafe fn row<'a>(self, p: usize) -> &'a mut T {
        assert!(p < self.len, "particle {p} of {}", self.len);
        // SAFETY: in bounds (checked above); exclusive by the caller's contract.
        unsafe { &mut *self.ptr.add(p) }
    }
}

// SAFETY: a `RowPtr` is made from a `&mut [T]` that its maker holds for the whole
// parallel pass, and the threads given copies touch disjoint rows (the callers'
// contract of `RowPtr::row`): sharing it is sharing disjoint parts of an exclusively
// borrowed array, as sending `&mut` to them would be.
unsafe impl<T: Send> Send for RowPtr<T> {}

unsafe impl<T: Send> Sync for RowPtr<T> {}

/// Ask for the cache lines of `field[at..at + width]` ahead of their use: a hint, no
/// access (a range outside the field is never touched).
#[inline(always)]
pub(crate) fn prefetch<T>(field: &[T], at: usize, width: usize) {
    prefetch_lines(
        field.as_ptr().wrapping_add(at).cast(),
        width * size_of::<T>(),
    );
}

/// Prefetch the cache lines of the `bytes` bytes from `first`: only an address, never
/// dereferenced.
#[inline(always)]
pub(super) fn prefetch_lines(first: *const u8, bytes: usize) {
    #[cfg(target_arch = "x86_64")]
    if bytes > 0 {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let last = first.wrapping_add(bytes - 1) as usize;
        let mut line = first as usize & !63;
        while line <= last {
            // SAFETY: a prefetch is a hint: it never faults, whatever the address, and
            // changes no memory; its SSE is in every x86-64 CPU.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(line as *const i8) };
            line += 64;
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (first, bytes);
}

// SAFETY: a `GridPtr` is only made in `scatter` from a `&mut [f64]` that it holds for
// its whole run, and the threads given copies write node records of disjoint node sets
// (see `scatter`), so sharing it between threads is sharing disjoint parts of a buffer
// borrowed exclusively.
unsafe impl Send for GridPtr {}

unsafe impl Sync for GridPtr {}

#[cfg(test)]
mod tests {
    use super::*;

    /// Node rows along the last axis that slab `s` of thickness `t` writes with a
    /// stencil of `na` nodes per axis: cells `s·t .. (s+1)·t`, each writing
    /// `c − below ..= c + above`.
    fn rows(s: i64, t: i64, na: i64) -> (i64, i64) {
        let (below, above) = ((na - 1) / 2, na - 1);
        (s * t - below, (s + 1) * t - 1 + above)
    }

    fn thickness<const NA: usize>() -> i64 {
        slab_thickness::<NA>() as i64
    }

    /// For every stencil width, same-coloured slabs (`s`, `s + 2`) write disjoint node
    /// rows at the derived thickness, and one cell thinner they would not.
    #[test]
    fn same_coloured_slabs_write_disjoint_rows_for_every_reach() {
        for (na, t) in [
            (2, thickness::<2>()),
            (3, thickness::<3>()),
            (4, thickness::<4>()),
            (5, thickness::<5>()),
        ] {
            for s in 0..6 {
                assert!(rows(s, t, na).1 < rows(s + 2, t, na).0, "NA {na}, slab {s}");
                if t > 1 {
                    assert!(rows(s, t - 1, na).1 >= rows(s + 2, t - 1, na).0, "NA {na}");
                }
            }
        }
        assert_eq!((thickness::<2>(), thickness::<3>()), (1, 3));
        assert_eq!(slab_thickness_for(false), 1);
        assert_eq!(slab_thickness_for(true), 3);
    }

    /// Particles in cells along one axis, each writing through a `GridPtr` the node
    /// rows of a stencil of `NA` nodes (`c − below ..= c + above`) and through a
    /// `RowPtr` its own row, from the tasks of `for_each_slab` on three threads: the
    /// sums equal one thread's, and the joined tally counts every particle once. (Under
    /// Miri, a race between two tasks' writes would stop the test.)
    fn parallel_writes<const NA: usize>() {
        let (cells, n) = (23usize, 157usize);
        let cell = |p: usize| ((p * 7919) % cells) as i64;
        let (below, above) = ((NA - 1) / 2, NA - 1);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .expect("a thread pool");
        let mut o = SlabOrder::new();
        let ix = o.begin(0, cells, slab_thickness::<NA>());
        struct Cells<F: Fn(usize) -> i64 + Sync>(usize, SlabIndex, F);
        impl<F: Fn(usize) -> i64 + Sync> SlabRuns for Cells<F> {
            fn count(&self) -> usize {
                self.0
            }
            fn each(&self, c: usize, mut f: impl FnMut(u32, std::ops::Range<usize>)) {
                let end = self.0.min((c + 1) * SlabOrder::CHUNK);
                for p in c * SlabOrder::CHUNK..end {
                    f(self.1.slab((self.2)(p)), p..p + 1);
                }
            }
        }
        o.finish(&Cells(n, ix, cell));
        o.check_reach::<NA>();
        let mut grid = vec![0.0; cells + NA + 1];
        let mut mine = vec![0u32; n];
        let (g, rows) = (GridPtr::new(&mut grid), RowPtr::new(&mut mine));
        let visited = pool.install(|| {
            o.for_each_slab(
                &|| 0usize,
                &|slab| {
                    for &p in slab.particles {
                        slab.check_cell(cell(p as usize));
                        let c = cell(p as usize) as usize + below;
                        // SAFETY: the slab's particles write rows within its reach,
                        // which no same-coloured slab shares (the property tested).
                        let rec = unsafe { g.record(c - below, below + above + 1) };
                        for (k, r) in rec.iter_mut().enumerate() {
                            *r += (k + 1) as f64;
                        }
                        // SAFETY: the order lists particle p once.
                        unsafe { *rows.row(p as usize) += 1 };
                    }
                    slab.particles.len()
                },
                &|a, b| a + b,
            )
        });
        let mut expect = vec![0.0; cells + NA + 1];
        for p in 0..n {
            let c = cell(p) as usize + below;
            for k in 0..=below + above {
                expect[c - below + k] += (k + 1) as f64;
            }
        }
        assert_eq!(visited, n, "NA {NA}");
        assert!(
            mine.iter().all(|&m| m == 1),
            "NA {NA}: a particle's row written twice"
        );
        assert_eq!(grid, expect, "NA {NA}");
    }

    #[test]
    fn parallel_writes_through_the_slab_order_do_not_race() {
        parallel_writes::<2>();
        parallel_writes::<3>();
    }

    /// Runs that list one particle twice (and so another never).
    struct Twice;

    impl SlabRuns for Twice {
        fn count(&self) -> usize {
            3
        }

        fn each(&self, c: usize, mut f: impl FnMut(u32, std::ops::Range<usize>)) {
            assert_eq!(c, 0);
            f(0, 0..2);
            f(1, 1..2);
        }
    }

    #[test]
    #[should_panic(expected = "lists a particle twice")]
    fn an_order_that_lists_a_particle_twice_is_refused() {
        let mut o = SlabOrder::new();
        o.begin(0, 4, 1);
        o.finish(&Twice);
    }

    #[test]
    #[should_panic(expected = "slabs 1 cells thick for a stencil of 3 nodes per axis")]
    fn slabs_too_thin_for_the_stencil_are_refused() {
        let mut o = SlabOrder::new();
        o.begin(0, 4, slab_thickness_for(false));
        o.check_reach::<3>();
    }

    /// The order lent as scratch leaves no slab behind to be read stale.
    #[test]
    fn scratch_empties_the_order() {
        struct One;
        impl SlabRuns for One {
            fn count(&self) -> usize {
                5
            }
            fn each(&self, _: usize, mut f: impl FnMut(u32, std::ops::Range<usize>)) {
                f(0, 0..5);
            }
        }
        let mut o = SlabOrder::new();
        o.begin(0, 2, 1);
        o.finish(&One);
        assert_eq!(o.slab(0), &[0, 1, 2, 3, 4]);
        o.lend_scratch().push(7);
        assert_eq!(o.slabs(), 0);
        assert_eq!(o.split(0, 0), None);
    }

    /// Runs that change between the count and the placing (the parallel path: two
    /// chunks, two slabs): the first call puts every particle in slab 0, later ones
    /// in slab 1, so slab 1's writes would run past the places counted for it.
    #[test]
    #[should_panic(expected = "a chunk's runs differ from those it counted")]
    fn runs_that_change_between_count_and_placing_are_refused() {
        struct Shifty(std::sync::atomic::AtomicUsize);
        impl SlabRuns for Shifty {
            fn count(&self) -> usize {
                2 * SlabOrder::CHUNK
            }
            fn each(&self, c: usize, mut f: impl FnMut(u32, std::ops::Range<usize>)) {
                let calls = self.0.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let s = u32::from(calls >= 2);
                f(s, c * SlabOrder::CHUNK..(c + 1) * SlabOrder::CHUNK);
            }
        }
        let mut o = SlabOrder::new();
        o.begin(0, 2, 1);
        o.finish(&Shifty(std::sync::atomic::AtomicUsize::new(0)));
    }

    /// A pass whose particles' cells disagree with the order (positions moved since
    /// it was built) is stopped at the first run outside the slab that lists it.
    #[test]
    #[should_panic(expected = "is in slab 1, not in the slab 0 that lists it")]
    fn a_run_outside_its_slab_is_refused() {
        struct Two;
        impl SlabRuns for Two {
            fn count(&self) -> usize {
                2
            }
            fn each(&self, _: usize, mut f: impl FnMut(u32, std::ops::Range<usize>)) {
                f(0, 0..1);
                f(1, 1..2);
            }
        }
        let mut o = SlabOrder::new();
        o.begin(0, 4, 1);
        o.finish(&Two);
        // Particle 0, listed in slab 0, now in cell 1.
        o.for_each_slab(
            &|| (),
            &|slab| slab.check_cell(slab.particles[0] as i64 + 1),
            &|(), ()| (),
        );
    }
}
