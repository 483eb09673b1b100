#!/usr/bin/python3
"""What a move consistent with the deformation does: a small 2D MPM in numpy (MUSL, FLIP,
lumped mass, the binary's walls, neo-Hookean Kirchhoff stress mu (F F^T - I) + lambda
ln J I, F <- (I + dt L) F) with five gradients, each a pair (the field u the particles
move with, the gradient G that deforms them and whose adjoint f = -G^T (v sigma) is the
internal force):

  mpm  u = sum_i S_i v_i, G = grad S (the binary's MPM under MUSL)
  cg   MPMCG as the binary: G = alpha grad S + (1 - alpha) sum_j S_j Lbar-stencil,
       u the reconstruction sum_j S_j (vbar_j + Lbar_j (x - x_j)), blended into the
       grid interpolation with the particle's hat weight on a wall's nodes
  rg   the same reconstruction u (hat blend), G = grad u: the particles deform with the
       gradient of the field they move with (continuous u, gradient jumps at faces)
  rh   u = sum_j H_j (vbar_j + Lbar_j (x - x_j)) with H_j the tensor products of the cubic
       Hermite weights (1 - xi)^2 (1 + 2 xi), xi^2 (3 - 2 xi) on the particle's cell, so
       grad u is continuous; G = grad u. On a wall's node vbar's held components and
       their derivatives along the wall are zero, so u satisfies the walls unblended.
  rq   as rh with quadratic nodal fields, u = sum_j H_j (v_j + Lbar_j d + d.Q_j.d / 2),
       d = x - x_j, v_j the grid velocity, Q_j = the Lbar stencil applied to Lbar
       (symmetrised): exact for quadratic fields away from walls, so the velocity
       gradient is second order. At a wall: a held component has zero derivatives along
       it (and, at a slip wall, a symmetry plane, zero second normal derivative); a slip
       wall's free component is even about it (zero normal derivative, second normal
       derivative 2 (v_in - v_j) / h^2 from the node inside).

Lbar_j, vbar_j and the fill-weighted domain are the binary's (docs/schemes.md). All
keep sum_i G_i = 0, sum_i x_i (x) G_i = I and the move's exactness for linear fields
(checked by --check), and force and gradient are adjoint by construction.

  --family   the cantilever family at 2 x 2 particles per cell (scripts/cantilever_family.sh's
             2D beams plus E = 0.7 and 0.8 MPa, aligned and shifted by half a cell):
             pieces and the energy balance at 3 s; 3 s (mpm) to 2 minutes (rq) a run
  --gradient the velocity gradient of a smooth field (sin pi x, sin pi y) at particles
             shifted off the lattice, against the exact one, per grid size
  --mms      the AA-MMS of inputs/axis_aligned_mms_2d.toml (unit square, slip faces, one
             period): displacement error (maximum over the run) and velocity error at
             the end, per grid size
  --disk     the spinning disk of docs/hard-cases.md: the strain energy as a share of the
             initial kinetic energy every 10 s (about 7 minutes per 10 s)

Transfers of the grid velocity, with any mode:

  --affine   the particle's last velocity gradient carried to the nodes, m_i v_i =
             sum_p m_p S_ip (v_p + L_p (x_i - x_p)) (--affine skew: its antisymmetric
             part only)
  --centroid the remapped grid velocity, which is the particles' at their mass
             centroid x_i + d_i, moved to the node with the reconstruction's gradient,
             v_i - d_i . Lbar_i(v), and the internal force the adjoint of the gradient of
             that velocity (so the force's power stays the stress power); --centroid K:
             K passes v_j = v - d . Lbar(v_(j-1)); --centroid exact: their fixed point,
             exact for linear fields

Usage: /usr/bin/python3 scripts/consistent_move.py --family [--schemes mpm,cg,rg,rh,rq] [--jobs 2]
       /usr/bin/python3 scripts/consistent_move.py --gradient [--cells 16,32,64]
       /usr/bin/python3 scripts/consistent_move.py --mms [--schemes cg,rh] [--cells 8,16,32] [--ppc 2] [--subpoints]
       /usr/bin/python3 scripts/consistent_move.py --disk [--schemes cg,rh] [--end 100] [--centroid]
       /usr/bin/python3 scripts/consistent_move.py --check
Needs numpy and scipy (Debian: python3-numpy python3-scipy). Results and their reading:
docs/hard-cases.md, "What a prototype shows".
"""
import argparse
import multiprocessing
import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

THETA = 0.9  # the fill a node needs to count in full (docs/schemes.md)
SUBPOINTS = False  # --subpoints
AFFINE = None  # --affine [full|skew]
CENTROID = None  # --centroid [once|exact]


