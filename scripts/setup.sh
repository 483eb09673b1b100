#!/usr/bin/env bash
# Installs what mpmcg needs to build and run on Debian 12 / Ubuntu: OpenMPI, parallel
# HDF5, libclang (rsmpi's bindgen), and a Rust toolchain if there is none.
# Idempotent: when everything is there it only checks and returns in a moment.
# Extra Debian packages may be named as arguments (scripts/gallery.sh adds its Python).
set -euo pipefail

packages=(gcc binutils libc6-dev pkg-config libclang-dev libopenmpi-dev openmpi-bin
          libhdf5-openmpi-dev hdf5-tools "$@")
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing ${missing[*]}" >&2
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
    [ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
fi
if ! command -v cargo >/dev/null 2>&1; then
    echo "setup: no Rust toolchain; installing one with rustup" >&2
    command -v curl >/dev/null || { ${sudo:-} apt-get install -y -qq curl ca-certificates >/dev/null; }
    curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh -s -- -y --profile minimal >&2
    . "$HOME/.cargo/env"
fi

# The parallel HDF5 that .cargo/config.toml points the build at.
hdf5_dir=/usr/lib/x86_64-linux-gnu/hdf5/openmpi
if [ ! -f "$hdf5_dir/lib/libhdf5.so" ] && [ ! -f "$hdf5_dir/libhdf5.so" ]; then
    echo "setup: parallel HDF5 not found in $hdf5_dir (non-x86_64 machine?); set HDF5_DIR in .cargo/config.toml" >&2
    exit 1
fi
