//! Particle to grid: the coloured scatter of mass, momentum and forces, summed per run of particles before they are added into the node records.

use super::*;

/// Read-only particle arrays for the scatter.
pub struct ScatterParts<'a, const D: usize> {
    pub x: &'a [Vector<D>],
    pub v: &'a [Vector<D>],
    /// The stress where particles store it, else empty and formed from `def_grad`.
    pub stress: &'a [Mat<D>],
    pub def_grad: &'a [Mat<D>],
    pub kind: &'a [u16],
    pub vol: particles::Volumes<'a, D>,
    pub mass: particles::Masses<'a>,
    pub x0: &'a [Vector<D>],
    pub half: &'a [[f64; D]],
    /// Storage index of each particle's cell's lower corner node.
    pub tile: &'a [u32],
    /// A grid field of D numbers per node whose interpolation at the particle replaces
    /// its velocity in the momentum ([`Sums::FromGrid`]; XPIC's `S⁺S`).
    pub src: &'a [f64],
    /// The external force per unit mass of each particle where the scene has a body
    /// force ([`external_accel`]), else empty.
    pub accel: &'a [Vector<D>],
}

/// Each particle's external force per unit mass (gravity and the body force), into
/// `out`, one entry per particle of `x0`: formed once a step, before the forces'
/// scatter, which uses it, and kept for the work the gather or the remap of the same
/// step counts with it. A benchmark's body force costs sines and a logarithm per
/// particle; a pass of its own forms them in batches ([`At::add_body_forces`]). With
/// `over`, the particles' reference half-widths, the body force is averaged over each
/// particle's box instead ([`At::body_force_over`]).
pub fn external_accel<const D: usize>(
    ctx: &Ctx<'_, D>,
    x0: &[Vector<D>],
    over: Option<&[[f64; D]]>,
    out: &mut [Vector<D>],
) {
    assert_eq!(out.len(), x0.len());
    const CHUNK: usize = 4096;
    out.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, out)| match (ctx.body_force, over) {
            (Some(b), Some(half)) => {
                let first = c * CHUNK;
                for (k, o) in out.iter_mut().enumerate() {
                    *o = ctx.gravity + b.body_force_over(&x0[first + k], &half[first + k]);
                }
            }
            (Some(b), None) => b.add_body_forces(ctx.gravity, x0, c * CHUNK, out),
            (None, _) => out.fill(ctx.gravity),
        });
}

/// What a scatter sums into the nodes' mass and momentum.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sums {
    /// `Σ m S` and `Σ m S v`: the particles' mass and momentum.
    Particles,
    /// `Σ m S` and `Σ m S u`, `u` the grid field `src` interpolated at each particle
    /// (grid → particle → grid in one pass: XPIC's `S⁺S`, the consistent mass matrix
    /// times a field).
    FromGrid,
    /// `Σ m S²` in the mass: the consistent mass matrix's diagonal (the null-space
    /// diagnostic's preconditioner); the momentum sums are not read.
    MassSquares,
}

/// How the scatter lays out its node record.
#[derive(Clone, Copy, Debug)]
pub struct ScatterMode {
    /// Record width per node.
    pub sw: usize,
    /// Scatter external and internal forces (else mass and momentum only).
    pub forces: bool,
    /// Also accumulate Σ(1−α) v σ S and the nodes' covered volume Σ v S (two-step
    /// schemes).
    pub two_step: bool,
    /// What the mass and momentum sums are of.
    pub sums: Sums,
    /// Also accumulate the first moment `Σ_p m_p S_j (x̂_p − x_j)` of each node, with
    /// `x̂_p = Σ_k S_k x_k` the node positions interpolated at the particle (two-step
    /// schemes with the centroid correction, [`NodeRecord::moment`]).
    pub moments: bool,
}