class Scene:
    """A rectangular grid of `cells` from `lower` with spacing h, its four faces'
    conditions ('fixed', 'slip'), a neo-Hookean material, gravity."""

    def __init__(self, lower, cells, h, faces, E, nu, rho, gravity=(0.0, 0.0)):
        self.lower, self.cells, self.h = np.array(lower, float), np.array(cells), h
        self.faces = faces
        self.mu = E / (2 * (1 + nu))
        self.lam = E * nu / ((1 + nu) * (1 - 2 * nu))
        self.rho = rho
        self.g = np.array(gravity, float)


class Grid:
    def __init__(self, sc):
        self.sc = sc
        self.nx, self.ny = sc.cells + 1
        self.nn = self.nx * self.ny
        i, j = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing='ij')
        i, j = i.ravel(), j.ravel()
        self.xn = np.stack([sc.lower[0] + i * sc.h, sc.lower[1] + j * sc.h], 1)
        # on[a]: nodes on a face normal to axis a; mask[:, a]: component a held
        self.on = {0: (i == 0) | (i == sc.cells[0]), 1: (j == 0) | (j == sc.cells[1])}
        self.mask = np.zeros((self.nn, 2), bool)
        for (a, side), kind in sc.faces.items():
            face = (i if a == 0 else j) == (0 if side == 0 else sc.cells[a])
            self.mask[face, :] |= kind == 'fixed'
            self.mask[face, a] |= kind == 'slip'

    def bc(self, v):
        v[self.mask] = 0.0
        return v

    def shape(self, x):
        """Hat weights: node indices (P, 4), weights, gradients (P, 4, 2), the local
        coordinate xi and per face the particles that give weight to its nodes."""
        sc = self.sc
        s = (x - sc.lower) / sc.h
        c = np.floor(s).astype(np.int64)
        if np.any(c < 0) or np.any(c >= sc.cells):
            raise RuntimeError('a particle left the grid')
        xi = s - c
        idx, w, gr = np.empty((len(x), 4), np.int64), np.empty((len(x), 4)), np.empty((len(x), 4, 2))
        k = 0
        for b in (0, 1):
            wy, dy = (xi[:, 1], 1.0) if b else (1 - xi[:, 1], -1.0)
            for a in (0, 1):
                wx, dx = (xi[:, 0], 1.0) if a else (1 - xi[:, 0], -1.0)
                idx[:, k] = (c[:, 0] + a) * self.ny + c[:, 1] + b
                w[:, k] = wx * wy
                gr[:, k, 0] = dx / sc.h * wy
                gr[:, k, 1] = wx * dy / sc.h
                k += 1
        ends = {}
        for a in (0, 1):
            ends[(a, 0)] = c[:, a] == 0
            ends[(a, 1)] = (c[:, a] == sc.cells[a] - 1) & (xi[:, a] > 0)
        return idx, w, gr, xi, ends


def csr(vals, idx, nn):
    rows = np.repeat(np.arange(len(idx)), idx.shape[1])
    return sp.csr_matrix((vals.ravel(), (rows, idx.ravel())), shape=(len(idx), nn))


def node_ops(gd, S, vol):
    """Lbar_b (so Lbar_j[a, b] = (Lb[b] v_a)_j) and Vb (vbar = Vb v_a, walls not yet
    applied) on the fill-weighted domain of particles with hat matrix S, volumes vol."""
    sc, h, ny = gd.sc, gd.sc.h, gd.ny
    cover = S.T @ vol
    i, j = gd.xn[:, 0], gd.xn[:, 1]
    edge = np.where(gd.on[0], 0.5, 1.0) * np.where(gd.on[1], 0.5, 1.0)
    phi = np.minimum(1.0, cover / (THETA * edge * h * h))
    ci, cj = np.meshgrid(np.arange(gd.nx - 1), np.arange(ny - 1), indexing='ij')
    ci, cj = ci.ravel(), cj.ravel()
    loc = [(a, b) for a in (0, 1) for b in (0, 1)]
    corner = [(ci + a) * ny + cj + b for a, b in loc]
    wc = np.min(np.stack([phi[k] for k in corner]), 0)
    on = wc > 0
    m1 = np.array([[h / 3, h / 6], [h / 6, h / 3]])   # int N_j N_i over a cell, per axis
    d1 = np.array([[-0.5, 0.5], [-0.5, 0.5]])         # int N_j N_i'
    r, c, v0, vx, vy = [], [], [], [], []
    for jl, (ja, jb) in enumerate(loc):
        for il, (ia, ib) in enumerate(loc):
            r.append(corner[jl][on])
            c.append(corner[il][on])
            v0.append(wc[on] * m1[ja, ia] * m1[jb, ib])
            vx.append(wc[on] * d1[ja, ia] * m1[jb, ib])
            vy.append(wc[on] * m1[ja, ia] * d1[jb, ib])
    r, c = np.concatenate(r), np.concatenate(c)
    mat = lambda v: sp.csr_matrix((np.concatenate(v), (r, c)), shape=(gd.nn, gd.nn))
    M0, M1 = mat(v0), [mat(vx), mat(vy)]
    V = np.asarray(M0.sum(1)).ravel()
    Di = sp.diags(np.where(V > 0, 1.0 / np.where(V > 0, V, 1.0), 0.0))
    Lb = [Di @ m for m in M1]
    xbar = [Di @ (M0 @ gd.xn[:, b]) for b in (0, 1)]
    Vb = Di @ M0 + sum(sp.diags(np.where(V > 0, gd.xn[:, b] - xbar[b], 0.0)) @ Lb[b] for b in (0, 1))
    return Lb, Vb


