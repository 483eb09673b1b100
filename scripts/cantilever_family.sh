#!/usr/bin/env bash
# The cantilever family of the hard cases: beams of 3, 4, 5 and 6 m (E = 2, 1, 1, 2 MPa)
# and two softer 4 m beams (E = 0.7, 0.8 MPa) clamped at x = 0 and sagging under
# gravity, h = 0.25 m, at 2 × 2 and 3 × 3 particles per cell, MPM and MPMCG (MUSL),
# plus the 4 m beam in 3D at 2 × 2 × 2 and 3 × 3 × 3 (1 m wide, free sides), and a bar
# hanging from a fixed ceiling. Prints, per run, the worst number of pieces over the
# snapshots and the largest gap to a nearest neighbour (scripts/connectivity.py,
# particles closer than one cell are neighbours). A few minutes on one core.
# Usage: scripts/cantilever_family.sh [OUT]        (default out/cantilever_family)
# Variants, as environment variables (the README's tables name the ones they used):
#   UPDATE=usl     the update order (default musl)
#   SHIFT=0.125    move the grid up by this much (half a cell: the beam's top and bottom
#                  faces then lie inside cells instead of on grid lines)
#   REFINE=2       divide h by this (same particles per cell, so more particles)
#   XPIC=2         update particle velocities by XPIC of this order instead of FLIP
#                  ([method] xpic, README: The cantilever family)
#   QUADRATURE=point   MPMCG's quadrature ([method] quadrature; MPM ignores it)
#   SHARPEN=0      sharpening of MPMCG's nodal averages ([method] sharpen; MPM ignores it)
#   CENTROID=0     passes of the centroid correction ([method] centroid_passes, MPMCG
#                  only; MPM ignores it)
#                  (unset, each of the three takes the scene's default: MPMCG's is the
#                  domain rule, sharpen 1, 4 passes under MUSL; docs/scenes.md)
#   SCHEMES=mpmcg  the gradients to run (default "mpm mpmcg")
#   PPC="2 3 4"   the beams' particles per cell (default "2 3")
#   REFERENCE=DIR  a run of this script at PPC=4 on the same grid: the free ends' distance
#                  from it (scripts/free_end.py)
# After the pieces, one line per run: the energy balance at the end (kinetic + strain
# − work of gravity, ~0 for a conservative run) against the largest work done; then the
# free end's displacement at 1 s and 3 s (scripts/free_end.py).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh python3-h5py python3-numpy
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
cargo build --release --quiet
out=${1:-out/cantilever_family}
mkdir -p "$out"
base=inputs/cantilever.toml

# variant TAG LENGTH E PPC GRADIENT [DIM]: inputs/cantilever.toml with the beam LENGTH
# long, the grid one metre longer and LENGTH + 0.5 deep below the beam.
variant() {
    local tag=$1 len=$2 e=$3 ppc=$4 g=$5 dim=${6:-2}
    local depth cx cy
    depth=$(awk "BEGIN{print $len + 0.5}")
    cx=$(awk "BEGIN{print int(($len + 1) / 0.25 + 0.5)}")
    cy=$(awk "BEGIN{print int(($depth + 1.5) / 0.25 + 0.5)}")
    local f="$out/$tag.toml"
    local r=${REFINE:-1} sh=${SHIFT:-0}
    cx=$((cx * r)); cy=$((cy * r))
    sed -e "s/^gradient = .*/gradient = \"$g\"/" \
        -e "s/youngs_modulus = 1.0e6/youngs_modulus = $e/" \
        -e "s/upper = \[4.0, 1.0\]/upper = [$len, 1.0]/" \
        -e "s/lower = \[0.0, -4.0\]/lower = [0.0, $(awk "BEGIN{print -$depth + $sh}")]/" \
        -e "s/upper = \[5.0, 1.5\]/upper = [$(awk "BEGIN{print $len + 1}"), $(awk "BEGIN{print 1.5 + $sh}")]/" \
        -e "s/^update = .*/update = \"${UPDATE:-musl}\"/" \
        -e "s/cells = \[20, 22\]/cells = [$cx, $cy]/" \
        -e "s/particles_per_cell = 4/particles_per_cell = $ppc/" "$base" > "$f"
    if [ "$dim" = 3 ]; then
        sed -i -e 's/^dim = 2/dim = 3/' \
            -e 's/^lower = \[\(.*\)\]/lower = [\1, -0.5]/' \
            -e 's/^upper = \[\(.*\)\]/upper = [\1, 1.5]/' \
            -e "s/^cells = \[\(.*\)\]\(.*\)/cells = [\1, $((8 * r))]\2/" \
            -e 's/y_upper = "slip" }/y_upper = "slip", z_lower = "slip", z_upper = "slip" }/' \
            -e 's/value = \[0.0, -10.0\]/value = [0.0, -10.0, 0.0]/' \
            -e 's/lower = \[0.0, 0.0\], upper = \[\(.*\), 1.0\]/lower = [0.0, 0.0, 0.0], upper = [\1, 1.0, 1.0]/' "$f"
    fi
    with_method "$f"
    target/release/mpmcg run "$f" --out "$out/$tag" --quiet --threads 1 \
        || echo "$tag: the run did not complete (exit $?)" >&2
}

