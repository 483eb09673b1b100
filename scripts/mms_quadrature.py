#!/usr/bin/env python3
"""A model of mpmcg's MPMCG step on the axis-aligned manufactured solution in 1D and
2D, to try quadratures of the internal force before building them into the solver.

It follows the solver's definitions for `inputs/axis_aligned_mms_1d.toml` and
`inputs/axis_aligned_mms_2d.toml` (USL, FLIP, slip faces, neo-Hookean in plane strain,
CFL 0.2 on each particle's wave speed at its J plus its speed, the force and the
velocity gradient by MPMCG's two local steps, particles moved by the reconstruction
`Σ_j S_j (v̄_j + L̄_j (x − x_j))`, the error as the solver's volume-weighted L2 norm,
its maximum over the run); with its defaults it reproduces `mpmcg sweep` on those
scenes (docs/verification.md has the comparison). Whole-body cell weights are 1 (the
body fills the grid), as the solver's are on this problem.

Quadratures of `Σ_p v_p σ_p G_i` (and, adjoint, of the velocity gradient):
  point   at the particle (the solver's default);
  gaussK  K Gauss-Legendre points per axis over the particle's current domain;
  domain  per axis the domain split at the cell face inside it, two Gauss points on
          each piece: exact for MPMCG's integrands (piecewise cubic per axis), i.e.
          the domain's integral of G_i with the stress constant over it.
The domain is the box of half-widths `l0 |F e_a|` around the particle (`l0` half the
particle spacing), so it follows the stretch along each axis.
`--mass domain` puts the mass, momentum, body force and the FLIP increment on the
same domain (the domain's averages of the hat functions); the move stays the
reconstruction at the particle. The solver's `quadrature = "domain"` is
`--quadrature domain --mass domain`.
Velocity steps: `own` advances the velocity by each step's own size, `centred` (the
solver) by the mean of this step's and the last, half on the first (leapfrog with
variable steps). `--dt-cells X` replaces the CFL step by the fixed step X / cells (CFL
0.2 starts at about 1.7e-3 / cells in 1D), to separate the errors of space and time.
`--stress linear` (1D, with a quadrature over the domain) takes each particle's stress as
linear over its domain, `σ_p + σ'_p (x − x_p)`, with `σ'_p` the hat gradient at the
particle of the stresses' nodal averages (`Σ_p V_p σ_p N_i / Σ_p V_p N_i`), instead of
constant (the solver); only the force sees the slope, the velocity gradient is as before.
`--momentum affine` (with `--mass domain`) takes each particle's velocity as affine over
its domain in the transfer to the grid, `v_p + L_p (x − x_p)` with its velocity gradient
of the last step (APIC's idea on the domain), instead of constant (the solver).

Run with the system Python (it needs numpy):
  /usr/bin/python3 scripts/mms_quadrature.py --dim 1 --ppc 2 --quadrature domain \
      --mass domain --cells 16,32,64,128,256,512
"""
import argparse
import itertools

import numpy as np

A, C, E, NU, RHO = 0.05, 100.0, 1e4, 0.3, 1.0
LAM = E * NU / ((1 + NU) * (1 - 2 * NU))
MU = E / (2 * (1 + NU))
END = 0.02  # one period
PHASE = np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3])


def exact(x0, t):
    """Displacement and velocity at reference positions x0 (N × D)."""
    d = x0.shape[1]
    s = A * np.sin(np.pi * x0)
    w = C * np.pi * t + PHASE[:d]
    return s * np.sin(w), s * C * np.pi * np.cos(w)


def body_force(x0, t):
    d = x0.shape[1]
    w = C * np.pi * t + PHASE[:d]
    u = A * np.sin(np.pi * x0) * np.sin(w)
    f = 1 + A * np.pi * np.cos(np.pi * x0) * np.sin(w)
    lnj = np.log(np.prod(f, axis=1))[:, None]
    return np.pi**2 * u * (MU / RHO - C * C - (LAM * (lnj - 1) - MU) / (RHO * f * f))


def stress(f):
    """Cauchy stress of F (N × D × D), neo-Hookean, plane strain in 2D."""
    j = np.linalg.det(f)
    b = f @ np.swapaxes(f, 1, 2)
    eye = np.eye(f.shape[1])
    return (MU * b + (LAM * np.log(j) - MU)[:, None, None] * eye) / j[:, None, None]


def signal(f):
    j = np.linalg.det(f)
    return np.sqrt(np.maximum(LAM + 2 * (MU - LAM * np.log(j)), LAM + 2 * MU) / RHO)


