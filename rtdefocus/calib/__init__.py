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
    import importlib

    from ..errors import InputError

    unknown = [s for s in stages if s not in STAGES]
    if unknown or "geometry" not in stages:
        raise InputError(f"stages must include 'geometry' and be among {STAGES}; got {stages}")
    # Sort the options out before the first capture: a misspelt option must not cost a whole
    # calibration (minutes on real hardware) before it is reported.
    modules = {s: importlib.import_module(f"{__name__}.{s}") for s in STAGES if s in stages}
    per_stage = {s: {k: options.pop(k) for k in list(options) if k in getattr(m, "OPTIONS", ())}
                 for s, m in modules.items()}
    if options:
        known = {s: sorted(getattr(m, "OPTIONS", ())) for s, m in modules.items()}
        raise InputError(f"unknown calibration options {sorted(options)} for stages {stages}; "
                         f"each stage accepts {known}")
    cap = Capturer(procam, progress)
    timings = {}
    calib = None
    for stage, mod in modules.items():
        t0 = time.perf_counter()
        if stage == "geometry":
            calib = mod.calibrate_geometry(procam, capture=cap, **per_stage[stage])
        else:
            getattr(mod, f"calibrate_{stage}")(procam, calib, capture=cap, **per_stage[stage])
        timings[stage] = time.perf_counter() - t0
    calib.meta["captures"] = dict(cap.counts)
    calib.meta["seconds"] = {k: round(v, 2) for k, v in timings.items()}
    log.info("calibration done: %d captures %s, %s", cap.total, cap.counts, calib.meta["seconds"])
    return calib


__all__ = ["calibrate", "Calibration", "Capturer", "STAGES"]
