"""The geometry of a set-up from a dense correspondence map made by another tool.

A structured-light tool of another rig (a DSLR's Gray code and phase shift, a commercial
scanner) gives, per camera pixel, the projector point (x, y) it sees and whether it decoded.
:func:`calibrate_from_correspondences` turns that map into a :class:`~.file.Calibration` with
the geometry stage itself, so the planes, folds, residual fields and lens come from the same
fitter and checks as a live calibration: :class:`MapProCam` is a ProCam whose "camera" shows
each pattern through the map (every camera pixel takes the pattern's value at its projector
point, black where the map is not valid), and the geometry stage calibrates it as it would a
real set-up. Its line patterns are binary and wide enough that the sampled ridges keep their
centres, so the map's sub-pixel precision carries through.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ..errors import InputError
from .file import Calibration

log = logging.getLogger(__name__)

__all__ = ["MapProCam", "calibrate_from_correspondences"]

# Camera code of the map's full white: below 255, so nothing the stage reads is clipped.
_WHITE = 200.0


class MapProCam:
    """A ProCam that renders each pattern through a dense projector <- camera map.

    Parameters
    ----------
    proj_xy : (Hc, Wc, 2) float, the projector point (x, y) each camera pixel sees (pixel
        centres at integers).
    valid : (Hc, Wc) bool, where ``proj_xy`` holds a decoded point.
    projector_size : (width, height) of the projector.
    """

    def __init__(self, proj_xy: np.ndarray, valid: np.ndarray, projector_size: tuple[int, int]):
        proj_xy = np.asarray(proj_xy, np.float64)
        valid = np.asarray(valid)
        if proj_xy.ndim != 3 or proj_xy.shape[2] != 2:
            raise InputError(f"proj_xy must be (Hc, Wc, 2): each camera pixel's projector (x, y); "
                             f"got shape {proj_xy.shape}")
        if valid.shape != proj_xy.shape[:2] or valid.dtype != bool:
            raise InputError(f"valid must be a bool mask of the camera's shape {proj_xy.shape[:2]}; "
                             f"got {valid.shape} {valid.dtype}")
        try:
            wp, hp = (int(v) for v in projector_size)
        except (TypeError, ValueError):
            raise InputError(f"projector_size must be (width, height); got {projector_size!r}") \
                from None
        if wp < 1 or hp < 1:
            raise InputError(f"projector_size must be positive; got {projector_size!r}")
        bad = valid & ~np.isfinite(proj_xy).all(axis=2)
        if bad.any():
            y, x = np.argwhere(bad)[0]
            raise InputError(f"proj_xy is not finite at {int(bad.sum())} valid camera pixels "
                             f"(the first at x={x}, y={y}); mark them invalid in `valid`")
        if valid.mean() < 0.01:
            raise InputError(f"only {int(valid.sum())} camera pixels are valid in the map: no "
                             "projector light to calibrate from")
        self.projector_size = (wp, hp)
        self.camera_size = (proj_xy.shape[1], proj_xy.shape[0])
        xy = np.where(valid[..., None], proj_xy, -1e4)   # invalid: far outside, black
        self._map_x = xy[..., 0].astype(np.float32)
        self._map_y = xy[..., 1].astype(np.float32)

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        """The camera frame of ``pattern`` seen through the map (uint8 RGB)."""
        # A little smoothing first: a camera pixel wider than a projector pixel would alias a
        # thin line; a symmetric blur keeps the line's centre.
        src = cv2.GaussianBlur(np.asarray(pattern, np.float32), (0, 0), 0.7)
        frame = cv2.remap(src, self._map_x, self._map_y, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        return np.clip(np.rint(frame * (_WHITE / 255.0)), 0, 255).astype(np.uint8)


def calibrate_from_correspondences(proj_xy: np.ndarray, valid: np.ndarray,
                                   projector_size: tuple[int, int], **options) -> Calibration:
    """The geometry of a set-up from another tool's dense correspondence map.

    Parameters
    ----------
    proj_xy : (Hc, Wc, 2) float
        For each camera pixel, the projector point (x, y) it sees (pixel centres at integer
        coordinates, OpenCV's convention; projector pixels, sub-pixel precision welcome).
    valid : (Hc, Wc) bool
        Where the map holds a decoded point (False: no projector light, a shadow, a pixel the
        tool could not decode).
    projector_size : (width, height)
        The projector's size in pixels; the camera's is the map's.
    **options
        Geometry options (:class:`~.geometry.stage.GeometryOptions`): ``planes`` ("auto" or
        their number), ``residual`` (a smooth residual per plane for walls that are planes only
        nearly), ``undistort`` (fit the camera lens's radial distortion: False when the map is
        already in ideal camera pixels), ``line_spacing``, ...

    Returns
    -------
    Calibration
        The geometry section (homographies, folds, residual fields, lens, lit outline), as the
        geometry stage makes it; ``meta["geometry"]["source"]`` is ``"correspondences"``. The
        radiometry and PSF sections need captures of the set-up (:func:`~rtdefocus.calibrate`).

    Raises
    ------
    InputError
        A map of the wrong shape, non-finite values where it is valid, almost nothing valid,
        or an unknown option.
    CalibrationError
        The map shows no surface the fitter accepts (the message says what it found).
    """
    from . import calibrate

    procam = MapProCam(proj_xy, valid, projector_size)
    calib = calibrate(procam, stages=("geometry",), **options)
    calib.meta["geometry"]["source"] = "correspondences"
    # The map has no light of its own: the rendered frames' drift and capture count say nothing.
    calib.meta["geometry"].pop("white_drift", None)
    calib.meta.pop("captures", None)
    log.info("geometry from a %dx%d correspondence map (%.0f %% valid): %d plane(s)",
             procam.camera_size[0], procam.camera_size[1], 100 * np.mean(valid), calib.n_planes)
    return calib
