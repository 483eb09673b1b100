#!/usr/bin/python3
"""The freely spinning disk of docs/hard-cases.md: where its spin turns into strain.

A neo-Hookean disk (radius 0.3 at the centre of a unit box of 20² cells, ρ = 1000,
E = 1000, ν = 0.3) spins at ω = 0.2 rad/s, MUSL, FLIP, dt = 1e-3, and touches no wall.
A rigid rotation has no strain, so what strain energy the disk gains is the scheme's.

- `--end T` (default 100 s, about 3 turns): the strain energy as a share of the
  initial kinetic energy every 10 s, and the total energy's drift, from history.csv.
- `--one-step`: the stress after the first step, by distance from the centre: in the
  interior it is the `(ω dt)²` of the step's `F = I + dt L`, and wherever it is larger
  the first transfer already made a strain rate a rigid rotation does not have. With
  `--gradient mpm` it also writes that step out (the grid velocities, `L` and the
  stress) and compares.

Usage: /usr/bin/python3 scripts/spinning_disk.py [--gradient mpmcg] [--ppc 2]
       [--quadrature point|domain] [--centroid K] [--sharpen B] [--seeding lattice|cut]
(each of the method's keys absent takes the scene's default: docs/scenes.md)
       [--end 100 | --one-step] [--mpmcg BIN]
Needs h5py (Debian: python3-h5py) for --one-step.
"""
import argparse
import csv
import glob
import json
import os
import subprocess
import sys
import tempfile

SCENE = """name = "spinning_disk"
dim = 2
[time]
end = {end}
dt = 1.0e-3
[method]
gradient = "{gradient}"
update = "musl"
flip = 1.0
{quadrature}
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [20, 20]
boundary = {{ x_lower = "slip", x_upper = "slip", y_lower = "slip", y_upper = "slip" }}
[[materials]]
name = "disk"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[bodies]]
material = "disk"
shape = {{ sphere = {{ center = [0.5, 0.5], radius = 0.3 }} }}
particles_per_cell = {ppc}
seeding = "{seeding}"
velocity_gradient = {{ value = [[0.0, -0.2], [0.2, 0.0]], about = [0.5, 0.5] }}
[output]
every = {every}
{fields}
"""


