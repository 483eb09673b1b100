//! Reference evaluation of the effective gradient `G_i(x)` of every scheme at a point:
//! slow and written for clarity, independent of the production code paths (the per-
//! particle [`crate::physics::shape`] stencils and the solver's two-step assembly), so that tests
//! can check one against the other and both against the identities `Σ_i G_i = 0` and
//! `Σ_i x_i ⊗ G_i = I`.
//!
//! - `mpm`:      `G_i = ∇S_i` (linear hat functions).
//! - `gimp`:     uniform GIMP, `S_i(x) = (1/2l) ∫_{x−l}^{x+l} N_i` per axis.
//! - `averaged`: `~∇S_i(x) = Σ_j S_j(x) (1/V_j) ∫_Ω S_j ∇S_i dv`.
//! - `mpmcg`:    `α(ξ) ∇S_i + (1 − α(ξ)) ~∇S_i`, α pluggable.
//! - `mpmcg` under the domain rule: that gradient averaged over the particle's domain,
//!   the box of half-widths `lp` (at most half a cell) cut at bounded grid faces.
//!
//! The integrals over the grid domain Ω (all cells, a set of cells, or the solver's
//! continuous weight per cell, see [`Domain`]) are evaluated by 2-point Gauss quadrature per axis on each cell (exact: the
//! integrand is at most quadratic per axis), not by the closed forms the solver uses.
//!
//! Node indices are global and *unwrapped*: on a periodic axis the nodes around a point
//! are numbered consecutively (possibly below 0 or above `cells`), so that
//! `Σ_i x_i ⊗ G_i(x)` can be formed with [`Geom::node_position`]. Use [`wrap_node`] to
//! compare nodes across a periodic seam.

use crate::physics::shape::{Alpha, Geom};
use std::collections::{BTreeMap, BTreeSet};

/// The grid domain Ω of the integrals: every cell, a set of cells, or a weight per cell
/// (by wrapped global cell index; cells not listed weigh 0).
#[derive(Clone, Debug, Default)]
pub enum Domain<const D: usize> {
    #[default]
    All,
    Cells(BTreeSet<[i64; D]>),
    Weighted(BTreeMap<[i64; D], f64>),
}

impl<const D: usize> Domain<D> {
    /// Is the (unwrapped) cell part of Ω (weight > 0)?
    pub fn contains(&self, geom: &Geom<D>, cell: [i64; D]) -> bool {
        self.weight(geom, cell) > 0.0
    }

    /// The weight of an (unwrapped) cell: 1 in Ω, 0 outside (and always outside a
    /// bounded axis), or the listed weight.
    pub fn weight(&self, geom: &Geom<D>, cell: [i64; D]) -> f64 {
        let mut w = cell;
        for a in 0..D {
            let n = geom.cells[a] as i64;
            if geom.periodic[a] {
                w[a] = cell[a].rem_euclid(n);
            } else if !(0..n).contains(&cell[a]) {
                return 0.0;
            }
        }
        match self {
            Domain::All => 1.0,
            Domain::Cells(set) => f64::from(u8::from(set.contains(&w))),
            Domain::Weighted(map) => map.get(&w).copied().unwrap_or(0.0),
        }
    }

    /// The solver's continuous domain for particles at `x` with volumes `vol`: each
    /// node's fill `φ_k = min(1, Σ_p S_k(x_p) v_p / (θ ∫ S_k dv))`, each cell weighing
    /// the smallest fill of its corners (see the solver's `domain_weights`). Written
    /// from the definition: shapes from [`linear_shape`], `∫ S_k dv` by quadrature.
    pub fn from_particles(geom: &Geom<D>, x: &[[f64; D]], vol: &[f64], theta: f64) -> Self {
        let mut cover: BTreeMap<[i64; D], f64> = BTreeMap::new();
        for (xp, &vp) in x.iter().zip(vol) {
            for (node, s, _) in linear_shape(geom, xp) {
                *cover.entry(wrap_node(geom, node)).or_default() += s * vp;
            }
        }
        Self::from_cover(geom, &cover, theta)
    }

    /// The same domain from each node's covered volume `Σ_p S_k v_p` (keyed by wrapped
    /// node), for particles whose weights are not the hat functions at their positions
    /// (the domain rule covers nodes with the averages over each particle's domain).
    pub fn from_cover(geom: &Geom<D>, cover: &BTreeMap<[i64; D], f64>, theta: f64) -> Self {
        let fill = |node: [i64; D]| -> f64 {
            let node = wrap_node(geom, node);
            let Some(&c) = cover.get(&node) else {
                return 0.0;
            };
            let support = node_volume(geom, &Domain::All, node);
            (c / (theta * support)).min(1.0)
        };
        let mut cells = BTreeMap::new();
        for &node in cover.keys() {
            // Every cell with this node as a corner.
            for cell in box_nodes(std::array::from_fn(|a| node[a] - 1), 2) {
                if Domain::<D>::All.weight(geom, cell) == 0.0 {
                    continue;
                }
                let w = box_nodes(cell, 2).into_iter().map(fill).fold(1.0, f64::min);
                if w > 0.0 {
                    cells.insert(wrap_node(geom, cell), w);
                }
            }
        }
        Domain::Weighted(cells)
    }
}

/// The gradient schemes of the module documentation (and README, "The schemes").
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Scheme<const D: usize> {
    Mpm,
    /// uGIMP with particle half-width `lp` per axis.
    Gimp {
        lp: [f64; D],
    },
    Averaged,
    Mpmcg(Alpha),
    /// MPMCG with its nodal averages sharpened by β ([`averaged_sharpened`]).
    MpmcgSharpened {
        alpha: Alpha,
        sharpen: f64,
    },
    /// MPMCG under the domain rule, over the box of half-widths `lp`, its nodal averages
    /// sharpened by `sharpen` (0: not).
    MpmcgDomain {
        alpha: Alpha,
        lp: [f64; D],
        sharpen: f64,
    },
}

/// Wrap a node index on the periodic axes into `0..cells`.
pub fn wrap_node<const D: usize>(geom: &Geom<D>, node: [i64; D]) -> [i64; D] {
    std::array::from_fn(|a| {
        if geom.periodic[a] {
            node[a].rem_euclid(geom.cells[a] as i64)
        } else {
            node[a]
        }
    })
}

/// 1D hat function of node `g` along axis `a` at coordinate `y`.
fn hat<const D: usize>(geom: &Geom<D>, a: usize, g: i64, y: f64) -> f64 {
    let xg = geom.lower[a] + g as f64 * geom.h[a];
    (1.0 - (y - xg).abs() / geom.h[a]).max(0.0)
}

/// Derivative of the 1D hat of node `g` at `y`, taken inside cell `c` (one-sided at a
/// node: the gradient of standard MPM belongs to the cell that holds the point).
fn hat_slope<const D: usize>(geom: &Geom<D>, a: usize, g: i64, c: i64) -> f64 {
    if g == c {
        -geom.inv_h[a]
    } else if g == c + 1 {
        geom.inv_h[a]
    } else {
        0.0
    }
}

/// Does node `g` exist along axis `a`?
fn exists<const D: usize>(geom: &Geom<D>, a: usize, g: i64) -> bool {
    geom.periodic[a] || (0..=geom.cells[a] as i64).contains(&g)
}

