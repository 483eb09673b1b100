#!/usr/bin/env python3
"""Phase shares of a step for two mpmcg binaries, from interleaved perf profiles.

    /usr/bin/python3 scripts/perf_shares.py --a NEW --b OLD SCENE [--runs 3] [--cpu 0]

Runs `perf record` on A and B in turn (A B A B ...), one thread pinned to one core, and
gives each phase's share of the step's samples (`scripts/perf_phases.py`) per binary:
the mean over the runs, its range, and A's mean over B's. A share is a ratio within
one run, so a machine whose speed drifts between runs (this 2-vCPU VM: single paired
wall-clock ratios of 0.73 to 1.39 in one sitting) moves it far less than it moves
wall time. It answers "did this pass get cheaper relative to the rest of the step";
`farm-bench` still gives the wall-clock claim. With `--phase NAME` (a phase as the table
names it) it also gives what the shares imply if only that phase changed: A's time for
it and A's step time, each over B's, from shares s_A and s_B of their own steps:
(s_A / (1 − s_A)) / (s_B / (1 − s_B)) and (1 − s_B) / (1 − s_A).

Needs perf, binutils' addr2line, and builds with line tables (the release profile has
them).
"""

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
LINE = re.compile(r"^\s+([0-9.]+) %\s+(\S.*)$")


def shares(binary, scene, cpu, tmp):
    """{phase: percent} of one profiled run of `binary` on `scene`."""
    data = os.path.join(tmp, "perf.data")
    cmd = ["perf", "record", "-q", "-F", "2999", "-o", data, "--"]
    if cpu is not None:
        cmd += ["taskset", "-c", str(cpu)]
    cmd += [binary, "run", scene, "--out", os.path.join(tmp, "out"), "--threads", "1", "--quiet"]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    out = subprocess.run(
        [sys.executable, os.path.join(HERE, "perf_phases.py"), data, "--binary", binary],
        check=True, capture_output=True, text=True,
    ).stdout
    got = {}
    for line in out.splitlines():
        if line.startswith("outside"):
            break
        m = LINE.match(line)
        if m:
            got[m.group(2).strip()] = float(m.group(1))
    return got


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("--a", required=True, help="the binary under test")
    ap.add_argument("--b", required=True, help="the binary to compare with")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--cpu", type=int, default=0, help="the core to pin to (-1: none)")
    ap.add_argument("--phase", help="the one phase the change touched (see above)")
    a = ap.parse_args()
    cpu = None if a.cpu < 0 else a.cpu
    runs = {"a": [], "b": []}
    with tempfile.TemporaryDirectory(prefix="perf_shares_") as tmp:
        for k in range(a.runs):
            for key in ("a", "b"):
                runs[key].append(shares(getattr(a, key), a.scene, cpu, tmp))
            print(f"  round {k + 1} of {a.runs}", file=sys.stderr, flush=True)
    phases = sorted({p for r in runs["a"] + runs["b"] for p in r},
                    key=lambda p: -statistics.mean(r.get(p, 0.0) for r in runs["b"]))
    print(f"{a.scene}: share of the step's samples, mean (min–max) of {a.runs} runs each")
    print("| phase | A | B | A / B |")
    print("|---|---:|---:|---:|")
    for p in phases:
        va = [r.get(p, 0.0) for r in runs["a"]]
        vb = [r.get(p, 0.0) for r in runs["b"]]
        ma, mb = statistics.mean(va), statistics.mean(vb)
        if max(ma, mb) < 0.5:
            continue
        ratio = f"{ma / mb:.3f}" if mb > 0 else "—"
        print(f"| {p} | {ma:.1f} % ({min(va):.1f}–{max(va):.1f}) | {mb:.1f} % ({min(vb):.1f}–{max(vb):.1f}) | {ratio} |")
    if a.phase:
        if a.phase not in phases:
            print(f"error: no phase named {a.phase!r}; the phases: {', '.join(phases)}", file=sys.stderr)
            sys.exit(2)
        sa = statistics.mean(r.get(a.phase, 0.0) for r in runs["a"]) / 100
        sb = statistics.mean(r.get(a.phase, 0.0) for r in runs["b"]) / 100
        print(f"If only {a.phase} changed: its time A / B {(sa / (1 - sa)) / (sb / (1 - sb)):.3f}, "
              f"the step's {(1 - sb) / (1 - sa):.3f}")


if __name__ == "__main__":
    main()
