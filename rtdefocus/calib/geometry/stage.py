"""Geometry stage: lines -> planes (any number), their homographies and folds -> lit area.

DESIGN.md §4, paper §3.1 (after Paidimarri & Chandran), extended to any number of planes.
Learnt only through ``capture``:

1. :mod:`.structured_light` gives, for every projected line, its sub-pixel ridge in the camera.
2. :func:`~.geometry_fit.fit_geometry` does the rest from those lines alone: kinks on each line
   (a projected straight line crossing a fold bends there; lens distortion bends it smoothly),
   the line crossings as dense projector <-> camera correspondences, how many planes they show
   (sequential RANSAC, a plane kept only while it is a contiguous region with kinks along its
   folds), one homography per plane, each fold in the camera from its kinks and in the projector
   through both of its planes' inverse homographies (which must agree).

Conventions (docs/internals.md): lines ``a x + b y + c = 0`` with ``a² + b² = 1``; two planes:
plane 0 where the fold is negative, the projector fold's normal towards +x (+y for a nearly
horizontal fold); more planes: numbered by their projector centroid x, ``fold_planes[j]`` =
[negative side, positive side], the same in the projector and the camera.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, fields, replace

from ...errors import CalibrationError, InputError
from ..capture import Capturer, check_capturer
from ..file import Calibration
from ..options import stage_options
from .dense import DenseDecoder, DensePatterns
from .fit import MAX_FOLD_DISAGREEMENT, GeometryDetail, check_planes_option, fit_geometry
from .homography import estimate_radial_k1, estimate_radial_k12
from .lens import check_lens_option, fit_with_known_lens, fit_with_lens
from .stray import stray_light, stray_light_warning
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
    planes : "auto" (as many planes as the crossings clearly show: each a contiguous region
        with kinks along its folds) or their number 1 .. 8; a number the data contradict is an
        error that says what was found.
    residual : fit each plane a smooth residual off its homography (walls that are planes
        only nearly: a bowed panel, a sagging sheet), carried by the warp and the file; when
        the flat-plane fit refuses the set-up, it is fitted again with a looser inlier distance
        (:data:`NEARLY_FLAT_FACTOR` × ``ransac_threshold``, and as many times the fold
        disagreement) and the residual. False: exact
        planes (the paper's model).
    dense : also project the dense patterns (:mod:`.dense`: Gray code plus phase shift in both
        directions, :meth:`~.dense.DensePatterns.count` more captures) and fit each plane's
        homography and residual field to every valid camera pixel's projector coordinates
        (:mod:`.dense_fit`); the line crossings still find the planes and folds. The pixels
        no plane fits (a far wall through a gap) are masked out and shown.
    lens : the camera's radial distortion (k1, k2) when it is known (measured once, e.g. the
        ``camera_distortion`` of a calibration on flat walls): taken as it is instead of
        estimated from the walls' crossings, which cannot tell a lens from walls that pillow
        (:func:`~.lens.fit_with_known_lens`). None: estimated (``undistort``).
    """

    line_spacing: int = 48
    line_phases: int = 4
    line_width: int = 3
    samples: int = 1
    min_kink_deg: float = 1.0
    fold_band: float | None = None
    ransac_threshold: float = 1.5
    undistort: bool = True
    planes: int | str = "auto"
    residual: bool = True
    dense: bool = False
    lens: tuple[float, float] | None = None


#: names of the stage's options (the fields of :class:`GeometryOptions`).
OPTIONS = tuple(f.name for f in fields(GeometryOptions))
#: The inlier distance of the second, nearly-flat fit, as a multiple of ``ransac_threshold``:
#: walls a few camera px off a plane stay one plane each, their residual fields take the rest.
NEARLY_FLAT_FACTOR = 4.0
#: ... but homography plus residual must still fit this share of each plane's crossings within
#: ``ransac_threshold``: crossings from before and after a knock are no smooth residual.
NEARLY_FLAT_INLIERS = 0.9


