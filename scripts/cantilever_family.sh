#!/usr/bin/env bash
# The cantilever family of the hard cases: beams of 3, 4, 5 and 6 m (E = 2, 1, 1, 2 MPa)
# clamped at x = 0 and sagging under gravity, h = 0.25 m, at 2 × 2 and 3 × 3 particles
# per cell, MPM and MPMCG (MUSL), plus the 4 m beam in 3D at 2 × 2 × 2 and 3 × 3 × 3
# (1 m wide, free sides). Prints, per run, the worst number of pieces over the snapshots and the largest
# gap to a nearest neighbour (scripts/connectivity.py, particles closer than one cell
# are neighbours). About two minutes on one core.
# Usage: scripts/cantilever_family.sh [OUT]        (default out/cantilever_family)
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
    sed -e "s/^gradient = .*/gradient = \"$g\"/" \
        -e "s/youngs_modulus = 1.0e6/youngs_modulus = $e/" \
        -e "s/upper = \[4.0, 1.0\]/upper = [$len, 1.0]/" \
        -e "s/lower = \[0.0, -4.0\]/lower = [0.0, -$depth]/" \
        -e "s/upper = \[5.0, 1.5\]/upper = [$(awk "BEGIN{print $len + 1}"), 1.5]/" \
        -e "s/cells = \[20, 22\]/cells = [$cx, $cy]/" \
        -e "s/particles_per_cell = 4/particles_per_cell = $ppc/" "$base" > "$f"
    if [ "$dim" = 3 ]; then
        sed -i -e 's/^dim = 2/dim = 3/' \
            -e 's/^lower = \[\(.*\)\]/lower = [\1, -0.5]/' \
            -e 's/^upper = \[\(.*\)\]/upper = [\1, 1.5]/' \
            -e 's/^cells = \[\(.*\)\]\(.*\)/cells = [\1, 8]\2/' \
            -e 's/y_upper = "slip" }/y_upper = "slip", z_lower = "slip", z_upper = "slip" }/' \
            -e 's/value = \[0.0, -10.0\]/value = [0.0, -10.0, 0.0]/' \
            -e 's/lower = \[0.0, 0.0\], upper = \[\(.*\), 1.0\]/lower = [0.0, 0.0, 0.0], upper = [\1, 1.0, 1.0]/' "$f"
    fi
    target/release/mpmcg run "$f" --out "$out/$tag" --quiet --threads 1 \
        || echo "$tag: the run did not complete (exit $?)" >&2
}

for g in mpm mpmcg; do
    for ppc in 2 3; do
        variant "L3_E2e6_ppc${ppc}_$g" 3.0 2.0e6 "$ppc" "$g"
        variant "L4_E1e6_ppc${ppc}_$g" 4.0 1.0e6 "$ppc" "$g"
        variant "L5_E1e6_ppc${ppc}_$g" 5.0 1.0e6 "$ppc" "$g"
        variant "L6_E2e6_ppc${ppc}_$g" 6.0 2.0e6 "$ppc" "$g"
    done
    variant "3D_L4_E1e6_ppc2_$g" 4.0 1.0e6 2 "$g" 3
    variant "3D_L4_E1e6_ppc3_$g" 4.0 1.0e6 3 "$g" 3
done
/usr/bin/python3 scripts/connectivity.py "$out"/*/ --quiet --radius 0.25
