"""Step 2 of the PSF stage: where to measure PSFs, per layout (:func:`plan_samples`; see
:mod:`rtdefocus.calib.psf`)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from ...checks import check_choice
from ...errors import CalibrationError
from ...planar import clip_polygon, inset_frame
from ..file import Calibration
from .dots import dot_geometry, dot_sizes
from .pilot import RadiusModel, fold_code

log = logging.getLogger(__name__)

__all__ = ["LAYOUTS", "SamplePlan", "plan_samples", "pack_distance", "fold_segment", "fold_segments"]

LAYOUTS = ("default", "paper", "dense")


def fold_segments(calib: Calibration, inset: float = 0.0) -> list[np.ndarray | None]:
    """Per fold of ``calib.layout``, the end points (2, 2) of the part of its line that really
    separates its two planes (:meth:`PlaneLayout.fold_segments`) inside the frame of pixel
    centres shrunk by ``inset``; None where they do not meet there. The ends are ordered along
    the line's direction (-b, a)."""
    if calib.n_planes == 1:
        return []
    return calib.layout.fold_segments(inset_frame(calib.projector_size, inset))


def fold_segment(calib: Calibration, inset: float = 0.0) -> np.ndarray | None:
    """End points (2, 2) of the fold of a two-plane calibration inside the frame shrunk by
    ``inset``; None for one plane or no crossing. Any number of planes: :func:`fold_segments`."""
    if calib.n_planes != 2:
        return None
    return fold_segments(calib, inset)[0]


@dataclass
class SamplePlan:
    """Where to measure PSFs and how to blend them.

    points : (N, 2) int projector pixels; planes : (N,) int (the plane, or
    :func:`~.pilot.fold_code` (j) on fold j, used by its two planes (``FOLD`` for the one fold
    of two planes); 0 for every sample when ``cross_fold``); kinds : (N,) str; radius : (N,) float, pilot
    prediction; quads : for ``paper``, per region a list of 4-index quads (cyclic order) used
    for bilinear blending, each with the half-plane it serves; metric : per region a 2×2
    matrix M, the triangulation is made of the points M x (default layout: stretched along the
    blur gradient, so triangles join neighbouring lines of equal blur, not far ones).
    """

    layout: str
    cross_fold: bool
    points: np.ndarray
    planes: np.ndarray
    kinds: np.ndarray
    radius: np.ndarray
    radius_signed: np.ndarray | None = None
    quads: dict = field(default_factory=dict)
    metric: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)


def _snap(pts: np.ndarray, size) -> np.ndarray:
    wp, hp = size
    p = np.rint(pts).astype(int)
    p[:, 0] = np.clip(p[:, 0], 0, wp - 1)
    p[:, 1] = np.clip(p[:, 1], 0, hp - 1)
    return p


def _dedupe(pts: np.ndarray, kinds: list, min_dist: float) -> tuple[np.ndarray, list]:
    keep_p, keep_k = [], []
    for p, k in zip(pts, kinds, strict=True):
        if keep_p and np.min(np.hypot(*(np.array(keep_p) - p).T)) < min_dist:
            continue
        keep_p.append(p)
        keep_k.append(k)
    return np.array(keep_p, int).reshape(-1, 2), keep_k


def _along(a: np.ndarray, b: np.ndarray, spacing: float, include_ends=True) -> np.ndarray:
    n = max(1, int(math.ceil(np.hypot(*(b - a)) / spacing)))
    t = np.linspace(0, 1, n + 1)
    if not include_ends:
        t = t[1:-1]
    return a + t[:, None] * (b - a)


def pack_distance(r: np.ndarray, dot_size: int | str = "auto") -> np.ndarray:
    """Smallest Chebyshev distance (px) of two dots of predicted radius r in one pattern."""
    r = np.asarray(r, np.float64)
    sup, win = dot_geometry(r, dot_sizes(r, dot_size))
    return win + sup + 1


