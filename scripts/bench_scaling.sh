#!/usr/bin/env bash
# Strong scaling on one machine: a 2D scene with 262 144 particles (256 x 256 cells,
# 2 x 2 particles per cell, MPMCG, USL), run on 1 rank x 1 thread, 2 ranks x 1 thread
# and 1 rank x 2 threads. Prints particle updates per second and parallel efficiency.
# Usage: scripts/bench_scaling.sh [gradient] [steps]   (run on an otherwise idle machine)
set -euo pipefail
cd "$(dirname "$0")/.."
gradient=${1:-mpmcg}
steps=${2:-100}
cargo build --release --quiet
dir=$(mktemp -d)
dt=1.0e-5
cat > "$dir/scene.toml" <<TOML
name = "scaling"
dim = 2
[time]
end = $(python3 -c "print($steps * $dt)")
dt = $dt
[method]
gradient = "$gradient"
update = "usl"
$([ "$gradient" = mpmcg ] && printf 'quadrature = "point"\nsharpen = 0.0')
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [256, 256]
boundary = { x_lower = "periodic", x_upper = "periodic", y_lower = "slip", y_upper = "slip" }
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1.0e6
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = { box = { lower = [0.0, 0.0], upper = [1.0, 1.0] } }
particles_per_cell = 2
velocity = [3.0, 0.0]
TOML
root=""
[ "$(id -u)" -eq 0 ] && root="--allow-run-as-root"
rate() { python3 -c "import json; print(json.load(open('$1/summary.json'))['particle_updates_per_second'])"; }
target/release/mpmcg run "$dir/scene.toml" --out "$dir/r1" --threads 1 -q
mpirun $root -n 2 --bind-to core target/release/mpmcg run "$dir/scene.toml" --out "$dir/r2" --threads 1 -q
target/release/mpmcg run "$dir/scene.toml" --out "$dir/t2" --threads 2 -q
r1=$(rate "$dir/r1"); r2=$(rate "$dir/r2"); t2=$(rate "$dir/t2")
python3 - "$r1" "$r2" "$t2" "$gradient" "$steps" <<'PY'
import sys
r1, r2, t2 = map(float, sys.argv[1:4])
print(f"gradient {sys.argv[4]}, 262144 particles, {sys.argv[5]} steps")
print(f"1 rank  x 1 thread : {r1:.3e} particle updates/s")
print(f"2 ranks x 1 thread : {r2:.3e} particle updates/s  efficiency {r2 / (2 * r1):.0%}")
print(f"1 rank  x 2 threads: {t2:.3e} particle updates/s  efficiency {t2 / (2 * r1):.0%}")
PY
rm -rf "$dir"
