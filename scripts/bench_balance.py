#!/usr/bin/env python3
"""Load balance benchmark (issue 13): an off-centre body on 1, 2 and 4 ranks, with the
blocks fixed (`[parallel] balance = "off"`) and following the particles ("auto").

The scene is the block drop of scripts/bench_peers.py moved off-centre and thrown
sideways: a neo-Hookean block [0.05, 0.45]^2 (E = 1e3, nu = 0.2, rho = 1)
in the unit box with slip walls, gravity, initial velocity (6, 0), cfl = 0.3, MPMCG,
MUSL, 4 x 4 particles per cell on 256^2 cells (`--size small`: 128^2). Equal blocks
give one rank every particle at the start (on 2 and on 4 ranks); the body then
crosses the middle.

Speed: each configuration runs to `warm` and to `warm + steps` steps; particle updates
per second are particles x (difference of steps) / (difference of wall seconds of
summary.json), so start-up and seeding drop out. Balance: summary.json's `balance`
(imbalance = largest rank's particles over the mean, sampled every `check_every`
steps over the longer run: mean, max and the share of samples within 1.10).
Runs with more ranks than cores (--oversubscribe) show the balance, not the speed.

Only the standard library. Usage:
    scripts/bench_balance.py [--mpmcg target/release/mpmcg] [--size full|small]
        [--repeats 3] [--ranks 1 2 4]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_peers  # noqa: E402  (the block drop's scene and time step)

SIZES = {"full": (256, 20, 200), "small": (128, 20, 400)}  # cells, warm, steps


def scene(cells, balance, steps):
    end = (steps - 0.5) * bench_peers.wave_dt(cells)
    text = bench_peers.scene(2, cells, 4, "mpmcg", "musl", end, name="off_centre")
    text = text.replace("lower = [0.2, 0.2], upper = [0.8, 0.8]",
                        "lower = [0.05, 0.05], upper = [0.45, 0.45]")
    assert "0.05, 0.05" in text, "the block drop's body moved: update bench_balance.py"
    text = text.replace("particles_per_cell = 4", "particles_per_cell = 4\nvelocity = [6.0, 0.0]")
    return text + f'[parallel]\nbalance = "{balance}"\n'


def run(a, tmp, ranks, balance, steps, cells):
    path = os.path.join(tmp, f"{ranks}_{balance}_{steps}.toml")
    with open(path, "w") as f:
        f.write(scene(cells, balance, steps))
    out = os.path.join(tmp, "out")
    cmd = [a.mpmcg, "run", path, "--out", out, "--quiet", "--threads", "1"]
    if ranks > 1:
        root = ["--allow-run-as-root"] if os.geteuid() == 0 else []
        cmd = ["mpirun", *root, "--oversubscribe", "-n", str(ranks), *cmd]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"mpmcg failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    if s["status"] != "completed":
        sys.exit(f"{' '.join(cmd)}: {s['status']}: {s.get('message')}")
    return s


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--mpmcg", default="target/release/mpmcg")
    p.add_argument("--size", choices=SIZES, default="full")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--ranks", type=int, nargs="+", default=[1, 2, 4])
    a = p.parse_args()
    cells, warm, steps = SIZES[a.size]
    configs = [(n, b) for n in a.ranks for b in (["off"] if n == 1 else ["off", "auto"])]
    pups = {c: [] for c in configs}
    last = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(a.repeats):
            for n, b in configs:
                s0 = run(a, tmp, n, b, warm, cells)
                s1 = run(a, tmp, n, b, warm + steps, cells)
                pups[(n, b)].append(
                    s1["particles"] * (s1["steps"] - s0["steps"])
                    / (s1["wall_seconds"] - s0["wall_seconds"]))
                last[(n, b)] = s1
    one = statistics.median(pups[(1, "off")]) if (1, "off") in pups else None
    print(f"mpmcg: {a.mpmcg}, {cells}^2 cells, {last[configs[0]]['particles']} particles, "
          f"{warm} + {steps} steps, {a.repeats} repeats (median; range)")
    print("| ranks | balance | pups | vs 1 rank | rebalances | imbalance mean / max "
          "| samples within 1.10 | final cuts |")
    print("| ---: | --- | ---: | ---: | ---: | ---: | ---: | --- |")
    for c in configs:
        n, b = c
        s = last[c]["balance"]
        med = statistics.median(pups[c])
        rel = f"{med / one:.2f}x" if one else "-"
        print(f"| {n} | {b} | {med:.3e} ({min(pups[c]):.2e}-{max(pups[c]):.2e}) | {rel} "
              f"| {s['rebalances']} | {s['imbalance_mean']:.3f} / {s['imbalance_max']:.3f} "
              f"| {100 * s['within_10_percent']:.0f} % of {s['checks']} | {s['cuts']} |")


if __name__ == "__main__":
    main()
