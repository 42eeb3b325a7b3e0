"""The geometry stage's fit: detected lines -> planes, homographies, folds (any number of planes).

:func:`fit_geometry` works on a :class:`~.structured_light.LineDetection` only, so a wrapper can
run it again on corrected detections (lens distortion). Steps (DESIGN.md §4, docs/internals.md):

1. **Kinks** on every line, several per line (:func:`~.fold.find_kinks`).
2. **Planes** from the line crossings (:mod:`.planes`): sequential RANSAC of homographies,
   labels cleaned on the projector grid, a candidate kept only while it is a contiguous region
   meeting a kept plane along a boundary where the lines bend (``planes="auto"``), or the count
   the caller forces.
3. **Camera folds**: for each pair of planes that meet, the kinks where the lines cross from one
   to the other, RANSAC and total least squares (:func:`~.fold.fit_fold`), as for one fold.
4. **Homographies**: per plane, the crossings inside it by more than ``fold_band`` from each of
   its folds (camera layout), normalised DLT in RANSAC and LM (:func:`~.homography.fit_homography`).
5. **Projector folds**: each camera fold's visible part mapped back through both of its planes'
   inverse homographies (:func:`~.fold.fold_to_projector`), which must agree.
6. **Residual** (``residual=True``): per plane, a smooth displacement (:mod:`rtdefocus.residual`)
   fitted to what its crossings leave off its homography, for walls that are planes only
   nearly; the projector folds of step 5 then map through the full map (homography plus
   residual).
7. **Numbering**: planes by the projector-space centroid x (ties within 5 % of the width by
   centroid y); two planes keep plane 0 on the negative side of the fold, oriented by
   :func:`~.planar.canonical_line`. ``fold_planes[j]`` = [negative side, positive side], the
   same planes on the same sides in the camera.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field

import numpy as np

from ...errors import CalibrationError, InputError
from ...planar import (
    MAX_PLANES,
    PlaneLayout,
    apply_h,
    canonical_line,
    line_eval,
    lit_polygon,
    normalise_line,
    segment_in_mask,
    tls_line,
)
from ...residual import displacement, fit_residual, proj_from_cam
from .dense_fit import (
    fit_plane_homography,
    outline_without,
    plane_samples,
    prefilter,
    unfit_region,
)
from .fold import Kink, find_kinks, fit_fold, fold_to_projector
from .homography import fit_homography, line_crossings
from .planes import (
    CrossingGrid,
    boundary_kinks,
    clean_labels,
    label_crossings,
    select_planes,
    sequential_homographies,
)
from .structured_light import LineDetection

# The stage's logger: lens.fit_with_lens holds back the first (distorted) fit's warnings there.
log = logging.getLogger(__package__ + ".geometry")

__all__ = ["GeometryDetail", "fit_geometry", "check_planes_option"]

#: Largest distance (projector px) between a fold's two images (one per plane) before the
#: result is refused.
MAX_FOLD_DISAGREEMENT = 3.0
#: A plane's residual field larger than this (camera px) somewhere in the frame is reported: the
#: wall is then far from a plane (or two surfaces were taken for one).
MAX_RESIDUAL_PX = 20.0
#: A residual field within this (camera px) everywhere is the crossings' noise: none is kept.
MIN_RESIDUAL_PX = 0.5
#: Share of the valid dense map that must fit no plane before the lit outline is cut: less is
#: blur at the folds and edges, not a surface.
MIN_UNFIT = 0.01


@dataclass
class GeometryDetail:
    """What the geometry stage saw, for diagnostics (kept in memory, never saved).

    Attributes
    ----------
    detection : the :class:`LineDetection` (lines, white/black frames).
    kinks : every :class:`Kink` found; ``fold_inliers`` (len(kinks),) bool those on a fold;
        ``kink_fold`` (len(kinks),) int the fold (index into ``folds_cam``) each lies on, -1 none.
    pts_proj_xy, pts_cam_xy : (n, 2) crossings; ``plane`` (n,) int8 plane (-1: in a fold
        band); ``inliers`` (n,) bool homography inliers; ``plane_coarse`` (n,) int8 the
        cleaned label of the model selection (final numbering; -1 none).
    grid_ix, grid_iy : (n,) int column / row of each crossing on the grid of projected lines.
    fold_segments_cam : per fold, (2, 2) ends of its visible part in the camera (or None).
    candidates : per RANSAC candidate, its evidence (dict) and ``H_cam_from_proj``.
    residual_inliers : (n,) bool the crossings the residual fields fit (None without them).
    unfit_mask : (Hc, Wc) bool camera pixels of the dense map that fit no plane (None without
        a dense map; :func:`~.dense_fit.unfit_region`).
    """

    detection: LineDetection
    kinks: list[Kink] = field(default_factory=list)
    fold_inliers: np.ndarray | None = None
    kink_fold: np.ndarray | None = None
    pts_proj_xy: np.ndarray | None = None
    pts_cam_xy: np.ndarray | None = None
    plane: np.ndarray | None = None
    inliers: np.ndarray | None = None
    plane_coarse: np.ndarray | None = None
    grid_ix: np.ndarray | None = None
    grid_iy: np.ndarray | None = None
    fold_segments_cam: list = field(default_factory=list)
    candidates: list = field(default_factory=list)
    residual_inliers: np.ndarray | None = None
    unfit_mask: np.ndarray | None = None


def check_planes_option(planes) -> int | None:
    """``planes`` as the fit takes it: None for "auto", else an int 1 .. MAX_PLANES."""
    if isinstance(planes, str):
        text = planes.strip().lower()
        if text == "auto":
            return None
        n = int(text) if text.isdigit() else None
    elif isinstance(planes, (int, np.integer)) and not isinstance(planes, bool):
        n = int(planes)
    else:
        n = None
    if n is None or not 1 <= n <= MAX_PLANES:
        raise InputError(f"planes must be 'auto' or a whole number 1..{MAX_PLANES}; got {planes!r}")
    return n

def fit_geometry(detection: LineDetection, projector_size: tuple[int, int],
                 camera_size: tuple[int, int], *, planes="auto", min_kink_deg: float = 1.0,
                 fold_band: float = 12.0, ransac_threshold: float = 1.5, residual: bool = False,
                 max_fold_disagreement: float = MAX_FOLD_DISAGREEMENT,
                 residual_threshold: float | None = None, min_residual_inliers: float = 0.0):
    """Planes, homographies and folds from the detected lines (steps in the module docstring).

    Parameters
    ----------
    detection : the lines (camera coordinates as observed, or corrected by a caller).
    projector_size, camera_size : (width, height).
    planes : "auto" (model selection) or the number of planes, 1 .. MAX_PLANES.
    min_kink_deg, fold_band, ransac_threshold : see :class:`~.geometry.GeometryOptions`
        (``fold_band`` in camera px, not None here).
    residual : fit each plane's smooth residual (step 6); ``parts["residual_cam"]`` holds it.
    max_fold_disagreement : projector px two planes' images of their fold may differ by.
    residual_threshold : camera px a crossing may be off homography plus residual and count
        as fitting it (None: ``ransac_threshold``).
    min_residual_inliers : least share of each plane's crossings that must fit homography plus
        residual; below it the crossings are inconsistent (the set-up moved) and the fit stops.

    Returns
    -------
    parts : dict of Calibration fields: ``H_cam_from_proj``, ``H_proj_from_cam`` (n, 3, 3),
        ``folds_proj``, ``folds_cam`` (f, 3), ``fold_planes`` (f, 2) int32, ``lit_polygon_cam``
        and, with ``residual``, ``residual_cam`` (n, gy, gx, 2).
    stats : dict for ``meta["geometry"]`` (n_planes, rms_px, inliers, folds, candidates, ...).
    detail : :class:`GeometryDetail`.

    Raises
    ------
    CalibrationError
        Too few crossings, crossings that no set of planes explains (the set-up moved), folds
        whose two images disagree, or a forced ``planes`` the data contradict.
    """
    want = check_planes_option(planes)
    band = float(fold_band)
    res_thr = float(ransac_threshold if residual_threshold is None else residual_threshold)
    detail = GeometryDetail(detection=detection)
    kinks = []
    for k, ln in enumerate(detection.lines):
        for kk in find_kinks(ln.t, ln.s, min_angle_deg=min_kink_deg, gap=2 * band):
            kk.point_cam_xy = (kk.point_cam_xy if ln.axis == "h" else kk.point_cam_xy[::-1]).copy()
            kk.line = k
            kinks.append(kk)
    detail.kinks = kinks
    proj, cam, pairs = line_crossings(detection.lines, camera_size)
    detail.pts_proj_xy, detail.pts_cam_xy = proj, cam
    if len(proj) < 8:
        raise CalibrationError(f"only {len(proj)} line crossings were found, at least 8 are needed; "
                               "make sure the camera sees the whole projected area")
    grid = CrossingGrid.build(proj, pairs)
    detail.grid_ix, detail.grid_iy = grid.ix, grid.iy
    stats: dict = {"kinks": len(kinks), "crossings": int(len(proj))}

    # ---- how many planes
    cands = sequential_homographies(proj, cam, threshold=ransac_threshold,
                                    min_count=max(12, int(0.005 * len(proj))))
    select = functools.partial(select_planes, cands, grid, proj, cam, kinks,
                               threshold=ransac_threshold)
    kept, evidence = select(strict=True)
    if want is not None and len(kept) < want:
        kept, evidence = select(strict=False, want=want)
    detail.candidates = [dict(e.as_dict(), H_cam_from_proj=c[0]) for e, c in zip(evidence, cands,
                                                                               strict=True)]
    stats["candidates"] = [e.as_dict() for e in evidence]
    _check_count(want, kept, evidence)
    n = len(kept)

    dense = detection.dense
    if n == 1:
        dset = plane_samples(dense, None, 1, band)[0] if dense is not None else None
        H, inl, rms = (fit_homography(proj, cam, threshold=ransac_threshold, what="the plane")
                       if dset is None else
                       fit_plane_homography(dset, proj, cam, ransac_threshold, "the plane"))
        check_fit(inl, rms, "the plane", ransac_threshold)
        Hs = H[None]
        folds_proj = folds_cam = np.zeros((0, 3))
        fold_planes = np.zeros((0, 2), np.int32)
        plane = np.zeros(len(proj), np.int8)
        coarse = plane.copy()
        fits = [(H, inl, rms)]
        fold_stats: list[dict] = []
        detail.fold_inliers = np.zeros(len(kinks), bool)
        detail.kink_fold = np.full(len(kinks), -1)
        layout_proj = PlaneLayout(1)
        ctrl = [dense_residual(H, proj, cam, dset, projector_size, res_thr)] if residual else None
    else:
        raw = label_crossings([cands[i][0] for i in kept], proj, cam, ransac_threshold)
        coarse, _ = clean_labels(grid, raw, n)
        (Hs, fits, folds_proj, folds_cam, fold_planes, plane, fold_stats,
         kink_fold, segs, ctrl) = _fit_planes(n, coarse, grid, proj, cam, kinks, detection.valid,
                                              band, ransac_threshold,
                                              projector_size if residual else None,
                                              max_fold_disagreement, res_thr, dense)
        # ---- numbering (docs/internals.md)
        layout_proj = PlaneLayout(n, folds_proj, fold_planes)
        order = _plane_order(layout_proj, projector_size)
        new_of = np.empty(n, np.int64)
        new_of[order] = np.arange(n)
        Hs = Hs[order]
        fits = [fits[o] for o in order]
        ctrl = None if ctrl is None else [ctrl[o] for o in order]
        fold_planes = new_of[fold_planes]
        plane = np.where(plane >= 0, new_of[np.maximum(plane, 0)], -1).astype(np.int8)
        coarse = np.where(coarse >= 0, new_of[np.maximum(coarse, 0)], -1)
        fo = sorted(range(len(fold_planes)), key=lambda j: tuple(sorted(fold_planes[j])))
        folds_proj, folds_cam, fold_planes = folds_proj[fo], folds_cam[fo], fold_planes[fo]
        fold_stats = [dict(fold_stats[j], planes=fold_planes[i].tolist()) for i, j in enumerate(fo)]
        renum = np.full(len(fo) + 1, -1)
        renum[np.asarray(fo)] = np.arange(len(fo))
        detail.kink_fold = renum[kink_fold]
        detail.fold_inliers = detail.kink_fold >= 0
        detail.fold_segments_cam = [segs[j] for j in fo]
        layout_proj = PlaneLayout(n, folds_proj, fold_planes)
    inliers = np.zeros(len(proj), bool)
    for p in range(n):
        inliers[np.flatnonzero(plane == p)[fits[p][1]]] = True
    detail.plane, detail.inliers = plane, inliers
    detail.plane_coarse = np.asarray(coarse, np.int8)

    Hs = np.stack([H / H[2, 2] for H in Hs])
    Hinv = np.stack([np.linalg.inv(H) for H in Hs])
    Hinv = np.stack([H / H[2, 2] for H in Hinv])
    parts = {"H_cam_from_proj": Hs, "H_proj_from_cam": Hinv,
             "folds_proj": np.asarray(folds_proj, np.float64).reshape(-1, 3),
             "folds_cam": np.asarray(folds_cam, np.float64).reshape(-1, 3),
             "fold_planes": np.asarray(fold_planes, np.int32).reshape(-1, 2),
             "lit_polygon_cam": lit_polygon(projector_size, Hs, layout_proj)}
    if ctrl is not None and not any(np.any(c[0]) for c in ctrl):
        stats["residual"] = {"rms_px_flat": [round(c[4], 4) for c in ctrl], "kept": False}
        ctrl = None                 # exact planes: no field is worth keeping
    if ctrl is not None:
        parts["residual_cam"] = np.stack([c[0] for c in ctrl])
        res_in = np.zeros(len(proj), bool)
        for p in range(n):
            res_in[np.flatnonzero(plane == p)[ctrl[p][1]]] = True
        detail.residual_inliers = res_in
        stats["residual"] = {
            "rms_px": [round(c[2], 4) for c in ctrl],
            "inlier_fraction": [round(float(c[1].mean()), 4) for c in ctrl],
            "max_px": [round(c[3], 3) for c in ctrl],
            "rms_px_flat": [round(c[4], 4) for c in ctrl], "kept": True}
        for p, c in enumerate(ctrl):
            share = float(c[1].mean()) if c[1].size else 0.0
            if share < min_residual_inliers:
                raise CalibrationError(
                    f"plane {p + 1} of {n}: the line crossings are inconsistent — only "
                    f"{100 * share:.0f} % of {c[1].size} fit its homography and a smooth residual "
                    f"within {res_thr} camera px. The set-up probably moved between captures "
                    "(camera or projector knocked, auto-focus or image stabilisation on), or the "
                    "surface is not smooth there. Fix both devices firmly and calibrate again.")
            if c[3] > MAX_RESIDUAL_PX:
                log.warning("plane %d of %d: its residual reaches %.1f camera px off its homography"
                            ": far from a plane, or two surfaces taken for one", p + 1, n, c[3])
    dis = [f["disagreement_px"] for f in fold_stats]
    stats.update(n_planes=n, planes_option=planes if want is None else want,
                 rms_px=[round(f[2], 4) for f in fits], inliers=[int(f[1].sum()) for f in fits],
                 inlier_fraction=[round(float(f[1].mean()), 4) for f in fits],
                 folds=fold_stats, fold_disagreement_px=max(dis) if dis else None,
                 fold_kinks=int(sum(f["kinks"] for f in fold_stats)))
    if n == 2:
        stats["fold_kink_rms_px"] = fold_stats[0]["kink_rms_px"]
    if dense is not None:
        detail.unfit_mask, stats["unfit"] = unfit_region(
            dense, Hs, layout_proj, parts.get("residual_cam"), projector_size)
        stats["dense"] = {"valid_fraction": round(float(dense.valid.sum()) /
                                                  max(int(dense.lit.sum()), 1), 4)}
        if stats["unfit"]["fraction"] > MIN_UNFIT:
            parts["lit_polygon_cam"] = outline_without(
                parts["lit_polygon_cam"], detail.unfit_mask, dense, Hs, layout_proj,
                parts.get("residual_cam"), projector_size)
        if stats["unfit"]["pixels"]:
            log.info("geometry: %.1f %% of the lit camera view fits no plane (camera box %s); "
                     "it is masked out of the fit", 100 * stats["unfit"]["fraction"],
                     stats["unfit"]["bbox_cam"])
    return parts, stats, detail


def _check_count(want: int | None, kept: list[int], evidence) -> None:
    """A forced plane count must be what the crossings show (clear error otherwise)."""
    if want is None or len(kept) == want:
        return
    found = len(kept)
    if found > want:
        shares = ", ".join(f"{100 * evidence[k].share:.0f} %" for k in kept)
        raise CalibrationError(
            f"planes={want} was asked for, but the line crossings show {found} planes ({shares} of "
            "the crossings), each a contiguous region with kinks along its folds; fewer planes "
            f"cannot explain them. Calibrate with planes='auto' (or {found}), or mask off the "
            "extra surfaces.")
    why = "; ".join(f"candidate {i + 1}: {e.reason}" for i, e in enumerate(evidence)
                    if not e.accepted) or "no further homography fits the crossings"
    raise CalibrationError(
        f"planes={want} was asked for, but the line crossings show only {found} plane(s) ({why}). "
        "A plane must hold a contiguous part of the projection with the lines bending along its "
        "folds; check that the camera sees every plane, or calibrate with planes='auto'.")


def plane_residual(H: np.ndarray, proj: np.ndarray, cam: np.ndarray,
                   projector_size: tuple[int, int], threshold: float, min_gain: float = 2.0):
    """One plane's residual field from its crossings (step 6): (ctrl (gy, gx, 2), inliers (N,)
    bool, RMS camera px of the inliers after the field, largest |field| over the frame (px),
    RMS of the same crossings off the homography alone).

    What the homography leaves is fitted by :func:`rtdefocus.residual.fit_residual`; crossings
    more than ``threshold`` off homography plus field are left out and the field refitted
    (twice), so a stray crossing does not bend the wall. A field that does not halve the
    homography's misfit (``min_gain``), or stays within :data:`MIN_RESIDUAL_PX`, is noise: the
    plane is kept exactly flat (zero field)."""
    r = cam - apply_h(H, proj)
    norm = np.linalg.norm(r, axis=1)
    keep = norm <= max(4.0 * threshold, 2.0 * float(np.percentile(norm, 90)) if len(norm) else 0)
    for _ in range(3):
        ctrl = fit_residual(proj[keep], r[keep], projector_size)
        err = np.linalg.norm(r - displacement(ctrl, proj[:, 0], proj[:, 1], projector_size), axis=1)
        keep = err <= threshold
    rms = float(np.sqrt(np.mean(err[keep] ** 2))) if keep.any() else float("inf")
    rms_flat = float(np.sqrt(np.mean(norm[keep] ** 2))) if keep.any() else float("inf")
    wp, hp = projector_size
    gx, gy = np.meshgrid(np.linspace(0, wp - 1, 33), np.linspace(0, hp - 1, 25))
    biggest = float(np.linalg.norm(displacement(ctrl, gx.ravel(), gy.ravel(), projector_size),
                                   axis=1).max())
    if not (rms_flat > min_gain * rms and biggest > MIN_RESIDUAL_PX):
        ctrl, biggest = np.zeros_like(ctrl), 0.0
        keep = norm <= threshold
        rms = rms_flat = float(np.sqrt(np.mean(norm[keep] ** 2))) if keep.any() else float("inf")
    return ctrl, keep, rms, biggest, rms_flat


def dense_residual(H: np.ndarray, proj: np.ndarray, cam: np.ndarray, dense_set,
                   projector_size: tuple[int, int], threshold: float):
    """:func:`plane_residual` fitted to the plane's dense samples (``dense_set`` = (proj, cam),
    or None: its crossings), its inliers given over the crossings (``proj``, ``cam``), which
    the consistency check and the diagnostics read."""
    if dense_set is None or len(dense_set[0]) < 200:
        return plane_residual(H, proj, cam, projector_size, threshold)
    dp, dc = dense_set
    ok = prefilter(H, dp, dc, proj, cam, threshold)
    ctrl, _, rms, biggest, rms_flat = plane_residual(H, dp[ok], dc[ok], projector_size, threshold,
                                                     min_gain=1.0)
    # Whether the field is worth keeping is the crossings' call (as without the dense map):
    # they are precise to a few hundredths of a pixel, a dense sample only to a tenth or so.
    flat = np.linalg.norm(cam - apply_h(H, proj), axis=1)
    err = np.linalg.norm(cam - apply_h(H, proj) - displacement(ctrl, proj[:, 0], proj[:, 1],
                                                                projector_size), axis=1)
    keep = err <= threshold
    if keep.any() and not float(np.sqrt(np.mean(flat[keep] ** 2))) > \
            2.0 * float(np.sqrt(np.mean(err[keep] ** 2))):
        ctrl, biggest = np.zeros_like(ctrl), 0.0
        keep = flat <= threshold
        rms = rms_flat
    return ctrl, keep, rms, biggest, rms_flat


def _fit_planes(n, coarse, grid, proj, cam, kinks, valid, band, threshold, residual_size=None,
                max_disagreement=MAX_FOLD_DISAGREEMENT, residual_threshold=None, dense=None):
    """Steps 3-6 for n >= 2 planes, in the model selection's numbering; ``residual_size``
    (the projector size) fits the residual fields (else None is returned for them); with a
    ``dense`` map each plane's homography and field are fitted to its dense samples."""
    kpts = np.array([kk.point_cam_xy for kk in kinks]).reshape(-1, 2)
    kink_fold = np.full(len(kinks), -1)
    folds_cam, pairs, fold_stats = [], [], []
    for a in range(n):
        for b in range(a + 1, n):
            n_cross, matched = boundary_kinks(grid, coarse, cam, kinks, a, b)
            if n_cross < 3:
                continue            # touching at a corner (a vertex), no shared edge
            res = fit_fold(kpts[matched], min_inliers=3) if len(matched) >= 3 else None
            if res is None:
                log.warning("planes %d and %d meet along %d line crossings but the kinks there "
                            "(%d) do not lie on a line; no fold between them", a, b, n_cross,
                            len(matched))
                continue
            line, inl, rms = res
            # Plane a on the negative side (in the camera, for now).
            if np.median(line_eval(line, cam[coarse == a])) > 0:
                line = -line
            kink_fold[np.asarray(matched)[inl]] = len(folds_cam)
            folds_cam.append(line)
            pairs.append((a, b))
            fold_stats.append({"kinks": int(inl.sum()), "kink_rms_px": round(rms, 4),
                               "boundary_crossings": int(n_cross),
                               "kink_share": round(len(matched) / n_cross, 3)})
    lonely = sorted(set(range(n)) - {p for pr in pairs for p in pr})
    if lonely:
        raise CalibrationError(
            f"plane(s) {lonely} of {n} have no fold with kinks along it: the line crossings split "
            "into regions that do not meet along a bend. The set-up probably moved between "
            "captures; fix both devices firmly and calibrate again.")
    folds_cam = np.array(folds_cam)
    fold_planes = np.array(pairs, np.int64)
    layout_cam = PlaneLayout(n, folds_cam, fold_planes)
    lab = layout_cam.label(cam[:, 0], cam[:, 1]).astype(np.int64)
    out = layout_cam.outside(cam[:, 0], cam[:, 1])
    plane = np.where(out[lab, np.arange(len(cam))] < -band, lab, -1).astype(np.int8)
    dsets = plane_samples(dense, layout_cam, n, band) if dense is not None else [None] * n
    fits = []
    for p in range(n):
        sel = plane == p
        what = f"plane {p + 1} of {n}"
        H, inl, rms = (fit_homography(proj[sel], cam[sel], threshold=threshold, what=what)
                       if dsets[p] is None else
                       fit_plane_homography(dsets[p], proj[sel], cam[sel], threshold, what))
        check_fit(inl, rms, what, threshold)
        fits.append((H, inl, rms))
    Hs = np.stack([f[0] for f in fits])
    Hinv = np.stack([np.linalg.inv(H) for H in Hs])
    ctrl = None
    if residual_size is not None:
        rt = threshold if residual_threshold is None else residual_threshold
        ctrl = [dense_residual(Hs[p], proj[plane == p], cam[plane == p], dsets[p], residual_size,
                               rt) for p in range(n)]
    folds_proj, segs = [], []
    for j, (a, b) in enumerate(pairs):
        seg = _visible_fold(layout_cam, j, valid)
        if seg is None:
            pts = kpts[kink_fold == j]
            seg = np.stack([pts.min(axis=0), pts.max(axis=0)])
        to_proj = None
        if ctrl is not None:
            to_proj = [functools.partial(proj_from_cam, Hinv[q], ctrl[q][0],
                                         projector_size=residual_size) for q in (a, b)]
        line, dis = fold_to_projector(folds_cam[j], Hinv[[a, b]], seg, to_proj=to_proj)
        if ctrl is not None and (np.any(ctrl[a][0]) or np.any(ctrl[b][0])):
            line = crease(line, [(Hs[q], ctrl[q][0]) for q in (a, b)], residual_size)
        line = canonical_line(line)
        fold_stats[j]["disagreement_px"] = round(dis, 4)
        if dis > max_disagreement:
            raise CalibrationError(
                f"planes {a + 1} and {b + 1} disagree about where their fold is by {dis:.1f} "
                "projector px: the kinks do not lie where the homographies meet. Check that the "
                "surface is made of flat walls, that the camera sees each of them, and that "
                "nothing moved.")
        # Same plane on the negative side in the projector and in the camera.
        if np.median(line_eval(line, proj[plane == a])) > 0:
            pairs[j] = (b, a)
            folds_cam[j] = -folds_cam[j]
        folds_proj.append(line)
        segs.append(seg)
    return (Hs, fits, np.array(folds_proj), folds_cam, np.array(pairs, np.int64), plane,
            fold_stats, kink_fold, segs, ctrl)


