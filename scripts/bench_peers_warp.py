#!/usr/bin/env python3
"""The block drop of scripts/bench_peers.sh as an MLS-MPM in NVIDIA warp, on the CPU.

MLS-MPM (Hu et al. 2018, "A moving least squares material point method"): quadratic
B-splines (3 nodes per axis), APIC affine momentum `C`, the stress folded into the
affine term of the particle-to-grid transfer, and the deformation gradient updated
from `C` (`F ← (I + Δt C) F`). The material is the same compressible neo-Hookean solid
as mpmcg's, `τ = μ (F Fᵀ − I) + λ ln J I` (Kirchhoff stress; plane strain in 2D).

Problem: a unit box with `cells` cells per axis, a block `[lo, hi]^D` seeded with
`ppc` particles per cell and axis at the centres of the sub-cells (as mpmcg seeds a box,
so both codes get the same particle count), E = 1e3, ν = 0.2, ρ = 1, gravity −9.81 on
axis 1, a fixed time step `cfl · h / c` with c the longitudinal wave speed, slip walls
three nodes deep (the block never reaches them in a benchmark's few hundred steps).

A step is four kernel launches: clear the grid, particle → grid, grid update, grid →
particle. The script times `--steps` steps after `--warmup` steps (the first launch
compiles the kernels, cached in `--cache`) and prints one JSON line:
    {"code": "warp", "dim": 2, "precision": "f64", "particles": ..., "steps": ...,
     "seconds": ..., "pups": ...}

Usage: python bench_peers_warp.py --dim 2 --cells 256 --ppc 4 --precision f64
"""

import argparse
import json
import math
import os
import sys
import time

import numpy as np
import warp as wp


