"""Line crossings -> how many planes, which crossing is on which, and where they meet.

Step 4 of the geometry stage (:mod:`.geometry`) for any number of planes:

1. **Candidates** (:func:`sequential_homographies`): RANSAC finds the homography with the
   largest consensus among the crossings, its inliers are set aside, and RANSAC runs again on
   the rest, until what is left is small. On a still set-up each candidate is one plane (or, with
   a strongly distorting lens, a leftover strip at the frame's edge).
2. **Labels on the projector grid** (:func:`clean_labels`): the crossings sit on a grid (one
   column per vertical line, one row per horizontal line). Each takes the candidate that maps it
   best, then a majority filter and "one connected region per plane" clean the labels: a plane is
   a contiguous region of the projector frame.
3. **Folds carry kinks** (:func:`boundary_kinks`): where the label changes between two
   neighbouring crossings of one projected line, that line crosses the fold, so it must bend
   there in the camera. A candidate plane is kept only while it is a contiguous region that
   meets a kept plane along a boundary where the lines bend (:func:`select_planes`). A set-up
   that moved between captures makes candidates that interleave line by line, with no bends
   between them; lens distortion makes candidates with no bends at all — neither is a plane.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ...errors import CalibrationError
from ...planar import MAX_PLANES, apply_h
from .fold import Kink
from .homography import fit_homography

log = logging.getLogger(__name__)

__all__ = ["CrossingGrid", "sequential_homographies", "clean_labels", "boundary_kinks",
           "PlaneEvidence", "select_planes"]


# --------------------------------------------------------------------------- the grid
@dataclass
class CrossingGrid:
    """Where each crossing sits on the grid of projected lines.

    Attributes
    ----------
    ix, iy : (n,) int column (vertical line) and row (horizontal line) of each crossing.
    shape : (rows, columns) of the grid.
    cell : (rows, columns) int index of the crossing in each cell, -1 where none was seen.
    line_v, line_h : (columns,) and (rows,) index in ``LineDetection.lines`` of each grid
        column's vertical line and each row's horizontal line (-1 when not detected).
    """

    ix: np.ndarray
    iy: np.ndarray
    shape: tuple[int, int]
    cell: np.ndarray
    line_v: np.ndarray
    line_h: np.ndarray

    @classmethod
    def build(cls, pts_proj_xy: np.ndarray, pairs: np.ndarray) -> CrossingGrid:
        xs, ix = np.unique(np.round(pts_proj_xy[:, 0], 3), return_inverse=True)
        ys, iy = np.unique(np.round(pts_proj_xy[:, 1], 3), return_inverse=True)
        cell = np.full((len(ys), len(xs)), -1, np.int64)
        cell[iy, ix] = np.arange(len(ix))
        line_v = np.full(len(xs), -1, np.int64)
        line_h = np.full(len(ys), -1, np.int64)
        line_v[ix] = pairs[:, 0]
        line_h[iy] = pairs[:, 1]
        return cls(ix.ravel(), iy.ravel(), (len(ys), len(xs)), cell, line_v, line_h)

    def image(self, values: np.ndarray, fill: int = -1) -> np.ndarray:
        """Per-crossing int values as a grid image (``fill`` where no crossing)."""
        img = np.full(self.shape, fill, np.int64)
        img[self.iy, self.ix] = values
        return img


# --------------------------------------------------------------------------- candidates
def sequential_homographies(pts_proj_xy: np.ndarray, pts_cam_xy: np.ndarray, *, threshold: float,
                            min_count: int, max_planes: int = MAX_PLANES):
    """Homographies of decreasing consensus: RANSAC, set the inliers aside, again.

    Returns
    -------
    list of (H_cam_from_proj (3, 3), inliers (n,) bool over all crossings) — at least one
    (:func:`~.homography.fit_homography` raises on the first when nothing fits), in the order
    found; stops when fewer than ``min_count`` crossings are left or none fit.
    """
    n = len(pts_proj_xy)
    rest = np.ones(n, bool)
    out = []
    while len(out) < max_planes and rest.sum() >= max(min_count, 8):
        idx = np.flatnonzero(rest)
        try:
            H, _, _ = fit_homography(pts_proj_xy[idx], pts_cam_xy[idx], threshold=threshold,
                                     what=f"candidate plane {len(out) + 1}")
        except CalibrationError:
            if not out:
                raise
            break
        err = np.linalg.norm(apply_h(H, pts_proj_xy) - pts_cam_xy, axis=1)
        inl = rest & (err < threshold)
        if inl.sum() < max(min_count, 8):
            break
        out.append((H, inl))
        rest &= ~inl
    return out


def reprojection_errors(Hs, pts_proj_xy: np.ndarray, pts_cam_xy: np.ndarray) -> np.ndarray:
    """(n, k) camera px distance of each crossing from its image under each homography."""
    return np.stack([np.linalg.norm(apply_h(H, pts_proj_xy) - pts_cam_xy, axis=1) for H in Hs],
                    axis=1)


# --------------------------------------------------------------------------- labels
def _majority(img: np.ndarray, n_labels: int, size: int = 5) -> np.ndarray:
    """Most frequent label >= 0 in each ``size`` x ``size`` window (-1 where none)."""
    from scipy.ndimage import uniform_filter

    counts = np.stack([uniform_filter((img == k).astype(np.float32), size, mode="constant")
                       for k in range(n_labels)])
    best = counts.argmax(axis=0)
    return np.where(counts.max(axis=0) > 0, best, -1)


def clean_labels(grid: CrossingGrid, raw: np.ndarray, n_labels: int):
    """Spatially clean per-crossing plane labels on the projector grid.

    A 5 x 5 majority vote, then each plane keeps only its largest 8-connected region; crossings
    cut off that way take the majority of their neighbours (repeated until none is left).

    Parameters
    ----------
    raw : (n,) int label of each crossing (-1: none fits).

    Returns
    -------
    labels : (n,) int cleaned labels (-1 only where no labelled crossing is near).
    kept : (n_labels,) float, share of the crossings labelled k that the cleaning leaves at k
        (near 1 for a plane, low for candidates that interleave line by line).
    """
    from scipy.ndimage import label as components

    img = grid.image(raw)
    present = grid.cell >= 0
    maj = np.where(present, _majority(img, n_labels), -1)
    # Keep a cell's own label where the vote ties with it (cells along a fold).
    out = maj.copy()
    eight = np.ones((3, 3), bool)
    for k in range(n_labels):
        comp, m = components(out == k, structure=eight)
        if m > 1:
            sizes = np.bincount(comp.ravel())[1:]
            out[(comp > 0) & (comp != 1 + int(np.argmax(sizes)))] = -1
    for _ in range(max(grid.shape)):
        hole = present & (out < 0)
        if not hole.any():
            break
        fill = _majority(out, n_labels, 3)
        if not (fill[hole] >= 0).any():
            break
        out[hole] = fill[hole]
    labels = out[grid.iy, grid.ix]
    kept = np.array([float(np.mean(labels[raw == k] == k)) if (raw == k).any() else 0.0
                     for k in range(n_labels)])
    return labels, kept


# --------------------------------------------------------------------------- kinks on boundaries
def boundary_kinks(grid: CrossingGrid, labels: np.ndarray, pts_cam_xy: np.ndarray,
                   kinks: list[Kink], a: int, b: int):
    """Where the projected lines cross from plane ``a`` to plane ``b``, and the kinks there.

    Along each projected line (a row or a column of the grid), two neighbouring crossings
    labelled ``a`` and ``b`` mean the line crosses their fold between them; a kink of that line
    between their camera points (with one grid step of slack each way) is the fold's trace.

    Returns
    -------
    crossings : int, how many times a line passes from ``a`` to ``b``.
    matched : sorted list of indices into ``kinks`` found at those places.
    """
    by_line: dict[int, list[int]] = {}
    for i, kk in enumerate(kinks):
        by_line.setdefault(kk.line, []).append(i)
    img = grid.image(labels)
    n_cross = 0
    matched: set[int] = set()
    for axis in ("h", "v"):
        lab = img if axis == "h" else img.T
        cell = grid.cell if axis == "h" else grid.cell.T
        line_of = grid.line_h if axis == "h" else grid.line_v
        coord = 0 if axis == "h" else 1       # the camera coordinate a kink's ``t`` follows
        for r in range(lab.shape[0]):
            cols = np.flatnonzero(cell[r] >= 0)
            if len(cols) < 2:
                continue
            lr = lab[r, cols]
            for u in np.flatnonzero(((lr[:-1] == a) & (lr[1:] == b)) | ((lr[:-1] == b) & (lr[1:] == a))):
                if cols[u + 1] - cols[u] > 2:        # a gap in the detection, not a boundary
                    continue
                n_cross += 1
                p, q = pts_cam_xy[cell[r, cols[u]], coord], pts_cam_xy[cell[r, cols[u + 1]], coord]
                lo, hi = min(p, q) - abs(q - p), max(p, q) + abs(q - p)
                for i in by_line.get(int(line_of[r]), []):
                    t = kinks[i].point_cam_xy[coord]
                    if lo <= t <= hi:
                        matched.add(i)
    return n_cross, sorted(matched)


# --------------------------------------------------------------------------- model selection
@dataclass
class PlaneEvidence:
    """Why a candidate plane was kept or not (meta["geometry"]["candidates"])."""

    crossings: int
    share: float
    kept: float
    kinks: int = 0
    kink_share: float = 0.0
    accepted: bool = False
    reason: str = ""
    neighbours: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"crossings": self.crossings, "share": round(self.share, 4),
                "kept_after_cleaning": round(self.kept, 4), "kinks": self.kinks,
                "kink_share": round(self.kink_share, 3), "accepted": self.accepted,
                "reason": self.reason}


def label_crossings(Hs, pts_proj_xy, pts_cam_xy, threshold: float) -> np.ndarray:
    """Each crossing's best homography, -1 where none maps it within 4 × ``threshold``."""
    err = reprojection_errors(Hs, pts_proj_xy, pts_cam_xy)
    raw = err.argmin(axis=1)
    return np.where(err.min(axis=1) < 4 * threshold, raw, -1)


