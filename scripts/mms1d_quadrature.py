#!/usr/bin/env python3
"""A 1D model of mpmcg's MPMCG step on the axis-aligned manufactured solution, to try
quadratures of the internal force before building them into the solver.

It follows the solver's definitions for `inputs/axis_aligned_mms_1d.toml` (USL, FLIP,
slip ends, neo-Hookean, CFL 0.2 on the current fastest signal, the force and the
velocity gradient by MPMCG's two local steps, particles moved by the reconstruction
`Σ_j S_j (v̄_j + L̄_j (x − x_j))`, the step from the neo-Hookean wave speed at each
particle's J plus its speed, the error as the solver's volume-weighted L2 norm, its
maximum over the run); with its defaults it reproduces
`mpmcg sweep inputs/axis_aligned_mms_1d.toml` to 0.1 % (displacement) and 1 %
(velocity). Whole-body cell weights are 1 (the body fills the grid), as the solver's
are on this problem.

Quadratures of `Σ_p v_p σ_p G_i` (and, adjoint, of the velocity gradient):
  point   at the particle (the solver);
  gaussK  K Gauss-Legendre points over the particle's current domain, width v_p;
  domain  the particle's domain split at the cell face inside it, two Gauss points on
          each piece: exact for the piecewise-cubic MPMCG integrands, i.e. the
          domain's integral of G_i with the stress constant over it.
Velocity steps: `own` advances the velocity by each step's own size (the solver),
`centred` by the mean of this step's and the last, half on the first (leapfrog with
variable steps).

Run with the system Python (it needs numpy):
  /usr/bin/python3 scripts/mms1d_quadrature.py --ppc 2 --quadrature domain \
      --cells 16,32,64,128,256,512
"""
import argparse

import numpy as np

A, C, E, NU, RHO = 0.05, 100.0, 1e4, 0.3, 1.0
LAM = E * NU / ((1 + NU) * (1 - 2 * NU))
MU = E / (2 * (1 + NU))
END = 0.02  # one period


def exact(x0, t):
    s = A * np.sin(np.pi * x0)
    return s * np.sin(C * np.pi * t), s * C * np.pi * np.cos(C * np.pi * t)


def body_force(x0, t):
    u = A * np.sin(np.pi * x0) * np.sin(C * np.pi * t)
    f = 1 + A * np.pi * np.cos(np.pi * x0) * np.sin(C * np.pi * t)
    return np.pi**2 * u * (MU / RHO - C * C - (LAM * (np.log(f) - 1) - MU) / (RHO * f * f))


def stress(f):
    return (MU * f * f + LAM * np.log(f) - MU) / f


def signal(f):
    """The neo-Hookean wave speed at J = f, the solver's: the tangent modulus, at
    least λ + 2μ."""
    return np.sqrt(np.maximum(LAM + 2 * (MU - LAM * np.log(f)), LAM + 2 * MU) / RHO)


def points(x, half, h, quadrature):
    """(position, weight) pairs over each particle's domain [x − half, x + half]."""
    top = 1 - 1e-15
    if quadrature == "point":
        return [(x, 1.0)]
    if quadrature.startswith("gauss"):
        g, w = np.polynomial.legendre.leggauss(int(quadrature[5:]))
        return [(np.clip(x + gk * half, 0, top), wk / 2) for gk, wk in zip(g, w)]
    lo, hi = np.clip(x - half, 0, 1), np.clip(x + half, 0, 1)
    face = np.floor(hi / h) * h
    cut = np.where((face > lo) & (face < hi), face, hi)
    out = []
    for a, b in ((lo, cut), (cut, hi)):
        mid, rad = (a + b) / 2, (b - a) / 2
        for g in (-1 / np.sqrt(3), 1 / np.sqrt(3)):
            out.append((np.clip(mid + g * rad, 0, top), rad / (hi - lo)))
    return out


def local(x, h, n):
    c = np.minimum(np.floor(x / h).astype(int), n - 1)
    xi = x / h - c
    return c, xi, 4 * xi * (1 - xi)