def operators(gd, x, vol, scheme, ops=None):
    """S (hat weights, for mass, momentum and FLIP) and per velocity component a the move
    U[a] and the gradient D[a][c] (d/dx_c), sparse particle x node matrices; `ops`
    replaces the node operators of the particles' domain (the finite-difference check)."""
    idx, w, gr, xi, ends = gd.shape(x)
    nn = gd.nn
    S = csr(w, idx, nn)
    Sc = [csr(gr[..., c], idx, nn) for c in (0, 1)]
    if scheme == 'mpm':
        return S, [S, S], [Sc, Sc], ends
    Lb, Vb = node_ops(gd, S, vol) if ops is None else ops
    dx = [x[:, None, b] - gd.xn[idx, b] for b in (0, 1)]
    if scheme in ('rh', 'rq'):
        W, G = hermite(xi, gd.sc.h)
    else:
        W, G = w, gr
    Wm, Wc = csr(W, idx, nn), [csr(G[..., c], idx, nn) for c in (0, 1)]
    WD = [csr(W * dx[b], idx, nn) for b in (0, 1)]
    WcD = [[csr(G[..., c] * dx[b], idx, nn) for b in (0, 1)] for c in (0, 1)]
    U, D = [], []
    for a in (0, 1):
        m = gd.mask[:, a].astype(float)
        Vba = sp.diags(1.0 - m) @ Vb
        La = Lb
        if scheme == 'rh':
            # d(v_a)/d(x_t) is zero along a wall that holds v_a (t: the wall's tangent)
            La = [sp.diags(1.0 - (gd.mask[:, a] & gd.on[1 - t])) @ Lb[t] for t in (0, 1)]
        if scheme == 'rq':
            Ua, Da = quadratic(gd, a, Lb, W, G, dx, idx)
            U.append(Ua.tocsr())
            D.append([d.tocsr() for d in Da])
            continue
        Ua = Wm @ Vba + WD[0] @ La[0] + WD[1] @ La[1]
        Da = [Wc[c] @ Vba + WcD[c][0] @ La[0] + WcD[c][1] @ La[1] + Wm @ La[c] for c in (0, 1)]
        if scheme == 'rh':
            U.append(Ua.tocsr())
            D.append([d.tocsr() for d in Da])
            continue
        # hat blend at walls: s = the particle's weight on nodes that hold v_a
        s = S @ m
        ds = [Sc[c] @ m for c in (0, 1)]
        U.append((sp.diags(1 - s) @ Ua + sp.diags(s) @ S).tocsr())
        if scheme == 'rg':
            D.append([(sp.diags(1 - s) @ Da[c] + sp.diags(s) @ Sc[c] + sp.diags(ds[c]) @ (S - Ua)).tocsr()
                      for c in (0, 1)])
        else:
            al = np.prod(4 * xi * (1 - xi), 1)
            D.append([(sp.diags(al) @ Sc[c] + sp.diags(1 - al) @ (S @ Lb[c])).tocsr() for c in (0, 1)])
    return S, U, D, ends


