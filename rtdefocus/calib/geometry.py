"""Geometry stage: kinks -> fold -> one homography per plane -> lit area and layout.

DESIGN.md §4, paper §3.1 (after Paidimarri & Chandran). Learnt only through ``capture``:

1. :mod:`.structured_light` gives, for every projected line, its sub-pixel ridge in the camera.
2. **Kinks.** A projected straight line crossing the fold is two straight segments in the camera.
   Per line, a *hinge* model (a quadratic plus a slope change at one place) is compared with a
   *cubic* (a smooth bend everywhere, as lens distortion makes): a kink is where the hinge fits
   much better *and* the direction changes by a real angle (:func:`find_kink`).
3. **Fold in the camera**: RANSAC over pairs of kink points, then total least squares on the
   inliers (:func:`fit_fold`). Too few consistent kinks: one plane (a flat wall is no error).
4. **Correspondences**: crossings of horizontal and vertical line ridges, each a projector point
   (x_line, y_line) and its camera point, split by the fold (a band around it is left out).
5. **Homographies**: per plane, normalised DLT inside RANSAC, then Levenberg–Marquardt on the
   inliers (OpenCV's ``findHomography`` normalises the points and refines with LM), forward and
   inverse (:func:`fit_homography`).
6. **Fold in the projector**: the visible camera fold mapped back through each plane's inverse
   homography; the two images agree for a consistent result, their largest distance along the
   visible segment is reported as ``fold_disagreement_px``.

Conventions (docs/internals.md): lines ``a x + b y + c = 0`` with ``a² + b² = 1``, plane 0 where
the line is negative, the same plane 0 in projector and camera. The projector fold is oriented
with its normal pointing to +x (to +y for a nearly horizontal fold), so plane 0 is the left
(top) one.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import CalibrationError, InputError
from ..procam import ProCam
from .capture import Capturer
from .file import Calibration
from .structured_light import DetectedLine, LineDetection, LineDetector, LinePatterns

log = logging.getLogger(__name__)

#: keyword options of :func:`calibrate_geometry` (``calibrate(**options)`` routes them here).
OPTIONS = ("line_spacing", "line_phases", "line_width", "samples", "min_kink_deg", "fold_band",
           "ransac_threshold")

__all__ = [
    "OPTIONS", "Kink", "GeometryDetail", "find_kink", "fit_fold", "line_crossings",
    "fit_homography", "fold_to_projector", "lit_polygon", "largest_inscribed_rect",
    "calibrate_geometry", "geometry_diagnostics", "apply_h", "apply_h_per_plane",
]


# --------------------------------------------------------------------------- small helpers
def apply_h(H: np.ndarray, pts_xy: np.ndarray) -> np.ndarray:
    """Map (n, 2) points through a 3×3 homography; returns (n, 2) float64."""
    p = np.asarray(pts_xy, dtype=np.float64).reshape(-1, 2)
    q = p @ H[:, :2].T + H[:, 2]
    return q[:, :2] / q[:, 2:3]


def apply_h_per_plane(Hs: np.ndarray, plane: np.ndarray, xs: np.ndarray,
                      ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map points through the homography of their own plane.

    Parameters
    ----------
    Hs : (n, 3, 3) homographies; plane : int array, the plane of each point (0 .. n-1);
    xs, ys : float arrays of the same shape as ``plane``.

    Returns
    -------
    mx, my : float64 arrays of that shape.
    """
    mx = np.empty(xs.shape, np.float64)
    my = np.empty(ys.shape, np.float64)
    for p in range(len(Hs)):
        sel = plane == p
        H = Hs[p]
        x, y = xs[sel], ys[sel]
        w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
        mx[sel] = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w
        my[sel] = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
    return mx, my


def _normalise_line(line: np.ndarray) -> np.ndarray:
    line = np.asarray(line, dtype=np.float64)
    return line / math.hypot(line[0], line[1])


def _line_eval(line: np.ndarray, pts_xy: np.ndarray) -> np.ndarray:
    return pts_xy @ line[:2] + line[2]


def _tls_line(pts: np.ndarray) -> np.ndarray:
    """Total-least-squares line through (n, 2) points, normalised."""
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    n = vt[1]
    return np.array([n[0], n[1], -n @ c])