# with_method FILE: the particle velocity update as XPIC=ORDER asks, and MPMCG's
# quadrature, sharpening and centroid correction as QUADRATURE, SHARPEN and CENTROID ask.
with_method() {
    if [ -n "${XPIC:-}" ]; then
        sed -i "s/^\[method\]/[method]\nxpic = $XPIC/" "$1"
    fi
    if [ -n "${QUADRATURE:-}" ] && grep -q '^gradient = "mpmcg"' "$1"; then
        sed -i "s/^\[method\]/[method]\nquadrature = \"$QUADRATURE\"/" "$1"
    fi
    if [ -n "${SHARPEN:-}" ] && grep -q '^gradient = "mpmcg"' "$1"; then
        sed -i "s/^\[method\]/[method]\nsharpen = $SHARPEN/" "$1"
    fi
    if [ -n "${CENTROID:-}" ] && grep -q '^gradient = "mpmcg"' "$1"; then
        sed -i "s/^\[method\]/[method]\ncentroid_passes = $CENTROID/" "$1"
    fi
}

# hanging TAG E GRADIENT: a 1 m × 4 m bar (2 × 2 per cell) hanging under its weight
# from a fixed ceiling at y = 0: tension at a clamp without bending (README, The
# cantilever family). Same variants; SHIFT moves the grid along x only (the bar's sides
# then lie inside cells), so that the ceiling, like the beams' clamp, stays on a grid
# face: moved off the bar's top, it held the bar only through the top cell's particles,
# which slid out of it, and the bar fell.
hanging() {
    local tag=$1 e=$2 g=$3 r=${REFINE:-1} sh=${SHIFT:-0}
    local f="$out/$tag.toml"
    cat > "$f" <<SCENE
name = "hanging_bar"
dim = 2
[time]
end = 3.0
cfl = 0.2
[method]
gradient = "$g"
update = "${UPDATE:-musl}"
[grid]
lower = [$(awk "BEGIN{print -1 + $sh}"), -8.0]
upper = [$(awk "BEGIN{print 2 + $sh}"), 0.0]
cells = [$((12 * r)), $((32 * r))]
boundary = { x_lower = "slip", x_upper = "slip", y_lower = "slip", y_upper = "fixed" }
[gravity]
value = [0.0, -10.0]
[[materials]]
name = "rubber"
model = "neo_hookean"
density = 1050.0
youngs_modulus = $e
poisson_ratio = 0.3
[[bodies]]
material = "rubber"
shape = { box = { lower = [0.0, -4.0], upper = [1.0, 0.0] } }
particles_per_cell = 2
[output]
every = 0.05
fields = ["velocity", "stress", "displacement"]
SCENE
    with_method "$f"
    target/release/mpmcg run "$f" --out "$out/$tag" --quiet --threads 1 \
        || echo "$tag: the run did not complete (exit $?)" >&2
}

for g in ${SCHEMES:-mpm mpmcg}; do
    hanging "hang_E2e5_ppc2_$g" 2.0e5 "$g"
    hanging "hang_E3e5_ppc2_$g" 3.0e5 "$g"
    for ppc in ${PPC:-2 3}; do
        variant "L3_E2e6_ppc${ppc}_$g" 3.0 2.0e6 "$ppc" "$g"
        variant "L4_E1e6_ppc${ppc}_$g" 4.0 1.0e6 "$ppc" "$g"
        variant "L5_E1e6_ppc${ppc}_$g" 5.0 1.0e6 "$ppc" "$g"
        variant "L6_E2e6_ppc${ppc}_$g" 6.0 2.0e6 "$ppc" "$g"
        variant "L4_E7e5_ppc${ppc}_$g" 4.0 0.7e6 "$ppc" "$g"
        variant "L4_E8e5_ppc${ppc}_$g" 4.0 0.8e6 "$ppc" "$g"
    done
    for ppc in ${PPC:-2 3}; do
        variant "3D_L4_E1e6_ppc${ppc}_$g" 4.0 1.0e6 "$ppc" "$g" 3
    done
done
/usr/bin/python3 scripts/connectivity.py "$out"/*/ --quiet --radius "$(awk "BEGIN{print 0.25 / ${REFINE:-1}}")"
for run in "$out"/*/; do
    /usr/bin/python3 - "$run" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1] + "history.csv")))
work = max(abs(float(r["external_work"])) for r in rows)
last = rows[-1]
print(f"{sys.argv[1]}: t = {float(last['time']):.2f}, energy balance {float(last['total']):.4g} J "
      f"against {work:.4g} J of work ({100 * float(last['total']) / work:+.1f} %)")
PY
done
/usr/bin/python3 scripts/free_end.py "$out"/*/ --cell "$(awk "BEGIN{print 0.25 / ${REFINE:-1}}")" \
    ${REFERENCE:+--reference "$REFERENCE"}