def quadratic(gd, a, Lb, W, G, dx, idx):
    """rq's move and gradient matrices for velocity component a."""
    sc, nn = gd.sc, gd.nn
    keepL = [np.ones(nn), np.ones(nn)]
    keepQ = [[np.ones(nn), np.ones(nn)], [np.ones(nn), np.ones(nn)]]
    addQ = sp.csr_matrix((nn, nn))
    for (n, side), kind in sc.faces.items():
        t = 1 - n
        on = np.isclose(gd.xn[:, n], sc.lower[n] + side * sc.cells[n] * sc.h)
        if kind == 'fixed' or a == n:
            keepL[t][on] = 0
            keepQ[t][t][on] = 0
            if kind == 'slip':
                keepQ[n][n][on] = 0
        else:
            keepL[n][on] = 0
            keepQ[n][t][on] = keepQ[t][n][on] = keepQ[n][n][on] = 0
            js = np.nonzero(on & ~gd.mask[:, a])[0]
            inside = js + (1 - 2 * side) * (gd.ny if n == 0 else 1)
            k = 2 / sc.h ** 2
            addQ = addQ + sp.csr_matrix((np.concatenate([np.full(len(js), k), np.full(len(js), -k)]),
                                         (np.concatenate([js, js]), np.concatenate([inside, js]))),
                                        shape=(nn, nn))
    La = [sp.diags(keepL[t]) @ Lb[t] for t in (0, 1)]
    Q = [[sp.diags(keepQ[b][c]) @ (0.5 * (Lb[c] @ La[b] + Lb[b] @ La[c])) for c in (0, 1)] for b in (0, 1)]
    # a slip wall's free component a is the tangential one: its normal is the other axis
    Q[1 - a][1 - a] = Q[1 - a][1 - a] + addQ
    Vn = sp.diags(1.0 - gd.mask[:, a])
    Wm, Wc = csr(W, idx, nn), [csr(G[..., e], idx, nn) for e in (0, 1)]
    WD = [csr(W * dx[b], idx, nn) for b in (0, 1)]
    WDD = [[csr(W * dx[b] * dx[c], idx, nn) for c in (0, 1)] for b in (0, 1)]
    WcD = [[csr(G[..., e] * dx[b], idx, nn) for b in (0, 1)] for e in (0, 1)]
    WcDD = [[[csr(G[..., e] * dx[b] * dx[c], idx, nn) for c in (0, 1)] for b in (0, 1)] for e in (0, 1)]
    half = lambda M: 0.5 * sum(M[b][c] @ Q[b][c] for b in (0, 1) for c in (0, 1))
    Ua = Wm @ Vn + WD[0] @ La[0] + WD[1] @ La[1] + half(WDD)
    Da = [Wc[e] @ Vn + WcD[e][0] @ La[0] + WcD[e][1] @ La[1] + Wm @ La[e] + half(WcDD[e])
          + WD[0] @ Q[0][e] + WD[1] @ Q[1][e] for e in (0, 1)]
    return Ua, Da


def hermite(xi, h):
    """Cubic Hermite weights and their gradients over a cell's 4 nodes (Grid.shape's
    order): C1 across faces, a partition of unity."""
    h0, h1 = (1 - xi) ** 2 * (1 + 2 * xi), xi ** 2 * (3 - 2 * xi)
    d1 = 6 * xi * (1 - xi) / h
    W, G = np.empty((len(xi), 4)), np.empty((len(xi), 4, 2))
    k = 0
    for b in (0, 1):
        wy, gy = (h1[:, 1], d1[:, 1]) if b else (h0[:, 1], -d1[:, 1])
        for a in (0, 1):
            wx, gx = (h1[:, 0], d1[:, 0]) if a else (h0[:, 0], -d1[:, 0])
            W[:, k], G[:, k, 0], G[:, k, 1] = wx * wy, gx * wy, wx * gy
            k += 1
    return W, G


def sub_operators(gd, x, F, vol, scheme, spacing):
    """The operators averaged over 2 x 2 sub-points of each particle's domain, at
    F (+-spacing/4, +-spacing/4) from its centre, a quarter of its volume each: the
    quadrature of the force, the gradient, the move and the transfers over the domain
    instead of at the centre."""
    off = np.array([[sx, sy] for sx in (-0.25, 0.25) for sy in (-0.25, 0.25)]) * spacing
    xs = (x[:, None, :] + np.einsum('pab,kb->pka', F, off)).reshape(-1, 2)
    S, U, D, _ = operators(gd, xs, np.repeat(vol / 4, 4), scheme)
    A = sp.kron(sp.identity(len(x)), np.full((1, 4), 0.25), format='csr')
    return (A @ S).tocsr(), [(A @ u).tocsr() for u in U], [[(A @ d).tocsr() for d in dd] for dd in D], \
        gd.shape(x)[4]


