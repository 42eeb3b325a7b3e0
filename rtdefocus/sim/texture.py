"""The "fabric" wall texture of the virtual set-up: a woven partition, wood-grain-like bands
and a printed poster (:class:`~rtdefocus.sim.VirtualProCam`'s ``texture="fabric"``)."""

from __future__ import annotations

import math

import numpy as np


def fabric(s: np.ndarray, y: np.ndarray, wall: np.ndarray) -> np.ndarray:
    """The "fabric" texture's albedo factor (3, N) at wall coordinates ``s`` (m along the wall
    from the fold), ``y`` (m, down; 0 at the projector's centre row) on ``wall`` (0 left, 1 right)."""
    out = np.ones((3, s.size))
    w0, w1 = wall == 0, wall == 1
    # Left: a woven partition, ±8 % in a 3 cm basket weave.
    weave = 1.0 + 0.08 * np.sin(2 * math.pi * s / 0.03) * np.sin(2 * math.pi * y / 0.03)
    out[:, w0] *= weave[w0]
    # Right: soft wood-grain-like bands (±6 %, 9 cm, slightly wavy) ...
    grain = 1.0 + 0.06 * np.sin(2 * math.pi * (y + 0.02 * np.sin(2 * math.pi * s / 0.4)) / 0.09)
    out[:, w1] *= grain[w1]
    # ... and a printed poster, coloured diagonal stripes (albedo × 0.45..1.0 per channel).
    poster = w1 & (s > 0.30) & (s < 0.80) & (y > -0.40) & (y < 0.10)
    ph = 2 * math.pi * (s / 0.16 + y / 0.23)
    for c, off in enumerate((0.0, 2.1, 4.2)):
        out[c, poster] *= 0.725 + 0.275 * np.cos(ph[poster] + off)
    return out
