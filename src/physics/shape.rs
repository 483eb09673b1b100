//! Grid geometry, shape functions and the closed-form grid integrals the gradient
//! schemes are built from.
//!
//! Nodes are addressed by global (unwrapped) index; a node on a bounded axis is an *end
//! node* if it lies on the grid boundary, where the integrals over the grid domain are
//! halved. On a periodic axis there are no end nodes.

use crate::input::scene::{Gradient, Quadrature};

/// `floor` as an integer without a libm call (x86-64's baseline has no SSE4.1 round):
/// truncate, then step down for negative non-integers.
#[inline(always)]
pub fn floor_i64(s: f64) -> i64 {
    let i = s as i64;
    if (i as f64) > s {
        i - 1
    } else {
        i
    }
}

/// Most nodes a particle touches: 3 per axis (GIMP) in 3D.
pub const MAX_NODES: usize = 27;

/// The uniform tensor grid, global.
#[derive(Clone, Debug)]
pub struct Geom<const D: usize> {
    pub lower: [f64; D],
    pub upper: [f64; D],
    pub h: [f64; D],
    pub inv_h: [f64; D],
    pub cells: [usize; D],
    pub periodic: [bool; D],
}

impl<const D: usize> Geom<D> {
    pub fn new(lower: [f64; D], upper: [f64; D], cells: [usize; D], periodic: [bool; D]) -> Self {
        let mut h = [0.0; D];
        let mut inv_h = [0.0; D];
        for a in 0..D {
            h[a] = (upper[a] - lower[a]) / cells[a] as f64;
            inv_h[a] = 1.0 / h[a];
        }
        Self {
            lower,
            upper,
            h,
            inv_h,
            cells,
            periodic,
        }
    }

    pub fn min_h(&self) -> f64 {
        self.h.iter().cloned().fold(f64::INFINITY, f64::min)
    }

    pub fn cell_volume(&self) -> f64 {
        self.h.iter().product()
    }

    /// Cell containing `x` and the local coordinate in it, per axis. On a bounded axis a
    /// point on the upper face belongs to the last cell (ξ = 1).
    // Always inlined: the 3D build made it a call returning its arrays through memory,
    // 8 % of a 3D step (docs/performance.md).
    #[inline(always)]
    pub fn locate(&self, x: &[f64; D]) -> ([i64; D], [f64; D]) {
        let mut c = [0i64; D];
        let mut xi = [0.0; D];
        for a in 0..D {
            let s = (x[a] - self.lower[a]) * self.inv_h[a];
            let mut i = floor_i64(s);
            if !self.periodic[a] {
                // (`max` then `min`, not `clamp`: the same for cells >= 1, without
                // `clamp`'s check of its bounds on every call.)
                i = i.max(0).min(self.cells[a] as i64 - 1);
            }
            c[a] = i;
            xi[a] = s - i as f64;
        }
        (c, xi)
    }

    /// Is node index `g` along axis `a` on the lower (-1), upper (+1) boundary, or not (0)?
    #[inline]
    pub fn end(&self, a: usize, g: i64) -> i32 {
        if self.periodic[a] {
            0
        } else if g == 0 {
            -1
        } else if g == self.cells[a] as i64 {
            1
        } else {
            0
        }
    }

    /// Does node `g` exist along axis `a` (always, on a periodic axis)?
    #[inline]
    pub fn exists(&self, a: usize, g: i64) -> bool {
        self.periodic[a] || (0..=self.cells[a] as i64).contains(&g)
    }

    /// `V_j = ∫ S_j dv` over the grid domain.
    pub fn node_volume(&self, node: [i64; D]) -> f64 {
        let mut v = 1.0;
        for (a, &g) in node.iter().enumerate() {
            v *= if self.end(a, g) != 0 {
                0.5 * self.h[a]
            } else {
                self.h[a]
            };
        }
        v
    }

    /// Position of a node.
    pub fn node_position(&self, node: [i64; D]) -> [f64; D] {
        let mut x = [0.0; D];
        for a in 0..D {
            x[a] = self.lower[a] + node[a] as f64 * self.h[a];
        }
        x
    }
}

/// 1D integral `∫ N_j N_i' dx` for `j - i = dj` at node `gi` along axis `a`.
#[inline]
pub fn int_n_dn<const D: usize>(geom: &Geom<D>, a: usize, gi: i64, dj: i64) -> f64 {
    match dj {
        -1 => 0.5,
        1 => -0.5,
        0 => 0.5 * geom.end(a, gi) as f64,
        _ => 0.0,
    }
}

