"""The live player's repeated-picture test (rtdefocus.stream.repeat): exact, whatever rows differ."""

from __future__ import annotations

import numpy as np
import pytest

from rtdefocus.stream.repeat import SAMPLE_ROWS, same_picture


@pytest.mark.parametrize("shape", [(600, 800, 3), (47, 63, 3), (5, 7, 3), (48, 64)],
                         ids=["800x600", "odd", "fewer-rows-than-the-sample", "grey"])
def test_same_picture_is_exact_on_every_row_and_column(shape):
    """Equal pictures in distinct arrays are the same; one value changed anywhere (on a
    sampled row or between two) makes them differ; a view that is not contiguous answers
    alike."""
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, shape, dtype=np.uint8)
    assert same_picture(a, a.copy()) and same_picture(a, a)
    step = max(1, shape[0] // SAMPLE_ROWS)
    for y in {0, 1, step - 1, step, shape[0] // 2, shape[0] - 1}:
        for x in (0, shape[1] // 3, shape[1] - 1):
            b = a.copy()
            b[y, x] ^= 1
            assert not same_picture(a, b), (y, x)
            assert same_picture(a[:, ::2], b[:, ::2]) == (x % 2 == 1), (y, x)  # (a view)
    assert same_picture(a[:, ::2], a.copy()[:, ::2])


def test_same_picture_differs_on_shape_and_dtype():
    a = np.zeros((48, 64, 3), np.uint8)
    assert not same_picture(a, np.zeros((48, 64, 4), np.uint8))
    assert not same_picture(a, np.zeros((48, 64, 3), np.uint16))
    assert not same_picture(a, np.zeros((64, 48, 3), np.uint8))
