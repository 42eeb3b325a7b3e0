"""The dense map in the geometry fit: many evenly spread samples per plane for its homography
and residual field, and the region that fits no plane (a far wall through a gap, an object).

The line crossings still decide how many planes there are and where their folds lie
(:mod:`.planes`, :mod:`.fold`); the dense samples (:class:`~.dense.DenseMap`) then replace
them in each plane's homography (RANSAC and LM, as for the crossings) and residual field, so
a bowed wall is measured everywhere, not only where two lines cross. After the fit, every
valid camera pixel whose projector coordinate the model (homography plus residual of the plane
it falls on) puts more than :data:`UNFIT_PX` away is *unfit*: masked out of the fit, drawn in
the geometry picture and counted in ``meta["geometry"]["unfit"]``; the projector pixels whose
light lands there are cut out of the lit outline (and so out of the display rectangle).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from ...planar import PlaneLayout, apply_h, apply_h_per_plane
from ...residual import displacement
from .dense import DenseMap
from .homography import fit_homography

__all__ = ["SAMPLE_STEP", "UNFIT_PX", "plane_samples", "fit_plane_homography", "prefilter",
           "unfit_region", "outline_without"]

#: Camera px between the dense samples the fit uses (each plane keeps tens of thousands).
SAMPLE_STEP = 4
#: A valid pixel this far (camera px) from the model's image of its projector point fits no plane.
UNFIT_PX = 3.0


def plane_samples(dense: DenseMap, layout_cam: PlaneLayout | None, n: int, band: float,
                  step: int = SAMPLE_STEP) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per plane, the dense samples (proj_xy (m, 2), cam_xy (m, 2)) inside it by more than
    ``band`` camera px from each of its folds and half that from the edge of the valid map
    (where the blur mixes in the dark: the phase is biased there); ``layout_cam`` None: one
    plane."""
    r = max(1, int(round(band / 2)))
    core = cv2.erode(dense.valid.astype(np.uint8),
                     cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    cam, proj = replace(dense, valid=core.astype(bool)).samples(step)
    if layout_cam is None or n == 1:
        return [(proj, cam)]
    lab = layout_cam.label(cam[:, 0], cam[:, 1]).astype(np.int64)
    out = layout_cam.outside(cam[:, 0], cam[:, 1])
    inside = out[lab, np.arange(len(cam))] < -band
    return [(proj[inside & (lab == p)], cam[inside & (lab == p)]) for p in range(n)]


def prefilter(H: np.ndarray, proj: np.ndarray, cam: np.ndarray, cross_proj: np.ndarray,
              cross_cam: np.ndarray, threshold: float) -> np.ndarray:
    """(m,) bool the dense samples a residual field may fit: off the homography by no more than
    the plane's crossings are (twice their 90th percentile, at least 4 × ``threshold``).

    The lines do not carry across a gap, so no crossing lands on a far wall seen through it,
    while its dense samples can be a third of the plane's: the crossings set the scale."""
    r = np.linalg.norm(cam - apply_h(H, proj), axis=1)
    rc = np.linalg.norm(cross_cam - apply_h(H, cross_proj), axis=1)
    lim = max(4.0 * threshold, 2.0 * float(np.percentile(rc, 90)) if len(rc) else 0.0)
    return r <= lim


def fit_plane_homography(dense_set: tuple[np.ndarray, np.ndarray], cross_proj: np.ndarray,
                         cross_cam: np.ndarray, threshold: float, what: str):
    """A plane's homography from its dense samples: (H, inliers over the *crossings* (n,) bool,
    RMS camera px of the dense inliers), the form :func:`~.homography.fit_homography` returns
    for the crossings (whose inliers the diagnostics and the lens estimate read)."""
    proj, cam = dense_set
    if len(proj) < 200:                  # a sliver of a plane: its crossings do as well
        return fit_homography(cross_proj, cross_cam, threshold=threshold, what=what)
    H, _, rms = fit_homography(proj, cam, threshold=threshold, what=what)
    inl = np.linalg.norm(cross_cam - apply_h(H, cross_proj), axis=1) <= threshold
    return H, inl, rms


def model_camera_points(Hs: np.ndarray, residual_cam, layout_proj: PlaneLayout, px: np.ndarray,
                        py: np.ndarray, projector_size) -> tuple[np.ndarray, np.ndarray]:
    """Where the fitted model (each point's plane's homography plus its residual field, when
    there is one) puts the projector points ``(px, py)`` in the camera."""
    plane = layout_proj.label(px, py).astype(np.intp)
    mx, my = apply_h_per_plane(Hs, plane, px, py)
    if residual_cam is not None:
        for p in range(len(Hs)):
            on = plane == p
            d = displacement(residual_cam[p], px[on], py[on], projector_size)
            mx[on] += d[:, 0]
            my[on] += d[:, 1]
    return mx, my


def unfit_region(dense: DenseMap, Hs: np.ndarray, layout_proj: PlaneLayout,
                 residual_cam: np.ndarray | None, projector_size: tuple[int, int],
                 limit: float = UNFIT_PX, step: int = 2) -> tuple[np.ndarray, dict]:
    """The camera pixels the model does not explain.

    Parameters
    ----------
    dense : the map, in the camera pixels of the fit (ideal where the lens was taken out).
    Hs : (n, 3, 3) camera-from-projector homographies; ``layout_proj`` the projector planes.
    residual_cam : (n, gy, gx, 2) residual fields or None.
    projector_size : (width, height).
    limit : camera px.
    step : the map is checked every ``step`` px and the mask filled in between.

    Returns
    -------
    mask : (Hc, Wc) bool unfit pixels (small specks removed: a region, not noise).
    stats : ``fraction`` (of the valid pixels), ``pixels``, ``bbox_cam`` [x0, y0, x1, y1] or None.
    """
    hc, wc = dense.valid.shape
    ys, xs = np.mgrid[0:hc:step, 0:wc:step]
    ok = dense.valid[ys, xs]
    px = dense.proj_xy[ys[ok], xs[ok], 0].astype(np.float64)
    py = dense.proj_xy[ys[ok], xs[ok], 1].astype(np.float64)
    mx, my = model_camera_points(Hs, residual_cam, layout_proj, px, py, projector_size)
    err = np.hypot(mx - xs[ok], my - ys[ok])
    small = np.zeros(ys.shape, np.uint8)
    small[ok] = err > limit
    # An opening drops isolated misfits (blur at the folds and the frame's edge), a closing
    # joins the region across the pixels the map could not read.
    kernel = np.ones((5, 5), np.uint8)
    small = cv2.morphologyEx(cv2.morphologyEx(small, cv2.MORPH_OPEN, kernel), cv2.MORPH_CLOSE, kernel)
    mask = cv2.resize(small, (wc, hc), interpolation=cv2.INTER_NEAREST).astype(bool)
    n_valid = max(int(dense.valid.sum()), 1)
    pix = int(mask.sum())
    bbox = None
    if pix:
        yy, xx = np.nonzero(mask)
        bbox = [int(xx.min()), int(yy.min()), int(xx.max()), int(yy.max())]
    return mask, {"fraction": round(pix / n_valid, 4), "pixels": pix, "bbox_cam": bbox,
                  "limit_px": limit}


def outline_without(polygon_cam: np.ndarray, unfit_mask: np.ndarray, dense: DenseMap,
                    Hs: np.ndarray, layout_proj: PlaneLayout, residual_cam: np.ndarray | None,
                    projector_size: tuple[int, int]) -> np.ndarray:
    """The lit outline (m, 2) camera px less where the model puts the projector pixels whose
    light lands on the unfit region.

    The planes' maps carry the projector pixels that light a far wall through a gap on as the
    wall's continuation, into camera pixels that stay dark: content placed there would land on
    the far wall. Those projector pixels are read off the dense map (the unfit pixels'
    coordinates), mapped through the model, and cut out of the outline; the largest piece left
    is the outline (``polygon_cam`` itself when nothing is cut)."""
    wp, hp = projector_size
    hc, wc = unfit_mask.shape
    sel = unfit_mask & dense.valid
    if not sel.any():
        return polygon_cam
    pts = np.rint(dense.proj_xy[sel]).astype(np.int64)
    ok = (pts[:, 0] >= 0) & (pts[:, 0] < wp) & (pts[:, 1] >= 0) & (pts[:, 1] < hp)
    gone = np.zeros((hp, wp), np.uint8)
    gone[pts[ok, 1], pts[ok, 0]] = 1
    gone = cv2.morphologyEx(gone, cv2.MORPH_CLOSE, np.ones((7, 7), np.uint8))
    ys, xs = np.nonzero(gone)
    px, py = xs.astype(np.float64), ys.astype(np.float64)
    mx, my = model_camera_points(Hs, residual_cam, layout_proj, px, py, projector_size)
    cut = np.zeros((hc, wc), np.uint8)
    ix, iy = np.rint(mx).astype(np.int64), np.rint(my).astype(np.int64)
    inside = (ix >= 0) & (ix < wc) & (iy >= 0) & (iy < hc)
    cut[iy[inside], ix[inside]] = 1
    # Several camera px per projector px: close the holes, then a little margin.
    cut = cv2.dilate(cv2.morphologyEx(cut, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)),
                     np.ones((3, 3), np.uint8))
    lit = np.zeros((hc, wc), np.uint8)
    cv2.fillPoly(lit, [np.round(polygon_cam * 16).astype(np.int32)], 1, shift=4)
    lit &= 1 - cut
    contours, _ = cv2.findContours(lit, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return polygon_cam
    big = cv2.approxPolyDP(max(contours, key=cv2.contourArea), 1.0, True).reshape(-1, 2)
    return big.astype(np.float64) if len(big) >= 3 else polygon_cam
