"""Recovered vs true values of calibration on the simulator's webcam presets.

    .venv/bin/python tools/webcam_table.py webcam webcam_pillar webcam_tilted webcam_offcenter

Prints one markdown row per preset (tests/setup_figures.py measures them against the ground
truth; the columns are tools/preset_table.py's): the lens k1 (recovered / true), camera
response error (max abs of the inverse curve over codes 0.05..0.95), projector gamma
(recovered / true), planes, fold error (projector px), held-out homography error, a
checkerboard through the calibrated warp (camera px RMS from where the display rect puts its
corners, and the largest bend of a row or column), kernel relative L2 medians inside the planes
and within 12 px of a fold, the compensation gain over geometry only with the calibrated and
the true kernels (and their ratio), the dots skipped and the calibration's seconds. The lens
distortion is on (the presets' k1 = -0.05); ``--no-distortion`` sets it to 0, ``--size``
changes the projector (the camera is 1.6 x it, as the presets' default); ``--flat`` calibrates
exact planes (no residual field).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from preset_table import HEADER, measure, parse_size  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presets", nargs="+")
    ap.add_argument("--no-distortion", action="store_true", help="set the lens distortion to 0")
    ap.add_argument("--size", type=parse_size, default=None,
                    help="projector WxH (default: the preset's)")
    ap.add_argument("--photos", type=int, default=2,
                    help="photographs the compensation gain is averaged over (0: no gain)")
    ap.add_argument("--dense", choices=("on", "off"), default=None,
                    help="dense structured light on or off (default: the geometry stage's)")
    ap.add_argument("--flat", action="store_true",
                    help="calibrate exact planes (no residual field), to see what it gains")
    args = ap.parse_args()
    kw = {"distortion": (0.0, 0.0)} if args.no_distortion else {}
    print(HEADER)
    calib_kw = {"residual": False} if args.flat else {}
    if args.dense is not None:
        calib_kw["dense"] = args.dense == "on"
    for p in args.presets:
        print(measure(p, args.size, args.photos, calib_kw, **kw), flush=True)


if __name__ == "__main__":
    main()
