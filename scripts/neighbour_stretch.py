#!/usr/bin/python3
"""Do neighbouring particles move apart as their deformation gradients say?

For every pair of lattice neighbours (particles one spacing apart in the first snapshot)
and every snapshot: the pair's stretch (its distance over the first), against the largest
principal stretch either particle's F allows, recovered from its neo-Hookean Cauchy stress
(J sigma = mu (b - I) + lambda ln J I, b = F F^T). A pair stretched far beyond that bound has
drifted apart without the material knowing: the particles moved by another velocity field
than the one that deformed them. Prints one line per snapshot (every K-th): the most
stretched pair, its bound and where it started, and the most stretched pair relative to its
bound.

2D (plane strain) runs of a neo-Hookean body.
Usage: scripts/neighbour_stretch.py OUT --youngs E [--poisson NU] [--every K]
Runs with /usr/bin/python3 and Debian's python3-h5py, python3-numpy and python3-scipy.
"""
import argparse
import glob

import h5py
import numpy as np
from scipy.spatial import cKDTree


def load(path):
    with h5py.File(path, "r") as f:
        order = np.argsort(f["id"][:])
        dim = int(f.attrs["dim"])
        return (float(f.attrs["time"]), f["position"][:][order, :dim],
                f["stress"][:][order].reshape(-1, 3, 3))


def largest_stretch(sigma, mu, lam):
    """Largest in-plane principal stretch sqrt(max eig b) of each particle, from its
    plane-strain stress: b_zz = 1 there, so J sigma_zz = lambda ln J gives J."""
    out = np.empty(len(sigma))
    for p, s in enumerate(sigma):
        j = 1.0
        for _ in range(60):  # a contraction while |J sigma_zz| < lambda
            j = np.exp(j * s[2, 2] / lam)
        b = np.eye(2) + (j * s[:2, :2] - lam * np.log(j) * np.eye(2)) / mu
        out[p] = np.sqrt(max(np.linalg.eigvalsh(b)[-1], 0.0))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--youngs", type=float, required=True)
    ap.add_argument("--poisson", type=float, default=0.3)
    ap.add_argument("--every", type=int, default=1)
    a = ap.parse_args()
    mu = a.youngs / (2 * (1 + a.poisson))
    lam = a.youngs * a.poisson / ((1 + a.poisson) * (1 - 2 * a.poisson))
    files = sorted(glob.glob(a.out + "/particles_*.h5"))
    if not files:
        raise SystemExit(f"no snapshots in {a.out}")
    with h5py.File(files[0], "r") as f:
        if int(f.attrs["dim"]) != 2:
            raise SystemExit("neighbour_stretch.py reads 2D (plane-strain) runs only")
    _, x0, _ = load(files[0])
    spacing = np.median(cKDTree(x0).query(x0, 2)[0][:, 1])
    pairs = cKDTree(x0).query_pairs(1.01 * spacing, output_type="ndarray")
    d0 = np.linalg.norm(x0[pairs[:, 1]] - x0[pairs[:, 0]], axis=1)
    for path in files[::a.every]:
        t, x, sigma = load(path)
        r = np.linalg.norm(x[pairs[:, 1]] - x[pairs[:, 0]], axis=1) / d0
        lm = largest_stretch(sigma, mu, lam)
        bound = np.maximum(lm[pairs[:, 0]], lm[pairs[:, 1]])
        i, j = np.argmax(r), np.argmax(r / bound)
        at = lambda k: "(" + ", ".join("%.3g" % c for c in x0[pairs[k, 0]]) + ")"
        print("t = %.3f  most stretched pair %.2f (F allows %.2f) from %s;  "
              "pair / bound at most %.2f (%.2f / %.2f) from %s" % (
                  t, r[i], bound[i], at(i), r[j] / bound[j], r[j], bound[j], at(j)))


if __name__ == "__main__":
    main()