def run(n, ppc, quadrature, kick):
    h = 1.0 / n
    x0 = (np.arange(n * ppc) + 0.5) / (n * ppc)
    vol0 = np.full(x0.size, 1.0 / x0.size)
    m = RHO * vol0
    x, f, v = x0.copy(), np.ones(x0.size), exact(x0, 0.0)[1]
    node_vol = np.full(n + 1, h)
    node_vol[[0, -1]] = h / 2
    t, dt_last = 0.0, None
    worst = np.zeros(3)
    nodes = lambda c, w: np.bincount(c, w, n + 1)
    while t < END - 1e-14:
        vol, sig = f * vol0, stress(f)
        dt = min(0.2 * h / np.max(signal(f) + np.abs(v)), END - t)
        if kick == "own":
            dtv = dt
        else:
            dtv = 0.5 * dt if dt_last is None else 0.5 * (dt_last + dt)
        dt_last = dt
        c, xi, _ = local(x, h, n)
        mass = nodes(c, m * (1 - xi)) + nodes(c + 1, m * xi)
        mom = nodes(c, m * v * (1 - xi)) + nodes(c + 1, m * v * xi)
        b = m * body_force(x0, t)
        force = nodes(c, b * (1 - xi)) + nodes(c + 1, b * xi)
        sbar = np.zeros(n + 1)
        quad = points(x, vol / 2, h, quadrature)
        for xq, wq in quad:
            cq, xiq, al = local(xq, h, n)
            s = wq * vol * sig
            force += nodes(cq, s * al / h) - nodes(cq + 1, s * al / h)
            sbar += nodes(cq, s * (1 - al) * (1 - xiq)) + nodes(cq + 1, s * (1 - al) * xiq)
        sbar /= node_vol
        # f_i −= Σ_j σ̄_j ∫ S_j S_i'  (1/2 from the left neighbour, −1/2 from the right)
        force[1:] -= 0.5 * sbar[:-1]
        force[:-1] += 0.5 * sbar[1:]
        force[0] += 0.5 * sbar[0]
        force[-1] -= 0.5 * sbar[-1]
        vi = mom / mass
        vn = vi + dtv * force / mass
        vi[[0, -1]] = vn[[0, -1]] = 0.0
        lbar = np.zeros(n + 1)
        lbar[:-1] += 0.5 * vn[1:]
        lbar[1:] -= 0.5 * vn[:-1]
        lbar[0] -= 0.5 * vn[0]
        lbar[-1] += 0.5 * vn[-1]
        lbar /= node_vol
        vbar = np.zeros(n + 1)
        vbar[1:-1] = (vn[:-2] + 4 * vn[1:-1] + vn[2:]) / 6
        vbar[0] = (h / 3 * vn[0] + h / 6 * vn[1] - lbar[0] * h * h / 6) / (h / 2)
        vbar[-1] = (h / 3 * vn[-1] + h / 6 * vn[-2] + lbar[-1] * h * h / 6) / (h / 2)
        grad = np.zeros(x.size)
        for xq, wq in quad:
            cq, xiq, al = local(xq, h, n)
            grad += wq * (al * (vn[cq + 1] - vn[cq]) / h
                          + (1 - al) * ((1 - xiq) * lbar[cq] + xiq * lbar[cq + 1]))
        v = v + (1 - xi) * (vn[c] - vi[c]) + xi * (vn[c + 1] - vi[c + 1])
        move = ((1 - xi) * (vbar[c] + lbar[c] * (x - c * h))
                + xi * (vbar[c + 1] + lbar[c + 1] * (x - (c + 1) * h)))
        f = f * (1 + dt * grad)
        x = x + dt * move
        t += dt
        vol = f * vol0
        norm = lambda e: np.sqrt(np.sum(vol * e * e) / vol.sum())
        u_exact, v_exact = exact(x0, t)
        worst = np.maximum(worst, [norm(x - x0 - u_exact), norm(v - v_exact),
                                   norm(v - exact(x0, t - 0.5 * dt)[1])])
    return worst


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--ppc", type=int, default=4)
    p.add_argument("--quadrature", default="point")
    p.add_argument("--kick", choices=["own", "centred"], default="own")
    p.add_argument("--cells", default="16,32,64,128,256")
    a = p.parse_args()
    print("cells  displacement order   velocity at t order   at t - dt/2 order")
    last = None
    for n in map(int, a.cells.split(",")):
        e = run(n, a.ppc, a.quadrature, a.kick)
        o = [""] * 3 if last is None else [f"{np.log2(l / k):5.2f}" for l, k in zip(last, e)]
        print(f"{n:5d}  {e[0]:.3e} {o[0]:>5}   {e[1]:.3e} {o[1]:>5}   {e[2]:.3e} {o[2]:>5}",
              flush=True)
        last = e


if __name__ == "__main__":
    main()