# --------------------------------------------------------------------------- kinks
@dataclass
class Kink:
    """A sharp change of direction on one detected line.

    Attributes
    ----------
    point_cam_xy : (2,) float64 camera point of the bend.
    angle_deg : direction change (degrees).
    score : how much better the hinge fits than the smooth cubic, in units of the noise
        variance ((RSS_cubic − RSS_hinge) / σ²).
    line : index of the line in :attr:`LineDetection.lines`.
    """

    point_cam_xy: np.ndarray
    angle_deg: float
    score: float
    line: int = -1


def _hinge_rss(u: np.ndarray, s: np.ndarray, taus: np.ndarray):
    """RSS and coefficients of ``s = c0 + c1 u + c2 u² + d·max(0, u − τ)`` for every τ."""
    base = np.stack([np.ones_like(u), u, u * u], axis=1)                    # (n, 3)
    hinge = np.maximum(0.0, u[None, :] - taus[:, None])                      # (m, n)
    m = len(taus)
    mean = s.mean()
    s = s - mean                  # centred: keeps |s|² − βᵀAᵀs free of cancellation
    # Normal equations per τ from shared pieces (matrix products, no (m, n, 4) array).
    AtA = np.empty((m, 4, 4))
    AtA[:, :3, :3] = base.T @ base
    hb = hinge @ base                                                        # (m, 3)
    AtA[:, :3, 3] = hb
    AtA[:, 3, :3] = hb
    AtA[:, 3, 3] = (hinge * hinge).sum(axis=1)
    Atb = np.empty((m, 4))
    Atb[:, :3] = base.T @ s
    Atb[:, 3] = hinge @ s
    beta = np.linalg.solve(AtA + 1e-12 * np.eye(4), Atb[..., None])[..., 0]
    rss = s @ s - (beta * Atb).sum(axis=1)        # least squares: |s|² − βᵀAᵀs
    beta[:, 0] += mean
    return np.maximum(rss, 0.0), beta


