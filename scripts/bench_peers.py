#!/usr/bin/env python3
"""Driver of scripts/bench_peers.sh: the block drop in mpmcg and in a warp MLS-MPM, one
core each, and a table of steady-state particle updates per second (pups).

The block drop: a neo-Hookean block [0.2, 0.8]^D (E = 1e3, ν = 0.2, ρ = 1) falls under
gravity in a unit box with slip walls, `cfl = 0.3`. Both codes seed the same particles
(sub-cell centres inside the block), so their particle counts are equal:
    2D: 256² cells, 4 × 4 particles per cell, 376 996 particles
    3D:  64³ cells, 2 × 2 × 2 particles per cell, 438 976 particles
(`--size small`: 128² and 32³, a quarter and an eighth of that.)

Steady state: mpmcg runs the scene twice, to `warmup` steps and to `warmup + steps`
steps, and its pups are particles × (difference of the steps) / (difference of the wall
seconds in summary.json), so start-up and the first, cold steps drop out. warp times
its own `steps` steps after `warmup` steps in one process (the first launch compiles
the kernels; they are cached). Each configuration runs `--repeats` times, interleaved
(mpmcg's three schemes, warp f64, warp f32, then again), and the table gives the
median with the range; a ratio is the median of the ratios within each round, which
holds better than a ratio of medians when the machine's speed drifts.

Only the standard library: the warp side runs in the virtual environment's Python
(`--warp-python`), this driver in any Python 3.
"""

import argparse
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

YOUNG, NU, RHO, GRAVITY, CFL = 1.0e3, 0.2, 1.0, -9.81, 0.3
LO, HI = 0.2, 0.8

# (label, gradient, update)
MPMCG_SCHEMES = [
    ("mpmcg, mpmcg gradient, MUSL", "mpmcg", "musl"),
    ("mpmcg, mpmcg gradient, USL", "mpmcg", "usl"),
    ("mpmcg, mpm gradient, USL", "mpm", "usl"),
]
WARP_PRECISIONS = [("warp MLS-MPM, f64", "f64"), ("warp MLS-MPM, f32", "f32")]

SIZES = {
    # dim: (cells, particles per cell per axis, warm-up steps, timed steps)
    "full": {2: (256, 4, 10, 100), 3: (64, 2, 5, 40)},
    "small": {2: (128, 4, 10, 100), 3: (32, 2, 10, 100)},
}


def wave_dt(cells):
    """The first step's size: cfl · h / c (the block starts at rest)."""
    mu = YOUNG / (2 * (1 + NU))
    lam = YOUNG * NU / ((1 + NU) * (1 - 2 * NU))
    return CFL * (1.0 / cells) / math.sqrt((lam + 2 * mu) / RHO)


# MPMCG at the particle, the scheme whose work per particle compares with the peer's;
# the default's domain rule, centroid passes and sharpening cost 4-8 times its step
# (docs/schemes.md, "Defaults"). The speed figures of the docs are of this method.
POINT_RULE = 'quadrature = "point"\ncentroid_passes = 0\nsharpen = 0.0\n'


def scene(dim, cells, ppc, gradient, update, end, lower=0.0, upper=1.0, name=None):
    """The block drop's scene file: the block [LO, HI]^D in the box [lower, upper]^D with
    `cells` cells per axis (scripts/bench_sparse.py widens the box); MPMCG at the
    particle (POINT_RULE)."""
    v = lambda x: "[" + ", ".join(str(x) for _ in range(dim)) + "]"  # noqa: E731
    g = [0.0] * dim
    g[1] = GRAVITY
    faces = ", ".join(f'{ax}_{side} = "slip"' for ax in "xyz"[:dim] for side in ("lower", "upper"))
    return f"""name = "{name or f'block_drop_{dim}d'}"
dim = {dim}
[time]
end = {end!r}
cfl = {CFL}
[method]
gradient = "{gradient}"
update = "{update}"
{POINT_RULE if gradient == "mpmcg" else ""}[grid]
lower = {v(lower)}
upper = {v(upper)}
cells = {v(cells)}
boundary = {{ {faces} }}
[[materials]]
name = "block"
model = "neo_hookean"
density = {RHO}
youngs_modulus = {YOUNG}
poisson_ratio = {NU}
[[bodies]]
material = "block"
shape = {{ box = {{ lower = {v(LO)}, upper = {v(HI)} }} }}
particles_per_cell = {ppc}
[gravity]
value = [{", ".join(str(x) for x in g)}]
[output]
snapshots = false
"""


def mpirun():
    """The start of an `mpirun` command: its path, and as root the flag Open MPI asks for;
    exits with a message where Open MPI is not installed."""
    path = shutil.which("mpirun")
    if path is None:
        sys.exit("mpirun not found (scripts/setup.sh installs Open MPI)")
    return [path, "--allow-run-as-root"] if os.geteuid() == 0 else [path]


def pinned(cmd, cpu):
    return (["taskset", "-c", str(cpu)] if cpu is not None else []) + cmd


def run_mpmcg(a, tmp, dim, cells, ppc, gradient, update, steps):
    """One mpmcg run to about `steps` steps: (particles, steps, wall seconds)."""
    # A little short of `steps` first steps, so that the CFL step (which shrinks a
    # little as the block speeds up) does not add one.
    end = (steps - 0.5) * wave_dt(cells)
    path = os.path.join(tmp, f"{dim}d_{gradient}_{update}_{steps}.toml")
    with open(path, "w") as f:
        f.write(scene(dim, cells, ppc, gradient, update, end))
    return run_scene(a, path, os.path.join(tmp, "out"))