class State:
    def __init__(self, sc, x, V, F, vol0):
        self.sc, self.gd = sc, Grid(sc)
        self.x, self.V, self.F, self.vol0 = x.copy(), V.copy(), F.copy(), vol0
        self.m = sc.rho * vol0
        self.t, self.steps, self.work = 0.0, 0, 0.0
        self.spacing = np.sqrt(vol0[0])   # the lattice spacing (all runs here are square)
        self.L = np.zeros((len(x), 2, 2))

    def p2g(self, S, mi, live, V):
        """Grid velocities from the particles' momenta, with --affine the particle's
        velocity gradient carried to the node: m_i v_i = sum_p m_p S_ip (v_p + L_p (x_i - x_p))."""
        gd, m = self.gd, self.m
        mom = np.stack([S.T @ (m * V[:, a]) for a in (0, 1)], 1)
        if AFFINE:
            L = self.L
            if AFFINE == 'skew':
                L = 0.5 * (L - L.transpose(0, 2, 1))
            for a in (0, 1):
                for c in (0, 1):
                    mom[:, a] += (S.T @ (m * L[:, a, c])) * gd.xn[:, c] - S.T @ (m * L[:, a, c] * self.x[:, c])
        v = np.zeros((gd.nn, 2))
        v[live] = mom[live] / mi[live, None]
        return gd.bc(v)

    def stress(self):
        sc, F = self.sc, self.F
        J = np.linalg.det(F)
        return sc.mu * (F @ F.transpose(0, 2, 1) - np.eye(2)) + (sc.lam * np.log(J))[:, None, None] * np.eye(2)

    def energies(self):
        sc, F = self.sc, self.F
        lj = np.log(np.linalg.det(F))
        W = 0.5 * sc.mu * (np.sum(F * F, axis=(1, 2)) - 2) - sc.mu * lj + 0.5 * sc.lam * lj ** 2
        return 0.5 * np.sum(self.m * np.sum(self.V ** 2, 1)), np.sum(self.vol0 * W)

    def prime(self, scheme):
        """With --affine, the particles' velocity gradient of their initial velocities (a
        few passes of L = D p2g(V), as a first step would compute it)."""
        if not AFFINE:
            return
        S, U, D, _ = operators(self.gd, self.x, self.vol0, scheme)
        mi = S.T @ self.m
        live = mi > 1e-12 * self.m.min()
        for _ in range(3):
            vh = self.p2g(S, mi, live, self.V)
            self.L = np.stack([np.stack([D[a][c] @ vh[:, a] for c in (0, 1)], 1) for a in (0, 1)], 1)

    def dt_cfl(self, cfl):
        sc = self.sc
        J = np.linalg.det(self.F)
        tang = sc.lam + 2 * (sc.mu - sc.lam * np.log(J))
        c = np.sqrt(np.maximum(tang, sc.lam + 2 * sc.mu) / sc.rho)
        return cfl * sc.h / np.max(c + np.linalg.norm(self.V, axis=1))

    def step(self, dt, scheme, body=None):
        """One MUSL step; body: force per unit mass at the particles, or None."""
        gd, sc, m, vol0 = self.gd, self.sc, self.m, self.vol0
        J = np.linalg.det(self.F)
        if SUBPOINTS:
            S, U, D, ends = sub_operators(gd, self.x, self.F, vol0 * J, scheme, self.spacing)
        else:
            S, U, D, ends = operators(gd, self.x, vol0 * J, scheme)
        mi = S.T @ m
        tau = self.stress()
        b = np.tile(sc.g, (len(m), 1)) if body is None else body
        live = mi > 1e-12 * m.min()
        if CENTROID:
            # The grid velocity is the particles' at their mass centroid x_i + d_i, not
            # at the node: C corrects it to the node with the reconstruction's gradient,
            # and the force is the adjoint of the gradient of the corrected velocity.
            Lb, _ = node_ops(gd, S, vol0 * J)
            d = np.zeros((gd.nn, 2))
            d[live] = np.stack([S.T @ (m * self.x[:, c]) for c in (0, 1)], 1)[live] / mi[live, None] - gd.xn[live]
            M = sum(sp.diags(d[:, c]) @ Lb[c] for c in (0, 1))
            P = [sp.diags((live & ~gd.mask[:, a]).astype(float)) for a in (0, 1)]
            if CENTROID == 'exact':
                # The fixed point v_c = P (v - d . Lbar(v_c)): exact for a linear field.
                lu = [splu((sp.identity(gd.nn) + P[a] @ M).tocsc()) for a in (0, 1)]
                C = [lambda u, a=a: P[a] @ lu[a].solve(P[a] @ u) for a in (0, 1)]
                CT = [lambda u, a=a: P[a] @ lu[a].solve(P[a] @ u, trans='T') for a in (0, 1)]
            else:
                # `once`: v_1 = P (v - d . Lbar(v)); a number k: k such passes, each
                # v_j = P (v - d . Lbar(v_(j-1))) from v_0 = P v.
                K = [P[a].tocsr() for a in (0, 1)]
                for _ in range(1 if CENTROID == 'once' else int(CENTROID)):
                    K = [(P[a] - P[a] @ M @ K[a]).tocsr() for a in (0, 1)]
                C = [lambda u, a=a: K[a] @ u for a in (0, 1)]
                CT = [lambda u, a=a: K[a].T @ u for a in (0, 1)]
        else:
            C = CT = [lambda u: u] * 2
        f = np.stack([-CT[a](D[a][0].T @ (vol0 * tau[:, a, 0]) + D[a][1].T @ (vol0 * tau[:, a, 1]))
                      + S.T @ (m * b[:, a]) for a in (0, 1)], 1)
        v, vp = self.p2g(S, mi, live, self.V), np.zeros((gd.nn, 2))
        vp[live] = v[live] + dt * f[live] / mi[live, None]
        gd.bc(vp)
        Svp = S @ vp
        Vn = self.V + Svp - S @ v
        free = Vn.copy()
        for (a, side), kind in sc.faces.items():
            if kind == 'slip':   # the binary's clip of the normal velocity at a slip wall
                e = ends[(a, side)]
                Vn[e, a] = (np.maximum if side == 0 else np.minimum)(Vn[e, a], Svp[e, a])
        self.work += 0.5 * np.sum(m * (np.sum(Vn ** 2, 1) - np.sum(free ** 2, 1)))
        self.work += 0.5 * dt * np.sum(m * np.sum((self.V + Vn) * b, 1))
        self.V = Vn
        vh = self.p2g(S, mi, live, Vn)
        if CENTROID:
            vh = np.stack([C[a](vh[:, a]) for a in (0, 1)], 1)
        L = np.stack([np.stack([D[a][c] @ vh[:, a] for c in (0, 1)], 1) for a in (0, 1)], 1)
        self.L = L
        self.F = (np.eye(2) + dt * L) @ self.F
        self.x = self.x + dt * np.stack([U[a] @ vh[:, a] for a in (0, 1)], 1)
        self.t += dt
        self.steps += 1
        if np.any(np.linalg.det(self.F) <= 0) or not np.all(np.isfinite(self.V)):
            raise RuntimeError('J <= 0 at t = %.3f' % self.t)


