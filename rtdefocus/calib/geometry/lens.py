"""The camera's lens: radial distortion, estimated by the geometry stage and undone everywhere
a camera picture or a camera point meets the calibration.

The model (:func:`~.planar.distort_points`) is radial about the image centre with r = 1 at the
frame corners: ``x_obs = c + (x - c)(1 + k1 r² + k2 r⁴)``. The calibration's homographies, fold,
lit outline and display rectangle are in *ideal* (undistorted) camera pixels; a captured frame
is in *observed* pixels. So:

* camera points measured on a frame are undistorted before any fit (:func:`undistort_detection`,
  :func:`ideal_points`);
* a map from projector pixels into a frame goes ideal -> observed (:func:`observed_points`);
* a frame compared with the display rectangle is resampled into ideal pixels first
  (:func:`undistort_image`, :func:`ideal_view`).

:func:`fit_with_lens` is the geometry stage's lens step: fit with k = 0, estimate k1 from how far
each plane's crossings are from a homography (:func:`~.homography.estimate_radial_k1`; k2 too
where it clearly explains more, :func:`~.homography.estimate_radial_k12`), and when that matters
undistort the detection and fit again.
"""

from __future__ import annotations

import functools
import logging
import os
from collections.abc import Callable
from dataclasses import replace

import cv2
import numpy as np

from ...errors import InputError
from ...planar import distort_points, undistort_points
from .structured_light import DetectedLine, LineDetection

log = logging.getLogger(__name__)

__all__ = ["lens_k", "ideal_points", "observed_points", "observed_maps", "undistort_image",
           "ideal_view", "lit_mask_observed", "undistort_line", "undistort_detection",
           "fit_with_lens", "fit_with_known_lens", "check_lens_option", "lens_from", "max_displacement",
           "MIN_EFFECT_PX", "MIN_EXPLAINED"]

#: Largest displacement (camera px, at the frame corners) of a distortion that is not worth
#: correcting: below it the estimate is within its own noise and a refit only costs time.
MIN_EFFECT_PX = 0.25
#: Share of the crossings' RMS misfit (k1 = 0) the fitted k1 must remove to be applied.
MIN_EXPLAINED = 0.1


def lens_k(calib_or_k) -> tuple[float, float] | None:
    """(k1, k2) of a Calibration (its ``camera_distortion``) or of a pair; None for an ideal
    lens (absent or all zero)."""
    k = getattr(calib_or_k, "camera_distortion", calib_or_k)
    if k is None:
        return None
    k1, k2 = (float(v) for v in np.asarray(k, np.float64).ravel()[:2])
    return None if k1 == 0.0 and k2 == 0.0 else (k1, k2)


def ideal_points(calib, pts_xy: np.ndarray) -> np.ndarray:
    """Observed camera points (..., 2) -> ideal camera points (float64), through ``calib``'s
    lens (unchanged for an ideal one)."""
    k = lens_k(calib)
    p = np.asarray(pts_xy, np.float64)
    return p.copy() if k is None else undistort_points(p, k, tuple(calib.camera_size))


def observed_points(calib, pts_xy: np.ndarray) -> np.ndarray:
    """Ideal camera points (..., 2) -> where the camera sees them (float64)."""
    k = lens_k(calib)
    p = np.asarray(pts_xy, np.float64)
    return p.copy() if k is None else distort_points(p, k, tuple(calib.camera_size))