def find_kink(t: np.ndarray, s: np.ndarray, *, min_angle_deg: float = 1.0, min_score: float = 200.0,
              min_side: float = 0.0, min_points: int = 20) -> Kink | None:
    """Find one sharp bend on a line sampled as ``s(t)`` (camera px), or None.

    Parameters
    ----------
    t : (n,) positions along the line (camera row for a near-vertical line, column otherwise).
    s : (n,) float positions across it.
    min_angle_deg : smallest direction change accepted as a kink.
    min_score : smallest (RSS_cubic − RSS_hinge) / σ² accepted; a smooth lens-distortion bend
        is fitted as well by the cubic as by the hinge and scores near 0.
    min_side : the bend must have at least this fraction of the points on each side.
    min_points : and at least this many (a fold near the frame edge still gives a kink).

    Returns
    -------
    Kink or None (``line`` left at -1).
    """
    t = np.asarray(t, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    n = t.size
    if n < 2 * min_points + 5:
        return None
    t0, th = 0.5 * (t.min() + t.max()), 0.5 * (t.max() - t.min())
    if th <= 0:
        return None
    u = (t - t0) / th
    keep = np.ones(n, bool)
    best = None
    for _ in range(2):          # fit, drop gross outliers (> 5 robust sigma), fit again
        uk, sk = u[keep], s[keep]
        nk = uk.size
        lo_i = max(int(min_side * nk), min_points)
        hi_i = nk - 1 - lo_i
        if hi_i <= lo_i:
            return None
        su = np.sort(uk)
        taus = np.linspace(su[lo_i], su[hi_i], 48)
        rss, beta = _hinge_rss(uk, sk, taus)
        i = int(np.argmin(rss))
        if i in (0, len(taus) - 1):
            return None         # best at the edge of the search: the bend (if any) is off it
        # Zoom in on the minimum: each pass searches ±1 step of the previous grid, 40x finer.
        lo_t, hi_t = taus[i - 1], taus[i + 1]
        for _ in range(2):
            fine = np.linspace(lo_t, hi_t, 41)
            frss, fbeta = _hinge_rss(uk, sk, fine)
            j = int(np.argmin(frss))
            lo_t, hi_t = fine[max(j - 1, 0)], fine[min(j + 1, len(fine) - 1)]
        tau, b, rss_h = fine[j], fbeta[j], frss[j]
        resid = sk - (b[0] + b[1] * uk + b[2] * uk * uk + b[3] * np.maximum(0.0, uk - tau))
        sigma = 1.4826 * np.median(np.abs(resid)) + 1e-6
        best = (tau, b, rss_h, uk, sk)
        new_keep = np.zeros(n, bool)
        full_res = s - (b[0] + b[1] * u + b[2] * u * u + b[3] * np.maximum(0.0, u - tau))
        new_keep[np.abs(full_res) < 5 * sigma] = True
        if new_keep.sum() == keep.sum() or new_keep.sum() < 2 * min_points + 5:
            break
        keep = new_keep
    tau, b, rss_h, uk, sk = best
    V = np.stack([np.ones_like(uk), uk, uk ** 2, uk ** 3], axis=1)
    coef, *_ = np.linalg.lstsq(V, sk, rcond=None)
    rss_c = float(((sk - V @ coef) ** 2).sum())
    dof = max(uk.size - 5, 1)
    var = max(rss_h / dof, 1e-6)
    score = (rss_c - rss_h) / var
    slope_l = (b[1] + 2 * b[2] * tau) / th          # ds/dt just before the bend
    slope_r = slope_l + b[3] / th
    angle = math.degrees(abs(math.atan(slope_r) - math.atan(slope_l)))
    if angle < min_angle_deg or score < min_score:
        return None
    tk = t0 + tau * th
    sk_val = b[0] + b[1] * tau + b[2] * tau * tau
    return Kink(point_cam_xy=np.array([tk, sk_val]), angle_deg=angle, score=float(score))


# --------------------------------------------------------------------------- fold
def fit_fold(points_xy: np.ndarray, *, tol: float = 3.0, min_inliers: int = 5,
             min_inlier_fraction: float = 0.5, seed: int = 0):
    """Robust line through kink points: RANSAC over pairs, then total least squares.

    Parameters
    ----------
    points_xy : (m, 2) camera points of the kinks.
    tol : RANSAC inlier distance (camera px).
    min_inliers, min_inlier_fraction : fewer consistent kinks than this means "no fold".

    Returns
    -------
    (line (3,) float64 normalised, inliers (m,) bool, rms float) or None when no fold is found.
    """
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    m = len(pts)
    if m < min_inliers:
        return None
    rng = np.random.default_rng(seed)
    if m * (m - 1) // 2 <= 2000:
        i, j = np.triu_indices(m, 1)
    else:
        i = rng.integers(0, m, 2000)
        j = rng.integers(0, m, 2000)
        ok = i != j
        i, j = i[ok], j[ok]
    d = pts[j] - pts[i]
    nrm = np.hypot(d[:, 0], d[:, 1])
    ok = nrm > 1e-9
    i, j, d, nrm = i[ok], j[ok], d[ok], nrm[ok]
    normals = np.stack([-d[:, 1], d[:, 0]], axis=1) / nrm[:, None]
    c = -(normals * pts[i]).sum(axis=1)
    dist = np.abs(pts @ normals.T + c[None, :])            # (m, pairs)
    counts = (dist < tol).sum(axis=0)
    if counts.size == 0:
        return None
    best = int(np.argmax(counts))
    inl = dist[:, best] < tol
    line = None
    for _ in range(3):              # least squares on the inliers, then re-select them
        if inl.sum() < 2:
            return None
        line = _tls_line(pts[inl])
        r = np.abs(_line_eval(line, pts))
        new = r < tol
        if np.array_equal(new, inl):
            break
        inl = new
    if inl.sum() < min_inliers or inl.sum() < min_inlier_fraction * m:
        return None
    rms = float(np.sqrt(np.mean(_line_eval(line, pts[inl]) ** 2)))
    return _normalise_line(line), inl, rms


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
    import cv2

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


# --------------------------------------------------------------------------- fold in projector
def _segment_in_mask(line: np.ndarray, mask: np.ndarray, n: int = 2000):
    """Endpoints (2, 2) of the part of a line inside a mask (the extreme samples inside), or None."""
    hc, wc = mask.shape
    a, b, c = line
    d = np.array([-b, a])
    p0 = -c * np.array([a, b])                      # foot of the perpendicular from the origin
    diag = math.hypot(wc, hc)
    centre = np.array([wc / 2.0, hc / 2.0])
    tc = (centre - p0) @ d
    ts = np.linspace(tc - diag, tc + diag, n)
    pts = p0[None, :] + ts[:, None] * d[None, :]
    xi, yi = np.rint(pts[:, 0]).astype(int), np.rint(pts[:, 1]).astype(int)
    ok = (xi >= 0) & (xi < wc) & (yi >= 0) & (yi < hc)
    ok[ok] = mask[yi[ok], xi[ok]]
    if ok.sum() < 2:
        return None
    idx = np.flatnonzero(ok)
    return np.stack([pts[idx[0]], pts[idx[-1]]])


def fold_to_projector(fold_cam: np.ndarray, H_proj_from_cam: np.ndarray,
                      segment_cam: np.ndarray):
    """The projector fold from the camera fold and each plane's inverse homography.

    Parameters
    ----------
    fold_cam : (3,) camera fold line.
    H_proj_from_cam : (2, 3, 3).
    segment_cam : (2, 2) ends of the visible part of the camera fold.

    Returns
    -------
    fold_proj : (3,) float64 normalised (orientation not yet fixed).
    disagreement : float, largest distance (projector px) between the two planes' images of the
        visible fold segment, measured at its ends.
    """
    ts = np.linspace(0.0, 1.0, 21)
    seg = segment_cam[0][None, :] * (1 - ts[:, None]) + segment_cam[1][None, :] * ts[:, None]
    m0 = apply_h(H_proj_from_cam[0], seg)
    m1 = apply_h(H_proj_from_cam[1], seg)
    line = _normalise_line(_tls_line(np.concatenate([m0, m1])))
    l0 = _normalise_line(_tls_line(m0))
    # Largest distance between the two mapped lines over the visible segment (at its ends,
    # where two lines are farthest apart).
    ends = np.stack([m0[0], m0[-1], m1[0], m1[-1]])
    l1 = _normalise_line(_tls_line(m1))
    dis = max(float(np.abs(_line_eval(l1, ends[:2])).max()),
              float(np.abs(_line_eval(l0, ends[2:])).max()))
    return line, dis


def _canonical(line: np.ndarray) -> np.ndarray:
    """Orient the normal towards +x (towards +y for a nearly horizontal line)."""
    a, b, _ = line
    if (abs(a) >= abs(b) and a < 0) or (abs(a) < abs(b) and b < 0):
        return -line
    return line


# --------------------------------------------------------------------------- lit area, layout
def _clip_polygon(poly: np.ndarray, line: np.ndarray, keep_negative: bool) -> np.ndarray:
    """Sutherland–Hodgman clip of a convex polygon by a half-plane of ``line``."""
    sgn = -1.0 if keep_negative else 1.0
    out = []
    n = len(poly)
    for k in range(n):
        p, q = poly[k], poly[(k + 1) % n]
        fp, fq = sgn * _line_eval(line, p[None])[0], sgn * _line_eval(line, q[None])[0]
        if fp >= 0:
            out.append(p)
        if (fp >= 0) != (fq >= 0):
            t = fp / (fp - fq)
            out.append(p + t * (q - p))
    return np.array(out).reshape(-1, 2)


def projector_frame(projector_size: tuple[int, int]) -> np.ndarray:
    """(4, 2) corners of the projector frame as a continuous area (pixel edges at ±0.5)."""
    wp, hp = projector_size
    return np.array([[-0.5, -0.5], [wp - 0.5, -0.5], [wp - 0.5, hp - 0.5], [-0.5, hp - 0.5]])


def plane_polygons_proj(projector_size, fold_proj: np.ndarray, n_planes: int) -> list[np.ndarray]:
    """The projector frame split at the fold: one convex polygon (k, 2) per plane."""
    frame = projector_frame(projector_size)
    if n_planes == 1:
        return [frame]
    return [_clip_polygon(frame, fold_proj, True), _clip_polygon(frame, fold_proj, False)]


def lit_polygon(projector_size: tuple[int, int], H_cam_from_proj: np.ndarray,
                fold_proj: np.ndarray) -> np.ndarray:
    """Outline (m, 2) float64 in camera px of what the projector lights, in boundary order.

    The projector frame's border, walked in order, is cut where the fold crosses it; each
    piece is mapped through its own plane's homography (both planes map the fold to the same
    camera line, so the pieces join there).
    """
    frame = projector_frame(projector_size)
    n = H_cam_from_proj.shape[0]
    if n == 1:
        return apply_h(H_cam_from_proj[0], frame)
    out = []
    for k in range(4):
        p, q = frame[k], frame[(k + 1) % 4]
        fp, fq = _line_eval(fold_proj, p[None])[0], _line_eval(fold_proj, q[None])[0]
        out.append(apply_h(H_cam_from_proj[int(fp >= 0)], p[None])[0])
        if (fp < 0) != (fq < 0):
            x = p + fp / (fp - fq) * (q - p)
            a, b = apply_h(H_cam_from_proj[0], x[None])[0], apply_h(H_cam_from_proj[1], x[None])[0]
            out.append(0.5 * (a + b))
    return np.array(out)


def _points_in_polygon(px: np.ndarray, py: np.ndarray, poly: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    """Points (any broadcastable shapes) inside or on the boundary of a simple polygon (m, 2)."""
    inside = np.zeros(np.broadcast(px, py).shape, bool)
    on_edge = np.zeros_like(inside)
    m = len(poly)
    for k in range(m):
        x1, y1 = poly[k]
        x2, y2 = poly[(k + 1) % m]
        dx, dy = x2 - x1, y2 - y1
        seg2 = dx * dx + dy * dy
        if seg2 > 0:        # distance to the segment: on the boundary counts as inside
            t = np.clip(((px - x1) * dx + (py - y1) * dy) / seg2, 0.0, 1.0)
            on_edge |= (px - x1 - t * dx) ** 2 + (py - y1 - t * dy) ** 2 <= eps * eps
        if y1 == y2:
            continue
        crosses = (py >= min(y1, y2)) & (py < max(y1, y2))
        xint = x1 + (py - y1) * dx / dy
        inside ^= crosses & (px < xint)
    return inside | on_edge


def largest_inscribed_rect(polygon: np.ndarray, aspect: float, camera_size: tuple[int, int],
                           margin: float = 0.0) -> tuple[int, int, int, int]:
    """Largest upright rectangle of a given aspect inside a polygon and the camera frame.

    Parameters
    ----------
    polygon : (m, 2) float camera points (x, y) of a simple polygon, in boundary order.
    aspect : width / height of the rectangle (> 0).
    camera_size : (width, height) of the camera.
    margin : fraction (0 <= margin < 1) by which the rectangle is shrunk about its centre
        (0.05: 5 % smaller in each direction).

    Returns
    -------
    (x, y, w, h) ints, an OpenCV Rect of camera pixels: columns x … x+w−1 and rows y … y+h−1,
    i.e. the continuous area [x − 0.5, x + w − 0.5] × [y − 0.5, y + h − 0.5], which lies inside
    the polygon. Among the positions of the largest size, the one nearest the middle of them.

    Raises
    ------
    InputError
        Bad aspect, margin or polygon; or no pixel of the camera lies inside the polygon.
    """
    poly = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    if not (np.isfinite(aspect) and aspect > 0):
        raise InputError(f"aspect must be a positive width/height ratio; got {aspect}")
    if not 0.0 <= margin < 1.0:
        raise InputError(f"margin must be a fraction in [0, 1); got {margin}")
    if len(poly) < 3 or not np.isfinite(poly).all():
        raise InputError(f"the lit polygon needs >= 3 finite vertices; got {poly.shape}")
    wc, hc = int(camera_size[0]), int(camera_size[1])
    # A pixel is usable when its four corners are inside the polygon and no polygon vertex
    # pokes into it (the only way a straight-edged outline can cut a square without
    # putting one of its corners outside).
    cx = np.arange(wc + 1, dtype=np.float64) - 0.5
    cy = np.arange(hc + 1, dtype=np.float64) - 0.5
    corner_in = _points_in_polygon(cx[None, :], cy[:, None], poly)
    pix = corner_in[:-1, :-1] & corner_in[:-1, 1:] & corner_in[1:, :-1] & corner_in[1:, 1:]
    vx, vy = np.rint(poly[:, 0]).astype(int), np.rint(poly[:, 1]).astype(int)
    strictly = (np.abs(poly[:, 0] - vx) < 0.5 - 1e-9) & (np.abs(poly[:, 1] - vy) < 0.5 - 1e-9)
    on = strictly & (vx >= 0) & (vx < wc) & (vy >= 0) & (vy < hc)
    pix[vy[on], vx[on]] = False
    if not pix.any():
        raise InputError("no camera pixel lies inside the lit polygon; the calibration's lit "
                         "area is empty or outside the camera frame")
    bad = np.zeros((hc + 1, wc + 1), np.int64)
    bad[1:, 1:] = np.cumsum(np.cumsum(~pix, axis=0), axis=1)

    def width_of(h: int) -> int:
        return max(1, int(round(h * aspect)))

    def fits(h: int) -> np.ndarray | None:
        w = width_of(h)
        if w > wc or h > hc:
            return None
        s = bad[h:, w:] - bad[:-h, w:] - bad[h:, :-w] + bad[:-h, :-w]
        ok = s == 0
        return ok if ok.any() else None

    lo, hi = 0, hc          # lo fits (0 = nothing), hi + 1 does not
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if fits(mid) is not None:
            lo = mid
        else:
            hi = mid - 1
    if lo == 0:
        raise InputError("the lit area is too small for any rectangle of aspect "
                         f"{aspect:.3f} at camera resolution")
    h = lo
    w = width_of(h)
    ys, xs = np.nonzero(fits(h))
    k = int(np.argmin((xs - xs.mean()) ** 2 + (ys - ys.mean()) ** 2))
    x, y = int(xs[k]), int(ys[k])
    if margin > 0:
        h2 = max(1, int(round(h * (1.0 - margin))))
        w2 = width_of(h2)
        x, y, w, h = x + (w - w2) // 2, y + (h - h2) // 2, w2, h2
    return x, y, w, h


# --------------------------------------------------------------------------- the stage
@dataclass
class GeometryDetail:
    """What the geometry stage saw, for diagnostics (kept in memory, never saved).

    Attributes
    ----------
    detection : the :class:`LineDetection` (lines, white/black frames).
    kinks : every :class:`Kink` found; ``fold_inliers`` (len(kinks),) bool those on the fold.
    pts_proj_xy, pts_cam_xy : (n, 2) crossings; ``plane`` (n,) int8 plane (-1: in the fold
        band); ``inliers`` (n,) bool homography inliers.
    """

    detection: LineDetection
    kinks: list[Kink] = field(default_factory=list)
    fold_inliers: np.ndarray | None = None
    pts_proj_xy: np.ndarray | None = None
    pts_cam_xy: np.ndarray | None = None
    plane: np.ndarray | None = None
    inliers: np.ndarray | None = None


def calibrate_geometry(procam: ProCam, *, capture: Capturer | None = None, line_spacing: int = 48,
                       line_phases: int = 4, line_width: int = 3, samples: int = 1,
                       min_kink_deg: float = 1.0, fold_band: float | None = None,
                       ransac_threshold: float = 1.5) -> Calibration:
    """Learn the set-up's geometry through ``capture`` only.

    Parameters
    ----------
    procam : ProCam
    capture : the calibration's :class:`Capturer` (counts, retries, progress); a fresh one
        when None.
    line_spacing : projector px between the lines of one pattern (> 2 × the largest blur
        diameter).
    line_phases : shifted copies per direction; lines every ``line_spacing / line_phases`` px.
    line_width : projector px.
    samples : captures averaged per pattern (camera noise).
    min_kink_deg : smallest bend (degrees) taken as a kink.
    fold_band : camera px on each side of the fold whose crossings are left out; default: the
        ridge window (covers the largest blurred line).
    ransac_threshold : homography RANSAC inlier distance (camera px).

    Returns
    -------
    Calibration
        Geometry section filled; ``meta["geometry"]`` holds the statistics (``n_planes``,
        ``rms_px``, ``inliers``, ``fold_disagreement_px``, ``captures``, lines and kinks).
        The transient attribute ``geometry_detail`` (:class:`GeometryDetail`) feeds
        :func:`geometry_diagnostics`; it is not saved.

    Raises
    ------
    CalibrationError
        The camera sees no projector light, the lines cannot be found, or the correspondences
        are inconsistent (the set-up moved); the message says what was seen and what to check.
    """
    t_start = time.perf_counter()
    cap = capture if capture is not None else Capturer(procam)
    if int(samples) < 1:
        raise InputError(f"samples must be >= 1; got {samples}")
    pats = LinePatterns(tuple(procam.projector_size), int(line_spacing), int(line_phases),
                        int(line_width))
    seq = pats.sequence()
    cap.begin("geometry", len(seq) * int(samples))
    det = LineDetector(pats)
    for name, pattern in seq:
        frame = cap(pattern) if samples == 1 else cap.mean(pattern, int(samples))
        det.add(name, frame)
    detection = det.result()
    lines = detection.lines
    camera_size = tuple(procam.camera_size)
    detail = GeometryDetail(detection=detection)

    # ---- kinks and the camera fold
    kinks = []
    for k, ln in enumerate(lines):
        kk = find_kink(ln.t, ln.s, min_angle_deg=min_kink_deg)
        if kk is not None:
            kk.point_cam_xy = (kk.point_cam_xy if ln.axis == "h" else kk.point_cam_xy[::-1]).copy()
            kk.line = k
            kinks.append(kk)
    detail.kinks = kinks
    fold = fit_fold(np.array([kk.point_cam_xy for kk in kinks])) if kinks else None
    proj, cam, _ = line_crossings(lines, camera_size)
    detail.pts_proj_xy, detail.pts_cam_xy = proj, cam
    band = float(fold_band) if fold_band is not None else float(det.half)

    stats: dict = {"captures": len(seq) * int(samples), "patterns": len(seq),
                   "lines_found": detection.stats["lines_found"],
                   "lines_expected": detection.stats["lines_expected"],
                   "ridge_points": detection.stats["points"], "kinks": len(kinks),
                   "crossings": int(len(proj)), "white_shift_px": detection.stats.get("white_shift_px"),
                   "options": {"line_spacing": pats.spacing, "line_phases": pats.phases,
                               "line_width": pats.width, "samples": int(samples),
                               "min_kink_deg": min_kink_deg, "fold_band": band,
                               "ransac_threshold": ransac_threshold}}

    if fold is None:
        log.info("geometry: %d kinks, no consistent fold: one plane", len(kinks))
        H, inl, rms = fit_homography(proj, cam, threshold=ransac_threshold, what="the plane")
        _check_fit(inl, rms, "the plane", ransac_threshold)
        Hs = H[None]
        fold_proj = np.zeros(3)
        fold_cam = np.zeros(3)
        plane = np.zeros(len(proj), np.int8)
        inliers = inl
        stats.update(n_planes=1, rms_px=[round(rms, 4)], inliers=[int(inl.sum())],
                     inlier_fraction=[round(float(inl.mean()), 4)], fold_disagreement_px=None,
                     fold_kinks=0)
        detail.fold_inliers = np.zeros(len(kinks), bool)
    else:
        fold_cam0, fold_inl, fold_rms = fold
        detail.fold_inliers = fold_inl
        side = _line_eval(fold_cam0, cam)
        sel = [side < -band, side > band]
        fits = []
        for k in range(2):
            what = f"the plane on the {'negative' if k == 0 else 'positive'} side of the fold"
            H, inl, rms = fit_homography(proj[sel[k]], cam[sel[k]], threshold=ransac_threshold,
                                         what=what)
            _check_fit(inl, rms, what, ransac_threshold)
            fits.append((H, inl, rms))
        Hs = np.stack([f[0] for f in fits])
        Hinv = np.stack([np.linalg.inv(H) for H in Hs])
        seg = _segment_in_mask(fold_cam0, detection.valid)
        if seg is None:
            pts = np.array([kk.point_cam_xy for kk in kinks])[fold_inl]
            seg = np.stack([pts.min(axis=0), pts.max(axis=0)])
        fold_proj, disagreement = fold_to_projector(fold_cam0, Hinv, seg)
        fold_proj = _canonical(fold_proj)
        # Plane 0 is the negative side of the projector fold; which camera side is that?
        neg0 = float(np.median(_line_eval(fold_proj, proj[sel[0]]))) < 0
        order = [0, 1] if neg0 else [1, 0]
        Hs = Hs[order]
        fits = [fits[o] for o in order]
        fold_cam = fold_cam0 if neg0 else -fold_cam0
        plane = np.full(len(proj), -1, np.int8)
        inliers = np.zeros(len(proj), bool)
        for new, old in enumerate(order):
            plane[sel[old]] = new
            inliers[np.flatnonzero(sel[old])[fits[new][1]]] = True
        stats.update(n_planes=2, rms_px=[round(f[2], 4) for f in fits],
                     inliers=[int(f[1].sum()) for f in fits],
                     inlier_fraction=[round(float(f[1].mean()), 4) for f in fits],
                     fold_disagreement_px=round(disagreement, 4), fold_kinks=int(fold_inl.sum()),
                     fold_kink_rms_px=round(fold_rms, 4))
        if disagreement > 3.0:
            raise CalibrationError(
                f"the two planes disagree about where the fold is by {disagreement:.1f} projector "
                "px: the kinks do not lie where the homographies meet. Check that the surface is "
                "two flat walls, that the camera sees both, and that nothing moved.")
    detail.plane, detail.inliers = plane, inliers
    Hs = np.stack([H / H[2, 2] for H in Hs])
    Hinv = np.stack([np.linalg.inv(H) for H in Hs])
    Hinv = np.stack([H / H[2, 2] for H in Hinv])
    poly = lit_polygon(pats.projector_size, Hs, fold_proj)
    calib = Calibration(projector_size=pats.projector_size, camera_size=camera_size,
                        H_cam_from_proj=Hs, H_proj_from_cam=Hinv, fold_proj=fold_proj,
                        fold_cam=fold_cam, lit_polygon_cam=poly)
    stats["seconds"] = round(time.perf_counter() - t_start, 2)
    stats["kinks_cam"] = [[round(float(v), 2) for v in kk.point_cam_xy] for kk in kinks]
    calib.meta["geometry"] = stats
    calib.geometry_detail = detail
    log.info("geometry: %d plane(s), RMS reprojection %s camera px, fold disagreement %s px, "
             "%d captures", stats["n_planes"], stats["rms_px"], stats["fold_disagreement_px"],
             stats["captures"])
    return calib


def _check_fit(inl: np.ndarray, rms: float, what: str, threshold: float) -> None:
    """Stop when the crossings do not agree on one homography; warn when many miss it.

    On a still set-up nearly all crossings are inliers (lens distortion of a few px lowers the
    share a little); crossings from captures taken before and after a move disagree by the move.
    """
    frac = float(inl.mean()) if inl.size else 0.0
    if frac < 0.6 or not np.isfinite(rms):
        raise CalibrationError(
            f"{what}: the line crossings are inconsistent — only {100 * frac:.0f} % of {inl.size} "
            f"fit one homography within {threshold} camera px. The set-up probably moved between "
            "captures (camera or projector knocked, auto-focus or image stabilisation on), or the "
            "surface is not flat there. Fix both devices firmly and calibrate again.")
    if frac < 0.9:
        log.warning("%s: only %.0f %% of the line crossings fit one homography within %.1f px "
                    "(RMS %.2f px): strong lens distortion or a curved surface?", what, 100 * frac,
                    threshold, rms)


# --------------------------------------------------------------------------- diagnostics
_PLANE_TINT = np.array([[60, 120, 255], [255, 150, 40]], np.float32)   # RGB per plane


def geometry_diagnostics(calib: Calibration, detail: GeometryDetail | None = None,
                         background: np.ndarray | None = None,
                         aspects: tuple[tuple[int, int], ...] = ((4, 3), (16, 9))) -> np.ndarray:
    """A picture of the geometry stage's result over the camera view.

    Parameters
    ----------
    calib : the calibration (geometry section).
    detail : what the stage saw (default: ``calib.geometry_detail`` when present); without it
        only the fitted fold, planes and display rectangles are drawn.
    background : (Hc, Wc, 3) uint8 camera view; default the white frame of ``detail``, else black.
    aspects : display rectangles to draw, as (w, h) aspect ratios.

    Returns
    -------
    (Hc, Wc, 3) uint8 RGB: the camera view (dimmed), each plane tinted (blue = plane 0,
    orange = plane 1), detected lines (green: vertical, cyan: horizontal), kinks (red: on the
    fold, hollow grey: rejected), the fold (yellow), the display rectangles (magenta 4:3,
    white 16:9, ...) and a caption.
    """
    import cv2

    detail = detail if detail is not None else getattr(calib, "geometry_detail", None)
    wc, hc = calib.camera_size
    if background is None:
        background = detail.detection.white_rgb if detail is not None else np.zeros((hc, wc, 3), np.uint8)
    img = 0.55 * np.asarray(background, dtype=np.float32)
    # Planes, tinted: each plane's share of the projector frame mapped into the camera.
    for k, pp in enumerate(plane_polygons_proj(calib.projector_size, calib.fold_proj, calib.n_planes)):
        if len(pp) < 3:
            continue
        pc = apply_h(calib.H_cam_from_proj[k], pp)
        mask = np.zeros((hc, wc), np.uint8)
        cv2.fillPoly(mask, [np.round(pc * 16).astype(np.int32)], 1, cv2.LINE_AA, shift=4)
        m = mask.astype(bool)
        img[m] = 0.7 * img[m] + 0.3 * _PLANE_TINT[k]
    img = np.clip(img, 0, 255).astype(np.uint8)
    sh = 4

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
    if calib.n_planes == 2:
        lit = np.zeros((hc, wc), np.uint8)
        cv2.fillPoly(lit, [np.round(calib.lit_polygon_cam).astype(np.int32)], 1)
        seg = _segment_in_mask(calib.fold_cam, lit.astype(bool))
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
    g = calib.meta.get("geometry", {})
    cap = (f"{calib.n_planes} plane(s)  RMS {g.get('rms_px')} px  fold disagreement "
           f"{g.get('fold_disagreement_px')} px  {g.get('captures')} captures")
    cv2.putText(img, cap, (10, hc - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, cap, (10, hc - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return img
