#!/usr/bin/python3
"""Phase speed of long waves on a regular 1D particle lattice, per scheme.

A periodic 1D grid of N cells (h = 1), `ppc` particles per cell at (q + 1/2)/ppc of each
cell, unit modulus and density, small strain: the stiffness K = Σ_p V_p B_pᵀ B_p with
B_p,i = G_i(x_p) (each scheme's gradient, docs/schemes.md), the lumped mass
M_i = Σ_p V_p S_i(x_p). A Fourier mode e^{ikx} on the nodes then has ω² = (e* K e) /
(e* M e), and the phase speed ω/k against the exact 1 is `1 + c2 (kh)² + ...`: the
script prints c2 for MPM, GIMP, averaged and MPMCG, and MPMCG with its nodal averages
sharpened by β, L̄ ← ((1 + β) I − β S) L̄ with S = M⁻¹ M_consistent
(`[method] sharpen`), and the β that makes c2 vanish.

With `--dim 2`: scalar waves (u_tt = Δu) on a periodic n × n grid, ppc × ppc particles
per cell, for waves along an axis and along a diagonal, MPMCG at the particle and with
the domain rule (each particle's gradient averaged over its box of half-width
h / (2 ppc), exactly: the integrands are cubics per axis, and 2 Gauss points per axis
integrate them), c2 at β = 0, 1, 2 and the β that makes it vanish.

Usage: /usr/bin/python3 scripts/dispersion.py [--ppc 2] [--cells 64] [--dim 1]
"""
import argparse

import numpy as np


def stiffness(scheme, n, ppc, beta=0.0):
    """K and the lumped mass of `scheme` on n cells with ppc particles per cell."""
    xp = np.array([c + (q + 0.5) / ppc for c in range(n) for q in range(ppc)])
    vp = 1.0 / ppc
    # Node i's hat at x and its derivative, periodic.
    d = (xp[:, None] - np.arange(n)[None, :] + n / 2) % n - n / 2
    s = np.maximum(0.0, 1.0 - np.abs(d))
    ds = np.where(np.abs(d) < 1.0, -np.sign(d), 0.0)
    eye = np.eye(n)
    # L̄_j = (v_{j+1} − v_{j−1}) / 2 on a full periodic grid (V_j = h), and S.
    lbar = (np.roll(eye, 1, axis=1) - np.roll(eye, -1, axis=1)) / 2.0
    smooth = (4.0 * eye + np.roll(eye, 1, axis=1) + np.roll(eye, -1, axis=1)) / 6.0
    lbar = ((1.0 + beta) * eye - beta * smooth) @ lbar
    xi = xp % 1.0
    alpha = {"mpm": np.ones_like(xi), "averaged": np.zeros_like(xi)}.get(scheme, 4 * xi * (1 - xi))
    if scheme == "gimp":
        half = 0.5 / ppc
        dp = (xp[:, None] + half - np.arange(n)[None, :] + n / 2) % n - n / 2
        dm = (xp[:, None] - half - np.arange(n)[None, :] + n / 2) % n - n / 2
        b = (np.maximum(0, 1 - np.abs(dp)) - np.maximum(0, 1 - np.abs(dm))) / (2 * half)
    else:
        b = alpha[:, None] * ds + (1 - alpha)[:, None] * (s @ lbar)
    return b.T @ (vp * b), (vp * s).sum(axis=0)


def c2(scheme, n, ppc, beta=0.0):
    k_mat, mass = stiffness(scheme, n, ppc, beta)
    k = 2 * np.pi / n
    e = np.exp(1j * k * np.arange(n))
    w2 = np.real(e.conj() @ k_mat @ e) / np.real(e.conj() @ (mass * e))
    return (np.sqrt(w2) / k - 1.0) / k**2