def calibrate_geometry(calib: Calibration | None, capture: Capturer,
                       options: GeometryOptions | None = None, **overrides) -> Calibration:
    """Learn the set-up's geometry through ``capture`` only.

    Parameters
    ----------
    calib : None
        The calibration so far: none, this stage makes it.
    capture : Capturer
        The calibration's capturer (the ProCam, counts, progress, frame cache).
    options : GeometryOptions, optional
        The stage's options (default: :class:`GeometryOptions`' defaults).
    **overrides
        Fields of :class:`GeometryOptions` (``line_spacing=32``, ``planes=2``, ...) replacing
        those of ``options``.

    Returns
    -------
    Calibration
        A new one, geometry section filled, in ideal camera pixels with ``camera_distortion``
        (k1, k2) the lens; ``meta["geometry"]`` holds the statistics (``n_planes``,
        ``rms_px`` and ``inliers`` per plane, ``folds`` (per fold: planes, kinks, kink RMS,
        disagreement), ``fold_disagreement_px`` (the largest), ``candidates`` (the model
        selection's evidence), ``captures``, lines and kinks).
        The transient attribute ``geometry_detail`` (:class:`GeometryDetail`) feeds
        :func:`geometry_diagnostics`; it is not saved.

    Raises
    ------
    InputError
        ``calib`` is not None, or an option is unknown or out of range (before any capture).
    CalibrationError
        The camera sees no projector light, the lines cannot be found, or the correspondences
        are inconsistent (the set-up moved), or ``planes`` forces a count the crossings
        contradict; the message says what was seen and what to check.
    """
    t_start = time.perf_counter()
    if calib is not None:
        raise InputError("the geometry stage makes the calibration, it fills none: pass "
                         "calib=None")
    check_capturer(capture)
    o = stage_options(GeometryOptions, options, **overrides)
    samples, planes, residual = o.samples, o.planes, o.residual
    ransac_threshold, min_kink_deg = o.ransac_threshold, o.min_kink_deg
    cap, procam = capture, capture.procam
    if int(samples) < 1:
        raise InputError(f"samples must be >= 1; got {samples}")
    check_planes_option(planes)          # before any capture
    known = check_lens_option(o.lens)
    dense = bool(o.dense)
    pats = LinePatterns(tuple(procam.projector_size), int(o.line_spacing), int(o.line_phases),
                        int(o.line_width))
    seq = pats.sequence()
    dense_dec = DenseDecoder(DensePatterns(pats.projector_size)) if dense else None
    if dense_dec is not None:       # before the closing white frame, which checks stability
        seq = seq[:-1] + dense_dec.patterns.sequence() + seq[-1:]
    cap.begin("geometry", len(seq) * int(samples))
    det = LineDetector(pats)
    for name, pattern in seq:
        frame = cap(pattern) if samples == 1 else cap.mean(pattern, int(samples))
        if name.startswith("d"):        # dense patterns (no line pattern's name starts so)
            if det.white is None:
                raise InputError("the white frame must be captured before the dense patterns")
            if not dense_dec.ready:
                dense_dec.set_frames(det.black, det.white)
            dense_dec.add(name, frame)
        else:
            det.add(name, frame)
    detection = det.result()
    if dense_dec is not None:
        detection = replace(detection, dense=dense_dec.result())
    n_captures = len(seq)
    camera_size = tuple(procam.camera_size)
    band = float(o.fold_band) if o.fold_band is not None else float(det.half)

    def fit(detection: LineDetection, threshold: float = ransac_threshold,
            disagreement: float = MAX_FOLD_DISAGREEMENT, min_residual_inliers: float = 0.0
            ) -> Calibration:
        parts, stats, detail = fit_geometry(detection, pats.projector_size, camera_size,
                                            planes=planes, min_kink_deg=min_kink_deg,
                                            residual=bool(residual),
                                            max_fold_disagreement=disagreement,
                                            residual_threshold=ransac_threshold,
                                            min_residual_inliers=min_residual_inliers,
                                            fold_band=band, ransac_threshold=threshold)
        used = {"line_spacing": pats.spacing, "line_phases": pats.phases,
                   "line_width": pats.width, "samples": int(samples), "min_kink_deg": min_kink_deg,
                   "fold_band": band, "ransac_threshold": threshold, "planes": planes,
                   "residual": bool(residual), "dense": dense,
                   "lens": None if known is None else list(known)}
        return _calibration(parts, stats, detail, pats, used, t_start, n_captures)

    def fit_lens(fit_one, detection, camera_size, correct, rough=None):
        if known is not None:
            return fit_with_known_lens(fit_one, detection, known, camera_size)
        return fit_with_lens(fit_one, detection, camera_size, correct=correct, rough=rough)

    # A strong lens can fail the first fit: a 4x looser inlier distance still measures it.
    try:
        calib = fit_lens(fit, detection, camera_size, bool(o.undistort),
                         rough=lambda d: fit(d, 4.0 * ransac_threshold))
    except CalibrationError as exc:
        if not residual:
            raise
        # Walls a few px off a plane split into many small planes, or their folds disagree:
        # one plane each with a looser inlier distance, and the residual fields take the rest.
        loose = NEARLY_FLAT_FACTOR * ransac_threshold
        log.info("geometry: the flat-plane fit refused the set-up (%s); fitting nearly flat "
                 "planes (inliers within %.1f px, residual fields)", exc, loose)
        try:
            calib = fit_lens(
                lambda d: fit(d, loose, NEARLY_FLAT_FACTOR * MAX_FOLD_DISAGREEMENT,
                              NEARLY_FLAT_INLIERS), detection, camera_size, bool(o.undistort))
        except CalibrationError:
            raise exc from None
        calib.meta["geometry"]["nearly_flat"] = {"flat_fit_error": str(exc), "threshold": loose}
    if not dense:       # the dense map masks such a region itself (meta["geometry"]["unfit"])
        _warn_stray_light(calib, band)
    return calib


