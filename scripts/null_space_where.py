#!/usr/bin/env python3
"""Where the velocity noise the grid cannot see sits in the coarse cantilever.

Runs inputs/cantilever_coarse.toml without XPIC (FLIP, 2 x 2 particles per cell) with
the `null_velocity` field in every snapshot (every 0.05 s), then prints at a few times
the invisible share of the kinetic energy (`null_kinetic / kinetic`) and where that
energy sits, by the particles' initial places: per half metre along the beam from the
clamp, in the top half of the beam, and in the 5 % of particles that hold most of it.
The particles share one mass, so a particle's energy share is its share of |v_null|^2.

Needs h5py: run it with /usr/bin/python3 after scripts/setup.sh. Usage:
    /usr/bin/python3 scripts/null_space_where.py --mpmcg target/release/mpmcg
        [--gradient mpmcg] [--out out/null_space_where]
"""

import argparse
import glob
import os
import re
import subprocess

import h5py
import numpy as np

TIMES = [0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0]


def scene(gradient):
    here = os.path.dirname(os.path.abspath(__file__))
    text = open(os.path.join(here, "..", "inputs", "cantilever_coarse.toml")).read()
    text = text.replace("xpic = 2\n", "")
    text = text.replace('gradient = "mpmcg"', f'gradient = "{gradient}"')
    return re.sub(r"fields = \[.*\]", 'fields = ["velocity", "null_velocity"]', text)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mpmcg", default="target/release/mpmcg")
    ap.add_argument("--gradient", default="mpmcg")
    ap.add_argument("--out", default="out/null_space_where")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    path = os.path.join(a.out, "scene.toml")
    with open(path, "w") as f:
        f.write(scene(a.gradient))
    subprocess.run([a.mpmcg, "run", path, "--out", a.out, "--quiet"], check=True)
    files = sorted(glob.glob(os.path.join(a.out, "particles_*.h5")))
    with h5py.File(files[0]) as f:
        ref = dict(zip(f["id"][:], f["position"][:]))
    print("time  invisible/KE  share by 0.5 m from the clamp (0 to 4 m)        top half  top 5 %")
    for name in files:
        with h5py.File(name) as f:
            t = f.attrs["time"]
            if not any(abs(t - w) < 0.026 for w in TIMES):
                continue
            x0 = np.array([ref[i] for i in f["id"][:]])
            e = (f["null_velocity"][:] ** 2).sum(1)
            ke = (f["velocity"][:] ** 2).sum(1).sum()
        tot = e.sum()
        along = [e[(x0[:, 0] >= s) & (x0[:, 0] < s + 0.5)].sum() / tot for s in np.arange(0, 4, 0.5)]
        top = e[x0[:, 1] > 0.5].sum() / tot
        most = np.sort(e)[::-1][: len(e) // 20].sum() / tot
        cols = " ".join(f"{s:.2f}" for s in along)
        print(f"{t:4.2f}  {tot / ke:12.2e}  {cols}  {top:8.2f}  {most:7.2f}")


if __name__ == "__main__":
    main()
