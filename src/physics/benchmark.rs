//! Problems with exact solutions (the scene's `[benchmark]` table): initial state, body
//! force and exact displacement/velocity of each particle from its reference position.
//! The formulas are at each kind below; sources: the vibrating bar of Bardenhagen &
//! Kober (2004), the axis-aligned manufactured solution of Steffen, Kirby & Berzins
//! (2008, Uintah's `AA` problem), the generalized vortex of Kamojjala, Brannon,
//! Sadeghirad & Guilkey and of Wang, Coombs, Augarde et al. (2019). The README
//! ("Scenes in `inputs/`", "Verification") says what each is checked against.

use crate::input::plan::BenchmarkPlan;
use crate::input::scene::Scene;
use crate::physics::material::{lame, Material};
use crate::physics::tensor::{Mat, Vector};
use rayon::prelude::*;
use std::f64::consts::{FRAC_PI_4, PI};

#[derive(Clone, Debug)]
pub enum Benchmark<const D: usize> {
    /// `v_x = v0 cos(ωt) sin(β (X − x0))`, fixed at `x0`, free at `x0 + L`.
    VibratingBar {
        v0: f64,
        beta: f64,
        omega: f64,
        x0: f64,
    },
    /// `u_i = A sin(π X_i) sin(cπt + φ_i)` on the unit cube, neo-Hookean.
    AxisAlignedMms {
        a: f64,
        c: f64,
        mu: f64,
        lambda: f64,
        rho0: f64,
    },
    /// Rotation of circles by `α(R,t) = A sin(cπt) h(R)` in the ring 0.75 <= R <= 1.25,
    /// `h = 1 − 32(R−1)² + 256(R−1)⁴`. The body force is the Lagrangian one, `b(X, t)`
    /// at the particle's reference position, as in Uintah's MMS (Kamojjala et al.).
    ///
    /// The published amplitude A = 1 (E = 1000, ρ = 1000) shears the ring to
    /// `R α_R ≈ 7.1` with hoop stress ≈ 50 μ while material streams through the grid at
    /// up to π, five times the shear wave speed; it was run with CPDI and total-
    /// Lagrangian MPM. Our point-particle FLIP schemes (mpm, gimp, mpmcg) do not track
    /// it at any resolution (displacement error ≈ 1); they converge for A ≲ 0.1, the
    /// amplitude of `inputs/generalized_vortex.toml` (numbers there).
    GeneralizedVortex {
        a: f64,
        c: f64,
        mu: f64,
        rho0: f64,
        center: [f64; 2],
    },
}

const PHASE: [f64; 3] = [0.0, 2.0 * PI / 3.0, 4.0 * PI / 3.0];

impl<const D: usize> Benchmark<D> {
    pub fn new(s: &Scene) -> Option<Self> {
        let m = &s.plan.materials[0];
        let (lambda, mu) = lame(m.youngs_modulus, m.poisson_ratio);
        Some(match s.plan.benchmark? {
            BenchmarkPlan::VibratingBar {
                amplitude,
                mode,
                bar: [lo, hi],
            } => {
                let beta = (2.0 * mode as f64 - 1.0) * PI / (2.0 * (hi - lo));
                let speed = Material::from_plan(m).wave_speed(1.0);
                Benchmark::VibratingBar {
                    v0: amplitude,
                    beta,
                    omega: beta * speed,
                    x0: lo,
                }
            }
            BenchmarkPlan::AxisAlignedMms { amplitude, c } => Benchmark::AxisAlignedMms {
                a: amplitude,
                c,
                mu,
                lambda,
                rho0: m.density,
            },
            BenchmarkPlan::GeneralizedVortex {
                amplitude,
                c,
                center,
            } => Benchmark::GeneralizedVortex {
                a: amplitude,
                c,
                mu,
                rho0: m.density,
                center,
            },
        })
    }

    /// Whether the problem drives the material with a body force.
    pub fn has_body_force(&self) -> bool {
        !matches!(self, Benchmark::VibratingBar { .. })
    }

    /// Exact displacement and velocity at reference position `x0`, time `t`.
    pub fn exact(&self, x0: &Vector<D>, t: f64) -> (Vector<D>, Vector<D>) {
        self.at(t).exact(x0)
    }

    /// The problem at time `t`, its factors that depend on time alone computed once
    /// (for a pass over the particles: they are sines and cosines).
    pub fn at(&self, t: f64) -> At<'_, D> {
        let mut sin = [0.0; 3];
        let mut cos = [0.0; 3];
        let mut phase = |i: usize, w: f64| (sin[i], cos[i]) = w.sin_cos();
        match *self {
            Benchmark::VibratingBar { omega, .. } => phase(0, omega * t),
            Benchmark::AxisAlignedMms { c, .. } => {
                for (i, ph) in PHASE.iter().enumerate().take(D) {
                    phase(i, c * PI * t + ph);
                }
            }
            Benchmark::GeneralizedVortex { c, .. } => phase(0, c * PI * t),
        }
        At {
            b: self,
            t,
            sin,
            cos,
            memo: &[],
        }
    }

    /// What the exact solution and the body force need of a reference position alone:
    /// sin(πX_i) and cos(πX_i) per axis (axis-aligned MMS), sin(β(X − x0)) (vibrating
    /// bar), R, sin Θ, h(R) with its derivatives and cos Θ (vortex). They are transcendental
    /// functions of a position that never changes, so a run forms them once per
    /// particle ([`Memo`]) instead of once or twice a step.
    pub fn factors(&self, x0: &Vector<D>) -> Factors {
        let mut f = [0.0; 6];
        match *self {
            Benchmark::VibratingBar { beta, x0: o, .. } => f[0] = (beta * (x0[0] - o)).sin(),
            Benchmark::AxisAlignedMms { .. } => {
                for i in 0..D {
                    (f[i], f[3 + i]) = (PI * x0[i]).sin_cos();
                }
            }
            Benchmark::GeneralizedVortex { center, .. } => {
                let dx = x0[0] - center[0];
                let dy = x0[1] - center[1];
                let r = dx.hypot(dy);
                let q = r - 1.0;
                // sin Θ and cos Θ as the ratios they are, with no atan2 and sin_cos
                // (the averaged force forms four of these a particle and step); at the
                // centre, Θ = 0 as atan2 has it.
                let (st, ct) = if r > 0.0 {
                    (dy / r, dx / r)
                } else {
                    (0.0, 1.0)
                };
                f = [
                    r,
                    st,
                    1.0 - 32.0 * q * q + 256.0 * q.powi(4),
                    -64.0 * q + 1024.0 * q.powi(3),
                    -64.0 + 3072.0 * q * q,
                    ct,
                ];
            }
        }
        Factors(f)
    }

    /// Exact deformation gradient at `x0`, time `t` (the initial state uses it).
    pub fn deformation_gradient(&self, x0: &Vector<D>, t: f64) -> Mat<D> {
        let mut f = Mat::<D>::identity();
        match *self {
            Benchmark::VibratingBar {
                v0,
                beta,
                omega,
                x0: o,
            } => {
                f[(0, 0)] += v0 / omega * (omega * t).sin() * beta * (beta * (x0[0] - o)).cos();
            }
            Benchmark::AxisAlignedMms { a, c, .. } => {
                for i in 0..D {
                    f[(i, i)] += a * PI * (PI * x0[i]).cos() * (c * PI * t + PHASE[i]).sin();
                }
            }
            Benchmark::GeneralizedVortex { .. } => {
                // F = Q(α) (I + R α_R (e_θ ⊗ e_R)) in the reference polar frame.
                let (r, st, ct, al, _, _, al_r, _) = self.at(t).vortex_terms(&self.factors(x0).0);
                let (c, s) = (al.cos(), al.sin());
                let er = [ct, st];
                let et = [-st, ct];
                let mut g = [[0.0; 2]; 2];
                for i in 0..2 {
                    for j in 0..2 {
                        g[i][j] = f64::from(u8::from(i == j)) + r * al_r * et[i] * er[j];
                    }
                }
                let q = [[c, -s], [s, c]];
                for i in 0..2 {
                    for j in 0..2 {
                        f[(i, j)] = q[i][0] * g[0][j] + q[i][1] * g[1][j];
                    }
                }
            }
        }
        f
    }

    /// Body force per unit mass at reference position `x0`, time `t`.
    pub fn body_force(&self, x0: &Vector<D>, t: f64) -> Vector<D> {
        self.at(t).body_force(x0)
    }
}

