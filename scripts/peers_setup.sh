# Sourced by the peer benchmarks (scripts/bench_peers.sh, scripts/bench_peers_mms.sh),
# from the repository root. Sets
# - `venv`: a virtual environment with warp-lang, numpy and matplotlib, made on first use
#   in $MPMCG_PEERS_VENV (default ~/.cache/mpmcg/venv-peers; needs `python3 -m venv`, on
#   Debian the python3-venv package), with warp's compiled kernels in $venv/kernels;
# - `MPMCG`: the mpmcg binary, $MPMCG if set, else a release build of this checkout;
# and one thread for every numeric library, checks for taskset, and prints the machine.
venv=${MPMCG_PEERS_VENV:-$HOME/.cache/mpmcg/venv-peers}
if ! "$venv/bin/python" -c "import warp, numpy, matplotlib" 2>/dev/null; then
    echo "setting up $venv (warp-lang, numpy, matplotlib)" >&2
    python3 -m venv "$venv" || {
        echo "python3 -m venv failed: on Debian/Ubuntu, apt-get install python3-venv" >&2
        exit 2
    }
    "$venv/bin/pip" install --quiet --upgrade pip
    "$venv/bin/pip" install --quiet warp-lang numpy matplotlib
fi
mkdir -p "$venv/kernels"

if [ -z "${MPMCG:-}" ]; then
    cargo build --release --quiet
    MPMCG="${CARGO_TARGET_DIR:-target}/release/mpmcg"
fi
command -v taskset >/dev/null || { echo "taskset not found (util-linux)" >&2; exit 2; }

export OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
echo "$(date -u +%Y-%m-%d) $(uname -m), $(getconf _NPROCESSORS_ONLN) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'); load: $(cut -d' ' -f1-3 /proc/loadavg)" >&2