/// Cell holding `x` (unwrapped on periodic axes; clamped into the grid on bounded ones,
/// so that the upper face belongs to the last cell) and the local coordinate ξ in it.
pub fn cell_of<const D: usize>(geom: &Geom<D>, x: &[f64; D]) -> ([i64; D], [f64; D]) {
    let mut c = [0i64; D];
    let mut xi = [0.0; D];
    for a in 0..D {
        let s = (x[a] - geom.lower[a]) / geom.h[a];
        let mut i = s.floor() as i64;
        if !geom.periodic[a] {
            i = i.clamp(0, geom.cells[a] as i64 - 1);
        }
        c[a] = i;
        xi[a] = s - i as f64;
    }
    (c, xi)
}

/// All `(node, offset)` pairs of a box `lo + {0..n}^D`.
fn box_nodes<const D: usize>(lo: [i64; D], n: usize) -> Vec<[i64; D]> {
    let total = n.pow(D as u32);
    (0..total)
        .map(|k| {
            let mut r = k;
            std::array::from_fn(|a| {
                let o = (r % n) as i64;
                r /= n;
                lo[a] + o
            })
        })
        .collect()
}

/// Linear shape functions at `x`: `(node, S_i(x), ∇S_i(x))` for the corners of the
/// cell holding `x`.
pub fn linear_shape<const D: usize>(
    geom: &Geom<D>,
    x: &[f64; D],
) -> Vec<([i64; D], f64, [f64; D])> {
    let (c, _) = cell_of(geom, x);
    box_nodes(c, 2)
        .into_iter()
        .map(|node| {
            let s: f64 = (0..D).map(|a| hat(geom, a, node[a], x[a])).product();
            let g = std::array::from_fn(|d| {
                let mut p = hat_slope(geom, d, node[d], c[d]);
                for e in 0..D {
                    if e != d {
                        p *= hat(geom, e, node[e], x[e]);
                    }
                }
                p
            });
            (node, s, g)
        })
        .collect()
}

/// Antiderivative of the unit hat `max(0, 1 − |t|)`.
fn hat_primitive(t: f64) -> f64 {
    if t <= -1.0 {
        0.0
    } else if t <= 0.0 {
        0.5 * (t + 1.0) * (t + 1.0)
    } else if t <= 1.0 {
        1.0 - 0.5 * (1.0 - t) * (1.0 - t)
    } else {
        1.0
    }
}

/// uGIMP shape functions at `x` for particle half-widths `lp`: per axis
/// `s_i = (1/2l) ∫_{x−l}^{x+l} N_i(y) dy` and `s_i' = (N_i(x+l) − N_i(x−l)) / 2l`,
/// the average of `N_i` and `N_i'` over the particle domain.
///
/// On a bounded axis the domain is kept inside the grid, `l = min(lp, x − lower,
/// upper − x)`, as [`crate::physics::shape::gimp`] does: outside the grid there are no nodes,
/// and a domain reaching out would lose the outside node's share (see
/// [`gimp_shape_truncated`]). Below `l = 10⁻³ h` (where the difference of primitives
/// below loses digits) the averages are taken as the hat function and its slope at `x`:
/// exact, since such a domain lies in one cell, where the hats are linear.
pub fn gimp_shape<const D: usize>(
    geom: &Geom<D>,
    x: &[f64; D],
    lp: &[f64; D],
) -> Vec<([i64; D], f64, [f64; D])> {
    let l: [f64; D] = std::array::from_fn(|a| {
        if geom.periodic[a] {
            lp[a]
        } else {
            lp[a].min(x[a] - geom.lower[a]).min(geom.upper[a] - x[a])
        }
    });
    gimp_shape_truncated(geom, x, &l)
}

/// uGIMP with the particle domain `[x − lp, x + lp]` as given, even where it reaches
/// outside a bounded grid: the outside nodes do not exist and are left out, so there
/// `Σ_i S_i = 1 − S_outside < 1` and neither identity holds. This was `shape::gimp`
/// before the domain was kept inside the grid.
pub fn gimp_shape_truncated<const D: usize>(
    geom: &Geom<D>,
    x: &[f64; D],
    lp: &[f64; D],
) -> Vec<([i64; D], f64, [f64; D])> {
    let (c, _) = cell_of(geom, x);
    let mut lo = [0i64; D];
    let mut w1: Vec<Vec<(f64, f64)>> = Vec::with_capacity(D);
    for a in 0..D {
        let (h, l) = (geom.h[a], lp[a]);
        // Every node within h + l of x (the cell's nodes for a tiny l).
        lo[a] = if l >= 1e-3 * h {
            ((x[a] - l - geom.lower[a]) / h).floor() as i64
        } else {
            c[a]
        };
        let mut v = Vec::new();
        for g in lo[a]..lo[a] + 4 {
            let xg = geom.lower[a] + g as f64 * h;
            let (s, ds) = if l >= 1e-3 * h {
                (
                    h * (hat_primitive((x[a] + l - xg) / h) - hat_primitive((x[a] - l - xg) / h))
                        / (2.0 * l),
                    (hat(geom, a, g, x[a] + l) - hat(geom, a, g, x[a] - l)) / (2.0 * l),
                )
            } else {
                (hat(geom, a, g, x[a]), hat_slope(geom, a, g, c[a]))
            };
            v.push(if exists(geom, a, g) {
                (s, ds)
            } else {
                (0.0, 0.0)
            });
        }
        w1.push(v);
    }
    box_nodes([0; D], 4)
        .into_iter()
        .filter_map(|o| {
            let node: [i64; D] = std::array::from_fn(|a| lo[a] + o[a]);
            let w: [(f64, f64); D] = std::array::from_fn(|a| w1[a][o[a] as usize]);
            let s: f64 = w.iter().map(|p| p.0).product();
            let g: [f64; D] = std::array::from_fn(|d| {
                (0..D)
                    .map(|e| if e == d { w[e].1 } else { w[e].0 })
                    .product()
            });
            (s != 0.0 || g.iter().any(|&v| v != 0.0)).then_some((node, s, g))
        })
        .collect()
}

/// 2-point Gauss quadrature of `f` over one (unwrapped) cell.
fn cell_quadrature<const D: usize, const N: usize>(
    geom: &Geom<D>,
    cell: [i64; D],
    f: impl Fn(&[f64; D]) -> [f64; N],
) -> [f64; N] {
    let q = 0.5 / 3f64.sqrt();
    let wt: f64 = geom.h.iter().map(|h| 0.5 * h).product();
    let mut sum = [0.0; N];
    for o in box_nodes([0; D], 2) {
        let y: [f64; D] = std::array::from_fn(|a| {
            let t = if o[a] == 0 { 0.5 - q } else { 0.5 + q };
            geom.lower[a] + (cell[a] as f64 + t) * geom.h[a]
        });
        let v = f(&y);
        for k in 0..N {
            sum[k] += wt * v[k];
        }
    }
    sum
}

/// Cells (unwrapped) that contain both nodes `j` and `i`.
fn shared_cells<const D: usize>(j: [i64; D], i: [i64; D]) -> Vec<[i64; D]> {
    if (0..D).any(|a| (j[a] - i[a]).abs() > 1) {
        return Vec::new();
    }
    box_nodes(std::array::from_fn(|a| j[a].max(i[a]) - 1), 2)
        .into_iter()
        .filter(|c| (0..D).all(|a| c[a] <= j[a].min(i[a])))
        .collect()
}

