#!/bin/sh
# Check that ParaView's three XDMF readers load the particles of run folders as
# written, and render each run's last step to OUT/paraview.png:
#     scripts/check_paraview.sh OUT...
# Needs pvpython (Debian 12: `apt-get install python3-paraview`). Debian's ParaView
# renders through X even "offscreen", so without a display it runs under xvfb-run
# (`apt-get install xvfb`).
set -eu
here=$(dirname "$0")
command -v pvpython >/dev/null || { echo "pvpython not found: apt-get install python3-paraview (Debian 12)" >&2; exit 2; }
[ $# -gt 0 ] || { echo "usage: $0 OUT..." >&2; exit 2; }
if [ -z "${DISPLAY:-}" ] && command -v xvfb-run >/dev/null; then
    exec xvfb-run -a pvpython --force-offscreen-rendering "$here/check_paraview.py" "$@"
fi
exec pvpython --force-offscreen-rendering "$here/check_paraview.py" "$@"