/// 1D integral `∫ N_j N_i dx` for `j - i = dj` at node `gi` along axis `a`.
#[inline]
pub fn int_n_n<const D: usize>(geom: &Geom<D>, a: usize, gi: i64, dj: i64) -> f64 {
    let h = geom.h[a];
    match dj {
        -1 | 1 => h / 6.0,
        0 => {
            if geom.end(a, gi) != 0 {
                h / 3.0
            } else {
                2.0 * h / 3.0
            }
        }
        _ => 0.0,
    }
}

/// `W_ji = ∫ S_j ∇S_i dv` for node `i` and neighbour `j = i + dj` (|dj| <= 1 per axis),
/// a tensor product of the 1D integrals. Zero if `j` does not exist.
pub fn grid_integral<const D: usize>(geom: &Geom<D>, gi: [i64; D], dj: [i64; D]) -> [f64; D] {
    let mut w = [0.0; D];
    for a in 0..D {
        if !geom.exists(a, gi[a] + dj[a]) {
            return [0.0; D];
        }
    }
    for (d, wd) in w.iter_mut().enumerate() {
        let mut p = int_n_dn(geom, d, gi[d], dj[d]);
        for e in 0..D {
            if e != d {
                p *= int_n_n(geom, e, gi[e], dj[e]);
            }
        }
        *wd = p;
    }
    w
}

/// A gradient scheme as the solver runs it, resolved once from the scene's names: the
/// shape functions of the particle loops (hat functions or GIMP's), the weight α of
/// the standard gradient against the grid-averaged one and where the particle
/// integrates them. Whether a step has the node → node steps follows from α.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GradientScheme {
    /// GIMP's shape functions (3 nodes per axis) instead of hat functions (2).
    pub gimp: bool,
    /// MPMCG's domain rule ([`domain`]): a particle's weights, force and velocity
    /// gradient integrated over its current domain, which reaches 3 nodes per axis.
    pub domain: bool,
    pub alpha: Alpha,
}

impl GradientScheme {
    pub fn of(g: Gradient, q: Quadrature) -> Self {
        let alpha = match g {
            Gradient::Mpm | Gradient::Gimp => Alpha::Constant(1.0),
            Gradient::Averaged => Alpha::Constant(0.0),
            Gradient::Mpmcg => Alpha::ProductOfShapes,
        };
        Self {
            gimp: g == Gradient::Gimp,
            domain: g == Gradient::Mpmcg && q == Quadrature::Domain,
            alpha,
        }
    }

    /// A particle touches 3 nodes per axis (GIMP, the domain rule), not 2.
    pub fn wide(self) -> bool {
        self.gimp || self.domain
    }

    /// The gradient goes through grid averages (σ̄, L̄): the step has MPMCG's node →
    /// node steps. Everything but α ≡ 1 does.
    pub fn two_step(self) -> bool {
        self.alpha != Alpha::Constant(1.0)
    }
}

/// Weight function α(x) of MPMCG: 1 gives MPM's gradient, 0 the averaged one. It must
/// vanish on cell faces for the gradient to be continuous.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Alpha {
    /// `Π_d 4 ξ_d (1 − ξ_d)`: a product of shape functions, 1 at the cell centre.
    ProductOfShapes,
    /// A constant: 0 is the averaged gradient, 1 standard MPM (used by tests).
    Constant(f64),
}

impl Alpha {
    #[inline]
    pub fn eval<const D: usize>(self, xi: &[f64; D]) -> f64 {
        match self {
            Alpha::ProductOfShapes => xi.iter().map(|&x| 4.0 * x * (1.0 - x)).product(),
            Alpha::Constant(c) => c,
        }
    }
}

/// Per-axis 1D weights of one particle; the tensor product gives node weights.
#[derive(Clone, Copy, Debug)]
pub struct Weights1<const D: usize> {
    /// Global index of the first node touched along each axis.
    pub base: [i64; D],
    /// The cell the particle is in (`Geom::locate`); `base` is this cell or the one
    /// below.
    pub cell: [i64; D],
    /// Nodes per axis: 2 (linear) or 3 (GIMP).
    pub n: usize,
    pub w: [[f64; 3]; D],
    pub dw: [[f64; 3]; D],
    /// Local cell coordinate.
    pub xi: [f64; D],
    /// `Π 4ξ(1−ξ)`, MPMCG's α, computed here while ξ is in registers: computing it
    /// later from `xi` reloads scalars just stored as one vector, a store-forwarding
    /// stall that cost a tenth of the gather.
    pub bubble: f64,
}

#[inline(always)]
fn bubble<const D: usize>(xi: &[f64; D]) -> f64 {
    let mut b = 1.0;
    for &x in xi {
        b *= 4.0 * x * (1.0 - x);
    }
    b
}

