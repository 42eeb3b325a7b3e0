"""Calibration: learn the geometry, radiometry and defocus kernels of a set-up through
``ProCam.capture`` only (DESIGN.md §1, §4; paper §2.1, §2.4)."""

from __future__ import annotations

import logging
import time

from ..procam import ProCam
from .capture import Capturer, ProgressFn
from .file import Calibration

log = logging.getLogger(__name__)

STAGES = ("geometry", "radiometry", "psf")


def calibrate(procam: ProCam, *, stages: tuple[str, ...] = STAGES,
              progress: ProgressFn | None = None, **options) -> Calibration:
    """Calibrate a projector-camera set-up.

    Parameters
    ----------
    procam : ProCam
        Anything with ``projector_size``, ``camera_size`` and ``capture(pattern)``.
    stages : tuple of str
        Which stages to run, in order: ``"geometry"`` (always needed), ``"radiometry"``,
        ``"psf"``.
    progress : callable(stage, done, total), optional
        Called after every capture (the CLI draws a progress bar from it).
    **options
        Stage options, passed to the stage that knows them (see each stage's function):
        geometry: ``line_spacing``, ...; psf: ``layout`` ("default", "paper", "dense"), ...

    Returns
    -------
    Calibration
        With ``meta["captures"]`` (per stage) and ``meta["seconds"]`` (per stage).
    """
    from .geometry import calibrate_geometry

    unknown = [s for s in stages if s not in STAGES]
    if unknown or "geometry" not in stages:
        from ..errors import InputError
        raise InputError(f"stages must include 'geometry' and be among {STAGES}; got {stages}")
    cap = Capturer(procam, progress)
    timings = {}
    t0 = time.perf_counter()
    calib = calibrate_geometry(procam, capture=cap, **_take(options, "geometry"))
    timings["geometry"] = time.perf_counter() - t0
    if "radiometry" in stages:
        from .radiometry import calibrate_radiometry
        t0 = time.perf_counter()
        calibrate_radiometry(procam, calib, capture=cap, **_take(options, "radiometry"))
        timings["radiometry"] = time.perf_counter() - t0
    if "psf" in stages:
        from .psf import calibrate_psf
        t0 = time.perf_counter()
        calibrate_psf(procam, calib, capture=cap, **_take(options, "psf"))
        timings["psf"] = time.perf_counter() - t0
    if options:
        from ..errors import InputError
        raise InputError(f"unknown calibration options {sorted(options)}")
    calib.meta["captures"] = dict(cap.counts)
    calib.meta["seconds"] = {k: round(v, 2) for k, v in timings.items()}
    log.info("calibration done: %d captures %s, %s", cap.total, cap.counts, calib.meta["seconds"])
    return calib


# Which keyword options each stage accepts; each stage module lists its own in OPTIONS.
def _take(options: dict, stage: str) -> dict:
    import importlib
    mod = importlib.import_module(f"{__name__}.{stage}")
    names = getattr(mod, "OPTIONS", ())
    return {k: options.pop(k) for k in list(options) if k in names}


__all__ = ["calibrate", "Calibration", "Capturer", "STAGES"]