/// [`Benchmark::factors`] of one reference position.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Factors([f64; 6]);

/// The factors of each particle with the reference position they were formed from:
/// an entry whose position is not the particle's (bit for bit) is not used, so the
/// memo needs no upkeep when particles are sorted, leave or arrive, and results are
/// the same with or without it ([`Memo::refresh`]).
#[derive(Clone, Debug, Default)]
pub struct Memo<const D: usize>(Vec<MemoEntry<D>>);

/// One particle's [`Memo`] entry: the reference position it was made for, its
/// factors, and for the vortex a time (NaN: none) with the body force at that time,
/// kept by [`At::exact_keeping_force`].
pub(crate) type MemoEntry<const D: usize> = (Vector<D>, Factors, f64, Vector<D>);

/// An entry made for reference position `x0`, nothing kept.
fn fresh<const D: usize>(b: &Benchmark<D>, x0: &Vector<D>) -> MemoEntry<D> {
    (*x0, b.factors(x0), f64::NAN, Vector::zeros())
}

impl<const D: usize> Memo<D> {
    /// The entries, one per particle where [`Memo::refresh`] made them: a sort moves
    /// them with their particles (an entry is a function of its reference position,
    /// so moved it is what `refresh` would form again).
    pub(crate) fn entries_mut(&mut self) -> &mut [MemoEntry<D>] {
        &mut self.0
    }

    /// `n` entries, those added made for no position (formed where first used).
    pub(crate) fn entries_for(&mut self, n: usize) -> &mut [MemoEntry<D>] {
        if self.0.capacity() < n {
            // As the particle arrays grow (`particles::reserve`): not to twice the count.
            self.0.reserve_exact(n + n / 16 - self.0.len());
        }
        self.0.resize(
            n,
            (
                Vector::from_element(f64::NAN),
                Factors::default(),
                f64::NAN,
                Vector::zeros(),
            ),
        );
        &mut self.0
    }

    /// Make the memo hold the factors of every particle of reference positions `x0`,
    /// forming only those whose entry was made for another position.
    pub fn refresh(&mut self, b: &Benchmark<D>, x0: &[Vector<D>]) {
        const CHUNK: usize = 4096;
        self.entries_for(x0.len())
            .par_chunks_mut(CHUNK)
            .zip(x0.par_chunks(CHUNK))
            .for_each(|(m, x0)| {
                for (m, x) in m.iter_mut().zip(x0) {
                    if !same(&m.0, x) {
                        *m = fresh(b, x);
                    }
                }
            });
    }
}

/// The same position bit for bit (`==` would take −0 for +0, whose sines differ).
fn same<const D: usize>(a: &Vector<D>, b: &Vector<D>) -> bool {
    a.iter()
        .zip(b.iter())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

/// A [`Benchmark`] at one time ([`Benchmark::at`]).
#[derive(Clone, Copy, Debug)]
pub struct At<'a, const D: usize> {
    b: &'a Benchmark<D>,
    /// The time.
    t: f64,
    /// Sine and cosine of the phase per axis: `cπt + φ_i` (axis-aligned MMS), `ωt`
    /// (vibrating bar, first entry), `cπt` (vortex, first entry).
    sin: [f64; 3],
    cos: [f64; 3],
    /// The particles' factors, where kept ([`At::with_memo`]).
    memo: &'a [MemoEntry<D>],
}

impl<'a, const D: usize> At<'a, D> {
    /// The same, reading the factors of particle `p` from `memo` where it holds them.
    pub fn with_memo(self, memo: &'a Memo<D>) -> Self {
        At {
            memo: &memo.0,
            ..self
        }
    }

    /// The factors of particle `p`, whose reference position is `x0[p]`, and the
    /// body force at this time where the memo keeps it.
    #[inline(always)]
    fn factors_of(&self, x0: &[Vector<D>], p: usize) -> (Factors, Option<Vector<D>>) {
        match self.memo.get(p) {
            Some((x, f, t, force)) if same(x, &x0[p]) => {
                let kept = t.to_bits() == self.t.to_bits();
                (*f, kept.then_some(*force))
            }
            _ => (self.b.factors(&x0[p]), None),
        }
    }

    /// Exact displacement and velocity of particle `p`, reference position `x0[p]`.
    pub fn exact_of(&self, x0: &[Vector<D>], p: usize) -> (Vector<D>, Vector<D>) {
        let (f, _) = self.factors_of(x0, p);
        self.exact_with(&x0[p], &f, None)
    }

    /// Body force per unit mass on particle `p`, reference position `x0[p]`.
    #[inline]
    pub fn body_force_of(&self, x0: &[Vector<D>], p: usize) -> Vector<D> {
        match self.factors_of(x0, p) {
            (_, Some(kept)) => kept,
            (f, None) => self.body_force_with(&f, None),
        }
    }

