#!/usr/bin/env bash
# Set-up, release build, then `mpmcg run` (the built-in default scene unless arguments
# say otherwise): `scripts/run.sh`, `scripts/run.sh inputs/vibrating_bar.toml`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
cargo build --release --quiet
exec target/release/mpmcg run "$@"
