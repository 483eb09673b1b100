#!/usr/bin/python3
"""Where the generalized vortex's error sits: by radius, and in holes of the ring.

For a run of inputs/generalized_vortex.toml with snapshots (give it
`[output] every = 0.05`), from the particles' positions (matched by id to their
reference positions, the t = 0 snapshot's, where the exact motion has not moved them):

- every snapshot: the displacement error of history.csv; the holes, cells at least one
  cell inside the ring's edges (0.75 + h <= r <= 1.25 - h, inside the body at every time,
  since the exact motion turns each circle into itself) that hold no particle, among
  the particles as they moved and among the same particles moved by the exact motion;
  the largest shear `R dα/dR` and principal stretch of that motion; the median radius;
- the snapshot with the largest error: its root mean square by radial band of the
  reference ring, each band's share of the squared error, and the outer band's mean
  radial and tangential error;
- the error's rigid part, the ring turned as a whole (`rot`, the least-squares angle of
  the particles' tangential errors), and the root mean square of the rest (`rest`), at
  every snapshot and the largest over them: the rigid part is what the particles' total
  angular momentum got wrong.

The bands, `rot` and `rest` weigh each particle by its volume at t = 0 where the
snapshots have the field `volume` (seeded `cut`, the ring's edge particles are smaller:
give the run `fields = ["velocity", "volume"]`), else count each once.

Usage: /usr/bin/python3 scripts/vortex_where.py RUN_DIR --cells N [--amplitude 0.1]
Needs h5py (Debian: python3-h5py).
"""
import argparse
import csv
import glob
import os

import h5py
import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("--cells", type=int, required=True, help="the scene's cells per axis")
    ap.add_argument("--amplitude", type=float, default=0.1)
    a = ap.parse_args()
    files = sorted(glob.glob(os.path.join(a.run, "particles_*.h5")))
    snaps = []
    for f in files:
        with h5py.File(f) as g:
            order = np.argsort(g["id"][:])
            snaps.append((float(g.attrs["time"]), g["position"][:, :2][order]))
            if len(snaps) == 1:
                w = g["volume"][:][order] if "volume" in g else np.ones(len(order))
    w = w / w.mean()
    x0 = snaps[0][1]
    lo, n = -1.5, a.cells  # the scene's grid: [-1.5, 1.5]²
    h = 3.0 / n
    c = lo + (np.arange(n) + 0.5) * h
    cx, cy = np.meshgrid(c, c, indexing="ij")
    rc = np.hypot(cx, cy)
    inside = (rc >= 0.75 + h) & (rc <= 1.25 - h)

    def holes(x):
        i = np.clip(((x - lo) / h).astype(int), 0, n - 1)
        seen = np.zeros((n, n), bool)
        seen[i[:, 0], i[:, 1]] = True
        return int((inside & ~seen).sum())

    rows = list(csv.DictReader(open(os.path.join(a.run, "history.csv"))))
    times = np.array([float(r["time"]) for r in rows])
    errors = np.array([float(r["displacement_l2"]) for r in rows])
    radius = np.hypot(x0[:, 0], x0[:, 1])
    theta = np.arctan2(x0[:, 1], x0[:, 0])
    s = radius - 1.0
    shape = 1 - 32 * s**2 + 256 * s**4
    slope = -64 * s + 1024 * s**3

    def exact(t):
        turn = a.amplitude * np.sin(np.pi * t)
        al = turn * shape
        return np.stack([radius * np.cos(theta + al), radius * np.sin(theta + al)], 1), turn, al

    print(f"{n} cells, {len(x0)} particles, {inside.sum()} cells inside the ring")
    print("     t     error  holes  exact-motion holes  shear  stretch  median r       rot      rest")
    worst = None
    rest_max = 0.0
    for t, x in snaps:
        xe, turn, al = exact(t)
        shear = np.abs(radius * turn * slope).max()
        stretch = shear / 2 + np.sqrt(1 + shear * shear / 4)
        e = errors[np.argmin(np.abs(times - t))]
        d = x - xe
        r = np.hypot(*xe.T)
        rot = (w * (d[:, 1] * xe[:, 0] - d[:, 0] * xe[:, 1])).sum() / (w * r * r).sum()
        rest = np.sqrt((w * ((d - rot * np.stack([-xe[:, 1], xe[:, 0]], 1)) ** 2).sum(1)).mean())
        rest_max = max(rest_max, rest)
        print(f"{t:6.3f} {e:9.2e} {holes(x):6d} {holes(xe):19d} {shear:6.2f} {stretch:8.2f} "
              f"{np.median(np.hypot(*x.T)):9.3f} {rot:+9.2e} {rest:9.2e}")
        e2 = w * ((x - xe) ** 2).sum(1)
        if worst is None or e2.mean() > worst[1].mean():
            worst = (t, e2, x, al)
    print(f"largest rms error less the rigid turn over the snapshots: {rest_max:.2e}")
    t, e2, x, al = worst
    bands = np.linspace(0.75, 1.25, 6)
    k = np.clip(np.digitize(radius, bands) - 1, 0, 4)
    print(f"largest error at t = {t:.3f}; by reference radius:")
    for b in range(5):
        m = k == b
        print(f"  R {bands[b]:.2f}-{bands[b + 1]:.2f}: rms {np.sqrt(e2[m].mean()):.2e}, "
              f"share {e2[m].sum() / e2.sum():.2f}")
    outer = k == 4
    r = np.hypot(*x.T)
    turned = (np.arctan2(x[:, 1], x[:, 0]) - theta - al + np.pi) % (2 * np.pi) - np.pi
    mean = lambda q: (w * q)[outer].sum() / w[outer].sum()
    print(f"  outer band: radial error mean {mean(r - radius):+.2e}, "
          f"tangential error mean {mean(radius * turned):+.2e}")


if __name__ == "__main__":
    main()
