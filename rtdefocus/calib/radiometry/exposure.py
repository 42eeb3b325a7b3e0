"""Camera exposure checks: over- and under-exposure of the white frame (radiometry stage), and
exposure / white-balance drift between two white frames taken apart in time: the geometry
stage's first frame against the radiometry stage's first, that one against the radiometry
stage's last, and the white frame the PSF stage normalises by against one more taken at the
stage's end; without the radiometry stage, the geometry stage's first white frame against its
last (``white_end``).

A webcam's auto-exposure and auto white balance change its gain while the patterns change
(a dark dot pattern after a white frame brightens the next frames), which bends every ratio
the calibration measures. These checks stop the calibration early with the fix, rather than
letting it fail, or succeed wrongly, deep inside a stage.
"""

from __future__ import annotations

import logging

import numpy as np

from ...errors import CalibrationError
from .camera_response import linearize

log = logging.getLogger(__name__)

# Fraction of the lit area allowed to clip on the white frame before it is an error.
_CLIP_FRACTION = 0.05
# The white frame's bright end (95th percentile over the lit area, brightest channel) must
# reach this code; below it the dots drown in the camera's noise and quantisation.
_MIN_WHITE_CODE = 64.0
# Relative change of the white frame (median over the lit area, any channel) that is drift.
DRIFT_TOLERANCE = 0.02
#: A camera code (a mean of a few frames) at or above which a pixel is clipped: the
#: radiometry and PSF stages never read it as data.
CLIPPED = 254.0
#: Share of the lit camera pixels clipped (any channel) on the white frame above which a
#: camera whose exposure the calibration controls is turned down (:func:`lower_exposure`) ...
CLIP_LOWER = 0.02
#: ... by this factor at a time, until under :data:`CLIP_DONE` of them clip.
EXPOSURE_STEP = 0.6
CLIP_DONE = 0.002
_MAX_STEPS = 6

_LOCK_HINT = ("Lock the camera's auto-exposure and auto white balance: run `rtdefocus calibrate "
              "... --lock` (optionally --exposure MS), which sets them through OpenCV and says "
              "which property the driver refused; lock those with the camera's own tool "
              "(docs/hardware.md, 'Lock the camera': e.g. v4l2-ctl on Linux, or the camera's "
              "settings app), then calibrate again")


def check_exposure(white: np.ndarray, lit: np.ndarray, saturated: float = 250.0,
                   black: np.ndarray | None = None) -> None:
    """Raise :class:`CalibrationError` when the white frame (camera codes, (Hc, Wc, 3)) clips
    on more than 5 % of the ``lit`` camera pixels (lower the exposure) or stays dim (raise it).

    With ``black``, a white frame hardly above the black one on most of the lit area is its
    own error (the projector is off or the camera looks elsewhere: no exposure fixes that).
    """
    m = np.asarray(lit, bool)
    w = np.asarray(white, np.float32)[m]
    if len(w) == 0:
        return
    if black is not None:
        above = (w - np.asarray(black, np.float32)[m]).max(axis=1) > 4.0
        if above.mean() < 0.25:
            raise CalibrationError(
                f"the white frame is brighter than the black one on only {100 * above.mean():.0f}% "
                "of the lit camera pixels: is the projector on, the camera pointed at the surface, "
                "and the geometry calibration right?")
    clipped = float((w >= saturated).any(axis=1).mean())
    if clipped > _CLIP_FRACTION:
        raise CalibrationError(
            f"the camera is over-exposed: the projector's white frame clips at {100 * clipped:.0f}% "
            "of the lit pixels. Lower the camera's exposure or gain (or the projector's "
            "brightness) until the white is bright but not clipped, or give the calibration the "
            "camera's exposure control (`rtdefocus calibrate ... --lock`: it then turns the "
            "camera down itself), then calibrate again")
    top = float(np.percentile(w.max(axis=1), 95))
    if top < _MIN_WHITE_CODE:
        raise CalibrationError(
            f"the camera is under-exposed: the projector's white frame reaches only code "
            f"{top:.0f} of 255. Raise the camera's exposure or gain until the white is bright "
            "but not clipped, then calibrate again")


def clipped_share(white: np.ndarray, lit: np.ndarray, every: bool = False) -> float:
    """Share of the ``lit`` camera pixels where the frame ``white`` (codes) clips in any
    channel (:data:`CLIPPED`; ``every``: in every channel)."""
    m = np.asarray(lit, bool)
    if not m.any():
        return 0.0
    clipped = np.asarray(white)[m] >= CLIPPED
    return float((clipped.all(axis=1) if every else clipped.any(axis=1)).mean())


def check_clipping(white: np.ndarray, lit: np.ndarray, stage: str, every: bool = False) -> None:
    """Raise :class:`CalibrationError` when the white frame (codes) clips on more than 5 % of
    the ``lit`` camera pixels (``every``: in every channel, for a stage that reads a pixel's
    unclipped channels): a stage that leaves clipped pixels out would have too little left
    to measure there (a camera the calibration cannot turn down)."""
    share = clipped_share(white, lit, every)
    if share > _CLIP_FRACTION:
        raise CalibrationError(
            f"the camera is over-exposed: the white frame clips at {100 * share:.0f}% of the lit "
            f"pixels{' in every channel' if every else ''}, which the {stage} stage cannot "
            "measure. Lower the camera's exposure or gain "
            "(or the projector's brightness) until the white is bright but not clipped, or give "
            "the calibration the camera's exposure control (a ProCam with `exposure` and "
            "`set_exposure`, e.g. `rtdefocus calibrate --lock`), then calibrate again")