def _fold_offset(model: RadiusModel, feet: np.ndarray, plane: int) -> np.ndarray:
    """How far from the fold a fold-side dot goes: just farther than the local blur (from the
    pilot, with a margin for its error and the pixel snap), so that its light stays on its
    own plane. Pixels between these samples and the fold take the nearest fold-side kernel;
    the radius changes by (slope × offset) over that strip, ~0.05 px on the simulator."""
    return np.ceil(1.1 * model(feet, plane) + 2.0)


def _thin(pts: np.ndarray, rank: np.ndarray, radius: np.ndarray, dot_size) -> np.ndarray:
    """Keep-mask of the samples: a sample is dropped when it would share a dot's window with a
    kept sample of a more important kind (lower ``rank``: corners, then fold samples) — it is
    redundant with it, and the set then fits in fewer patterns. Samples of the same kind are
    never dropped for each other (a steep blur gradient may need a second pattern)."""
    pd = pack_distance(radius, dot_size)
    keep = np.zeros(len(pts), bool)
    for i in np.argsort(rank, kind="stable"):
        k = np.flatnonzero(keep & (rank < rank[i]))
        if len(k):
            d = np.max(np.abs(pts[k] - pts[i]), axis=1)
            if np.any(d < np.maximum(pd[k], pd[i])):
                continue
        keep[i] = True
    return keep


def _fold_samples(calib: Calibration, model: RadiusModel, plane: int, j: int,
                  seg: np.ndarray, count: int | None, spacing: float, edge_inset: float
                  ) -> np.ndarray:
    """Samples along fold ``j`` (its segment ``seg``) on ``plane``'s side. The two planes'
    samples are staggered by half a step along the fold (the plane on its negative side takes
    the ends), so that both sides fit in one pattern although each is only just farther from
    the fold than the blur."""
    length = float(np.hypot(*(seg[1] - seg[0])))
    n = count if count is not None else max(2, int(math.ceil(length / spacing)) + 1)
    first = plane == calib.layout.fold_planes[j][0]
    t = np.linspace(0, 1, n) if first else (np.arange(n - 1) + 0.5) / (n - 1)
    feet = seg[0] + t[:, None] * (seg[1] - seg[0])
    d = _fold_offset(model, feet, plane)
    pts = feet + d[:, None] * calib.layout.inward(j, plane)
    # Keep them inside the frame: shift along the fold if the offset pushed them out.
    wp, hp = calib.projector_size
    lo, hi = np.array([edge_inset, edge_inset]), np.array([wp - 1 - edge_inset, hp - 1 - edge_inset])
    ok = np.all((pts >= lo) & (pts <= hi), axis=1)
    # Near a vertex, as far from the plane's other folds as from this one (its light stays on
    # its plane); the plane's corner, inset from both folds, samples the vertex.
    layout = calib.layout
    for k in layout.bounding_folds(plane):
        if k != j:
            ok &= layout.fold_distance(k, pts, plane) >= d
    return pts[ok]


def _separate_corners(points: np.ndarray, planes: np.ndarray, kinds: np.ndarray,
                      model: RadiusModel, centroids: dict, dot_size, size) -> np.ndarray:
    """Make the planes' corners fit in one dot pattern (in place); returns a keep-mask.

    Where three or more planes meet at a vertex, their corners there face each other across
    several folds, closer than two dots may be in one pattern (two planes' corners, each half a
    dot spacing from their one fold, always fit). Such a corner is moved into its plane,
    towards the centroid of its outline, until they fit; of two corners of one plane closer
    than that (a fold meeting the frame near its corner), the second is dropped: the first
    stands for both."""
    keep = np.ones(len(points), bool)
    idx = np.flatnonzero(kinds == "corner")
    pts = points[idx].astype(np.float64)
    pl = planes[idx]
    for _ in range(20):
        r = np.array([model(q[None], int(p))[0] for q, p in zip(pts, pl, strict=True)])
        sup, win = dot_geometry(r, dot_sizes(r, dot_size))
        push = np.zeros_like(pts)
        for a in range(len(idx)):
            for b in range(a + 1, len(idx)):
                if not (keep[idx[a]] and keep[idx[b]]):
                    continue
                need = max(win[a] + sup[b], win[b] + sup[a]) + 2     # pack_patterns' test
                d = float(np.max(np.abs(pts[a] - pts[b])))
                if d >= need:
                    continue
                if pl[a] == pl[b]:
                    keep[idx[b]] = False
                    continue
                for i in (a, b):
                    u = centroids[int(pl[i])] - pts[i]
                    n = float(np.hypot(*u))
                    if n > 1e-9:
                        push[i] += min((need - d) / 2 + 1, n) * u / n
        if not push.any():
            break
        pts += push
    points[idx] = _snap(pts, size)
    return keep