    /// [`At::exact`] of the particle at reference position `x0` whose memo entry is
    /// `e` (made for `x0` first if it was not). For the vortex it also keeps in `e`
    /// the body force at this time, which shares the exact solution's terms and
    /// current polar angle: the error norms after a step and the next step's body
    /// force are at the same time, and one pass forms both (the same numbers as
    /// [`At::exact`] and [`At::body_force`]).
    // Always: out of line, its result came back through memory, and the loads that
    // read it waited on the stores (store forwarding failed): the MMS's error pass
    // took 2.4× its share of the step.
    #[inline(always)]
    pub(crate) fn exact_keeping_force(
        &self,
        x0: &Vector<D>,
        e: &mut MemoEntry<D>,
    ) -> (Vector<D>, Vector<D>) {
        if !same(&e.0, x0) {
            *e = fresh(self.b, x0);
        }
        if !matches!(self.b, Benchmark::GeneralizedVortex { .. }) {
            return self.exact_with(x0, &e.1, None);
        }
        // All inlined: the compiler forms the terms once for the three.
        let (s, c) = self.vortex_angle(&e.1 .0);
        (e.2, e.3) = (self.t, self.vortex_force(&e.1 .0, Some([s, c])));
        self.exact_with(x0, &e.1, Some([s, c]))
    }

    /// [`At::exact_keeping_force`] of particles `k = 0 ..` at reference positions
    /// `x0[k]` with memo entries `e[k]`, handed to `each(first, out)` in that order,
    /// up to eight at a time: `out[i]` is `(u, v)` of particle `first + i`.
    ///
    /// A batch at a time, not a particle at a time: called per particle and not
    /// inlined, the caller's closure loaded each `(u, v)` right after this stored it
    /// (store forwarding failed) and its sums went through memory, a particle after
    /// the other: that closure was 7 % of the vortex's step.
    ///
    /// The vortex's terms, angle, force and motion are pure arithmetic, but a particle
    /// at a time they are a chain (the angle's series, then the force) that left the
    /// core waiting: the error pass was a seventh of the vortex's step. Here eight
    /// particles go through each stage together, lane by lane, by the same
    /// expressions as the functions `exact_keeping_force` inlines, so the numbers are
    /// the same to the bit; only the rare angle beyond ±π/4 takes libm's call.
    #[inline]
    pub(crate) fn exact_keeping_forces(
        &self,
        x0: &[Vector<D>],
        e: &mut [MemoEntry<D>],
        mut each: impl FnMut(usize, &[(Vector<D>, Vector<D>)]),
    ) {
        const N: usize = 8;
        let mut out = [(Vector::<D>::zeros(), Vector::<D>::zeros()); N];
        let Benchmark::GeneralizedVortex {
            mu, rho0, center, ..
        } = *self.b
        else {
            for (b, (x0, e)) in x0.chunks(N).zip(e.chunks_mut(N)).enumerate() {
                for (o, (x, e)) in out.iter_mut().zip(x0.iter().zip(e)) {
                    *o = self.exact_keeping_force(x, e);
                }
                each(b * N, &out[..x0.len()]);
            }
            return;
        };
        let g = mu / rho0;
        let mut x_batches = x0.chunks_exact(N);
        let mut e_batches = e.chunks_exact_mut(N);
        for (b, (x0, e)) in (&mut x_batches).zip(&mut e_batches).enumerate() {
            for (x, e) in x0.iter().zip(e.iter_mut()) {
                if !same(&e.0, x) {
                    *e = fresh(self.b, x);
                }
            }
            // Each term in an array of its own, so that every loop below is whole
            // vector operations (arrays of tuples left the series half scalar).
            let [mut r, mut st, mut ct, mut al, mut al_t, mut al_tt, mut al_r, mut al_rr] =
                [[0.0; N]; 8];
            for k in 0..N {
                (
                    r[k], st[k], ct[k], al[k], al_t[k], al_tt[k], al_r[k], al_rr[k],
                ) = self.vortex_terms(&e[k].1 .0);
            }
            // `rotated`, with the series in every lane and libm's call where it is due.
            let (mut sa, mut ca) = ([0.0; N], [0.0; N]);
            for k in 0..N {
                (sa[k], ca[k]) = small_sin_cos(al[k]);
            }
            for k in 0..N {
                // (NaN too, as in `rotated`.)
                if al[k].abs() <= FRAC_PI_4 {
                    continue;
                }
                (sa[k], ca[k]) = libm_sin_cos(al[k]);
            }
            let [mut f0, mut f1, mut x0s, mut x1s, mut v0, mut v1] = [[0.0; N]; 6];
            for k in 0..N {
                let angle = (st[k] * ca[k] + ct[k] * sa[k], ct[k] * ca[k] - st[k] * sa[k]);
                let terms = [r[k], al_t[k], al_tt[k], al_r[k], al_rr[k]];
                [f0[k], f1[k]] = vortex_force_of(g, terms, angle);
                ([x0s[k], x1s[k]], [v0[k], v1[k]]) = vortex_motion_of(center, r[k], al_t[k], angle);
            }
            for k in 0..N {
                let mut f = Vector::<D>::zeros();
                (f[0], f[1]) = (f0[k], f1[k]);
                (e[k].2, e[k].3) = (self.t, f);
                // `exact_with`.
                let mut x = Vector::<D>::zeros();
                (x[0], x[1]) = (x0s[k], x1s[k]);
                let (u, v) = &mut out[k];
                *u = x - x0[k];
                (v[0], v[1]) = (v0[k], v1[k]);
            }
            each(b * N, &out);
        }
        let rest = x_batches.remainder();
        for (o, (x, e)) in out
            .iter_mut()
            .zip(rest.iter().zip(e_batches.into_remainder()))
        {
            *o = self.exact_keeping_force(x, e);
        }
        each(x0.len() - rest.len(), &out[..rest.len()]);
    }

    /// Exact displacement and velocity at reference position `x0`.
    pub fn exact(&self, x0: &Vector<D>) -> (Vector<D>, Vector<D>) {
        self.exact_with(x0, &self.b.factors(x0), None)
    }

    /// Body force per unit mass at reference position `x0`.
    pub fn body_force(&self, x0: &Vector<D>) -> Vector<D> {
        self.body_force_with(&self.b.factors(x0), None)
    }

