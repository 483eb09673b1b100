#!/usr/bin/env bash
# What output costs: a 2D scene with 250 000 particles (250 x 250 cells, 2 x 2 particles
# per cell, MPMCG, MUSL, fixed dt) on 2 ranks, run
#   none:        [output] snapshots = false, no [checkpoint]
#   snapshots:   [output] every 40 steps (11 snapshots of 400 steps) with velocity and stress
#   checkpoints: [checkpoint] every 100 steps (3 checkpoints, keep = 2), no snapshots
# each `repeat` times in turn. Prints, for the fastest run of each, the wall time of the
# job, and the time spent writing files as the run itself measured it (`output_seconds`
# in summary.json) with its fraction of the run's wall time: on a shared machine the
# difference between two runs is mostly noise, the in-run measurement is not.
# Usage: scripts/bench_output.sh [steps] [repeat] [dir]   (dir: where the files go; put
# it on the file system you will write to; default a fresh folder under /tmp)
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-400}
repeat=${2:-2}
dir=${3:-$(mktemp -d)}
mkdir -p "$dir"
cargo build --release --quiet
dt=1.0e-5
end=$(python3 -c "print($steps * $dt)")
scene() {
    cat <<TOML
name = "output_cost"
dim = 2
[time]
end = $end
dt = $dt
[method]
gradient = "mpmcg"
update = "musl"
quadrature = "point"          # MPMCG at the particle, as bench_peers.py runs it
centroid_passes = 0
sharpen = 0.0
[grid]
lower = [0.0, 0.0]
upper = [1.0, 1.0]
cells = [250, 250]
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
}
# A scene without [output] writes its initial and final states: say "none".
{ scene; printf '[output]\nsnapshots = false\n'; } > "$dir/none.toml"
{ scene; printf '[output]\nevery = %s\nfields = ["velocity", "stress"]\n' "$(python3 -c "print(40 * $dt)")"; } > "$dir/snapshots.toml"
{ scene; printf '[output]\nsnapshots = false\n[checkpoint]\nevery_steps = 100\nkeep = 2\n'; } > "$dir/checkpoints.toml"
root=""
[ "$(id -u)" -eq 0 ] && root="--allow-run-as-root"
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg) on $(nproc) cores"
for r in $(seq 1 "$repeat"); do
    for c in none snapshots checkpoints; do
        rm -rf "$dir/out_$c"
        # Wall time of the whole job, start-up included.
        t0=$(date +%s.%N)
        mpirun $root -n 2 --bind-to core target/release/mpmcg run "$dir/$c.toml" --out "$dir/out_$c" --threads 1 -q
        t1=$(date +%s.%N)
        python3 -c "print($t1 - $t0)" >> "$dir/wall_$c"
        cp "$dir/out_$c/summary.json" "$dir/summary_${c}_$r.json"
    done
done
echo "load after:  $(cut -d' ' -f1-3 /proc/loadavg)"
du -sh "$dir/out_snapshots" "$dir/out_checkpoints" | sed 's/^/output size: /'
python3 - "$dir" "$steps" "$repeat" <<'PY'
import json, sys
d, steps, repeat = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
print(f"250000 particles, 2 ranks, {steps} steps, fastest of {repeat}")
for c, files, what in (("none", 0, "no output"),
                       ("snapshots", steps // 40 + 1, "snapshots every 40 steps"),
                       ("checkpoints", steps // 100 - 1, "checkpoints every 100 steps")):
    runs = [json.load(open(f"{d}/summary_{c}_{r}.json")) for r in range(1, repeat + 1)]
    jobs = [float(x) for x in open(f"{d}/wall_{c}")]
    k = min(range(repeat), key=lambda i: jobs[i])
    s = runs[k]
    out = s["output_seconds"]["snapshots"] + s["output_seconds"]["checkpoints"]
    line = f"{what:28s}: job {jobs[k]:6.2f} s, run {s['wall_seconds']:6.2f} s"
    if files:
        line += (f", writing {out:5.2f} s = {out / s['wall_seconds']:.1%} of the run "
                 f"({out / files:.3f} s per file, {files} files)")
    print(line)
PY
[ -z "${3:-}" ] && rm -rf "$dir"
exit 0
