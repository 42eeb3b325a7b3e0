"""Plane geometry shared by the calibration stages and the file format (a leaf module).

Homographies applied per plane, lines ``a x + b y + c = 0`` (normalised: a² + b² = 1),
convex polygons clipped by a line, the projector frame and its planes, the lit outline in the
camera and the largest display rectangle inside it. Only NumPy: every calibration module may
import this one, and it imports none of them.

Conventions (docs/internals.md): points are (x, y); sizes (width, height); plane 0 is where the
fold line is negative, in the projector and in the camera alike.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError

__all__ = [
    "apply_h", "apply_h_per_plane", "normalise_line", "line_eval", "tls_line", "canonical_line",
    "segment_in_mask", "clip_polygon", "projector_frame", "inset_frame", "fold_sign",
    "plane_polygons_proj", "plane_polygon", "lit_polygon", "points_in_polygon",
    "largest_inscribed_rect",
]


# --------------------------------------------------------------------------- homographies, lines
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


def normalise_line(line: np.ndarray) -> np.ndarray:
    line = np.asarray(line, dtype=np.float64)
    return line / math.hypot(line[0], line[1])


def line_eval(line: np.ndarray, pts_xy: np.ndarray) -> np.ndarray:
    """Signed value of ``line`` at (n, 2) points (the distance when the line is normalised)."""
    return pts_xy @ line[:2] + line[2]


def tls_line(pts: np.ndarray) -> np.ndarray:
    """Total-least-squares line through (n, 2) points, normalised."""
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    n = vt[1]
    return np.array([n[0], n[1], -n @ c])



def canonical_line(line: np.ndarray) -> np.ndarray:
    """Orient the normal towards +x (towards +y for a nearly horizontal line)."""
    a, b, _ = line
    if (abs(a) >= abs(b) and a < 0) or (abs(a) < abs(b) and b < 0):
        return -line
    return line



def segment_in_mask(line: np.ndarray, mask: np.ndarray, n: int = 2000):
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

# --------------------------------------------------------------------------- polygons
def clip_polygon(poly: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Sutherland–Hodgman: the part of a convex polygon (m, 2) where ``line`` (a, b, c) is <= 0.

    ``-line`` keeps the other side. Returns (k, 2) float64, (0, 2) when nothing is left.
    """
    a, b, c = line
    out = []
    n = len(poly)
    for i in range(n):
        p, q = poly[i], poly[(i + 1) % n]
        fp, fq = a * p[0] + b * p[1] + c, a * q[0] + b * q[1] + c
        if fp <= 0:
            out.append(p)
        if (fp < 0 < fq) or (fq < 0 < fp):
            t = fp / (fp - fq)
            out.append(p + t * (q - p))
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def projector_frame(projector_size: tuple[int, int]) -> np.ndarray:
    """(4, 2) corners of the projector frame as a continuous area (pixel edges at ±0.5)."""
    wp, hp = projector_size
    return np.array([[-0.5, -0.5], [wp - 0.5, -0.5], [wp - 0.5, hp - 0.5], [-0.5, hp - 0.5]])


def inset_frame(size: tuple[int, int], inset: float) -> np.ndarray:
    """(4, 2) corners of the rectangle of pixel centres ``inset`` px inside a (width, height)
    frame."""
    w, h = size
    e = float(inset)
    return np.array([[e, e], [w - 1 - e, e], [w - 1 - e, h - 1 - e], [e, h - 1 - e]], np.float64)


def fold_sign(plane: int) -> float:
    """s such that s · fold(x) > 0 inside ``plane`` (plane 0 is where the fold line is negative)."""
    return -1.0 if plane == 0 else 1.0


def plane_polygons_proj(projector_size, fold_proj: np.ndarray, n_planes: int) -> list[np.ndarray]:
    """The projector frame split at the fold: one convex polygon (k, 2) per plane."""
    frame = projector_frame(projector_size)
    if n_planes == 1:
        return [frame]
    fold = np.asarray(fold_proj, np.float64)
    return [clip_polygon(frame, fold), clip_polygon(frame, -fold)]


