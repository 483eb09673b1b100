#!/usr/bin/env bash
# The README's gallery of hard cases: runs each hard-case scene of inputs/ (MPMCG and
# the scheme it is compared with), then draws its final state and energy history into
# docs/gallery/. Takes a couple of minutes on 2 cores.
# Usage: scripts/gallery.sh            (runs go to out/gallery/, pictures to docs/gallery/)
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh python3-h5py python3-matplotlib
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
cargo build --release --quiet
runs=out/gallery
pics=docs/gallery
mkdir -p "$runs" "$pics"

# run SCENE GRADIENT [TAG [SED]]: the scene with its gradient replaced (and an optional
# sed edit), output in $runs/TAG_GRADIENT. A run that turns unstable is kept: its
# snapshots up to the failure are part of the picture.
run() {
    local scene=$1 g=$2 tag=${3:-$(basename "$1" .toml)} edit=${4:-}
    local tmp
    tmp=$(mktemp --suffix .toml)
    sed -e "s/^gradient = .*/gradient = \"$g\"/" ${edit:+-e "$edit"} "$scene" > "$tmp"
    # The default scene writes no snapshots: ask for some.
    grep -q '^\[output\]' "$tmp" || printf '\n[output]\nevery = 0.1\nfields = ["velocity", "stress"]\n' >> "$tmp"
    echo "gallery: $tag with $g" >&2
    # A fresh folder: snapshots of an earlier, longer or different run would stay
    # beside the new ones and render.py picks snapshots by file name.
    rm -rf "${runs:?}/${tag}_$g"
    target/release/mpmcg run "$tmp" --out "$runs/${tag}_$g" --quiet || true
    rm -f "$tmp"
}
energy() { /usr/bin/python3 scripts/plot_energy.py "${@:3}" -o "$pics/$1_energy.svg" --title "$2"; }
render() { /usr/bin/python3 scripts/render.py "$2" -o "$pics/$1.png" "${@:3}"; }

run inputs/default.toml mpmcg colliding_disks 's/^end = .*/end = 4.0/'
run inputs/default.toml mpm colliding_disks 's/^end = .*/end = 4.0/'
energy colliding_disks "Colliding disks" $runs/colliding_disks_mpmcg $runs/colliding_disks_mpm
render colliding_disks $runs/colliding_disks_mpmcg --time 1.9 --title "Colliding disks, MPMCG, contact"

for s in bent_beam bent_beam_small; do
    run inputs/$s.toml mpmcg; run inputs/$s.toml mpm
    energy $s "Bent beam (${s#bent_beam})" $runs/${s}_mpmcg $runs/${s}_mpm
done
render bent_beam $runs/bent_beam_mpmcg --time 0.8 --title "Bent beam, MPMCG"

run inputs/cantilever.toml mpmcg; run inputs/cantilever.toml mpm
energy cantilever "Cantilever under gravity" $runs/cantilever_mpmcg $runs/cantilever_mpm
render cantilever $runs/cantilever_mpmcg --time 1.2 --title "Cantilever, MPMCG, 4x4 ppc"
# The same at 2 x 2 particles per cell, where MPMCG separates at the clamp (MPM not here).
run inputs/cantilever.toml mpmcg cantilever_ppc2 's/^particles_per_cell = 4/particles_per_cell = 2/'
render cantilever_ppc2 $runs/cantilever_ppc2_mpmcg --time 2.8 --title "Cantilever, MPMCG, 2x2 ppc"

run inputs/zigzag.toml averaged; run inputs/zigzag.toml mpmcg
energy zigzag "MMS at amplitude 0.05: averaged vs MPMCG" $runs/zigzag_averaged $runs/zigzag_mpmcg
render zigzag_averaged $runs/zigzag_averaged --field speed --title "Averaged (α = 0), end of the run"
render zigzag_mpmcg $runs/zigzag_mpmcg --field speed --time 0.046 --title "MPMCG, same time"

run inputs/brittle_bar.toml mpmcg; run inputs/brittle_bar.toml mpm
energy brittle_bar "Brittle bar below its strength" $runs/brittle_bar_mpmcg $runs/brittle_bar_mpm
render brittle_bar $runs/brittle_bar_mpmcg --title "Brittle bar, MPMCG (von Mises stress)"

run inputs/taylor_bar.toml mpmcg
energy taylor_bar "Taylor bar" $runs/taylor_bar_mpmcg
render taylor_bar $runs/taylor_bar_mpmcg --field plastic_strain --view xz --title "Taylor bar at 80 µs (0.8 mm cells)"

echo "gallery: pictures in $pics/" >&2
