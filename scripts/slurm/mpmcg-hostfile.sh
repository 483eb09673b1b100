#!/bin/bash
# Run an mpmcg scene with plain `mpirun` on the hosts of a host file, without a batch
# system: checkpoints by wall time, and after a crash (a node lost, a killed rank) the
# run continues from the newest checkpoint, up to MPMCG_MAX_RETRIES times. Running the
# same command again (after a reboot, or after stopping it) continues too.
#
#   scripts/slurm/mpmcg-hostfile.sh HOSTFILE SCENE.toml OUT [RANKS]
#
# HOSTFILE is OpenMPI's (`node1 slots=32` per line); RANKS defaults to the sum of the
# slots. Stop the run with SIGTERM or Ctrl-C to this script: mpmcg writes a final
# checkpoint and the script exits with status 4 without retrying.
#
# Like mpmcg.sbatch, it runs OUT/chain_scene.toml, a copy of SCENE with
# `[checkpoint] every_seconds` added if SCENE has no [checkpoint].
#
# Environment:
#   MPMCG                     the binary [mpmcg on PATH, else target/release/mpmcg]
#   MPMCG_CHECKPOINT_SECONDS  wall seconds between checkpoints if SCENE has none [1800]
#   MPMCG_MAX_RETRIES         restarts after failures other than bad input or
#                             instability [3]
#   MPMCG_MPIRUN_ARGS         more mpirun arguments (e.g. "--bind-to core")
#   MPMCG_DRY_RUN=1           print the mpirun command instead of running it
set -euo pipefail

if [[ $# -lt 3 || $# -gt 4 ]]; then
    echo "usage: $0 HOSTFILE SCENE.toml OUT [RANKS]" >&2
    exit 2
fi
hostfile=$1
scene=$2
out=$3
if [[ ! -f $hostfile ]]; then
    echo "error: $hostfile: no such host file" >&2
    exit 2
fi
ranks=${4:-$(sed -n 's/.*slots=\([0-9]*\).*/\1/p' "$hostfile" | awk '{s += $1} END {print s + 0}')}
if ! [[ $ranks =~ ^[1-9][0-9]*$ ]]; then
    echo "error: give RANKS, or slots=N on the lines of $hostfile" >&2
    exit 2
fi
retries=${MPMCG_MAX_RETRIES:-3}
dry=${MPMCG_DRY_RUN:-0}

exe=${MPMCG:-}
if [[ -z $exe ]]; then
    exe=$(command -v mpmcg || echo target/release/mpmcg)
fi
if [[ ! -x $exe ]]; then
    echo "error: no mpmcg binary at '$exe' (set MPMCG=/path/to/mpmcg)" >&2
    exit 2
fi
exe=$(realpath "$exe")

mkdir -p "$out"
chain_scene=$out/chain_scene.toml
if [[ ! -f $chain_scene ]]; then
    if [[ ! -f $scene ]]; then
        echo "error: $scene: no such scene file" >&2
        exit 2
    fi
    cp "$scene" "$chain_scene.tmp"
    if ! grep -q '^[[:space:]]*\[checkpoint\]' "$chain_scene.tmp"; then
        printf '\n# Added by mpmcg-hostfile.sh: wall-clock checkpoints.\n[checkpoint]\nevery_seconds = %s\n' \
            "${MPMCG_CHECKPOINT_SECONDS:-1800}" >>"$chain_scene.tmp"
    fi
    if ! "$exe" check "$chain_scene.tmp" >/dev/null; then
        rm -f "$chain_scene.tmp"
        exit 2
    fi
    mv "$chain_scene.tmp" "$chain_scene"
fi

# A stop request goes to mpirun as SIGUSR1, which Open MPI forwards to every rank at
# once (a SIGTERM reaches them only after odls_base_sigkill_timeout, and SIGKILL
# follows as soon after); the ranks finish the step and write a final checkpoint.
pid=
stopping=0
stop() {
    stopping=1
    if [[ -n $pid ]]; then
        kill -USR1 "$pid" 2>/dev/null || true
    fi
}
trap stop TERM INT

attempt=0
while :; do
    newest=$(find "$out" -maxdepth 1 -name 'checkpoint_*.h5' | sort | tail -n 1)
    cmd=(mpirun --hostfile "$hostfile" -n "$ranks" ${MPMCG_MPIRUN_ARGS:-}
        "$exe" run "$chain_scene" --out "$out")
    if [[ -n $newest ]]; then
        cmd+=(--restart "$newest")
    fi
    echo "mpmcg: attempt $((attempt + 1)): from ${newest:-the start}"
    if [[ $dry == 1 ]]; then
        echo "dry run: ${cmd[*]}"
        exit 0
    fi
    rc=0
    "${cmd[@]}" &
    pid=$!
    # A trapped signal ends `wait` early: wait again for mpirun's own status.
    wait "$pid" || rc=$?
    if ((stopping)); then
        rc=0
        wait "$pid" || rc=$?
        echo "mpmcg: stopped on request (status $rc); rerun this command to continue from the newest checkpoint" >&2
        exit 4
    fi
    pid=
    case $rc in
    0)
        echo "mpmcg: completed; output in $out"
        exit 0
        ;;
    2 | 3 | 4)
        # Bad input, unstable, or stopped on request: a retry would not help.
        echo "mpmcg: stopped with status $rc (2 bad input, 3 unstable, 4 interrupted: rerun this command to continue)" >&2
        exit "$rc"
        ;;
    esac
    attempt=$((attempt + 1))
    if ((attempt > retries)); then
        echo "mpmcg: status $rc after $retries retries; giving up" >&2
        exit "$rc"
    fi
    echo "mpmcg: status $rc; continuing from the newest checkpoint" >&2
done
