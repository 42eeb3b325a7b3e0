"""Recovered vs true figures of a calibration on a simulated set-up (the webcam
and rooms figures), shared by tests/test_webcam.py, tests/test_rooms_e2e.py, tools/webcam_table.py
and tools/preset_table.py.

Every figure is measured against the simulator's ground truth, never read from the
calibration's own statistics: lens k1, camera response (max abs error of the inverse curve over
codes 0.05..0.95), projector gamma, the number of planes, every fold (projector px), a
checkerboard through the calibrated warp (camera px RMS, in ideal camera pixels), kernel
relative L2 inside the planes and near the folds, and the compensation gain as a share of the
gain with the true kernels (the oracle).

Any number of planes: estimated planes are matched to the true ones by the overlap of the
projector plane maps (not by index), each true fold is judged along the part of it that really
separates its two planes inside the frame, and "near the folds" is within :data:`NEAR_FOLD` px
of any such part. For two planes every figure is the one the single-fold version gave.
"""

from __future__ import annotations

import checkerboard
import numpy as np
from calib_presets import NEAR_FOLD, kernel_errors

# Inverse-response error is measured over codes 0.05..0.95 of full scale (the range).
CODES = slice(13, 243)


def _true_layout(truth):
    from rtdefocus.planar import PlaneLayout

    if truth.folds_proj is None or len(truth.folds_proj) == 0:
        return None
    return PlaneLayout(truth.n_planes, truth.folds_proj, truth.fold_planes)


def true_fold_segments(truth, inset: float = 0.0) -> list[np.ndarray]:
    """The part (2, 2) of each true fold that separates its two planes inside the rectangle of
    projector pixel centres, grown by ``-inset`` px beyond it when ``inset`` < 0 (folds whose
    planes do not meet there are left out)."""
    from rtdefocus.planar import inset_frame

    layout = _true_layout(truth)
    if layout is None:
        return []
    hp, wp = truth.radius_map.shape
    return [s for s in layout.fold_segments(inset_frame((wp, hp), inset)) if s is not None]


def fold_distance(truth, xy: np.ndarray) -> np.ndarray:
    """Distance (px) of projector points to the nearest true fold, along the part of each that
    separates its planes (inf without a fold). Each part runs on NEAR_FOLD px beyond the frame,
    so a point within NEAR_FOLD px of a fold that leaves the frame gets its distance to the
    line, as the single-fold version measured it."""
    d = np.full(len(xy), np.inf)
    for a, b in true_fold_segments(truth, -NEAR_FOLD):
        ab = b - a
        t = np.clip((xy - a) @ ab / (ab @ ab), 0.0, 1.0)
        d = np.minimum(d, np.hypot(*(xy - a - t[:, None] * ab).T))
    return d


def match_planes(calib, truth) -> tuple[np.ndarray, float]:
    """Estimated plane -> true plane by the largest overlap of the projector plane maps, and
    the share of projector pixels whose estimated plane maps to their true one."""
    wp, hp = calib.projector_size
    yy, xx = np.mgrid[0:hp, 0:wp]
    est = calib.layout.label(xx, yy) if calib.n_planes > 1 else np.zeros((hp, wp), int)
    overlap = np.array([[np.sum((est == i) & (truth.plane_map == j)) for j in range(truth.n_planes)]
                        for i in range(calib.n_planes)])
    to_true = overlap.argmax(axis=1)
    return to_true, float(np.mean(to_true[est] == truth.plane_map))


def fold_errors(calib, truth) -> list[float]:
    """Per true fold (in the truth's order), the largest distance (projector px) of the
    calibrated fold between the same two planes from the true fold, along the true fold's part
    inside the frame of pixel centres (inf where the calibration has no fold between them)."""
    layout = _true_layout(truth)
    if layout is None:
        return []
    to_true, _ = match_planes(calib, truth)
    hp, wp = truth.radius_map.shape
    from rtdefocus.planar import inset_frame

    out = []
    for pair, seg in zip(layout.fold_planes, layout.fold_segments(inset_frame((wp, hp), 0.0)),
                         strict=True):
        if seg is None:
            continue
        est = [f for f, fp in zip(calib.folds_proj, calib.fold_planes, strict=True)
               if calib.n_planes > 1 and set(to_true[fp].tolist()) == set(pair.tolist())]
        # the error is linear along the segment: its ends bound it
        out.append(float(np.abs(seg @ est[0][:2] + est[0][2]).max()) if est else float("inf"))
    return out


def fold_error(calib, truth) -> float:
    """Largest error of :func:`fold_errors` (nan without a true fold)."""
    errs = fold_errors(calib, truth)
    return max(errs) if errs else float("nan")


