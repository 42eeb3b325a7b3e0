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
import time
from dataclasses import dataclass, field, fields

import numpy as np

from ..errors import CalibrationError, InputError
from ..procam import ProCam
from .capture import Capturer
from .file import Calibration
from .fold import Kink, find_kink, fit_fold, fold_to_projector
from .homography import estimate_radial_k1, fit_homography, line_crossings
from .lens import fit_with_lens
from .planar import canonical_line, line_eval, lit_polygon, segment_in_mask
from .structured_light import LineDetection, LineDetector, LinePatterns

log = logging.getLogger(__name__)

__all__ = ["GeometryOptions", "OPTIONS", "GeometryDetail", "calibrate_geometry"]


@dataclass(frozen=True)
class GeometryOptions:
    """Options of the geometry stage, with their defaults (``calibrate(**options)`` routes
    these names to :func:`calibrate_geometry`).

    Attributes
    ----------
    line_spacing : projector px between the lines of one pattern (> 2 × the largest blur
        diameter).
    line_phases : shifted copies per direction; lines every ``line_spacing / line_phases`` px.
    line_width : projector px.
    samples : captures averaged per pattern (camera noise).
    min_kink_deg : smallest bend (degrees) taken as a kink.
    fold_band : camera px on each side of the fold whose crossings are left out; None: the
        ridge window (covers the largest blurred line).
    ransac_threshold : homography RANSAC inlier distance (camera px).
    undistort : take the lens's radial distortion out (:func:`~.lens.fit_with_lens`) when it
        moves the frame corners by more than a quarter pixel.
    """

    line_spacing: int = 48
    line_phases: int = 4
    line_width: int = 3
    samples: int = 1
    min_kink_deg: float = 1.0
    fold_band: float | None = None
    ransac_threshold: float = 1.5
    undistort: bool = True


#: names of the stage's options (the fields of :class:`GeometryOptions`).
OPTIONS = tuple(f.name for f in fields(GeometryOptions))
_D = GeometryOptions()


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


def calibrate_geometry(procam: ProCam, *, capture: Capturer | None = None,
                       line_spacing: int = _D.line_spacing, line_phases: int = _D.line_phases,
                       line_width: int = _D.line_width, samples: int = _D.samples,
                       min_kink_deg: float = _D.min_kink_deg, fold_band: float | None = _D.fold_band,
                       ransac_threshold: float = _D.ransac_threshold,
                       undistort: bool = _D.undistort) -> Calibration:
    """Learn the set-up's geometry through ``capture`` only.

    Parameters
    ----------
    procam : ProCam
    capture : the calibration's :class:`Capturer` (counts, retries, progress); a fresh one
        when None.
    line_spacing, line_phases, line_width, samples, min_kink_deg, fold_band, ransac_threshold,
    undistort : see :class:`GeometryOptions` (their defaults are its defaults).

    Returns
    -------
    Calibration
        Geometry section filled, in ideal camera pixels with ``camera_distortion`` (k1, k2) the
        lens; ``meta["geometry"]`` holds the statistics (``n_planes``,
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
    camera_size = tuple(procam.camera_size)

    def fit(detection: LineDetection, threshold: float = ransac_threshold) -> Calibration:
        return _fit_geometry(detection, pats, seq, samples, det, camera_size, min_kink_deg,
                             fold_band, threshold, t_start)

    # A strong lens can fail the first fit: a 4x looser inlier distance still measures it.
    return fit_with_lens(fit, detection, camera_size, correct=bool(undistort),
                         rough=lambda d: fit(d, 4.0 * ransac_threshold))


def _fit_geometry(detection: LineDetection, pats: LinePatterns, seq: list, samples: int,
                  det: LineDetector, camera_size: tuple[int, int], min_kink_deg: float,
                  fold_band: float | None, ransac_threshold: float, t_start: float) -> Calibration:
    """Kinks -> fold -> homographies -> lit outline, on the camera coordinates of ``detection``
    (steps 2-6 of the module docstring)."""
    lines = detection.lines
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
        side = line_eval(fold_cam0, cam)
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
        seg = segment_in_mask(fold_cam0, detection.valid)
        if seg is None:
            pts = np.array([kk.point_cam_xy for kk in kinks])[fold_inl]
            seg = np.stack([pts.min(axis=0), pts.max(axis=0)])
        fold_proj, disagreement = fold_to_projector(fold_cam0, Hinv, seg)
        fold_proj = canonical_line(fold_proj)
        # Plane 0 is the negative side of the projector fold; which camera side is that?
        neg0 = float(np.median(line_eval(fold_proj, proj[sel[0]]))) < 0
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
    # The lens's radial distortion, from how far each plane's crossings are from a homography
    # (in the coordinates given: lens.fit_with_lens undistorts them and fits again if it matters).
    k1, rms_k1, rms_0 = estimate_radial_k1(
        [(proj[(plane == p) & inliers], cam[(plane == p) & inliers])
         for p in range(int(stats["n_planes"]))], camera_size)
    stats["distortion"] = {"k1": round(k1, 4), "rms_px": round(rms_k1, 4),
                           "rms_px_without": round(rms_0, 4)}
    Hs = np.stack([H / H[2, 2] for H in Hs])
    Hinv = np.stack([np.linalg.inv(H) for H in Hs])
    Hinv = np.stack([H / H[2, 2] for H in Hinv])
    poly = lit_polygon(pats.projector_size, Hs, fold_proj)
    calib = Calibration.with_fold(projector_size=pats.projector_size, camera_size=camera_size,
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