def _iso_stretch(poly: np.ndarray, coef: np.ndarray, radius_step: float,
                 max_spacing: float) -> np.ndarray:
    """2×2 metric that makes the iso-grid's cells square: stretch along the blur gradient by
    (spacing along lines / spacing between lines). Barycentric weights are affine-invariant,
    so this only changes *which* triangles are formed."""
    g = np.asarray(coef[:2], np.float64)
    gn = float(np.hypot(*g))
    if gn < 1e-9:
        return np.eye(2)
    ghat = g / gn
    t = poly @ ghat
    span = float(t.max() - t.min())
    n = max(1, int(math.ceil(gn * span / radius_step)), int(math.ceil(span / max_spacing)))
    stretch = float(np.clip(max_spacing / (span / n), 1.0, 8.0))
    return np.eye(2) + (stretch - 1.0) * np.outer(ghat, ghat)


def _iso_grid(poly: np.ndarray, coef: np.ndarray, radius_step: float, max_spacing: float
              ) -> np.ndarray:
    """Samples on lines of equal predicted radius (r = gx x + gy y + c), ``radius_step`` apart
    in radius (and at most ``max_spacing`` apart), each line sampled every ``max_spacing``
    at common positions so neighbouring lines form near-rectangular cells; clipped to the
    convex ``poly`` whose outline (chord ends) they also cover."""
    g = np.asarray(coef[:2], np.float64)
    gn = float(np.hypot(*g))
    ghat = g / gn if gn > 1e-9 else np.array([1.0, 0.0])
    ehat = np.array([-ghat[1], ghat[0]])
    t, sv = poly @ ghat, poly @ ehat
    span = float(t.max() - t.min())
    n = max(1, int(math.ceil(gn * span / radius_step)), int(math.ceil(span / max_spacing)))
    s_span = float(sv.max() - sv.min())
    m = max(1, int(math.ceil(s_span / max_spacing)))
    s_grid = sv.min() + np.linspace(0, 1, m + 1) * s_span
    out = []
    for ti in t.min() + np.linspace(0, 1, n + 1) * span:
        # The chord of the convex polygon on the line ghat . x = ti.
        chord = clip_polygon(clip_polygon(poly, (ghat[0], ghat[1], -ti - 1e-6)),
                             (-ghat[0], -ghat[1], ti - 1e-6))
        if len(chord) == 0:
            continue
        cs = chord @ ehat
        lo, hi = float(cs.min()), float(cs.max())
        step = s_span / m          # grid points closer than half a step to a chord end go
        ss = np.concatenate([[lo], s_grid[(s_grid > lo + 0.5 * step) &
                                          (s_grid < hi - 0.5 * step)], [hi]])
        out.append(ti * ghat + ss[:, None] * ehat)
    return np.vstack(out) if out else np.zeros((0, 2))


