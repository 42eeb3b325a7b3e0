"""Projector light the planes do not explain: a lit camera region outside the planes' outline.

The line-based fit sees only the lines it can follow. Light that passes a wall's edge and lands
on something farther away (a far wall through a gap, an object) is dimmer, carries no crossing
the planes fit, and lies outside the outline the planes' homographies give the projector frame.
The fit still succeeds, but the outline then takes the projector pixels that light that region
for a wall's continuation, and the display area can reach over the gap. The dense map
(``dense=True``) sees the region and masks it; this check names it so the user knows to ask.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["stray_light", "stray_light_warning", "STRAY_LEVEL", "STRAY_MIN_SHARE"]

#: Lit: white minus black above this share of the walls' median (the walls' blur halo and
#: interreflections stay under 5 %; a far wall 2x as far away as the walls reaches about 20 %).
STRAY_LEVEL = 0.08
#: A region is reported when it holds at least this share of the walls' lit camera pixels.
STRAY_MIN_SHARE = 0.01


def stray_light(white: np.ndarray, black: np.ndarray, valid: np.ndarray,
                lit_polygon_cam: np.ndarray, margin_px: float,
                pts_cam_xy: np.ndarray | None = None, *, level: float = STRAY_LEVEL,
                min_share: float = STRAY_MIN_SHARE) -> dict | None:
    """The lit camera region outside the planes' outline, or None when there is none.

    Parameters
    ----------
    white, black : (Hc, Wc) grey camera frames of the full white and black patterns.
    valid : (Hc, Wc) bool pixels lit well enough to measure (the walls).
    lit_polygon_cam : (k, 2) the planes' outline of the projector frame, camera (x, y).
    margin_px : camera px around the outline taken as its blur halo.
    pts_cam_xy : (n, 2) crossings the planes fit; a region holding one is the planes'.
    level, min_share : :data:`STRAY_LEVEL`, :data:`STRAY_MIN_SHARE`.

    Returns
    -------
    dict or None
        ``bbox_cam`` [x0, y0, x1, y1], ``pixels``, ``share`` (of the walls' lit pixels),
        ``brightness`` (median, relative to the walls'), ``outline_dark`` (share of the
        outline the camera sees unlit: projector light that lands elsewhere).
    """
    diff = cv2.medianBlur(np.ascontiguousarray(white - black, np.float32), 5)
    ref = float(np.median(diff[valid])) if valid.any() else 0.0
    if ref <= 0:
        return None
    outline = np.zeros(diff.shape, np.uint8)
    cv2.fillPoly(outline, [np.round(np.asarray(lit_polygon_cam)).astype(np.int32)], 1)
    r = max(1, int(np.ceil(margin_px)))
    halo = cv2.dilate(outline, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2))
    lit = ((diff > level * ref) & (halo == 0)).astype(np.uint8)
    lit = cv2.morphologyEx(lit, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, box, _ = cv2.connectedComponentsWithStats(lit)
    keep = np.zeros(n, bool)
    keep[1:] = box[1:, cv2.CC_STAT_AREA] >= min_share * max(int(valid.sum()), 1)
    if pts_cam_xy is not None and len(pts_cam_xy):
        xy = np.round(np.asarray(pts_cam_xy)).astype(np.intp)
        inside = (xy[:, 0] >= 0) & (xy[:, 0] < diff.shape[1]) & (xy[:, 1] >= 0) & \
            (xy[:, 1] < diff.shape[0])
        keep[np.unique(labels[xy[inside, 1], xy[inside, 0]])] = False
    if not keep.any():
        return None
    region = keep[labels]
    ys, xs = np.nonzero(region)
    inner = outline.astype(bool)
    return {"bbox_cam": [int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())],
            "pixels": int(region.sum()),
            "share": round(float(region.sum()) / max(int(valid.sum()), 1), 4),
            "brightness": round(float(np.median(diff[region])) / ref, 3),
            "outline_dark": round(float((inner & ~valid).sum()) / max(int(inner.sum()), 1), 4)}


def stray_light_warning(stats: dict) -> str:
    """The one-line warning for :func:`stray_light`'s region: where, how much, and the fix."""
    x0, y0, x1, y1 = stats["bbox_cam"]
    return (f"a lit region at camera x {x0}-{x1}, y {y0}-{y1} ({100 * stats['share']:.0f} % of "
            f"the walls' area, {100 * stats['brightness']:.0f} % as bright) fits none of the "
            "planes the line crossings found: a far wall through a gap, or an object. The "
            "projector pixels that light it are taken for a wall's continuation, so the display "
            "area can reach over it; calibrate with --dense (rd.calibrate(..., dense=True)), which "
            "masks that region and keeps the display area off it")
