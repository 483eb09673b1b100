#!/usr/bin/env python3
"""Steady-state speed-up of 2 threads and of 2 ranks over one thread on the block drop
of `scripts/bench_peers.py` (issue 14: 2 threads >= 1.85x, 2 ranks >= 1.9x).

Usage (after `cargo build --release`):
    /usr/bin/python3 scripts/bench_parallel.py [--mpmcg target/release/mpmcg]
        [--dims 2,3] [--rounds 3] [--gradient mpmcg] [--update musl]

Per dimension (2D 256^2 cells x 4^2 per cell, 3D 64^3 x 2^3, MUSL, MPMCG) and round,
four configurations run in turn: 1 thread pinned to core 0 (`taskset -c 0`), 1 rank
with `--threads 2`, `mpirun -n 2` with one thread each, and "2 copies": two independent
one-thread runs of the same scene at once, pinned to cores 0 and 1. Each runs the scene
to two step counts (10 and 110 in 2D, 5 and 45 in 3D) and the particle updates per
second are particles x copies x (difference of steps) / (difference of whole-process
wall seconds, until every copy ended), so seeding and start-up drop out. Prints each
round and the medians; the speed-ups are the median pups over the median one-thread
pups, with the per-round ratios.

The copies share no work and exchange nothing, so their speed-up is what the machine
gives two cores doing this step at all (its shared memory bus, caches and clock):
the ceiling for 2 threads and 2 ranks, whose speed-ups are also given as a fraction
of it. About 7 minutes for both dimensions and 3 rounds on a 2-core machine; run it
on an idle one.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_peers  # noqa: E402

SIZES = {2: (256, 4, 10, 110), 3: (64, 2, 5, 45)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mpmcg", default="target/release/mpmcg")
    ap.add_argument("--dims", default="2,3")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--gradient", default="mpmcg")
    ap.add_argument("--update", default="musl")
    a = ap.parse_args()
    binary = os.path.abspath(a.mpmcg)
    mpirun = bench_peers.mpirun()
    # Each configuration: the commands started together (one per copy), before and
    # after `run SCENE --out DIR --quiet`.
    single = ["--threads", "1"]
    configs = {
        "1 thread": [(["taskset", "-c", "0", binary], single)],
        "2 threads": [([binary], ["--threads", "2"])],
        "2 ranks": [([*mpirun, "--oversubscribe", "-n", "2", binary], single)],
        "2 copies": [(["taskset", "-c", str(c), binary], single) for c in (0, 1)],
    }
    with tempfile.TemporaryDirectory() as tmp:

        def run(copies, scene, out):
            """Particles (all copies'), steps and wall seconds until every copy ended."""
            t = time.perf_counter()
            procs = []
            for c, (pre, post) in enumerate(copies):
                cmd = pre + ["run", scene, "--out", f"{out}_{c}", "--quiet"] + post
                procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
            done = [p.communicate() for p in procs]
            wall = time.perf_counter() - t
            particles, steps = 0, set()
            for c, (p, (_, err)) in enumerate(zip(procs, done)):
                if p.returncode != 0:
                    sys.exit(f"mpmcg failed ({p.returncode}): {scene}\n{err}")
                with open(os.path.join(f"{out}_{c}", "summary.json")) as f:
                    s = json.load(f)
                particles += s["particles"]
                steps.add(s["steps"])
            assert len(steps) == 1, f"copies ended at different steps: {steps}"
            return particles, steps.pop(), wall

        for d in (int(x) for x in a.dims.split(",")):
            cells, ppc, short, long = SIZES[d]
            scenes = []
            for steps in (short, long):
                path = os.path.join(tmp, f"block_{d}d_{steps}.toml")
                end = (steps - 0.5) * bench_peers.wave_dt(cells)
                with open(path, "w") as f:
                    f.write(bench_peers.scene(d, cells, ppc, a.gradient, a.update, end))
                scenes.append(path)
            pups = {k: [] for k in configs}
            for r in range(a.rounds):
                for k, copies in configs.items():
                    n0, s0, w0 = run(copies, scenes[0], os.path.join(tmp, f"o{d}a"))
                    n1, s1, w1 = run(copies, scenes[1], os.path.join(tmp, f"o{d}b"))
                    assert n0 == n1
                    pups[k].append(n1 * (s1 - s0) / (w1 - w0))
                    print(f"{d}D round {r + 1} {k}: {pups[k][-1]:.3e} pups", file=sys.stderr)
            one = statistics.median(pups["1 thread"])
            print(f"{d}D {a.gradient} {a.update}, {cells}^{d} cells, {ppc}^{d} per cell, median of {a.rounds}:")
            for k, v in pups.items():
                line = f"  {k}: {statistics.median(v):.3e} pups"
                if k != "1 thread":
                    per = " ".join(f"{x / y:.2f}" for x, y in zip(v, pups["1 thread"]))
                    line += f", {statistics.median(v) / one:.2f}x one thread (per round {per})"
                if k in ("2 threads", "2 ranks"):
                    ceiling = statistics.median(pups["2 copies"])
                    line += f", {statistics.median(v) / ceiling:.2f} of 2 copies'"
                print(line)


if __name__ == "__main__":
    main()
