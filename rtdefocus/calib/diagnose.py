"""Causes, not symptoms: when a calibration stage fails (dots or lines not found where they
should be), check the cheap likely causes before reporting.

Two checks, two captures (a white and, when none was kept, a black frame):

* **moved / light changed**: a fresh white frame against the first white frame of the
  calibration (kept by :class:`~.capture.Capturer`). A global shift of the lit area means the
  camera or the projector moved; a change of level with no shift means the light changed
  (room lights, daylight, the projector's lamp or the camera's auto-exposure).
* **partial view**: the lit area (white minus black) reaching the camera frame's edges means
  the camera does not see the whole projection, so dots and lines near those edges are lost.

:func:`explain` turns the stage's error into one whose message starts with the cause and its
fix and keeps the original symptom; with no cause found the original error stands.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import CalibrationError
from ..imageio import to_grey
from .capture import Capturer

log = logging.getLogger(__name__)

__all__ = ["Cause", "find_cause", "explain", "MIN_SHIFT_PX", "MAX_LEVEL_CHANGE", "EDGE_LIT"]

#: A fresh white frame shifted by more than this (camera px) from the first: the set-up moved.
MIN_SHIFT_PX = 1.5
#: Mean |fresh − first| over the lit area, relative to its contrast, above which the light changed.
MAX_LEVEL_CHANGE = 0.1
#: Share of one frame edge's pixels that are lit above which the projection runs off that edge.
EDGE_LIT = 0.02
_MIN_CONTRAST = 10.0      # camera codes: white − black where the projector lights the surface


@dataclass(frozen=True)
class Cause:
    """A likely cause of a failed stage: ``kind`` ("moved", "light", "partial-view"), the
    ``message`` naming it and the fix, and the measurements behind it."""

    kind: str
    message: str
    details: dict


def _lit(white: np.ndarray, black: np.ndarray) -> np.ndarray:
    diff = white - black
    hi = float(np.percentile(diff, 99.5))
    return diff > max(_MIN_CONTRAST, 0.2 * hi)


def _shift(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Translation (dx, dy) of ``b`` against ``a`` (phase correlation: any size of shift)."""
    win = cv2.createHanningWindow((a.shape[1], a.shape[0]), cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(a.astype(np.float32), b.astype(np.float32), win)
    return float(dx), float(dy)


def find_cause(capture: Capturer) -> Cause | None:
    """Check whether the set-up moved, the light changed, or the camera sees only part of the
    projection (two captures, counted as stage ``"diagnose"``); None when none of these."""
    wp, hp = capture.procam.projector_size
    ref_white, ref_black = capture.first_white, capture.first_black
    capture.begin("diagnose", 1 if ref_black is not None else 2)
    white = to_grey(capture(np.full((hp, wp, 3), 255, np.uint8)))
    black = to_grey(ref_black if ref_black is not None else
                  capture(np.zeros((hp, wp, 3), np.uint8)))
    lit = _lit(white, black)
    if ref_white is not None:
        ref = to_grey(ref_white)
        ref_lit = _lit(ref, black)
        if ref_lit.mean() > 0.01 or lit.mean() > 0.01:
            dx, dy = _shift(ref, white)
            shift = math.hypot(dx, dy)
            both = ref_lit & lit
            contrast = float(np.mean((ref - black)[both])) if both.any() else 0.0
            change = float(np.mean(np.abs(white - ref)[both])) / contrast if contrast > 0 else 1.0
            moved_area = float((ref_lit ^ lit).sum()) / max(float(ref_lit.sum()), 1.0)
            details = {"shift_px": round(shift, 2), "dx": round(dx, 2), "dy": round(dy, 2),
                       "level_change": round(change, 4), "lit_area_change": round(moved_area, 4)}
            if shift > MIN_SHIFT_PX:
                return Cause("moved", (
                    f"the set-up moved since the start of calibration: a fresh white frame is "
                    f"shifted by {shift:.1f} camera px ({dx:+.1f}, {dy:+.1f}) from the one "
                    "captured at the start, so the geometry learnt then no longer holds. Fix "
                    "the camera and the projector firmly (tripod; auto-focus and image "
                    "stabilisation off), keep the room still, and calibrate again from the "
                    "start"), details)
            if change > MAX_LEVEL_CHANGE:
                return Cause("light", (
                    f"the light changed since the start of calibration: a fresh white frame "
                    f"differs by {100 * change:.0f} % of the projector's contrast from the one "
                    "captured at the start, with no shift. Keep the room lights and daylight "
                    "steady, lock the camera's exposure, gain and white balance, let the "
                    "projector warm up, and calibrate again"), details)
    return partial_view(lit)


def partial_view(lit: np.ndarray) -> Cause | None:
    """The ``"partial-view"`` cause when the lit area (camera-sized bool mask) runs off the
    camera frame's edges, else None."""
    edges = {"top": lit[:2].mean(), "bottom": lit[-2:].mean(), "left": lit[:, :2].mean(),
             "right": lit[:, -2:].mean()}
    cut = [name for name, share in edges.items() if share > EDGE_LIT]
    if cut:
        shares = ", ".join(f"{name} {100 * edges[name]:.0f} %" for name in cut)
        return Cause("partial-view", (
            f"the camera does not see the whole projection: the lit area runs off the camera "
            f"frame's {' and '.join(cut)} edge{'s' if len(cut) > 1 else ''} (share of the edge "
            f"lit: {shares}), so dots and lines there are lost. Turn or move the camera, or zoom "
            "out, until the whole projected area is inside the frame with a margin, and "
            "calibrate again"), {"edges_lit": {k: round(float(v), 4) for k, v in edges.items()}})
    return None


def view_warning(capture: Capturer) -> str | None:
    """After a calibration that succeeded: a warning when its first white frame shows the
    projection running off the camera frame (no capture needed). Lost dots near the edge were
    filled from their neighbours and the display rectangle stays inside what the camera saw,
    but the user should know."""
    if capture.first_white is None or capture.first_black is None:
        return None
    cause = partial_view(_lit(to_grey(capture.first_white), to_grey(capture.first_black)))
    return None if cause is None else cause.message


def explain(error: CalibrationError, capture: Capturer, stage: str) -> CalibrationError:
    """``error`` with its likely cause put first (a new CalibrationError with ``cause`` set and
    the original chained), or ``error`` itself when no cause is found or the checks fail."""
    try:
        cause = find_cause(capture)
    except Exception as exc:  # the diagnosis must never hide the original failure
        log.warning("could not check the causes of the failed %s stage: %s", stage, exc)
        return error
    if cause is None:
        log.info("%s stage failed; the set-up did not move, the light is steady and the camera "
                 "sees the whole projection", stage)
        return error
    log.info("%s stage failed; likely cause %s %s", stage, cause.kind, cause.details)
    new = CalibrationError(f"{cause.message}. (The {stage} stage failed with: {error})")
    new.cause = cause
    new.__cause__ = error
    return new
