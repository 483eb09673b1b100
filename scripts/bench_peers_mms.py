#!/usr/bin/env python3
"""Driver of scripts/bench_peers_mms.sh: error against wall time on the 2D axis-aligned
manufactured solution, mpmcg's schemes beside a warp MLS-MPM, one core each.

Two cases, each at the cell sizes h = 1/N given:
- walls: inputs/axis_aligned_mms_2d.toml (the unit square between slip faces);
- periodic: inputs/axis_aligned_mms_2d_periodic.toml ([0, 2]² wrapped, 2N cells per
  axis for the same h), where no stencil meets a wall.

mpmcg runs `mpmcg sweep` (--threads 1) over its schemes; the peer is
scripts/bench_peers_mms_warp.py (same particles, error measure and time-step rule).
Every run is pinned to one core with taskset. Writes into --out:
    results.csv               case, code, cells per unit length, particles, steps,
                              wall seconds, displacement and velocity errors
    error_vs_wall_time.svg    both cases, every code
    error_vs_h.svg
    report.md                 the table with orders and the command

Runs in the peers' virtual environment (matplotlib); mpmcg's sweep folders stay in
--out/sweep-walls and --out/sweep-periodic.
"""

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import time

SCHEMES = ["mpm", "gimp", "mpmcg-point", "mpmcg-domain"]
PEER = "warp MLS-MPM"
CASES = {
    "walls": ("inputs/axis_aligned_mms_2d.toml", 1),
    "periodic": ("inputs/axis_aligned_mms_2d_periodic.toml", 2),
}


def pinned(cpu, cmd):
    return ["taskset", "-c", str(cpu)] + cmd


def run_mpmcg(a, case, cells):
    scene, span = CASES[case]
    out = os.path.join(a.out, f"sweep-{case}")
    cmd = [a.mpmcg, "sweep", scene, "--cells", ",".join(str(span * n) for n in cells),
           "--gradient", ",".join(a.schemes), "--ppc", str(a.ppc), "--threads", "1",
           "--out", out, "--quiet"]
    print("+", " ".join(cmd), file=sys.stderr)
    subprocess.run(pinned(a.cpu, cmd), check=True)
    rows = []
    with open(os.path.join(out, "results.csv")) as f:
        for r in csv.DictReader(f):
            if r["status"] != "completed":
                continue
            rows.append({
                "case": case, "code": r["gradient"], "cells": int(r["cells"]) // span,
                "particles": int(r["particles"]), "steps": int(r["steps"]),
                "wall_seconds": float(r["wall_seconds"]),
                "displacement_l2": float(r["displacement_l2"]),
                "velocity_l2": float(r["velocity_l2"]),
            })
    return rows


def run_peer(a, case, n):
    cmd = [sys.executable, os.path.join(os.path.dirname(__file__), "bench_peers_mms_warp.py"),
           "--cells", str(n), "--ppc", str(a.ppc), "--cache", a.warp_cache]
    if case == "periodic":
        cmd.append("--periodic")
    print("+", " ".join(cmd), file=sys.stderr)
    p = subprocess.run(pinned(a.cpu, cmd), check=True, capture_output=True, text=True)
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("{")][-1]
    r = json.loads(line)
    return {"case": case, "code": PEER, "cells": n, "particles": r["particles"],
            "steps": r["steps"], "wall_seconds": r["wall_seconds"],
            "displacement_l2": r["displacement_l2"], "velocity_l2": r["velocity_l2"]}


def orders(rows, key):
    out, prev = [], None
    for r in rows:
        out.append("" if prev is None else
                   f"{math.log(prev[key] / r[key]) / math.log(r['cells'] / prev['cells']):.2f}")
        prev = r
    return out


def plot(rows, path, x_key, x_label, ppc):
    import matplotlib
    import matplotlib.ticker
    matplotlib.use("svg")
    # Text as text (the browser lays it out) and fixed ids: small, reproducible files.
    matplotlib.rcParams["svg.fonttype"] = "none"
    matplotlib.rcParams["svg.hashsalt"] = "mpmcg"
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharey=True)
    for ax, case in zip(axes, CASES):
        for code in SCHEMES + [PEER]:
            pts = sorted((r[x_key], r["displacement_l2"]) for r in rows
                         if r["case"] == case and r["code"] == code)
            if pts:
                style = "s--" if code == PEER else "o-"
                ax.loglog(*zip(*pts), style, label=code)
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(f"AA-MMS 2D, {case}, {ppc} × {ppc} particles per cell")
        ax.set_xlabel(x_label)
        ax.grid(True, which="major", alpha=0.3)
    axes[0].set_ylabel("displacement error (max over the run)")
    axes[1].legend()
    fig.tight_layout()
    fig.savefig(path, metadata={"Date": None})
    plt.close(fig)