def axis_points(x, half, h, quadrature):
    """Per axis: (position, weight) pairs over [x − half, x + half] (arrays of N)."""
    top = 1 - 1e-15
    if quadrature == "point":
        return [(x, np.ones_like(x))]
    if quadrature.startswith("gauss"):
        g, w = np.polynomial.legendre.leggauss(int(quadrature[5:]))
        return [(np.clip(x + gk * half, 0, top), np.full_like(x, wk / 2)) for gk, wk in zip(g, w)]
    lo, hi = np.clip(x - half, 0, 1), np.clip(x + half, 0, 1)
    face = np.floor(hi / h) * h
    cut = np.where((face > lo) & (face < hi), face, hi)
    out = []
    for a, b in ((lo, cut), (cut, hi)):
        mid, rad = (a + b) / 2, (b - a) / 2
        for g in (-1 / np.sqrt(3), 1 / np.sqrt(3)):
            out.append((np.clip(mid + g * rad, 0, top), rad / (hi - lo)))
    return out


class Grid:
    """Nodes (n + 1)^D of the unit box; node arrays are shaped (n + 1,) * D."""

    def __init__(self, n, d):
        self.n, self.d, self.h = n, d, 1.0 / n
        h, m = self.h, n + 1
        # 1D ∫ N_j N_i (mass) and ∫ N_j N_i' (gradient), [j, i], and ∫ N_j.
        self.mass1 = np.diag(np.full(m, 2 * h / 3)) + np.diag(np.full(n, h / 6), 1) \
            + np.diag(np.full(n, h / 6), -1)
        self.mass1[0, 0] = self.mass1[-1, -1] = h / 3
        self.grad1 = np.diag(np.full(n, 0.5), 1) - np.diag(np.full(n, 0.5), -1)
        self.grad1[0, 0], self.grad1[-1, -1] = -0.5, 0.5
        self.vol1 = np.full(m, h)
        self.vol1[[0, -1]] = h / 2
        # ∫ N_j (x_j − y) dy: zero inside, ∓h²/6 at the two ends.
        self.moment1 = np.zeros(m)
        self.moment1[0], self.moment1[-1] = -h * h / 6, h * h / 6
        self.node_vol = self.outer([self.vol1] * d)
        # ∫ S_j (x_j − y)_c dy per axis c, for the smoothed velocity v̄.
        self.moment = [self.outer([self.moment1 if e == c else self.vol1 for e in range(d)])
                       for c in range(d)]

    def outer(self, vecs):
        out = vecs[0]
        for v in vecs[1:]:
            out = np.multiply.outer(out, v)
        return out

    def apply(self, field, mats):
        """Σ_j field[j] Π_a mats[a][j_a, i_a], per node i."""
        for a, k in enumerate(mats):
            field = np.moveaxis(np.tensordot(field, k, axes=([a], [0])), -1, a)
        return field

    def kernel(self, b):
        """The 1D factors of ∫ S_j ∂_b S_i dv."""
        return [self.grad1 if a == b else self.mass1 for a in range(self.d)]

    def scatter(self, cell, xi, values):
        """Add values (N × K) at each particle's 2^D nodes with hat weights: (K,) + nodes."""
        d, m = self.d, self.n + 1
        out = np.zeros((values.shape[1], m**d))
        for idx, w, _ in self.corners(cell, xi):
            for k in range(values.shape[1]):
                out[k] += np.bincount(idx, w * values[:, k], m**d)
        return out.reshape((values.shape[1],) + (m,) * d)

    def corners(self, cell, xi):
        """Per corner: flat node index, hat weight and hat gradient (N × D)."""
        d, m, h = self.d, self.n + 1, self.h
        for corner in itertools.product((0, 1), repeat=d):
            w = np.ones(len(xi))
            idx = np.zeros(len(xi), dtype=int)
            per = []
            for a, o in enumerate(corner):
                per.append(xi[:, a] if o else 1 - xi[:, a])
                idx = idx * m + cell[:, a] + o
            for p in per:
                w = w * p
            g = np.empty_like(xi)
            for b, o in enumerate(corner):
                gb = np.full(len(xi), (1.0 if o else -1.0) / h)
                for a in range(d):
                    if a != b:
                        gb = gb * per[a]
                g[:, b] = gb
            yield idx, w, g


def locate(x, h, n):
    cell = np.minimum(np.floor(x / h).astype(int), n - 1)
    xi = x / h - cell
    return cell, xi, np.prod(4 * xi * (1 - xi), axis=1)