    /// [`At::exact`] from the position's [`Factors`] (and the vortex angle's sine and
    /// cosine, if known).
    #[inline(always)]
    fn exact_with(
        &self,
        x0: &Vector<D>,
        f: &Factors,
        angle: Option<[f64; 2]>,
    ) -> (Vector<D>, Vector<D>) {
        let f = &f.0;
        let mut u = Vector::<D>::zeros();
        let mut v = Vector::<D>::zeros();
        match *self.b {
            Benchmark::VibratingBar { v0, omega, .. } => {
                let s = f[0];
                u[0] = v0 / omega * self.sin[0] * s;
                v[0] = v0 * self.cos[0] * s;
            }
            Benchmark::AxisAlignedMms { a, c, .. } => {
                for i in 0..D {
                    let s = f[i];
                    u[i] = a * s * self.sin[i];
                    v[i] = a * s * c * PI * self.cos[i];
                }
            }
            Benchmark::GeneralizedVortex { .. } => {
                let (x, vel) = self.vortex_motion(f, angle);
                u = x - x0;
                v = vel;
            }
        }
        (u, v)
    }

    /// [`At::body_force`] from the position's [`Factors`] (and the vortex angle's sine
    /// and cosine, if known).
    fn body_force_with(&self, f: &Factors, angle: Option<[f64; 2]>) -> Vector<D> {
        let f = &f.0;
        let mut b = Vector::<D>::zeros();
        match *self.b {
            Benchmark::VibratingBar { .. } => {}
            Benchmark::AxisAlignedMms { .. } => {
                let (u, fii, j) = self.mms_terms(f);
                // ln J of the diagonal F, one logarithm for all axes.
                b = self.mms_force(&u, &fii, j.ln());
            }
            Benchmark::GeneralizedVortex { .. } => b = self.vortex_force(f, angle),
        }
        b
    }

    /// The vortex's body force at a reference point of factors `f` (and the sine and
    /// cosine of its current polar angle, if known).
    #[inline(always)]
    fn vortex_force(&self, f: &[f64; 6], angle: Option<[f64; 2]>) -> Vector<D> {
        let Benchmark::GeneralizedVortex { mu, rho0, .. } = *self.b else {
            unreachable!()
        };
        let (r, st, ct, al, al_t, al_tt, al_r, al_rr) = self.vortex_terms(f);
        // Of the current polar angle Θ + α.
        let angle = angle.map_or_else(|| rotated_unkept(st, ct, al), |[s, c]| (s, c));
        let mut b = Vector::<D>::zeros();
        [b[0], b[1]] = vortex_force_of(mu / rho0, [r, al_t, al_tt, al_r, al_rr], angle);
        b
    }

    /// The axis-aligned MMS's displacement `u`, the diagonal of `F` and `J` at a
    /// reference point of factors `f`: what its body force needs besides `ln J`.
    #[inline(always)]
    fn mms_terms(&self, f: &[f64; 6]) -> ([f64; D], [f64; D], f64) {
        let Benchmark::AxisAlignedMms { a, .. } = *self.b else {
            unreachable!()
        };
        let mut u = [0.0; D];
        let mut fii = [0.0; D];
        let mut j = 1.0;
        for i in 0..D {
            let (s, co) = (f[i], f[3 + i]);
            u[i] = a * s * self.sin[i];
            fii[i] = 1.0 + a * PI * co * self.sin[i];
            j *= fii[i];
        }
        (u, fii, j)
    }

    /// The axis-aligned MMS's body force from [`At::mms_terms`] and `ln J`.
    #[inline(always)]
    fn mms_force(&self, u: &[f64; D], fii: &[f64; D], lnj: f64) -> Vector<D> {
        let Benchmark::AxisAlignedMms {
            c,
            mu,
            lambda,
            rho0,
            ..
        } = *self.b
        else {
            unreachable!()
        };
        let mut b = Vector::<D>::zeros();
        for i in 0..D {
            b[i] = PI
                * PI
                * u[i]
                * (mu / rho0 - c * c - (lambda * (lnj - 1.0) - mu) / (rho0 * fii[i] * fii[i]));
        }
        b
    }

    /// Body force per unit mass averaged over the box `x0 ± half` (reference
    /// coordinates): the 2^D-point Gauss rule, at `x0 ± half/√3` per axis, exact for a
    /// force cubic in each coordinate. Its error is `O(half⁴)` where the point value's
    /// is `O(half²)`: over a particle's box it is the particle's body force per unit
    /// mass to that order (`[benchmark] body_force = "domain"`).
    pub fn body_force_over(&self, x0: &Vector<D>, half: &[f64; D]) -> Vector<D> {
        let g = 1.0 / 3f64.sqrt();
        let mut sum = Vector::<D>::zeros();
        for corner in 0..1usize << D {
            let x = Vector::<D>::from_fn(|a, _| {
                let side = if corner >> a & 1 == 0 { -g } else { g };
                x0[a] + side * half[a]
            });
            sum += self.body_force(&x);
        }
        sum / f64::from(1u32 << D)
    }

    /// `base` plus the body force per unit mass of particles `first ..` into `out`
    /// (one per entry), the same numbers as [`At::body_force_of`] of each.
    ///
    /// The axis-aligned MMS's force is a chain, memo → `J` → `ln J` → a division, that
    /// a particle at a time leaves the core waiting on (a quarter of that scene's
    /// step). In batches the logarithms are independent calls the core overlaps.
    pub fn add_body_forces(
        &self,
        base: Vector<D>,
        x0: &[Vector<D>],
        first: usize,
        out: &mut [Vector<D>],
    ) {
        if !matches!(self.b, Benchmark::AxisAlignedMms { .. }) {
            for (k, o) in out.iter_mut().enumerate() {
                *o = base + self.body_force_of(x0, first + k);
            }
            return;
        }
        const BATCH: usize = 32;
        let mut u = [[0.0; D]; BATCH];
        let mut fii = [[0.0; D]; BATCH];
        let mut lnj = [0.0; BATCH];
        for (c, out) in out.chunks_mut(BATCH).enumerate() {
            let p0 = first + c * BATCH;
            for k in 0..out.len() {
                let (f, _) = self.factors_of(x0, p0 + k);
                let j;
                (u[k], fii[k], j) = self.mms_terms(&f.0);
                lnj[k] = j;
            }
            for l in &mut lnj[..out.len()] {
                *l = l.ln();
            }
            for (k, o) in out.iter_mut().enumerate() {
                *o = base + self.mms_force(&u[k], &fii[k], lnj[k]);
            }
        }
    }