def _refine(pts: np.ndarray, kinds: list, rfun, radius_step: float, max_spacing: float,
            max_points: int) -> tuple[np.ndarray, list]:
    """Longest-edge bisection of the Delaunay triangulation until, in every triangle, the
    predicted radius varies by <= radius_step (checked at vertices and edge midpoints) and no
    edge is longer than max_spacing."""
    # scipy loads on first use (~1 s): `import rtdefocus.calib` (the player loads Calibration) stays fast.
    from scipy.spatial import Delaunay

    pts = pts.astype(np.float64)
    for _ in range(40):
        if len(pts) >= max_points or len(pts) < 3:
            break
        tri = Delaunay(pts)
        S = tri.simplices
        P = pts[S]                                               # (T, 3, 2)
        r = rfun(P.reshape(-1, 2)).reshape(-1, 3)
        e_idx = np.array([[0, 1], [1, 2], [2, 0]])
        A, B = P[:, e_idx[:, 0]], P[:, e_idx[:, 1]]              # (T, 3, 2)
        L = np.hypot(*(B - A).transpose(2, 0, 1))                # (T, 3)
        M = (A + B) / 2
        rm = rfun(M.reshape(-1, 2)).reshape(-1, 3)
        dr = np.abs(r[:, e_idx[:, 0]] - r[:, e_idx[:, 1]])
        # An edge is split where the radius changes too much along it, or bends (a wall
        # crossing the focus), or where it is too long; the radius criterion splits the edge
        # that changes most, so triangles may stay long along lines of equal blur.
        lin_err = np.abs(rm - (r[:, e_idx[:, 0]] + r[:, e_idx[:, 1]]) / 2)
        score = np.maximum(dr / radius_step, 2 * lin_err / radius_step)
        split_r = (score.max(1) > 1) & (L[np.arange(len(L)), score.argmax(1)] > 6.0)
        split_l = ~split_r & (L.max(1) > max_spacing)
        if not (split_r.any() or split_l.any()):
            break
        which = np.where(split_r, score.argmax(1), L.argmax(1))
        bad = split_r | split_l
        new = M[np.flatnonzero(bad), which[bad]]
        new = np.unique(np.rint(new), axis=0)
        d = np.min(np.hypot(new[:, None, 0] - pts[None, :, 0], new[:, None, 1] - pts[None, :, 1]),
                   axis=1)
        new = new[d >= 3.0]
        if len(new) == 0:
            break
        new = new[: max_points - len(pts)]
        pts = np.vstack([pts, new])
        kinds = kinds + ["refine"] * len(new)
    return pts, kinds


