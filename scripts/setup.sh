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

# The parallel HDF5 that .cargo/config.toml points the build at (as `.hdf5`): the user's
# HDF5_DIR if set, else Debian's multiarch path for this machine's architecture, else the
# installation point `h5pcc -showconfig` reports.
root=$(cd "$(dirname "$0")/.." && pwd)
find_hdf5() {
    if [ -n "${HDF5_DIR:-}" ]; then echo "$HDF5_DIR"; return; fi
    local multiarch
    multiarch=$(gcc -print-multiarch 2>/dev/null || true)
    [ -n "$multiarch" ] || multiarch="$(uname -m)-linux-gnu"
    if [ -d "/usr/lib/$multiarch/hdf5/openmpi/include" ]; then
        echo "/usr/lib/$multiarch/hdf5/openmpi"; return
    fi
    if command -v h5pcc >/dev/null 2>&1; then
        h5pcc -showconfig 2>/dev/null | sed -n 's/^ *Installation point: *//p' | head -1
    fi
}
hdf5_dir=$(find_hdf5)
if [ -z "$hdf5_dir" ] || [ ! -d "$hdf5_dir/include" ] \
   || { [ ! -f "$hdf5_dir/lib/libhdf5.so" ] && [ ! -f "$hdf5_dir/libhdf5.so" ]; }; then
    echo "setup: no parallel HDF5 found (looked at HDF5_DIR, /usr/lib/<multiarch>/hdf5/openmpi, h5pcc -showconfig); install libhdf5-openmpi-dev or set HDF5_DIR to a parallel HDF5's installation (with include/ and lib/)" >&2
    exit 1
fi
if [ "$(readlink "$root/.hdf5" 2>/dev/null)" != "$hdf5_dir" ]; then
    ln -sfn "$hdf5_dir" "$root/.hdf5"
fi
