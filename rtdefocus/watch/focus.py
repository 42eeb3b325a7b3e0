"""The size of a focus change from the content: the kernel radius scale whose prediction
brings the residual report's band-pass ratio back to its level while the model was right."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..calib.file import Calibration
from .levels import band_level
from .mend import rescale_radii
from .residual import ResidualReport

__all__ = ["fit_band_scale"]


def fit_band_scale(calib: Calibration, shown: np.ndarray, capture: np.ndarray, level: float,
                   report: Callable[..., ResidualReport], lo: float = 0.5, hi: float = 2.0,
                   tol: float = 0.005) -> float:
    """The radius scale (:func:`~rtdefocus.watch.mend.rescale_radii`) whose prediction brings
    the band ratio of ``capture`` back to ``level``, its value while the model was right (the
    ratio grows with the scale: a blurrier prediction has less band-pass energy). Regula falsi
    (Illinois) on log scale; ``report`` is the residual report function.

    The ratio, not the residual, is matched: the observation is smoothed by its resampling
    into projector pixels, so the least residual lies at a larger scale than the true one."""
    def g(log_s: float) -> float:
        c = calib if log_s == 0.0 else rescale_radii(calib, math.exp(log_s))
        return math.log(band_level(report(c, shown, capture)) / level)

    a, b = 0.0, 0.0
    fa = g(0.0)
    # Bracket the root from s = 1 outwards.
    step = math.log(1.15) if fa < 0 else -math.log(1.15)
    b = step
    fb = g(b)
    while fa * fb > 0:
        if abs(b) >= math.log(hi if step > 0 else 1 / lo):
            return math.exp(b)
        a, fa = b, fb
        b = b + step
        fb = g(b)
    side = 0
    for _ in range(12):
        c = b - fb * (b - a) / (fb - fa)
        fc = g(c)
        if abs(b - a) < tol or fc == 0:
            return math.exp(c)
        if fc * fb < 0:
            a, fa = b, fb
            if side == -1:
                fa /= 2
            side = -1
        else:
            if side == 1:
                fa /= 2
            side = 1
        b, fb = c, fc
    return math.exp(b)
