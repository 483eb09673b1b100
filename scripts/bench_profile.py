#!/usr/bin/env python3
"""Where a step's time goes on 1, 2 and 4 ranks: summary.json's `profile`.

The block drop of scripts/bench_peers.py (MPMCG, MUSL, one thread per rank; `--size
small`: 128² cells, 4 × 4 particles per cell in 2D; 32³, 2 × 2 × 2 in 3D), run on each
rank count with `mpirun --oversubscribe` (more ranks than cores show the waits of time
slicing, not of a network). Prints per run: the step's mean milliseconds, the share of
it each rank spent blocked in the solver's collectives and exchanges (mean, with the
least and most blocked rank), the synchronisations per step, and the two largest parts.

Only the standard library. Usage:
    scripts/bench_profile.py [--mpmcg target/release/mpmcg] [--size small|full]
        [--dims 2 3] [--ranks 1 2 4]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_peers import SIZES, scene, wave_dt  # noqa: E402


def run(mpmcg, text, ranks, work):
    path = os.path.join(work, "scene.toml")
    with open(path, "w") as f:
        f.write(text)
    out = os.path.join(work, f"out{ranks}")
    cmd = [mpmcg, "run", path, "--out", out, "--quiet", "--threads", "1"]
    if ranks > 1:
        cmd = ["mpirun", "--oversubscribe", "--mca", "mpi_yield_when_idle", "1",
               "-n", str(ranks)] + cmd
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "summary.json")) as f:
        return json.load(f)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mpmcg", default="target/release/mpmcg")
    ap.add_argument("--size", choices=sorted(SIZES), default="small")
    ap.add_argument("--dims", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2, 4])
    a = ap.parse_args()
    print("| dim | ranks | step ms | blocked in collectives | blocked in exchanges "
          "| collectives / exchanges per step | largest parts |")
    print("| ---: | ---: | ---: | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as work:
        for dim in a.dims:
            cells, ppc, warm, steps = SIZES[a.size][dim]
            text = scene(dim, cells, ppc, "mpmcg", "musl", (warm + steps + 0.5) * wave_dt(cells))
            for ranks in a.ranks:
                p = run(a.mpmcg, text, ranks, work)["profile"]
                parts = p["seconds_per_step"]
                total = sum(x["mean"] for x in parts)
                b = p["blocked_seconds_per_step"]
                share = lambda s: "%.1f %% (%.1f–%.1f)" % tuple(  # noqa: E731
                    100 * s[k] / total for k in ("mean", "min", "max"))
                top = sorted(parts, key=lambda x: -x["mean"])[:2]
                print(f"| {dim} | {ranks} | {1e3 * total:.2f} | {share(b['collectives'])} "
                      f"| {share(b['exchanges'])} | {p['step_collectives']:.2f} / "
                      f"{p['step_exchanges']:.0f} | "
                      + ", ".join(f"{x['part']} {100 * x['mean'] / total:.0f} %" for x in top)
                      + " |")


if __name__ == "__main__":
    main()
