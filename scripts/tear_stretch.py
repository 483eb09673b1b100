#!/usr/bin/python3
"""Where a 2D beam clamped at x = 0 opens: per particle of its first columns, the
largest stretch its own F carries against how far it has moved from its neighbour.

A neo-Hookean particle's Kirchhoff stress is tau = mu (b - I) + lambda ln J I, so its
left Cauchy-Green tensor b, and the largest principal stretch sqrt(max eig b), follow
from the Cauchy stress of a snapshot (J solves det b = J^2, plane strain). Beside it,
the distance to the particle that started one seeding spacing further along x, in
spacings. Where the two agree the particles moved apart because the material stretched;
where the distance runs away from the stretch they drifted apart.

Usage: /usr/bin/python3 scripts/tear_stretch.py OUT --time T --youngs E [--poisson 0.3]
       [--columns 5]
Needs h5py and scipy (Debian: python3-h5py python3-scipy).
"""
import argparse
import glob

import h5py
import numpy as np
from scipy.optimize import brentq


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out")
    ap.add_argument("--time", type=float, required=True)
    ap.add_argument("--youngs", type=float, required=True)
    ap.add_argument("--poisson", type=float, default=0.3)
    ap.add_argument("--columns", type=int, default=5)
    a = ap.parse_args()
    mu = a.youngs / (2 * (1 + a.poisson))
    lam = a.youngs * a.poisson / ((1 + a.poisson) * (1 - 2 * a.poisson))
    snaps = []
    for path in sorted(glob.glob(a.out + "/particles_*.h5")):
        with h5py.File(path, "r") as f:
            snaps.append((abs(float(f.attrs["time"]) - a.time), path))
    path = min(snaps)[1]
    with h5py.File(path, "r") as f:
        t = float(f.attrs["time"])
        x = f["position"][:, :2]
        x0 = x - f["displacement"][:, :2]
        sig = f["stress"][:].reshape(-1, 3, 3)[:, :2, :2]
    xs, ys = np.unique(np.round(x0[:, 0], 9)), np.unique(np.round(x0[:, 1], 9))
    s = xs[1] - xs[0]
    key = np.floor(x0 / s + 1e-6).astype(int)
    at = {(k[0], k[1]): i for i, k in enumerate(key)}

    def stretch(i):
        def b_of(J):
            return np.eye(2) + (J * sig[i] - lam * np.log(J) * np.eye(2)) / mu

        # det b = J^2 may have more than one root: the one whose b is positive definite.
        g = np.geomspace(0.05, 20.0, 400)
        r = np.array([np.linalg.det(b_of(J)) - J * J for J in g])
        for k in np.nonzero(np.sign(r[:-1]) != np.sign(r[1:]))[0]:
            J = brentq(lambda J: np.linalg.det(b_of(J)) - J * J, g[k], g[k + 1])
            if np.all(np.linalg.eigvalsh(b_of(J)) > 0):
                break
        else:
            return float("nan"), float("nan")
        return np.sqrt(np.linalg.eigvalsh(b_of(J)).max()), J

    print("t = %.3f s: per particle, largest stretch / J of its F | distance to the next "
          "particle along x in spacings (rows from the top, columns from the clamp)" % t)
    for y in ys[::-1]:
        cells = []
        for xc in xs[: a.columns]:
            kx, ky = int(np.floor(xc / s + 1e-6)), int(np.floor(y / s + 1e-6))
            i, j = at[(kx, ky)], at.get((kx + 1, ky))
            lmax, J = stretch(i)
            gap = np.linalg.norm(x[j] - x[i]) / s if j is not None else float("nan")
            cells.append("%.2f / %.2f | %5.2f" % (lmax, J, gap))
        print("y0 = %.4f  " % y + "   ".join(cells))


if __name__ == "__main__":
    main()
