"""Kernel layouts compared on one measurement (evaluation only, not the product).

:func:`calibrate_psf_layouts` runs the PSF stage (:class:`rtdefocus.calib.psf.PsfRun`) for
several ``(layout, cross_fold)`` at once: all layouts' dots share one pilot and one set of
patterns, each pattern averaged the same number of times, so every PSF has the noise it would
have in a run of its own layout and the layouts are compared on equal terms at a fraction of
the captures.
"""

from __future__ import annotations

import copy

from ..calib.capture import Capturer
from ..calib.file import Calibration
from ..calib.psf import PsfOptions, PsfRun, psf_options

__all__ = ["calibrate_psf_layouts"]


def calibrate_psf_layouts(calib: Calibration, capture: Capturer,
                          options: PsfOptions | None = None, *, layouts=(("default", False),),
                          **overrides) -> dict:
    """:func:`rtdefocus.calib.psf.calibrate_psf` for several ``(layout, cross_fold)``, measured
    together.

    Parameters
    ----------
    calib : Calibration with the geometry section; the first layout fills it, the others are
        filled into copies.
    capture : Capturer (the ProCam, counts, frame cache; stage ``"psf"``).
    layouts : sequence of ``(layout, cross_fold)``.
    options, **overrides : as for ``calibrate_psf`` (``layout`` and ``cross_fold`` are ignored:
        ``layouts`` says which).

    Returns
    -------
    dict ``{(layout, cross_fold): Calibration}``.
    """
    o = psf_options(options, **overrides)
    keys = [(str(lay), bool(cf)) for lay, cf in layouts]
    run = PsfRun.start(calib, capture, o, keys)
    plans = {key: run.plan(key) for key in keys}
    dots = run.measure(list(plans.values()))
    return {key: run.fill(calib if n == 0 else copy.deepcopy(calib), key, plan, dots)
            for n, (key, plan) in enumerate(plans.items())}