/// Linear hat functions.
#[inline(always)]
pub fn linear<const D: usize>(geom: &Geom<D>, x: &[f64; D]) -> Weights1<D> {
    let (c, xi) = geom.locate(x);
    let mut w = hat(geom, &xi);
    w.base = c;
    w.cell = c;
    w
}

/// Linear hat functions at local cell coordinate `xi` (as [`Geom::locate`] gives it),
/// the cell left unset (`base` and `cell` zero): for loops that know the cell.
#[inline(always)]
pub fn hat<const D: usize>(geom: &Geom<D>, xi: &[f64; D]) -> Weights1<D> {
    let xi = *xi;
    let mut w = [[0.0; 3]; D];
    let mut dw = [[0.0; 3]; D];
    for a in 0..D {
        w[a][0] = 1.0 - xi[a];
        w[a][1] = xi[a];
        dw[a][0] = -geom.inv_h[a];
        dw[a][1] = geom.inv_h[a];
    }
    Weights1 {
        base: [0; D],
        cell: [0; D],
        n: 2,
        w,
        dw,
        xi,
        bubble: bubble(&xi),
    }
}

/// Uniform GIMP: hat functions convolved with the particle's characteristic function of
/// half-width `lp[a]` (<= h/2).
///
/// On a bounded axis the half-width is shrunk to the particle's distance from the grid
/// boundary, so that the particle domain never reaches outside the grid. There are no
/// nodes out there: a domain sticking out would lose the outside node's share, the
/// weights would no longer sum to one, `Σ_i ∇S_i ≠ 0`, and momentum would not be
/// conserved (a body against a free face, `tests/schemes.rs`). Shrinking the domain
/// symmetrically keeps the particle's centroid, so `Σ_i S_i x_i = x` and
/// `Σ_i x_i ⊗ ∇S_i = I` hold as well. A shrunk domain `[x − l, x + l]` touches the
/// boundary and, as `l < lp <= h/2`, lies inside the boundary cell, where the hat
/// functions are linear: its averages are the linear weights of that cell, which is
/// how they are computed (exactly, for any `l` down to 0).
#[inline]
pub fn gimp<const D: usize>(geom: &Geom<D>, x: &[f64; D], lp: &[f64; D]) -> Weights1<D> {
    let (c, xi) = geom.locate(x);
    let mut base = c;
    let mut w = [[0.0; 3]; D];
    let mut dw = [[0.0; 3]; D];
    for a in 0..D {
        let h = geom.h[a];
        let l = lp[a];
        let shrunk = !geom.periodic[a] && (x[a] - geom.lower[a] < l || geom.upper[a] - x[a] < l);
        if xi[a] < 0.5 {
            base[a] = c[a] - 1;
        }
        if shrunk {
            // Linear weights on the slots of the cell's nodes, the third slot empty.
            base[a] = c[a];
            w[a] = [1.0 - xi[a], xi[a], 0.0];
            dw[a] = [-geom.inv_h[a], geom.inv_h[a], 0.0];
        }
        for k in 0..3 {
            let g = base[a] + k as i64;
            if shrunk || !geom.exists(a, g) {
                continue;
            }
            // Signed distance from the node to the particle.
            let r = (xi[a] + (c[a] - g) as f64) * h;
            let ar = r.abs();
            let s = r.signum();
            let (wk, dk) = if ar < l {
                (1.0 - (r * r + l * l) / (2.0 * h * l), -r / (h * l))
            } else if ar < h - l {
                (1.0 - ar / h, -s / h)
            } else if ar < h + l {
                let q = h + l - ar;
                (q * q / (4.0 * h * l), -s * q / (2.0 * h * l))
            } else {
                (0.0, 0.0)
            };
            w[a][k] = wk;
            dw[a][k] = dk;
        }
        shift_inside(geom, a, &mut base[a], [&mut w[a], &mut dw[a]]);
    }
    Weights1 {
        base,
        cell: c,
        n: 3,
        w,
        dw,
        xi,
        bubble: bubble(&xi),
    }
}