def _warn_stray_light(calib: Calibration, margin_px: float) -> None:
    """Name a lit camera region that none of the planes explains (:mod:`.stray`) in
    ``meta["geometry"]["stray_light"]``, ``meta["warnings"]`` and the log."""
    detail = calib.geometry_detail
    det = detail.detection
    stats = stray_light(det.white, det.black, det.valid, calib.lit_polygon_cam, margin_px,
                        detail.pts_cam_xy[detail.inliers])
    if stats is None:
        return
    calib.meta["geometry"]["stray_light"] = stats
    text = stray_light_warning(stats)
    calib.meta.setdefault("warnings", []).append(text)
    log.warning("geometry: %s", text)


def _calibration(parts: dict, fit_stats: dict, detail: GeometryDetail, pats: LinePatterns,
                 options: dict, t_start: float, n_patterns: int) -> Calibration:
    """The Calibration and its ``meta["geometry"]`` from one :func:`fit_geometry`."""
    detection = detail.detection
    camera_size = tuple(detection.valid.shape[::-1])
    stats: dict = {"captures": n_patterns * options["samples"], "patterns": n_patterns,
                   "lines_found": detection.stats["lines_found"],
                   "lines_expected": detection.stats["lines_expected"],
                   "ridge_points": detection.stats["points"],
                   "white_shift_px": detection.stats.get("white_shift_px"),
                   "options": options}
    stats.update(fit_stats)
    # The lens's radial distortion, from how far each plane's crossings are from a homography
    # (in the coordinates given: lens.fit_with_lens undistorts them and fits again if it matters).
    proj, cam, plane, inliers = detail.pts_proj_xy, detail.pts_cam_xy, detail.plane, detail.inliers
    sets = [(proj[(plane == p) & inliers], cam[(plane == p) & inliers])
            for p in range(int(stats["n_planes"]))]
    k1, rms_k1, rms_0 = estimate_radial_k1(sets, camera_size)
    # k1 and k2 together: lens.fit_with_lens keeps k2 only where it clearly explains more.
    k1b, k2b, rms_k12 = estimate_radial_k12(sets, camera_size, k1)
    stats["distortion"] = {"k1": round(k1, 4), "rms_px": round(rms_k1, 4),
                           "rms_px_without": round(rms_0, 4),
                           "k12": [round(k1b, 5), round(k2b, 5)], "rms_px_k12": round(rms_k12, 4)}
    calib = Calibration(projector_size=pats.projector_size, camera_size=camera_size, **parts)
    stats["seconds"] = round(time.perf_counter() - t_start, 2)
    stats["kinks_cam"] = [[round(float(v), 2) for v in kk.point_cam_xy] for kk in detail.kinks]
    calib.meta["geometry"] = stats
    calib.geometry_detail = detail
    log.info("geometry: %d plane(s), RMS reprojection %s camera px, fold disagreement %s px, "
             "%d captures", stats["n_planes"], stats["rms_px"], stats["fold_disagreement_px"],
             stats["captures"])
    return calib

