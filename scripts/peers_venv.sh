# Sourced by the peer benchmarks (scripts/bench_peers.sh, scripts/bench_peers_mms.sh):
# sets `venv` to a virtual environment with warp-lang, numpy and matplotlib, made on
# first use in $MPMCG_PEERS_VENV (default ~/.cache/mpmcg/venv-peers; needs
# `python3 -m venv`, on Debian the python3-venv package), with warp's compiled kernels
# in $venv/kernels.
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