    /// (R, Θ, α, α_t, α_tt, α_R, α_RR) of the vortex at a reference point of factors
    /// `f`, with sin Θ and cos Θ after R.
    #[allow(clippy::type_complexity)]
    #[inline(always)]
    fn vortex_terms(&self, f: &[f64; 6]) -> (f64, f64, f64, f64, f64, f64, f64, f64) {
        let Benchmark::GeneralizedVortex { a, c, .. } = *self.b else {
            unreachable!()
        };
        let [r, st, h, hr, hrr, ct] = *f;
        let w = c * PI;
        let (s, co) = (self.sin[0], self.cos[0]);
        (
            r,
            st,
            ct,
            a * s * h,
            a * w * co * h,
            -a * w * w * s * h,
            a * s * hr,
            a * s * hrr,
        )
    }

    /// Sine and cosine of the vortex's current polar angle Θ + α at a reference point
    /// of factors `f`.
    #[inline(always)]
    fn vortex_angle(&self, f: &[f64; 6]) -> (f64, f64) {
        let (_, st, ct, al, ..) = self.vortex_terms(f);
        rotated(st, ct, al)
    }

    #[inline(always)]
    fn vortex_motion(&self, f: &[f64; 6], angle: Option<[f64; 2]>) -> (Vector<D>, Vector<D>) {
        let Benchmark::GeneralizedVortex { center, .. } = *self.b else {
            unreachable!()
        };
        // (Without a kept angle, from the terms at hand: `vortex_angle` would form
        // them again.)
        let (r, st, ct, al, al_t, ..) = self.vortex_terms(f);
        let angle = angle.map_or_else(|| rotated_unkept(st, ct, al), |[s, c]| (s, c));
        let mut x = Vector::<D>::zeros();
        let mut v = Vector::<D>::zeros();
        ([x[0], x[1]], [v[0], v[1]]) = vortex_motion_of(center, r, al_t, angle);
        (x, v)
    }
}

/// The vortex's body force per unit mass from its terms (R, α_t, α_tt, α_R, α_RR of
/// `At::vortex_terms`), `g = μ/ρ0` and the sine and cosine of the current polar angle.
#[inline(always)]
fn vortex_force_of(
    g: f64,
    [r, al_t, al_tt, al_r, al_rr]: [f64; 5],
    (sp, cp): (f64, f64),
) -> [f64; 2] {
    let br = -r * al_t * al_t + g * r * al_r * al_r;
    let bt = r * al_tt - g * (r * al_rr + 3.0 * al_r);
    [br * cp - bt * sp, br * sp + bt * cp]
}

/// The vortex's current position and velocity at radius `r` turning at `α_t`, from the
/// sine and cosine of the current polar angle.
#[inline(always)]
fn vortex_motion_of(
    center: [f64; 2],
    r: f64,
    al_t: f64,
    (sp, cp): (f64, f64),
) -> ([f64; 2], [f64; 2]) {
    (
        [center[0] + r * cp, center[1] + r * sp],
        [-al_t * r * sp, al_t * r * cp],
    )
}

/// Sine and cosine of Θ + α from those of Θ (a particle's reference polar angle,
/// kept) and the angle α it has turned by.
///
/// Formed once per particle and step, `(Θ + α).sin_cos()` was the vortex's costliest
/// call (8 % of its step): a general argument sends libm through its range
/// reduction. Here a small α (always, for A ≲ π/4: |α| ≤ A) takes the series of
/// [`small_sin_cos`] and the sum formulas, a few ulp from the direct call.
#[inline(always)]
fn rotated(st: f64, ct: f64, al: f64) -> (f64, f64) {
    let (sa, ca) = if al.abs() <= FRAC_PI_4 {
        small_sin_cos(al)
    } else {
        libm_sin_cos(al)
    };
    (st * ca + ct * sa, ct * ca - st * sa)
}

/// [`rotated`] where the pass has no angle kept: out of line, so that the compiler
/// does not form it on both sides of that choice (it is free of side effects).
#[cold]
#[inline(never)]
fn rotated_unkept(st: f64, ct: f64, al: f64) -> (f64, f64) {
    rotated(st, ct, al)
}

/// `x.sin_cos()` out of line, for the same reason.
#[cold]
#[inline(never)]
fn libm_sin_cos(x: f64) -> (f64, f64) {
    x.sin_cos()
}

