#!/usr/bin/env python3
"""The sparse grid's benchmark: the same block in its tight box and in a box K times
wider per axis at the same cell size, time per step and peak memory per rank.

The block drop of scripts/bench_peers.py: a neo-Hookean block [0.2, 0.8]^D (E = 1e3,
nu = 0.2, rho = 1) under gravity with slip walls, cfl = 0.3, MUSL, mpmcg gradient.
Tight box: [0, 1]^D with N cells per axis. Wide box: [-(K-1)/2, (K+1)/2]^D with K*N
cells per axis (`--wider K`, default 4; (K-1)/2 * N a multiple of 4), so
the cells, the particles and their global cell offsets modulo 4 are the same and the
runs are the same physics (the walls are far from the block for the few steps timed);
the final momenta agree to round-off (the positions are rounded against another grid
origin).

Time per step: each configuration runs twice, to `warm` and to `warm + steps` steps,
and the step time is the difference of the wall seconds of summary.json divided by the
difference of the steps (start-up and the first steps drop out). Peak memory: the
largest resident set of a rank of the longer run (GNU time's %M, one per rank). One
rank runs pinned to one core (`--cpu`); `--ranks R` runs under `mpirun
--oversubscribe -n R` (not pinned), one thread per rank. Runs are repeated `--repeats`
times interleaved (tight, wide, tight, ...), and the table gives min and median; the
ratio is wide/tight of the medians.

Only the standard library. Usage:
    scripts/bench_sparse.py --mpmcg target/release/mpmcg [--dims 2 3] [--repeats 5]
        [--cpu 1] [--size full|small] [--wider 5] [--ranks 1]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_peers  # noqa: E402  (the block drop's scene, shared)


SIZES = {
    # dim: (cells of the tight box per axis, particles per cell per axis, warm, steps)
    "full": {2: (256, 4, 5, 40), 3: (64, 2, 3, 15)},
    "small": {2: (128, 4, 5, 40), 3: (32, 2, 5, 30)},
}


def scene(dim, cells, ppc, wide, steps):
    """bench_peers.py's block drop, MPMCG with MUSL, to about `steps` steps, in the tight
    box or the one `wide` times wider (0: tight)."""
    k = wide
    lo, hi, n = (-(k - 1) / 2, (k + 1) / 2, k * cells) if wide else (0.0, 1.0, cells)
    name = f"block_drop_{dim}d_{'wide' if wide else 'tight'}"
    end = (steps - 0.5) * bench_peers.wave_dt(cells)
    return bench_peers.scene(dim, n, ppc, "mpmcg", "musl", end, lo, hi, name)


def run(a, tmp, dim, cells, ppc, wide, steps):
    """(steps, wall seconds, peak RSS in MB, final momentum) of one run."""
    path = os.path.join(tmp, f"{dim}d_{wide}_{steps}.toml")
    with open(path, "w") as f:
        f.write(scene(dim, cells, ppc, wide, steps))
    out = os.path.join(tmp, "out")
    rss = os.path.join(tmp, "rss")
    if os.path.exists(rss):
        os.remove(rss)
    cmd = []
    if a.ranks > 1:
        cmd += [*bench_peers.mpirun(), "--oversubscribe", "-n", str(a.ranks)]
    cmd += ["/usr/bin/time", "-f", "%M", "-a", "-o", rss]
    if a.cpu is not None and a.ranks == 1:
        cmd += ["taskset", "-c", str(a.cpu)]
    cmd += [a.mpmcg, "run", path, "--out", out, "--quiet", "--threads", "1"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"mpmcg failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    with open(rss) as f:
        peak = max(int(x) for x in f.read().split()) / 1024.0
    return s["steps"], s["wall_seconds"], peak, s["momentum"]["final"], s["particles"]


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--mpmcg", default="target/release/mpmcg")
    p.add_argument("--dims", type=int, nargs="+", default=[2, 3])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--cpu", type=int, default=None)
    p.add_argument("--size", choices=SIZES, default="full")
    p.add_argument("--wider", type=int, default=4, help="the wide box, times the tight")
    p.add_argument("--ranks", type=int, default=1)
    a = p.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for dim in a.dims:
            cells, ppc, warm, steps = SIZES[a.size][dim]
            times = {False: [], True: []}
            mems = {False: [], True: []}
            moms = {}
            for _ in range(a.repeats):
                for wide in (False, True):
                    k = a.wider if wide else 0
                    s0, w0, _, _, n = run(a, tmp, dim, cells, ppc, k, warm)
                    s1, w1, m1, mom, _ = run(a, tmp, dim, cells, ppc, k, warm + steps)
                    times[wide].append((w1 - w0) / (s1 - s0))
                    mems[wide].append(m1)
                    moms[wide] = mom
            scale = max(abs(x) for x in moms[False] + moms[True]) or 1.0
            diff = max(abs(a - b) for a, b in zip(moms[False], moms[True])) / scale
            rows.append((dim, cells, n, times, mems, diff))
    print(f"mpmcg: {a.mpmcg}, size {a.size}, {a.repeats} repeats, cpu {a.cpu}, "
          f"ranks {a.ranks}")
    print("| dim | box | cells per axis | particles | step ms (min / median) "
          "| peak MB per rank (min / median) |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for dim, cells, n, times, mems, diff in rows:
        for wide in (False, True):
            t, m = times[wide], mems[wide]
            print(
                f"| {dim}D | {f'{a.wider}x wider' if wide else 'tight'} "
                f"| {a.wider * cells if wide else cells} | {n} "
                f"| {1e3 * min(t):.1f} / {1e3 * statistics.median(t):.1f} "
                f"| {min(m):.0f} / {statistics.median(m):.0f} |"
            )
        rt = statistics.median(times[True]) / statistics.median(times[False])
        rm = statistics.median(mems[True]) / statistics.median(mems[False])
        print(f"{dim}D wide/tight: time per step {rt:.3f}x, peak memory {rm:.3f}x; "
              f"final momentum differs by {diff:.1e} (relative; positions round "
              f"differently against another grid origin)")


if __name__ == "__main__":
    main()
