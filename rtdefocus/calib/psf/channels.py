"""The PSF stage's channel sum where the white frame clips in some channels only.

The stage measures a dot as the sum of the three channels of its linear light (about √3 more
signal to noise than one). Where the white frame clips in one or two channels (a red wall, a
camera whose channels differ), those channels are no data, but the others still are: there
the sum is estimated from the unclipped channels, scaled by the ratio of the full sum to theirs
on the same wall's pixels where nothing clips (the walls' colour is smooth; the projector's
white and a dot's light have the same colour at a pixel when the blur is achromatic). Pixels
clipped in every channel are no data at all. Where nothing clips, the sum is the plain one,
bit for bit.
"""

from __future__ import annotations

import numpy as np

from ..radiometry.exposure import CLIPPED

__all__ = ["ChannelSum"]

# A wall needs this many unclipped pixels to give a channel ratio.
_MIN_PIXELS = 50


class ChannelSum:
    """``(frame linear light (Hc, Wc, 3)) -> (Hc, Wc)`` channel sum, with the channels the
    white frame clips left out and made up for (see the module's docstring).

    Parameters
    ----------
    white_codes : (Hc, Wc, 3) camera codes of the white frame (what is tested for clipping).
    black, white : (Hc, Wc, 3) linear light of the black and white frames.
    sides : (Hc, Wc) bool masks of each wall's camera pixels.

    Attributes
    ----------
    dead : (Hc, Wc) bool, clipped in every channel (or on a wall that gives no ratio).
    use : (Hc, Wc, 3) bool, the channels the sum reads.
    """

    def __init__(self, white_codes: np.ndarray, black: np.ndarray, white: np.ndarray,
                 sides: list[np.ndarray]):
        clip = np.asarray(white_codes) >= CLIPPED
        self.use = ~clip
        self.dead = clip.all(axis=2)
        self.partial = clip.any(axis=2) & ~self.dead
        self.scale = self.offset = None
        if not self.partial.any():
            return
        span = white - black
        clean = ~clip.any(axis=2) & (span.sum(axis=2) > 0)
        code = (clip * np.array([1, 2, 4])).sum(axis=2)       # which channels clip
        scale = np.ones(clip.shape[:2], np.float64)
        for side in sides:
            ref = span[side & clean]
            for k in np.unique(code[side & self.partial]):
                at = side & self.partial & (code == k)
                keep = np.array([not (k >> c) & 1 for c in range(3)])
                part = ref[:, keep].sum(axis=1)
                good = part > 0
                if good.sum() < _MIN_PIXELS:
                    self.dead |= at                   # no unclipped pixels to scale by
                    continue
                scale[at] = float(np.median(ref[good].sum(axis=1) / part[good]))
        self.partial &= ~self.dead
        self.scale = scale
        # The dot frames carry the black frame's light in every channel: it is added whole.
        self.offset = black.sum(axis=2) - scale * (black * self.use).sum(axis=2)

    def __call__(self, lin: np.ndarray) -> np.ndarray:
        total = lin.sum(axis=2)
        if self.scale is None:
            return total
        made_up = self.scale * (lin * self.use).sum(axis=2) + self.offset
        return np.where(self.partial, made_up, total).astype(total.dtype)

    def clipped(self, codes: np.ndarray) -> np.ndarray:
        """(Hc, Wc) bool: pixels of a frame (codes) clipped in a channel the sum reads."""
        return ((np.asarray(codes) >= CLIPPED) & self.use).any(axis=2)