def lattice(lower, upper, spacing):
    g = [np.arange(lo + spacing / 2, hi, spacing) for lo, hi in zip(lower, upper)]
    return np.stack(np.meshgrid(*g, indexing='ij'), -1).reshape(-1, 2)


def pieces(x, radius):
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree
    pairs = cKDTree(x).query_pairs(radius, output_type='ndarray')
    g = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(x),) * 2)
    return connected_components(g, directed=False)[0]


def beam(args):
    """scripts/cantilever_family.sh's 2D beam of `length` (h = 0.25 m, clamped at x = 0,
    the grid one metre longer and length + 0.5 deep), 2 x 2 per cell, to 3 s."""
    scheme, length, E, shift = args
    h, ppc, depth = 0.25, 2, length + 0.5
    cells = (int((length + 1) / h + 0.5), int((depth + 1.5) / h + 0.5))
    faces = {(0, 0): 'fixed', (0, 1): 'slip', (1, 0): 'slip', (1, 1): 'slip'}
    sc = Scene((0.0, -depth + shift), cells, h, faces, E, 0.3, 1050.0, (0.0, -10.0))
    x = lattice((0.0, 0.0), (length, 1.0), h / ppc)
    st = State(sc, x, np.zeros_like(x), np.tile(np.eye(2), (len(x), 1, 1)), np.full(len(x), (h / ppc) ** 2))
    worst, status, every = 1, 'completed', 0.05
    t0 = time.time()
    try:
        for k in range(1, 61):
            while st.t < k * every - 1e-12:
                st.step(min(st.dt_cfl(0.2), k * every - st.t), scheme)
            worst = max(worst, pieces(st.x, h))
    except RuntimeError as e:
        status = str(e)
    ke, se = st.energies()
    return ('%-4s %g m, E = %g MPa, shift %g: %s, worst %d piece(s), energy balance %+.1f %% of '
            'the work, %d steps (%.0f s)' % (scheme, length, E / 1e6, shift, status, worst,
                                              100 * (ke + se - st.work) / st.work, st.steps, time.time() - t0))


