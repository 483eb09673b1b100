#!/usr/bin/python3
"""The generalized vortex's rigid turn predicted from its seeding alone.

The manufactured body force of inputs/generalized_vortex.toml has no net torque on the
exact ring (its shear part, g (R² h'' + 3 R h'), integrates to R³ h' at the edges, where
h' = 0), and the internal forces of any scheme here have none on the particles. So the
ring's angular momentum follows the particles' sum of the body force's torque alone, and
where that sum misses the exact integral the ring turns as a whole. With the torque
error ΔT sin(πt) (c = 1) against the moment of inertia I, the turn at t = 1 is
A ΔT / (π I) (the mean over the ring of T/I, as the inertial part scales with I too).

For each grid this prints the relative torque error and the predicted turn at t = 1 for
the particles seeded on the lattice (`seeding = "lattice"`: a full particle at each
lattice point inside the ring), seeded `cut` (each the area of its lattice box inside
the ring, at that part's centroid, measured on a sub-lattice of 16 × 16 points as mpmcg
does), and seeded `cut` with each particle's force averaged over its box (`[benchmark]
body_force = "domain"`: 2 × 2 Gauss points of the box shrunk to the particle's area,
the torque about the centre of that mean force at the particle; to first order in A,
where the force is tangential). Measured turns (scripts/vortex_where.py, column `rot`,
MPMCG at 64 cells): lattice +8.3e-3 rad, on the grid shifted by h/4 -5.3e-3; cut
+2.3e-3.

Usage: /usr/bin/python3 scripts/vortex_seeding.py [--cells 16,32,64,128] [--shift 0.25]
Needs numpy.
"""
import argparse

import numpy as np

A, PPC, SUB = 0.1, 2, 16
G = (1000.0 / (2 * 1.3)) / 1000.0  # shear wave speed squared, mu / rho


def h(r):
    q = r - 1
    return 1 - 32 * q * q + 256 * q**4


def dh(r):
    q = r - 1
    return -64 * q + 1024 * q**3


def ddh(r):
    q = r - 1
    return -64 + 3072 * q * q


def torque(r):
    """R b_θ per unit mass over A ρ sin(πt): inertial part and shear part."""
    return -np.pi**2 * r * r * h(r) - G * (r * r * ddh(r) + 3 * r * dh(r))


def ring(r):
    return (r >= 0.75) & (r <= 1.25)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", default="16,32,64,128")
    ap.add_argument("--shift", type=float, default=0.0, help="grid shifted by this share of a cell")
    a = ap.parse_args()
    rs = np.linspace(0.75, 1.25, 200001)
    w = np.gradient(rs)
    t_exact = 2 * np.pi * np.sum(rs * torque(rs) * w)
    i_exact = 2 * np.pi * np.sum(rs**3 * w)
    print(f"exact torque {t_exact:.6f}, moment of inertia {i_exact:.6f} (per A ρ sin πt and per ρ)")
    print(" cells   lattice dT/T   turn        cut dT/T    turn        domain dT/T turn")
    for n in map(int, a.cells.split(",")):
        hh = 3.0 / n
        m = n * PPC
        vol = (hh / PPC) ** 2
        c = -1.5 + a.shift * hh + (np.arange(m) + 0.5) * hh / PPC
        x, y = np.meshgrid(c, c)
        r = np.hypot(x, y)
        inside = ring(r)
        t_lat, i_lat = np.sum(torque(r[inside])) * vol, np.sum(r[inside] ** 2) * vol
        cs = -1.5 + a.shift * hh + (np.arange(m * SUB) + 0.5) * hh / PPC / SUB
        xs, ys = np.meshgrid(cs, cs)
        ins = ring(np.hypot(xs, ys)).astype(float)
        count = ins.reshape(m, SUB, m, SUB).sum(axis=(1, 3))
        seen = count > 0
        xc = (xs * ins).reshape(m, SUB, m, SUB).sum(axis=(1, 3))[seen] / count[seen]
        yc = (ys * ins).reshape(m, SUB, m, SUB).sum(axis=(1, 3))[seen] / count[seen]
        v = count[seen] / SUB**2 * vol
        rc = np.hypot(xc, yc)
        t_cut, i_cut = np.sum(v * torque(rc)), np.sum(v * rc**2)
        # The box of a cut particle shrinks with its area, as mpmcg seeds it.
        half = 0.5 * hh / PPC * np.sqrt(count[seen] / SUB**2)
        t_dom = 0.0
        for sx in (-1, 1):
            for sy in (-1, 1):
                xg = xc + sx * half / np.sqrt(3)
                yg = yc + sy * half / np.sqrt(3)
                rg2 = xg * xg + yg * yg
                # b_θ(r_g) e_θ(x_g) at the particle: torque (x_p · x_g) b_θ / r_g.
                t_dom = t_dom + 0.25 * np.sum(v * torque(np.sqrt(rg2)) * (xc * xg + yc * yg) / rg2)
        turn = lambda t, i: A * (t / i - t_exact / i_exact) / np.pi
        print(
            f"{n:6d}   {(t_lat - t_exact) / t_exact:+.2e}   {turn(t_lat, i_lat):+.2e}"
            f"   {(t_cut - t_exact) / t_exact:+.2e}   {turn(t_cut, i_cut):+.2e}"
            f"   {(t_dom - t_exact) / t_exact:+.2e}   {turn(t_dom, i_cut):+.2e}"
        )


if __name__ == "__main__":
    main()
