#!/usr/bin/env bash
# Taylor bar at a finer resolution than the test suite's: inputs/taylor_bar.toml with
# its cells refined N times per axis (N = 2: 0.4 mm cells, 33 k particles, about 3 min
# on one core; N = 3: 112 k particles, about 15 min), on RANKS ranks (default 1).
# Prints the final length, mushroom radius and peak plastic strain at 80 µs.
# Usage: scripts/taylor_bar.sh [N] [RANKS]
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-2}
ranks=${2:-1}
scripts/setup.sh python3-h5py
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
cargo build --release --quiet
out=out/taylor_bar_x$n
scene=$(mktemp --suffix .toml)
sed -e "s/^cells = \[12, 12, 42\]/cells = [$((12 * n)), $((12 * n)), $((42 * n))]/" \
    inputs/taylor_bar.toml > "$scene"
root=""
[ "$(id -u)" -eq 0 ] && root="--allow-run-as-root"
mpirun $root --oversubscribe -n "$ranks" target/release/mpmcg run "$scene" --out "$out"
rm -f "$scene"
/usr/bin/python3 - "$out" "$n" <<'PY'
import glob, sys
import h5py, numpy as np
out, n = sys.argv[1], int(sys.argv[2])
half = 0.8e-3 / n / 4  # particle centres lie a quarter cell inside the surface
with h5py.File(sorted(glob.glob(out + "/particles_*.h5"))[-1], "r") as f:
    x, eps, t = f["position"][:], f["plastic_strain"][:], f.attrs["time"]
r = np.hypot(x[:, 0], x[:, 1]).max()
print(f"t = {t * 1e6:.1f} us, cells {0.8 / n:.3f} mm, {len(x)} particles")
print(f"final length {(x[:, 2].max() + half) * 1e3:.2f} mm (reference 21.4-21.5)")
print(f"mushroom radius {r * 1e3:.2f} mm at particle centres, {(r + half) * 1e3:.2f} mm with half a spacing (reference 7.0-7.1)")
print(f"peak plastic strain {eps.max():.2f} (reference 2.5-3)")
PY
