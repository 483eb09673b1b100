#!/usr/bin/env bash
# Error against wall time on the 2D axis-aligned manufactured solution: mpmcg's schemes
# (mpm, gimp, mpmcg, mpmcg-domain) and a warp MLS-MPM (scripts/bench_peers_mms_warp.py:
# quadratic B-splines and APIC, the same particles, error measure and time-step rule),
# on the unit square between slip walls and on its periodic variant, one core each.
# Writes results.csv, report.md, error_vs_wall_time.svg and error_vs_h.svg into --out
# (default out/peers-mms); scripts/bench_peers_mms.py says what each holds.
#
# Usage: scripts/bench_peers_mms.sh [--cells 8,16,32,64,128] [--periodic-cells 8,16,32,64,128]
#                                   [--ppc 2] [--cpu K] [--out DIR]
# The defaults take about 35 minutes on one core of a quiet machine (the periodic grid
# has 4 times the particles of the walls' at the same h); `--cells 8,16,32
# --periodic-cells 8,16,32` about 30 seconds.
#
# Set-up on first use: a virtual environment with warp-lang (scripts/peers_setup.sh).
# The mpmcg binary: $MPMCG if set, else a release build of this checkout. Run it on an
# otherwise idle machine: the figures are wall time.
set -euo pipefail
cd "$(dirname "$0")/.."

source scripts/peers_setup.sh
exec "$venv/bin/python" scripts/bench_peers_mms.py --mpmcg "$MPMCG" --warp-cache "$venv/kernels" "$@"
