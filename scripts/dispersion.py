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

Usage: /usr/bin/python3 scripts/dispersion.py [--ppc 2] [--cells 64]
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


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ppc", type=int, default=2)
    ap.add_argument("--cells", type=int, default=64)
    a = ap.parse_args()
    for scheme in ("mpm", "gimp", "averaged", "mpmcg"):
        print(f"{scheme:9s} c2 = {c2(scheme, a.cells, a.ppc):+.4f}")
    c0, c1 = c2("mpmcg", a.cells, a.ppc), c2("mpmcg", a.cells, a.ppc, 1.0)
    for beta in (1.0, 2.0):
        print(f"mpmcg, sharpen = {beta:g}: c2 = {c2('mpmcg', a.cells, a.ppc, beta):+.4f}")
    print(f"c2 vanishes at sharpen = {-c0 / (c1 - c0):.2f}")


if __name__ == "__main__":
    main()