def run(d, n, ppc, quadrature, kick, dt_cells=0.0, linear=False, affine=False):
    g = Grid(n, d)
    h, m = g.h, n + 1
    ax = (np.arange(n * ppc) + 0.5) / (n * ppc)
    x0 = np.stack([c.ravel() for c in np.meshgrid(*([ax] * d), indexing="ij")], axis=1)
    vol0 = (1.0 / (n * ppc)) ** d
    mass = RHO * vol0
    l0 = 0.5 / (n * ppc)
    # The exact state at t = 0 (in 2D the second axis starts displaced and strained).
    u, v = exact(x0, 0.0)
    x = x0 + u
    stretch = 1 + A * np.pi * np.cos(np.pi * x0) * np.sin(PHASE[:d])
    f = np.einsum("na,ab->nab", stretch, np.eye(d))
    t, dt_last = 0.0, None
    # The velocity gradient of the last step (at t = 0 the exact one), for --momentum affine.
    lprev = np.einsum("na,ab->nab", A * np.pi * np.cos(np.pi * x0) * C * np.pi * np.cos(PHASE[:d]),
                      np.eye(d))
    worst = np.zeros(3)
    while t < END - 1e-14:
        vol = np.linalg.det(f) * vol0
        sig = stress(f)
        cfl = 0.2 * h / np.max(signal(f) + np.linalg.norm(v, axis=1))
        dt = min(dt_cells / n if dt_cells else cfl, END - t)
        dtv = dt if kick == "own" else (0.5 * dt if dt_last is None else 0.5 * (dt_last + dt))
        dt_last = dt
        cell, xi, _ = locate(x, h, n)
        b = body_force(x0, t)
        half = l0 * np.linalg.norm(f, axis=1)  # |F e_a| per axis
        per_axis = [axis_points(x[:, a], half[:, a], h, quadrature) for a in range(d)]
        vals = np.column_stack([np.full(len(x), mass), mass * v, mass * b])
        if MASS == "point":
            rec = g.scatter(cell, xi, vals)
        else:
            rec = 0
            for combo in itertools.product(*per_axis):
                xq = np.stack([c[0] for c in combo], axis=1)
                wq = np.prod(np.stack([c[1] for c in combo], axis=1), axis=1)
                cq, xiq, al = locate(xq, h, n)
                vq = vals
                if affine:
                    va = v + np.einsum("nab,nb->na", lprev, xq - x)
                    vq = np.column_stack([np.full(len(x), mass), mass * va, mass * b])
                rec = rec + g.scatter(cq, xiq, vq * wq[:, None])
        nodes_mass, mom, force = rec[0], rec[1:1 + d], rec[1 + d:].copy()
        points = []
        sbar = np.zeros((d, d) + (m,) * d)
        if linear:
            # The stresses' nodal averages and their hat gradient at each particle.
            shat = g.scatter(cell, xi, (vol * sig[:, 0, 0])[:, None])[0] \
                / g.scatter(cell, xi, vol[:, None])[0]
            slope = np.zeros(len(x))
            for idx, w, gr in g.corners(cell, xi):
                slope += shat[idx] * gr[:, 0]
        for combo in itertools.product(*per_axis):
            xq = np.stack([c[0] for c in combo], axis=1)
            wq = np.prod(np.stack([c[1] for c in combo], axis=1), axis=1)
            cq, xiq, al = locate(xq, h, n)
            points.append((cq, xiq, al, wq))
            s = (wq * vol)[:, None, None] * sig
            if linear:
                s = s + (wq * vol * slope * (xq[:, 0] - x[:, 0]))[:, None, None]
            for idx, w, gr in g.corners(cq, xiq):
                for a in range(d):
                    fa = -np.einsum("nb,nb->n", s[:, a, :], gr) * al
                    force[a] += np.bincount(idx, fa, m**d).reshape((m,) * d)
                    for c in range(d):
                        sbar[a, c] += np.bincount(idx, s[:, a, c] * (1 - al) * w,
                                                  m**d).reshape((m,) * d)
        sbar /= g.node_vol
        for a in range(d):
            for c in range(d):
                force[a] -= g.apply(sbar[a, c], g.kernel(c))
        vi = mom / nodes_mass
        vn = vi + dtv * force / nodes_mass
        walls(vi)
        walls(vn)
        # L̄_j = (1/V_j) Σ_i v_i ⊗ ∫ S_j ∇S_i and the smoothed velocity v̄_j.
        lbar = np.array([[g.apply(vn[a], [k.T for k in g.kernel(c)]) / g.node_vol
                          for c in range(d)] for a in range(d)])
        mass_all = [g.mass1.T] * d
        vbar = np.array([g.apply(vn[a], mass_all) for a in range(d)])
        for a in range(d):
            for c in range(d):
                vbar[a] += lbar[a, c] * g.moment[c]
        vbar /= g.node_vol
        walls(vbar)
        # Gather: velocity gradient over the same points; FLIP; the move.
        grad = np.zeros_like(f)
        lflat = lbar.reshape(d, d, -1)
        vflat = vn.reshape(d, -1)
        for cq, xiq, al, wq in points:
            for idx, w, gr in g.corners(cq, xiq):
                grad += wq[:, None, None] * (
                    al[:, None, None] * vflat[:, idx].T[:, :, None] * gr[:, None, :]
                    + ((1 - al) * w)[:, None, None] * np.moveaxis(lflat[:, :, idx], -1, 0))
        dv = np.zeros_like(v)
        move = np.zeros_like(v)
        vbf, dvf = vbar.reshape(d, -1), (vn - vi).reshape(d, -1)
        if MASS != "point":
            for cq, xiq, al, wq in points:
                for idx, w, _ in g.corners(cq, xiq):
                    dv += (wq * w)[:, None] * dvf[:, idx].T
        for idx, w, _ in g.corners(cell, xi):
            xj = np.stack(np.unravel_index(idx, (m,) * d), axis=1) * h
            if MASS == "point":
                dv += w[:, None] * dvf[:, idx].T
            move += w[:, None] * (vbf[:, idx].T
                                  + np.einsum("nac,nc->na", np.moveaxis(lflat[:, :, idx], -1, 0),
                                              x - xj))
        v = v + dv
        lprev = grad
        f = (np.eye(d) + dt * grad) @ f
        x = x + dt * move
        t += dt
        vol = np.linalg.det(f) * vol0
        norm = lambda e: np.sqrt(np.sum(vol * np.sum(e * e, axis=1)) / vol.sum())
        u_exact, v_exact = exact(x0, t)
        worst = np.maximum(worst, [norm(x - x0 - u_exact), norm(v - v_exact),
                                   norm(v - exact(x0, t - 0.5 * dt)[1])])
    return worst


