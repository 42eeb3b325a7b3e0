"""Recovered vs true values of calibration on the simulator's webcam presets (issue 11).

    .venv/bin/python tools/webcam_table.py webcam webcam_pillar webcam_tilted webcam_offcenter

Prints one markdown row per preset (tests/webcam_figures.py measures them against the ground
truth): the lens k1 (recovered / true), camera response error (max abs of the inverse curve
over codes 0.05..0.95), projector gamma (recovered / true), fold error (projector px), a
checkerboard through the calibrated warp (camera px RMS from where the display rect puts its
corners, and the largest bend of a row or column), kernel relative L2 medians inside the planes
and within 12 px of the fold, the compensation gain over geometry only with the calibrated and
the true kernels (and their ratio), and the dots skipped. The lens distortion is on (the
presets' k1 = -0.05); ``--no-distortion`` sets it to 0, ``--size`` changes the projector
(the camera is 1.6 x it, as the presets' default).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from webcam_figures import HEADER, figures, row  # noqa: E402

import rtdefocus as rd  # noqa: E402


def measure(preset: str, distortion: bool, size: tuple[int, int] | None, photos: int) -> str:
    kw = {} if distortion else {"distortion": (0.0, 0.0)}
    if size is not None:
        kw.update(projector_size=size, camera_size=(int(size[0] * 1.6), int(size[1] * 1.6)))
    pc = rd.sim.VirtualProCam(preset, **kw)
    t0 = time.perf_counter()
    try:
        cal = rd.calibrate(pc)
    except rd.errors.RtDefocusError as exc:
        return f"| {preset} | fails: {exc} |"
    seconds = time.perf_counter() - t0
    images = None
    if photos:
        from rtdefocus.samples import photographs

        images = dict(list(photographs().items())[:photos])
    return row(preset, figures(pc, cal, images)) + f" <!-- calibrated in {seconds:.0f} s -->"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presets", nargs="+")
    ap.add_argument("--no-distortion", action="store_true", help="set the lens distortion to 0")
    ap.add_argument("--size", type=lambda s: tuple(int(v) for v in s.split("x")), default=None,
                    help="projector WxH (default: the preset's)")
    ap.add_argument("--photos", type=int, default=2,
                    help="photographs the compensation gain is averaged over (0: no gain)")
    args = ap.parse_args()
    print(HEADER)
    for p in args.presets:
        print(measure(p, not args.no_distortion, args.size, args.photos), flush=True)


if __name__ == "__main__":
    main()
