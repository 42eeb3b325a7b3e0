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

from .errors import InputError

__all__ = [
    "apply_h", "apply_h_per_plane", "normalise_line", "line_eval", "tls_line", "canonical_line",
    "segment_in_mask", "clip_polygon", "projector_frame", "inset_frame", "fold_sign",
    "MAX_PLANES", "MAX_FOLDS", "PlaneLayout", "fold_segments_cam", "plane_polygons_proj",
    "plane_polygon", "lit_polygon",
    "points_in_polygon",
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
    """s such that s · fold(x) > 0 inside ``plane`` of a two-plane set-up (plane 0 is where the
    fold line is negative)."""
    return -1.0 if plane == 0 else 1.0


# --------------------------------------------------------------------------- plane layouts
#: Most planes one calibration handles (the GL warp's matrix array is this long), and most
#: folds between them (planes meeting along lines make at most 3 n - 6 folds for n >= 3).
MAX_PLANES = 8
MAX_FOLDS = 2 * MAX_PLANES


class PlaneLayout:
    """How an image (the projector frame, or the camera's view of it) splits into planes.

    Parameters
    ----------
    n_planes : int, 1 .. :data:`MAX_PLANES`.
    folds : (m, 3) float lines ``a x + b y + c = 0`` (normalised here: a² + b² = 1), one per
        pair of planes that meet inside the frame.
    fold_planes : (m, 2) int, for each fold the plane on its negative side and the plane on
        its positive side.

    A point belongs to plane p when it is on p's side of every fold that bounds p. Fitted folds
    that should meet at one vertex pass a little apart; there a point goes to the plane it is
    least outside of (:meth:`label`), so the labels always tile the frame, with no gap or
    overlap. Two planes: one fold, plane 0 on its negative side (ties, on
    the line itself, go to the higher plane).
    """

    def __init__(self, n_planes: int, folds=None, fold_planes=None):
        n = int(n_planes)
        f = np.zeros((0, 3)) if folds is None else np.asarray(folds, np.float64).reshape(-1, 3)
        fp = (np.zeros((0, 2), np.int64) if fold_planes is None
              else np.asarray(fold_planes).reshape(-1, 2).astype(np.int64))
        if not 1 <= n <= MAX_PLANES:
            raise InputError(f"a plane layout has 1 to {MAX_PLANES} planes; got {n}")
        if len(f) > MAX_FOLDS:
            raise InputError(f"a plane layout has at most {MAX_FOLDS} folds; got {len(f)}")
        if len(f) != len(fp):
            raise InputError(f"{len(f)} fold lines but {len(fp)} fold plane pairs; give one pair "
                             "(negative side, positive side) per fold")
        if not np.isfinite(f).all() or (len(f) and not (np.hypot(f[:, 0], f[:, 1]) > 0).all()):
            raise InputError(f"fold lines must be finite with (a, b) != 0; got {f.tolist()}")
        if len(fp) and (fp.min() < 0 or fp.max() >= n or (fp[:, 0] == fp[:, 1]).any()):
            raise InputError(f"fold plane pairs must name two different planes among 0..{n - 1}; "
                             f"got {fp.tolist()}")
        if n > 1:
            touched = set(fp.ravel().tolist())
            if len(touched) < n:
                raise InputError(f"planes {sorted(set(range(n)) - touched)} of {n} have no fold; "
                                 "every plane of a layout must meet another one")
        self.n_planes = n
        self.folds = f / np.hypot(f[:, 0], f[:, 1])[:, None] if len(f) else f
        self.fold_planes = fp
        # signs[p, j]: +1 where plane p lies on fold j's positive side, -1 negative, 0 unbounded.
        s = np.zeros((n, len(f)))
        for j, (neg, pos) in enumerate(fp):
            s[neg, j], s[pos, j] = -1.0, 1.0
        self.signs = s

    @classmethod
    def from_fold(cls, fold, n_planes: int) -> PlaneLayout:
        """One plane (``fold`` ignored), or two planes split by one line (plane 0 negative)."""
        if int(n_planes) == 1:
            return cls(1)
        if int(n_planes) != 2:
            raise InputError(f"one fold line splits the frame into 2 planes, not {n_planes}; "
                             "give a PlaneLayout for more")
        if fold is None:
            raise InputError("two planes need a fold line (a, b, c); got None")
        return cls(2, np.asarray(fold, np.float64).reshape(1, 3), [[0, 1]])

    @classmethod
    def coerce(cls, planes, n_planes: int) -> PlaneLayout:
        """A layout from what callers pass as "the planes": a PlaneLayout, a (3,) fold line
        (two planes) or None / zeros (one plane)."""
        if isinstance(planes, PlaneLayout):
            if planes.n_planes != int(n_planes):
                raise InputError(f"the plane layout has {planes.n_planes} planes but "
                                 f"{n_planes} homographies were given; they must agree")
            return planes
        if int(n_planes) == 1:
            return cls(1)
        if planes is None:
            raise InputError(f"{n_planes} planes need their fold (a line (a, b, c) or a "
                             "PlaneLayout); got None")
        line = np.asarray(planes, np.float64).reshape(-1)
        if line.shape != (3,) or not np.isfinite(line).all() or not np.hypot(line[0], line[1]) > 0:
            raise InputError(f"the fold must be a finite line (a, b, c) with (a, b) != 0 (or a "
                             f"PlaneLayout); got {np.asarray(planes).tolist()}")
        return cls.from_fold(line, n_planes)

    @property
    def n_folds(self) -> int:
        return len(self.folds)

    def bounding_folds(self, plane: int) -> list[int]:
        """Indices of the folds that bound ``plane``."""
        return [int(j) for j in np.flatnonzero(self.signs[plane])]

    def bounding(self, plane: int) -> list[tuple[np.ndarray, float]]:
        """The folds that bound ``plane``: (line, s) with s · line(x) >= 0 inside the plane."""
        return [(self.folds[j], float(self.signs[plane, j])) for j in self.bounding_folds(plane)]

    def inward(self, j: int, plane: int) -> np.ndarray:
        """Unit normal (2,) of fold ``j`` pointing into ``plane``."""
        return float(self.signs[plane, j]) * self.folds[j][:2].astype(np.float64)

    def fold_distance(self, j: int, pts_xy: np.ndarray, plane: int) -> np.ndarray:
        """Signed distance (px) of points (N, 2) into ``plane`` from fold ``j`` (positive inside)."""
        a, b, c = self.folds[j]
        return float(self.signs[plane, j]) * (pts_xy[:, 0] * a + pts_xy[:, 1] * b + c)

    def outside(self, x, y) -> np.ndarray:
        """(n_planes, *shape) float64: how far (px) each point is outside each plane; <= 0 inside
        (the largest distance to the wrong side of a bounding fold; -inf for a lone plane)."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        out = np.full((self.n_planes,) + x.shape, -np.inf)
        for j, (a, b, c) in enumerate(self.folds):
            v = a * x + b * y + c
            for p in np.flatnonzero(self.signs[:, j]):
                np.maximum(out[p], -self.signs[p, j] * v, out=out[p])
        return out

    def label(self, x, y) -> np.ndarray:
        """int8 plane of each point (arrays broadcast): the plane it is least outside of, ties
        to the higher index (the GL warp makes the same choice)."""
        v = self.outside(x, y)
        best = np.zeros(v.shape[1:], np.int8)
        best_v = v[0].copy()
        for p in range(1, self.n_planes):
            take = v[p] <= best_v
            best[take] = p
            best_v[take] = v[p][take]
        return best

    def polygon(self, frame: np.ndarray, plane: int, fold_inset: float = 0.0) -> np.ndarray:
        """Convex outline (k, 2) of ``plane`` inside the convex polygon ``frame``, kept
        ``fold_inset`` px away from each of its folds; (0, 2) when nothing is left."""
        poly = np.asarray(frame, np.float64)
        for (a, b, c), s in self.bounding(plane):
            poly = clip_polygon(poly, (-s * a, -s * b, -s * c + fold_inset))
            if len(poly) == 0:
                break
        return poly

    def fold_segments(self, frame: np.ndarray) -> list[np.ndarray | None]:
        """Per fold, the end points (2, 2) of the part of its line that really separates its
        two planes inside the convex ``frame`` (shared edge of their outlines), or None."""
        out = []
        for j, (neg, pos) in enumerate(self.fold_planes):
            ends = []
            for p in (neg, pos):
                poly = self.polygon(frame, p)
                on = np.abs(line_eval(self.folds[j], poly)) < 1e-6 if len(poly) else []
                if np.count_nonzero(on) < 2:
                    ends = None
                    break
                ends.append(poly[on])
            if ends is None:
                out.append(None)
                continue
            d = np.array([-self.folds[j][1], self.folds[j][0]])
            t0, t1 = (e @ d for e in ends)
            lo, hi = max(t0.min(), t1.min()), min(t0.max(), t1.max())
            if not hi > lo:
                out.append(None)
                continue
            both = np.concatenate(ends)
            tt = both @ d
            out.append(np.stack([both[np.argmin(np.abs(tt - lo))], both[np.argmin(np.abs(tt - hi))]]))
        return out

    def __eq__(self, other) -> bool:
        return (isinstance(other, PlaneLayout) and self.n_planes == other.n_planes
                and np.array_equal(self.folds, other.folds)
                and np.array_equal(self.fold_planes, other.fold_planes))

    __hash__ = None

    def __repr__(self) -> str:
        return (f"PlaneLayout({self.n_planes} planes, folds {np.round(self.folds, 4).tolist()}, "
                f"fold_planes {self.fold_planes.tolist()})")


def fold_segments_cam(projector_size, H_cam_from_proj: np.ndarray,
                      layout: PlaneLayout) -> list[np.ndarray | None]:
    """Per fold of ``layout``, the part that separates its planes inside the projector frame
    (:meth:`PlaneLayout.fold_segments`) in camera pixels: its ends (2, 2) mapped through the
    homography of the plane on its negative side (both planes map the fold to one camera
    line); None where the planes do not meet in the frame."""
    segs = layout.fold_segments(projector_frame(projector_size))
    return [None if seg is None else apply_h(H_cam_from_proj[layout.fold_planes[j][0]], seg)
            for j, seg in enumerate(segs)]


def plane_polygons_proj(projector_size, planes, n_planes: int) -> list[np.ndarray]:
    """The projector frame split into planes: one convex polygon (k, 2) per plane.
    ``planes``: a :class:`PlaneLayout`, or a fold line / None (see :meth:`PlaneLayout.coerce`)."""
    layout = PlaneLayout.coerce(planes, n_planes)
    frame = projector_frame(projector_size)
    return [layout.polygon(frame, p) for p in range(layout.n_planes)]


def plane_polygon(projector_size: tuple[int, int], planes, n_planes: int,
                  plane: int, edge_inset: float = 0.0, fold_inset: float = 0.0) -> np.ndarray:
    """Convex outline (m, 2) of ``plane`` in projector pixels (pixel centres), shrunk by
    ``edge_inset`` from the frame edges and by ``fold_inset`` from each of its folds. Empty
    (0, 2) when nothing is left. ``planes`` as in :func:`plane_polygons_proj`."""
    layout = PlaneLayout.coerce(planes, n_planes)
    return layout.polygon(inset_frame(projector_size, edge_inset), plane, fold_inset)


def lit_polygon(projector_size: tuple[int, int], H_cam_from_proj: np.ndarray,
                planes) -> np.ndarray:
    """Outline (m, 2) float64 in camera px of what the projector lights, in boundary order.

    The projector frame's border, walked in order, is cut where it passes from one plane to
    another; each piece is mapped through its own plane's homography (neighbouring planes map
    their fold to the same camera line, so the pieces join there). ``planes``: a
    :class:`PlaneLayout`, or a fold line / None for one or two planes.
    """
    frame = projector_frame(projector_size)
    n = H_cam_from_proj.shape[0]
    if n == 1:
        return apply_h(H_cam_from_proj[0], frame)
    layout = PlaneLayout.coerce(planes, n)
    out = []
    for k in range(4):
        p, q = frame[k], frame[(k + 1) % 4]
        # Where each fold crosses this edge, then the plane of every piece between crossings.
        ts = [0.0, 1.0]
        for line in layout.folds:
            fp, fq = line_eval(line, p[None])[0], line_eval(line, q[None])[0]
            if (fp < 0) != (fq < 0) and fp != fq:
                ts.append(fp / (fp - fq))
        ts = np.unique(np.clip(ts, 0.0, 1.0))
        mids = p + 0.5 * (ts[:-1] + ts[1:])[:, None] * (q - p)
        labels = layout.label(mids[:, 0], mids[:, 1])
        out.append(apply_h(H_cam_from_proj[labels[0]], p[None])[0])
        for i in range(1, len(labels)):
            if labels[i] != labels[i - 1]:
                x = p + ts[i] * (q - p)
                a = apply_h(H_cam_from_proj[labels[i - 1]], x[None])[0]
                b = apply_h(H_cam_from_proj[labels[i]], x[None])[0]
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
