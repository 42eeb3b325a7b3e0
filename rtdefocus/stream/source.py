"""What every frame source hands out: :class:`Frame`, and the :class:`Source` base class.

A module of its own so that the sources in other modules (PyAV video, screen capture) and
:mod:`~rtdefocus.stream.sources`, which opens them by name, all build on it without importing
each other.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One input frame.

    Attributes
    ----------
    index : int
        Position in the source, from 0; strictly increasing in the order frames are read.
    image : ndarray, (H, W, 3) uint8
        RGB.
    t_read : float
        ``time.perf_counter()`` when the frame was read (for latency).
    name : str or None
        File name of a slide.
    """

    index: int
    image: np.ndarray
    t_read: float
    name: str | None = None


class Source:
    """Base class of frame sources; use as a context manager or call :meth:`close`."""

    kind = "source"
    live = False
    still = False
    #: Nominal frames per second (None when unknown or not meaningful).
    fps: float | None = None
    #: Number of frames when known in advance (None for cameras and unknown lengths).
    n_frames: int | None = None

    def read(self) -> Frame | None:
        """The next frame, or None at the end of the source."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the file or device (idempotent)."""

    def describe(self) -> str:
        return self.kind

    def __iter__(self) -> Iterator[Frame]:
        while (frame := self.read()) is not None:
            yield frame

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Pacer:
    """Hands out a live source's frame ``index`` at its time, ``t0 + index / fps`` (``t0``: the
    first frame's). With ``rebase``, a source that fell behind by more than a frame restarts
    its clock at the frame it is on, so it does not deliver a burst of late frames."""

    def __init__(self, *, rebase: bool = False):
        self.rebase = rebase
        self._t0: float | None = None

    def wait(self, index: int, fps: float) -> float:
        """Wait for frame ``index``'s time; return that time (``perf_counter`` seconds)."""
        now = time.perf_counter()
        if self._t0 is None:
            self._t0 = now
        due = self._t0 + index / fps
        if due > now:
            time.sleep(due - now)
        elif self.rebase and now - due > 1.0 / fps:
            self._t0 = now - index / fps
            due = now
        return due
