"""The PSF stage from another rig's dot captures: given dot positions, no pilot, no capturer.

:func:`calibrate_psf_from_dots` replays saved dot frames into the stage's own steps: each
frame's dots are solved by :func:`~.dots.measure_psfs` (the same per-dot least-squares fit,
background and cleaning), twice — first with a window from the dots' spacing, whose
measured radii stand in for the pilot (a :class:`~.pilot.RadiusModel` fitted per plane),
then with the windows that model predicts — and the kernels are averaged, cleaned and
blended into the kernel field F by :meth:`~.stage.PsfRun.fill`, as in :func:`~.stage.calibrate_psf`.
"""

from __future__ import annotations

import logging

import numpy as np

from ...errors import InputError
from ..capture import check_geometry
from ..file import Calibration
from .dots import Measurement, measure_psfs
from .pilot import RadiusModel, fold_code, support_bound
from .sampling import SamplePlan
from .stage import Dots, PsfOptions, PsfRun, psf_options

log = logging.getLogger(__name__)


class _Replay:
    """The one method of a capturer :func:`measure_psfs` calls: every pattern of one saved
    frame is that frame (its dots were placed, and kept apart, by the other rig)."""

    def __init__(self, frame: np.ndarray):
        self.frame = frame

    def mean(self, pattern, n):
        return self.frame


def _check_captures(calib: Calibration, captures) -> list[tuple[np.ndarray, np.ndarray]]:
    wp, hp = calib.projector_size
    wc, hc = calib.camera_size
    out = []
    for i, item in enumerate(captures):
        try:
            pts, frame = item
        except (TypeError, ValueError):
            raise InputError(f"capture {i} must be a pair (dot positions (N, 2), camera frame); "
                             f"got {type(item).__name__}") from None
        pts, frame = np.asarray(pts, np.float64), np.asarray(frame)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
            raise InputError(f"capture {i}: dot positions must be an (N, 2) array of projector "
                             f"px; got shape {pts.shape}")
        if (pts < 0).any() or (pts[:, 0] > wp - 1).any() or (pts[:, 1] > hp - 1).any():
            raise InputError(f"capture {i}: dot positions must lie in the {wp}x{hp} projector "
                             "frame; give them in the calibration's projector pixels")
        if frame.shape != (hc, wc, 3) or frame.dtype.kind not in "uf":
            raise InputError(f"capture {i}: the frame must be an RGB image of the camera's "
                             f"size ({hc}, {wc}, 3), uint8/uint16 or float codes; got "
                             f"{frame.dtype} {frame.shape}")
        out.append((np.rint(pts).astype(int), frame))
    return out


def _measure(calib, captures, radius_of, lut, dot_size) -> Measurement:
    """Every capture's dots through :func:`measure_psfs`, joined into one Measurement."""
    parts = [measure_psfs(calib, _Replay(frame), pts, radius_of(k, pts), averages=1,
                          camera_lut=lut, dot_size=dot_size)
             for k, (pts, frame) in enumerate(captures)]
    cat = {name: np.concatenate([getattr(p, name) for p in parts])
           for name in ("bound", "radius", "support", "sigma", "snr", "dots", "noise", "skipped")}
    return Measurement(psfs=[k for p in parts for k in p.psfs],
                       raw=[k for p in parts for k in p.raw], patterns=len(parts), averages=1,
                       captures=len(parts), **cat)


