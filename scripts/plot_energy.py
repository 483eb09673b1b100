#!/usr/bin/env python3
"""Energy history of one or more runs (their history.csv) as a plot.

    scripts/plot_energy.py OUT [OUT ...] -o energy.svg [--title T]

Per run: kinetic, strain (stored) energy, plastic work where the scene has a plastic
material, and the total balance (kinetic + strain + plastic work - external work).
Several runs (e.g. one per scheme) share the axes; each is labelled by its folder's
name. The format follows the output's extension (svg, png, pdf).
"""
import argparse
import csv
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def history(out):
    with open(os.path.join(out, "history.csv")) as f:
        rows = list(csv.DictReader(f))
    return {k: [float(r[k]) for r in rows] for k in rows[0]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="output folders with history.csv")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--title", default="")
    a = ap.parse_args()
    fig, ax = plt.subplots(figsize=(7, 4))
    styles = ["-", "--", ":", "-."]
    for i, out in enumerate(a.runs):
        h = history(out)
        name = os.path.basename(os.path.normpath(out))
        ls = styles[i % len(styles)]
        t = h["time"]
        ax.plot(t, h["kinetic"], ls, color="tab:blue", label=f"{name}: kinetic")
        ax.plot(t, h["strain"], ls, color="tab:orange", label=f"{name}: strain")
        if "plastic_work" in h:
            ax.plot(t, h["plastic_work"], ls, color="tab:red", label=f"{name}: plastic work")
        ax.plot(t, h["total"], ls, color="black", label=f"{name}: total")
    ax.set_xlabel("time")
    ax.set_ylabel("energy")
    ax.set_title(a.title)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(a.output)


if __name__ == "__main__":
    main()