/// Particle → grid over all particles into `scat` (cleared by the caller), in slab
/// colours so that no two threads write the same node.
///
/// Why threads never write the same record: slab `s` holds the particles whose cell
/// lies in cells `[lo + s·T, lo + (s+1)·T)` of the block along the last axis (`T` the
/// [`slab_thickness`], checked against `NA` here; `SlabIndex::slab` asserts the cell). A particle in cell `c` writes
/// nodes `c ..= c + 1` along that axis with hat functions, so slab `s` writes node rows
/// `lo + s·T ..= lo + (s+1)·T` and slab `s + 2` starts at row `lo + (s+2)·T`: disjoint
/// for T >= 1. A GIMP particle writes `c − 1 ..= c + 2`, so slab `s` writes up to row
/// `lo + (s+1)·T + 1` and slab `s + 2` from row `lo + (s+2)·T − 1`: disjoint for
/// T >= 3. Same-coloured slabs thus write disjoint node sets, and the
/// storage map of [`Tiles`] is injective (a node has one tile, a tile one slot), so
/// they write disjoint records. The two colours run one after the other.
///
pub fn scatter<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: &ScatterParts<'_, D>,
    slabs: &SlabOrder,
    scat: &mut [f64],
    m: ScatterMode,
) {
    slabs.check_reach::<NA>();
    let grid = GridPtr::new(scat);
    let slab = |slab: Slab<'_>| scatter_slab::<D, NA, N>(ctx, parts, slab, grid, m);
    slabs.for_each_slab(&|| (), &slab, &|(), ()| ());
}

/// The scatter of one slab's particles into the records behind `grid`.
pub(super) fn scatter_slab<const D: usize, const NA: usize, const N: usize>(
    ctx: &Ctx<'_, D>,
    parts: &ScatterParts<'_, D>,
    slab: Slab<'_>,
    grid: GridPtr,
    m: ScatterMode,
) {
    let mut acc = ScatterSums::<D, N>::new();
    // The sums stay in memory (L1), added into by vector loads and stores. Held in
    // registers, the compiler split them into single numbers and put them back into
    // vectors for every particle (two dozen shuffles per particle, a third of the 2D
    // scatter's samples); marking the place as seen from outside keeps it whole:
    // the 2D block drop 0.93x the time, 3D the same.
    let acc = std::hint::black_box(&mut acc);
    let mut run = Run::<D, NA, N>::new();
    let mut cell = CellAt::<D>::new();
    let mut kinds = particles::KindCache::new(ctx.kind_mass, ctx.kind_vol0, ctx.materials);
    // Each node's position relative to the first node of its particle's stencil: a
    // moment relative to the node is then the same sum wherever the stencil lies, a
    // node's image across a periodic seam included.
    let off: [[f64; N]; D] = std::array::from_fn(|a| {
        std::array::from_fn(|n| ((n / NA.pow(a as u32)) % NA) as f64 * ctx.geom.h[a])
    });
    // The arrays every particle has, each as long as the positions: one index check
    // per particle then covers them all.
    let len = parts.x.len();
    let (xs, vels, tiles, kind) = (
        &parts.x[..len],
        &parts.v[..len],
        &parts.tile[..len],
        &parts.kind[..len],
    );
    for &p in slab.particles {
        let p = p as usize;
        assert!(p < len, "slab order names particle {p} of {len}");
        let at = kinds.get(kind[p]);
        // The stress first: in 3D it is a call (`particles::stress_call`), and every
        // vector register live across it is saved and reloaded; before the weights,
        // few are.
        let (vol, vs) = if m.forces {
            particles::volume_and_stress(parts.stress, &parts.vol, ctx.materials, &at, p)
        } else {
            (parts.vol.get(p), Mat::<D>::zeros())
        };
        let half = ctx.half_width(parts.half, parts.def_grad, p);
        // (ξ formed here, not before the stress: there, the 2D scatter's share
        // grew 1.13 against ξ kept by the tile pass, here 1.06.)
        let c = *cell.of(ctx, tiles[p]);
        let xi = ctx.local(&xs[p], &c);
        let reads = Reads {
            gradients: m.forces,
            moments: false,
        };
        let (mut k, below, _) = ctx.weights::<NA, N>(&xs[p], half.as_ref(), &xi, reads);
        if run.is_new(ctx, tiles[p], below) {
            if run.started() {
                acc.flush(ctx, grid, &run.idx, m);
            }
            slab.check_cell(c[D - 1] as i64);
            run.enter(ctx, tiles[p], below);
            // The run's records are added into at its end, after its particles:
            // fetched meanwhile, not waited for then.
            for &n in &run.idx {
                grid.prefetch(n * m.sw, m.sw);
            }
        }
        let mass = at.mass;
        let mv = momentum(m.sums, &k.s, &run.idx, parts.src, &vels[p]) * mass;
        let fe = if m.forces {
            ctx.accel_kept(parts.accel, parts.x0, p) * mass
        } else {
            Vector::<D>::zeros()
        };
        if m.sums == Sums::MassSquares {
            // Squared here, not in `add`: a test in its loops cost the 2D step 1.24×.
            // (The momentum sums then hold `Σ m S² v`, which this mode does not read.)
            for s in &mut k.s {
                *s *= *s;
            }
        }
        acc.add(&k, mass, &mv, vol, &vs, &fe, m);
        if m.moments {
            acc.add_moment(&k, mass, &off);
        }
    }
    if run.started() {
        acc.flush(ctx, grid, &run.idx, m);
    }
}

