#!/usr/bin/env python3
"""The 2D axis-aligned manufactured solution as an MLS-MPM in NVIDIA warp, on the CPU.

The peer of scripts/bench_peers_mms.sh: the MLS-MPM of scripts/bench_peers_warp.py
(Hu et al. 2018: quadratic B-splines, APIC affine momentum `C`, the stress folded into
the affine term, `F ← (I + Δt C) F`) on the problem of inputs/axis_aligned_mms_2d.toml,
with what mpmcg does to it wherever the problem, not the scheme, decides:

- the solution `u_i = A sin(π X_i) sin(cπt + φ_i)`, its body force
  `b_i = π² u_i [μ/ρ0 − c² − (λ (ln J − 1) − μ) / (ρ0 F_ii²)]` at each particle's
  reference position, at the time the step starts; the neo-Hookean Kirchhoff stress
  `τ = μ (F Fᵀ − I) + λ ln J I` in plane strain; E = 1e4, ν = 0.3, ρ0 = 1, A = 0.05,
  c = 100, one period (t = 0.02);
- particles at the centres of `ppc × ppc` sub-cells, `x = X + u(X, 0)`,
  `F = I + ∂u/∂X`, the APIC matrix `C` the exact velocity gradient;
- the time step `cfl · h / max_p(c(J_p) + |v_p|)` with the neo-Hookean wave speed
  `sqrt(max(λ + 2μ, λ + 2(μ − λ ln J)) / ρ0)`, shortened to land on the end time,
  and the velocity's step centred (`(Δt_prev + Δt)/2`, velocities at the middle of a
  step: the particles start with the exact velocity half a first step before t = 0);
- the error: the volume-weighted particle L2 norms `sqrt(Σ J V0 |e|² / Σ J V0)` of the
  displacement (at the step's end) and of the velocity (at its middle), after every
  step, the maximum over the run.

Walls (the unit square, `cells` per axis): the stencil of a particle within h/2 of a
face reaches a node outside it, so the grid has one node past each face; the slip
condition zeroes the normal velocity at the face's nodes and those past it.
Periodic (`--periodic`): the solution has period 2, so the square is [0, 2]² with
2·`cells` cells per axis, wrapped; the same spacing h = 1/cells.

The step (clear, particle → grid, grid update, grid → particle, the error and the next
step's signal speed) is timed from the first step to the last, with the kernels
compiled before (cached in `--cache`); reading the step's maximum speed back to the
host is part of it, as mpmcg's reduction is part of its step. Prints one JSON line:
    {"code": "warp-mls-mpm", "cells": ..., "periodic": ..., "particles": ...,
     "steps": ..., "wall_seconds": ..., "displacement_l2": ..., "velocity_l2": ...}

Usage: python bench_peers_mms_warp.py --cells 32 [--ppc 2] [--periodic]
"""

import argparse
import json
import math
import sys
import time

import numpy as np
import warp as wp

PHASE = (0.0, 2.0 * math.pi / 3.0)


