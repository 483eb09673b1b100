#!/usr/bin/env bash
# Whether two builds give the same bits: runs every scene of inputs/ (its end time cut
# to a tenth, a few snapshots), the block drop of scripts/bench_peers.py in 2D and 3D
# under mpmcg/MUSL, mpm/USL and gimp/MUSL (small grids, 60 steps), the built-in default
# scene, and two scenes on 3 ranks (--oversubscribe) with each binary, and compares
# history.csv and every snapshot byte for byte.
#     scripts/same_bits.sh OLD_BINARY NEW_BINARY [WORK_DIR]
# Exit status 1 if any file differs. A refactoring that claims "no change of result"
# is checked with it; the figures go in its commit message or closing note.
set -euo pipefail
old=$1
new=$2
work=${3:-$(mktemp -d)}
root=$(cd "$(dirname "$0")/.." && pwd)
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
mkdir -p "$work/scenes"
for f in "$root"/inputs/*.toml; do
    name=$(basename "$f" .toml)
    # A tenth of the run, four snapshots.
    awk '
        /^\[/ { section = $0 }
        section == "[time]" && $1 == "end" { end = $3 / 10; print "end = " end; next }
        section == "[output]" && $1 == "every" { next }
        { print }
        END { }
    ' "$f" > "$work/scenes/$name.toml"
    end=$(awk '/^\[/ { s = $0 } s == "[time]" && $1 == "end" { print $3 / 10 }' "$f")
    if grep -q '^\[output\]' "$work/scenes/$name.toml"; then
        sed -i "/^\[output\]/a every = $(awk -v e="$end" 'BEGIN { print e / 4 }')" "$work/scenes/$name.toml"
    else
        printf '\n[output]\nevery = %s\n' "$(awk -v e="$end" 'BEGIN { print e / 4 }')" >> "$work/scenes/$name.toml"
    fi
done
python3 - "$root/scripts/bench_peers.py" "$work/scenes" <<'PY'
import importlib.util, sys
spec = importlib.util.spec_from_file_location("bench_peers", sys.argv[1])
bp = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bp)
for dim, cells, ppc in [(2, 32, 4), (3, 12, 2)]:
    for gradient, update in [("mpmcg", "musl"), ("mpm", "usl"), ("gimp", "musl")]:
        name = f"drop{dim}d_{gradient}_{update}"
        text = bp.scene(dim, cells, ppc, gradient, update, 59.5 * bp.wave_dt(cells), name=name)
        text = text.replace("snapshots = false", "every = " + repr(20 * bp.wave_dt(cells)))
        open(f"{sys.argv[2]}/{name}.toml", "w").write(text)
PY
runs=0
diffs=0
compare() { # label dir_old dir_new
    local n=0
    for f in "$2"/history.csv "$2"/particles_*.h5; do
        [ -e "$f" ] || continue
        n=$((n + 1))
        if ! cmp -s "$f" "$3/$(basename "$f")"; then
            echo "DIFFERS $1: $(basename "$f")"
            diffs=$((diffs + 1))
        fi
    done
    echo "$1: $n files compared"
    runs=$((runs + 1))
}
one() { # label ranks scene-or-empty
    local label=$1 ranks=$2 scene=$3
    for which in old new; do
        local bin=$old
        [ "$which" = new ] && bin=$new
        local out="$work/$label.$which"
        rm -rf "$out"
        if [ "$ranks" -gt 1 ]; then
            mpirun -n "$ranks" --oversubscribe "$bin" run $scene --out "$out" --quiet >/dev/null 2>&1
        else
            "$bin" run $scene --out "$out" --quiet --threads 2 >/dev/null 2>&1
        fi
    done
    compare "$label" "$work/$label.old" "$work/$label.new"
}
for f in "$work"/scenes/*.toml; do
    one "$(basename "$f" .toml)" 1 "$f"
done
one default 1 ""
one default_3ranks 3 ""
one cantilever_coarse_3ranks 3 "$work/scenes/cantilever_coarse.toml"
echo "$runs runs, $diffs files differ"
[ "$diffs" -eq 0 ]