/// The velocity whose momentum a particle scatters: its own, or under
/// [`Sums::FromGrid`] the grid field `src` interpolated with its weights `s` at its
/// nodes `idx`.
#[inline(always)]
fn momentum<const D: usize, const N: usize>(
    sums: Sums,
    s: &[f64; N],
    idx: &[usize; N],
    src: &[f64],
    v: &Vector<D>,
) -> Vector<D> {
    if sums != Sums::FromGrid {
        return *v;
    }
    let mut u = Vector::<D>::zeros();
    for n in 0..N {
        for a in 0..D {
            u[a] += s[n] * src[idx[n] * D + a];
        }
    }
    u
}

/// A scatter's sums over one run of particles that share their nodes (particles sorted
/// by cell: 16 in a row in 2D at 4 × 4 per cell), added into the node records once per
/// run. The particle loop adds into these fixed places, which need no index
/// arithmetic or bounds checks and do not wait on the previous particle's store into
/// the grid; the records see one addition per run instead of one per particle.
/// Each sum is per node, nodes innermost.
///
/// Aligned to 32 bytes: the clear after each run (`memset`) then stores whole aligned
/// vectors where the next run's first particle loads them, and each load finds its
/// store to forward from. Unaligned, every such load spans two of `memset`'s stores
/// and waits for them to reach the cache: the 3D scatter's two hottest instructions
/// (12 % and 8.5 % of its samples), gone from the profile once aligned.
#[repr(C, align(32))]
pub(super) struct ScatterSums<const D: usize, const N: usize> {
    pub(super) mass: [f64; N],
    pub(super) mom: [[f64; N]; D],
    pub(super) force: [[f64; N]; D],
    /// Hat functions: the internal force's sums per pair of nodes along each axis,
    /// `pairs[a][b][m] = Σ_p α_p V_p σ_p[a][b] ∂_b S_upper(x_p)` over the `m`-th pair
    /// ([`pair`]); the upper node gets minus it, the lower one it, at the flush.
    pub(super) pairs: [[[f64; N]; D]; D],
    /// The upper triangle ([`sym_index`]); 6 is the 3D count.
    pub(super) stress: [[f64; N]; 6],
    pub(super) cover: [f64; N],
    /// The first moment relative to each node ([`ScatterMode::moments`]).
    pub(super) moment: [[f64; N]; D],
}

impl<const D: usize, const N: usize> ScatterSums<D, N> {
    pub(super) fn new() -> Self {
        ScatterSums {
            mass: [0.0; N],
            mom: [[0.0; N]; D],
            force: [[0.0; N]; D],
            pairs: [[[0.0; N]; D]; D],
            stress: [[0.0; N]; 6],
            cover: [0.0; N],
            moment: [[0.0; N]; D],
        }
    }