/// sin x and cos x for |x| ≤ π/4 by their Taylor series to x¹⁷ and x¹⁶: the first
/// terms left out, x¹⁹/19! and x¹⁸/18!, are below 3e-18 there, under a fortieth of
/// an ulp of the results (sin x ≥ 0.99 x, cos x ≥ 0.7), and Horner's rule in x² adds
/// a few ulp of rounding (`small_sin_cos_matches_libm`). Pure arithmetic: the loops
/// that call it are free to vectorise.
#[inline(always)]
fn small_sin_cos(x: f64) -> (f64, f64) {
    // 1/n! for n = 2 ..= 17.
    const F: [f64; 16] = {
        let mut f = [0.0; 16];
        let mut k = 1.0;
        let mut n = 2;
        while n <= 17 {
            k *= n as f64;
            f[n - 2] = 1.0 / k;
            n += 1;
        }
        f
    };
    let x2 = x * x;
    // sin x = x (1 − x² (1/3! − x² (1/5! − ... − x²/17!))), cos x = 1 − x² (1/2! − ...
    // − x²/16!): the nesting alternates the signs.
    let mut s = F[15];
    let mut c = F[14];
    for k in (0..7).rev() {
        s = F[2 * k + 1] - x2 * s;
        c = F[2 * k] - x2 * c;
    }
    (x * (1.0 - x2 * s), 1.0 - x2 * c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The MMS body force balances the equation of motion: compute ρ0 ü − ∇·P by finite
    /// differences of the exact field and compare with ρ0 b.
    #[test]
    fn mms_body_force_satisfies_momentum_balance_2d() {
        let (lambda, mu) = lame(1e4, 0.3);
        let bm = Benchmark::<2>::AxisAlignedMms {
            a: 0.05,
            c: 100.0,
            mu,
            lambda,
            rho0: 1.0,
        };
        let piola = |x: &Vector<2>, t: f64| {
            let f = bm.deformation_gradient(x, t);
            let fit = f.try_inverse().unwrap().transpose();
            let j = crate::physics::tensor::det(&f);
            (f - fit) * mu + fit * (lambda * j.ln())
        };
        let x = Vector::<2>::new(0.3, 0.7);
        let t = 0.0071;
        let e = 1e-5;
        let et = 1e-7;
        let acc = (bm.exact(&x, t + et).1 - bm.exact(&x, t - et).1) / (2.0 * et);
        let mut div = Vector::<2>::zeros();
        for j in 0..2 {
            let mut dx = Vector::<2>::zeros();
            dx[j] = e;
            let dp = (piola(&(x + dx), t) - piola(&(x - dx), t)) / (2.0 * e);
            for i in 0..2 {
                div[i] += dp[(i, j)];
            }
        }
        let b = bm.body_force(&x, t);
        let resid = acc - div - b;
        assert!(resid.norm() < 1e-4 * b.norm().max(1.0), "residual {resid}");
    }

    /// The series agree with libm's sine and cosine over |x| ≤ π/4 to 2 ulp of the
    /// result (libm's own are within 1), and the sum formulas of `rotated` with
    /// `(Θ + α).sin_cos()` to 3 ulp of 1 (their two products and a sum round) over
    /// every Θ, α up to ±π/4 and beyond.
    #[test]
    fn small_sin_cos_matches_libm() {
        let ulps = |a: f64, b: f64| (a - b).abs() / (f64::EPSILON * b.abs().max(f64::MIN_POSITIVE));
        let mut worst: f64 = 0.0;
        let n = 100_000;
        for k in -n..=n {
            let x = FRAC_PI_4 * k as f64 / n as f64;
            let (s, c) = small_sin_cos(x);
            if x != 0.0 {
                worst = worst.max(ulps(s, x.sin()));
            } else {
                assert_eq!(s, 0.0);
            }
            worst = worst.max(ulps(c, x.cos()));
        }
        assert!(worst <= 2.0, "{worst} ulp");
        let mut worst: f64 = 0.0;
        for i in 0..400 {
            let th = -PI + 2.0 * PI * i as f64 / 400.0;
            for k in -50..=50 {
                let al = 1.2 * k as f64 / 50.0;
                let (st, ct) = th.sin_cos();
                let (s, c) = rotated(st, ct, al);
                let (se, ce) = (th + al).sin_cos();
                worst = worst.max((s - se).abs()).max((c - ce).abs());
            }
        }
        assert!(worst <= 3.0 * f64::EPSILON, "{worst}");
    }

    /// An axis-aligned MMS whose particles cross cells (A = 0.05, c = 100, E = 1e4).
    fn test_mms() -> Benchmark<2> {
        let (lambda, mu) = lame(1e4, 0.3);
        Benchmark::AxisAlignedMms {
            a: 0.05,
            c: 100.0,
            mu,
            lambda,
            rho0: 1.0,
        }
    }

    /// The vortex with the published parameters: E = 1000, ν = 0.3, ρ0 = 1000, A = c = 1.
    fn published_vortex() -> Benchmark<2> {
        let (_, mu) = lame(1000.0, 0.3);
        Benchmark::GeneralizedVortex {
            a: 1.0,
            c: 1.0,
            mu,
            rho0: 1000.0,
            center: [0.0, 0.0],
        }
    }

    /// The vortex body force balances the equation of motion in the current frame:
    /// ρ a = ∇·σ + ρ b with σ = μ (F Fᵀ − I) (J = 1), by finite differences in x.
    #[test]
    fn vortex_body_force_satisfies_momentum_balance() {
        let bm = published_vortex();
        let Benchmark::GeneralizedVortex { mu, .. } = bm else {
            unreachable!()
        };
        let x0 = Vector::<2>::new(0.6, 0.75);
        let t = 0.37;
        // Cauchy stress as a function of the current position: invert the motion.
        let cauchy = |x: &Vector<2>| {
            // Reference point of current point x: rotate back by α(R, t), R = |x|.
            let r = x.norm();
            let th = x[1].atan2(x[0]);
            let probe = Vector::<2>::new(r, 0.0);
            let (_, _, _, al, ..) = bm.at(t).vortex_terms(&bm.factors(&probe).0);
            let xr = Vector::<2>::new(r * (th - al).cos(), r * (th - al).sin());
            let f = bm.deformation_gradient(&xr, t);
            (f * f.transpose() - Mat::<2>::identity()) * mu
        };
        let (xc, _) = bm.at(t).vortex_motion(&bm.factors(&x0).0, None);
        let e = 1e-5;
        let mut div = Vector::<2>::zeros();
        for j in 0..2 {
            let mut dx = Vector::<2>::zeros();
            dx[j] = e;
            let ds = (cauchy(&(xc + dx)) - cauchy(&(xc - dx))) / (2.0 * e);
            for i in 0..2 {
                div[i] += ds[(i, j)];
            }
        }
        let et = 1e-6;
        let acc = (bm.exact(&x0, t + et).1 - bm.exact(&x0, t - et).1) / (2.0 * et);
        let b = bm.body_force(&x0, t);
        let resid = acc * 1000.0 - div - b * 1000.0;
        assert!(resid.norm() < 1e-3 * (div.norm() + 1.0), "residual {resid}");
        // J = 1 for a rigid rotation of each circle.
        assert!(
            (crate::physics::tensor::det(&bm.deformation_gradient(&x0, t)) - 1.0).abs() < 1e-12
        );
    }

    /// The vortex against an independent symbolic derivation (sympy, Cartesian and
    /// Lagrangian: x = Q(α) X, F = ∂x/∂X, P = μ(F − F⁻ᵀ) + λ ln J F⁻ᵀ,
    /// b = ẍ − Div P / ρ0 with E = 1000, ν = 0.3, ρ0 = 1000, A = c = 1), at reference
    /// points in all four quadrants and t = 0 (initial state: x = X, F = I).
    #[test]
    fn vortex_matches_symbolic_reference() {
        let bm = published_vortex();
        // (X, Y, t), b, v, x, F (row-major).
        #[allow(clippy::type_complexity)]
        let cases: [([f64; 3], [f64; 2], [f64; 2], [f64; 2], [f64; 4]); 6] = [
            (
                [0.6, 0.75, 0.37],
                [-9.115431701492868, -1.2730041015273568],
                [-1.1169886652545769, -0.2237432783372263],
                [-0.18864352092740366, 0.9417609155258633],
                [
                    -0.6889002765997091,
                    -2.4307268716260753,
                    0.4991112059390407,
                    0.3094831392114613,
                ],
            ),
            (
                [-0.9, 0.3, 0.0],
                [7.477569327913091, -2.4925231093043636],
                [-0.8647293985931721, -2.594188195779516],
                [-0.9, 0.3],
                [1.0, 0.0, 0.0, 1.0],
            ),
            (
                [0.2, -1.1, 0.81],
                [5.459813864486061, 0.8988126732370938],
                [-1.5230066622336689, -0.8705521353851198],
                [0.5548263635671639, -0.9706532368929892],
                [
                    0.37002322207806504,
                    2.818138463035588,
                    0.00545883796559371,
                    2.744108209025053,
                ],
            ),
            (
                [1.0, 0.0, 0.5],
                [-12.408146198683848, 7.967179051608533],
                [0.0, 0.0],
                [0.5403023058681398, 0.8414709848078965],
                [
                    0.5403023058681398,
                    -0.8414709848078965,
                    0.8414709848078965,
                    0.5403023058681398,
                ],
            ),
            (
                [-0.55, -0.62, 0.23],
                [-12.065573852606983, 2.1454585750355273],
                [0.47260423441366495, -0.2827559983570672],
                [-0.4255183436186778, -0.7112201763476743],
                [
                    -0.8334104466474503,
                    -2.2326084604892604,
                    1.2719428707119578,
                    2.2074962244728935,
                ],
            ),
            (
                [0.0, 0.8, 0.95],
                [3.8245327044270825, 0.10806786219745684],
                [0.32164405439681054, 0.006521875128954394],
                [-0.01621801426353307, 0.7998355931148275],
                [
                    0.9997944913935344,
                    -0.596834017048097,
                    0.020272517829416338,
                    0.9881037355699308,
                ],
            ),
        ];
        for (p, b, v, x, f) in cases {
            let x0 = Vector::<2>::new(p[0], p[1]);
            let t = p[2];
            let bb = bm.body_force(&x0, t);
            let (u, vv) = bm.exact(&x0, t);
            let ff = bm.deformation_gradient(&x0, t);
            for i in 0..2 {
                assert!((bb[i] - b[i]).abs() < 1e-9, "b at {p:?}: {bb} vs {b:?}");
                assert!((vv[i] - v[i]).abs() < 1e-12, "v at {p:?}: {vv} vs {v:?}");
                assert!((x0[i] + u[i] - x[i]).abs() < 1e-12, "x at {p:?}");
                for j in 0..2 {
                    assert!(
                        (ff[(i, j)] - f[2 * i + j]).abs() < 1e-12,
                        "F at {p:?}: {ff}"
                    );
                }
            }
        }
    }

    /// The domain average of the body force: against a 200 × 200 midpoint rule over
    /// the box, for the vortex near the ring's outer edge (where `h''` is largest) and
    /// the 2D manufactured solution, its error is fourth order in the box's size
    /// (halving the box divides it by 12 or more) and far below the point value's,
    /// which is second order (divided by about 4).
    #[test]
    fn body_force_over_a_box_is_fourth_order() {
        let midpoint = |at: &At<'_, 2>, x0: &Vector<2>, half: f64| {
            let n = 200;
            let mut sum = Vector::<2>::zeros();
            for i in 0..n {
                for j in 0..n {
                    let s = |k: usize| (2.0 * (k as f64 + 0.5) / n as f64 - 1.0) * half;
                    sum += at.body_force(&Vector::<2>::new(x0[0] + s(i), x0[1] + s(j)));
                }
            }
            sum / (n * n) as f64
        };
        let mms = test_mms();
        let vortex = published_vortex();
        for (b, x0) in [
            (&vortex, Vector::<2>::new(0.83, 0.83)),
            (&mms, Vector::<2>::new(0.31, 0.62)),
        ] {
            let at = b.at(0.37);
            let errs = |half: f64| {
                let want = midpoint(&at, &x0, half);
                (
                    (at.body_force_over(&x0, &[half; 2]) - want).norm(),
                    (at.body_force(&x0) - want).norm(),
                )
            };
            let (g1, p1) = errs(0.04);
            let (g2, p2) = errs(0.02);
            assert!(g1 / g2 > 12.0, "Gauss {g1:e} -> {g2:e}");
            assert!((3.5..4.5).contains(&(p1 / p2)), "point {p1:e} -> {p2:e}");
            assert!(g1 < 0.05 * p1, "Gauss {g1:e} against point {p1:e}");
        }
    }

    /// The memo changes no bit: with entries that are current, stale (particles
    /// reordered since the refresh, as a sort by cell leaves them), missing
    /// (arrivals) or made for −0 where the particle sits at +0 (whose sines differ in
    /// sign), and with the vortex angle kept for this time or another,
    /// `exact_of`, `body_force_of` and `add_body_forces` equal the exact solution and
    /// body force formed from the position itself, for each kind of benchmark.
    #[test]
    fn memo_changes_no_bit() {
        let mms = test_mms();
        let bar = Benchmark::<2>::VibratingBar {
            v0: 0.1,
            beta: 1.3,
            omega: 2.0,
            x0: 0.0,
        };
        let mut x0: Vec<Vector<2>> = (0..37)
            .map(|k| {
                let s = k as f64 / 37.0;
                Vector::<2>::new(0.9 * s + 0.05, (7.0 * s).fract() * 0.8 + 0.1)
            })
            .collect();
        x0[3] = Vector::<2>::new(-0.0, 0.5);
        for b in [mms, bar, published_vortex()] {
            let t = 0.0123;
            let check = |memo: &Memo<2>, x0: &[Vector<2>]| {
                let at = b.at(t).with_memo(memo);
                for p in 0..x0.len() {
                    let (u, v) = at.exact_of(x0, p);
                    let (ue, ve) = b.exact(&x0[p], t);
                    let f = at.body_force_of(x0, p);
                    let fe = b.body_force(&x0[p], t);
                    for (x, y) in [(u, ue), (v, ve), (f, fe)] {
                        assert!(same(&x, &y), "{b:?} particle {p}: {x:?} vs {y:?}");
                    }
                }
                // In batches (of 32: 37 particles make a full and a partial one),
                // from particle 1 on, onto a base.
                let base = Vector::<2>::new(0.5, -9.81);
                let mut out = vec![Vector::<2>::zeros(); x0.len().saturating_sub(1)];
                at.add_body_forces(base, x0, 1, &mut out);
                for (k, f) in out.iter().enumerate() {
                    let fe = base + b.body_force(&x0[k + 1], t);
                    assert!(same(f, &fe), "{b:?} batch, particle {}", k + 1);
                }
            };
            let mut memo = Memo::default();
            check(&memo, &x0);
            memo.refresh(&b, &x0);
            check(&memo, &x0);
            let mut moved = x0.clone();
            moved.reverse();
            moved[3] = Vector::<2>::new(0.0, 0.5);
            moved.push(Vector::<2>::new(0.31, 0.77));
            check(&memo, &moved);
            memo.refresh(&b, &moved);
            check(&memo, &moved);
            moved.truncate(5);
            memo.refresh(&b, &moved);
            check(&memo, &moved);
            // The vortex's body force kept for this time, for another time (not to be
            // used), and with the particles reordered since; the exact solution the
            // keeping pass gives is the one formed from the position, and the kept
            // force is the body force.
            let keep = |memo: &mut Memo<2>, x0: &[Vector<2>], t: f64| {
                let at = b.at(t);
                for (x, e) in x0.iter().zip(memo.entries_for(x0.len())) {
                    let (u, v) = at.exact_keeping_force(x, e);
                    let (ue, ve) = b.exact(x, t);
                    assert!(same(&u, &ue) && same(&v, &ve), "{b:?} keeping, {x:?}");
                    if matches!(b, Benchmark::GeneralizedVortex { .. }) {
                        assert_eq!(e.2.to_bits(), t.to_bits());
                        assert!(same(&e.3, &b.body_force(x, t)), "kept force at {x:?}");
                    }
                }
            };
            keep(&mut memo, &moved, t);
            check(&memo, &moved);
            keep(&mut memo, &moved, 0.5 * t);
            check(&memo, &moved);
            keep(&mut memo, &moved, t);
            moved.reverse();
            check(&memo, &moved);
            // Entries made for other positions are formed again by the keeping pass.
            moved.push(Vector::<2>::new(0.2, 0.4));
            keep(&mut memo, &moved, t);
            check(&memo, &moved);
        }
    }

    /// `exact_keeping_forces` (eight particles at a time) hands out, in particle order,
    /// what `exact_keeping_force` gives one at a time, and leaves the memo the same to
    /// the bit: for full batches and a partial one, entries made for these positions
    /// or for others, angles within ±π/4 (the series) and beyond (libm), and each
    /// kind of benchmark.
    #[test]
    fn batched_keeping_is_the_one_at_a_time() {
        // A spiral over the ring and a little beyond; 8 · 5 + 3 particles.
        let x0: Vec<Vector<2>> = (0..43)
            .map(|k| {
                let (r, a) = (0.7 + 0.6 * k as f64 / 42.0, 2.39996 * k as f64);
                Vector::<2>::new(r * a.cos(), r * a.sin())
            })
            .collect();
        let mms = test_mms();
        let bits = |v: &Vector<2>| v.map(f64::to_bits);
        let (mut series, mut libm) = (0, 0);
        for b in [published_vortex(), mms] {
            // At t = 0.5 the published vortex turns by α = h(R), beyond π/4 near R = 1.
            for t in [0.0123, 0.5] {
                let at = b.at(t);
                let mut memo = Memo::default();
                // Every third entry made for another position.
                memo.refresh(&b, &x0.iter().map(|x| x * 1.5).collect::<Vec<_>>());
                memo.refresh(
                    &b,
                    &x0.iter()
                        .enumerate()
                        .map(|(k, x)| if k % 3 == 0 { x * 1.5 } else { *x })
                        .collect::<Vec<_>>(),
                );
                let mut one = memo.clone();
                let mut batched = memo;
                let want: Vec<_> = x0
                    .iter()
                    .zip(one.entries_mut())
                    .map(|(x, e)| at.exact_keeping_force(x, e))
                    .collect();
                let mut got = Vec::new();
                at.exact_keeping_forces(&x0, batched.entries_mut(), |first, uv| {
                    got.extend(uv.iter().enumerate().map(|(i, uv)| (first + i, *uv)))
                });
                assert_eq!(got.len(), x0.len());
                for (k, ((i, (u, v)), (uw, vw))) in got.iter().zip(&want).enumerate() {
                    assert_eq!(*i, k, "{b:?} t = {t}: order");
                    assert!(
                        bits(u) == bits(uw) && bits(v) == bits(vw),
                        "{b:?} t = {t}, {k}"
                    );
                }
                for (k, (m, o)) in batched.0.iter().zip(&one.0).enumerate() {
                    assert!(
                        bits(&m.0) == bits(&o.0) && bits(&m.3) == bits(&o.3),
                        "entry {k}"
                    );
                    assert_eq!(m.2.to_bits(), o.2.to_bits(), "entry {k}");
                    assert_eq!(
                        m.1 .0.map(f64::to_bits),
                        o.1 .0.map(f64::to_bits),
                        "entry {k}"
                    );
                }
                if let Benchmark::GeneralizedVortex { .. } = b {
                    for e in &one.0 {
                        let (_, _, _, al, ..) = at.vortex_terms(&e.1 .0);
                        *if al.abs() <= FRAC_PI_4 {
                            &mut series
                        } else {
                            &mut libm
                        } += 1;
                    }
                }
            }
        }
        assert!(
            series > 0 && libm > 0,
            "angles {series} within π/4, {libm} beyond"
        );
    }

    /// A sort moves the memo's entries with their particles (`Solver::sort`): moved,
    /// they are bit for bit the entries `refresh` forms for the reordered particles.
    #[test]
    fn moved_memo_is_the_refreshed_one() {
        let b = published_vortex();
        let x0: Vec<Vector<2>> = (0..40)
            .map(|k| {
                let a = 0.37 * k as f64;
                Vector::<2>::new((0.8 + 0.01 * k as f64) * a.cos(), 0.9 * a.sin())
            })
            .collect();
        // New position k holds old particle perm[k]: cycles of several lengths.
        let perm: Vec<u32> = (0..40u32).map(|k| (k * 7 + 3) % 40).collect();
        let sorted: Vec<Vector<2>> = perm.iter().map(|&p| x0[p as usize]).collect();
        let mut moved = Memo::default();
        moved.refresh(&b, &x0);
        let at = b.at(0.25);
        for (x, e) in x0.iter().zip(moved.entries_mut()) {
            at.exact_keeping_force(x, e);
        }
        // As the sort moves it: with particles' arrays (here none).
        let mut parts = crate::mpm::particles::Particles::<2>::default();
        parts.permute_with(&perm, &mut Vec::new(), moved.entries_mut());
        let mut formed = Memo::default();
        formed.refresh(&b, &sorted);
        for (x, e) in sorted.iter().zip(formed.entries_mut()) {
            at.exact_keeping_force(x, e);
        }
        assert_eq!(moved.0.len(), formed.0.len());
        for (k, (m, f)) in moved.0.iter().zip(&formed.0).enumerate() {
            assert!(same(&m.0, &f.0) && same(&m.3, &f.3), "position {k}");
            assert_eq!(m.2.to_bits(), f.2.to_bits(), "entry {k}");
            for (x, y) in m.1 .0.iter().zip(f.1 .0.iter()) {
                assert_eq!(x.to_bits(), y.to_bits(), "entry {k}");
            }
        }
    }
}
