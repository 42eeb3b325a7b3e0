"""The ``rtdefocus aim`` loop: a camera, the projector's window holding a pattern, and a
preview window on the laptop showing :func:`rtdefocus.hardware.aim.compose_aim_frame`.

Thin on purpose: every picture comes from :mod:`rtdefocus.hardware.aim`; the windows are
anything with ``size``, ``show(frame)`` and ``poll() -> keys`` (tests pass fakes or Xvfb
windows), the camera anything with ``read()`` and ``drain(until)``.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from .aim import PATTERN_KEYS, AimView, aim_pattern, analyse, compose_aim_frame, find_projected_area

log = logging.getLogger(__name__)

QUIT_KEYS = frozenset({"q", "escape", "close"})


def _capture(camera, projector, pattern: np.ndarray, settle: float) -> np.ndarray:
    t = projector.show(pattern)
    t = float(t) if t is not None else time.perf_counter()
    camera.drain(t + settle, min_frames=1)
    return camera.read()


def learn_area(camera, projector, settle: float = 0.3):
    """Show white, then black; the projected area from their difference (None when the
    camera does not see the projection)."""
    w, h = projector.size
    white = _capture(camera, projector, np.full((h, w, 3), 255, np.uint8), settle)
    black = _capture(camera, projector, np.zeros((h, w, 3), np.uint8), settle)
    area = find_projected_area(white, black)
    if area is None:
        log.warning("the camera does not see the projection: white and black look the same. "
                    "Aim the camera at the projected area and check --screen")
    return area


def run_aim(camera, projector, preview, *, calib=None, pattern: str = "checker",
            settle: float = 0.3, max_frames: int | None = None) -> AimView | None:
    """Hold ``pattern`` on ``projector`` and show the analysed camera picture in ``preview``
    until q/Esc (or ``max_frames`` camera frames). Keys in either window: w/g/c switch the
    pattern, r finds the projected area again. Returns the last :class:`AimView`."""
    size = tuple(projector.size)
    area = learn_area(camera, projector, settle)
    projector.show(aim_pattern(pattern, size))
    view, frames = None, 0
    while max_frames is None or frames < max_frames:
        keys = list(projector.poll()) + list(preview.poll())
        if QUIT_KEYS & set(keys):
            break
        for key in keys:
            if key in PATTERN_KEYS and PATTERN_KEYS[key] != pattern:
                pattern = PATTERN_KEYS[key]
                projector.show(aim_pattern(pattern, size))
            elif key == "r":
                area = learn_area(camera, projector, settle)
                projector.show(aim_pattern(pattern, size))
        # The area is learnt from white and black (at the start and on r), not from live
        # frames: just after a switch the camera still shows the previous pattern.
        frame = camera.read()
        view = analyse(frame, area, pattern=pattern, projector_size=size, calib=calib)
        preview.show(compose_aim_frame(frame, area=view.area, clipped=view.clipped,
                                       regions=view.regions, readings=view.readings,
                                       pattern=pattern, size=tuple(preview.size)))
        frames += 1
    return view