def homography_rms(calib, truth, n: int = 4000) -> float:
    """RMS (camera px) over ``n`` projector points spread over the frame, farther than 8 px from
    every true fold, between where the calibration maps each (its plane's homography, plus its
    residual when it has one) and where
    the truth does (the true plane's; on a set-up whose walls bow, the exact map
    ``truth.cam_from_proj`` at pixel centres). Points on no true plane (a far wall) are left
    out."""
    from rtdefocus.planar import apply_h

    hp, wp = truth.radius_map.shape
    rng = np.random.default_rng(11)
    pts = np.stack([rng.uniform(-0.5, wp - 0.5, n), rng.uniform(-0.5, hp - 0.5, n)], axis=1)
    dense = truth.extra.get("shaped", False)
    if dense:
        pts = np.clip(np.rint(pts), 0, [wp - 1, hp - 1])
    pts = pts[fold_distance(truth, pts) > 8]
    ix = np.clip(np.rint(pts[:, 0]), 0, wp - 1).astype(int)
    iy = np.clip(np.rint(pts[:, 1]), 0, hp - 1).astype(int)
    true_plane = truth.plane_map[iy, ix]
    est_plane = calib.plane_of(pts[:, 0], pts[:, 1]).astype(int)
    err = np.full(len(pts), np.nan)
    for k in range(calib.n_planes):
        for j in range(truth.n_planes):
            sel = (est_plane == k) & (true_plane == j)
            want = (truth.cam_from_proj[iy[sel], ix[sel]] if dense
                    else apply_h(truth.H_cam_from_proj[j], pts[sel]))
            err[sel] = np.linalg.norm(calib.cam_from_proj(pts[sel, 0], pts[sel, 1]) - want, axis=1)
    return float(np.sqrt(np.nanmean(err ** 2)))


def checkerboard_rms(procam, calib) -> tuple[float, float, int]:
    """(RMS, largest row/column bend) in camera px of a checkerboard's inner corners through
    the calibrated warp against where the display rect puts them, and how many planes the
    corners fall on (so how many folds the rows cross). The camera view is divided
    by a white view (texture) and undistorted with the *true* lens, so the figure judges the
    calibrated geometry (lens included) against the truth."""
    err, grid = checkerboard.through_warp(procam, calib, lens=procam.truth.distortion)
    bend = 0.0
    for line in list(grid) + list(grid.transpose(1, 0, 2)):
        centred = line - line.mean(axis=0)
        bend = max(bend, float(np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(len(line))))
    pts = np.rint(grid.reshape(-1, 2)).astype(int)
    plane = procam.truth.extra["camera_plane_map"][pts[:, 1], pts[:, 0]]
    return float(np.sqrt(np.mean(err ** 2))), bend, len(np.unique(plane[plane >= 0]))


def kernel_medians(calib, truth, n: int = 200) -> tuple[float, float]:
    """Median kernel relative L2 at ``n`` projector pixels farther than NEAR_FOLD px from every
    fold and at ``n // 2`` within NEAR_FOLD px of one (:func:`fold_distance`; nan for one
    plane)."""
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
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.study.scores import camera_view, psnr, rect_mask

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
           "planes": calib.n_planes, "planes_true": t.n_planes,
           "fold_px": fold_error(calib, t),
           "homography_rms": homography_rms(calib, t),
           "skipped": len(calib.meta.get("psf", {}).get("skipped", []))}
    out["checker_rms"], out["checker_bend"], out["checker_planes"] = checkerboard_rms(procam, calib)
    out["kernel_inside"], out["kernel_fold"] = kernel_medians(calib, t)
    if images:
        g_cal, g_or = gain_share(procam, calib, images)
        out.update(gain_db=g_cal, gain_oracle_db=g_or, gain_share=g_cal / g_or)
    return out


HEADER = ("| preset | k1 rec / true | camera resp. err | proj. gamma rec / true | planes rec / true"
          " | fold err (proj px) | homography RMS (cam px) | checkerboard RMS / bend (cam px), planes"
          " | kernel L2 inside | kernel L2 near folds | gain dB cal / oracle (share) | dots skipped"
          " | calibration (s) |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def row(name: str, f: dict) -> str:
    """One markdown row of :data:`HEADER` (``f["seconds"]``: how long the calibration took,
    optional)."""
    gain = (f"{f['gain_db']:.2f} / {f['gain_oracle_db']:.2f} ({100 * f['gain_share']:.0f} %)"
            if "gain_db" in f else "-")
    seconds = f"{f['seconds']:.0f}" if "seconds" in f else "-"
    return (f"| {name} | {f['k1']:.4f} / {f['k1_true']:g} | {f['camera_err']:.4f} | "
            f"{f['gamma']:.3f} / {f['gamma_true']:g} | {f['planes']} / {f['planes_true']} | "
            f"{f['fold_px']:.3f} | {f['homography_rms']:.3f} | "
            f"{f['checker_rms']:.3f} / {f['checker_bend']:.3f}, {f['checker_planes']} | "
            f"{f['kernel_inside']:.3f} | {f['kernel_fold']:.3f} | {gain} | {f['skipped']} | {seconds} |")
