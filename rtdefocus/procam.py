"""The ProCam protocol: a projector and a camera looking at the surface.

Anything that implements it can be calibrated: the built-in virtual set-up
(:mod:`rtdefocus.sim`) and real hardware (:class:`rtdefocus.HardwareProCam`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from .errors import InputError


@runtime_checkable
class ProCam(Protocol):
    """A projector and a camera looking at the surface.

    Attributes
    ----------
    projector_size : (width, height) of the projector in pixels.
    camera_size : (width, height) of the camera in pixels.
    """

    projector_size: tuple[int, int]
    camera_size: tuple[int, int]

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        """Show ``pattern`` ((Hp, Wp, 3) uint8 RGB) full-screen; return one camera frame
        ((Hc, Wc, 3) uint8 RGB)."""
        ...


def check_pattern(pattern: np.ndarray, projector_size: tuple[int, int]) -> np.ndarray:
    """Validate a projector pattern: (Hp, Wp, 3) uint8 RGB (a (Hp, Wp) grey one is expanded)."""
    wp, hp = projector_size
    pattern = np.asarray(pattern)
    if pattern.ndim == 2:
        pattern = np.repeat(pattern[:, :, None], 3, axis=2)
    if pattern.shape != (hp, wp, 3):
        raise InputError(f"pattern must be (H, W, 3) = ({hp}, {wp}, 3) for a {wp}x{hp} projector; "
                         f"got shape {pattern.shape}. Resize it or use comp.warp() first.")
    if pattern.dtype != np.uint8:
        raise InputError(f"pattern must be uint8 RGB (0..255); got dtype {pattern.dtype}. "
                         "Convert with np.clip(x * 255, 0, 255).astype(np.uint8) for [0, 1] floats.")
    return pattern
