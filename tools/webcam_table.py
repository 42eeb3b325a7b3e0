"""Recovered vs true values of calibration on the simulator's webcam presets (issue 11).

    .venv/bin/python tools/webcam_table.py webcam webcam_pillar --no-distortion

Prints one row per preset: the lens k1 (recovered / true), camera response error (max abs
of the inverse curve over codes 0.05..0.95), projector gamma (recovered / true),
fold error (projector px), kernel relative
L2 medians inside the planes and within 12 px of the fold, and the dots skipped.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from calib_presets import fold_distance, kernel_errors  # noqa: E402

import rtdefocus as rd  # noqa: E402


def row(preset: str, distortion: bool) -> str:
    pc = rd.sim.VirtualProCam(preset, **({} if distortion else {"distortion": (0.0, 0.0)}))
    t = pc.truth
    try:
        cal = rd.calibrate(pc)
    except rd.errors.RtDefocusError as exc:
        return f"| {preset} | fails: {exc} |"
    r = cal.meta["radiometry"]
    cam = float(np.abs(cal.camera_lut[:, 13:243] - t.camera_response[13:243]).max())
    hp, wp = t.radius_map.shape
    rng = np.random.default_rng(7)
    xy = np.column_stack([rng.integers(0, wp, 1500), rng.integers(0, hp, 1500)])
    fd = fold_distance(t, xy.astype(float))
    ei = float(np.median(kernel_errors(cal, t, xy[fd > 12][:200])))
    en = float(np.median(kernel_errors(cal, t, xy[fd <= 12][:100]))) if (fd <= 12).any() else float("nan")
    if t.fold_proj is not None:
        a, b, c = t.fold_proj
        ys = np.array([0.0, hp - 1.0])
        xs = -(b * ys + c) / a
        fold = float(np.abs(cal.fold_proj[0] * xs + cal.fold_proj[1] * ys + cal.fold_proj[2]).max())
    else:
        fold = float("nan")
    k1 = cal.meta["geometry"].get("distortion", {}).get("k1", float("nan"))
    return (f"| {preset} | {k1:.4f} / {t.distortion[0]:g} | {cam:.4f} | "
            f"{np.mean(r['gamma']):.3f} / {t.projector_gamma} | "
            f"{fold:.3f} | {ei:.3f} | {en:.3f} | {len(cal.meta['psf'].get('skipped', []))} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presets", nargs="+")
    ap.add_argument("--no-distortion", action="store_true", help="set the lens distortion to 0")
    args = ap.parse_args()
    print("| preset | k1 rec / true | camera response err | projector gamma rec / true | "
          "fold err (proj px) | "
          "kernel L2 inside | kernel L2 near fold | dots skipped |")
    print("|---|---|---|---|---|---|---|---|")
    for p in args.presets:
        print(row(p, not args.no_distortion), flush=True)


if __name__ == "__main__":
    main()