def plan_samples(calib: Calibration, model: RadiusModel, layout: str = "default", *,
                 cross_fold: bool = False, fold_samples: int | None = None,
                 radius_step: float = 0.5, max_spacing: float = 150.0, dense_spacing: float = 50.0,
                 edge_inset: float = 2.0, max_points: int = 150,
                 dot_size: int | str = "auto") -> SamplePlan:
    """Choose the PSF sample points of a layout (see the module docstring).

    Parameters
    ----------
    calib : Calibration with the geometry section.
    model : RadiusModel from :func:`pilot_radius` (fitted per plane, or as one region when
        ``cross_fold``).
    layout : ``"default"`` | ``"paper"`` | ``"dense"``.
    cross_fold : lay out and blend over the whole frame as one region (ignore the planes).
    fold_samples : samples along each fold per side (default: one every ``max_spacing / 2``).
    radius_step : default layout: predicted radius step between lines of equal blur (px).
    max_spacing : default layout: largest spacing along and across those lines (px).
    dense_spacing : dense layout: grid step (px).
    edge_inset : distance of the samples from the frame edges (px).
    max_points : cap on the samples per region (refinement of a non-affine radius only).
    dot_size : as in :func:`calibrate_psf` (sets how close dots may be in one pattern).

    Samples closer than two dots may be in one pattern are thinned out (corners first, then
    fold samples, then the rest), so that a layout fits in as few patterns as possible.
    """
    check_choice(layout, LAYOUTS, "layout")
    size = calib.projector_size
    one_region = cross_fold or calib.n_planes == 1
    regions = [0] if one_region else list(range(calib.n_planes))
    segs = [] if one_region else fold_segments(calib, inset=edge_inset)
    all_pts, all_planes, all_kinds = [], [], []
    metric: dict = {}
    centroids: dict = {}

    fold_pts_paper = None
    if layout == "paper" and not one_region:
        if all(seg is None for seg in segs):
            raise CalibrationError("the fold does not cross the projector frame; calibrate the "
                                   "geometry again or use a single plane")
        # The two ends of every fold, shared by its two planes.
        fold_pts_paper = [(_snap(seg, size), fold_code(j))
                          for j, seg in enumerate(segs) if seg is not None]

    for p in regions:
        if one_region:
            poly = inset_frame(size, edge_inset)
            def rfun(xy):
                return model(xy, 0)
        else:
            mine = [j for j in calib.layout.bounding_folds(p) if segs[j] is not None]
            feet = np.vstack([segs[j] for j in mine]) if mine else np.zeros((0, 2))
            d_max = 0.0
            if len(feet):
                pd = float(pack_distance(model(feet, p), dot_size).max())
                # Corners: the two planes' fold-side corners face each other across the fold;
                # half a dot spacing each keeps them in one pattern. The paper's corners keep
                # a full spacing from its fold points.
                d_max = pd + 2 if layout == "paper" else max(
                    float(_fold_offset(model, feet, p).max()), math.ceil(pd / 2) + 1)
            poly = calib.layout.polygon(inset_frame(size, edge_inset), p, d_max)
            def rfun(xy, p=p):
                return model(xy, p)
        centroids[p] = poly.mean(axis=0) if len(poly) else None
        if len(poly) < 3:
            raise CalibrationError(f"plane {p} leaves no room for PSF samples after insetting "
                                   "from the frame and its folds; is a fold near the frame edge, "
                                   "or is the plane a sliver? Calibrate the geometry again "
                                   "(fewer planes)")
        kinds: list[str]
        if layout == "paper":
            pts = poly.copy()
            kinds = ["corner"] * len(pts)
        elif layout == "dense":
            wp, hp = size
            gx = np.arange(edge_inset, wp - edge_inset, dense_spacing)
            gy = np.arange(edge_inset, hp - edge_inset, dense_spacing)
            gx += (wp - 1 - edge_inset - gx[-1]) / 2 - (gx[0] - edge_inset) / 2
            gy += (hp - 1 - edge_inset - gy[-1]) / 2 - (gy[0] - edge_inset) / 2
            G = np.array(np.meshgrid(gx, gy)).reshape(2, -1).T
            inside = np.ones(len(G), bool)
            for i in range(len(poly)):        # inside the convex (inset) polygon
                a, b = poly[i], poly[(i + 1) % len(poly)]
                inside &= ((b[0] - a[0]) * (G[:, 1] - a[1]) - (b[1] - a[1]) * (G[:, 0] - a[0])) \
                    >= -1e-9 * _orient(poly)
            pts = np.vstack([poly, G[inside]])
            kinds = ["corner"] * len(poly) + ["grid"] * int(inside.sum())
        else:  # default
            base = [poly]
            kinds = ["corner"] * len(poly)
            for j in [] if one_region else mine:
                fs = _fold_samples(calib, model, p, j, segs[j], fold_samples, max_spacing / 2,
                                   edge_inset)
                base.append(fs)
                kinds += ["fold-side"] * len(fs)
            reg = 0 if one_region else p
            if model.kind.get(reg) in ("affine", "abs-affine", "constant"):
                grid = _iso_grid(poly, model.coef[reg], radius_step, max_spacing)
                metric[p] = _iso_stretch(poly, model.coef[reg], radius_step, max_spacing)
                base.append(grid)
                kinds += ["grid"] * len(grid)
                pts = np.vstack(base)
            else:  # radius not affine: refine a triangulation where it varies
                for i in range(len(poly)):
                    mid = _along(poly[i], poly[(i + 1) % len(poly)], max_spacing, False)
                    base.append(mid)
                    kinds += ["edge"] * len(mid)
                pts, kinds = _refine(np.vstack(base), kinds, rfun, radius_step, max_spacing,
                                     max_points)
        pts_i, kinds = _dedupe(_snap(pts, size), list(kinds), 3.0)
        all_pts.append(pts_i)
        all_planes.append(np.full(len(pts_i), p, int))
        all_kinds += kinds

    points = np.vstack(all_pts)
    planes = np.concatenate(all_planes)
    kinds_arr = np.array(all_kinds)
    if not one_region:
        keep = _separate_corners(points, planes, kinds_arr, model, centroids, dot_size, size)
        points, planes, kinds_arr = points[keep], planes[keep], kinds_arr[keep]
    if layout != "paper":
        # Thin across all planes, most important kinds first.
        radius = np.array([model(pt[None].astype(np.float64), 0 if one_region else int(pl))[0]
                           for pt, pl in zip(points, planes, strict=True)])
        rank = np.array([{"corner": 0, "fold-side": 1}.get(k, 2) for k in kinds_arr])
        keep = _thin(points, rank, radius, dot_size)
        points, planes, kinds_arr = points[keep], planes[keep], kinds_arr[keep]
    for ends, code in fold_pts_paper or []:
        points = np.vstack([points, ends])
        planes = np.concatenate([planes, [code, code]])
        kinds_arr = np.concatenate([kinds_arr, ["fold", "fold"]])
    radius = np.empty(len(points))
    signed = np.empty(len(points))
    for p in np.unique(planes):
        sel = planes == p
        radius[sel] = model(points[sel].astype(np.float64), 0 if one_region else int(p))
        signed[sel] = model.signed(points[sel].astype(np.float64), 0 if one_region else int(p))
    plan = SamplePlan(layout=layout, cross_fold=cross_fold, points=points.astype(np.int32),
                      planes=planes.astype(np.int32), kinds=kinds_arr, radius=radius,
                      radius_signed=signed,
                      metric=metric)
    if layout == "paper":
        plan.quads = _paper_quads(calib, plan, one_region)
    return plan


