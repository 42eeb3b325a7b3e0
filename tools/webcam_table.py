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
exact planes (no residual field); ``--dense on`` adds the dense structured light;
``--lens-from webcam`` measures the lens once on the flat-walled webcam preset and gives it to
the geometry stage (``lens=``) instead of estimating it from the walls.
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
    ap.add_argument("--lens-from", default=None, metavar="PRESET",
                    help="calibrate PRESET's geometry first and give its lens to the others (a "
                    "lens measured once on flat walls)")
    ap.add_argument("--flat", action="store_true",
                    help="calibrate exact planes (no residual field), to see what it gains")
    args = ap.parse_args()
    kw = {"distortion": (0.0, 0.0)} if args.no_distortion else {}
    print(HEADER)
    calib_kw = {"residual": False} if args.flat else {}
    if args.dense is not None:
        calib_kw["dense"] = args.dense == "on"
    if args.lens_from:
        # The lens measured once on another set-up of the same camera, then taken as given.
        from helpers import Blind

        import rtdefocus as rd

        size = {} if args.size is None else {
            "projector_size": args.size,
            "camera_size": (int(args.size[0] * 1.6), int(args.size[1] * 1.6))}
        ref = rd.sim.VirtualProCam(args.lens_from, projector_gamma=2.2, **size, **kw)
        lens = rd.calibrate(Blind(ref), stages=["geometry"]).camera_distortion
        calib_kw["lens"] = (float(lens[0]), float(lens[1]))
        print(f"<!-- lens from {args.lens_from}: k1 = {lens[0]:.5f}, k2 = {lens[1]:.5f} -->")
    for p in args.presets:
        print(measure(p, args.size, args.photos, calib_kw, **kw), flush=True)


if __name__ == "__main__":
    main()
