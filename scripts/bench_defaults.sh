#!/usr/bin/env bash
# The cost of MPMCG's defaults (the domain rule, sharpen = 1, 4 centroid passes under
# MUSL) against MPMCG at the particle, on the block drop of scripts/bench_peers.py
# (2D 256², 4 × 4 per cell; 3D 64³, 2 × 2 × 2; MUSL; 40 and 15 steps), one pinned core:
# farm-bench's paired wall-time ratio of the whole runs, then each run's time per step
# from summary.json (set-up excluded). About two minutes.
# Usage: scripts/bench_defaults.sh [OUT]        (default out/bench_defaults)
set -euo pipefail
cd "$(dirname "$0")/.."
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
cargo build --release --quiet
out=$(realpath -m "${1:-out/bench_defaults}")
mkdir -p "$out"
bin=$(realpath target/release/mpmcg)
/usr/bin/python3 - "$out" <<'PY'
import sys
sys.path.insert(0, "scripts")
import bench_peers as b
out = sys.argv[1]
for dim, cells, ppc, steps in [(2, 256, 4, 40), (3, 64, 2, 15)]:
    text = b.scene(dim, cells, ppc, "mpmcg", "musl", (steps + 0.5) * b.wave_dt(cells))
    open(f"{out}/point{dim}.toml", "w").write(text)
    open(f"{out}/defaults{dim}.toml", "w").write(text.replace(b.POINT_RULE, ""))
PY
for dim in 2 3; do
    echo "== ${dim}D: defaults (A) against the point rule (B)"
    farm-bench -n 3 --pin 1 --timeout 600 \
        --vs "$bin run $out/point$dim.toml --out $out/point$dim --quiet --threads 1" \
        -- "$bin" run "$out/defaults$dim.toml" --out "$out/defaults$dim" --quiet --threads 1 |
        grep -E "wall|A/B"
    for r in point defaults; do
        /usr/bin/python3 -c "import json, sys; s = json.load(open(sys.argv[1]))
print(f\"$r: {s['steps']} steps, {1e3 * s['wall_seconds'] / s['steps']:.1f} ms a step\")" "$out/$r$dim/summary.json"
    done
done
