"""Recovered vs true figures of the full calibration on the simulator's plain presets.

    .venv/bin/python tools/preset_table.py                      # all seven, 800x600
    .venv/bin/python tools/preset_table.py u_cubicle corner_ceiling --size 480x360

Each preset (camera noise on, projector gamma 2.2 as in tests/calib_presets.py) is calibrated
end to end with ``rd.calibrate`` through ``capture`` only (the ground truth is hidden from it,
tests/helpers.Blind), then one markdown row is printed (tests/setup_figures.py measures every
figure against the ground truth): planes found / true, the largest fold error (projector px,
along each true fold inside the frame), the held-out homography error (camera px RMS, 8 px
away from the folds), a checkerboard through the calibrated warp (camera px RMS, largest bend
of a row or column), kernel relative L2 medians inside the planes and within 12 px of any fold,
the compensation gain over geometry only with the calibrated and the true kernels (and their
ratio), the dots skipped, and the seconds the calibration took. ``--flat`` calibrates exact planes (no
residual field), so its rows show what the residual gains on walls that bow. ``--size`` changes the
projector (the camera is 1.6 x it, as the presets' default); the blur radii stay the preset's
(``blur_range_px``), so a smaller projector has relatively larger blur.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from helpers import Blind  # noqa: E402
from setup_figures import HEADER, figures, row  # noqa: E402

import rtdefocus as rd  # noqa: E402
from rtdefocus.cli.common import parse_size  # noqa: E402

PLAIN = ("cubicle", "pillar", "flat", "tilted", "offcenter", "u_cubicle", "corner_ceiling")


def measure(preset: str, size: tuple[int, int] | None = None, photos: int = 2,
            calib_kw: dict | None = None, **procam_kw) -> str:
    """One row of :data:`setup_figures.HEADER` for ``preset`` (``procam_kw`` go to
    :class:`rtdefocus.sim.VirtualProCam`, ``calib_kw`` to ``rd.calibrate``), or a row saying
    why the calibration failed."""
    if size is not None:
        procam_kw.update(projector_size=size, camera_size=(int(size[0] * 1.6), int(size[1] * 1.6)))
    pc = rd.sim.VirtualProCam(preset, **procam_kw)
    t0 = time.perf_counter()
    try:
        cal = rd.calibrate(Blind(pc), **(calib_kw or {}))
    except rd.errors.RtDefocusError as exc:
        return f"| {preset} | fails: {exc} |"
    seconds = time.perf_counter() - t0
    images = None
    if photos:
        from rtdefocus.study.samples import photographs

        images = dict(list(photographs().items())[:photos])
    return row(preset, {**figures(pc, cal, images), "seconds": seconds})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presets", nargs="*", default=list(PLAIN),
                    help=f"presets (default: {' '.join(PLAIN)})")
    ap.add_argument("--size", type=parse_size, default=None,
                    help="projector WxH (default: the preset's, 800x600)")
    ap.add_argument("--gamma", type=float, default=2.2, help="projector gamma (default 2.2)")
    ap.add_argument("--photos", type=int, default=2,
                    help="photographs the compensation gain is averaged over (0: no gain)")
    ap.add_argument("--dense", choices=("on", "off"), default=None,
                    help="dense structured light on or off (default: the geometry stage's)")
    ap.add_argument("--flat", action="store_true",
                    help="calibrate exact planes (no residual field), to see what it gains")
    args = ap.parse_args()
    print(HEADER)
    kw = {"residual": False} if args.flat else {}
    if args.dense is not None:
        kw["dense"] = args.dense == "on"
    for p in args.presets:
        print(measure(p, args.size, args.photos, kw, projector_gamma=args.gamma), flush=True)


if __name__ == "__main__":
    main()
