"""Recovered vs true figures of a calibration on a simulated set-up (issue 11's done-when list),
shared by tests/test_webcam.py and tools/webcam_table.py.

Every figure is measured against the simulator's ground truth, never read from the
calibration's own statistics: lens k1, camera response (max abs error of the inverse curve over
codes 0.05..0.95), projector gamma, fold (projector px), a checkerboard through the calibrated
warp (camera px RMS, in ideal camera pixels), kernel relative L2 inside the planes and near the
fold, and the compensation gain as a share of the gain with the true kernels (the oracle).
"""

from __future__ import annotations

import checkerboard
import numpy as np
from calib_presets import NEAR_FOLD, fold_distance, kernel_errors

# Inverse-response error is measured over codes 0.05..0.95 of full scale (the range).
CODES = slice(13, 243)


def fold_error(calib, truth) -> float:
    """Largest distance (projector px) between the true fold and the calibrated one, at the
    frame's top and bottom rows (nan for one plane)."""
    if truth.fold_proj is None or calib.n_planes == 1:
        return float("nan")
    hp = truth.radius_map.shape[0]
    a, b, c = truth.fold_proj
    ys = np.array([0.0, hp - 1.0])
    xs = -(b * ys + c) / a
    f = calib.fold_proj
    return float(np.abs(f[0] * xs + f[1] * ys + f[2]).max())


def checkerboard_rms(procam, calib) -> tuple[float, float]:
    """(RMS, largest row/column bend) in camera px of a checkerboard's inner corners through
    the calibrated warp against where the display rect puts them. The camera view is divided
    by a white view (texture) and undistorted with the *true* lens, so the figure judges the
    calibrated geometry (lens included) against the truth."""
    from rtdefocus.calib.lens import undistort_image
    from rtdefocus.gl.warp import warp_image

    img = checkerboard.board()
    rect = calib.display_rect((img.shape[1], img.shape[0]), margin=0.05)
    frame = warp_image(calib, img, rect=rect)
    view = procam.capture(frame, sharp=True).astype(np.float32)
    white = procam.capture(np.full_like(frame, 255), sharp=True).astype(np.float32)
    view = np.clip(255.0 * view / np.maximum(white, 1.0), 0, 255).astype(np.uint8)
    view = undistort_image(view, procam.truth.distortion, tuple(procam.camera_size))
    err, grid = checkerboard.corner_errors(view, rect, img.shape)
    bend = 0.0
    for line in list(grid) + list(grid.transpose(1, 0, 2)):
        centred = line - line.mean(axis=0)
        bend = max(bend, float(np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(len(line))))
    return float(np.sqrt(np.mean(err ** 2))), bend


def kernel_medians(calib, truth, n: int = 200) -> tuple[float, float]:
    """Median kernel relative L2 at ``n`` projector pixels farther than 12 px from the fold and
    at ``n // 2`` within 12 px of it (nan for one plane)."""
    hp, wp = truth.radius_map.shape
    rng = np.random.default_rng(7)
    xy = np.column_stack([rng.integers(0, wp, 8 * n), rng.integers(0, hp, 8 * n)])
    fd = fold_distance(truth, xy.astype(float))
    inside = float(np.median(kernel_errors(calib, truth, xy[fd > NEAR_FOLD][:n])))
    near = xy[fd <= NEAR_FOLD][: n // 2]
    return inside, float(np.median(kernel_errors(calib, truth, near))) if len(near) else float("nan")


def gain_share(procam, calib, images: dict) -> tuple[float, float]:
    """(calibrated, oracle) mean PSNR gain in dB of ``ycbcr`` over geometry only, over the
    display rect of the calibrated geometry, camera views in ideal camera pixels; both
    compensators solve for the calibrated warp of each image."""
    from rtdefocus import Compensator
    from rtdefocus.scores import camera_view, psnr, rect_mask
    from rtdefocus.sim import oracle_calibration

    geometry = Compensator(calib, method="none")
    ours = Compensator(calib, method="ycbcr")
    oracle = Compensator(oracle_calibration(procam), method="ycbcr")
    wc, hc = calib.camera_size
    g_cal, g_or = [], []
    for image in images.values():
        mask = rect_mask(calib.display_rect((image.shape[1], image.shape[0])), (hc, wc))
        warped = geometry.warp(image)
        sharp = camera_view(procam, calib, warped, sharp=True)
        p0 = psnr(camera_view(procam, calib, warped), sharp, mask)
        ours.reset()
        oracle.reset()
        # Both solve for the same warped target: the calibrated and the true geometry differ by
        # hundredths of a pixel, but their display rects may differ by a whole one.
        for comp, gains in ((ours, g_cal), (oracle, g_or)):
            view = camera_view(procam, calib, comp.compensate_warped(warped, warm_start=False))
            gains.append(psnr(view, sharp, mask) - p0)
    return float(np.mean(g_cal)), float(np.mean(g_or))


def figures(procam, calib, images: dict | None = None) -> dict:
    """All the figures of one calibrated set-up (``images``: photographs for the gain; None
    leaves the gain out)."""
    t = procam.truth
    out = {"k1": float(np.asarray(calib.camera_distortion if calib.camera_distortion is not None
                                  else (0.0, 0.0))[0]),
           "k1_true": float(t.distortion[0]),
           "camera_err": float(np.abs(calib.camera_lut[:, CODES] - t.camera_response[CODES]).max()),
           "gamma": float(np.mean(calib.meta["radiometry"]["gamma"])),
           "gamma_true": float(t.projector_gamma),
           "fold_px": fold_error(calib, t),
           "skipped": len(calib.meta.get("psf", {}).get("skipped", []))}
    out["checker_rms"], out["checker_bend"] = checkerboard_rms(procam, calib)
    out["kernel_inside"], out["kernel_fold"] = kernel_medians(calib, t)
    if images:
        g_cal, g_or = gain_share(procam, calib, images)
        out.update(gain_db=g_cal, gain_oracle_db=g_or, gain_share=g_cal / g_or)
    return out


HEADER = ("| preset | k1 rec / true | camera resp. err | proj. gamma rec / true | fold err (proj px)"
          " | checkerboard RMS / bend (cam px) | kernel L2 inside | kernel L2 near fold | gain dB "
          "cal / oracle (share) | dots skipped |\n|---|---|---|---|---|---|---|---|---|---|")


def row(name: str, f: dict) -> str:
    """One markdown row of :data:`HEADER`."""
    gain = (f"{f['gain_db']:.2f} / {f['gain_oracle_db']:.2f} ({100 * f['gain_share']:.0f} %)"
            if "gain_db" in f else "-")
    return (f"| {name} | {f['k1']:.4f} / {f['k1_true']:g} | {f['camera_err']:.4f} | "
            f"{f['gamma']:.3f} / {f['gamma_true']:g} | {f['fold_px']:.3f} | "
            f"{f['checker_rms']:.3f} / {f['checker_bend']:.3f} | {f['kernel_inside']:.3f} | "
            f"{f['kernel_fold']:.3f} | {gain} | {f['skipped']} |")