def command():
    """This run as the wrapper's command line, without what the wrapper adds and where
    the output went."""
    args, skip = [], False
    for w in sys.argv[1:]:
        if skip:
            skip = False
        elif w in ("--mpmcg", "--warp-cache", "--out"):
            skip = True
        elif w != "--report-only":
            args.append(w)
    return " ".join(["scripts/bench_peers_mms.sh"] + args)


def at_equal_time(rows, case, code):
    """The error of `code` at each wall time the peer took, interpolated log-log
    between its neighbouring runs, as a ratio to the peer's error there."""
    mine = sorted((r["wall_seconds"], r["displacement_l2"]) for r in rows
                  if r["case"] == case and r["code"] == code)
    out = []
    for p in sorted((r for r in rows if r["case"] == case and r["code"] == PEER), key=lambda r: r["cells"]):
        t = p["wall_seconds"]
        for (t0, e0), (t1, e1) in zip(mine, mine[1:]):
            if t0 <= t <= t1:
                f = math.log(t / t0) / math.log(t1 / t0)
                e = math.exp(math.log(e0) + f * math.log(e1 / e0))
                out.append((p["cells"], e / p["displacement_l2"]))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mpmcg", required=True)
    ap.add_argument("--warp-cache", required=True)
    ap.add_argument("--cells", default="8,16,32,64,128", help="walls: cells per axis")
    ap.add_argument("--periodic-cells", default="8,16,32,64,128",
                    help="periodic: cells per unit length (the grid has twice as many)")
    ap.add_argument("--schemes", default=",".join(SCHEMES))
    ap.add_argument("--ppc", type=int, default=2)
    ap.add_argument("--cpu", type=int, default=0)
    ap.add_argument("--out", default="out/peers-mms")
    ap.add_argument("--report-only", action="store_true",
                    help="redraw the plots and the report from --out/results.csv")
    a = ap.parse_args()
    a.schemes = a.schemes.split(",")
    os.makedirs(a.out, exist_ok=True)

    started = time.strftime("%Y-%m-%d")
    rows = []
    if a.report_only:
        with open(os.path.join(a.out, "results.csv")) as f:
            for r in csv.DictReader(f):
                rows.append(dict(r, cells=int(r["cells"]), particles=int(r["particles"]), steps=int(r["steps"]),
                                 wall_seconds=float(r["wall_seconds"]),
                                 displacement_l2=float(r["displacement_l2"]), velocity_l2=float(r["velocity_l2"])))
        started = time.strftime("%Y-%m-%d", time.localtime(os.path.getmtime(os.path.join(a.out, "results.csv"))))
    for case, cells in () if a.report_only else (("walls", a.cells), ("periodic", a.periodic_cells)):
        cells = [int(c) for c in cells.split(",") if c]
        if not cells:
            continue
        rows += run_mpmcg(a, case, cells)
        for n in cells:
            rows.append(run_peer(a, case, n))

    keys = ["case", "code", "cells", "particles", "steps", "wall_seconds", "displacement_l2",
            "velocity_l2"]
    if not a.report_only:
        with open(os.path.join(a.out, "results.csv"), "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=keys)
            w.writeheader()
            w.writerows(rows)
    plot(rows, os.path.join(a.out, "error_vs_wall_time.svg"), "wall_seconds", "wall time of the steps (s), one core", a.ppc)
    plot([dict(r, h=1.0 / r["cells"]) for r in rows], os.path.join(a.out, "error_vs_h.svg"), "h",
         "cell size h", a.ppc)

    lines = [f"# AA-MMS 2D: mpmcg and a warp MLS-MPM, {started}", "",
             "    " + command(), "",
             "| case | code | 1/h | particles | steps | wall s | displacement | order | velocity | order |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for case in CASES:
        for code in a.schemes + [PEER]:
            rs = sorted((r for r in rows if r["case"] == case and r["code"] == code),
                        key=lambda r: r["cells"])
            ou, ov = orders(rs, "displacement_l2"), orders(rs, "velocity_l2")
            for r, u, v in zip(rs, ou, ov):
                lines.append(f"| {case} | {code} | {r['cells']} | {r['particles']} | {r['steps']} | "
                             f"{r['wall_seconds']:.3g} | {r['displacement_l2']:.3e} | {u} | "
                             f"{r['velocity_l2']:.3e} | {v} |")
    lines += ["", "The error at the peer's wall time, interpolated between runs, over the peer's error "
              "(below 1: more accurate for the same time):", ""]
    for case in CASES:
        for code in a.schemes:
            ratios = at_equal_time(rows, case, code)
            if ratios:
                lines.append(f"- {case}, {code}: " + ", ".join(f"{r:.2f} at the peer's 1/h = {n}" for n, r in ratios))
    with open(os.path.join(a.out, "report.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
