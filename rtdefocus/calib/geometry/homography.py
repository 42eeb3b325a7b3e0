"""Line crossings -> one homography per plane: steps 4 and 5 of the geometry stage.

Crossings of horizontal and vertical line ridges give projector points and their camera images
(:func:`line_crossings`); per plane, a normalised DLT inside RANSAC, then Levenberg–Marquardt on
the inliers (OpenCV's ``findHomography``), gives the camera-from-projector homography
(:func:`fit_homography`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ...errors import CalibrationError
from ...planar import apply_h
from .structured_light import DetectedLine

__all__ = ["line_crossings", "fit_homography"]


# --------------------------------------------------------------------------- crossings
def _dense(lines: list[DetectedLine], length: int) -> np.ndarray:
    out = np.full((len(lines), length), np.nan)
    for k, ln in enumerate(lines):
        out[k, ln.t] = ln.s
    return out


def _interp_rows(table: np.ndarray, rows: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """table[rows, pos] linearly interpolated in pos; NaN outside or next to a gap."""
    n = table.shape[1]
    p0 = np.floor(pos)
    ok = np.isfinite(pos) & (p0 >= 0) & (p0 < n - 1)
    i0 = np.where(ok, p0, 0).astype(np.int64)
    f = np.where(ok, pos - p0, 0.0)
    v = table[rows, i0] * (1 - f) + table[rows, i0 + 1] * f
    return np.where(ok, v, np.nan)


def line_crossings(lines: list[DetectedLine], camera_size: tuple[int, int]):
    """Crossings of every detected vertical line with every horizontal one.

    A projector point (x_v, y_h) lies on both lines, so its camera image is where the two
    ridges cross (exact for any homography, which maps lines to lines).

    Returns
    -------
    pts_proj_xy : (n, 2) float64 projector points.
    pts_cam_xy : (n, 2) float64 camera points.
    pairs : (n, 2) int index of the (vertical, horizontal) line in ``lines``.
    """
    wc, hc = camera_size
    iv = [k for k, ln in enumerate(lines) if ln.axis == "v"]
    ih = [k for k, ln in enumerate(lines) if ln.axis == "h"]
    if not iv or not ih:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2), int)
    F = _dense([lines[k] for k in iv], hc)      # x of vertical line i at camera row y
    G = _dense([lines[k] for k in ih], wc)      # y of horizontal line j at camera column x
    nv, nh = len(iv), len(ih)
    ri = np.repeat(np.arange(nv), nh)
    rj = np.tile(np.arange(nh), nv)
    x = np.nanmedian(F, axis=1)[ri]
    y = np.full_like(x, np.nan)
    for _ in range(12):         # x = f_i(y), y = g_j(x): a contraction for near-square lines
        y = _interp_rows(G, rj, x)
        x_new = _interp_rows(F, ri, y)
        done = np.nanmax(np.abs(x_new - x)) if np.isfinite(x_new).any() else 0.0
        x = x_new
        if done < 1e-4:
            break
    y = _interp_rows(G, rj, x)
    # Converged and consistent: x on line i at y, and y on line j at x.
    ok = np.isfinite(x) & np.isfinite(y)
    ok &= np.abs(_interp_rows(F, ri, y) - x) < 1e-2
    cam = np.stack([x[ok], y[ok]], axis=1)
    proj = np.stack([np.array([lines[iv[i]].coord for i in ri[ok]]),
                     np.array([lines[ih[j]].coord for j in rj[ok]])], axis=1)
    pairs = np.stack([np.asarray(iv)[ri[ok]], np.asarray(ih)[rj[ok]]], axis=1)
    return proj, cam, pairs


# --------------------------------------------------------------------------- homographies
def fit_homography(pts_proj_xy: np.ndarray, pts_cam_xy: np.ndarray, *, threshold: float = 1.5,
                   what: str = "plane"):
    """Camera-from-projector homography: normalised DLT in RANSAC, then LM on the inliers.

    Parameters
    ----------
    pts_proj_xy, pts_cam_xy : (n, 2) corresponding points (n >= 8).
    threshold : RANSAC inlier threshold in camera px.
    what : name used in error messages.

    Returns
    -------
    H_cam_from_proj : (3, 3) float64, H[2, 2] = 1.
    inliers : (n,) bool.
    rms : float, RMS reprojection error on the inliers (camera px).

    Raises
    ------
    CalibrationError
        Too few points, or no homography found.
    """
    src = np.ascontiguousarray(pts_proj_xy, dtype=np.float64).reshape(-1, 1, 2)
    dst = np.ascontiguousarray(pts_cam_xy, dtype=np.float64).reshape(-1, 1, 2)
    n = len(src)
    if n < 8:
        raise CalibrationError(f"{what}: only {n} line crossings, at least 8 are needed for a "
                               "homography; make sure the camera sees the whole projected area")
    try:
        H, mask = cv2.findHomography(src, dst, cv2.RANSAC, threshold, maxIters=4000,
                                     confidence=0.999)
    except cv2.error as exc:        # never let an OpenCV traceback reach the user
        raise CalibrationError(f"{what}: homography estimation failed on {n} crossings "
                               f"({exc.err}); the line detections are degenerate") from exc
    if H is None or not np.isfinite(H).all():
        raise CalibrationError(f"{what}: no homography fits the {n} line crossings; the "
                               "detections are inconsistent (did the set-up move?)")
    inl = mask.ravel().astype(bool)
    for _ in range(2):   # LM refinement (method 0 = all given points) on the current inliers
        if inl.sum() < 8:
            break
        H_ref, _ = cv2.findHomography(src[inl], dst[inl], 0)
        if H_ref is None or not np.isfinite(H_ref).all():
            break
        H = H_ref
        err = np.linalg.norm(apply_h(H, src.reshape(-1, 2)) - dst.reshape(-1, 2), axis=1)
        new = err < threshold
        if np.array_equal(new, inl):
            break
        inl = new
    H = H / H[2, 2]
    err = np.linalg.norm(apply_h(H, src.reshape(-1, 2)) - dst.reshape(-1, 2), axis=1)
    rms = float(np.sqrt(np.mean(err[inl] ** 2))) if inl.any() else float("inf")
    return H, inl, rms




def radial_rms(sets: list[tuple[np.ndarray, np.ndarray]], k: tuple[float, float],
               camera_size: tuple[int, int]) -> float:
    """RMS (camera px, over all planes) of each plane's crossings from its own homography once
    the camera points are undistorted with the lens ``k`` = (k1, k2); planes with fewer than 8
    crossings are left out. ``sets``: per plane, (projector xy (n, 2), camera xy (n, 2))."""
    from ...planar import undistort_points

    sq, n = 0.0, 0
    for proj, cam in sets:
        if len(proj) < 8:
            continue
        und = undistort_points(cam, k, camera_size)
        H, _ = cv2.findHomography(np.ascontiguousarray(proj, np.float64),
                                  np.ascontiguousarray(und, np.float64), 0)
        if H is None or not np.isfinite(H).all():
            return float("inf")
        sq += float((np.linalg.norm(apply_h(H, proj) - und, axis=1) ** 2).sum())
        n += len(proj)
    return math.sqrt(sq / max(n, 1))


def estimate_radial_k1(sets: list[tuple[np.ndarray, np.ndarray]], camera_size: tuple[int, int],
                       bound: float = 0.3) -> tuple[float, float, float]:
    """The camera's radial distortion k1 (model of :func:`~.planar.distort_points`) from the
    line crossings of each plane.

    A projected line is straight on a plane, so the camera points of a plane are a homography
    of their projector points once undistorted: k1 is the value that makes each plane's
    homography fit best (a 1-D search of :func:`radial_rms`; the homographies by DLT + LM on
    the given points). ``sets``: per plane, (projector xy (n, 2), camera xy (n, 2)) — the
    RANSAC inliers.

    Returns (k1, rms at k1, rms at k1 = 0), the RMS in camera px over all planes.
    """
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(lambda k1: radial_rms(sets, (k1, 0.0), camera_size),
                          bounds=(-bound, bound), method="bounded", options={"xatol": 1e-4})
    return float(res.x), float(res.fun), radial_rms(sets, (0.0, 0.0), camera_size)


def estimate_radial_k12(sets: list[tuple[np.ndarray, np.ndarray]], camera_size: tuple[int, int],
                        k1: float = 0.0, bound: float = 0.3) -> tuple[float, float, float]:
    """(k1, k2, rms) of the lens that makes each plane's crossings a homography best, both
    terms fitted together (a 2-D simplex search of :func:`radial_rms` from (``k1``, 0), each
    term within ``bound``). With k1 alone a lens whose k2 is not 0 leaves a misfit that grows
    towards the corners (as r⁴) and biases k1; this fit removes both."""
    from scipy.optimize import minimize

    def cost(k: np.ndarray) -> float:
        if np.abs(k).max() > bound:
            return float("inf")
        return radial_rms(sets, (float(k[0]), float(k[1])), camera_size)

    res = minimize(cost, np.array([k1, 0.0]), method="Nelder-Mead",
                   options={"xatol": 1e-4, "fatol": 1e-5, "initial_simplex":
                            np.array([[k1, 0.0], [k1 + 0.02, 0.0], [k1, 0.02]])})
    return float(res.x[0]), float(res.x[1]), float(res.fun)