/// `V_j = ∫_Ω w S_j dv` (w the cell weights of Ω).
pub fn node_volume<const D: usize>(geom: &Geom<D>, omega: &Domain<D>, j: [i64; D]) -> f64 {
    weighted_integral(geom, omega, shared_cells(j, j), |y| {
        (0..D).map(|a| hat(geom, a, j[a], y[a])).product()
    })
}

/// `Σ_c w_c ∫_c f dv` over those of `cells` that are in Ω.
fn weighted_integral<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    cells: Vec<[i64; D]>,
    f: impl Fn(&[f64; D]) -> f64,
) -> f64 {
    cells
        .into_iter()
        .filter(|&c| omega.contains(geom, c))
        .map(|c| omega.weight(geom, c) * cell_quadrature(geom, c, |y| [f(y)])[0])
        .sum()
}

/// `∫_Ω w S_j ∇S_i dv`.
pub fn integral<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    j: [i64; D],
    i: [i64; D],
) -> [f64; D] {
    let mut w = [0.0; D];
    for c in shared_cells(j, i) {
        if !omega.contains(geom, c) {
            continue;
        }
        let v: [f64; D] = cell_quadrature(geom, c, |y| {
            let sj: f64 = (0..D).map(|a| hat(geom, a, j[a], y[a])).product();
            std::array::from_fn(|d| {
                let mut p = sj * hat_slope(geom, d, i[d], c[d]);
                for e in 0..D {
                    if e != d {
                        p *= hat(geom, e, i[e], y[e]);
                    }
                }
                p
            })
        });
        let wc = omega.weight(geom, c);
        for d in 0..D {
            w[d] += wc * v[d];
        }
    }
    w
}

/// `∫_Ω w S_j S_k dv`, the consistent mass between nodes `j` and `k` (unit density).
pub fn mass_integral<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    j: [i64; D],
    k: [i64; D],
) -> f64 {
    weighted_integral(geom, omega, shared_cells(j, k), |y| {
        (0..D)
            .map(|a| hat(geom, a, j[a], y[a]) * hat(geom, a, k[a], y[a]))
            .product()
    })
}

/// The sharpening of nodal averages at node `j` (`[method] sharpen = β`): the nodes `k`
/// and weights `A_jk = (1 + β) δ_jk − β (1/V_j) ∫_Ω w S_j S_k dv` with which a sharpened
/// average is `Σ_k A_jk φ_k`; only `j` itself, with weight 1, when β = 0.
pub fn sharpening<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    j: [i64; D],
    beta: f64,
) -> Vec<([i64; D], f64)> {
    if beta == 0.0 {
        return vec![(j, 1.0)];
    }
    let vj = node_volume(geom, omega, j);
    box_nodes(std::array::from_fn(|a| j[a] - 1), 3)
        .into_iter()
        .filter(|k| (0..D).all(|a| exists(geom, a, k[a])))
        .map(|k| {
            let own = if k == j { 1.0 + beta } else { 0.0 };
            (k, own - beta * mass_integral(geom, omega, j, k) / vj)
        })
        .collect()
}

/// Standard MPM: `G_i = ∇S_i` on the cell holding `x`.
pub fn mpm<const D: usize>(geom: &Geom<D>, x: &[f64; D]) -> Vec<([i64; D], [f64; D])> {
    linear_shape(geom, x)
        .into_iter()
        .map(|(n, _, g)| (n, g))
        .collect()
}

/// uGIMP: `G_i = ∇S_i` of [`gimp_shape`].
pub fn gimp<const D: usize>(
    geom: &Geom<D>,
    x: &[f64; D],
    lp: &[f64; D],
) -> Vec<([i64; D], [f64; D])> {
    gimp_shape(geom, x, lp)
        .into_iter()
        .map(|(n, _, g)| (n, g))
        .collect()
}

/// The averaged gradient `~∇S_i(x) = Σ_j S_j(x) (1/V_j) ∫_Ω S_j ∇S_i dv`.
///
/// # Panics
/// If `x` is not in a cell of Ω (its nodes' `V_j` could vanish).
pub fn averaged<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
) -> Vec<([i64; D], [f64; D])> {
    averaged_sharpened(geom, omega, x, 0.0)
}

/// The averaged gradient with its nodal averages sharpened by β,
/// `Σ_j S_j(x) Σ_k A_jk (1/V_k) ∫_Ω S_k ∇S_i dv` ([`sharpening`]'s `A`).
///
/// # Panics
/// If `x` is not in a cell of Ω.
pub fn averaged_sharpened<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
    beta: f64,
) -> Vec<([i64; D], [f64; D])> {
    let (c, _) = cell_of(geom, x);
    assert!(
        omega.contains(geom, c),
        "point {x:?} is in cell {c:?}, outside Ω"
    );
    let mut acc: BTreeMap<[i64; D], [f64; D]> = BTreeMap::new();
    for (j, sj, _) in linear_shape(geom, x) {
        for (k, ajk) in sharpening(geom, omega, j, beta) {
            let vk = node_volume(geom, omega, k);
            if vk <= 0.0 {
                continue;
            }
            for i in box_nodes(std::array::from_fn(|a| k[a] - 1), 3) {
                if !(0..D).all(|a| exists(geom, a, i[a])) {
                    continue;
                }
                let w = integral(geom, omega, k, i);
                let e = acc.entry(i).or_insert([0.0; D]);
                for d in 0..D {
                    e[d] += sj * ajk / vk * w[d];
                }
            }
        }
    }
    acc.into_iter().collect()
}

/// MPMCG with any weight `α(ξ)` of the local cell coordinate:
/// `G_i = α ∇S_i + (1 − α) ~∇S_i`.
pub fn mpmcg_with<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
    alpha: impl Fn(&[f64; D]) -> f64,
) -> Vec<([i64; D], [f64; D])> {
    mpmcg_sharpened(geom, omega, x, alpha, 0.0)
}

/// [`mpmcg_with`] with the averaged part's nodal averages sharpened by β
/// ([`averaged_sharpened`]).
pub fn mpmcg_sharpened<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
    alpha: impl Fn(&[f64; D]) -> f64,
    beta: f64,
) -> Vec<([i64; D], [f64; D])> {
    let (_, xi) = cell_of(geom, x);
    let al = alpha(&xi);
    let mut acc: BTreeMap<[i64; D], [f64; D]> = BTreeMap::new();
    for (n, g) in averaged_sharpened(geom, omega, x, beta) {
        acc.insert(n, g.map(|v| (1.0 - al) * v));
    }
    for (n, g) in mpm(geom, x) {
        let e = acc.entry(n).or_insert([0.0; D]);
        for d in 0..D {
            e[d] += al * g[d];
        }
    }
    acc.into_iter().collect()
}

/// MPMCG with one of the solver's [`Alpha`] choices.
pub fn mpmcg<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
    alpha: Alpha,
) -> Vec<([i64; D], [f64; D])> {
    mpmcg_with(geom, omega, x, |xi| alpha.eval(xi))
}