def _orient(poly: np.ndarray) -> float:
    """+1 for a counter-clockwise polygon in (x, y) (shoelace sign), -1 for clockwise."""
    x, y = poly[:, 0], poly[:, 1]
    return 1.0 if (x * np.roll(y, -1) - np.roll(x, -1) * y).sum() >= 0 else -1.0


def _paper_quads(calib: Calibration, plan: SamplePlan, one_region: bool) -> dict:
    """Bilinear quads of the paper layout: per plane its corner quad and, for a plane with one
    fold (two planes), between the quad's fold-side edge and the fold, a strip quad closed by
    the two fold points. A plane that is not a quadrilateral is blended on triangles."""
    quads: dict = {}
    regions = [0] if one_region else list(range(calib.n_planes))
    for p in regions:
        idx = np.flatnonzero(plan.planes == p)
        if len(idx) != 4:
            log.warning("paper layout: plane %d is not a quadrilateral (%d corners); its "
                        "kernels are blended on triangles instead", p, len(idx))
            continue
        quads[p] = [("main", idx.tolist())]
        if one_region:
            continue
        folds = calib.layout.bounding_folds(p)
        fold_idx = np.flatnonzero(np.isin(plan.planes, [fold_code(j) for j in folds]))
        if len(folds) != 1 or len(fold_idx) != 2:
            continue
        pts = plan.points.astype(np.float64)
        dist = calib.layout.fold_distance(folds[0], pts[idx], p)
        near = idx[np.argsort(dist)[:2]]                   # the two fold-side corners
        # Order the strip quad cyclically: corner A, corner B, fold point near B, near A.
        fa = fold_idx[np.argmin(np.hypot(*(pts[fold_idx] - pts[near[0]]).T))]
        fb = fold_idx[fold_idx != fa][0]
        quads[p].append(("strip", [int(near[0]), int(near[1]), int(fb), int(fa)]))
    return quads