def lower_exposure(capture, lit: np.ndarray, white: np.ndarray) -> float | None:
    """Turn the camera's exposure down while the white frame clips, when the calibration
    controls it (``capture.exposure`` is not None).

    ``white`` is the white frame (codes) just taken at the current exposure. Nothing happens
    (no capture) unless it clips on more than :data:`CLIP_LOWER` of the ``lit`` pixels; then
    the exposure drops by :data:`EXPOSURE_STEP` at a time, one white capture after each,
    until under :data:`CLIP_DONE` clip. Returns the new exposure over the old one (what the
    linear light of every later frame is scaled by), or None when it did not change.
    """
    start = capture.exposure
    share = clipped_share(white, lit)
    if start is None or share <= CLIP_LOWER:
        return None
    pattern = np.full((capture.procam.projector_size[1], capture.procam.projector_size[0], 3),
                      255, np.uint8)
    exposure = start
    for _ in range(_MAX_STEPS):
        exposure = capture.set_exposure(exposure * EXPOSURE_STEP) or exposure * EXPOSURE_STEP
        share = clipped_share(capture(pattern), lit)
        if share <= CLIP_DONE:
            break
    log.warning("the white frame clipped: camera exposure lowered from %.4g to %.4g (%.1f%% of "
                "the lit pixels still clip)", start, exposure, 100 * share)
    return exposure / start


def drift(first: np.ndarray, later: np.ndarray, black: np.ndarray, lit: np.ndarray,
          camera_lut=1.0, gain: float = 1.0) -> np.ndarray:
    """(3,) relative change per channel of the white frame ``later`` against ``first`` (camera
    codes), in camera-linear light above ``black``: the median over the ``lit`` pixels whose
    white is clearly above black and not clipped. ``gain``: the change expected (the exposure
    of ``later`` over that of ``first``; ``black`` is ``later``'s), taken out."""
    b = linearize(black, camera_lut)
    f = linearize(first, camera_lut) - b / gain
    g = linearize(later, camera_lut) - b
    m = np.asarray(lit, bool) & (f.min(axis=2) > 0.05) & (np.maximum(first, later).max(axis=2) < 250)
    if m.sum() < 100:
        return np.zeros(3)
    return np.array([float(np.median(g[..., c][m] / f[..., c][m])) / gain - 1.0
                     for c in range(3)])


def check_drift(first: np.ndarray, later: np.ndarray, black: np.ndarray, lit: np.ndarray,
                camera_lut=1.0, *, stage: str = "radiometry",
                tolerance: float = DRIFT_TOLERANCE, gain: float = 1.0) -> np.ndarray:
    """Raise :class:`CalibrationError` naming the fix when the white frame changed by more than
    ``tolerance`` (any channel) between ``first`` and ``later`` (beyond the exposure change
    ``gain``, see :func:`drift`); returns the change (3,)."""
    d = drift(first, later, black, lit, camera_lut, gain)
    worst = int(np.argmax(np.abs(d)))
    if abs(d[worst]) > tolerance:
        what = "exposure" if np.all(np.sign(d) == np.sign(d[worst])) and \
            np.ptp(d) < 0.5 * abs(d[worst]) else "white balance"
        raise CalibrationError(
            f"the camera's {what} changed during the {stage} stage: the same white frame came "
            f"out {100 * d[worst]:+.1f}% ({'RGB'[worst]} channel; R/G/B "
            f"{', '.join(f'{100 * v:+.1f}%' for v in d)}) at its end than at its start. "
            + _LOCK_HINT)
    return d


def check_geometry_drift(capture, calib) -> np.ndarray | None:
    """The geometry stage's drift check, for a calibration without the radiometry stage (which
    checks the same span with the measured response): the stage's first white frame against
    its last (``white_end``, already in its sequence), so no extra capture. Returns the change
    (3,), or None when the stage did not take both frames.

    The camera's response is not measured without the radiometry stage, so the codes are read
    as sRGB, what webcams send: a linear camera's drift is then overstated about 2x, i.e. the
    check errs toward reporting an exposure that moved.
    """
    from ..geometry.lens import lit_mask_observed
    from .camera_response import known_response

    first, last, black = capture.first_white, capture.last_white, capture.first_black
    if first is None or last is None or black is None:
        return None
    f32 = np.float32
    return check_drift(first.astype(f32), last.astype(f32), black.astype(f32),
                       lit_mask_observed(calib), known_response("srgb"), stage="geometry")


def check_end_white(capture, calib, white: np.ndarray, black: np.ndarray,
                    camera_lut=1.0, *, stage: str = "psf") -> np.ndarray:
    """One more white capture at the end of a stage against ``white``, the white frame (camera
    codes) the stage measured everything against (the PSF stage normalises every dot by it):
    :func:`check_drift` of the two, the change (3,) returned."""
    from ..geometry.lens import lit_mask_observed

    wp, hp = calib.projector_size
    later = capture(np.full((hp, wp, 3), 255, np.uint8)).astype(np.float32)
    return check_drift(white, later, black, lit_mask_observed(calib), camera_lut, stage=stage)