def run_scene(a, path, out):
    """`mpmcg run` of the scene file `path` on one thread, pinned to `a.cpu`, output in
    `out`; exits unless it completed. Returns (particles, steps, wall seconds)."""
    cmd = pinned([a.mpmcg, "run", path, "--out", out, "--quiet", "--threads", "1"], a.cpu)
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"mpmcg failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    if s["status"] != "completed":
        sys.exit(f"{path}: {s['status']}: {s.get('message')}")
    return s["particles"], s["steps"], s["wall_seconds"]


def mpmcg_pups(a, tmp, dim, cells, ppc, warm, steps, gradient, update):
    n, s0, w0 = run_mpmcg(a, tmp, dim, cells, ppc, gradient, update, warm)
    n1, s1, w1 = run_mpmcg(a, tmp, dim, cells, ppc, gradient, update, warm + steps)
    assert n == n1
    return n, n * (s1 - s0) / (w1 - w0)


def warp_pups(a, dim, cells, ppc, warm, steps, precision):
    cmd = pinned(
        [
            a.warp_python,
            os.path.join(os.path.dirname(os.path.abspath(__file__)), "bench_peers_warp.py"),
            "--dim", str(dim), "--cells", str(cells), "--ppc", str(ppc),
            "--block", str(LO), str(HI), "--precision", precision,
            "--steps", str(steps), "--warmup", str(warm), "--cfl", str(CFL),
        ]
        + (["--cache", a.warp_cache] if a.warp_cache else []),
        a.cpu,
    )
    r = subprocess.run(cmd, capture_output=True, text=True)
    lines = [l for l in r.stdout.splitlines() if l.startswith("{")]
    if r.returncode != 0 or not lines:
        sys.exit(f"warp failed ({r.returncode}): {' '.join(cmd)}\n{r.stdout}\n{r.stderr}")
    w = json.loads(lines[-1])
    return w["particles"], w["pups"], w["warp"]


def sci(x):
    """3 significant digits, `6.27e6` rather than `6.27e+06`."""
    m, e = f"{x:.2e}".split("e")
    return f"{m}e{int(e)}"


def fmt(xs):
    med = statistics.median(xs)
    if len(xs) == 1:
        return sci(med)
    return f"{sci(med)} ({sci(min(xs))}–{sci(max(xs))})"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mpmcg", required=True, help="the mpmcg binary")
    ap.add_argument("--warp-python", required=True, help="a Python with warp-lang")
    ap.add_argument("--warp-cache", default=None, help="warp's kernel cache folder")
    ap.add_argument("--size", choices=sorted(SIZES), default="full")
    ap.add_argument("--dims", default="2,3", help="which of 2,3")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cpu", type=int, default=0, help="the core to pin to (-1: none)")
    a = ap.parse_args()
    if a.cpu < 0:
        a.cpu = None
    dims = [int(d) for d in a.dims.split(",")]

    rows = [label for label, _, _ in MPMCG_SCHEMES] + [label for label, _ in WARP_PRECISIONS]
    pups = {(r, d): [] for r in rows for d in dims}
    counts = {}
    version = "?"
    began = time.time()
    with tempfile.TemporaryDirectory(prefix="bench_peers_") as tmp:
        for d in dims:
            cells, ppc, warm, steps = SIZES[a.size][d]
            for rep in range(a.repeats):
                for label, gradient, update in MPMCG_SCHEMES:
                    n, p = mpmcg_pups(a, tmp, d, cells, ppc, warm, steps, gradient, update)
                    counts.setdefault(d, set()).add(n)
                    pups[(label, d)].append(p)
                    print(f"  {d}D #{rep + 1} {label}: {p:.3e} pups", file=sys.stderr, flush=True)
                for label, precision in WARP_PRECISIONS:
                    n, p, version = warp_pups(a, d, cells, ppc, warm, steps, precision)
                    counts.setdefault(d, set()).add(n)
                    pups[(label, d)].append(p)
                    print(f"  {d}D #{rep + 1} {label}: {p:.3e} pups", file=sys.stderr, flush=True)
    for d in dims:
        if len(counts[d]) != 1:
            sys.exit(f"{d}D: the codes seeded different particle counts: {sorted(counts[d])}")

    def head(d):
        cells, ppc, warm, steps = SIZES[a.size][d]
        n = counts[d].pop()
        counts[d].add(n)
        return f"{d}D {cells}^{d}, {ppc}^{d} per cell, {n} particles"

    print(
        f"block drop, steady-state particle updates per second, 1 core, "
        f"median (min–max) of {a.repeats}; warp {version}; {time.time() - began:.0f} s"
    )
    cols = []
    for d in dims:
        cols += [head(d), "/ warp f64", "/ warp f32"]
    print("| code | " + " | ".join(cols) + " |")
    print("|---|" + "---:|" * len(cols))
    def ratio(r, d, peer):
        return statistics.median(x / y for x, y in zip(pups[(r, d)], pups[(peer, d)]))

    for r in rows:
        cells = []
        for d in dims:
            cells += [
                fmt(pups[(r, d)]),
                f"{ratio(r, d, 'warp MLS-MPM, f64'):.2f}",
                f"{ratio(r, d, 'warp MLS-MPM, f32'):.2f}",
            ]
        print(f"| {r} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
