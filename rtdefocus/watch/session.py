"""What a watched show needs around the :class:`~rtdefocus.watch.Watcher`: the camera's view of
the show, a clock of show time for shows that do not run in real time, a virtual set-up that
changes on a timeline, and the mended calibration saved beside the original."""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..calib.file import Calibration, npz_path
from ..errors import InputError

log = logging.getLogger(__name__)


def camera_view(procam) -> Callable[[np.ndarray], np.ndarray]:
    """``look(shown_projector_frame) -> camera frame`` for a :class:`Watcher`.

    A procam with a ``look()`` method (hardware: the camera frame of whatever the show's
    window shows, no pattern projected) is asked for that; otherwise (the virtual set-up)
    ``procam.capture`` renders the camera's view of the frame shown.
    """
    look = getattr(procam, "look", None)
    if callable(look):
        return LiveView(procam)
    return procam.capture


class LiveView:
    """``look(shown_projector_frame)`` of a camera that watches a live show (``procam.look()``:
    the camera frame of whatever the show's window shows, taken a little after the call).

    :attr:`looked_at` (``procam.looked_at``, ``time.perf_counter`` seconds) says when the picture
    the camera saw was on the wall: a :class:`Watcher` on the same clock compares the capture
    with the frame it was offered last before then, not with the frame offered when the look
    started (on moving content the two differ by the camera's latency).
    """

    def __init__(self, procam):
        self.procam = procam

    def __call__(self, shown: np.ndarray) -> np.ndarray:
        return self.procam.look()

    @property
    def looked_at(self) -> float | None:
        """When the last look's picture was on the wall (None before a look)."""
        return getattr(self.procam, "looked_at", None)


class FrameClock:
    """Show time by frame count: the n-th call returns ``n / fps`` (from 0).

    The Watcher reads its clock once per frame offered, so with this clock a show rendered
    to a file (faster or slower than real time) is watched at its own pace, deterministically.
    """

    def __init__(self, fps: float):
        if not (np.isfinite(fps) and fps > 0):
            raise InputError(f"fps must be a positive number; got {fps!r}")
        self.fps = float(fps)
        self.frames = 0

    def __call__(self) -> float:
        t = self.frames / self.fps
        self.frames += 1
        return t

    @property
    def now(self) -> float:
        """The show time of the last frame counted (0 before any)."""
        return max(self.frames - 1, 0) / self.fps


def timeline_view(procam, timeline, clock: FrameClock) -> Callable[[np.ndarray], np.ndarray]:
    """``look`` for a :class:`~rtdefocus.watch.Watcher` on a virtual set-up that changes on
    ``timeline`` (:class:`~rtdefocus.sim.Timeline`): the events due by the show time are
    applied before the camera renders the frame shown."""
    def look(shown: np.ndarray) -> np.ndarray:
        for ev in timeline.advance(procam, clock.now):
            log.info("set-up changed at %.2f s: %s %s", ev.t, ev.kind, ev.params)
        return procam.capture(shown)
    return look


def watched_path(path: str | os.PathLike) -> Path:
    """Where the mended calibration of ``path`` is saved: ``NAME.watched.npz`` beside it."""
    path = npz_path(Path(path))
    return path.with_name(path.stem + ".watched.npz")


def save_watched(calib: Calibration, original: str | os.PathLike) -> Path:
    """Save ``calib`` (a watcher's mended calibration) beside ``original``, atomically
    (:meth:`Calibration.save` writes a temporary file and renames it). Returns the path."""
    path = watched_path(original)
    if path.resolve() == npz_path(Path(original)).resolve():
        raise InputError(f"the watched calibration would overwrite the original {original}")
    return calib.save(path)