def walls(vel):
    """Slip faces: the normal component vanishes on the nodes of each face."""
    for a in range(vel.shape[0]):
        face = [slice(None)] * (vel.ndim - 1)
        for end in (0, -1):
            face[a] = end
            vel[a][tuple(face)] = 0.0


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dim", type=int, choices=[1, 2], default=1)
    p.add_argument("--ppc", type=int, default=4, help="particles per cell per axis")
    p.add_argument("--quadrature", default="point")
    p.add_argument("--kick", choices=["own", "centred"], default="centred")
    p.add_argument("--cells", default="16,32,64,128,256")
    p.add_argument("--mass", choices=["point", "domain"], default="point",
                   help="weights of mass, momentum, body force and the FLIP increment")
    p.add_argument("--dt-cells", type=float, default=0.0,
                   help="a fixed step of DT_CELLS / cells instead of CFL 0.2")
    p.add_argument("--stress", choices=["constant", "linear"], default="constant",
                   help="the particle's stress over its domain (linear: 1D only)")
    p.add_argument("--momentum", choices=["constant", "affine"], default="constant",
                   help="the particle's velocity over its domain in the transfer (affine: --mass domain)")
    a = p.parse_args()
    if a.momentum == "affine" and a.mass != "domain":
        p.error("--momentum affine needs --mass domain")
    if a.stress == "linear" and (a.dim != 1 or a.quadrature == "point"):
        p.error("--stress linear needs --dim 1 and a quadrature over the domain")
    global MASS
    MASS = a.mass
    print("cells  displacement order   velocity at t order   at t - dt/2 order")
    last = None
    for n in map(int, a.cells.split(",")):
        e = run(a.dim, n, a.ppc, a.quadrature, a.kick, a.dt_cells, a.stress == "linear",
                a.momentum == "affine")
        o = [""] * 3 if last is None else [f"{np.log2(l / k):5.2f}" for l, k in zip(last, e)]
        print(f"{n:5d}  {e[0]:.3e} {o[0]:>5}   {e[1]:.3e} {o[1]:>5}   {e[2]:.3e} {o[2]:>5}",
              flush=True)
        last = e


if __name__ == "__main__":
    main()