    /// Add one particle's contributions: mass, momentum `mv`, and as `m` asks the
    /// cover (volume `vol`), the forces (external `fe`, internal from `vs = V σ`) and
    /// the averaged-stress sum.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn add(
        &mut self,
        k: &Kern<D, N>,
        mass: f64,
        mv: &Vector<D>,
        vol: f64,
        vs: &Mat<D>,
        fe: &Vector<D>,
        m: ScatterMode,
    ) {
        // Node-innermost loops over fixed arrays: each is a few vector operations.
        for n in 0..N {
            self.mass[n] += mass * k.s[n];
        }
        for a in 0..D {
            for n in 0..N {
                self.mom[a][n] += mv[a] * k.s[n];
            }
        }
        if m.two_step {
            for n in 0..N {
                self.cover[n] += vol * k.s[n];
            }
        }
        if m.forces && hats::<D, N>() {
            // A hat's derivative along b at the lower node of a pair is exactly minus
            // the upper one's: one product per pair, not per node.
            for a in 0..D {
                for n in 0..N {
                    self.force[a][n] += fe[a] * k.s[n];
                }
                for b in 0..D {
                    let avs = k.alpha * vs[(a, b)];
                    for m in 0..N / 2 {
                        self.pairs[a][b][m] += avs * k.g[b][pair(b, m).1];
                    }
                }
            }
        } else if m.forces {
            for a in 0..D {
                for n in 0..N {
                    let mut sg = 0.0;
                    for b in 0..D {
                        sg += vs[(a, b)] * k.g[b][n];
                    }
                    self.force[a][n] += fe[a] * k.s[n] - k.alpha * sg;
                }
            }
        }
        if m.forces && m.two_step {
            let c = &k.avg_w;
            for a in 0..D {
                for b in a..D {
                    let t = &mut self.stress[sym_index::<D>(a, b)];
                    for n in 0..N {
                        t[n] += c[n] * vs[(a, b)];
                    }
                }
            }
        }
    }

    /// Add one particle's first moment relative to each of its nodes: the node
    /// positions `off`, relative to the stencil's first node, interpolated at the
    /// particle, less each node's own.
    #[inline(always)]
    pub(super) fn add_moment(&mut self, k: &Kern<D, N>, mass: f64, off: &[[f64; N]; D]) {
        for a in 0..D {
            let mut r = 0.0;
            for n in 0..N {
                r += k.s[n] * off[a][n];
            }
            for n in 0..N {
                self.moment[a][n] += mass * k.s[n] * (r - off[a][n]);
            }
        }
    }

    /// Add the sums into the records of nodes `idx` and start again from zero.
    #[inline(always)]
    pub(super) fn flush(
        &mut self,
        ctx: &Ctx<'_, D>,
        grid: GridPtr,
        idx: &[usize; N],
        m: ScatterMode,
    ) {
        type R<const D: usize> = NodeRecord<D>;
        let sw = m.sw;
        if m.forces && hats::<D, N>() {
            // Each node is in one pair along each axis: it gets its pair's sum, plus at
            // the lower node and minus at the upper (`x + (−p)` is `x − p` to the bit),
            // spread over all nodes first so that the additions are whole vectors.
            for a in 0..D {
                for b in 0..D {
                    let p = &self.pairs[a][b];
                    let mut e = [0.0; N];
                    for (n, e) in e.iter_mut().enumerate() {
                        let m = pair_of(b, n);
                        *e = if (n >> b) & 1 == 0 { p[m] } else { -p[m] };
                    }
                    for n in 0..N {
                        self.force[a][n] += e[n];
                    }
                }
            }
        }
        for n in 0..N {
            debug_assert!(
                idx[n] >= ctx.tiles.tile_nodes(),
                "a particle's node in the zero tile: its tile was not touched"
            );
            // SAFETY: no other thread writes this record while this one does (see
            // `scatter`), and this thread holds no other reference into the buffer
            // while `rec` lives.
            let rec = unsafe { grid.record(idx[n] * sw, sw) };
            rec[R::<D>::MASS] += self.mass[n];
            for a in 0..D {
                rec[R::<D>::momentum(a)] += self.mom[a][n];
            }
            if m.two_step {
                rec[R::<D>::cover(sw)] += self.cover[n];
            }
            if m.moments {
                for a in 0..D {
                    rec[R::<D>::moment(a)] += self.moment[a][n];
                }
            }
            if m.forces {
                for a in 0..D {
                    rec[R::<D>::force(a)] += self.force[a][n];
                }
                if m.two_step {
                    for k in 0..R::<D>::SYM {
                        rec[R::<D>::stress_sum(0, 0) + k] += self.stress[k][n];
                    }
                }
            }
        }
        *self = Self::new();
    }
}