/// Quadrature points `y` and weights `w` (summing to 1) over the box of half-widths `lp`
/// around `x` (each at most half a cell), cut at bounded grid faces: 3-point Gauss per
/// axis on each cell's piece of the box, exact for polynomials of degree 5 per axis
/// within a cell.
fn box_points<const D: usize>(geom: &Geom<D>, x: &[f64; D], lp: &[f64; D]) -> Vec<([f64; D], f64)> {
    const G: [(f64, f64); 3] = [
        (-0.774_596_669_241_483_4, 5.0 / 18.0),
        (0.0, 8.0 / 18.0),
        (0.774_596_669_241_483_4, 5.0 / 18.0),
    ];
    let axes: Vec<Vec<(f64, f64)>> = (0..D)
        .map(|a| {
            let r = lp[a].min(0.5 * geom.h[a]);
            let (mut lo, mut hi) = (x[a] - r, x[a] + r);
            if !geom.periodic[a] {
                lo = lo.max(geom.lower[a]);
                hi = hi.min(geom.upper[a]);
            }
            if hi <= lo {
                return vec![(x[a], 1.0)];
            }
            let face = geom.lower[a] + ((hi - geom.lower[a]) / geom.h[a]).floor() * geom.h[a];
            let cuts = if face > lo && face < hi {
                vec![(lo, face), (face, hi)]
            } else {
                vec![(lo, hi)]
            };
            cuts.into_iter()
                .flat_map(|(p0, p1)| {
                    G.map(|(g, w)| {
                        (
                            0.5 * (p0 + p1) + g * 0.5 * (p1 - p0),
                            w * (p1 - p0) / (hi - lo),
                        )
                    })
                })
                .collect()
        })
        .collect();
    let total: usize = axes.iter().map(Vec::len).product();
    (0..total)
        .map(|k| {
            let mut r = k;
            let mut y = [0.0; D];
            let mut w = 1.0;
            for a in 0..D {
                let (ya, wa) = axes[a][r % axes[a].len()];
                r /= axes[a].len();
                y[a] = ya;
                w *= wa;
            }
            (y, w)
        })
        .collect()
}

/// MPMCG under the domain rule: [`mpmcg`]'s gradient averaged over the box of
/// half-widths `lp` around `x` (each at most half a cell), cut at bounded grid faces,
/// by 3-point Gauss quadrature per axis on each cell's piece of the box: exact, as the
/// gradient is a polynomial of degree at most 3 per axis within a cell. Nodes are
/// unwrapped as seen from each quadrature point.
pub fn mpmcg_domain<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
    alpha: Alpha,
    (lp, beta): (&[f64; D], f64),
) -> Vec<([i64; D], [f64; D])> {
    let mut acc: BTreeMap<[i64; D], [f64; D]> = BTreeMap::new();
    for (y, w) in box_points(geom, x, lp) {
        for (n, g) in mpmcg_sharpened(geom, omega, &y, |xi| alpha.eval(xi), beta) {
            let e = acc.entry(n).or_insert([0.0; D]);
            for d in 0..D {
                e[d] += w * g[d];
            }
        }
    }
    acc.into_iter().collect()
}

/// `L̄_j = (1/V_j) Σ_i v_i ⊗ ∫_Ω w S_j ∇S_i dv` (row a, column b) from nodal velocities
/// `vel` (by unwrapped node); zero where `V_j` is not positive.
pub fn velocity_average<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    j: [i64; D],
    vel: impl Fn([i64; D]) -> [f64; D],
) -> [[f64; D]; D] {
    let vj = node_volume(geom, omega, j);
    let mut l = [[0.0; D]; D];
    if vj <= 0.0 {
        return l;
    }
    for i in box_nodes(std::array::from_fn(|a| j[a] - 1), 3) {
        if !(0..D).all(|a| exists(geom, a, i[a])) {
            continue;
        }
        let (w, v) = (integral(geom, omega, j, i), vel(i));
        for a in 0..D {
            for b in 0..D {
                l[a][b] += v[a] * w[b] / vj;
            }
        }
    }
    l
}

/// The velocity a two-step scheme moves a point `x` of Ω with, from nodal velocities
/// `vel` (by unwrapped node): `u(x) = Σ_j S_j(x) (v̄_j + L̄_j (x − x_j))` over the nodes
/// `j` of `x`'s cell, with `L̄_j` of [`velocity_average`] and
/// `v̄_j = (1/V_j) ∫_Ω w S_j (v_h(y) + L̄_j (x_j − y)) dy`, `v_h = Σ_i S_i v_i`. Grids
/// without walls (free or periodic faces): the solver also applies wall conditions to
/// `v̄_j`.
pub fn moving_velocity<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
    vel: impl Fn([i64; D]) -> [f64; D],
) -> [f64; D] {
    moving_velocity_sharpened(geom, omega, x, 0.0, vel)
}

/// [`moving_velocity`] with `L̄` sharpened by β in the term `L̄_j (x − x_j)`
/// ([`sharpening`]); `v̄_j` is formed with the plain `L̄_j`, as the solver forms it
/// before it sharpens.
pub fn moving_velocity_sharpened<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
    beta: f64,
    vel: impl Fn([i64; D]) -> [f64; D],
) -> [f64; D] {
    let mut u = [0.0; D];
    for (j, sj, _) in linear_shape(geom, x) {
        let vj = node_volume(geom, omega, j);
        let l = velocity_average(geom, omega, j, &vel);
        let xj = geom.node_position(j);
        let mut vbar = [0.0; D];
        for c in shared_cells(j, j) {
            if !omega.contains(geom, c) {
                continue;
            }
            let part: [f64; D] = cell_quadrature(geom, c, |y| {
                let s_j: f64 = (0..D).map(|a| hat(geom, a, j[a], y[a])).product();
                let mut vh = [0.0; D];
                for i in box_nodes(c, 2) {
                    let si: f64 = (0..D).map(|a| hat(geom, a, i[a], y[a])).product();
                    let v = vel(i);
                    (0..D).for_each(|a| vh[a] += si * v[a]);
                }
                std::array::from_fn(|a| {
                    let corr: f64 = (0..D).map(|b| l[a][b] * (xj[b] - y[b])).sum();
                    s_j * (vh[a] + corr)
                })
            });
            let wc = omega.weight(geom, c);
            (0..D).for_each(|a| vbar[a] += wc * part[a] / vj);
        }
        let mut ls = [[0.0; D]; D];
        for (k, ajk) in sharpening(geom, omega, j, beta) {
            let lk = if k == j {
                l
            } else {
                velocity_average(geom, omega, k, &vel)
            };
            for a in 0..D {
                for b in 0..D {
                    ls[a][b] += ajk * lk[a][b];
                }
            }
        }
        for a in 0..D {
            let lin: f64 = (0..D).map(|b| ls[a][b] * (x[b] - xj[b])).sum();
            u[a] += sj * (vbar[a] + lin);
        }
    }
    u
}

/// The velocity MPMCG under the domain rule moves a particle at `x` with: the average of
/// [`moving_velocity_sharpened`] over its domain, the box of half-widths `lp` cut at
/// bounded grid faces (the same box its gradient is averaged over).
pub fn moving_velocity_domain<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    x: &[f64; D],
    (lp, beta): (&[f64; D], f64),
    vel: impl Fn([i64; D]) -> [f64; D],
) -> [f64; D] {
    let mut u = [0.0; D];
    for (y, w) in box_points(geom, x, lp) {
        let uy = moving_velocity_sharpened(geom, omega, &y, beta, &vel);
        (0..D).for_each(|a| u[a] += w * uy[a]);
    }
    u
}

