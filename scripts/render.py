#!/usr/bin/env python3
"""Picture of a run's particles at one snapshot (the last by default).

    scripts/render.py OUT -o final.png [--field F] [--time T] [--view xy|xz]

F colours the particles: von_mises or pressure (from `stress`, the full 3 x 3
Cauchy stress, which in 2D includes the plane-strain sigma_zz; von_mises is the
default when present), speed (from `velocity`), plastic_strain, damage, or any
scalar dataset of the snapshot. 3D runs are drawn projected on the chosen plane (default xz: a side view).
"""
import argparse
import glob
import os

import h5py
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def colour(f, field):
    # Both invariants need all three normal stresses: in plane strain sigma_zz is
    # stored in the (3, 3) entry, without it pressure and von Mises are wrong.
    if field == "von_mises":
        s = f["stress"][:].reshape(-1, 3, 3)
        dev = s - np.trace(s, axis1=1, axis2=2)[:, None, None] / 3 * np.eye(3)
        return np.sqrt(1.5 * (dev**2).sum(axis=(1, 2))), "von Mises stress"
    if field == "pressure":
        s = f["stress"][:].reshape(-1, 3, 3)
        return -np.trace(s, axis1=1, axis2=2) / 3, "pressure"
    if field == "speed":
        return np.linalg.norm(f["velocity"][:], axis=1), "speed"
    return f[field][:], field.replace("_", " ")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--field")
    ap.add_argument("--time", type=float)
    ap.add_argument("--view", default="xz", choices=["xy", "xz"])
    ap.add_argument("--title", default="")
    a = ap.parse_args()
    files = sorted(glob.glob(os.path.join(a.run, "particles_*.h5")))
    if not files:
        raise SystemExit(f"{a.run}: no particles_*.h5 snapshots")
    if a.time is None:
        path = files[-1]
    else:
        path = min(files, key=lambda p: abs(h5py.File(p, "r").attrs["time"] - a.time))
    with h5py.File(path, "r") as f:
        x = f["position"][:]
        dim = int(f.attrs["dim"])
        field = a.field or ("von_mises" if "stress" in f else "speed" if "velocity" in f else None)
        c, label = colour(f, field) if field else (None, "")
        t = float(f.attrs["time"])
    j = 1 if dim < 3 or a.view == "xy" else 2
    order = np.argsort(x[:, 1]) if dim == 3 and j == 2 else slice(None)
    fig, ax = plt.subplots(figsize=(6, 5))
    n = len(x)
    size = max(0.5, min(12.0, 4e4 / n))
    sc = ax.scatter(x[order, 0], x[order, j], c=None if c is None else c[order], s=size,
                    cmap="viridis", linewidths=0)
    if c is not None:
        fig.colorbar(sc, ax=ax, label=label)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y" if j == 1 else "z")
    ax.set_title(f"{a.title} t = {t:.4g}".strip())
    fig.tight_layout()
    fig.savefig(a.output, dpi=110)


if __name__ == "__main__":
    main()
