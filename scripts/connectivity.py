#!/usr/bin/python3
"""Connectivity of a run's particle cloud, per snapshot: how many pieces the material is
in, and the largest distance from a particle to its nearest neighbour.

Two particles are neighbours when closer than R (default: 1.5 initial particle spacings,
the spacing taken as the median nearest-neighbour distance of the first snapshot); the
pieces are the connected components of that graph. A body that stays whole is 1 piece;
a spuriously separated one is more. The largest gap is capped at R (a particle with no
neighbour closer than R is cut off).

Usage: scripts/connectivity.py OUT [OUT...] [--radius R] [--every K]
Prints one line per snapshot (every K-th) and a summary line per run:
    OUT: worst N pieces at t = T (step S); largest gap G spacings; SNAPS snapshots
Runs with /usr/bin/python3 and Debian's python3-h5py and python3-numpy.
"""
import argparse
import glob
import os
import sys

import h5py
import numpy as np


def pieces(x, r):
    """(number of connected components, largest nearest-neighbour distance capped at r)."""
    n = len(x)
    if n == 0:
        return 0, 0.0
    keys = np.floor(x / r).astype(np.int64)
    bins = {}
    for i, k in enumerate(map(tuple, keys)):
        bins.setdefault(k, []).append(i)
    parent = np.arange(n)

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    dim = x.shape[1]
    offsets = np.array(np.meshgrid(*[[-1, 0, 1]] * dim, indexing="ij")).reshape(dim, -1).T
    nearest = np.full(n, r)
    for k, members in bins.items():
        cand = []
        for o in offsets:
            cand.extend(bins.get(tuple(np.add(k, o)), ()))
        cand = np.array(cand)
        for i in members:
            d = np.linalg.norm(x[cand] - x[i], axis=1)
            close = cand[(d < r) & (cand != i)]
            if len(close):
                nearest[i] = min(nearest[i], d[(d < r) & (cand != i)].min())
            for j in close:
                a, b = root(i), root(j)
                if a != b:
                    parent[a] = b
    roots = sum(1 for i in range(n) if root(i) == i)
    return roots, float(nearest.max())


def snapshot(path):
    with h5py.File(path, "r") as f:
        dim = int(f.attrs["dim"])
        return float(f.attrs["time"]), int(f.attrs["step"]), f["position"][:, :dim]


def spacing(x):
    """Median nearest-neighbour distance (brute force on a sample)."""
    rng = np.random.default_rng(0)
    sample = x[rng.choice(len(x), min(len(x), 400), replace=False)]
    d = np.linalg.norm(sample[:, None, :] - x[None, :, :], axis=2)
    d[d == 0] = np.inf
    return float(np.median(d.min(axis=1)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", nargs="+")
    ap.add_argument("--radius", type=float, help="neighbour distance (default 1.5 spacings)")
    ap.add_argument("--every", type=int, default=1, help="print every K-th snapshot")
    ap.add_argument("--quiet", action="store_true", help="summary lines only")
    a = ap.parse_args()
    worst_pieces = 0
    for out in a.out:
        files = sorted(glob.glob(os.path.join(out, "particles_*.h5")))
        if not files:
            sys.exit(f"{out}: no particles_*.h5 snapshots")
        _, _, x0 = snapshot(files[0])
        s = spacing(x0)
        r = a.radius or 1.5 * s
        worst = (0, 0.0, 0.0, 0)
        for k, f in enumerate(files):
            t, step, x = snapshot(f)
            p, gap = pieces(x, r)
            if (p, gap) > worst[:2]:
                worst = (p, gap, t, step)
            if not a.quiet and k % a.every == 0:
                print(f"{out}: t = {t:.4g} step {step}: {p} piece(s), largest gap {gap / s:.2f} spacings")
        print(f"{out}: worst {worst[0]} piece(s) at t = {worst[2]:.4g} (step {worst[3]}); "
              f"largest gap {worst[1] / s:.2f} spacings; {len(files)} snapshots")
        worst_pieces = max(worst_pieces, worst[0])
    return 0


if __name__ == "__main__":
    sys.exit(main())