def mms(scheme, n, ppc):
    """AA-MMS 2D (docs/verification.md): A = 0.05, c = 100, one period, CFL 0.2."""
    E, nu, rho, c, A = 1e4, 0.3, 1.0, 100.0, 0.05
    phase = np.array([0.0, 2 * np.pi / 3])
    faces = {(0, 0): 'slip', (0, 1): 'slip', (1, 0): 'slip', (1, 1): 'slip'}
    sc = Scene((0.0, 0.0), (n, n), 1.0 / n, faces, E, nu, rho)

    def exact(X, t):
        u = A * np.sin(np.pi * X) * np.sin(c * np.pi * t + phase)
        v = A * np.sin(np.pi * X) * c * np.pi * np.cos(c * np.pi * t + phase)
        return u, v, 1 + A * np.pi * np.cos(np.pi * X) * np.sin(c * np.pi * t + phase)

    X = lattice((0.0, 0.0), (1.0, 1.0), 1.0 / (n * ppc))
    u, v, Fd = exact(X, 0.0)
    F = np.zeros((len(X), 2, 2))
    F[:, 0, 0], F[:, 1, 1] = Fd[:, 0], Fd[:, 1]
    st = State(sc, X + u, v, F, np.full(len(X), (1.0 / (n * ppc)) ** 2))
    err, end = 0.0, 0.02
    while st.t < end - 1e-12:
        u, _, Fd = exact(X, st.t)
        J = np.prod(Fd, 1)
        b = np.pi ** 2 * u * (st.sc.mu / rho - c ** 2 - (st.sc.lam * (np.log(J) - 1) - st.sc.mu)[:, None] / (rho * Fd ** 2))
        st.step(min(st.dt_cfl(0.2), end - st.t), scheme, body=b)
        u, v, _ = exact(X, st.t)
        err = max(err, np.sqrt(np.mean(np.sum((st.x - X - u) ** 2, 1))))
    return err, np.sqrt(np.mean(np.sum((st.V - v) ** 2, 1))), st.steps


def disk(scheme, end, ppc):
    faces = {(0, 0): 'slip', (0, 1): 'slip', (1, 0): 'slip', (1, 1): 'slip'}
    sc = Scene((0.0, 0.0), (20, 20), 0.05, faces, 1000.0, 0.3, 1000.0)
    x = lattice((0.0, 0.0), (1.0, 1.0), 0.05 / ppc)
    x = x[np.linalg.norm(x - 0.5, axis=1) <= 0.3]
    r = x - 0.5
    st = State(sc, x, 0.2 * np.stack([-r[:, 1], r[:, 0]], 1), np.tile(np.eye(2), (len(x), 1, 1)),
               np.full(len(x), (0.05 / ppc) ** 2))
    st.prime(scheme)
    ke0 = st.energies()[0]
    for k in range(1, int(round(end / 10)) + 1):
        for _ in range(10000):
            st.step(1e-3, scheme)
        ke, se = st.energies()
        print('%s %dx%d t = %3.0f s: strain %5.2f %%, kinetic %6.2f %%, total %+.3f %% of the initial '
              'kinetic energy' % (scheme, ppc, ppc, 10 * k, 100 * se / ke0, 100 * ke / ke0,
                                  100 * (ke + se - ke0) / ke0), flush=True)


def gradient(schemes, cells):
    """The velocity gradient of v = (sin pi x, sin pi y) on the unit square with slip
    faces, at 2 x 2 particles per cell shifted smoothly off the lattice, against the
    exact one; and the move against v."""
    for n in cells:
        faces = {(0, 0): 'slip', (0, 1): 'slip', (1, 0): 'slip', (1, 1): 'slip'}
        gd = Grid(Scene((0.0, 0.0), (n, n), 1.0 / n, faces, 1e4, 0.3, 1.0))
        X = lattice((0.0, 0.0), (1.0, 1.0), 0.5 / n)
        x = X + 0.3 / n * np.array([1.0, 0.5]) * np.sin(np.pi * X)
        vn = gd.bc(np.sin(np.pi * gd.xn))
        exact = np.pi * np.cos(np.pi * x)
        for s in schemes:
            S, U, D, _ = operators(gd, x, np.full(len(x), (0.5 / n) ** 2), s)
            L = np.stack([np.stack([D[a][c] @ vn[:, a] for c in (0, 1)], 1) for a in (0, 1)], 1)
            L[:, 0, 0] -= exact[:, 0]
            L[:, 1, 1] -= exact[:, 1]
            u = np.stack([U[a] @ vn[:, a] for a in (0, 1)], 1)
            print('%-4s %3d cells: gradient error %.3e, move error %.3e (rms over particles)' % (
                s, n, np.sqrt(np.mean(np.sum(L ** 2, axis=(1, 2)))),
                np.sqrt(np.mean(np.sum((u - np.sin(np.pi * x)) ** 2, 1)))))


