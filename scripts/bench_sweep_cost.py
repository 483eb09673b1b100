#!/usr/bin/env python3
"""What a benchmark scene's exact solution costs: the steady-state particle updates per
second (pups) of the sweep's scenes against the block drop of `scripts/bench_peers.py`
at (nearly) the same particle count, with the same gradient, update and particles per
cell, one core each (issue 14: within 1.5x).

Usage (after `cargo build --release`):
    /usr/bin/python3 scripts/bench_sweep_cost.py [--mpmcg target/release/mpmcg]
        [--repeats 3] [--cpu 0] [--case mms:64 --case vortex:128 ...]

A case is `SCENE:CELLS`, SCENE one of `mms` (inputs/axis_aligned_mms_2d.toml) and
`vortex` (inputs/generalized_vortex.toml), CELLS its cells per axis; the default is the
finest grid of each committed sweep (mms:64, vortex:128). The block drop's block is
[0.2, 0.8]^2 with a whole number of cells, the box around it a whole number of cells
too, so that the block holds the square number of particles nearest the scene's count.

Steady state as in bench_peers.py: each scene runs to two end times (a fifth of its
own and its own, the block drop to the same step counts), and pups are particles x
(difference of steps) / (difference of wall seconds in summary.json), so seeding and
start-up drop out. Snapshots are off in both. The rounds are interleaved; the table
gives medians with ranges, and the ratio is the median of the per-round ratios.
"""

import argparse
import math
import os
import re
import statistics
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_peers as peers  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = {
    "mms": os.path.join(ROOT, "inputs", "axis_aligned_mms_2d.toml"),
    "vortex": os.path.join(ROOT, "inputs", "generalized_vortex.toml"),
}


def key(text, name):
    m = re.search(rf"^{name}\s*=\s*([^#\n]+)", text, re.M)
    return m.group(1).strip() if m else None


def benchmark_scene(path, cells, end):
    """The scene file at `cells` per axis, ending at `end`, without snapshots; MPMCG at
    the particle, as the block drop runs it (scripts/bench_peers.py's POINT_RULE), so
    that the two differ in their problem alone."""
    text = open(path).read()
    if key(text, "gradient") == '"mpmcg"':
        text = text.replace("[method]\n", "[method]\n" + peers.POINT_RULE, 1)
    text = re.sub(r"^cells\s*=.*$", f"cells = [{cells}, {cells}]", text, count=1, flags=re.M)
    text = re.sub(r"^end\s*=.*$", f"end = {end!r}", text, count=1, flags=re.M)
    text = re.sub(r"^\[output\][^\[]*", "", text, flags=re.M)
    return text + "\n[output]\nsnapshots = false\n"


def block_drop(n, ppc, gradient, update, steps):
    """The block drop whose block holds the square particle count nearest `n`."""
    b = max(1, round(math.sqrt(n) / ppc))  # block cells per axis
    h = (peers.HI - peers.LO) / b
    pad = round(peers.LO / h)
    lower, upper = peers.LO - pad * h, peers.HI + pad * h
    cells = b + 2 * pad
    # The box is not the unit box: the first step's size is that of h.
    end = (steps - 0.5) * peers.wave_dt(1.0 / h)
    return peers.scene(2, cells, ppc, gradient, update, end, lower, upper, name="block_drop_2d")


def run(a, tmp, name, text):
    path = os.path.join(tmp, name + ".toml")
    with open(path, "w") as f:
        f.write(text)
    return peers.run_scene(a, path, os.path.join(tmp, "out"))


def pups(runs):
    (n, s0, w0), (n1, s1, w1) = runs
    assert n == n1
    return n * (s1 - s0) / (w1 - w0)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mpmcg", default=os.path.join(ROOT, "target", "release", "mpmcg"))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cpu", type=int, default=0, help="the core to pin to (-1: none)")
    ap.add_argument("--case", action="append", help="SCENE:CELLS (mms:64, vortex:128)")
    a = ap.parse_args()
    a.cpu = None if a.cpu < 0 else a.cpu
    cases = a.case or ["mms:64", "vortex:128"]
    os.environ.update(OMP_NUM_THREADS="1", RAYON_NUM_THREADS="1")
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_sweep_cost_") as tmp:
        for case in cases:
            scene, cells = case.split(":")
            cells = int(cells)
            text = open(SCENES[scene]).read()
            end = float(key(text, "end"))
            gradient = key(text, "gradient").strip('"')
            update = key(text, "update").strip('"')
            ppc = int(key(text, "particles_per_cell"))
            bench, drop, ratios = [], [], []
            counts = None
            for rep in range(a.repeats):
                br = [run(a, tmp, f"{scene}_{k}", benchmark_scene(SCENES[scene], cells, end * f))
                      for k, f in enumerate((0.2, 1.0))]
                dr = [run(a, tmp, f"drop_{k}", block_drop(br[0][0], ppc, gradient, update, s))
                      for k, s in enumerate((br[0][1], br[1][1]))]
                counts = (br[0][0], dr[0][0], br[0][1], br[1][1], dr[0][1], dr[1][1])
                bench.append(pups(br))
                drop.append(pups(dr))
                ratios.append(drop[-1] / bench[-1])
                print(f"  {case} #{rep + 1}: {bench[-1]:.3e} pups, block drop {drop[-1]:.3e}",
                      file=sys.stderr, flush=True)
            rows.append((case, gradient, update, ppc, counts, bench, drop, ratios))
    print("| scene | scheme | particles (scene / block drop) | steps | scene pups | block drop pups | block drop / scene |")
    print("|---|---|---|---|---:|---:|---:|")
    for case, gradient, update, ppc, c, bench, drop, ratios in rows:
        print(f"| {case} | {gradient} {update.upper()}, {ppc}×{ppc} per cell | {c[0]} / {c[1]} | "
              f"{c[2]}→{c[3]} / {c[4]}→{c[5]} | {peers.fmt(bench)} | {peers.fmt(drop)} | "
              f"{statistics.median(ratios):.2f} |")


if __name__ == "__main__":
    main()