/// `G_i(x)` of `scheme` at `x`, as (global unwrapped node index, G) pairs. Ω matters
/// only for `averaged` and `mpmcg`, which need `x` in a cell of Ω.
pub fn gradient<const D: usize>(
    geom: &Geom<D>,
    omega: &Domain<D>,
    scheme: Scheme<D>,
    x: &[f64; D],
) -> Vec<([i64; D], [f64; D])> {
    match scheme {
        Scheme::Mpm => mpm(geom, x),
        Scheme::Gimp { lp } => gimp(geom, x, &lp),
        Scheme::Averaged => averaged(geom, omega, x),
        Scheme::Mpmcg(alpha) => mpmcg(geom, omega, x, alpha),
        Scheme::MpmcgSharpened { alpha, sharpen } => {
            mpmcg_sharpened(geom, omega, x, |xi| alpha.eval(xi), sharpen)
        }
        Scheme::MpmcgDomain { alpha, lp, sharpen } => {
            mpmcg_domain(geom, omega, x, alpha, (&lp, sharpen))
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::mpm::solver::cell_integral;

    type Pairs<const D: usize> = Vec<([i64; D], [f64; D])>;

    /// Also used by the solver's tests.
    pub(crate) use decomposition::splitmix::Rng;

    /// A grid with non-square cells, 3 to 6 cells per axis, each axis periodic with
    /// probability 1/3 if `periodic`.
    fn random_geom<const D: usize>(rng: &mut Rng, periodic: bool) -> Geom<D> {
        let lower: [f64; D] = std::array::from_fn(|_| 4.0 * rng.f64() - 2.0);
        let cells: [usize; D] = std::array::from_fn(|_| 3 + rng.below(4));
        let upper: [f64; D] =
            std::array::from_fn(|a| lower[a] + cells[a] as f64 * (0.3 + 1.7 * rng.f64()));
        let per: [bool; D] = std::array::from_fn(|_| periodic && rng.below(3) == 0);
        Geom::new(lower, upper, cells, per)
    }

    /// A random cell, half the time one touching a grid face.
    fn random_cell<const D: usize>(rng: &mut Rng, geom: &Geom<D>) -> [i64; D] {
        let mut c: [i64; D] = std::array::from_fn(|a| rng.below(geom.cells[a]) as i64);
        if rng.below(2) == 0 {
            let a = rng.below(D);
            c[a] = if rng.below(2) == 0 {
                0
            } else {
                geom.cells[a] as i64 - 1
            };
        }
        c
    }

    fn point_in<const D: usize>(rng: &mut Rng, geom: &Geom<D>, c: [i64; D]) -> [f64; D] {
        std::array::from_fn(|a| geom.lower[a] + (c[a] as f64 + rng.f64()) * geom.h[a])
    }

    /// Σ_i G_i = 0 and Σ_i x_i ⊗ G_i = I to round-off; returns the worst relative errors.
    fn identities<const D: usize>(geom: &Geom<D>, g: &Pairs<D>) -> (f64, f64) {
        let mut sum = [0.0; D];
        let mut mom = [[0.0; D]; D];
        let mut scale = 0.0f64;
        let mut mscale = 0.0f64;
        for (n, gi) in g {
            let xi = geom.node_position(*n);
            for a in 0..D {
                sum[a] += gi[a];
                scale += gi[a].abs();
                for b in 0..D {
                    mom[a][b] += xi[a] * gi[b];
                    mscale += (xi[a] * gi[b]).abs();
                }
            }
        }
        let e0 = sum.iter().map(|v| v.abs()).fold(0.0, f64::max) / scale;
        let mut e1 = 0.0f64;
        for (a, row) in mom.iter().enumerate() {
            for (b, m) in row.iter().enumerate() {
                let id = if a == b { 1.0 } else { 0.0 };
                e1 = e1.max((m - id).abs());
            }
        }
        (e0, e1 / mscale.max(1.0))
    }

    const ROUND_OFF: f64 = 1e-13;

    fn schemes<const D: usize>(geom: &Geom<D>, ppc: usize) -> [Scheme<D>; 7] {
        let lp = std::array::from_fn(|a| 0.5 * geom.h[a] / ppc as f64);
        // A stretched domain, clamped at half a cell along the first axis.
        let stretched = std::array::from_fn(|a| lp[a] * [2.7, 1.3, 0.6][a]);
        [
            Scheme::Mpm,
            Scheme::Gimp { lp },
            Scheme::Averaged,
            Scheme::Mpmcg(Alpha::ProductOfShapes),
            Scheme::MpmcgSharpened {
                alpha: Alpha::ProductOfShapes,
                sharpen: 2.0,
            },
            Scheme::MpmcgDomain {
                alpha: Alpha::ProductOfShapes,
                lp: stretched,
                sharpen: 0.0,
            },
            Scheme::MpmcgDomain {
                alpha: Alpha::ProductOfShapes,
                lp: stretched,
                sharpen: 2.0,
            },
        ]
    }

    /// The identities `Σ_i G_i = 0` and `Σ_i x_i ⊗ G_i = I` at 200 random points per
    /// scheme (MPMCG sharpened too), many in cells on the grid boundary, on grids with non-square cells and
    /// some periodic axes. GIMP included: its particle domain is kept inside the grid
    /// (the truncated variant fails there, see `gimp_truncation_breaks_partition_of_unity`).
    fn check_identities<const D: usize>(seed: u64) {
        let mut rng = Rng(seed);
        let mut worst = [(0.0f64, 0.0f64); 7];
        let mut boundary_points = 0;
        for _ in 0..20 {
            let geom = random_geom::<D>(&mut rng, true);
            let ppc = 1 + rng.below(4);
            for (k, scheme) in schemes(&geom, ppc).into_iter().enumerate() {
                // The domain rule sharpened sums 27 × 27 reference gradients a point in
                // 3D: fewer points there keep the test to a second.
                let points = if D == 3 && k == 6 { 2 } else { 10 };
                for _ in 0..points {
                    let c = random_cell(&mut rng, &geom);
                    let x = point_in(&mut rng, &geom, c);
                    if (0..D).any(|a| c[a] == 0 || c[a] == geom.cells[a] as i64 - 1) {
                        boundary_points += 1;
                    }
                    let g = gradient(&geom, &Domain::All, scheme, &x);
                    let (e0, e1) = identities(&geom, &g);
                    assert!(
                        e0 < ROUND_OFF && e1 < ROUND_OFF,
                        "{scheme:?} D={D} at {x:?}: |ΣG| = {e0:e}, |Σx⊗G − I| = {e1:e}"
                    );
                    worst[k] = (worst[k].0.max(e0), worst[k].1.max(e1));
                }
            }
        }
        assert!(
            boundary_points > 375,
            "only {boundary_points} points in boundary cells"
        );
        eprintln!(
            "D={D}: worst (ΣG, Σx⊗G − I) per scheme mpm/gimp/averaged/mpmcg/mpmcg sharpened/domain/domain sharpened: {worst:?}"
        );
    }

    #[test]
    fn identities_1d() {
        check_identities::<1>(1);
    }

    #[test]
    fn identities_2d() {
        check_identities::<2>(2);
    }

    #[test]
    fn identities_3d() {
        check_identities::<3>(3);
    }

    /// Near a bounded face a GIMP particle domain of the nominal width reaches outside
    /// the grid, where there are no nodes: the truncated weights lose the outside
    /// node's share and neither identity holds. Keeping the domain inside the grid
    /// (`gimp_shape`, `shape::gimp`) restores both, also exactly on the boundary.
    #[test]
    fn gimp_truncation_breaks_partition_of_unity() {
        let geom = Geom::<1>::new([0.0], [1.0], [4], [false]);
        let lp = [0.0625];
        let sum = |r: &Vec<([i64; 1], f64, [f64; 1])>| r.iter().map(|p| p.1).sum::<f64>();
        // Half a particle width outside the lower face: 1 − (share of the outside node),
        // with the share q²/4hl of GIMP's outer branch, q = l/2.
        let x = [0.03125];
        let s = sum(&gimp_shape_truncated(&geom, &x, &lp));
        assert!(
            (s - (1.0 - 0.03125f64.powi(2) / (4.0 * 0.25 * 0.0625))).abs() < 1e-15,
            "Σ S = {s}"
        );
        let g: Pairs<1> = gimp_shape_truncated(&geom, &x, &lp)
            .into_iter()
            .map(|p| (p.0, p.2))
            .collect();
        let (e0, e1) = identities(&geom, &g);
        assert!(e0 > 1e-3 && e1 > 1e-3, "{e0:e} {e1:e}");
        for x in [
            0.0,
            1e-300,
            1e-12,
            0.01,
            0.03125,
            0.0624,
            0.5,
            0.97,
            1.0 - 1e-12,
            1.0,
        ] {
            let r = gimp_shape(&geom, &[x], &lp);
            let s = sum(&r);
            let first: f64 = r.iter().map(|p| p.1 * geom.node_position(p.0)[0]).sum();
            let g: Pairs<1> = r.into_iter().map(|p| (p.0, p.2)).collect();
            let (e0, e1) = identities(&geom, &g);
            assert!(
                (s - 1.0).abs() < 1e-15 && (first - x).abs() < 1e-15,
                "at {x}: Σ S = {s}, Σ S x_i = {first}"
            );
            assert!(e0 < ROUND_OFF && e1 < ROUND_OFF, "at {x}: {e0:e} {e1:e}");
        }
    }

    /// Same values at `x ± δ`, after wrapping periodic node indices: the largest
    /// difference in any node's gradient, and the largest gradient.
    fn jump<const D: usize>(geom: &Geom<D>, a: &Pairs<D>, b: &Pairs<D>) -> (f64, f64) {
        let mut m: BTreeMap<[i64; D], ([f64; D], [f64; D])> = BTreeMap::new();
        // Sum: on a periodic axis of 3 cells two unwrapped nodes can be the same node.
        for (n, g) in a {
            let e = m.entry(wrap_node(geom, *n)).or_insert(([0.0; D], [0.0; D]));
            (0..D).for_each(|k| e.0[k] += g[k]);
        }
        for (n, g) in b {
            let e = m.entry(wrap_node(geom, *n)).or_insert(([0.0; D], [0.0; D]));
            (0..D).for_each(|k| e.1[k] += g[k]);
        }
        let mut d = 0.0f64;
        let mut big = 0.0f64;
        for (ga, gb) in m.values() {
            for k in 0..D {
                d = d.max((ga[k] - gb[k]).abs());
                big = big.max(ga[k].abs()).max(gb[k].abs());
            }
        }
        (d, big)
    }

    /// MPMCG's (and the averaged, and GIMP's) gradient is continuous across cell faces,
    /// including a periodic seam; MPM's jumps by O(1/h).
    fn check_continuity<const D: usize>(seed: u64) {
        let mut rng = Rng(seed);
        let mut worst = [0.0f64; 3];
        for _ in 0..10 {
            let geom = random_geom::<D>(&mut rng, true);
            let lp: [f64; D] = std::array::from_fn(|a| 0.25 * geom.h[a]);
            for _ in 0..10 {
                let a = rng.below(D);
                let n = geom.cells[a];
                let k = if geom.periodic[a] {
                    rng.below(n)
                } else {
                    1 + rng.below(n - 1)
                };
                let c = random_cell(&mut rng, &geom);
                let mut x = point_in(&mut rng, &geom, c);
                x[a] = geom.lower[a] + k as f64 * geom.h[a];
                let del = 1e-9 * geom.h[a];
                let mut lo = x;
                let mut hi = x;
                lo[a] -= del;
                hi[a] += del;
                let om = Domain::All;
                let alpha = Alpha::ProductOfShapes;
                let (d, big) = jump(
                    &geom,
                    &mpmcg(&geom, &om, &lo, alpha),
                    &mpmcg(&geom, &om, &hi, alpha),
                );
                worst[0] = worst[0].max(d / big);
                assert!(
                    d < 1e-7 * big,
                    "MPMCG D={D} jumps by {d:e} (of {big:e}) at {x:?}, axis {a}"
                );
                let (d, big) = jump(
                    &geom,
                    &averaged(&geom, &om, &lo),
                    &averaged(&geom, &om, &hi),
                );
                worst[1] = worst[1].max(d / big);
                assert!(d < 1e-7 * big, "averaged D={D} jumps by {d:e} at {x:?}");
                let (d, big) = jump(&geom, &gimp(&geom, &lo, &lp), &gimp(&geom, &hi, &lp));
                worst[2] = worst[2].max(d / big);
                assert!(d < 1e-7 * big, "GIMP D={D} jumps by {d:e} at {x:?}");
                let (d, _) = jump(&geom, &mpm(&geom, &lo), &mpm(&geom, &hi));
                assert!(
                    d > 0.4 * geom.inv_h[a],
                    "MPM D={D} should jump at {x:?}: {d:e}"
                );
            }
        }
        eprintln!("D={D}: largest relative jump at faces ± 1e-9 h: mpmcg {:.1e}, averaged {:.1e}, gimp {:.1e}", worst[0], worst[1], worst[2]);
    }

    #[test]
    fn continuity_across_faces_1d() {
        check_continuity::<1>(11);
    }

    #[test]
    fn continuity_across_faces_2d() {
        check_continuity::<2>(12);
    }

    #[test]
    fn continuity_across_faces_3d() {
        check_continuity::<3>(13);
    }

    /// Largest difference between two sets of pairs (missing nodes count as zero).
    fn diff<const D: usize>(a: &Pairs<D>, b: &Pairs<D>) -> f64 {
        let mut m: BTreeMap<[i64; D], [f64; D]> = BTreeMap::new();
        for (n, g) in a {
            m.insert(*n, *g);
        }
        for (n, g) in b {
            let e = m.entry(*n).or_insert([0.0; D]);
            for k in 0..D {
                e[k] -= g[k];
            }
        }
        m.values()
            .flat_map(|v| v.iter())
            .map(|v| v.abs())
            .fold(0.0, f64::max)
    }

    fn check_alpha_limits<const D: usize>(seed: u64) {
        let mut rng = Rng(seed);
        for _ in 0..10 {
            let geom = random_geom::<D>(&mut rng, true);
            let om = Domain::All;
            let scale = geom.inv_h.iter().cloned().fold(0.0, f64::max);
            for _ in 0..10 {
                let c = random_cell(&mut rng, &geom);
                let x = point_in(&mut rng, &geom, c);
                let tol = 1e-15 * scale;
                assert!(
                    diff(
                        &mpmcg(&geom, &om, &x, Alpha::Constant(0.0)),
                        &averaged(&geom, &om, &x)
                    ) <= tol
                );
                assert!(
                    diff(
                        &mpmcg(&geom, &om, &x, Alpha::Constant(1.0)),
                        &mpm(&geom, &x)
                    ) <= tol
                );
                // The product of shapes is 1 at the cell centre and 0 on the faces (to the
                // round-off of the local coordinate ξ).
                let tol = 1e-13 * scale;
                let centre: [f64; D] =
                    std::array::from_fn(|a| geom.lower[a] + (c[a] as f64 + 0.5) * geom.h[a]);
                assert!(
                    diff(
                        &mpmcg(&geom, &om, &centre, Alpha::ProductOfShapes),
                        &mpm(&geom, &centre)
                    ) <= tol
                );
                let mut face = x;
                let a = rng.below(D);
                face[a] = geom.lower[a] + c[a] as f64 * geom.h[a];
                assert!(
                    diff(
                        &mpmcg(&geom, &om, &face, Alpha::ProductOfShapes),
                        &averaged(&geom, &om, &face)
                    ) <= tol
                );
            }
        }
    }

    #[test]
    fn mpmcg_alpha_limits() {
        check_alpha_limits::<1>(21);
        check_alpha_limits::<2>(22);
        check_alpha_limits::<3>(23);
    }

    /// In the 1D interior `~∇S_i(x) = (S_{i−1}(x) − S_{i+1}(x)) / 2h`.
    #[test]
    fn averaged_1d_interior_is_central_difference_of_shapes() {
        let mut rng = Rng(31);
        for periodic in [false, true] {
            let geom = Geom::<1>::new([-0.3], [1.7], [7], [periodic]);
            let h = geom.h[0];
            for _ in 0..200 {
                let c = if periodic {
                    rng.below(7)
                } else {
                    1 + rng.below(5)
                } as i64;
                let x = point_in(&mut rng, &geom, [c]);
                let s = |g: i64| hat(&geom, 0, g, x[0]);
                let expect: Pairs<1> = (c - 1..=c + 2)
                    .map(|i| ([i], [(s(i - 1) - s(i + 1)) / (2.0 * h)]))
                    .collect();
                let got = averaged(&geom, &Domain::All, &x);
                assert!(
                    diff(&got, &expect) < 1e-14 / h,
                    "at {x:?}: {got:?} vs {expect:?}"
                );
            }
        }
    }

    /// Nodes `i` of the grid (wrapped) and neighbours `j = i + dj`, |dj| <= 1.
    fn node_pairs<const D: usize>(geom: &Geom<D>) -> Vec<([i64; D], [i64; D])> {
        let top: [i64; D] =
            std::array::from_fn(|a| geom.cells[a] as i64 + i64::from(!geom.periodic[a]));
        let mut out = Vec::new();
        let counts: usize = top.iter().map(|&t| t as usize).product();
        for k in 0..counts {
            let mut r = k;
            let i: [i64; D] = std::array::from_fn(|a| {
                let v = (r % top[a] as usize) as i64;
                r /= top[a] as usize;
                v
            });
            for dj in box_nodes([-1; D], 3) {
                out.push((i, dj));
            }
        }
        out
    }

    /// The solver's cell-by-cell assembly over Ω: `Σ_{c ∈ Ω, c ∋ i, j} cell_integral`.
    fn assembled<const D: usize>(
        geom: &Geom<D>,
        omega: &Domain<D>,
        i: [i64; D],
        j: [i64; D],
    ) -> [f64; D] {
        let mut w = [0.0; D];
        for c in shared_cells(j, i) {
            if !omega.contains(geom, c) || !(0..D).all(|a| exists(geom, a, j[a])) {
                continue;
            }
            let corner = |n: [i64; D]| (0..D).map(|a| ((n[a] - c[a]) as usize) << a).sum::<usize>();
            let v = cell_integral::<D>(&geom.h, corner(j), corner(i));
            for d in 0..D {
                w[d] += v[d];
            }
        }
        w
    }

    /// Σ over cells of `solver::cell_integral` = closed-form `shape::grid_integral` =
    /// Gauss quadrature, for every node including end nodes and periodic seams.
    fn check_assembly<const D: usize>(seed: u64) {
        let mut rng = Rng(seed);
        for trial in 0..6 {
            let geom = random_geom::<D>(&mut rng, trial % 2 == 1);
            let scale: f64 =
                geom.h.iter().product::<f64>() * geom.inv_h.iter().cloned().fold(0.0, f64::max);
            for (i, dj) in node_pairs(&geom) {
                let j: [i64; D] = std::array::from_fn(|a| i[a] + dj[a]);
                let closed = crate::physics::shape::grid_integral(&geom, i, dj);
                let cells = assembled(&geom, &Domain::All, i, j);
                let quad = if (0..D).all(|a| exists(&geom, a, j[a])) {
                    integral(&geom, &Domain::All, j, i)
                } else {
                    [0.0; D]
                };
                for d in 0..D {
                    assert!(
                        (closed[d] - cells[d]).abs() < 1e-14 * scale && (closed[d] - quad[d]).abs() < 1e-14 * scale,
                        "D={D} i={i:?} dj={dj:?}: closed {closed:?}, cells {cells:?}, quadrature {quad:?} ({geom:?})"
                    );
                }
                if dj == [0; D] {
                    let v = node_volume(&geom, &Domain::All, i);
                    assert!((v - geom.node_volume(i)).abs() < 1e-14 * v);
                }
            }
        }
    }

    #[test]
    fn cell_assembly_equals_grid_integral() {
        check_assembly::<1>(41);
        check_assembly::<2>(42);
        check_assembly::<3>(43);
    }

    fn random_domain<const D: usize>(rng: &mut Rng, geom: &Geom<D>) -> (Domain<D>, Vec<[i64; D]>) {
        let mut set = BTreeSet::new();
        let total: usize = geom.cells.iter().product();
        while set.is_empty() {
            for k in 0..total {
                let mut r = k;
                let c: [i64; D] = std::array::from_fn(|a| {
                    let v = (r % geom.cells[a]) as i64;
                    r /= geom.cells[a];
                    v
                });
                if rng.below(10) < 6 {
                    set.insert(c);
                }
            }
        }
        let cells = set.iter().cloned().collect();
        (Domain::Cells(set), cells)
    }

    /// With Ω a random subset of cells, the identities hold at points in occupied cells,
    /// and the cell-by-cell assembly over Ω equals the quadrature over Ω.
    fn check_subdomain<const D: usize>(seed: u64) {
        let mut rng = Rng(seed);
        for _ in 0..10 {
            let geom = random_geom::<D>(&mut rng, true);
            let (om, cells) = random_domain(&mut rng, &geom);
            for _ in 0..20 {
                let c = cells[rng.below(cells.len())];
                let x = point_in(&mut rng, &geom, c);
                for scheme in [Scheme::Averaged, Scheme::Mpmcg(Alpha::ProductOfShapes)] {
                    let g = gradient(&geom, &om, scheme, &x);
                    let (e0, e1) = identities(&geom, &g);
                    assert!(
                        e0 < ROUND_OFF && e1 < ROUND_OFF,
                        "{scheme:?} D={D} Ω={om:?} at {x:?}: {e0:e} {e1:e}"
                    );
                }
            }
            let scale: f64 =
                geom.h.iter().product::<f64>() * geom.inv_h.iter().cloned().fold(0.0, f64::max);
            for (i, dj) in node_pairs(&geom) {
                let j: [i64; D] = std::array::from_fn(|a| i[a] + dj[a]);
                if !(0..D).all(|a| exists(&geom, a, j[a])) {
                    continue;
                }
                let (w, q) = (assembled(&geom, &om, i, j), integral(&geom, &om, j, i));
                for d in 0..D {
                    assert!(
                        (w[d] - q[d]).abs() < 1e-14 * scale,
                        "D={D} i={i:?} j={j:?}: {w:?} vs {q:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn identities_on_random_subdomains() {
        check_subdomain::<1>(51);
        check_subdomain::<2>(52);
        check_subdomain::<3>(53);
    }

    /// Particle clouds with free surfaces everywhere: one isolated particle, a cluster
    /// in a grid corner, and a random scatter over part of the grid, with random
    /// volumes. With the continuous domain built from them, the identities hold to
    /// round-off at every particle for `averaged` and `mpmcg`: the cell holding a
    /// particle always has weight > 0, so every node whose shape is non-zero there has
    /// `V_j > 0`.
    fn check_particle_domains<const D: usize>(seed: u64) {
        let mut rng = Rng(seed);
        let mut points = 0;
        for case in 0..30 {
            let geom = random_geom::<D>(&mut rng, true);
            let n = [1, 3, 2 + rng.below(12)][case % 3];
            let x: Vec<[f64; D]> = (0..n)
                .map(|_| match case % 3 {
                    // Near the lower corner of the grid.
                    1 => std::array::from_fn(|a| geom.lower[a] + 0.9 * geom.h[a] * rng.f64()),
                    _ => {
                        let c = random_cell(&mut rng, &geom);
                        point_in(&mut rng, &geom, c)
                    }
                })
                .collect();
            let vol: Vec<f64> = (0..n)
                .map(|_| geom.cell_volume() * (0.05 + 0.5 * rng.f64()))
                .collect();
            let om = Domain::from_particles(&geom, &x, &vol, crate::mpm::solver::FULL_FILL);
            for xp in &x {
                for scheme in [Scheme::Averaged, Scheme::Mpmcg(Alpha::ProductOfShapes)] {
                    let g = gradient(&geom, &om, scheme, xp);
                    let (e0, e1) = identities(&geom, &g);
                    assert!(
                        e0 < ROUND_OFF && e1 < ROUND_OFF,
                        "{scheme:?} D={D} {n} particles, at {xp:?}: {e0:e} {e1:e}"
                    );
                    points += 1;
                }
            }
        }
        assert!(points >= 60);
    }

    #[test]
    fn identities_at_free_surfaces_and_isolated_particles() {
        check_particle_domains::<1>(61);
        check_particle_domains::<2>(62);
        check_particle_domains::<3>(63);
    }

    /// A regular lattice of `ppc` particles per cell and axis filling the grid covers
    /// every node fully: every cell weighs 1, the domain of all cells (the closed forms
    /// of the whole grid), so interior results are those of `w ≡ 1`.
    #[test]
    fn full_lattice_weighs_one_everywhere() {
        fn check<const D: usize>(seed: u64) {
            let mut rng = Rng(seed);
            for _ in 0..5 {
                let geom = random_geom::<D>(&mut rng, true);
                let ppc = 1 + rng.below(4);
                let per_axis: [usize; D] = std::array::from_fn(|a| geom.cells[a] * ppc);
                let total: usize = per_axis.iter().product();
                let x: Vec<[f64; D]> = (0..total)
                    .map(|k| {
                        let mut r = k;
                        std::array::from_fn(|a| {
                            let i = r % per_axis[a];
                            r /= per_axis[a];
                            geom.lower[a] + (i as f64 + 0.5) * geom.h[a] / ppc as f64
                        })
                    })
                    .collect();
                let vol = vec![geom.cell_volume() / (ppc.pow(D as u32)) as f64; total];
                let Domain::Weighted(w) =
                    Domain::from_particles(&geom, &x, &vol, crate::mpm::solver::FULL_FILL)
                else {
                    unreachable!()
                };
                let cells: usize = geom.cells.iter().product();
                assert_eq!(w.len(), cells, "D={D} ppc={ppc}");
                for (c, v) in &w {
                    assert!((v - 1.0).abs() < 1e-12, "D={D} ppc={ppc} cell {c:?}: {v}");
                }
            }
        }
        check::<1>(71);
        check::<2>(72);
        check::<3>(73);
    }

    /// Pairs of a production [`crate::physics::shape::Weights1`] stencil (S, ∇S).
    fn stencil_pairs<const D: usize>(
        w: &crate::physics::shape::Weights1<D>,
    ) -> (Pairs<D>, Pairs<D>) {
        let st = w.stencil();
        let mut s = Vec::new();
        let mut g = Vec::new();
        for k in 0..st.count {
            let n: [i64; D] = std::array::from_fn(|a| w.base[a] + i64::from(st.off[k][a]));
            let mut sv = [0.0; D];
            sv[0] = st.s[k];
            s.push((n, sv));
            g.push((n, st.g[k]));
        }
        (s, g)
    }

    fn split<const D: usize>(r: Vec<([i64; D], f64, [f64; D])>) -> (Pairs<D>, Pairs<D>) {
        let s = r
            .iter()
            .map(|(n, s, _)| {
                let mut v = [0.0; D];
                v[0] = *s;
                (*n, v)
            })
            .collect();
        (s, r.into_iter().map(|(n, _, g)| (n, g)).collect())
    }

    /// The production per-particle stencils (`shape::linear`, `shape::gimp`) agree with
    /// the reference, also for GIMP particles sticking out of a bounded grid (both leave
    /// the outside node out).
    fn check_production_stencils<const D: usize>(seed: u64) {
        let mut rng = Rng(seed);
        for _ in 0..10 {
            let geom = random_geom::<D>(&mut rng, true);
            let ppc = 1 + rng.below(4);
            let lp: [f64; D] = std::array::from_fn(|a| 0.5 * geom.h[a] / ppc as f64);
            let scale = geom.inv_h.iter().cloned().fold(0.0, f64::max);
            for _ in 0..20 {
                let c = random_cell(&mut rng, &geom);
                let mut x = point_in(&mut rng, &geom, c);
                // Now and then exactly on a bounded face.
                let a = rng.below(D);
                if !geom.periodic[a] && rng.below(4) == 0 {
                    x[a] = if rng.below(2) == 0 {
                        geom.lower[a]
                    } else {
                        geom.upper[a]
                    };
                }
                let (s0, g0) = stencil_pairs(&crate::physics::shape::linear(&geom, &x));
                let (s1, g1) = split(linear_shape(&geom, &x));
                assert!(
                    diff(&s0, &s1) < 1e-14 && diff(&g0, &g1) < 1e-14 * scale,
                    "linear at {x:?}"
                );
                let (s0, g0) = stencil_pairs(&crate::physics::shape::gimp(&geom, &x, &lp));
                let (s1, g1) = split(gimp_shape(&geom, &x, &lp));
                assert!(
                    diff(&s0, &s1) < 1e-13 && diff(&g0, &g1) < 1e-13 * scale,
                    "gimp at {x:?} lp {lp:?}: {s0:?} {g0:?} vs {s1:?} {g1:?}"
                );
            }
        }
    }

    #[test]
    fn production_stencils_match_reference() {
        check_production_stencils::<1>(61);
        check_production_stencils::<2>(62);
        check_production_stencils::<3>(63);
    }
}
