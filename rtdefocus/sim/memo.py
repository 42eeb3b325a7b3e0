"""The last noiseless render of a :class:`~rtdefocus.sim.VirtualProCam`, kept for the next
capture of the same pattern (a calibration averages several captures of each pattern)."""

from __future__ import annotations

import numpy as np


def _setup(procam) -> tuple:
    """What a render reads: arrays the simulator replaces (never edits) on a change, and
    numbers."""
    return (procam._proj_lut, procam._blur, procam._pad_shade, procam._map_x, procam._map_y,
            procam._cam_albedo, procam._margin, float(procam.ambient))


class LastRender:
    """One pattern, the set-up it was rendered in, and its camera irradiance before the
    exposure drift and the noise."""

    def __init__(self) -> None:
        self.pattern = None
        self.setup: tuple = ()
        self.cam = None

    def get(self, procam, pattern: np.ndarray) -> np.ndarray | None:
        """A copy of the render of ``pattern`` in ``procam``'s set-up, or None if it is not
        the last one rendered."""
        if self.cam is None or not all(a is b or (not isinstance(a, np.ndarray) and a == b)
                                       for a, b in zip(_setup(procam), self.setup, strict=True)):
            return None
        if not np.array_equal(pattern, self.pattern):
            return None
        return self.cam.copy()

    def put(self, procam, pattern: np.ndarray, cam: np.ndarray) -> None:
        """Keep ``cam`` as the render of ``pattern`` in ``procam``'s set-up."""
        self.pattern, self.setup, self.cam = pattern.copy(), _setup(procam), cam.copy()

    @staticmethod
    def forget(procam) -> None:
        """Drop ``procam``'s kept render (so the next capture renders: timings)."""
        procam.__dict__.pop("_last_render", None)