/// The domain rule's per-axis data of one particle over the 3 nodes from `base`: the
/// hat functions at the particle (its move's blend at a wall) and the averages over its
/// domain `[x − l, x + l]` of `N_k`, `a N_k` and `a N_k'`, with `a(ξ) = 4ξ(1 − ξ)` in the
/// cell of each point. MPMCG's α is `Π_a a(ξ_a)`, so over a box every integral the particle
/// needs is a product of these: its mass, momentum and velocity weight `avg(S_k) =
/// Π avg(N_k)`, the force's and the velocity gradient's
/// `avg(α ∂_b S_k) = avg(a N_k')_b Π_{a≠b} avg(a N_k)_a` and
/// `avg((1 − α) S_k) = avg(S_k) − Π avg(a N_k)` ([`DomainWeights1::node`]).
#[derive(Clone, Copy, Debug)]
pub struct DomainWeights1<const D: usize> {
    /// Global index of the first of the 3 nodes per axis.
    pub base: [i64; D],
    /// The cell the particle is in (`Geom::locate`).
    pub cell: [i64; D],
    /// Hat functions at the particle, on the slots of its cell's nodes.
    pub w: [[f64; 3]; D],
    pub avg_n: [[f64; 3]; D],
    pub avg_an: [[f64; 3]; D],
    pub avg_adn: [[f64; 3]; D],
    /// The centred first moments `avg(N_k (x − x_p))` (lengths): with `avg_n`, the move's
    /// average of the reconstruction over the domain.
    pub avg_nc: [[f64; 3]; D],
}

/// Which of a particle's interpolation data a pass reads besides the shape functions
/// (the weights of mass, momentum and velocity, and the hat functions at the particle):
/// the gradients (with the weights of the nodes' averages) and the domain rule's first
/// moments. The others are not formed (left zero): the remap reads neither, the
/// scatter no moments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reads {
    pub gradients: bool,
    pub moments: bool,
}

impl Reads {
    pub const ALL: Reads = Reads {
        gradients: true,
        moments: true,
    };
}

/// One piece of a particle's domain along an axis, the part of it in one cell: its
/// share of the domain's averages over the cell's lower and upper node (`[lower,
/// upper]` per row). Each average is a polynomial of degree at most 3 in the cell's
/// coordinate u, so it follows from the piece's centre `m`, its half-length's square
/// `q` (so that `avg (u − m)² = q/3` and `avg (u − m)³ = 0`) and `mu`, the centre's
/// offset from the particle in cells. Every term is written in these centred
/// quantities, so that nothing is a difference of nearly equal numbers: an interior
/// domain's moments, of order `q`, are formed from `q`, not from positions of order 1.
#[derive(Clone, Copy, Default)]
struct Piece {
    n: [f64; 2],
    an: [f64; 2],
    adn: [f64; 2],
    nc: [f64; 2],
}

impl Piece {
    /// The piece `[u0, u1]` of a cell (its own coordinates) holding the share `f` of
    /// the domain, whose centre lies `mu` cells from the particle; `h` the cell size and
    /// `inv_h` its inverse.
    #[inline(always)]
    fn new(u0: f64, u1: f64, f: f64, mu: f64, [h, inv_h]: [f64; 2], reads: Reads) -> Piece {
        let m = 0.5 * (u0 + u1);
        let half = 0.5 * (u1 - u0);
        let q = half * half;
        let mut p = Piece {
            n: [f * (1.0 - m), f * m],
            ..Piece::default()
        };
        if reads.gradients {
            // avg a(u) (1 − u) and avg a(u) u, a = 4u(1 − u).
            let lower = 4.0 * (m * (1.0 - m) * (1.0 - m) + q * (m - 2.0 / 3.0));
            let upper = 4.0 * (m * m * (1.0 - m) + q * (1.0 / 3.0 - m));
            p.an = [f * lower, f * upper];
            let slope = f * (lower + upper) * inv_h;
            p.adn = [-slope, slope];
        }
        if reads.moments {
            // avg (1 − u) (x − x_p) and avg u (x − x_p), x − x_p = (mu + u − m) h.
            p.nc = [
                f * h * (mu * (1.0 - m) - q / 3.0),
                f * h * (mu * m + q / 3.0),
            ];
        }
        p
    }
}