def check():
    """The identities and the move's exactness for linear fields at particles off the
    walls, and rh's gradient against finite differences of its move."""
    faces = {(0, 0): 'fixed', (0, 1): 'slip', (1, 0): 'slip', (1, 1): 'slip'}
    sc = Scene((0.0, -4.5), (20, 24), 0.25, faces, 1e6, 0.3, 1050.0)
    gd = Grid(sc)
    rng = np.random.default_rng(1)
    x = lattice((0.0, 0.0), (4.0, 1.0), 0.125)
    x += rng.uniform(-0.05, 0.05, x.shape)
    x[:, 0] = np.maximum(x[:, 0], 0.01)
    vol = np.full(len(x), 0.125 ** 2)
    inner = x[:, 0] > 0.5
    one = np.ones(gd.nn)
    for scheme in ('mpm', 'cg', 'rg', 'rh', 'rq'):
        S, U, D, _ = operators(gd, x, vol, scheme)
        e0 = max(abs(D[a][c] @ one)[inner].max() for a in (0, 1) for c in (0, 1))
        eI = max(abs(D[a][c] @ gd.xn[:, b] - (b == c))[inner].max()
                 for a in (0, 1) for b in (0, 1) for c in (0, 1))
        eu = max(abs(U[a] @ gd.xn[:, b] - x[:, b])[inner].max() for a in (0, 1) for b in (0, 1))
        print('%-4s |sum G| %.1e  |sum x G - I| %.1e  |u(x) - x| %.1e' % (scheme, e0, eI, eu))
    # rh, rq: G is the gradient of the move (node operators held fixed)
    v = np.stack([np.sin(gd.xn[:, 0]) * np.cos(2 * gd.xn[:, 1]), np.cos(gd.xn[:, 0] + gd.xn[:, 1])], 1)
    gd.bc(v)
    for scheme in ('rh', 'rq'):
        S, U, D, _ = operators(gd, x, vol, scheme)
        ops = node_ops(gd, S, vol)
        worst = 0.0
        for c in (0, 1):
            e = np.zeros(2)
            e[c] = 1e-6
            up = operators(gd, x + e, vol, scheme, ops)[1]
            um = operators(gd, x - e, vol, scheme, ops)[1]
            for a in (0, 1):
                fd = (up[a] @ v[:, a] - um[a] @ v[:, a]) / 2e-6
                worst = max(worst, abs(fd - D[a][c] @ v[:, a]).max())
        print('%-4s gradient against finite differences of the move: %.1e' % (scheme, worst))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--family', action='store_true')
    ap.add_argument('--mms', action='store_true')
    ap.add_argument('--disk', action='store_true')
    ap.add_argument('--check', action='store_true')
    ap.add_argument('--gradient', action='store_true')
    ap.add_argument('--subpoints', action='store_true',
                    help='integrate over 2 x 2 sub-points of each particle (--mms, --family)')
    ap.add_argument('--affine', nargs='?', const='full', default=None,
                    help='carry the particle velocity gradient to the nodes (m_i v_i = sum m_p S (v_p + L_p (x_i - x_p)))')
    ap.add_argument('--centroid', nargs='?', const='once', default=None,
                    help='correct the remapped grid velocity from the particles\' mass centroid to the node '
                         '(force adjoint): once (default), K passes, or exact (the fixed point)')
    ap.add_argument('--schemes', default=None)
    ap.add_argument('--cells', default='8,16,32')
    ap.add_argument('--ppc', type=int, default=2)
    ap.add_argument('--end', type=float, default=100.0)
    ap.add_argument('--jobs', type=int, default=2)
    a = ap.parse_args()
    global SUBPOINTS, AFFINE, CENTROID
    CENTROID = a.centroid
    SUBPOINTS = a.subpoints
    AFFINE = a.affine
    if a.check:
        check()
    if a.gradient:
        gradient((a.schemes or 'mpm,cg,rh,rq').split(','), list(map(int, a.cells.split(','))))
    if a.family:
        schemes = (a.schemes or 'mpm,cg,rg,rh,rq').split(',')
        runs = [(s, L, E, sh) for s in schemes for sh in (0.0, 0.125)
                for L, E in ((3, 2e6), (4, 1e6), (5, 1e6), (6, 2e6), (4, 0.7e6), (4, 0.8e6))]
        with multiprocessing.Pool(a.jobs) as pool:
            for line in pool.imap(beam, runs):
                print(line, flush=True)
    if a.mms:
        for s in (a.schemes or 'cg,rh').split(','):
            prev = None
            for n in map(int, a.cells.split(',')):
                e, ev, steps = mms(s, n, a.ppc)
                order = '' if prev is None else ', order %.2f' % np.log2(prev / e)
                print('%-4s %dx%d %3d cells: displacement %.3e%s, velocity %.3e, %d steps'
                      % (s, a.ppc, a.ppc, n, e, order, ev, steps), flush=True)
                prev = e
    if a.disk:
        for s in (a.schemes or 'cg,rh').split(','):
            disk(s, a.end, a.ppc)


if __name__ == '__main__':
    main()