def calibrate_psf_from_dots(calib: Calibration, captures, *, dot_size: int = 1,
                            options: PsfOptions | None = None, **overrides) -> Calibration:
    """Fill ``calib``'s psf section (the kernel field F) from dot captures made elsewhere.

    Parameters
    ----------
    calib : Calibration
        With the geometry section (the camera <-> projector mapping the dots are solved
        through; required). Its radiometry's ``camera_lut`` linearises the frames when
        present; without it the camera is taken as linear. No black or white frame is
        needed: each dot's background is fitted around it. Filled in place and returned.
    captures : sequence of (points, frame)
        ``points`` (N, 2) projector px of the dots lit in that frame (their centres; each
        dot a ``dot_size`` square), ``frame`` (Hc, Wc, 3) RGB camera frame of them: uint8 /
        uint16 codes, or float codes (0..255) for the mean of several captures — keep the
        mean unrounded: a wide kernel's rim is a fraction of a code, and the stage itself
        averages ~20 captures per dot. Dots must be farther apart than their blur diameter
        plus a few px, and at least 3 per plane.
    dot_size : int
        Side of the projected square dots (px).
    options : PsfOptions, optional
        The stage's options; ``iso_tolerance`` and ``iso_distance`` (averaging along lines
        of equal blur) apply, the layout and capture options do not (the dots are given).
    **overrides
        Fields of :class:`~.stage.PsfOptions` replacing those of ``options``.

    Returns
    -------
    Calibration
        As :func:`~.stage.calibrate_psf`; ``meta["psf"]["layout"]`` is ``"given"``.

    Raises
    ------
    InputError
        A capture that is not (an (N, 2) array in the projector frame, an RGB frame of the
        camera's size).
    CalibrationError
        A dot outside the camera's view, or a plane with fewer than 3 measurable dots.
    """
    o = psf_options(options, **overrides)
    check_geometry(calib, "psf")
    caps = _check_captures(calib, captures)
    lut = calib.camera_lut if calib.camera_lut is not None else 1.0

    # First pass: each dot's window as wide as its frame's dot spacing allows (the light of
    # the nearest dot kept out), standing in for the pilot's radius.
    def from_spacing(_k, pts):
        if len(pts) < 2:
            return np.full(len(pts), 4.0)
        d = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        room = 0.5 * d.min(axis=1) - 3 - dot_size / 2.0
        b0, b1 = support_bound(np.array([0.0, 1.0]))      # affine in the radius: invert it
        return np.clip((room - b0) / (b1 - b0), 0.5, None)

    points = np.concatenate([p for p, _ in caps])
    index = {}
    for i, (x, y) in enumerate(points.tolist()):
        if (x, y) in index:
            raise InputError(f"the dot at projector pixel ({x}, {y}) is given twice; give each "
                             "position once (average its frames instead)")
        index[(x, y)] = i
    first = _measure(calib, caps, from_spacing, lut, dot_size)
    ok = ~first.skipped
    multi = calib.n_planes > 1
    planes = calib.plane_of(points[:, 0], points[:, 1]).astype(int) if multi \
        else np.zeros(len(points), int)
    model = RadiusModel(points=points[ok].astype(np.float64), radii=first.radius[ok])
    for p in range(calib.n_planes if multi else 1):
        model.fit(p, planes[ok] == p)
    if multi:
        model.folds = {fold_code(j): (int(a), int(b))
                       for j, (a, b) in enumerate(calib.layout.fold_planes)}

    def predicted(signed=False):
        out = np.empty(len(points))
        for p in np.unique(planes):
            sel = planes == p
            f = model.signed if signed else model
            out[sel] = f(points[sel].astype(np.float64), int(p))
        return out

    # Second pass: the windows of the fitted model, as the stage's measurement uses.
    radius = predicted()
    starts = np.cumsum([0] + [len(p) for p, _ in caps])
    meas = _measure(calib, caps, lambda k, _pts: radius[starts[k]:starts[k + 1]], lut, dot_size)
    plan = SamplePlan(layout="default", cross_fold=False, points=points, planes=planes,
                      kinds=np.array(["given"] * len(points)), radius=radius,
                      radius_signed=predicted(signed=True))
    run = PsfRun(calib, None, o, lut, 0, model)
    run.fill(calib, ("default", False), plan, Dots(index, meas, 1, len(caps)))
    calib.meta["psf"]["layout"] = "given"
    log.info("psf from %d captures: %d dots, radius %.2f..%.2f px", len(caps), len(points),
             meas.radius.min(), meas.radius.max())
    return calib


__all__ = ["calibrate_psf_from_dots"]
