#!/usr/bin/env python3
"""What a two-rank step could reach under a noisy neighbour, whatever its physics: the
model of `scripts/noisy_model.c` (phases of calibrated arithmetic, each ended by a
message to the other rank) run quiet and with a busy loop sharing rank 1's core, for
step structures today's solver has and ones it does not have yet.

Usage:
    /usr/bin/python3 scripts/bench_noisy_model.py [--rounds 3] [--steps 600]

The model's step is 9 phases of 0.75 ms per rank at an even split (the 2D block drop of
`scripts/bench_time_balance.py`: 600 steps take 4.1 s quiet on this VM, 9
synchronisation points a step). `mpirun -n 2 --bind-to core --map-by core`, rank r on
core r; the busy loop is pinned to core 1, as in `bench_time_balance.py`. Each noisy
row is reported over the quiet time of today's structure (lock-step, even split,
spinning), median over the rounds. Needs two cores and `mpicc`; about 4 minutes.
"""

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_peers  # noqa: E402
import bench_time_balance  # noqa: E402

PHASES, PHASE_US = 9, 750

# (what it models, rank 1's share, lookahead in phases, interior fraction, nap in µs)
ROWS = [
    ("today: lock-step, even split, waits spin (`auto`)", 0.5, 1, 0.0, 0),
    ("lock-step, rank 1 a third (`time`)", 1 / 3, 1, 0.0, 0),
    ("lock-step, a third, waits sleep", 1 / 3, 1, 0.0, 20),
    ("90 % of each phase before its wait, a third", 1 / 3, 1, 0.9, 0),
    ("90 % before the wait, a third, waits sleep", 1 / 3, 1, 0.9, 20),
    ("90 % before the wait, even split, waits sleep", 0.5, 1, 0.9, 20),
    ("one phase ahead, a third, waits sleep", 1 / 3, 2, 0.0, 20),
    ("three phases ahead, a third", 1 / 3, 4, 0.0, 0),
]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=600)
    a = ap.parse_args()
    mpirun, mpicc = bench_peers.mpirun(), shutil.which("mpicc")
    if mpicc is None:
        sys.exit("mpicc not found (scripts/setup.sh installs Open MPI)")
    if os.cpu_count() < 2:
        sys.exit("needs two cores")
    source = os.path.join(os.path.dirname(os.path.abspath(__file__)), "noisy_model.c")
    with tempfile.TemporaryDirectory() as tmp:
        binary = os.path.join(tmp, "noisy_model")
        subprocess.run([mpicc, "-O2", "-o", binary, source], check=True)

        def run(share, lookahead, interior, nap, noisy):
            cmd = [*mpirun, "-n", "2", "--bind-to", "core", "--map-by", "core", binary]
            cmd += [str(a.steps), str(PHASES), str(PHASE_US), f"{share:.6f}", str(lookahead), str(interior), str(nap)]
            r = bench_time_balance.run_beside_busy_loop(cmd, noisy)
            if r.returncode != 0:
                sys.exit(f"the model failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
            return float(r.stdout.strip())

        quiet, noisy = [], {k: [] for k in range(len(ROWS))}
        for r in range(a.rounds):
            quiet.append(run(0.5, 1, 0.0, 0, False))
            for k, (_, share, lookahead, interior, nap) in enumerate(ROWS):
                noisy[k].append(run(share, lookahead, interior, nap, True))
            print(f"round {r + 1}: quiet {quiet[-1]:.2f} s", file=sys.stderr)
        q = statistics.median(quiet)
        print(f"quiet, today's structure: {q:.2f} s ({a.steps} steps, median of {a.rounds})\n")
        print("| step structure, busy loop on rank 1's core | noisy over quiet (median) | range |")
        print("| --- | ---: | --- |")
        for k, (name, *_) in enumerate(ROWS):
            t = noisy[k]
            print(f"| {name} | {statistics.median(t) / q:.2f}× | {min(t) / q:.2f}–{max(t) / q:.2f} |")


if __name__ == "__main__":
    main()