def plane_polygon(projector_size: tuple[int, int], fold_proj: np.ndarray, n_planes: int,
                  plane: int, edge_inset: float = 0.0, fold_inset: float = 0.0) -> np.ndarray:
    """Convex outline (m, 2) of ``plane`` in projector pixels (pixel centres), shrunk by
    ``edge_inset`` from the frame edges and by ``fold_inset`` from the fold. Empty (0, 2) when
    nothing is left."""
    poly = inset_frame(projector_size, edge_inset)
    if n_planes == 2:
        a, b, c = fold_proj
        s = fold_sign(plane)
        poly = clip_polygon(poly, (-s * a, -s * b, -s * c + fold_inset))
    return poly


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
        fp, fq = line_eval(fold_proj, p[None])[0], line_eval(fold_proj, q[None])[0]
        out.append(apply_h(H_cam_from_proj[int(fp >= 0)], p[None])[0])
        if (fp < 0) != (fq < 0):
            x = p + fp / (fp - fq) * (q - p)
            a, b = apply_h(H_cam_from_proj[0], x[None])[0], apply_h(H_cam_from_proj[1], x[None])[0]
            out.append(0.5 * (a + b))
    return np.array(out)


def points_in_polygon(px: np.ndarray, py: np.ndarray, poly: np.ndarray, eps: float = 1e-7) -> np.ndarray:
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
    corner_in = points_in_polygon(cx[None, :], cy[:, None], poly)
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


# --------------------------------------------------------------------------- lens distortion
def distortion_scale(camera_size: tuple[int, int]) -> tuple[float, float, float]:
    """Centre (cx, cy) and radius normalisation of the radial distortion model: the image
    centre, and half the frame diagonal (r = 1 at the corners)."""
    wc, hc = camera_size
    return (wc - 1) / 2.0, (hc - 1) / 2.0, 0.5 * math.hypot(wc, hc)


def _radial_frame(pts_xy, k, camera_size):
    """Points as float64, (k1, k2) as floats, and the model's centre and scale."""
    k1, k2 = (float(v) for v in k)
    return np.asarray(pts_xy, dtype=np.float64), k1, k2, distortion_scale(camera_size)


def distort_points(pts_xy: np.ndarray, k: tuple[float, float] | np.ndarray,
                   camera_size: tuple[int, int]) -> np.ndarray:
    """Ideal (pinhole) camera pixels -> observed pixels under radial distortion.

    ``x_obs = c + (x - c)(1 + k1 r² + k2 r⁴)`` with r = |x - c| / (half diagonal), c the image
    centre (:func:`distortion_scale`). ``pts_xy`` (..., 2); returns float64 of the same shape.
    """
    p, k1, k2, (cx, cy, s) = _radial_frame(pts_xy, k, camera_size)
    if k1 == 0.0 and k2 == 0.0:
        return p.copy()
    dx, dy = (p[..., 0] - cx) / s, (p[..., 1] - cy) / s
    r2 = dx * dx + dy * dy
    f = 1.0 + k1 * r2 + k2 * r2 * r2
    return np.stack([cx + s * dx * f, cy + s * dy * f], axis=-1)


def undistort_points(pts_xy: np.ndarray, k: tuple[float, float] | np.ndarray,
                     camera_size: tuple[int, int], iterations: int = 12) -> np.ndarray:
    """Observed camera pixels -> ideal (pinhole) pixels: the inverse of :func:`distort_points`
    (fixed-point iteration; exact to ~1e-6 px for |k1|, |k2| < 0.3)."""
    p, k1, k2, (cx, cy, s) = _radial_frame(pts_xy, k, camera_size)
    if k1 == 0.0 and k2 == 0.0:
        return p.copy()
    dx, dy = (p[..., 0] - cx) / s, (p[..., 1] - cy) / s
    ux, uy = dx.copy(), dy.copy()
    for _ in range(iterations):
        r2 = ux * ux + uy * uy
        f = 1.0 + k1 * r2 + k2 * r2 * r2
        ux, uy = dx / f, dy / f
    return np.stack([cx + s * ux, cy + s * uy], axis=-1)


__all__ += ["distortion_scale", "distort_points", "undistort_points"]