/// The domain rule's per-axis data ([`DomainWeights1`]) of a particle at `x` with
/// half-widths `lp` (each taken at most half a cell, so that the domain meets at most
/// two cells and 3 nodes). The domain is the particle's current one (the caller scales
/// the reference half-width by the stretch `|F e_a|`). On a bounded axis it is cut at
/// the grid's faces: there are no nodes outside, and an average over the part inside
/// keeps `Σ_k avg N_k = 1` and `Σ_k avg N_k' = 0`, so the gradient's identities hold.
/// The window of 3 nodes starts one below the cell where `ξ < ½` (the domain may reach
/// the cell below), else at the cell, and at a bounded end is shifted inside the grid
/// as GIMP's is. Of the averages only those `reads` asks for besides `avg_n` are formed
/// (the others stay zero). Inlined, so that the data stay in registers and a pass's
/// `reads` is a constant.
#[inline(always)]
pub fn domain<const D: usize>(
    geom: &Geom<D>,
    x: &[f64; D],
    lp: &[f64; D],
    reads: Reads,
) -> DomainWeights1<D> {
    let (c, xi) = geom.locate(x);
    let mut d = DomainWeights1 {
        base: c,
        cell: c,
        w: [[0.0; 3]; D],
        avg_n: [[0.0; 3]; D],
        avg_an: [[0.0; 3]; D],
        avg_adn: [[0.0; 3]; D],
        avg_nc: [[0.0; 3]; D],
    };
    for a in 0..D {
        let t = xi[a];
        let below = t < 0.5;
        d.base[a] = c[a] - i64::from(below);
        // The domain in the cell's coordinates, cut at the grid's faces.
        let r = (lp[a] * geom.inv_h[a]).min(0.5);
        let (mut lo, mut hi) = (t - r, t + r);
        if !geom.periodic[a] {
            lo = lo.max(-(c[a] as f64));
            hi = hi.min((geom.cells[a] as i64 - c[a]) as f64);
        }
        let len = hi - lo;
        // (A piece in a neighbour exists only where the domain has a width.)
        let share = |u0: f64, u1: f64| (u1 - u0) / len;
        let h = [geom.h[a], geom.inv_h[a]];
        // The piece in the particle's cell (a domain of zero width is its point there),
        // and the one in the neighbour it reaches: the cell below where ξ < ½, above
        // where not (a half-width of at most half a cell reaches no further).
        let (u0, u1) = (lo.max(0.0), hi.min(1.0));
        let own_share = if len > 0.0 { share(u0, u1) } else { 1.0 };
        let own = Piece::new(u0, u1, own_share, 0.5 * (u0 + u1) - t, h, reads);
        let rows: [[f64; 3]; 5] = if below {
            let other = if lo < 0.0 {
                Piece::new(lo + 1.0, 1.0, share(lo, 0.0), 0.5 * lo - t, h, reads)
            } else {
                Piece::default()
            };
            let join = |o: [f64; 2], p: [f64; 2]| [o[0], o[1] + p[0], p[1]];
            [
                [0.0, 1.0 - t, t],
                join(other.n, own.n),
                join(other.an, own.an),
                join(other.adn, own.adn),
                join(other.nc, own.nc),
            ]
        } else {
            let other = if hi > 1.0 {
                Piece::new(
                    0.0,
                    hi - 1.0,
                    share(1.0, hi),
                    0.5 * (1.0 + hi) - t,
                    h,
                    reads,
                )
            } else {
                Piece::default()
            };
            let join = |p: [f64; 2], o: [f64; 2]| [p[0], p[1] + o[0], o[1]];
            [
                [1.0 - t, t, 0.0],
                join(own.n, other.n),
                join(own.an, other.an),
                join(own.adn, other.adn),
                join(own.nc, other.nc),
            ]
        };
        [d.w[a], d.avg_n[a], d.avg_an[a], d.avg_adn[a], d.avg_nc[a]] = rows;
        let rows = [
            &mut d.w[a],
            &mut d.avg_n[a],
            &mut d.avg_an[a],
            &mut d.avg_adn[a],
            &mut d.avg_nc[a],
        ];
        shift_inside(geom, a, &mut d.base[a], rows);
    }
    d
}

/// The first of the 3 nodes per axis that GIMP's and the domain rule's weights cover,
/// for a particle in cell `c` at local coordinate `xi` ([`Geom::locate`]): one below
/// the cell where ξ < ½ (the domain may reach the cell below), else the cell's own,
/// kept on the grid's nodes at a bounded end ([`keep_inside`]). Particles with the same
/// window share their nodes, which the wide passes read and write once per run of them.
#[inline(always)]
pub fn window<const D: usize>(geom: &Geom<D>, c: &[i64; D], xi: &[f64; D]) -> [i64; D] {
    std::array::from_fn(|a| keep_inside(geom, a, c[a] - i64::from(xi[a] < 0.5)))
}

/// The first node `base` of a window of 3 along axis `a`, moved onto the grid's nodes
/// at a bounded end (unchanged on a periodic axis).
#[inline(always)]
fn keep_inside<const D: usize>(geom: &Geom<D>, a: usize, base: i64) -> i64 {
    if geom.periodic[a] {
        base
    } else if base < 0 {
        0
    } else if base + 2 > geom.cells[a] as i64 {
        base - 1
    } else {
        base
    }
}

/// Keep a window of 3 nodes from `base` along axis `a` on existing nodes at a bounded
/// end ([`keep_inside`]), moving its per-node `rows` with it (the dropped node has
/// weight zero: the domain stays inside the grid), so that the stencil never indexes
/// outside the grid.
#[inline(always)]
fn shift_inside<const D: usize, const R: usize>(
    geom: &Geom<D>,
    a: usize,
    base: &mut i64,
    rows: [&mut [f64; 3]; R],
) {
    let kept = keep_inside(geom, a, *base);
    if kept > *base {
        for v in rows {
            *v = [v[1], v[2], 0.0];
        }
    } else if kept < *base {
        for v in rows {
            *v = [0.0, v[0], v[1]];
        }
    }
    *base = kept;
}

