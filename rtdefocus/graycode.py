"""The Gray code (reflected binary) of stripe indices: neighbouring stripes differ in one bit,
so a camera pixel on a stripe edge is off by at most one stripe. Used by the geometry stage's
line labels and by the hardware's coarse projector-to-camera map (a leaf module)."""

from __future__ import annotations

import numpy as np


def gray_code_bit(index: np.ndarray, bit: int, n_bits: int) -> np.ndarray:
    """Bit ``bit`` (0 = most significant of ``n_bits``) of the Gray code of ``index``; 0 or 1,
    ``index``'s integer dtype."""
    code = index ^ (index >> 1)
    return (code >> (n_bits - 1 - bit)) & 1


def decode_gray(bits: list[np.ndarray]) -> np.ndarray:
    """Stripe index from Gray-code bit images (MSB first, each (H, W) bool); (H, W) int32."""
    g = np.zeros(bits[0].shape, np.int32)
    for b in bits:
        g = (g << 1) | b.astype(np.int32)
    k = g.copy()
    shift = g >> 1
    while shift.any():          # Gray -> binary: k = g ^ (g >> 1) ^ (g >> 2) ^ ...
        k ^= shift
        shift >>= 1
    return k
