"""Sub-pixel geometry mends by direct alignment of the shown content.

A shift per plane (what the residual report measures) leaves a turned projector or a moved
camera a pixel or so off: a turn shears and scales each plane's content as well as moving it.
Here the blurred frame ``F P`` and the observation with the room light taken off and divided
by the albedo (both in projector pixels, as the report compares them) are aligned per plane by
enhanced correlation (``cv2.findTransformECC``) with a homography, on the plane's watched
pixels. The warp ``W_p`` found satisfies ``obs(W_p(y)) ≈ pred(y)``, so ``W_p = H_p⁻¹ H'_p``:

* a projector move: ``H'_p = H_p W_p`` (:func:`~rtdefocus.watch.mend.mend_projector`, folds
  re-derived from the corrected homographies);
* a camera move: one camera-side homography ``C`` with ``C H_p ≈ H_p W_p`` for every plane,
  fitted by least squares to points of all the planes' watched regions together
  (:func:`~rtdefocus.watch.mend.mend_camera`).

Each round re-resamples the observation through the corrected calibration, so a few rounds
converge on what is left.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import cv2
import numpy as np

from ..calib.file import Calibration
from ..errors import InputError
from ..planar import apply_h
from .mend import camera_motion, mend_camera, mend_projector
from .residual import predictor_for

log = logging.getLogger(__name__)

__all__ = ["content_warps", "mend_geometry", "refit_geometry", "which_moved"]

# ECC stops after this many iterations or when the warp moves by less than this.
_ECC_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-5)


def _translation(o) -> np.ndarray:
    return np.array([[1.0, 0.0, o[0]], [0.0, 1.0, o[1]], [0.0, 0.0, 1.0]])


def content_warps(calib: Calibration, shown: np.ndarray, capture: np.ndarray,
                  min_pixels: int = 400, start: np.ndarray | None = None
                  ) -> list[np.ndarray | None]:
    """Per plane, the homography ``W_p`` (projector px, 3×3) with ``obs(W_p(y)) ≈ pred(y)`` on
    the plane's watched pixels, or None where the plane has too few of them or the alignment
    did not converge (content too plain).

    Parameters
    ----------
    calib : the calibration the observation is resampled with.
    shown : (Hp, Wp, 3) uint8, the projector frame shown when ``capture`` was taken.
    capture : (Hc, Wc, 3) uint8 camera frame.
    start : (n, 2) per-plane content shifts (projector px, the residual report's) to start
        from; the identity by default (the alignment converges over a pixel or two).
    """
    pred = predictor_for(calib)
    blurred = pred.blurred(shown)
    obs, _ = pred.observe(capture)
    content = obs
    if calib.ambient_proj is not None:
        content = content - calib.ambient_proj
    if calib.albedo_proj is not None:
        content = content / np.maximum(calib.albedo_proj, np.float32(1e-3))
    a_g = np.ascontiguousarray(blurred.mean(axis=2), np.float32)
    b_g = np.ascontiguousarray(content.mean(axis=2), np.float32)
    out: list[np.ndarray | None] = []
    for p, win in enumerate(pred.windows):
        if win is None or win.size < min_pixels:
            out.append(None)
            continue
        y0, _, x0, _ = win.box
        a = np.ascontiguousarray(win.cut(a_g))
        b = np.ascontiguousarray(win.cut(b_g))
        mask = win.mask.astype(np.uint8)
        W = np.eye(3, dtype=np.float32)
        if start is not None and np.all(np.isfinite(start[p])):
            W[:2, 2] = start[p]
        try:
            _, W = cv2.findTransformECC(a, b, W, cv2.MOTION_HOMOGRAPHY, _ECC_CRITERIA, mask, 1)
        except cv2.error as exc:             # content too plain to align
            log.debug("content alignment of a plane failed: %s", exc)
            out.append(None)
            continue
        W = np.asarray(W, np.float64)
        if not np.all(np.isfinite(W)):
            out.append(None)
            continue
        o = np.array([x0, y0], np.float64)
        out.append(_translation(o) @ W @ _translation(-o))
    return out


def _camera_transform(calib: Calibration, warps: list[np.ndarray | None]) -> np.ndarray | None:
    """One camera homography ``C`` with ``C H_p y ≈ H_p W_p y`` over a grid of every measured
    plane's watched pixels (least squares), or None when no plane was measured."""
    pred = predictor_for(calib)
    src, dst = [], []
    for p, (W, win) in enumerate(zip(warps, pred.windows, strict=True)):
        if W is None or win is None:
            continue
        ys, xs = np.nonzero(win.mask[::8, ::8])
        y0, _, x0, _ = win.box
        y = np.stack([xs * 8.0 + x0, ys * 8.0 + y0], axis=1)
        H = calib.H_cam_from_proj[p]
        src.append(apply_h(H, y))
        dst.append(apply_h(H @ W, y))
    if not src or sum(len(s) for s in src) < 8:
        return None
    C, _ = cv2.findHomography(np.concatenate(src), np.concatenate(dst), 0)
    return None if C is None else C / C[2, 2]


def refit_geometry(calib: Calibration, shown: np.ndarray, capture: np.ndarray, moved: str,
                   rounds: int = 2, tol_px: float = 0.02) -> tuple[Calibration, float]:
    """``calib`` corrected by ``rounds`` rounds of content alignment, and the largest motion
    (projector px, at the watched pixels' corners) the last round found.

    Parameters
    ----------
    moved : "projector" (a homography per plane, folds kept consistent) or "camera" (one
        camera-side homography for every plane).
    tol_px : stop once a round moves no watched corner by more than this.
    """
    if moved not in ("projector", "camera"):
        raise ValueError(f"moved must be 'projector' or 'camera'; got {moved!r}")
    last = float("nan")
    for _ in range(rounds):
        warps = content_warps(calib, shown, capture)
        if all(W is None for W in warps):
            break
        last = _largest_motion(calib, warps)
        if moved == "projector":
            calib = mend_projector(calib, np.stack([np.eye(3) if W is None else W
                                                    for W in warps]))
        else:
            C = _camera_transform(calib, warps)
            if C is None:
                break
            calib = mend_camera(calib, C)
        if last < tol_px:
            break
    return calib, last


def _largest_motion(calib: Calibration, warps: list[np.ndarray | None]) -> float:
    """Largest |W_p(y) − y| (projector px) over the corners of each plane's watched box."""
    pred = predictor_for(calib)
    worst = 0.0
    for W, win in zip(warps, pred.windows, strict=True):
        if W is None or win is None:
            continue
        y0, y1, x0, x1 = win.box
        c = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]], np.float64)
        worst = max(worst, float(np.linalg.norm(apply_h(W, c) - c, axis=1).max()))
    return worst


