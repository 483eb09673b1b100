#!/bin/sh
# Check that ParaView's three XDMF readers load the particles of run folders as
# written, and render each run's last step to OUT/paraview.png:
#     scripts/check_paraview.sh OUT...
# Needs pvpython (Debian 12: `apt-get install python3-paraview`). Debian's ParaView
# renders through X even "offscreen", so without a display it runs under xvfb-run
# (`apt-get install xvfb`); with neither, the readers are checked and no picture is
# made (its render window would die with SIGSEGV), and the script says so.
set -eu
here=$(dirname "$0")
command -v pvpython >/dev/null || { echo "pvpython not found: apt-get install python3-paraview (Debian 12)" >&2; exit 2; }
[ $# -gt 0 ] || { echo "usage: $0 OUT..." >&2; exit 2; }
# On one of our machines (a gVisor sandbox) pvpython 5.11 fails to open its render
# window about half the time ("bad X server connection", SIGABRT) while the display
# works for other clients, and more often with a soft limit of 20000 open files than at
# the usual 1024. That failure, and only that one, is retried (up to 12 attempts); any
# other failure of the checks ends the script at once.
if [ "$(ulimit -n)" = unlimited ] || [ "$(ulimit -n)" -gt 1024 ]; then
    ulimit -Sn 1024
fi
log=$(mktemp)
trap 'rm -f "$log"' EXIT
attempt=1
while :; do
    status=0
    if [ -z "${DISPLAY:-}" ] && command -v xvfb-run >/dev/null; then
        xvfb-run -a pvpython --force-offscreen-rendering "$here/check_paraview.py" "$@" >"$log" 2>&1 || status=$?
    elif [ -z "${DISPLAY:-}" ]; then
        echo "check_paraview: no display and no xvfb-run: the readers checked, no picture made (apt-get install xvfb for one)" >&2
        pvpython "$here/check_paraview.py" --no-picture "$@" >"$log" 2>&1 || status=$?
    else
        pvpython --force-offscreen-rendering "$here/check_paraview.py" "$@" >"$log" 2>&1 || status=$?
    fi
    if [ "$status" -ne 0 ] && [ "$attempt" -lt 12 ] && grep -q "bad X server connection" "$log"; then
        echo "check_paraview: pvpython could not open its render window (attempt $attempt); retrying" >&2
        attempt=$((attempt + 1))
        continue
    fi
    cat "$log"
    exit "$status"
done
