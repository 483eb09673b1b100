#!/usr/bin/env bash
# Halo traffic per rank per step on 1, 2, 3, 4, 6 and 8 ranks, for a 2D and a 3D scene:
# payload bytes and non-empty messages sent to other ranks, from summary.json's `halo`
# (docs/scaling.md). Byte and message counts do not depend on the machine's speed, so
# the ranks may outnumber the cores (--oversubscribe); no timings are reported.
#
# Both scenes fill a periodic box with material moving diagonally at 0.05 cells per
# step, MPMCG at the particle with MUSL (as the other figures of docs/scaling.md; its
# defaults make more exchanges, see there): every rank is an interior rank with
# neighbours on all sides, as most ranks of a large run are, and particles cross block
# faces.
#
# Usage: scripts/bench_halo.sh [RANKS...]   (default: 1 2 3 4 6 8)
set -euo pipefail
cd "$(dirname "$0")/.."
ranks=("$@")
[ ${#ranks[@]} -eq 0 ] && ranks=(1 2 3 4 6 8)
cargo build --release --quiet
bin=${CARGO_TARGET_DIR:-target}/release/mpmcg
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
root=""
[ "$(id -u)" -eq 0 ] && root="--allow-run-as-root"

# scene DIM CELLS STEPS: a full periodic box of CELLS^DIM cells, 2 particles per cell
# and axis, run for STEPS steps of a fixed dt.
scene() {
    python3 - "$@" <<'PY'
import sys
dim, cells, steps = map(int, sys.argv[1:4])
dt = 1.0e-4
h = 1.0 / cells
v = 0.05 * h / dt                     # 0.05 cells per step
vel = [v, 0.6 * v, 0.3 * v][:dim]
axes = "xyz"[:dim]
faces = ", ".join(f'{a}_lower = "periodic", {a}_upper = "periodic"' for a in axes)
vec = lambda xs: "[" + ", ".join(repr(float(x)) for x in xs) + "]"
print(f'''name = "halo_{dim}d"
dim = {dim}
[time]
end = {steps * dt!r}
dt = {dt!r}
[method]
gradient = "mpmcg"
quadrature = "point"
centroid_passes = 0
sharpen = 0.0
[grid]
lower = {vec([0] * dim)}
upper = {vec([1] * dim)}
cells = {[cells] * dim}
boundary = {{ {faces} }}
[[materials]]
name = "m"
model = "neo_hookean"
density = 1000.0
youngs_modulus = 1.0e5
poisson_ratio = 0.3
[[bodies]]
material = "m"
shape = {{ box = {{ lower = {vec([0] * dim)}, upper = {vec([1] * dim)} }} }}
particles_per_cell = 2
velocity = {vec(vel)}''')
PY
}

scene 2 128 40 > "$dir/halo_2d.toml"
scene 3 32 20 > "$dir/halo_3d.toml"

for s in halo_2d halo_3d; do
    for n in "${ranks[@]}"; do
        mpirun $root --oversubscribe --mca mpi_yield_when_idle 1 -n "$n" \
            "$bin" run "$dir/$s.toml" --out "$dir/$s-$n" --threads 1 --quiet
    done
done

python3 - "$dir" "${ranks[@]}" <<'PY'
import json, sys
d, ranks = sys.argv[1], sys.argv[2:]
for s, desc in [("halo_2d", "2D, 128 x 128 cells, 65 536 particles, 40 steps"),
                ("halo_3d", "3D, 32 x 32 x 32 cells, 262 144 particles, 20 steps")]:
    print(f"\n{desc} (MPMCG, MUSL, periodic box full of material moving 0.05 cells/step)\n")
    print("| ranks | blocks | halo ops/step | grid halo kB/rank/step min / mean / max "
          "| grid messages/rank/step min / mean / max | peers min / mean / max "
          "| migration B/rank/step mean / max | migration messages/rank/step mean |")
    print("| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for n in ranks:
        j = json.load(open(f"{d}/{s}-{n}/summary.json"))
        h = j["halo"]
        g, m, p = h["grid"], h["migration"], h["peers_per_rank"]
        b, ms = g["bytes_per_rank_per_step"], g["messages_per_rank_per_step"]
        mb, mm = m["bytes_per_rank_per_step"], m["messages_per_rank_per_step"]
        print(f"| {n} | {'x'.join(map(str, j['blocks']))} | {g['exchanges_per_step']:g} "
              f"| {b['min']/1e3:.1f} / {b['mean']/1e3:.1f} / {b['max']/1e3:.1f} "
              f"| {ms['min']:g} / {ms['mean']:.1f} / {ms['max']:g} "
              f"| {p['min']:g} / {p['mean']:.1f} / {p['max']:g} "
              f"| {mb['mean']:.0f} / {mb['max']:.0f} | {mm['mean']:.2f} |")
PY
