#!/bin/sh
# Build the folders of examples/fleet.yaml from the reference recordings in bags/:
#   fleet/recordings/NAME.mcap  the drive torque recorded for case NAME (a copy of bags/NAME_torque.mcap)
#   fleet/golden/NAME.mcap      the engine-idle drive driven by it ('belt-drive sim --torque-bag', stamped
#                               from 0 as a campaign writes its runs): the outputs this version computes,
#                               to keep and compare later runs against.
# Run from anywhere: sh examples/make_fleet.sh [BELT_DRIVE]  (default: belt-drive on the PATH, else .venv/bin)
set -eu
here=$(cd "$(dirname "$0")" && pwd)
bags="$here/../bags"
bd=${1:-$(command -v belt-drive || echo "$here/../.venv/bin/belt-drive")}
mkdir -p "$here/fleet/recordings" "$here/fleet/golden"
for case in engine_idle engine_runup compressor_cycling; do
  cp "$bags/${case}_torque.mcap" "$here/fleet/recordings/$case.mcap"
  "$bd" sim "$bags/engine_idle.yaml" --torque-bag "$here/fleet/recordings/$case.mcap" \
    --start-time 0 --out "$here/fleet/golden/$case.mcap" --force --quiet > /dev/null
  echo "fleet/recordings/$case.mcap -> fleet/golden/$case.mcap"
done
