#!/usr/bin/env bash
# A plain install (no extras) of the built wheel into a fresh venv runs the main commands:
# calibrate the built-in cubicle and play a picture through the calibration. Part of `make
# test`: a runtime import that only an extra brings in, or a file the wheel does not ship,
# fails here, not on a user's machine. (`pip install .` builds the same wheel.)
set -euo pipefail
cd "$(dirname "$0")/.."
src=$(pwd)
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
PYTHON=${PYTHON:-python3}
"$PYTHON" -m venv "$dir/venv"
"$dir/venv/bin/python" -m pip wheel -q --disable-pip-version-check --no-deps -w "$dir/wheel" "$src"
"$dir/venv/bin/python" -m pip install -q --disable-pip-version-check "$dir"/wheel/rtdefocus-*.whl
cd "$dir"
export PATH="$dir/venv/bin:$PATH"
rtdefocus -q simulate --scene cubicle --pattern checker -o picture.png
rtdefocus -q calibrate --sim cubicle -o setup.npz
rtdefocus -q play setup.npz picture.png --out shown.png
test -s shown.png
rtdefocus cameras --probe 0 > /dev/null || true   # the camera listing imports and runs
echo "plain install of the wheel: calibrate and play work without extras"
