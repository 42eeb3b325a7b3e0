"""A picture of the geometry stage's result over the camera view (:func:`geometry_diagnostics`)."""

from __future__ import annotations

import cv2
import numpy as np

from ...errors import InputError
from ...planar import apply_h, fold_segments_cam, plane_polygons_proj
from ..file import Calibration
from .stage import GeometryDetail

__all__ = ["geometry_diagnostics"]

# --------------------------------------------------------------------------- diagnostics
# RGB per plane: blue, orange, then colours apart from the lines' green/cyan and the folds' yellow.
_PLANE_TINT = np.array([[60, 120, 255], [255, 150, 40], [200, 60, 220], [40, 200, 120],
                        [230, 60, 60], [140, 100, 60], [120, 120, 255], [255, 120, 180]],
                       np.float32)     # one per plane up to MAX_PLANES
_UNFIT_TINT = np.array([255, 40, 40], np.float32)     # the region no plane fits


def geometry_diagnostics(calib: Calibration, detail: GeometryDetail | None = None,
                         background: np.ndarray | None = None,
                         aspects: tuple[tuple[int, int], ...] = ((4, 3), (16, 9))) -> np.ndarray:
    """A picture of the geometry stage's result over the camera view.

    Parameters
    ----------
    calib : the calibration (geometry section).
    detail : what the stage saw (default: ``calib.geometry_detail``); without it
        only the fitted fold, planes and display rectangles are drawn.
    background : (Hc, Wc, 3) uint8 camera view; default the white frame of ``detail``, else black.
    aspects : display rectangles to draw, as (w, h) aspect ratios.

    Returns
    -------
    (Hc, Wc, 3) uint8 RGB: the camera view (dimmed), each plane tinted (blue = plane 0,
    orange = plane 1, purple = plane 2, ...), detected lines (green: vertical, cyan:
    horizontal), kinks (red: on the fold, hollow grey: rejected), every fold (yellow, where it
    separates its two planes), the region no plane fits (red, hatched, outlined and named
    "no plane fits: masked"; with the dense map), the display rectangles (magenta 4:3,
    white 16:9, ...) and a caption.
    """
    detail = detail if detail is not None else calib.geometry_detail
    wc, hc = calib.camera_size
    if background is None:
        background = detail.detection.white_rgb if detail is not None else np.zeros((hc, wc, 3), np.uint8)
    img = 0.55 * np.asarray(background, dtype=np.float32)
    # Planes, tinted: each plane's share of the projector frame mapped into the camera.
    for k, pp in enumerate(plane_polygons_proj(calib.projector_size, calib.layout, calib.n_planes)):
        if len(pp) < 3:
            continue
        pc = apply_h(calib.H_cam_from_proj[k], pp)
        mask = np.zeros((hc, wc), np.uint8)
        cv2.fillPoly(mask, [np.round(pc * 16).astype(np.int32)], 1, cv2.LINE_AA, shift=4)
        m = mask.astype(bool)
        img[m] = 0.7 * img[m] + 0.3 * _PLANE_TINT[k % len(_PLANE_TINT)]
    unfit = getattr(detail, "unfit_mask", None) if detail is not None else None
    if unfit is not None and unfit.any():
        # Fits no plane (a far wall through a gap, an object): red, hatched, and named.
        yy, xx = np.mgrid[0:hc, 0:wc]
        hatch = unfit & (((xx + yy) // 6) % 2 == 0)
        img[unfit] = 0.5 * img[unfit] + 0.5 * _UNFIT_TINT
        img[hatch] = 0.6 * img[hatch] + 0.4 * _UNFIT_TINT
    img = np.clip(img, 0, 255).astype(np.uint8)
    sh = 4
    if unfit is not None and unfit.any():
        contours, _ = cv2.findContours(unfit.astype(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, contours, -1, tuple(int(v) for v in _UNFIT_TINT), 2, cv2.LINE_AA)
        big = max(contours, key=cv2.contourArea)
        x, y, w, h = cv2.boundingRect(big)
        for col, thick in (((0, 0, 0), 3), ((255, 255, 255), 1)):
            cv2.putText(img, "no plane fits: masked", (int(np.clip(x + 4, 4, wc - 190)), y + h // 2),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.5, col, thick, cv2.LINE_AA)

    def P(pts):
        return np.round(np.asarray(pts) * (1 << sh)).astype(np.int32)

    if detail is not None:
        for ln in detail.detection.lines:
            col = (0, 230, 0) if ln.axis == "v" else (0, 220, 255)
            pts = ln.pts_cam_xy
            breaks = np.flatnonzero(np.diff(ln.t) > 3) + 1
            for part in np.split(pts, breaks):
                if len(part) > 1:
                    cv2.polylines(img, [P(part)], False, col, 1, cv2.LINE_AA, shift=sh)
        inl = detail.fold_inliers if detail.fold_inliers is not None else np.zeros(len(detail.kinks), bool)
        for kk, ok in zip(detail.kinks, inl, strict=False):
            c = tuple(int(v) for v in P(kk.point_cam_xy))
            if ok:
                cv2.circle(img, c, 5 << sh, (255, 30, 30), -1, cv2.LINE_AA, shift=sh)
            else:
                cv2.circle(img, c, 5 << sh, (170, 170, 170), 1, cv2.LINE_AA, shift=sh)
    for seg in fold_segments_cam(calib.projector_size, calib.H_cam_from_proj, calib.layout):
        if seg is not None:
            cv2.line(img, tuple(int(v) for v in P(seg[0])), tuple(int(v) for v in P(seg[1])),
                     (255, 255, 0), 2, cv2.LINE_AA, shift=sh)
    colours = [(255, 0, 255), (255, 255, 255), (0, 255, 0), (255, 128, 0)]
    for k, (aw, ah) in enumerate(aspects):
        try:
            x, y, w, h = calib.display_rect((aw, ah))
        except InputError:
            continue
        col = colours[k % len(colours)]
        cv2.rectangle(img, (x, y), (x + w - 1, y + h - 1), col, 2)
        # Labels alternate between the top and the bottom edge so nested rectangles stay legible.
        ty = y + 22 + 22 * (k // 2) if k % 2 else y + h - 10 - 22 * (k // 2)
        cv2.putText(img, f"{aw}:{ah}  {w}x{h} at ({x}, {y})", (x + 6, ty), cv2.FONT_HERSHEY_SIMPLEX,
                    0.6, col, 1, cv2.LINE_AA)
    cap = caption(calib)
    cv2.putText(img, cap, (10, hc - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, cap, (10, hc - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def caption(calib: Calibration) -> str:
    """The picture's caption: planes, RMS, fold disagreement, captures, and for planes with a
    residual field how far each bows off its plane (camera px)."""
    g = calib.meta.get("geometry", {})
    cap = (f"{calib.n_planes} plane(s)  RMS {g.get('rms_px')} px  fold disagreement "
           f"{g.get('fold_disagreement_px')} px  {g.get('captures')} captures")
    res = g.get("residual") or {}
    if res.get("kept"):
        bows = ", ".join(f"{v:.1f}" for v in res.get("max_px", []))
        cap += f"  bow off the planes {bows} px"
        if "nearly_flat" in g:
            cap += " (nearly flat fit)"
    unfit = g.get("unfit") or {}
    if unfit.get("pixels"):
        cap += f"  masked (no plane fits) {100 * unfit['fraction']:.0f} % of the view"
    return cap
