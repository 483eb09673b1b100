#!/usr/bin/python3
"""How far a run under `balance = "time"` drifts from the same run under `auto`: the
cuts then follow the clock, so the sums at the nodes the moving cuts pass are added in
another order, and the two runs agree to round-off rather than to the bit.

Usage (after `cargo build --release`; needs h5py):
    /usr/bin/python3 scripts/time_balance_drift.py [--mpmcg target/release/mpmcg]

The 2D block drop of `scripts/bench_peers.py` at 128^2 cells, 2 x 2 particles per
cell, MPMCG, MUSL, to t = 0.4 (about 6000 steps; the block lands on the floor at
t = 0.2), on `mpirun -n 2`, one thread per rank, snapshots every 0.1. Prints, at each
snapshot, the largest difference in position (in cells) and in velocity (over the
largest speed) between the two runs, particle by particle, and beside it the same
between the `auto` run and one on a single rank (the difference the docs allow
between rank counts); and the rebalances each made. About 25 s.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import h5py
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_peers  # noqa: E402

CELLS, PPC, END = 128, 2, 0.4


def by_id(path):
    with h5py.File(path) as f:
        order = np.argsort(f["id"][()])
        return f["position"][()][order], f["velocity"][()][order]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mpmcg", default="target/release/mpmcg")
    a = ap.parse_args()
    binary = os.path.abspath(a.mpmcg)
    mpirun = bench_peers.mpirun()
    text = bench_peers.scene(2, CELLS, PPC, "mpmcg", "musl", END)
    text = text.replace("[output]\nsnapshots = false", '[output]\nevery = 0.1\nfields = ["velocity"]')
    with tempfile.TemporaryDirectory() as tmp:
        for name, ranks, balance in (("auto", 2, "auto"), ("time", 2, "time"), ("one", 1, "auto")):
            path = os.path.join(tmp, f"{name}.toml")
            with open(path, "w") as f:
                f.write(text + f'[parallel]\nbalance = "{balance}"\n')
            cmd = [*mpirun, "-n", str(ranks), "--bind-to", "core", "--map-by", "core", binary]
            cmd += ["run", path, "--out", os.path.join(tmp, name), "--quiet", "--threads", "1"]
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                sys.exit(f"mpmcg failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
            with open(os.path.join(tmp, name, "summary.json")) as f:
                s = json.load(f)
            moves = s["balance"]["rebalances"]
            print(f"{balance} on {ranks}: {s['steps']} steps, {moves} rebalances, last cuts {s['balance']['cuts']}")
        snaps = sorted(n for n in os.listdir(os.path.join(tmp, "auto")) if n.startswith("particles_") and n.endswith(".h5"))
        print("| snapshot | `time` against `auto`: position (cells) | velocity / max speed | bit-identical "
              "| 2 ranks against 1: position | velocity |")
        print("| --- | ---: | ---: | --- | ---: | ---: |")
        for n in snaps:
            (xa, va), (xt, vt), (x1, v1) = (by_id(os.path.join(tmp, b, n)) for b in ("auto", "time", "one"))
            speed = max(np.abs(va).max(), np.finfo(float).tiny)
            same = np.array_equal(xa, xt) and np.array_equal(va, vt)
            print(
                f"| {n} | {np.abs(xa - xt).max() * CELLS:.1e} | {np.abs(va - vt).max() / speed:.1e} "
                f"| {'yes' if same else 'no'} | {np.abs(xa - x1).max() * CELLS:.1e} | {np.abs(va - v1).max() / speed:.1e} |"
            )

if __name__ == "__main__":
    main()
