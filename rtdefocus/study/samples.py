"""The sample images of the demo and of ``rtdefocus eval``: photographs and a text slide."""

from __future__ import annotations

import cv2
import numpy as np

from .extras import need

__all__ = ["text_slide", "photographs", "demo_images"]


def text_slide(size: tuple[int, int] = (640, 480)) -> np.ndarray:
    """A slide of black text on white: (h, w, 3) uint8 for ``size = (w, h)``.

    Several lines of decreasing size (the smallest strokes are 1–2 px wide): the hardest case
    for compensation, with no room above white or below black to pre-sharpen into.
    """
    w, h = int(size[0]), int(size[1])
    img = np.full((h, w, 3), 255, np.uint8)
    # (text, stroke thickness at 640 px width); each line is scaled to span 88 % of the width,
    # so text crosses the middle of the frame (where a centred fold is).
    lines = [("Defocus compensation", 3), ("on a two-wall corner, sharp", 2),
             ("Projected text stays readable even", 2), ("where the two walls meet: edges, strokes,",
                                                          1),
             ("The quick brown fox jumps over the lazy dog 0123456789", 1),
             ("Pack my box with five dozen liquor jugs - 42", 1),
             ("Sphinx of black quartz, judge my vow! 1/2 3:4", 1)]
    font = cv2.FONT_HERSHEY_SIMPLEX
    y = 0.0
    for text, thick in lines:
        th = max(1, int(round(thick * w / 640.0)))
        (tw, tht), _ = cv2.getTextSize(text, font, 1.0, th)
        fs = 0.88 * w / tw
        y += 1.75 * tht * fs
        cv2.putText(img, text, (int(0.04 * w), int(y)), font, fs, (0, 0, 0), th, cv2.LINE_AA)
    return img


def photographs() -> dict[str, np.ndarray]:
    """The test photographs (scikit-image's chelsea, coffee, astronaut, rocket) as RGB uint8."""
    data = need("skimage.data", "the test photographs")
    return {name: np.ascontiguousarray(getattr(data, name)())
            for name in ("chelsea", "coffee", "astronaut", "rocket")}


def demo_images(include_text: bool = True) -> dict[str, np.ndarray]:
    """The demo's inputs: scikit-image's chelsea (the paper's cat), coffee, astronaut, rocket,
    and a text slide."""
    images = photographs()
    if include_text:
        images["text"] = text_slide((800, 600))
    return images
