"""Capture sets, clipped dots and another tool's correspondence map, measured on the simulator.

    .venv/bin/python tools/captures_table.py                    # 800x600 projector
    .venv/bin/python tools/captures_table.py --size 200x150

Three tables, printed as markdown:

* **saved captures**: for the cubicle and the ``clipping`` preset (camera exposed 1.6x too
  long), a live ``rd.calibrate(..., save_captures=DIR)`` through tests/helpers.Blind with the
  camera's exposure control, then ``rd.calibrate_from_captures(DIR)``: captures, the set's size
  on disk, seconds of each, whether every array of the two Calibrations is equal;
* **clipped dots**: kernel relative L2 medians inside the walls and within 12 px of the fold
  (tests/setup_figures.kernel_medians, against the simulator's truth), the exposure factor the
  calibration chose, and what a camera without the control gets;
* **correspondences**: ``rd.calibrate_from_correspondences`` on the simulator's own camera ->
  projector map of the cubicle: planes, the homographies' error in projector px (every 4th
  projector pixel of each true plane, through the true homography and back through the
  calibrated one) and seconds;
* **a channel that clips** (``--channels`` prints only this one): the geometry and PSF
  stages, no exposure control, on the cubicle seen by a plain camera and by one whose red
  channel is 1.6x too sensitive (a ``post`` of tests/helpers.Blind).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from helpers import Blind  # noqa: E402
from setup_figures import kernel_medians  # noqa: E402

import rtdefocus as rd  # noqa: E402
from rtdefocus.cli.common import parse_size  # noqa: E402


def _equal(a, b, tmp: Path) -> bool:
    with np.load(a.save(tmp / "a.npz")) as fa, np.load(b.save(tmp / "b.npz")) as fb:
        return sorted(fa.files) == sorted(fb.files) and all(
            np.array_equal(fa[k], fb[k]) for k in fa.files if k != "meta")


def saved_and_clipped(size, camera) -> None:
    print("| preset | captures | set on disk | live s | replay s | arrays equal | exposure "
          "factor | kernel L2 inside | near fold |")
    print("|---|---|---|---|---|---|---|---|---|")
    for preset in ("cubicle", "clipping"):
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            procam = rd.sim.VirtualProCam(preset, projector_size=size, camera_size=camera)
            t0 = time.perf_counter()
            live = rd.calibrate(Blind(procam, exposure=True), save_captures=tmp / "set")
            t1 = time.perf_counter()
            again = rd.calibrate_from_captures(tmp / "set")
            t2 = time.perf_counter()
            mb = sum(f.stat().st_size for f in (tmp / "set").rglob("*") if f.is_file()) / 2 ** 20
            inside, near = kernel_medians(live, procam.truth)
            factor = live.meta["radiometry"]["exposure_lowered"]
            print(f"| {preset} | {sum(live.meta['captures'].values())} | {mb:.1f} MB | "
                  f"{t1 - t0:.1f} | {t2 - t1:.1f} | {_equal(live, again, tmp)} | "
                  f"{factor if factor is not None else '-'} | {inside:.4f} | {near:.4f} |")
    procam = rd.sim.VirtualProCam("clipping", projector_size=size, camera_size=camera)
    try:
        rd.calibrate(Blind(procam))
        print("| clipping, no exposure control | calibrated |")
    except rd.CalibrationError as exc:
        print(f"| clipping, no exposure control | refused: {str(exc)[:110]}... |")


def correspondences(size, camera) -> None:
    procam = rd.sim.VirtualProCam("cubicle", projector_size=size, camera_size=camera)
    truth = procam.truth
    xy = truth.extra["proj_from_cam"]
    valid = np.isfinite(xy).all(axis=2) & truth.extra["camera_in_frame"]
    t0 = time.perf_counter()
    calib = rd.calibrate_from_correspondences(xy, valid, size)
    seconds = time.perf_counter() - t0
    wp, hp = size
    gx, gy = np.meshgrid(np.arange(0, wp, 4.0), np.arange(0, hp, 4.0))
    pts = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    true_plane = truth.plane_map[gy.astype(int).ravel(), gx.astype(int).ravel()]
    rows = []
    for p in range(len(truth.H_cam_from_proj)):
        sel = true_plane == p
        cam = truth.H_cam_from_proj[p] @ pts[:, sel]
        back = np.einsum("nij,jn->in", calib.H_proj_from_cam[
            calib.plane_of(pts[0, sel], pts[1, sel]).astype(int)], cam / cam[2])
        rows.append(np.linalg.norm(back[:2] / back[2] - pts[:2, sel], axis=0))
    err = np.concatenate(rows)
    per_plane = ", ".join(f"{np.sqrt(np.mean(e ** 2)):.4f}" for e in rows)
    print("| map | planes found / true | H error RMS (per plane) | max | seconds |")
    print("|---|---|---|---|---|")
    print(f"| cubicle, true map, {100 * valid.mean():.0f} % valid | {calib.n_planes} / "
          f"{len(truth.H_cam_from_proj)} | {np.sqrt(np.mean(err ** 2)):.4f} ({per_plane}) | "
          f"{err.max():.4f} | {seconds:.1f} |")


def _red_hot(index, pattern, frame):
    f = frame.astype(np.float32)
    f[..., 0] *= 1.6
    return np.clip(np.rint(f), 0, 255).astype(np.uint8)


def channels(size, camera) -> None:
    print("| camera (geometry and psf stages, no exposure control) | clipped R / G / B on white "
          "| kernel L2 inside | near fold |")
    print("|---|---|---|---|")
    for name, post in (("plain", None), ("red channel 1.6x too sensitive", _red_hot)):
        procam = rd.sim.VirtualProCam("cubicle", projector_size=size, camera_size=camera)
        calib = rd.calibrate(Blind(procam, post), stages=("geometry", "psf"))
        white = Blind(procam, post).capture(np.full((size[1], size[0], 3), 255, np.uint8))
        lit = white.max(axis=2) > 30
        share = " / ".join(f"{100 * v:.0f} %" for v in (white >= 254)[lit].mean(axis=0))
        inside, near = kernel_medians(calib, procam.truth)
        print(f"| {name} | {share} | {inside:.4f} | {near:.4f} |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=parse_size, default=(800, 600), help="projector WxH "
                   "(the camera is 1.6x it)")
    p.add_argument("--channels", action="store_true", help="only the table of a camera whose "
                   "red channel clips")
    args = p.parse_args(argv)
    size = args.size
    camera = (int(round(size[0] * 1.6)), int(round(size[1] * 1.6)))
    if not args.channels:
        saved_and_clipped(size, camera)
        print()
        correspondences(size, camera)
        print()
    channels(size, camera)
    return 0


if __name__ == "__main__":
    sys.exit(main())