def make_kernels(dim, dtype):
    """The four kernels of a step for dimension `dim` and scalar type `dtype`.

    The node loops are nested `range(3)` loops (the third of length 1 in 2D), which
    warp unrolls (it unrolls loops of up to `max_unroll` = 16 iterations: one flat loop
    over 27 nodes in 3D would stay a loop with run-time indexing, 2x slower). Node
    offsets come from a small vector (`ofs[i]`): `float64(i)` of an unrolled loop index
    breaks warp 1.19's typing of `i` in later integer expressions ("Input types must be
    the same")."""
    vec = wp.types.vector(dim, dtype)
    mat = wp.types.matrix((dim, dim), dtype)
    veci = wp.types.vector(dim, int)
    wmat = wp.types.matrix((3, dim), dtype)  # quadratic B-spline weights per axis
    vec3 = wp.types.vector(3, dtype)

    @wp.func
    def weights(xp: vec):
        """Lower node and the 3 weights per axis of a particle at `xp` (grid units)."""
        base = veci()
        fx = vec()
        w = wmat()
        for a in range(dim):
            b = int(wp.floor(xp[a] - dtype(0.5)))
            base[a] = b
            f = xp[a] - dtype(b)
            fx[a] = f
            w[0, a] = dtype(0.5) * (dtype(1.5) - f) * (dtype(1.5) - f)
            w[1, a] = dtype(0.75) - (f - dtype(1.0)) * (f - dtype(1.0))
            w[2, a] = dtype(0.5) * (f - dtype(0.5)) * (f - dtype(0.5))
        return base, fx, w

    @wp.kernel(module="unique")
    def clear(grid_v: wp.array(dtype=vec), grid_m: wp.array(dtype=dtype)):
        i = wp.tid()
        grid_v[i] = vec()
        grid_m[i] = dtype(0.0)

    @wp.func
    def kirchhoff(fp: mat, mu: dtype, lam: dtype):
        """Neo-Hookean Kirchhoff stress μ (F Fᵀ − I) + λ ln J I."""
        eye = wp.identity(n=dim, dtype=dtype)
        return mu * (fp * wp.transpose(fp) - eye) + lam * wp.log(wp.determinant(fp)) * eye

    @wp.func
    def node(i: int, j: int, k: int, base: veci, fx: vec, w: wmat, dx: dtype, nodes: int):
        """Index, weight and offset `x_i − x_p` of node (i, j, k) of the particle's 3^D
        (k = 0 in 2D)."""
        ofs = vec3(dtype(0.0), dtype(1.0), dtype(2.0))
        dpos = vec()
        dpos[0] = (ofs[i] - fx[0]) * dx
        dpos[1] = (ofs[j] - fx[1]) * dx
        weight = w[i, 0] * w[j, 1]
        idx = (base[0] + i) + (base[1] + j) * nodes
        if wp.static(dim == 3):
            dpos[2] = (ofs[k] - fx[2]) * dx
            weight = weight * w[k, 2]
            idx = idx + (base[2] + k) * nodes * nodes
        return idx, weight, dpos

    @wp.kernel(module="unique")
    def p2g(
        x: wp.array(dtype=vec), v: wp.array(dtype=vec), c_aff: wp.array(dtype=mat),
        f_def: wp.array(dtype=mat), grid_v: wp.array(dtype=vec), grid_m: wp.array(dtype=dtype),
        nodes: int, inv_dx: dtype, dt: dtype, p_vol: dtype, p_mass: dtype, mu: dtype, lam: dtype,
    ):
        p = wp.tid()
        base, fx, w = weights(x[p] * inv_dx)
        affine = (-dt * p_vol * dtype(4.0) * inv_dx * inv_dx) * kirchhoff(f_def[p], mu, lam) + p_mass * c_aff[p]
        mv = p_mass * v[p]
        dx = dtype(1.0) / inv_dx
        for i in range(3):
            for j in range(3):
                for k in range(wp.static(3 if dim == 3 else 1)):
                    idx, weight, dpos = node(i, j, k, base, fx, w, dx, nodes)
                    wp.atomic_add(grid_v, idx, weight * (mv + affine * dpos))
                    wp.atomic_add(grid_m, idx, weight * p_mass)

    @wp.kernel(module="unique")
    def g2p(
        x: wp.array(dtype=vec), v: wp.array(dtype=vec), c_aff: wp.array(dtype=mat),
        f_def: wp.array(dtype=mat), grid_v: wp.array(dtype=vec), nodes: int, inv_dx: dtype, dt: dtype,
    ):
        p = wp.tid()
        base, fx, w = weights(x[p] * inv_dx)
        dx = dtype(1.0) / inv_dx
        new_v = vec()
        new_c = mat()
        for i in range(3):
            for j in range(3):
                for k in range(wp.static(3 if dim == 3 else 1)):
                    idx, weight, dpos = node(i, j, k, base, fx, w, dx, nodes)
                    gv = grid_v[idx]
                    new_v = new_v + weight * gv
                    new_c = new_c + (dtype(4.0) * inv_dx * inv_dx * weight) * wp.outer(gv, dpos)
        v[p] = new_v
        c_aff[p] = new_c
        f_def[p] = (wp.identity(n=dim, dtype=dtype) + dt * new_c) * f_def[p]
        x[p] = x[p] + dt * new_v

    @wp.kernel(module="unique")
    def grid_update(
        grid_v: wp.array(dtype=vec),
        grid_m: wp.array(dtype=dtype),
        nodes: int,
        dt: dtype,
        gravity: dtype,
    ):
        i = wp.tid()
        m = grid_m[i]
        if m > dtype(0.0):
            gv = grid_v[i] / m
            gv[1] = gv[1] + dt * gravity
            r = i
            for a in range(dim):
                c = r % nodes
                r = r // nodes
                if c < 3 and gv[a] < dtype(0.0):
                    gv[a] = dtype(0.0)
                if c > nodes - 4 and gv[a] > dtype(0.0):
                    gv[a] = dtype(0.0)
            grid_v[i] = gv

    return clear, p2g, grid_update, g2p


