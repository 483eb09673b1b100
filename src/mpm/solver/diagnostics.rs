//! What a run reports of the state: energy and momentum totals and error norms against an exact solution.

use super::*;

/// The sum of `f(k)` over `k` in `lo..hi`, in parallel, added in a tree fixed by the
/// range (halves), so that the result does not depend on the threads.
pub(super) fn tree_sum<const N: usize>(
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
pub(super) fn add_errors<const D: usize>(
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

impl<'c, const D: usize> Solver<'c, D> {
    /// A hash of this rank's particles (ids, positions and velocities to the bit): the
    /// same for a state reached again bit for bit, and almost surely not for one that
    /// differs in any bit. The particles' hashes are added, so the hash does not
    /// depend on their order, the thread count or the reduction's grouping.
    pub fn fingerprint(&self) -> u64 {
        fingerprint(&self.parts)
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

    /// The time the particles' velocities are at: half the last step before the
    /// positions' ([`Solver::kick`]).
    pub fn velocity_time(&self) -> f64 {
        self.t - 0.5 * self.dt
    }

    /// Volume-weighted L2 norms of the displacement and velocity errors against the
    /// benchmark's exact solution, the displacement's at the current time and the
    /// velocity's at [`Solver::velocity_time`] (over all ranks).
    pub fn errors(&self) -> Option<(f64, f64)> {
        let b = self.benchmark.as_ref()?;
        let bv = b.at(self.velocity_time());
        let b = b.at(self.t).with_memo(&self.scratch.memo);
        let (parts, vol0) = (&self.parts, &self.kinds.vol0[..]);
        // Summed per fixed chunk, then in a fixed tree: the same on any thread count.
        let chunk = |k: usize| {
            let mut s = [0.0; 3];
            for p in k * LOCATE_CHUNK..parts.len().min((k + 1) * LOCATE_CHUNK) {
                let exact = (b.exact_of(&parts.x0, p).0, bv.exact(&parts.x0[p]).1);
                add_errors(&mut s, (parts, vol0), p, exact);
            }
            s
        };
        let s = tree_sum(0, parts.len().div_ceil(LOCATE_CHUNK), &chunk);
        Some(self.error_norms(s))
    }

    /// The L2 norms of [`Solver::errors`] from this rank's sums (`add_errors`), over
    /// all ranks.
    pub(super) fn error_norms(&self, mut s: [f64; 3]) -> (f64, f64) {
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
        let (at, bv) = (b.at(self.t), b.at(self.velocity_time()));
        let (parts, vol0) = (&self.parts, &self.kinds.vol0[..]);
        let n = parts.len();
        let chunks = n.div_ceil(LOCATE_CHUNK);
        self.scratch.error_sums.resize(chunks, [0.0; 3]);
        // Each chunk's sums as `errors` forms them, then the same tree.
        self.scratch
            .memo
            .entries_for(n)
            .par_chunks_mut(LOCATE_CHUNK)
            .zip(self.scratch.error_sums.par_iter_mut())
            .enumerate()
            .for_each(|(k, (memo, sums))| {
                let mut s = [0.0; 3];
                let first = k * LOCATE_CHUNK;
                let x0 = &parts.x0[first..first + memo.len()];
                at.exact_keeping_forces(x0, memo, |i, out| {
                    // The sums in registers over the batch (the closure's `s` is
                    // kept in memory: each particle's adds waited on the last's).
                    let mut acc = s;
                    for (k, &(u, _)) in out.iter().enumerate() {
                        let p = first + i + k;
                        let exact = (u, bv.exact(&parts.x0[p]).1);
                        add_errors(&mut acc, (parts, vol0), p, exact);
                    }
                    s = acc;
                });
                *sums = s;
            });
        let sums = &self.scratch.error_sums;
        let s = tree_sum(0, chunks, &|k| sums[k]);
        Some(self.error_norms(s))
    }
}

/// [`Solver::fingerprint`] of the particles `p`.
pub fn fingerprint<const D: usize>(p: &Particles<D>) -> u64 {
    use decomposition::splitmix::mix;
    const ODD: [u64; 6] = [
        0x9e37_79b9_7f4a_7c15,
        0xbf58_476d_1ce4_e5b9,
        0x94d0_49bb_1331_11eb,
        0xd6e8_feb8_6659_fd93,
        0xa076_1d64_78bd_642f,
        0xe703_7ed1_a0b4_28db,
    ];
    (0..p.len())
        .into_par_iter()
        .with_min_len(4096)
        .map(|i| {
            // Each value's bits multiplied by its own odd constant: a change in
            // one value changes the sum, and one mix spreads it.
            let mut h = p.id[i];
            for a in 0..D {
                h = h.wrapping_add(p.x[i][a].to_bits().wrapping_mul(ODD[2 * a]));
                h = h.wrapping_add(p.v[i][a].to_bits().wrapping_mul(ODD[2 * a + 1]));
            }
            mix(h)
        })
        .reduce(|| 0, u64::wrapping_add)
        .wrapping_add(mix(p.len() as u64))
}

#[cfg(test)]
mod fingerprint_tests {
    use super::*;
    use crate::input::scene;
    use decomposition::{Layout, LocalComm};

    /// The fingerprint is the same on 1 and 3 threads and with the particles in
    /// another order, and changes when one bit of one position or velocity does.
    #[test]
    fn fingerprint_sees_every_bit_and_not_the_order() {
        // More particles than one thread's share (4096), so that 3 threads split them.
        let text = super::super::setup::sparse_tests::text(2, 1.0, 256, "mpmcg");
        let sc = scene::parse(&text, "sparse").unwrap();
        LocalComm::run(1, |comm| {
            let layout = Layout::choose([256; 2], [false; 2], 1).unwrap();
            let mut s = Solver::<2>::new(&sc, comm, layout);
            s.advance().unwrap();
            let on = |threads: usize, s: &Solver<2>| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let parts = &s.parts;
                pool.install(|| fingerprint(parts))
            };
            let h = on(1, &s);
            assert_eq!(on(3, &s), h, "thread count");
            let n = s.parts.len();
            assert!(n > 3 * 4096, "{n} particles");
            let last = n - 1;
            s.parts.x.swap(0, last);
            s.parts.v.swap(0, last);
            s.parts.id.swap(0, last);
            assert_eq!(on(2, &s), h, "order");
            for (field, a) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                let bits = |s: &mut Solver<2>| {
                    let w = if field == 0 {
                        &mut s.parts.x[7][a]
                    } else {
                        &mut s.parts.v[7][a]
                    };
                    *w = f64::from_bits(w.to_bits() ^ 1);
                };
                bits(&mut s);
                assert_ne!(on(1, &s), h, "last bit of field {field}, axis {a}");
                bits(&mut s);
                assert_eq!(on(1, &s), h);
            }
        });
    }
}