def c2_2d(n, ppc, beta, direction, domain):
    """c2 of MPMCG for the scalar wave `e^{i k·x}`, k = 2π direction / n, on an n × n
    periodic grid (h = 1, unit density and modulus): ω² = Σ_p V_p |G(e)(x_p)|² / Σ_i m_i
    with G the scheme's gradient (at the particle, or averaged over its box)."""
    j = np.arange(n)
    x, y = np.meshgrid(j, j, indexing="ij")
    k = 2 * np.pi * np.asarray(direction, dtype=float) / n
    u = np.exp(1j * (k[0] * x + k[1] * y))

    def smooth(f, axis):
        return (4 * f + np.roll(f, 1, axis) + np.roll(f, -1, axis)) / 6

    def central(f, axis):
        return (np.roll(f, -1, axis) - np.roll(f, 1, axis)) / 2

    # L̄ = (1/V_j) Σ_i u_i ∫ S_j ∇S_i: the central difference along the derivative's
    # axis, the consistent-mass smoothing across it; sharpened with S = smoothing².
    lbar = [smooth(central(u, 0), 1), smooth(central(u, 1), 0)]
    lbar = [(1 + beta) * g - beta * smooth(smooth(g, 0), 1) for g in lbar]
    q = (np.arange(ppc) + 0.5) / ppc
    gauss = [(-0.5 / (ppc * np.sqrt(3)), 0.5), (0.5 / (ppc * np.sqrt(3)), 0.5)] if domain else [(0.0, 1.0)]
    energy = 0.0
    for qx in q:
        for qy in q:
            grad = np.zeros((2, n, n), complex)
            for gx, wx in gauss:
                for gy, wy in gauss:
                    xi, eta = qx + gx, qy + gy
                    sx, sy, ds = (1 - xi, xi), (1 - eta, eta), (-1.0, 1.0)
                    alpha = 16 * xi * (1 - xi) * eta * (1 - eta)
                    for ox in (0, 1):
                        for oy in (0, 1):
                            def at(f):
                                return np.roll(np.roll(f, -ox, 0), -oy, 1)

                            s_n = sx[ox] * sy[oy]
                            hat = (ds[ox] * sy[oy], sx[ox] * ds[oy])
                            for a in range(2):
                                grad[a] += wx * wy * (alpha * hat[a] * at(u) + (1 - alpha) * s_n * at(lbar[a]))
            energy += (np.abs(grad) ** 2).sum() / ppc**2
    kk = np.hypot(*k)
    return (np.sqrt(energy / n**2) / kk - 1.0) / kk**2


def main_2d(n, ppc):
    print(f"2D scalar waves, {n}² cells, {ppc} × {ppc} per cell: c2 at sharpen = 0, 1, 2")
    for domain in (False, True):
        for name, direction in (("axis", (1, 0)), ("diagonal", (1, 1))):
            c = [c2_2d(n, ppc, beta, direction, domain) for beta in (0.0, 1.0, 2.0)]
            rule = "domain rule" if domain else "particle"
            print(
                f"mpmcg, {rule:11s} {name:8s} c2 = {c[0]:+.4f} {c[1]:+.4f} {c[2]:+.4f}, "
                f"vanishes at sharpen = {-c[0] / (c[1] - c[0]):.2f}"
            )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ppc", type=int, default=2)
    ap.add_argument("--cells", type=int, default=64)
    ap.add_argument("--dim", type=int, choices=(1, 2), default=1)
    a = ap.parse_args()
    if a.dim == 2:
        main_2d(a.cells, a.ppc)
        return
    for scheme in ("mpm", "gimp", "averaged", "mpmcg"):
        print(f"{scheme:9s} c2 = {c2(scheme, a.cells, a.ppc):+.4f}")
    c0, c1 = c2("mpmcg", a.cells, a.ppc), c2("mpmcg", a.cells, a.ppc, 1.0)
    for beta in (1.0, 2.0):
        print(f"mpmcg, sharpen = {beta:g}: c2 = {c2('mpmcg', a.cells, a.ppc, beta):+.4f}")
    print(f"c2 vanishes at sharpen = {-c0 / (c1 - c0):.2f}")


if __name__ == "__main__":
    main()