@functools.lru_cache(maxsize=8)
def _maps(k: tuple[float, float], camera_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    wc, hc = camera_size
    ys, xs = np.mgrid[0:hc, 0:wc].astype(np.float64)
    obs = distort_points(np.stack([xs, ys], axis=-1), k, camera_size)
    mx = np.ascontiguousarray(obs[..., 0], np.float32)
    my = np.ascontiguousarray(obs[..., 1], np.float32)
    mx.flags.writeable = my.flags.writeable = False      # shared by every caller
    return mx, my


def observed_maps(k, camera_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(Hc, Wc) float32 maps for ``cv2.remap``: the observed position of every ideal camera
    pixel (cached per lens and size; read-only)."""
    kk = lens_k(k) or (0.0, 0.0)
    return _maps(kk, (int(camera_size[0]), int(camera_size[1])))


def undistort_image(img: np.ndarray, k, camera_size: tuple[int, int] | None = None,
                    interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """A camera frame (Hc, Wc[, C]) resampled into ideal (undistorted) camera pixels.

    ``k``: (k1, k2) or a Calibration. Pixels whose observed position falls outside the frame
    are 0. Bilinear by default (``cv2.INTER_NEAREST`` for masks and labels). An ideal lens
    returns ``img`` itself.
    """
    kk = lens_k(k)
    if kk is None:
        return img
    size = camera_size if camera_size is not None else tuple(k.camera_size)
    mx, my = observed_maps(kk, size)
    a = np.asarray(img)
    src = a.astype(np.uint8) if a.dtype == bool else a
    out = cv2.remap(np.ascontiguousarray(src), mx, my, interpolation,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(bool) if a.dtype == bool else out


def ideal_view(calib, frame: np.ndarray) -> np.ndarray:
    """A captured frame in the calibration's (ideal) camera pixels, ready to be cropped by
    ``calib.display_rect`` or compared with ``fold_cam`` (the frame itself for an ideal lens)."""
    return undistort_image(frame, calib)


def lit_mask_observed(calib, step: float = 4.0) -> np.ndarray:
    """(Hc, Wc) bool: the observed camera pixels inside the lit outline (``lit_polygon_cam``);
    its edges, straight in ideal pixels, are sampled every ``step`` px before distortion so
    they bend as the lens bends them."""
    wc, hc = calib.camera_size
    poly = np.asarray(calib.lit_polygon_cam, np.float64)
    if lens_k(calib) is not None:
        dense = []
        for p, q in zip(poly, np.roll(poly, -1, axis=0), strict=True):
            n = max(1, int(np.ceil(np.linalg.norm(q - p) / step)))
            dense.append(p + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (q - p))
        poly = observed_points(calib, np.vstack(dense))
    mask = np.zeros((hc, wc), np.uint8)
    cv2.fillPoly(mask, [np.round(poly * 16).astype(np.int32)], 1, shift=4)
    return mask.astype(bool)


# --------------------------------------------------------------------------- the detection
def undistort_line(ln: DetectedLine, k: tuple[float, float],
                   camera_size: tuple[int, int]) -> DetectedLine:
    """A detected ridge in ideal camera pixels, resampled at whole rows ("v") or columns ("h")
    (the form :func:`~.homography.line_crossings` and :func:`~.fold.find_kink` read).

    Samples between two ideal positions are linearly interpolated only where the two observed
    samples were neighbours (t and t + 1): gaps stay gaps.
    """
    if len(ln.t) < 2:
        return replace(ln, t=ln.t[:0], s=ln.s[:0])
    ideal = undistort_points(ln.pts_cam_xy, k, camera_size)
    along, across = (ideal[:, 1], ideal[:, 0]) if ln.axis == "v" else (ideal[:, 0], ideal[:, 1])
    order = np.argsort(along, kind="stable")
    along, across, t_obs = along[order], across[order], ln.t[order]
    t_new = np.arange(int(np.ceil(along[0])), int(np.floor(along[-1])) + 1)
    j = np.clip(np.searchsorted(along, t_new, side="right"), 1, len(along) - 1)
    joined = (t_obs[j] - t_obs[j - 1]) == 1
    f = (t_new - along[j - 1]) / np.maximum(along[j] - along[j - 1], 1e-9)
    s_new = across[j - 1] + f * (across[j] - across[j - 1])
    keep = joined & (f >= 0) & (f <= 1)
    return replace(ln, t=t_new[keep].astype(ln.t.dtype), s=s_new[keep].astype(np.float64))


def undistort_detection(det: LineDetection, k: tuple[float, float],
                        camera_size: tuple[int, int]) -> LineDetection:
    """The whole line detection in ideal camera pixels: every ridge (:func:`undistort_line`),
    the frames, the valid mask and the dense map resampled (so the diagnostics draw on a
    matching picture)."""
    lines = [undistort_line(ln, k, camera_size) for ln in det.lines]
    return replace(
        det, lines=[ln for ln in lines if len(ln.t) > 0],
        white=undistort_image(det.white, k, camera_size),
        black=undistort_image(det.black, k, camera_size),
        valid=undistort_image(det.valid, k, camera_size, cv2.INTER_NEAREST),
        white_rgb=undistort_image(det.white_rgb, k, camera_size),
        stats=dict(det.stats),
        dense=None if det.dense is None else det.dense.resampled(*observed_maps(k, camera_size)))


def max_displacement(k, camera_size: tuple[int, int]) -> float:
    """Largest displacement (camera px) the radial lens ``k`` = (k1, k2) makes within the
    frame: r (k1 r² + k2 r⁴) times the model's radius scale, over 0 <= r <= 1 (the corners)."""
    from ...planar import distortion_scale

    r = np.linspace(0.0, 1.0, 101)
    return float(np.abs(r * (k[0] * r ** 2 + k[1] * r ** 4)).max() * distortion_scale(camera_size)[2])


# --------------------------------------------------------------------------- the geometry step
class _HoldWarnings(logging.Filter):
    """Holds back the warnings a logger emits (the first, distorted fit's "only 80 % of the
    crossings fit" is a symptom the lens correction then cures)."""

    def __init__(self, name: str):
        super().__init__()
        self.logger = logging.getLogger(name)
        self.held: list[logging.LogRecord] = []

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.WARNING:
            self.held.append(record)
            return False
        return True

    def __enter__(self):
        self.logger.addFilter(self)
        return self

    def __exit__(self, *exc) -> None:
        self.logger.removeFilter(self)

    def release(self) -> None:
        for record in self.held:
            self.logger.handle(record)


def fit_with_lens(fit: Callable[[LineDetection], object], detection: LineDetection,
                  camera_size: tuple[int, int], *, correct: bool = True,
                  rough: Callable[[LineDetection], object] | None = None,
                  min_effect_px: float = MIN_EFFECT_PX, logger: str = __package__ + ".geometry"):
    """Run the geometry fit with the lens's radial distortion taken out.

    ``fit(detection) -> Calibration`` is the geometry stage's fit (kinks, fold, homographies);
    it reports, in ``meta["geometry"]["distortion"]``, the k1 that best straightens its planes'
    crossings (:func:`~.homography.estimate_radial_k1`) and the (k1, k2) that do it together
    (:func:`~.homography.estimate_radial_k12`). The lens is (k1, k2) when k2 removes at least
    :data:`MIN_EXPLAINED` of the misfit k1 alone leaves and moves some point of the frame by
    more than ``min_effect_px``, else (k1, 0). When that lens moves the frame by more than
    ``min_effect_px`` and removes at least :data:`MIN_EXPLAINED` of the crossings' RMS misfit
    (and ``correct``), the detection is undistorted with it (:func:`undistort_detection`) and
    fitted again; ``calib.camera_distortion`` is set to (k1, k2) and the homographies, fold,
    outline (and so the display rectangle) are in ideal camera pixels.
    ``meta["geometry"]["distortion"]`` then holds ``k1``, ``k2``, ``applied``, the largest
    displacement ``corner_px``, the RMS without / with the model, the k1-only and the two-term
    estimates with their RMS, and the residual k1 the second fit still sees.

    A lens strong enough that the first fit fails (too few crossings fit one homography) is
    estimated from ``rough(detection)`` (the same fit with a looser inlier distance) instead;
    the first fit's error is raised when that does not explain it. Warnings of the first fit
    (logger ``logger``) are held back, and repeated only when no correction follows.
    """
    from ...errors import CalibrationError

    first_error = None
    try:
        with _HoldWarnings(logger) as held:
            calib = fit(detection)
    except CalibrationError as exc:
        if not (correct and rough is not None):
            held.release()
            raise
        first_error = exc
        try:
            with _HoldWarnings(logger):
                calib = rough(detection)
        except CalibrationError:
            held.release()
            raise exc from None
    d0 = dict(calib.meta["geometry"].get("distortion", {}))
    k1 = float(d0.get("k1", 0.0))
    rms0, rms1 = d0.get("rms_px_without"), d0.get("rms_px")
    k, rms_k = (k1, 0.0), rms1
    # k2 too, where it clearly explains more of the misfit than k1 alone (and moves some point
    # of the frame visibly): with k2 = 0 in truth the 2-term fit only fits the noise.
    k12, rms12 = d0.get("k12"), d0.get("rms_px_k12")
    if k12 is not None and rms12 is not None and rms1 is not None and \
            rms12 < (1.0 - MIN_EXPLAINED) * rms1 and \
            max_displacement((0.0, float(k12[1])), camera_size) > min_effect_px:
        k, rms_k = (float(k12[0]), float(k12[1])), rms12
    corner_px = max_displacement(k, camera_size)
    info = {"k1": round(k[0], 5), "k2": round(k[1], 5), "corner_px": round(corner_px, 3),
            "rms_px_without": rms0, "rms_px": rms_k, "k1_only": round(k1, 5),
            "rms_px_k1_only": rms1, "k12_fit": k12, "rms_px_k12": rms12, "applied": False}
    # Worth it when the lens moves the corners visibly *and* explains part of the crossings'
    # misfit: on an ideal lens k1 is the estimate's noise and leaves the misfit as it was.
    explains = rms0 is not None and rms_k is not None and rms_k < (1.0 - MIN_EXPLAINED) * rms0
    if correct and corner_px > min_effect_px and explains:
        ideal = undistort_detection(detection, k, camera_size)
        calib = fit(ideal)
        residual = calib.meta["geometry"].get("distortion", {})
        info.update(applied=True, residual_k1=residual.get("k1"),
                    rms_px=residual.get("rms_px_without"), first_fit_failed=first_error is not None)
        calib.camera_distortion = np.array(k, np.float64)
        log.info("geometry: lens k1 = %.4f, k2 = %.4f (%.2f px at most) taken out; RMS %s -> %s px",
                 k[0], k[1], corner_px, info["rms_px_without"], info["rms_px"])
    else:
        held.release()
        if first_error is not None:
            raise first_error
        calib.camera_distortion = np.zeros(2, np.float64)
    calib.meta["geometry"]["distortion"] = info
    return calib


def check_lens_option(lens) -> tuple[float, float] | None:
    """The geometry stage's ``lens`` option as (k1, k2) floats (None stays None); InputError
    naming the problem otherwise."""
    if lens is None:
        return None
    try:
        k = tuple(float(v) for v in np.asarray(lens, np.float64).ravel())
    except (TypeError, ValueError):
        k = ()
    if len(k) != 2 or not all(np.isfinite(k)) or max(abs(v) for v in k) > 1.0:
        raise InputError(f"lens must be the camera's radial distortion (k1, k2), two finite "
                         f"numbers within -1..1 (a calibration's camera_distortion); got {lens!r}")
    return k


def lens_from(source, camera_size: tuple[int, int] | None = None) -> tuple[float, float] | None:
    """The ``lens`` option from what a user gives: None, (k1, k2), or a calibration (a
    :class:`~rtdefocus.calib.file.Calibration` or the path of its file) whose measured lens
    (``camera_distortion``) is taken, e.g. one made once on flat walls or a wall chart.

    ``camera_size`` (width, height), when given, is the camera being calibrated: the lens is
    normalised to the frame's corners, so a calibration of another frame shape is refused.

    Raises
    ------
    InputError
        Malformed (k1, k2), or a calibration that holds no lens (an older file, or one not made
        by the geometry stage) or was made at another frame shape.
    CalibrationFileError
        A path that is not a readable calibration file.
    """
    if isinstance(source, (str, os.PathLike)):
        from ..file import Calibration

        source = Calibration.load(source)
    if not hasattr(source, "camera_distortion"):
        return check_lens_option(source)
    path = source.meta.get("loaded_from", {}).get("path")
    where = repr(path) if path else "the calibration"
    if source.camera_distortion is None:
        raise InputError(f"{where} holds no lens (camera_distortion): it is an older calibration "
                         "or one not made by the geometry stage; calibrate on flat walls with this "
                         "version (`rtdefocus calibrate ... --stages geometry -o flat.npz`) and "
                         "take its lens, or give it as --lens K1,K2")
    if camera_size is not None and tuple(source.camera_size) != tuple(camera_size):
        (w0, h0), (w1, h1) = source.camera_size, camera_size
        if abs(w0 * h1 - w1 * h0) > 0.01 * w0 * h1:
            raise InputError(f"{where} was made with a {w0}x{h0} camera frame, this one is "
                             f"{w1}x{h1}: its lens is normalised to another frame shape; "
                             "calibrate the lens at this camera size")
        log.warning("the lens of %s was measured at %dx%d, this camera frame is %dx%d (same "
                    "shape: taken as it is)", where, w0, h0, w1, h1)
    return check_lens_option(source.camera_distortion)


def fit_with_known_lens(fit: Callable[[LineDetection], object], detection: LineDetection,
                        k: tuple[float, float], camera_size: tuple[int, int]):
    """Run the geometry fit with a known lens ``k`` = (k1, k2) taken out, instead of the one
    :func:`fit_with_lens` estimates from the walls.

    The walls' own crossings cannot tell a lens from walls that pillow: a sheet bulging
    towards the room bends the lines much as barrel distortion does. A lens measured once
    (on flat walls, or by any camera calibration) removes that doubt.
    ``meta["geometry"]["distortion"]`` holds ``k1``, ``k2``, ``given`` (True), ``applied``, the
    largest displacement ``corner_px`` and the k1 the fit still sees (``residual_k1``).
    """
    applied = lens_k(k) is not None
    calib = fit(undistort_detection(detection, k, camera_size) if applied else detection)
    residual = calib.meta["geometry"].get("distortion", {})
    calib.camera_distortion = np.array(k, np.float64)
    calib.meta["geometry"]["distortion"] = {
        "k1": round(k[0], 5), "k2": round(k[1], 5), "given": True, "applied": applied,
        "corner_px": round(max_displacement(k, camera_size), 3),
        "residual_k1": residual.get("k1"), "rms_px": residual.get("rms_px_without")}
    log.info("geometry: the given lens k1 = %.4f, k2 = %.4f taken out", k[0], k[1])
    return calib