def _grid(win, step: int = 8) -> np.ndarray:
    ys, xs = np.nonzero(win.mask[::step, ::step])
    y0, _, x0, _ = win.box
    return np.stack([xs * float(step) + x0, ys * float(step) + y0], axis=1)


def which_moved(calib: Calibration, warps: list[np.ndarray | None]) -> str | None:
    """"projector" or "camera": which single motion explains the planes' content warps better
    (camera px RMS), or None with fewer than two planes measured.

    A projector turned about its centre or shifted moves its image by one homography in
    projector pixels, the same for every plane; a moved camera moves its view by one
    homography in camera pixels. Each hypothesis's common homography is fitted to all the
    planes' points together; the one that leaves less is what moved (the wall's texture, which
    a noisy camera blurs, is not needed to tell them apart)."""
    pred = predictor_for(calib)
    ys, cams, moved = [], [], []
    for p, (W, win) in enumerate(zip(warps, pred.windows, strict=True)):
        if W is None or win is None:
            continue
        y = _grid(win)
        H = calib.H_cam_from_proj[p]
        ys.append((p, y, apply_h(W, y)))
        cams.append(apply_h(H, y))
        moved.append(apply_h(H @ W, y))
    if len(ys) < 2:
        return None
    P, _ = cv2.findHomography(np.concatenate([y for _, y, _ in ys]),
                              np.concatenate([w for _, _, w in ys]), 0)
    C, _ = cv2.findHomography(np.concatenate(cams), np.concatenate(moved), 0)
    if P is None or C is None:
        return None
    err_p = np.concatenate([apply_h(calib.H_cam_from_proj[p] @ P, y) - m
                            for (p, y, _), m in zip(ys, moved, strict=True)])
    err_c = apply_h(C, np.concatenate(cams)) - np.concatenate(moved)
    rms_p, rms_c = (float(np.sqrt(np.mean(e ** 2))) for e in (err_p, err_c))
    log.debug("which moved: projector %.4f, camera %.4f camera px RMS", rms_p, rms_c)
    return "camera" if rms_c < rms_p else "projector"