impl<const D: usize> DomainWeights1<D> {
    /// Node `o` (its slot per axis): `avg(S)` and the hat function at the particle.
    #[inline(always)]
    pub fn node(&self, o: &[usize; D]) -> (f64, f64) {
        let (mut s, mut n) = (1.0, 1.0);
        for a in 0..D {
            s *= self.w[a][o[a]];
            n *= self.avg_n[a][o[a]];
        }
        (n, s)
    }

    /// Node `o`'s α-part of the gradient `avg(α ∇S)` and the weight `avg((1 − α) S)`
    /// of the node's averages σ̄ and L̄, given its `avg(S)` ([`DomainWeights1::node`]).
    /// Formed from the averages [`Reads::gradients`] asks for.
    #[inline(always)]
    pub fn gradient(&self, o: &[usize; D], avg_s: f64) -> ([f64; D], f64) {
        let mut an = 1.0;
        for a in 0..D {
            an *= self.avg_an[a][o[a]];
        }
        let g = std::array::from_fn(|b| {
            let mut p = self.avg_adn[b][o[b]];
            for a in 0..D {
                if a != b {
                    p *= self.avg_an[a][o[a]];
                }
            }
            p
        });
        (g, avg_s - an)
    }

    /// Node `o`'s centred moments `avg(S (x − x_p))` per axis.
    #[inline(always)]
    pub fn moments(&self, o: &[usize; D]) -> [f64; D] {
        std::array::from_fn(|b| {
            let mut p = self.avg_nc[b][o[b]];
            for a in 0..D {
                if a != b {
                    p *= self.avg_n[a][o[a]];
                }
            }
            p
        })
    }
}

/// Node weights and gradients of one particle, tensor products of [`Weights1`].
#[derive(Clone, Copy, Debug)]
pub struct Stencil<const D: usize> {
    pub count: usize,
    /// Offsets of the nodes from `base`, per axis.
    pub off: [[u8; D]; MAX_NODES],
    pub s: [f64; MAX_NODES],
    pub g: [[f64; D]; MAX_NODES],
}

