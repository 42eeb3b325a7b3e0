#!/usr/bin/env python
"""Why the warm start keeps less of the offline gain on a fast pan: a short clip of
the ``eval --video`` kind (a still, then a pan), scored as the eval scores it.

Modes, each through :meth:`rtdefocus.Compensator.compensate` frame by frame:

``flow``     the real-time path: 2 iterations per frame, the motion from DIS optical flow;
``exact``    the same with the *exact* motion of the pan (the clip's known shift mapped through
             the calibration's per-plane homographies into projector space): the flow's share;
``conv0``    the previous frame solved to convergence (``--converge`` cold iterations), carried
             along the exact motion, 0 iterations: how stale the carried correction itself is;
``conv2``    the same plus 2 iterations;
``offline``  40 cold iterations per frame (the eval's ceiling).

With ``--where`` it also writes ``where.png``: the camera-view squared-error excess of each mode
over ``offline`` on the pan's last frame (bright = where the gain is lost).

Example (about 30 s at 400x300, 4 min at 800x600 on 2 loaded cores)::

    .venv/bin/python tools/pan_diagnosis.py --size 800x600 --still 12 --pan 6 --where out/
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

import rtdefocus as rd
from rtdefocus import sim
from rtdefocus.cli.common import parse_size
from rtdefocus.compensate.motion import Motion
from rtdefocus.reference.warp import check_warp_inputs
from rtdefocus.study.eval_video import Segment, make_clip
from rtdefocus.study.scores import camera_view, psnr, rect_mask

MODES = ("flow", "exact", "conv0", "conv2", "offline")


def exact_motion(calib, size: tuple[int, int], dx: float) -> Motion:
    """The exact projector-space motion of a pan by ``dx`` input pixels (content moving left):
    for every projector pixel, where its content was in the previous frame (through the camera:
    projector -> camera by the pixel's plane, shifted, back by the plane it lands on). Invalid
    where the content was outside the picture or the frame."""
    w_in, h_in = size
    wp, hp = calib.projector_size
    rect = calib.display_rect(size)
    hs, layout, (x0, _, w, _), _ = check_warp_inputs(calib.H_cam_from_proj, calib.layout, rect,
                                                    (wp, hp))
    xs, ys = np.meshgrid(np.arange(wp, dtype=np.float64), np.arange(hp, dtype=np.float64))
    m = hs[layout.label(xs, ys)]
    z = m[..., 2, 0] * xs + m[..., 2, 1] * ys + m[..., 2, 2]
    xc = (m[..., 0, 0] * xs + m[..., 0, 1] * ys + m[..., 0, 2]) / z
    yc = (m[..., 1, 0] * xs + m[..., 1, 1] * ys + m[..., 1, 2]) / z
    u = (xc - x0 + 0.5) * w_in / w - 0.5
    xc2 = xc + dx * w / w_in
    out = np.zeros((hp, wp, 2))
    done = np.zeros((hp, wp), bool)
    for q, hq in enumerate(hs):
        hi = np.linalg.inv(hq)
        z = hi[2, 0] * xc2 + hi[2, 1] * yc + hi[2, 2]
        px = (hi[0, 0] * xc2 + hi[0, 1] * yc + hi[0, 2]) / z
        py = (hi[1, 0] * xc2 + hi[1, 1] * yc + hi[1, 2]) / z
        ok = (layout.label(px, py) == q) & ~done
        out[ok, 0], out[ok, 1] = px[ok], py[ok]
        done |= ok
    valid = (done & (out[..., 0] >= 0) & (out[..., 0] <= wp - 1) & (out[..., 1] >= 0)
             & (out[..., 1] <= hp - 1) & (u >= 0) & (u + dx <= w_in - 1))
    return Motion(out.astype(np.float32), valid, float(valid.mean()), False)


class _Exact:
    """A stand-in for the Compensator's MotionEstimator that answers the known motion."""

    def __init__(self, motion: Motion):
        self.motion = motion

    def estimate(self, previous, current) -> Motion:
        return self.motion


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="400x300", help="projector = clip size WxH")
    ap.add_argument("--still", type=int, default=12, help="still frames before the pan")
    ap.add_argument("--pan", type=int, default=6, help="pan frames")
    ap.add_argument("--speed", type=float, default=14.0, help="px/frame at 800 px wide")
    ap.add_argument("--iterations", type=int, default=2)
    ap.add_argument("--converge", type=int, default=60, help="cold iterations of conv0/conv2")
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--where", default=None, help="folder for where.png")
    a = ap.parse_args(argv)
    wp, hp = parse_size(a.size)
    cam = (int(wp * 1.6), int(hp * 1.6))
    procam = sim.VirtualProCam("cubicle", projector_size=(wp, hp), camera_size=cam, seed=0)
    calib = sim.oracle_calibration(procam)
    clip = make_clip((wp, hp), (Segment("still", "still", a.still),
                                Segment("pan", "pan", a.pan, a.speed)))
    mask = rect_mask(calib.display_rect((wp, hp)), (cam[1], cam[0]))
    motion = exact_motion(calib, (wp, hp), a.speed * wp / 800.0)
    comps = {m: rd.Compensator(calib, backend=a.backend) for m in MODES}
    for m in ("exact", "conv0", "conv2"):
        comps[m]._motion = _Exact(motion)
    gains = {m: [] for m in MODES}
    views = {}
    t0 = time.perf_counter()
    for i, (seg, image) in enumerate(clip):
        last_still = seg == "still" and i == a.still - 1
        if seg == "still" and not last_still:
            for m in ("flow", "exact"):
                comps[m].compensate(image, iterations=a.iterations)
            continue
        warped = comps["offline"].warp(image)
        ref = camera_view(procam, calib, warped, sharp=True)
        base = psnr(camera_view(procam, calib, warped), ref, mask)
        for m, c in comps.items():
            if m in ("flow", "exact"):
                out = c.compensate(image, iterations=a.iterations)
            elif m == "offline" or last_still:
                out = c.compensate(image, iterations=40 if m == "offline" else a.converge,
                                   warm_start=False)
            else:
                out = c.compensate(image, iterations=0 if m == "conv0" else a.iterations)
                c.compensate(image, iterations=a.converge, warm_start=False)  # the next carry's
                c._prev_warped = warped.copy()                                 # converged start
            if seg == "pan":
                views[m] = camera_view(procam, calib, out)
                gains[m].append(psnr(views[m], ref, mask) - base)
        if seg == "pan":
            print(f"frame {i}: " + "  ".join(f"{m} {gains[m][-1]:+.2f}" for m in MODES)
                  + f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
    off = np.mean(gains["offline"])
    print("pan mean gain over geometry only (share of offline): " + "  ".join(
        f"{m} {np.mean(g):+.2f} ({np.mean(g) / off:.0%})" for m, g in gains.items()))
    if a.where:
        _where(Path(a.where), views, ref, mask)
    return 0


def _where(folder: Path, views: dict, ref: np.ndarray, mask: np.ndarray) -> None:
    """where.png: per mode (rows), the squared-error excess over offline, blurred."""
    folder.mkdir(parents=True, exist_ok=True)
    ref = ref.astype(np.float32)

    def err(v):
        return ((v.astype(np.float32) - ref) ** 2).mean(-1)

    rows = []
    for m in ("flow", "conv0", "conv2"):
        ex = np.where(mask, np.maximum(err(views[m]) - err(views["offline"]), 0), 0)
        ex = cv2.GaussianBlur(ex.astype(np.float32), (0, 0), 4)
        ex = np.clip(ex / max(float(np.percentile(ex[mask], 99.5)), 1e-9), 0, 1)
        rows.append(cv2.applyColorMap((ex * 255).astype(np.uint8), cv2.COLORMAP_INFERNO))
    cv2.imwrite(str(folder / "where.png"), np.vstack(rows))
    print(f"wrote {folder / 'where.png'} (rows: flow, conv0, conv2)")


if __name__ == "__main__":
    sys.exit(main())
