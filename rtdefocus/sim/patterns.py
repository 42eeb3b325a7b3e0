"""Named test patterns for the virtual projector (``rtdefocus simulate --pattern``)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError

PATTERNS = ("checker", "lines", "dots")


def test_pattern(name: str, size: tuple[int, int]) -> np.ndarray:
    """A named test pattern for a projector of ``size`` = (width, height).

    ``checker``: 40 px squares; ``lines``: 2 px white grid lines every 50 px on black;
    ``dots``: 5×5 px white dots every 60 px on black. Returns (H, W, 3) uint8 RGB.
    """
    w, h = int(size[0]), int(size[1])
    if w <= 0 or h <= 0:
        raise InputError(f"pattern size must be positive (width, height); got {size!r}")
    y, x = np.mgrid[0:h, 0:w]
    if name == "checker":
        img = ((x // 40 + y // 40) % 2).astype(np.uint8) * 255
    elif name == "lines":
        img = (((x - 25) % 50 < 2) | ((y - 25) % 50 < 2)).astype(np.uint8) * 255
    elif name == "dots":
        img = (((x - 28) % 60 < 5) & ((y - 28) % 60 < 5)).astype(np.uint8) * 255
    else:
        raise InputError(f"unknown test pattern {name!r}; choose one of {', '.join(PATTERNS)}")
    return np.repeat(img[:, :, None], 3, axis=2)


test_pattern.__test__ = False   # not a pytest test, despite the name


test_pattern.__test__ = False   # not a pytest test, despite the name
