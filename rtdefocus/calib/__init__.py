"""Calibration: learn the geometry, radiometry and defocus kernels of a set-up through
``ProCam.capture`` only (DESIGN.md §1, §4; paper §2.1, §2.4)."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from ..checks import check_procam
from ..errors import CalibrationError, InputError, InputTypeError
from ..procam import ProCam
from .capture import Capturer, ProgressFn
from .diagnose import explain, view_warning
from .file import Calibration
from .geometry.lens import lens_from
from .geometry.stage import GeometryOptions, calibrate_geometry
from .psf import PsfOptions, calibrate_psf
from .radiometry.exposure import check_geometry_drift
from .radiometry.stage import RadiometryOptions, calibrate_radiometry

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Stage:
    """One calibration stage: the function that runs it and the dataclass of its options.

    Every stage has the same contract, ``run(calib, capture, options=None, **overrides) ->
    Calibration``: it takes the calibration so far (None for the first stage, geometry, which
    makes it), the :class:`Capturer` (the ProCam, the counts, the frame cache the stages
    share) and its options (an instance of ``options``, keyword overrides checked against its
    fields), and returns the calibration with its part filled.
    """

    run: Callable[..., Calibration]
    options: type

    def option_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in fields(self.options))


#: The stages, in the order they run; geometry makes the Calibration the others fill in.
STAGE_TABLE: dict[str, Stage] = {
    "geometry": Stage(calibrate_geometry, GeometryOptions),
    "radiometry": Stage(calibrate_radiometry, RadiometryOptions),
    "psf": Stage(calibrate_psf, PsfOptions),
}
STAGES = tuple(STAGE_TABLE)


def calibrate(procam: ProCam, *, stages: tuple[str, ...] = STAGES,
              progress: ProgressFn | None = None, save_captures: str | os.PathLike | None = None,
              **options) -> Calibration:
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
    save_captures : folder, optional
        Keep every pattern and capture there (lossless PNG) with a JSON index written last
        (:mod:`.captureset`); :func:`~.captureset.calibrate_from_captures` redoes the
        calibration from them bit for bit. A calibration that fails keeps its captures too
        (they replay to the same failure); one interrupted by the camera keeps no index.
    **options
        Stage options, passed to the stage whose options dataclass has that field
        (:class:`~.geometry.GeometryOptions`, :class:`~.radiometry.RadiometryOptions`,
        :class:`~.psf.PsfOptions`): geometry ``line_spacing``, ...; psf ``layout``
        ("default", "paper", "dense"), ...; geometry ``lens`` also takes a
        :class:`Calibration` or the path of a calibration file, whose measured lens is used
        (:func:`~.geometry.lens.lens_from`).

    Returns
    -------
    Calibration
        With ``meta["captures"]`` (per stage) and ``meta["seconds"]`` (per stage); where the
        calibration turned a clipping camera's exposure down, ``meta["exposure"]`` (``from``,
        ``to``: the camera stays at ``to``).

    Raises
    ------
    InputError
        An unknown stage or option (before the first capture; the message lists the valid
        options of each stage); :class:`~rtdefocus.errors.InputTypeError` for a ``procam``
        that is not a :class:`~rtdefocus.ProCam` (no sizes or no ``capture``).
    CalibrationError
        A stage could not learn what it needs from the captures. Before it is reported, two
        more captures check the likely causes (:mod:`.diagnose`): the set-up moved or the
        light changed since the start, or the camera sees only part of the projection; when
        one is found the message starts with it and its fix (``error.cause``).
    """
    check_procam(procam)
    if isinstance(stages, str) or not all(isinstance(s, str) for s in stages):
        raise InputTypeError(f"stages must be a tuple of stage names, e.g. ('geometry', 'psf'); "
                             f"got {stages!r}")
    if progress is not None and not callable(progress):
        raise InputTypeError(f"progress must be a function progress(stage, done, total) or None; "
                             f"got {type(progress).__name__}")
    unknown = [s for s in stages if s not in STAGES]
    if unknown or "geometry" not in stages:
        raise InputError(f"stages must include 'geometry' and be among {STAGES}; got {stages}")
    # Sort the options out before the first capture: a misspelt option must not cost a whole
    # calibration (minutes on real hardware) before it is reported.
    if options.get("lens") is not None:
        # A calibration (or its file) gives its measured lens; the capture set records numbers.
        options["lens"] = lens_from(options["lens"], tuple(procam.camera_size))
    chosen = {s: STAGE_TABLE[s] for s in STAGES if s in stages}
    per_stage = {s: {k: options.pop(k) for k in list(options) if k in st.option_names()}
                 for s, st in chosen.items()}
    if options:
        known = {s: sorted(st.option_names()) for s, st in chosen.items()}
        raise InputError(f"unknown calibration options {sorted(options)} for stages {stages}; "
                         f"each stage accepts {known}")
    recorder = None
    if save_captures is not None:
        from .captureset import CaptureRecorder

        saved_options = {k: v for st in per_stage.values() for k, v in st.items()}
        procam = recorder = CaptureRecorder(procam, save_captures)
    cap = Capturer(procam, progress)
    if recorder is not None:
        recorder.stage = lambda: cap.stage
    try:
        calib = _run_stages(procam, chosen, per_stage, cap)
    except CalibrationError as exc:
        if recorder is not None:
            recorder.finish(saved_options, tuple(chosen), outcome=f"failed: {exc}")
        raise
    if recorder is not None:
        recorder.finish(saved_options, tuple(chosen))
    return calib


def _run_stages(procam, chosen: dict, per_stage: dict, cap: Capturer) -> Calibration:
    """The stages of :func:`calibrate`, in order, through ``cap``; the Calibration."""
    timings = {}
    calib = None
    for name, st in chosen.items():
        t0 = time.perf_counter()
        try:
            calib = st.run(calib, cap, **per_stage[name])
            if name == "geometry" and "radiometry" not in chosen:
                # The radiometry stage checks the geometry stage's drift with the camera's
                # measured response; without it, the stage's own first and last white.
                drift = check_geometry_drift(cap, calib)
                calib.meta["geometry"]["white_drift"] = \
                    None if drift is None else np.round(drift, 4).tolist()
        except CalibrationError as exc:
            # Dots or lines not found are symptoms; name the likely cause (moved set-up,
            # changed light, partial view) when a quick check finds one.
            raise explain(exc, cap, name) from exc
        timings[name] = time.perf_counter() - t0
    calib.meta["captures"] = dict(cap.counts)
    if cap.exposure_changes:
        # The camera was turned down so its frames do not clip; it stays there.
        calib.meta["exposure"] = {"from": cap.exposure_changes[0][0],
                                  "to": cap.exposure_changes[-1][1]}
    calib.meta["seconds"] = {k: round(v, 2) for k, v in timings.items()}
    if hasattr(procam, "setup_record"):
        # Real hardware: the monitor and camera, so later commands find them again. A record
        # that cannot be made costs the convenience, never the calibration.
        try:
            calib.meta["hardware"] = procam.setup_record()
        except Exception as exc:  # noqa: BLE001
            log.warning("the monitor and camera could not be recorded (%s): pass --screen and "
                        "--camera to later commands", exc)
    warning = view_warning(cap)
    if warning:
        log.warning("calibration done, but %s", warning)
        calib.meta.setdefault("warnings", []).append(warning)
    log.info("calibration done: %d captures %s, %s", cap.total, cap.counts, calib.meta["seconds"])
    return calib


__all__ = ["calibrate", "Calibration", "Capturer", "STAGES", "STAGE_TABLE", "Stage",
           "GeometryOptions", "RadiometryOptions", "PsfOptions"]
