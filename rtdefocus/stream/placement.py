"""Where the content sits in the projector's frame: ``--fit contain|cover`` and ``--margin``.

Without a placement the Compensator shows each input in the largest lit rectangle of the
input's own aspect. A :class:`Placement` instead lays every input onto a canvas of the
projector's size first (the projector's frame: the largest lit rectangle of the projector's
aspect), inside a margin, either whole with black bars (``contain``) or filling the box and
cropped (``cover``). All items of a playlist then share one frame, whatever their aspect.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

FITS = ("contain", "cover")


def parse_margin(text: str) -> float | int:
    """``"0.05"`` -> 0.05 (a fraction of the frame's width and height, in [0, 0.5));
    ``"40px"`` -> 40 (projector pixels on each side)."""
    t = str(text).strip().lower()
    try:
        if t.endswith("px"):
            value = int(t[:-2])
            if value < 0:
                raise ValueError
            return value
        value = float(t)
        if not 0.0 <= value < 0.5:
            raise ValueError
        return value
    except ValueError:
        raise InputError(f"margin must be a fraction in [0, 0.5) such as 0.05, or pixels such as "
                         f"40px; got {text!r}") from None


@dataclass(frozen=True)
class Placement:
    """How content is laid onto the projector's frame.

    Attributes
    ----------
    size : (width, height) of the frame (the projector's size).
    fit : ``"contain"`` (whole picture, black bars) or ``"cover"`` (fills the box, cropped).
    margin : a float fraction in [0, 0.5) of the frame's width and height, or an int of pixels,
        kept black on each side.
    """

    size: tuple[int, int]
    fit: str = "contain"
    margin: float | int = 0.0

    def __post_init__(self):
        if self.fit not in FITS:
            raise InputError(f"fit must be one of {', '.join(FITS)}; got {self.fit!r}")
        w, h = self.size
        mx, my = self.margins()
        if w - 2 * mx < 1 or h - 2 * my < 1:
            raise InputError(f"margin {self.margin!r} leaves nothing of the {w}x{h} frame; give a "
                             "smaller margin")

    def margins(self) -> tuple[int, int]:
        """The margin in pixels, (horizontal, vertical)."""
        w, h = self.size
        if isinstance(self.margin, int) and not isinstance(self.margin, bool):
            return self.margin, self.margin
        m = float(self.margin)
        if not 0.0 <= m < 0.5:
            raise InputError(f"margin fraction must be in [0, 0.5); got {m}")
        return round(m * w), round(m * h)

    def box(self) -> tuple[int, int, int, int]:
        """The content box ``(x, y, w, h)`` in the frame's pixels."""
        w, h = self.size
        mx, my = self.margins()
        return mx, my, w - 2 * mx, h - 2 * my

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """``image`` (RGB uint8, any size) on a black frame of :attr:`size`, placed."""
        w, h = self.size
        bx, by, bw, bh = self.box()
        ih, iw = image.shape[:2]
        if self.fit == "cover":
            scale = max(bw / iw, bh / ih)
            # Crop the input to the box's aspect first (centred), then resize: no oversized copy.
            cw, ch = min(iw, max(1, round(bw / scale))), min(ih, max(1, round(bh / scale)))
            x0, y0 = (iw - cw) // 2, (ih - ch) // 2
            image = image[y0:y0 + ch, x0:x0 + cw]
            nw, nh = bw, bh
        else:
            scale = min(bw / iw, bh / ih)
            nw, nh = max(1, round(iw * scale)), max(1, round(ih * scale))
        ih, iw = image.shape[:2]
        interp = cv2.INTER_AREA if nw < iw else cv2.INTER_LINEAR
        resized = image if (nw, nh) == (iw, ih) else cv2.resize(image, (nw, nh), interpolation=interp)
        out = np.zeros((h, w, 3), np.uint8)
        x0, y0 = bx + (bw - nw) // 2, by + (bh - nh) // 2
        out[y0:y0 + nh, x0:x0 + nw] = resized
        return out
