#!/usr/bin/env bash
# Set-up, then the whole test suite (plain `cargo test` over the workspace), including
# the multi-rank tests that spawn mpirun.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
exec cargo test --workspace "$@"
