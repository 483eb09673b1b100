#!/usr/bin/env bash
# Per-core speed against the fastest CPU MPM peer: the same block drop (neo-Hookean
# block, E = 1e3, nu = 0.2, rho = 1, gravity, unit box, cfl = 0.3) in mpmcg (mpmcg
# gradient MUSL and USL, mpm gradient USL) and in a warp MLS-MPM on the CPU (f64 and
# f32; scripts/bench_peers_warp.py), equal particle counts, one core each. Prints a
# table of steady-state particle updates per second and mpmcg's ratio to warp.
#
# Usage: scripts/bench_peers.sh [--size full|small] [--dims 2,3] [--repeats N] [--cpu K]
#   full  (default): 2D 256^2 cells x 4^2 per cell (376 996 particles), 3D 64^3 x 2^3
#         (438 976); 3.5 minutes with 3 repeats on a quiet 2-core machine, 7 on a busy one
#   small: 2D 128^2, 3D 32^3; about 1.5 minutes
#
# Set-up on first use: a virtual environment with warp-lang (scripts/peers_setup.sh).
# The mpmcg binary: $MPMCG if set, else a release build of this checkout.
# Pinned with taskset to core K (default 0), mpmcg with --threads 1, the OMP and rayon
# thread variables at 1 (warp runs its CPU kernels on one thread). Run it on an otherwise
# idle machine: the figures are wall time.
set -euo pipefail
cd "$(dirname "$0")/.."

source scripts/peers_setup.sh
exec python3 scripts/bench_peers.py --mpmcg "$MPMCG" --warp-python "$venv/bin/python" \
    --warp-cache "$venv/kernels" "$@"
