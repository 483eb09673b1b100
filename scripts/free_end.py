#!/usr/bin/python3
"""The free end's displacement of the cantilever family's runs at 1 s and 3 s, and with
--reference its distance from a finer run of the same beam.

The free end is the mean over the particles that started within half a cell of the
beam's end (x0 largest; a hanging bar's bottom, y0 smallest), from the snapshots at
1 s and 3 s. A run is a directory written by scripts/cantilever_family.sh, named
TAG_ppcK_GRADIENT/; its reference is REF/TAG_ppc4_mpmcg/ (the same beam at 4 × 4 per
cell, e.g. `SCHEMES=mpmcg QUADRATURE=domain PPC=4 scripts/cantilever_family.sh REF`,
on the same grid). Prints one line per run and then, per gradient and particles per
cell, the largest distance over the 2D beams and that of the 3D beam.

Usage: /usr/bin/python3 scripts/free_end.py RUN... [--reference REF] [--cell 0.25]
Needs h5py (Debian: python3-h5py).
"""
import argparse
import glob
import os
import re

import h5py
import numpy as np

TIMES = (1.0, 3.0)


def free_end(run, h):
    """The free end's displacement (D components) at TIMES, None where no snapshot is."""
    snaps = {}
    for path in glob.glob(os.path.join(run, "particles_*.h5")):
        with h5py.File(path, "r") as f:
            snaps[float(f.attrs["time"])] = path
    out = []
    for t in TIMES:
        near = min(snaps, key=lambda s: abs(s - t)) if snaps else None
        if near is None or abs(near - t) > 1e-6:
            out.append(None)
            continue
        with h5py.File(snaps[near], "r") as f:
            dim = int(f.attrs["dim"])
            u = f["displacement"][:, :dim]
            x0 = f["position"][:, :dim] - u
        if "hang_" in os.path.basename(run.rstrip("/")):
            end = x0[:, 1] <= x0[:, 1].min() + 0.5 * h
        else:
            end = x0[:, 0] >= x0[:, 0].max() - 0.5 * h
        out.append(u[end].mean(0))
    return out


def fmt(u):
    return "–" if u is None else "(" + ", ".join("%.3f" % c for c in u) + ")"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--reference")
    ap.add_argument("--cell", type=float, default=0.25, help="the cell size h (m)")
    a = ap.parse_args()
    worst = {}
    for run in a.runs:
        name = os.path.basename(run.rstrip("/"))
        m = re.match(r"(.*)_ppc(\d+)_(\w+)$", name)
        if not m or not os.path.isfile(os.path.join(run, "history.csv")):
            continue
        tips = free_end(run, a.cell)
        line = "%s: free end's displacement at 1 s %s m, at 3 s %s m" % (
            run.rstrip("/"), fmt(tips[0]), fmt(tips[1]))
        if a.reference and not name.startswith("hang_"):
            ref = os.path.join(a.reference, "%s_ppc4_mpmcg" % m.group(1))
            if os.path.isdir(ref):
                r = free_end(ref, a.cell)
                err = [float("nan") if u is None or v is None else float(np.linalg.norm(u - v))
                       for u, v in zip(tips, r)]
                line += "; from the reference " + ", ".join(
                    "%.3f m" % e if np.isfinite(e) else "–" for e in err)
                key = (m.group(3), int(m.group(2)), m.group(1).startswith("3D"))
                worst.setdefault(key, []).append(err)
        print(line)
    # The largest over the runs that reached the time (a run that ended unstable has no
    # snapshot there), and how many did.
    for (g, ppc, three), errs in sorted(worst.items()):
        parts = []
        for k, t in enumerate(TIMES):
            e = [x[k] for x in errs if np.isfinite(x[k])]
            parts.append("at %g s %s (%d of %d runs)" % (
                t, "%.3f m" % max(e) if e else "–", len(e), len(errs)))
        print("%s, %d per cell, %s: largest distance from the reference %s"
              % (g, ppc, "3D beam" if three else "2D beams", ", ".join(parts)))


if __name__ == "__main__":
    main()
