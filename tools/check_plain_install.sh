#!/usr/bin/env bash
# A plain install (no extras) of the built wheel into a fresh venv runs the main commands:
# calibrate the built-in cubicle and play a picture and a PDF deck through the calibration. Part
# of `make test`: a runtime import that only an extra brings in, or a file the wheel does not ship,
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
# A two-page PDF deck written by hand (a coloured rectangle a page), shown as numbered PNGs.
python - <<'PDF'
objs = [b"<< /Type /Catalog /Pages 2 0 R >>", b"<< /Type /Pages /Kids [3 0 R 5 0 R] /Count 2 >>"]
for i, rgb in enumerate((b"1 0 0", b"0 0 1")):
    stream = rgb + b" rg 40 40 320 220 re f"
    objs += [b"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 400 300] /Contents %d 0 R >>" % (4 + 2 * i),
             b"<< /Length %d >>\nstream\n%s\nendstream" % (len(stream), stream)]
out, offsets = bytearray(b"%PDF-1.4\n"), []
for n, body in enumerate(objs, 1):
    offsets.append(len(out))
    out += b"%d 0 obj\n%s\nendobj\n" % (n, body)
xref = len(out)
out += b"xref\n0 %d\n0000000000 65535 f \n" % (len(objs) + 1)
out += b"".join(b"%010d 00000 n \n" % o for o in offsets)
out += b"trailer\n<< /Size %d /Root 1 0 R >>\nstartxref\n%d\n%%%%EOF\n" % (len(objs) + 1, xref)
open("deck.pdf", "wb").write(out)
PDF
rtdefocus -q play setup.npz deck.pdf --out slides/
test "$(ls slides | wc -l)" -eq 2
rtdefocus cameras --probe 0 > /dev/null || true   # the camera listing imports and runs
echo "plain install of the wheel: calibrate and play (a picture, a PDF deck) work without extras"