def transfer_check(x0, stress, r):
    """MPM's first step, written out: the rigid field's grid velocities are the
    mass-weighted means of the particles' (equal masses), `L` their gradient with the
    hat functions at the particles, and the stress that of `F = I + dt L` (plane
    strain, the neo-Hookean law). Prints how far that is from the run's stress, and the
    symmetric part of `L`, which a rigid rotation does not have, inside and at the rim."""
    import numpy as np
    h, nodes, dt, omega = 0.05, 21, 1.0e-3, 0.2
    mu = 1000.0 / (2 * 1.3)
    lam = 1000.0 * 0.3 / (1.3 * 0.4)
    v = omega * np.stack([-(x0[:, 1] - 0.5), x0[:, 0] - 0.5], 1)
    cell = np.floor(x0 / h).astype(int)
    xi = x0 / h - cell
    mass = np.zeros((nodes, nodes))
    mom = np.zeros((nodes, nodes, 2))
    corners = []
    for ax in (0, 1):
        for ay in (0, 1):
            wx = xi[:, 0] if ax else 1 - xi[:, 0]
            wy = xi[:, 1] if ay else 1 - xi[:, 1]
            grad = np.stack([(1 if ax else -1) / h * wy, wx * (1 if ay else -1) / h], 1)
            i, j = cell[:, 0] + ax, cell[:, 1] + ay
            np.add.at(mass, (i, j), wx * wy)
            np.add.at(mom, (i, j), (wx * wy)[:, None] * v)
            corners.append((i, j, grad))
    vel = mom / np.where(mass > 0, mass, 1.0)[..., None]
    grad_v = sum(np.einsum("pa,pb->pab", vel[i, j], g) for i, j, g in corners)
    f = np.zeros((len(x0), 3, 3))
    f[:, :2, :2] = np.eye(2) + dt * grad_v
    f[:, 2, 2] = 1.0
    jac = np.linalg.det(f)
    tau = mu * (f @ f.transpose(0, 2, 1) - np.eye(3)) + (lam * np.log(jac))[:, None, None] * np.eye(3)
    want = (tau / jac[:, None, None]).reshape(len(x0), 9)
    size = np.sqrt((stress ** 2).sum(axis=1))
    print(f"  the run's stress against F = I + dt L of the mass-weighted grid velocities: "
          f"{np.abs(want - stress).max() / size.max():.1e} of the largest")
    sym = np.abs(0.5 * (grad_v + grad_v.transpose(0, 2, 1)))
    print(f"  symmetric part of L over omega: {sym[r < 0.15].max() / omega:.1e} inside r = 0.15, "
          f"{sym[r > 0.25].max() / omega:.2f} outside r = 0.25")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--gradient", default="mpmcg")
    ap.add_argument("--ppc", type=int, default=2)
    # Absent, each takes the scene's default (docs/scenes.md).
    ap.add_argument("--quadrature", choices=("point", "domain"))
    ap.add_argument("--centroid", type=int, help="[method] centroid_passes")
    ap.add_argument("--sharpen", type=float, help="[method] sharpen")
    ap.add_argument("--seeding", default="lattice", choices=("lattice", "cut"), help="[[bodies]] seeding")
    ap.add_argument("--end", type=float, default=100.0)
    ap.add_argument("--one-step", action="store_true")
    ap.add_argument("--mpmcg", default=os.path.join(os.path.dirname(__file__), "..", "target", "release", "mpmcg"))
    a = ap.parse_args()
    end = 1.0e-3 if a.one_step else a.end
    text = SCENE.format(
        end=end, gradient=a.gradient, ppc=a.ppc, seeding=a.seeding,
        quadrature=(f'quadrature = "{a.quadrature}"' if a.quadrature is not None else "")
        + (f"\ncentroid_passes = {a.centroid}" if a.centroid is not None else "")
        + (f"\nsharpen = {a.sharpen}" if a.sharpen is not None else ""),
        every=end if a.one_step else 10.0,
        fields='fields = ["stress"]' if a.one_step else "")
    with tempfile.TemporaryDirectory() as tmp:
        scene = os.path.join(tmp, "disk.toml")
        out = os.path.join(tmp, "out")
        with open(scene, "w") as f:
            f.write(text)
        subprocess.run([a.mpmcg, "run", scene, "--out", out, "--quiet", "--threads", "1"], check=True)
        with open(os.path.join(out, "summary.json")) as f:
            ran = json.load(f)
        print(f"{a.gradient}, {a.ppc} x {a.ppc} per cell, {ran.get('quadrature', 'point')} rule"
              + (f", {ran['centroid_passes']} centroid passes" if "centroid_passes" in ran else "")
              + (f", sharpened by {ran['sharpen']}" if "sharpen" in ran else "")
              + (", seeded cut" if a.seeding == "cut" else ""))
        if a.one_step:
            import h5py
            import numpy as np
            with h5py.File(sorted(glob.glob(os.path.join(out, "particles_*.h5")))[-1]) as g:
                order = np.argsort(g["id"][:])
                x = g["position"][:, :2][order]
                s = g["stress"][:][order]
            r = np.hypot(x[:, 0] - 0.5, x[:, 1] - 0.5)
            size = np.sqrt((s ** 2).sum(axis=1))
            for lo in np.arange(0.0, 0.3, 0.05):
                k = (r >= lo) & (r < lo + 0.05)
                print(f"  r {lo:.2f}-{lo + 0.05:.2f}: {k.sum():4d} particles, |stress| mean {size[k].mean():.2e}, "
                      f"max {size[k].max():.2e} Pa")
            if a.gradient == "mpm":
                with h5py.File(sorted(glob.glob(os.path.join(out, "particles_*.h5")))[0]) as g:
                    x0 = g["position"][:, :2][np.argsort(g["id"][:])]
                transfer_check(x0, s, r)
        else:
            rows = list(csv.DictReader(open(os.path.join(out, "history.csv"))))
            k0 = float(rows[0]["kinetic"])
            e0 = float(rows[0]["total"])
            times = [float(r["time"]) for r in rows]
            for k in range(int(end / 10.0 + 1e-9) + 1):
                r = rows[min(range(len(rows)), key=lambda i: abs(times[i] - 10.0 * k))]
                t = float(r["time"])
                print(f"  t = {t:5.1f}: strain {100 * float(r['strain']) / k0:5.2f} % of the initial "
                      f"kinetic energy, total energy {100 * (float(r['total']) / e0 - 1):+.3f} %")


if __name__ == "__main__":
    sys.exit(main())