def crease(line: np.ndarray, maps, projector_size: tuple[int, int], reach: float = 16.0,
           step: float = 0.25, min_shift: float = 1.0) -> np.ndarray:
    """The projector fold where two planes' full maps (homography plus residual) meet, near
    ``line``: at points along it inside the frame, the offset along its normal (within
    ``reach`` px) where the two camera points are nearest, then a line through those.

    The kinks that give the camera fold sit where straight pieces of a line meet; on a wall
    that bows the piece beside the fold is curved, which moves the kinks (a pixel or two, the
    same on every line) while the two maps still meet exactly at the fold. The crease is
    taken only where it moves the fold by more than ``min_shift`` px somewhere in the frame:
    on exact planes the kinks are unbiased and the residuals' noise near the fold (where they
    have no crossings) would only add a few tenths of a pixel."""
    wp, hp = projector_size
    a, b, c = line / np.hypot(line[0], line[1])
    n = np.array([a, b])
    d = np.array([-b, a])
    p0 = -c * n
    half = float(np.hypot(wp, hp))
    t = np.linspace(-half, half, 801)
    pts = p0 + t[:, None] * d
    pts = pts[(pts[:, 0] >= 0) & (pts[:, 0] <= wp - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= hp - 1)]
    if len(pts) < 8:
        return line
    pts = pts[:: max(1, len(pts) // 40)]
    offs = np.arange(-reach, reach + step / 2, step)
    grid = (pts[:, None, :] + offs[None, :, None] * n).reshape(-1, 2)

    def cam(H, ctrl):
        return apply_h(H, grid) + displacement(ctrl, grid[:, 0], grid[:, 1], projector_size)

    gap = np.linalg.norm(cam(*maps[0]) - cam(*maps[1]), axis=1).reshape(len(pts), len(offs))
    k = np.clip(np.argmin(gap, axis=1), 1, len(offs) - 2)
    rows = np.arange(len(pts))
    # Parabola through the smallest gap and its neighbours: sub-step offset.
    g0, g1, g2 = gap[rows, k - 1], gap[rows, k], gap[rows, k + 1]
    den = g0 - 2 * g1 + g2
    frac = np.where(den > 1e-12, 0.5 * (g0 - g2) / np.where(den > 1e-12, den, 1.0), 0.0)
    best = offs[k] + np.clip(frac, -1, 1) * step
    inner = (np.argmin(gap, axis=1) > 0) & (np.argmin(gap, axis=1) < len(offs) - 1)
    if inner.sum() < 4:
        return line
    on = pts[inner] + best[inner, None] * n
    out = normalise_line(tls_line(on))
    out = out if out @ [a, b, 0.0] >= 0 else -out
    shift = float(np.abs(line_eval(out, pts[[0, -1]])).max())     # the ends bound a line's
    return out if shift > min_shift else line


def _visible_fold(layout: PlaneLayout, j: int, valid: np.ndarray):
    """Ends (2, 2) of the part of camera fold ``j`` that separates its two planes inside the
    lit ``valid`` mask (the whole lit line for two planes), or None."""
    if layout.n_planes == 2:
        return segment_in_mask(layout.folds[j], valid)
    hc, wc = valid.shape
    yy, xx = np.mgrid[0:hc, 0:wc]
    a, b, _ = layout.folds[j]
    # Both sides of the line, 2 px out, must be the fold's two planes.
    pair = set(layout.fold_planes[j].tolist())
    lo = layout.label(xx - 2 * a, yy - 2 * b)
    hi = layout.label(xx + 2 * a, yy + 2 * b)
    mask = valid & (lo != hi) & np.isin(lo, list(pair)) & np.isin(hi, list(pair))
    return segment_in_mask(layout.folds[j], mask)


def _plane_order(layout: PlaneLayout, projector_size) -> list[int]:
    """Planes in calibration order: two by the fold's side, more by centroid (module docstring)."""
    n = layout.n_planes
    if n == 2:     # fold j already canonical, fold_planes[0] = [negative side, positive side]
        return [int(layout.fold_planes[0, 0]), int(layout.fold_planes[0, 1])]
    wp, hp = projector_size
    yy, xx = np.mgrid[0:hp:2, 0:wp:2]
    lab = layout.label(xx, yy).ravel().astype(np.int64)
    count = np.maximum(np.bincount(lab, minlength=n), 1)
    cx = np.bincount(lab, weights=xx.ravel(), minlength=n) / count
    cy = np.bincount(lab, weights=yy.ravel(), minlength=n) / count

    def cmp(p, q):
        if abs(cx[p] - cx[q]) < 0.05 * wp:
            return cy[p] - cy[q]
        return cx[p] - cx[q]

    return sorted(range(n), key=functools.cmp_to_key(cmp))


def check_fit(inl: np.ndarray, rms: float, what: str, threshold: float) -> None:
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