def mend_geometry(calib: Calibration, reports: list, shown: np.ndarray, capture: np.ndarray,
                  min_confidence: float, clear_px: float,
                  report: Callable) -> tuple[Calibration | None, dict]:
    """The calibration mended for the geometry change ``reports`` (a watcher's looks) measured,
    and what was done; (None, detail) when the change is under ``clear_px`` (too small to apply).

    Parameters
    ----------
    reports : :class:`~rtdefocus.watch.residual.ResidualReport` of the looks that saw the change.
    shown, capture : the last look's projector frame and camera frame.
    min_confidence : a plane's phase-correlation peak under it says nothing of its shift.
    clear_px : projector px under which the change is no change.
    report : the residual report function (to tell a camera move from a projector move when
        the content warps do not say).
    """
    # Planes whose correlation peak is too low say nothing; a plane no look could measure
    # takes the mean of the others.
    seen = np.stack([np.where((r.confidence >= min_confidence)[:, None], r.shifts_proj, np.nan)
                     for r in reports])
    ok = np.isfinite(seen).all(axis=2).any(axis=0)
    if not ok.any():
        raise InputError("no plane's content shift could be measured")
    shifts = np.full((calib.n_planes, 2), np.nan)
    shifts[ok] = np.nanmedian(seen[:, ok], axis=0)
    shifts[~ok] = shifts[ok].mean(axis=0)
    detail: dict = {"shifts_proj": np.round(shifts, 3).tolist()}
    if float(np.linalg.norm(shifts, axis=1).max()) < clear_px:
        return None, detail
    # A camera move shifts the walls with the content, a projector move the content alone:
    # one homography for all planes, in projector or in camera pixels, says which moved.
    detail["moved"] = "projector"
    new = mend_projector(calib, shifts)
    cam = camera_motion(calib, shifts)
    moved = which_moved(calib, content_warps(calib, shown, capture, start=shifts))
    if moved == "camera" and np.all(np.isfinite(cam)):
        detail.update(moved="camera", shift_cam=np.round(cam.mean(axis=0), 3).tolist())
        new = mend_camera(calib, cam.mean(axis=0))
    elif moved is None and np.all(np.isfinite(cam)):
        # the warps do not say: the mend whose model explains the capture better
        as_cam = mend_camera(calib, cam.mean(axis=0))
        rms = {"camera": report(as_cam, shown, capture).rms_after,
               "projector": report(new, shown, capture).rms_after}
        detail["rms"] = {k: round(v, 6) for k, v in rms.items()}
        if rms["camera"] < rms["projector"]:
            detail.update(moved="camera", shift_cam=np.round(cam.mean(axis=0), 3).tolist())
            new = as_cam
    # The shifts leave a turn's shear and scale: align the content to the sub-pixel.
    new, left = refit_geometry(new, shown, capture, detail["moved"])
    detail["refit_left_px"] = round(left, 4)
    return new, detail