def make_kernels(periodic):
    vec = wp.vec2d
    mat = wp.mat22d
    f64 = wp.float64
    wmat = wp.types.matrix((3, 2), f64)
    vec3 = wp.types.vector(3, f64)

    @wp.func
    def weights(xp: vec):
        """Lower node and the 3 quadratic B-spline weights per axis at `xp` (grid units)."""
        base = wp.vec2i()
        fx = vec()
        w = wmat()
        for a in range(2):
            b = int(wp.floor(xp[a] - f64(0.5)))
            base[a] = b
            f = xp[a] - f64(b)
            fx[a] = f
            w[0, a] = f64(0.5) * (f64(1.5) - f) * (f64(1.5) - f)
            w[1, a] = f64(0.75) - (f - f64(1.0)) * (f - f64(1.0))
            w[2, a] = f64(0.5) * (f - f64(0.5)) * (f - f64(0.5))
        return base, fx, w

    @wp.func
    def node(i: int, j: int, base: wp.vec2i, fx: vec, w: wmat, dx: f64, nodes: int):
        """Index, weight and offset `x_i − x_p` of node (i, j) of the particle's 3 × 3.
        Walls: node k of an axis is stored at k + 1 (one node past the lower face);
        periodic: at k mod nodes."""
        ofs = vec3(f64(0.0), f64(1.0), f64(2.0))
        dpos = vec((ofs[i] - fx[0]) * dx, (ofs[j] - fx[1]) * dx)
        ix = base[0] + i
        iy = base[1] + j
        if wp.static(periodic):
            ix = (ix + nodes) % nodes
            iy = (iy + nodes) % nodes
        else:
            ix = ix + 1
            iy = iy + 1
        return ix + iy * nodes, w[i, 0] * w[j, 1], dpos

    @wp.func
    def exact(x0: vec, t: f64, amp: f64, c: f64):
        """Displacement, velocity and diagonal of F of the solution at X = x0, time t."""
        u = vec()
        v = vec()
        fii = vec()
        pi = f64(wp.pi)
        for a in range(2):
            ph = f64(0.0)
            if a == 1:
                ph = f64(2.0) * pi / f64(3.0)
            s = wp.sin(pi * x0[a])
            u[a] = amp * s * wp.sin(c * pi * t + ph)
            v[a] = amp * s * c * pi * wp.cos(c * pi * t + ph)
            fii[a] = f64(1.0) + amp * pi * wp.cos(pi * x0[a]) * wp.sin(c * pi * t + ph)
        return u, v, fii

    @wp.kernel
    def clear(grid_v: wp.array(dtype=vec), grid_m: wp.array(dtype=f64)):
        i = wp.tid()
        grid_v[i] = vec()
        grid_m[i] = f64(0.0)

    @wp.kernel
    def p2g(
        x: wp.array(dtype=vec), x0: wp.array(dtype=vec), v: wp.array(dtype=vec),
        c_aff: wp.array(dtype=mat), f_def: wp.array(dtype=mat),
        grid_v: wp.array(dtype=vec), grid_m: wp.array(dtype=f64),
        nodes: int, inv_dx: f64, kick: f64, t: f64, p_vol: f64, p_mass: f64,
        mu: f64, lam: f64, rho0: f64, amp: f64, c: f64,
    ):
        p = wp.tid()
        fp = f_def[p]
        eye = wp.identity(n=2, dtype=f64)
        tau = mu * (fp * wp.transpose(fp) - eye) + lam * wp.log(wp.determinant(fp)) * eye
        affine = (-kick * p_vol * f64(4.0) * inv_dx * inv_dx) * tau + p_mass * c_aff[p]
        # The body force at the particle's reference position, at the step's start.
        u, ve, fii = exact(x0[p], t, amp, c)
        lnj = wp.log(fii[0] * fii[1])
        pi = f64(wp.pi)
        b = vec()
        for a in range(2):
            b[a] = pi * pi * u[a] * (
                mu / rho0 - c * c - (lam * (lnj - f64(1.0)) - mu) / (rho0 * fii[a] * fii[a])
            )
        mv = p_mass * (v[p] + kick * b)
        base, fx, w = weights(x[p] * inv_dx)
        dx = f64(1.0) / inv_dx
        for i in range(3):
            for j in range(3):
                idx, weight, dpos = node(i, j, base, fx, w, dx, nodes)
                wp.atomic_add(grid_v, idx, weight * (mv + affine * dpos))
                wp.atomic_add(grid_m, idx, weight * p_mass)

    @wp.kernel
    def grid_update(grid_v: wp.array(dtype=vec), grid_m: wp.array(dtype=f64), nodes: int):
        i = wp.tid()
        m = grid_m[i]
        if m > f64(0.0):
            gv = grid_v[i] / m
            if wp.static(not periodic):
                # Slip faces: stored index 1 is the lower face, nodes − 2 the upper.
                ix = i % nodes
                iy = i // nodes
                if ix <= 1 or ix >= nodes - 2:
                    gv[0] = f64(0.0)
                if iy <= 1 or iy >= nodes - 2:
                    gv[1] = f64(0.0)
            grid_v[i] = gv

    @wp.kernel
    def g2p(
        x: wp.array(dtype=vec), x0: wp.array(dtype=vec), v: wp.array(dtype=vec),
        c_aff: wp.array(dtype=mat), f_def: wp.array(dtype=mat), grid_v: wp.array(dtype=vec),
        nodes: int, inv_dx: f64, dt: f64, t_end: f64, p_vol: f64,
        mu: f64, lam: f64, rho0: f64, amp: f64, c: f64, sums: wp.array(dtype=f64),
    ):
        p = wp.tid()
        base, fx, w = weights(x[p] * inv_dx)
        dx = f64(1.0) / inv_dx
        new_v = vec()
        new_c = mat()
        for i in range(3):
            for j in range(3):
                idx, weight, dpos = node(i, j, base, fx, w, dx, nodes)
                gv = grid_v[idx]
                new_v = new_v + weight * gv
                new_c = new_c + (f64(4.0) * inv_dx * inv_dx * weight) * wp.outer(gv, dpos)
        fp = (wp.identity(n=2, dtype=f64) + dt * new_c) * f_def[p]
        xp = x[p] + dt * new_v
        v[p] = new_v
        c_aff[p] = new_c
        f_def[p] = fp
        x[p] = xp
        # The error (displacement at the step's end, velocity at its middle) and the
        # signal speed the next step derives from.
        jp = wp.determinant(fp)
        vol = jp * p_vol
        u, ve, fii = exact(x0[p], t_end, amp, c)
        um, vm, fm = exact(x0[p], t_end - f64(0.5) * dt, amp, c)
        eu = xp - x0[p] - u
        ev = new_v - vm
        wp.atomic_add(sums, 0, vol * wp.dot(eu, eu))
        wp.atomic_add(sums, 1, vol * wp.dot(ev, ev))
        wp.atomic_add(sums, 2, vol)
        modulus = wp.max(lam + f64(2.0) * mu, lam + f64(2.0) * (mu - lam * wp.log(jp)))
        wp.atomic_max(sums, 3, wp.sqrt(modulus / rho0) + wp.length(new_v))

    return clear, p2g, grid_update, g2p


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", type=int, required=True, help="cells per unit length (h = 1/cells)")
    ap.add_argument("--ppc", type=int, default=2, help="particles per cell per axis")
    ap.add_argument("--periodic", action="store_true", help="[0, 2]² periodic instead of slip walls")
    ap.add_argument("--cfl", type=float, default=0.2)
    ap.add_argument("--end", type=float, default=0.02)
    ap.add_argument("--amplitude", type=float, default=0.05)
    ap.add_argument("--cache", default=None, help="warp kernel cache folder")
    a = ap.parse_args()

    if a.cache:
        wp.config.kernel_cache_dir = a.cache
    wp.config.quiet = True
    wp.init()
    device = "cpu"
    kernels = make_kernels(a.periodic)
    clear, p2g, grid_update, g2p = kernels

    young, nu, rho0, c = 1.0e4, 0.3, 1.0, 100.0
    amp = a.amplitude
    mu = young / (2.0 * (1.0 + nu))
    lam = young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    h = 1.0 / a.cells
    span = 2.0 if a.periodic else 1.0
    cells = int(round(span * a.cells))
    nodes = cells if a.periodic else cells + 3

    # Sub-cell centres over the whole square, as mpmcg seeds a box that fills the grid.
    k = np.arange(cells * a.ppc)
    axis = (k + 0.5) * (h / a.ppc)
    gx, gy = np.meshgrid(axis, axis, indexing="ij")
    x0 = np.stack([gx.ravel(), gy.ravel()], axis=1)
    n = len(x0)
    p_vol = (h / a.ppc) ** 2
    p_mass = rho0 * p_vol

    def wave(j):
        return math.sqrt(max(lam + 2.0 * mu, lam + 2.0 * (mu - lam * math.log(j))) / rho0)

    s = np.sin(np.pi * x0)
    co = np.cos(np.pi * x0)
    ph = np.array(PHASE)
    u0 = amp * s * np.sin(ph)
    fii0 = 1.0 + amp * np.pi * co * np.sin(ph)
    j0 = fii0.prod(axis=1)
    v_at = lambda t: amp * s * c * np.pi * np.cos(c * np.pi * t + ph)  # noqa: E731
    speed = max(wave(j) for j in (j0.min(), j0.max())) + np.linalg.norm(v_at(0.0), axis=1).max()
    dt = min(a.cfl * h / speed, a.end)
    fdot = amp * np.pi * co * c * np.pi * np.cos(ph)
    c0 = np.zeros((n, 2, 2))
    c0[:, 0, 0] = fdot[:, 0] / fii0[:, 0]
    c0[:, 1, 1] = fdot[:, 1] / fii0[:, 1]
    f0 = np.zeros((n, 2, 2))
    f0[:, 0, 0] = fii0[:, 0]
    f0[:, 1, 1] = fii0[:, 1]

    vec, mat = wp.vec2d, wp.mat22d
    x = wp.array(x0 + u0, dtype=vec, device=device)
    xr = wp.array(x0, dtype=vec, device=device)
    v = wp.array(v_at(-0.5 * dt), dtype=vec, device=device)
    c_aff = wp.array(c0, dtype=mat, device=device)
    f_def = wp.array(f0, dtype=mat, device=device)
    grid_v = wp.zeros(nodes * nodes, dtype=vec, device=device)
    grid_m = wp.zeros(nodes * nodes, dtype=wp.float64, device=device)
    sums = wp.zeros(4, dtype=wp.float64, device=device)
    wp.force_load(device=device)

    inv = 1.0 / h
    t, dt_prev, steps = 0.0, dt, 0
    max_u = max_v = 0.0
    t0 = time.perf_counter()
    while t < a.end * (1.0 - 1e-12):
        dt = min(dt, a.end - t)
        kick = 0.5 * (dt_prev + dt)
        sums.zero_()
        wp.launch(clear, dim=nodes * nodes, inputs=[grid_v, grid_m], device=device)
        wp.launch(p2g, dim=n, inputs=[x, xr, v, c_aff, f_def, grid_v, grid_m, nodes, inv, kick, t,
                                      p_vol, p_mass, mu, lam, rho0, amp, c], device=device)
        wp.launch(grid_update, dim=nodes * nodes, inputs=[grid_v, grid_m, nodes], device=device)
        wp.launch(g2p, dim=n, inputs=[x, xr, v, c_aff, f_def, grid_v, nodes, inv, dt, t + dt, p_vol,
                                      mu, lam, rho0, amp, c, sums], device=device)
        su, sv, sw, smax = sums.numpy()
        t += dt
        steps += 1
        if not all(math.isfinite(q) for q in (su, sv, smax)):
            print(f"warp MMS became non-finite at step {steps}", file=sys.stderr)
            sys.exit(3)
        max_u = max(max_u, math.sqrt(su / sw))
        max_v = max(max_v, math.sqrt(sv / sw))
        dt_prev, dt = dt, a.cfl * h / smax
    sec = time.perf_counter() - t0

    print(json.dumps({
        "code": "warp-mls-mpm",
        "warp": wp.config.version,
        "cells": a.cells,
        "periodic": a.periodic,
        "ppc": a.ppc,
        "particles": n,
        "steps": steps,
        "wall_seconds": sec,
        "particle_updates_per_second": n * steps / sec,
        "displacement_l2": max_u,
        "velocity_l2": max_v,
    }))


if __name__ == "__main__":
    main()