def seed(dim, cells, ppc, lo, hi):
    """Sub-cell centres inside [lo, hi]^dim, as mpmcg seeds a box body."""
    h = 1.0 / (cells * ppc)
    k = np.arange(cells * ppc)
    c = (k + 0.5) * h
    axis = c[(c >= lo) & (c <= hi)]
    grids = np.meshgrid(*([axis] * dim), indexing="ij")
    return np.stack([g.ravel() for g in grids], axis=1)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2)
    ap.add_argument("--cells", type=int, default=256, help="cells per axis of the unit box")
    ap.add_argument("--ppc", type=int, default=4, help="particles per cell per axis")
    ap.add_argument("--block", type=float, nargs=2, default=(0.2, 0.8), metavar=("LO", "HI"))
    ap.add_argument("--precision", choices=("f32", "f64"), default="f64")
    ap.add_argument("--steps", type=int, default=100, help="timed steps")
    ap.add_argument("--warmup", type=int, default=5, help="untimed steps first")
    ap.add_argument("--cfl", type=float, default=0.3)
    ap.add_argument("--cache", default=None, help="warp kernel cache folder")
    a = ap.parse_args()

    if a.cache:
        wp.config.kernel_cache_dir = a.cache
    wp.config.quiet = True
    wp.init()
    device = "cpu"
    dtype = wp.float64 if a.precision == "f64" else wp.float32
    np_t = np.float64 if a.precision == "f64" else np.float32
    clear, p2g, grid_update, g2p = make_kernels(a.dim, dtype)

    young, nu, rho, g = 1.0e3, 0.2, 1.0, -9.81
    mu = young / (2.0 * (1.0 + nu))
    lam = young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    dx = 1.0 / a.cells
    wave = math.sqrt((lam + 2.0 * mu) / rho)
    dt = a.cfl * dx / wave
    p_vol = (dx / a.ppc) ** a.dim
    p_mass = rho * p_vol
    nodes = a.cells + 1

    pos = seed(a.dim, a.cells, a.ppc, a.block[0], a.block[1]).astype(np_t)
    n = len(pos)
    vec = wp.types.vector(a.dim, dtype)
    mat = wp.types.matrix((a.dim, a.dim), dtype)
    x = wp.array(pos, dtype=vec, device=device)
    v = wp.zeros(n, dtype=vec, device=device)
    c_aff = wp.zeros(n, dtype=mat, device=device)
    f_def = wp.array(np.tile(np.eye(a.dim, dtype=np_t), (n, 1, 1)), dtype=mat, device=device)
    grid_v = wp.zeros(nodes**a.dim, dtype=vec, device=device)
    grid_m = wp.zeros(nodes**a.dim, dtype=dtype, device=device)
    T = np_t
    args_p2g = [x, v, c_aff, f_def, grid_v, grid_m, nodes, T(1.0 / dx), T(dt), T(p_vol), T(p_mass), T(mu), T(lam)]

    def step():
        wp.launch(clear, dim=nodes**a.dim, inputs=[grid_v, grid_m], device=device)
        wp.launch(p2g, dim=n, inputs=args_p2g, device=device)
        wp.launch(grid_update, dim=nodes**a.dim, inputs=[grid_v, grid_m, nodes, T(dt), T(g)], device=device)
        wp.launch(g2p, dim=n, inputs=[x, v, c_aff, f_def, grid_v, nodes, T(1.0 / dx), T(dt)], device=device)

    for _ in range(a.warmup):
        step()
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    for _ in range(a.steps):
        step()
    wp.synchronize_device(device)
    sec = time.perf_counter() - t0

    xs = x.numpy()
    vs = v.numpy()
    if not (np.isfinite(xs).all() and np.isfinite(vs).all()):
        print("warp block drop became non-finite", file=sys.stderr)
        sys.exit(3)
    out = {
        "code": "warp",
        "warp": wp.config.version,
        "dim": a.dim,
        "precision": a.precision,
        "cells": a.cells,
        "particles": n,
        "steps": a.steps,
        "dt": dt,
        "seconds": sec,
        "pups": n * a.steps / sec,
        # A sanity check that it is the same problem: the centre of mass falls freely.
        "mean_velocity_1": float(vs[:, 1].mean()),
        "expected_velocity_1": g * dt * (a.warmup + a.steps),
        "threads": os.environ.get("OMP_NUM_THREADS", ""),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
