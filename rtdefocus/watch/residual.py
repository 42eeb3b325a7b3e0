"""What the camera should see of a shown frame, and what a capture says changed.

The calibration's forward model predicts the camera's linear light at every projector pixel:
``L(x) = albedo(x) · (F P)(x) + ambient(x)`` with ``P`` the frame decoded through the projector
response and ``F`` the calibrated kernel field (DESIGN.md §3). A capture, linearised through
the camera's inverse response and resampled into projector pixels through the calibrated
homographies and lens, is compared with it there:

* geometry: per plane, the content's shift (projector px) inside the plane away from its folds
  and the frame's edge, between the blurred frame ``F P`` and the observation with the room
  light taken off and divided by the albedo: the wall's printed texture stays where it is
  when the projector moves, so only the projected content moves;
* light: ``observed ≈ gain · predicted + added · shape`` by least squares on the aligned
  prediction, ``shape`` the calibrated ambient map normalised to mean 1 (uniform when the
  calibration saw no ambient), so ``added`` is the mean camera light the room added;
* focus: the band-pass energy (difference of Gaussians) of the observation against that of
  the prediction. The resampling into projector pixels smooths the observation, so the ratio
  is below 1 on an unchanged set-up: a change in blur shows as a change of the ratio against
  its value while the calibration was known to be right.
"""

from __future__ import annotations

import threading

import numpy as np

from ..calib.file import Calibration
from ..errors import InputError
from .predictor import ResidualPredictor, ResidualReport, calibration_keys

__all__ = ["ResidualReport", "observe_proj", "predict_proj", "predictor_for", "residual_report"]

# The predictors of the calibrations reported on lately: a show runs with one calibration, and
# a mend replaces it with another, so two entries are enough.
_CACHE_SIZE = 2
_cache: list[tuple[tuple, ResidualPredictor]] = []
_cache_lock = threading.Lock()


def predictor_for(calib: Calibration, margin: int | None = None,
                  backend: str = "auto") -> ResidualPredictor:
    """The cached :class:`ResidualPredictor` of ``calib`` (built on first use, and again when
    the calibration's geometry, light or kernels change: only the changed part is rebuilt)."""
    key = (id(calib), calibration_keys(calib), margin, backend)
    with _cache_lock:
        for k, pred in _cache:
            if k == key:
                return pred
        # the latest predictor of the same settings lends the parts that did not change
        last = next((p for k, p in _cache if k[2:] == key[2:]), None)
    pred = ResidualPredictor(calib, backend=backend, margin=margin, reuse=last)
    with _cache_lock:
        _cache.insert(0, (key, pred))
        del _cache[_CACHE_SIZE:]
    return pred


def predict_proj(calib: Calibration, frame: np.ndarray) -> np.ndarray:
    """The camera's linear light expected at each projector pixel while ``frame`` is shown.

    Parameters
    ----------
    calib : Calibration; without radiometry the albedo is 1 and the ambient 0, without
        kernels the blur is the identity.
    frame : (Hp, Wp, 3) uint8 projector frame.

    Returns
    -------
    (Hp, Wp, 3) float32.
    """
    return predictor_for(calib).predict(frame)


def observe_proj(calib: Calibration, capture: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A camera frame as linear light at each projector pixel, and where the camera sees it.

    The camera's inverse response is ``calib.camera_lut`` (a linear camera when None).

    Returns
    -------
    (Hp, Wp, 3) float32 and (Hp, Wp) bool.
    """
    return predictor_for(calib).observe(capture)


def residual_report(calib: Calibration, frame: np.ndarray, capture: np.ndarray,
                    margin: int | None = None, min_pixels: int = 400,
                    predictor: ResidualPredictor | None = None) -> ResidualReport:
    """Compare a capture with the calibration's prediction of it: light and geometry.

    Parameters
    ----------
    calib : the calibration the show runs with (geometry; radiometry and kernels when
        present; ``camera_lut`` for a camera that is not linear).
    frame : (Hp, Wp, 3) uint8, the projector frame shown when ``capture`` was taken.
    capture : (Hc, Wc, 3) uint8 camera frame.
    margin : projector px kept away from the frame's edge and the folds (None: 4 % of the
        smaller side, at least 8): content moved across them would read as a change.
    min_pixels : a plane with fewer watched pixels gets a NaN shift.
    predictor : the :class:`ResidualPredictor` of ``calib`` to use (then ``margin`` is its
        own); by default a cached one (:func:`predictor_for`: OpenCL when a device exists).

    Returns
    -------
    ResidualReport
    """
    if predictor is None:
        predictor = predictor_for(calib, margin)
    elif predictor.calib is not calib:
        raise InputError("the predictor was built for another calibration; build one with "
                         "ResidualPredictor(calib) or leave predictor=None")
    elif margin is not None and int(margin) != predictor.margin:
        raise InputError(f"margin={margin} differs from the predictor's {predictor.margin}; "
                         "pass the margin to ResidualPredictor, or leave it out here")
    return predictor.report(frame, capture, min_pixels=min_pixels)
