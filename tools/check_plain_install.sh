#!/usr/bin/env bash
# A plain `pip install .` (no extras) into a fresh venv runs the main commands: calibrate the
# built-in cubicle and play a picture through the calibration. Part of `make test`:
# a runtime import that only an extra brings in fails here, not on a user's machine.
set -euo pipefail
cd "$(dirname "$0")/.."
src=$(pwd)
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
PYTHON=${PYTHON:-python3}
"$PYTHON" -m venv "$dir/venv"
"$dir/venv/bin/python" -m pip install -q --disable-pip-version-check "$src"
cd "$dir"
export PATH="$dir/venv/bin:$PATH"
rtdefocus -q simulate --scene cubicle --pattern checker -o picture.png
rtdefocus -q calibrate --sim cubicle -o setup.npz
rtdefocus -q play setup.npz picture.png --out shown.png
test -s shown.png
echo "plain install: calibrate and play work without extras"
