#!/usr/bin/env python3
"""Balance by particles (`auto`) against balance by measured time (`time`) on 2 ranks,
in two cases where equal particle counts are not equal work.

Usage (after `cargo build --release`):
    /usr/bin/python3 scripts/bench_time_balance.py [--mpmcg target/release/mpmcg]
        [--case materials,noisy] [--balance auto,time] [--rounds 3] [--steps 1000]

Both cases are the 2D block drop of `scripts/bench_peers.py` (256^2 cells, 4 x 4
particles per cell, MPMCG, MUSL) on `mpirun -n 2`, one thread per rank, rank r bound
to core r; the blocks split the box at x = 1/2, so each rank starts with half the body.

- `materials`: the body's left half is `j2_plastic` (its stress update costs several
  times the neo-Hookean one's), the right half neo-Hookean as before. Quiet machine.
- `noisy`: the body is neo-Hookean throughout; each run is done quiet and again with
  a busy loop pinned to core 1 (a process that never sleeps, sharing the second
  rank's core), reported as noisy over quiet.

Reported per case and balance: the steps' wall time (`summary.json`'s `wall_seconds`,
set-up excluded), median over the rounds (the balances alternate within a round), the
rebalances and the final cuts. Needs two cores; about 8 minutes with the defaults.
"""

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_peers  # noqa: E402

CELLS, PPC = 256, 4


def run_beside_busy_loop(cmd, noisy, core=1):
    """`cmd`'s completed process; with `noisy`, while a busy loop (a process that never
    sleeps) runs pinned to `core`."""
    with contextlib.ExitStack() as stack:
        if noisy:
            busy = subprocess.Popen(["taskset", "-c", str(core), sys.executable, "-c", "while True: pass"])
            stack.callback(busy.wait)
            stack.callback(busy.kill)
        return subprocess.run(cmd, capture_output=True, text=True)


def scene(case, balance, steps):
    end = (steps - 0.5) * bench_peers.wave_dt(CELLS)
    text = bench_peers.scene(2, CELLS, PPC, "mpmcg", "musl", end)
    if case == "materials":
        lo, hi, mid = bench_peers.LO, bench_peers.HI, 0.5 * (bench_peers.LO + bench_peers.HI)
        body = text[text.index("[[bodies]]") : text.index("[gravity]")]
        halves = ""
        for m, (a, b) in (("plastic", (lo, mid)), ("block", (mid, hi))):
            halves += body.replace('material = "block"', f'material = "{m}"').replace(
                f"lower = [{lo}, {lo}], upper = [{hi}, {hi}]", f"lower = [{a}, {lo}], upper = [{b}, {hi}]"
            )
        plastic = text[text.index("[[materials]]") : text.index("[[bodies]]")]
        plastic = plastic.replace('name = "block"', 'name = "plastic"').replace(
            'model = "neo_hookean"', 'model = "j2_plastic"\nyield_stress = 50.0\nhardening = 100.0'
        )
        text = text.replace(body, plastic + halves)
    return text + f'[parallel]\nbalance = "{balance}"\n'


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mpmcg", default="target/release/mpmcg")
    ap.add_argument("--case", default="materials,noisy")
    ap.add_argument("--balance", default="auto,time")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=1000)
    a = ap.parse_args()
    binary = os.path.abspath(a.mpmcg)
    if os.cpu_count() < 2:
        sys.exit("needs two cores")
    ranks = [*bench_peers.mpirun(), "-n", "2", "--bind-to", "core", "--map-by", "core", binary]
    balances = a.balance.split(",")
    with tempfile.TemporaryDirectory() as tmp:

        def run(case, balance, noisy):
            path = os.path.join(tmp, f"{case}_{balance}.toml")
            with open(path, "w") as f:
                f.write(scene(case, balance, a.steps))
            out = os.path.join(tmp, "out")
            cmd = ranks + ["run", path, "--out", out, "--quiet", "--threads", "1"]
            r = run_beside_busy_loop(cmd, noisy)
            if r.returncode != 0:
                sys.exit(f"mpmcg failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
            with open(os.path.join(out, "summary.json")) as f:
                s = json.load(f)
            return s["wall_seconds"], s["balance"]["rebalances"], s["balance"]["cuts"][0]

        for case in a.case.split(","):
            rows = {b: [] for b in balances}
            for r in range(a.rounds):
                for b in balances:
                    if case == "noisy":
                        quiet = run(case, b, False)[0]
                        wall, moves, cuts = run(case, b, True)
                    else:
                        quiet = None
                        wall, moves, cuts = run(case, b, False)
                    rows[b].append((wall, quiet, moves, cuts))
                    extra = f" (quiet {quiet:.2f} s, {wall / quiet:.2f}x)" if quiet else ""
                    print(f"{case} {b} round {r + 1}: {wall:.2f} s{extra}, {moves} rebalances, cuts {cuts}", file=sys.stderr)
            print(f"{case}: 2D block drop, {CELLS}^2 cells, {PPC}^2 per cell, {a.steps} steps, 2 ranks:")
            for b, rs in rows.items():
                line = f"  balance {b}: {statistics.median(w for w, _, _, _ in rs):.2f} s"
                if case == "noisy":
                    ratios = [w / q for w, q, _, _ in rs]
                    line += f", noisy/quiet {statistics.median(ratios):.2f} (per round {' '.join(f'{x:.2f}' for x in ratios)})"
                line += f", rebalances {' '.join(str(m) for _, _, m, _ in rs)}, last cuts {rs[-1][3]}"
                print(line)


if __name__ == "__main__":
    main()