def select_planes(candidates, grid: CrossingGrid, pts_proj_xy, pts_cam_xy, kinks: list[Kink], *,
                  threshold: float, strict: bool = True, want: int | None = None):
    """Keep the candidates that are planes (see the module docstring).

    Parameters
    ----------
    candidates : from :func:`sequential_homographies`; the first is always kept.
    strict : the thresholds of ``planes="auto"`` (a plane holds >= 3 % of the crossings and
        >= 5 kinks on its fold); False relaxes them for a count the user forced (>= 0.5 % and
        3 kinks; contiguity and kinks are still required).
    want : stop once this many planes are kept.

    Returns
    -------
    kept : list of indices into ``candidates``.
    evidence : list of :class:`PlaneEvidence`, one per candidate.
    """
    min_share, min_kinks = (0.03, 5) if strict else (0.005, 3)
    Hs = [c[0] for c in candidates]
    kept = [0]
    evidence = [PlaneEvidence(int(candidates[0][1].sum()), float(candidates[0][1].mean()), 1.0,
                              accepted=True, reason="largest consensus")]
    evidence += [None] * (len(candidates) - 1)

    def evaluate(k: int) -> PlaneEvidence:
        trial = kept + [k]
        raw = label_crossings([Hs[i] for i in trial], pts_proj_xy, pts_cam_xy, threshold)
        labels, share_kept = clean_labels(grid, raw, len(trial))
        me = len(trial) - 1
        ev = PlaneEvidence(int((labels == me).sum()), float(np.mean(labels == me)),
                           float(share_kept[me]))
        if ev.share < min_share:
            ev.reason = f"holds {100 * ev.share:.1f} % of the crossings (< {100 * min_share:g} %)"
            return ev
        if ev.kept < 0.7:
            ev.reason = (f"not one region: only {100 * ev.kept:.0f} % of its crossings survive the "
                         "spatial cleaning")
            return ev
        best = (0, 0.0, 0)
        for other in range(me):
            n_cross, matched = boundary_kinks(grid, labels, pts_cam_xy, kinks, other, me)
            if n_cross:
                best = max(best, (len(matched), len(matched) / n_cross, other))
        ev.kinks, ev.kink_share = best[0], best[1]
        if ev.kinks < min_kinks or ev.kink_share < 0.3:
            ev.reason = (f"no fold: {ev.kinks} kinks where the lines cross into it "
                         f"({100 * ev.kink_share:.0f} % of the crossings)")
            return ev
        ev.accepted, ev.reason = True, "contiguous, kinks along its fold"
        ev.neighbours = [trial[best[2]]]
        return ev

    # In order of consensus; passes repeat while one adds a plane, since a plane meets the
    # kept ones only once the plane between them is kept.
    pending = list(range(1, len(candidates)))
    grew = True
    while grew and pending:
        grew = False
        for k in list(pending):
            if want is not None and len(kept) >= want:
                break
            evidence[k] = evaluate(k)
            if evidence[k].accepted:
                kept.append(k)
                pending.remove(k)
                grew = True
    for k in pending:
        if evidence[k] is None:
            evidence[k] = PlaneEvidence(int(candidates[k][1].sum()),
                                        float(candidates[k][1].mean()), 0.0,
                                        reason=f"{want} planes asked for")
    log.debug("plane candidates: %s", [e.as_dict() for e in evidence])
    return kept, evidence
