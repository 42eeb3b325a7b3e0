"""What the residual report reads after each change of the virtual set-up, and what it costs.

At 800x600 (camera 1280x960), per preset: a fresh set-up with its oracle calibration (the
camera's true response added), smooth aperiodic content (Gaussian-smoothed noise, σ 3 px);
one change per row, on a fresh set-up each, against the unchanged calibration. "true" is the
content's mean motion per plane from the simulator's ground truth. The cost is the median of
three calls of `residual_report` (NumPy, host), and each change's own rebuild time.

    python tools/bench_watch.py [preset ...]
"""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np

from rtdefocus import sim
from rtdefocus.planar import apply_h
from rtdefocus.watch import residual_report

CHANGES = [
    ("unchanged", {}),
    ("projector 0.3° + 3 px", {"bump": {"projector_yaw_deg": 0.3, "projector_shift_px": 3.0}}),
    ("camera 4 px", {"bump": {"camera_shift_px": 4.0}}),
    ("room light +0.1", {"set_light": "+0.1"}),
    ("blur radii ×1.15", {"refocus": {"scale": 1.15}}),
]


def content(size):
    w, h = size
    img = cv2.GaussianBlur(np.random.default_rng(0).random((h, w)).astype(np.float32), (0, 0), 3)
    img = (img - img.min()) / (img.max() - img.min())
    return np.repeat((40 + 180 * img)[..., None], 3, axis=2).astype(np.uint8)


def true_motion(calib, pc, plane):
    wp, hp = pc.projector_size
    ys, xs = np.mgrid[hp // 4:3 * hp // 4:8, wp // 8:7 * wp // 8:8]
    sel = pc.truth.plane_map[ys, xs] == plane
    pts = np.stack([xs[sel], ys[sel]], axis=1).astype(np.float64)
    back = apply_h(calib.H_proj_from_cam[plane], apply_h(pc.truth.H_cam_from_proj[plane], pts))
    return (back - pts).mean(axis=0)


def main(presets) -> None:
    print("| preset | change | change s | report s | gain | ambient added (true) | band ratio "
          "| shift per plane, proj px (true) |")
    print("|---|---|---|---|---|---|---|---|")
    for preset in presets:
        for name, change in CHANGES:
            pc = sim.VirtualProCam(preset)
            calib = sim.oracle_calibration(pc)
            calib.camera_lut = np.tile(pc.truth.camera_response, (3, 1)).astype(np.float32)
            frame = content(pc.projector_size)
            gamma0 = pc.truth.ambient_proj.copy()
            t0 = time.perf_counter()
            for kind, params in change.items():
                if kind == "set_light":
                    pc.set_light(ambient=pc.ambient + float(params))
                else:
                    getattr(pc, kind)(**params)
            t_change = time.perf_counter() - t0
            cap = pc.capture(frame)
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                r = residual_report(calib, frame, cap)
                times.append(time.perf_counter() - t0)
            added = float((pc.truth.ambient_proj - gamma0).mean())
            shifts = "; ".join(
                f"({r.shifts_proj[p][0]:+.2f}, {r.shifts_proj[p][1]:+.2f}) "
                f"({true_motion(calib, pc, p)[0]:+.2f}, {true_motion(calib, pc, p)[1]:+.2f})"
                for p in range(calib.n_planes))
            print(f"| {preset} | {name} | {t_change:.1f} | {np.median(times):.2f} | {r.gain:.3f} "
                  f"| {r.ambient_added:.4f} ({added:.4f}) | {r.band_ratio:.3f} | {shifts} |")


if __name__ == "__main__":
    main(sys.argv[1:] or ["cubicle", "webcam_cubicle"])