impl<const D: usize> Weights1<D> {
    #[inline]
    pub fn stencil(&self) -> Stencil<D> {
        let n = self.n;
        let count = n.pow(D as u32);
        let mut st = Stencil {
            count,
            off: [[0; D]; MAX_NODES],
            s: [0.0; MAX_NODES],
            g: [[0.0; D]; MAX_NODES],
        };
        for k in 0..count {
            let mut r = k;
            let mut o = [0u8; D];
            for oa in o.iter_mut() {
                *oa = (r % n) as u8;
                r /= n;
            }
            let mut s = 1.0;
            for a in 0..D {
                s *= self.w[a][o[a] as usize];
            }
            let mut g = [0.0; D];
            for (d, gd) in g.iter_mut().enumerate() {
                let mut p = self.dw[d][o[d] as usize];
                for e in 0..D {
                    if e != d {
                        p *= self.w[e][o[e] as usize];
                    }
                }
                *gd = p;
            }
            st.off[k] = o;
            st.s[k] = s;
            st.g[k] = g;
        }
        st
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// GIMP particles near, on and against bounded faces: the weights sum to one, the
    /// gradients to zero, and both reproduce linear fields (`Σ S_i x_i = x`,
    /// `Σ x_i ⊗ ∇S_i = I`). Before the particle domain was kept inside the grid, a
    /// domain reaching out lost the outside node's share here.
    #[test]
    fn gimp_is_a_partition_of_unity_at_bounded_faces() {
        let geom = Geom::<2>::new([-0.5, 1.0], [1.5, 1.6], [8, 4], [false, false]);
        let lp = [0.125 * geom.h[0], 0.5 * geom.h[1]];
        let xs = [
            -0.5,
            -0.5 + 1e-13,
            -0.49,
            -0.45,
            -0.5 + lp[0],
            0.3,
            1.5 - 0.02,
            1.5,
        ];
        let ys = [
            1.0,
            1.0 + 1e-300,
            1.01,
            1.0 + lp[1],
            1.3,
            1.6 - 0.1,
            1.6 - 1e-9,
            1.6,
        ];
        for &x in &xs {
            for &y in &ys {
                let p = [x, y];
                let w = gimp(&geom, &p, &lp);
                let st = w.stencil();
                let mut sum = 0.0;
                let mut first = [0.0; 2];
                let mut gsum = [0.0; 2];
                let mut mom = [[0.0; 2]; 2];
                for k in 0..st.count {
                    let node = [
                        w.base[0] + i64::from(st.off[k][0]),
                        w.base[1] + i64::from(st.off[k][1]),
                    ];
                    assert!(
                        geom.exists(0, node[0]) && geom.exists(1, node[1]),
                        "{node:?} at {p:?}"
                    );
                    let xn = geom.node_position(node);
                    sum += st.s[k];
                    for a in 0..2 {
                        first[a] += st.s[k] * xn[a];
                        gsum[a] += st.g[k][a];
                        for (m, g) in mom[a].iter_mut().zip(&st.g[k]) {
                            *m += xn[a] * g;
                        }
                    }
                }
                assert!((sum - 1.0).abs() < 1e-14, "Σ S = {sum} at {p:?}");
                for a in 0..2 {
                    assert!(
                        (first[a] - p[a]).abs() < 1e-14,
                        "Σ S x = {first:?} at {p:?}"
                    );
                    assert!(gsum[a].abs() < 1e-13, "Σ ∇S = {gsum:?} at {p:?}");
                    for b in 0..2 {
                        let id = if a == b { 1.0 } else { 0.0 };
                        assert!(
                            (mom[a][b] - id).abs() < 1e-13,
                            "Σ x ⊗ ∇S = {mom:?} at {p:?}"
                        );
                    }
                }
            }
        }
    }

    /// The domain rule's per-axis averages (the moments included) against a fine
    /// midpoint sum over the domain cut at the grid's faces, at points inside, next to
    /// and on bounded faces, on a periodic axis across its seam, with short and clamped half-widths; and the
    /// sums its identities rest on: `Σ avg N = 1`, `Σ avg N x_k` the domain's centre,
    /// `Σ avg(a N') = 0`.
    #[test]
    fn domain_averages_are_the_integrals_over_the_domain() {
        let geom = Geom::<2>::new([-0.5, 0.0], [1.5, 1.0], [8, 5], [false, true]);
        let xs = [-0.5, -0.49, -0.45, -0.3, 0.0, 0.37, 1.45, 1.5 - 1e-12, 1.5];
        let ys = [0.0, 0.01, 0.5, 0.99, 0.3];
        let lps = [[0.0, 0.0], [0.01, 0.02], [0.0625, 0.05], [0.3, 0.4]];
        let a_of = |u: f64| 4.0 * u * (1.0 - u);
        for &x in &xs {
            for &y in &ys {
                for lp in &lps {
                    let p = [x, y];
                    let d = domain(&geom, &p, lp, Reads::ALL);
                    for ax in 0..2 {
                        let h = geom.h[ax];
                        let r = lp[ax].min(0.5 * h);
                        let (mut lo, mut hi) = (p[ax] - r, p[ax] + r);
                        if !geom.periodic[ax] {
                            lo = lo.max(geom.lower[ax]);
                            hi = hi.min(geom.upper[ax]);
                        }
                        let (mut n, mut an, mut adn, mut nc) =
                            ([0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3]);
                        let m = 20_000;
                        for i in 0..m {
                            let xq = if hi > lo {
                                lo + (i as f64 + 0.5) / m as f64 * (hi - lo)
                            } else {
                                lo
                            };
                            let s = (xq - geom.lower[ax]) / h;
                            for k in 0..3 {
                                // Hat of node base + k at xq, its slope, and a in its cell.
                                let t = s - (d.base[ax] + k as i64) as f64;
                                if t.abs() >= 1.0 {
                                    continue;
                                }
                                let cell_t = s - s.floor();
                                let au = a_of(cell_t);
                                n[k] += (1.0 - t.abs()) / m as f64;
                                an[k] += au * (1.0 - t.abs()) / m as f64;
                                adn[k] -= au * t.signum() / h / m as f64;
                                nc[k] += (1.0 - t.abs()) * (xq - p[ax]) / m as f64;
                            }
                        }
                        for k in 0..3 {
                            let tol = 1e-6;
                            let at = format!("{p:?} lp {lp:?} axis {ax} node {k}");
                            assert!(
                                (d.avg_n[ax][k] - n[k]).abs() < tol,
                                "N {at}: {:?} vs {n:?}",
                                d.avg_n[ax]
                            );
                            assert!(
                                (d.avg_an[ax][k] - an[k]).abs() < tol,
                                "aN {at}: {:?} vs {an:?}",
                                d.avg_an[ax]
                            );
                            assert!(
                                (d.avg_adn[ax][k] - adn[k]).abs() * h < tol,
                                "aN' {at}: {:?} vs {adn:?}",
                                d.avg_adn[ax]
                            );
                            assert!(
                                (d.avg_nc[ax][k] - nc[k]).abs() < tol * h,
                                "N (x - x_p) {at}: {:?} vs {nc:?}",
                                d.avg_nc[ax]
                            );
                        }
                        let sum = |v: &[f64; 3]| v.iter().sum::<f64>();
                        let centre = (0..3)
                            .map(|k| d.avg_n[ax][k] * (d.base[ax] + k as i64) as f64 * h)
                            .sum::<f64>()
                            + geom.lower[ax];
                        assert!((sum(&d.avg_n[ax]) - 1.0).abs() < 1e-14);
                        assert!((sum(&d.w[ax]) - 1.0).abs() < 1e-14);
                        assert!(
                            (centre - 0.5 * (lo + hi)).abs() < 1e-14,
                            "{centre} at {p:?}"
                        );
                        assert!(sum(&d.avg_adn[ax]).abs() * h < 1e-14);
                    }
                }
            }
        }
    }

    /// [`window`] names the first node of GIMP's and the domain rule's 3 per axis, the
    /// node the passes key their runs by: at points inside, on and next to bounded faces
    /// (two-cell axes included), across a periodic seam, at ξ = ½, with
    /// half-widths from zero to past half a cell.
    #[test]
    fn window_is_the_first_node_of_the_wide_weights() {
        let mut rng = decomposition::splitmix::Rng::new(5);
        for cells in [[2usize, 2], [2, 9], [7, 3]] {
            for periodic in [[false, false], [false, true], [true, false]] {
                let geom = Geom::<2>::new([-0.5, 0.25], [1.5, 1.0], cells, periodic);
                let mut pts = Vec::new();
                for _ in 0..400 {
                    pts.push([-0.5 + 2.0 * rng.f64(), 0.25 + 0.75 * rng.f64()]);
                }
                // Faces, cell middles (ξ = ½ exactly) and points a hair from them.
                for k in 0..=2 * cells[0] {
                    for j in 0..=2 * cells[1] {
                        let (x, y) = (
                            -0.5 + k as f64 * 0.5 * geom.h[0],
                            0.25 + j as f64 * 0.5 * geom.h[1],
                        );
                        pts.extend([[x, y], [x - 1e-13, y + 1e-13], [x + 1e-13, y]]);
                    }
                }
                for x in pts {
                    let x = std::array::from_fn(|a| x[a].clamp(geom.lower[a], geom.upper[a]));
                    let (c, xi) = geom.locate(&x);
                    let w = window(&geom, &c, &xi);
                    for lp in [
                        [0.0, 0.0],
                        [0.1, 0.05],
                        [0.25 * geom.h[0], 0.5 * geom.h[1]],
                        [1.0, 1.0],
                    ] {
                        let gl = lp.map(|l: f64| l.min(0.5 * geom.h[0]).min(0.5 * geom.h[1]));
                        assert_eq!(
                            gimp(&geom, &x, &gl).base,
                            w,
                            "GIMP at {x:?}, {cells:?} {periodic:?}"
                        );
                        assert_eq!(
                            domain(&geom, &x, &lp, Reads::ALL).base,
                            w,
                            "domain at {x:?}, {cells:?} {periodic:?}"
                        );
                    }
                }
            }
        }
    }

    /// The domain rule forms what a pass reads and nothing else: with fewer
    /// [`Reads`] the averages it forms are the same bits as with all, the others zero.
    #[test]
    fn domain_forms_only_what_is_read() {
        let geom = Geom::<2>::new([-0.5, 0.0], [1.5, 1.0], [8, 5], [false, true]);
        let mut rng = decomposition::splitmix::Rng::new(9);
        for _ in 0..200 {
            let x = [-0.5 + 2.0 * rng.f64(), rng.f64()];
            let lp = [0.2 * rng.f64(), 0.15 * rng.f64()];
            let all = domain(&geom, &x, &lp, Reads::ALL);
            for (gradients, moments) in [(false, false), (true, false), (false, true)] {
                let d = domain(&geom, &x, &lp, Reads { gradients, moments });
                assert_eq!(
                    (d.base, d.cell, d.w, d.avg_n),
                    (all.base, all.cell, all.w, all.avg_n)
                );
                let zero = [[0.0; 3]; 2];
                let (an, adn) = if gradients {
                    (all.avg_an, all.avg_adn)
                } else {
                    (zero, zero)
                };
                assert_eq!((d.avg_an, d.avg_adn), (an, adn), "{x:?}");
                assert_eq!(d.avg_nc, if moments { all.avg_nc } else { zero }, "{x:?}");
            }
        }
    }
}
