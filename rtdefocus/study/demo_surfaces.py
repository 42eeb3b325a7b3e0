"""The demo's surfaces section (``rtdefocus demo --surfaces``): the ``fabric`` preset (a
blue-grey woven partition, a beige wall with a poster, room light) side by side — geometry only |
defocus only | defocus + flatten | sharp on a white wall — and its uniformity figures.

Calibrated with :func:`rtdefocus.sim.oracle_calibration` (true geometry, radiometry and kernels)
to keep the demo short; the main section shows calibration through ``capture`` only.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .. import sim
from ..compensate import Compensator
from ..imageio import write_image
from .panels import crop_box, fit_height, hstack, label
from .scores import camera_view, coefficient_of_variation, psnr_affine, rect_mask

__all__ = ["SURFACE_VIEWS", "run_surfaces"]

# (label, surface, method); the fourth view is the input on a uniform white wall.
SURFACE_VIEWS = (("geometry only", "keep", "none"), ("defocus only", "keep", "ycbcr"),
                 ("defocus + flatten", "flatten", "ycbcr"))


def _inset(rect, shape, frac=0.05):
    x, y, w, h = rect
    dx, dy = int(frac * w), int(frac * h)
    return rect_mask((x + dx, y + dy, w - 2 * dx, h - 2 * dy), shape)


def on_white_wall(image: np.ndarray, rect, shape) -> np.ndarray:
    """The input as on a uniform white wall: resized into the display rectangle."""
    x, y, w, h = rect
    out = np.zeros(tuple(shape) + (3,), np.uint8)
    out[y:y + h, x:x + w] = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
    return out


def run_surfaces(out: Path, images: dict[str, np.ndarray], *, seed: int = 0,
                 **procam_options) -> tuple[list[Path], str, dict]:
    """Write ``fabric_<name>_side_by_side.png`` per image; return (files, markdown, figures).

    figures: ``cov`` (label -> CoV of a flat grey field in the camera view, display rectangle
    with a 5 % inset) and ``psnr_white`` (image -> label -> PSNR after one global gain and
    offset against the input on a white wall), plus ``clipped`` (image -> share, flatten).
    """
    procam = sim.VirtualProCam("fabric", seed=seed, **procam_options)
    calib = sim.oracle_calibration(procam)
    comps = {title: Compensator(calib, surface=s, method=m) for title, s, m in SURFACE_VIEWS}
    wc, hc = calib.camera_size
    rows, cols = crop_box(calib)
    grey = np.full((90, 120, 3), 128, np.uint8)
    mask = _inset(calib.display_rect((120, 90)), (hc, wc))
    figures: dict = {"cov": {}, "psnr_white": {}, "clipped": {}}
    for title, comp in comps.items():
        view = camera_view(procam, calib, comp.compensate(grey))
        figures["cov"][title] = coefficient_of_variation(view, mask)
    files = []
    for name, image in images.items():
        rect = calib.display_rect(image.shape[1::-1])
        m = _inset(rect, (hc, wc))
        white = on_white_wall(image, rect, (hc, wc))
        panels, scores = [], {}
        for title, comp in comps.items():
            view = camera_view(procam, calib, comp.compensate(image, warm_start=False))
            scores[title] = psnr_affine(view, white, m)
            panels.append(label(fit_height(view[rows, cols], 300), title))
        figures["clipped"][name] = comps["defocus + flatten"].last_info.get("clipped")
        panels.append(label(fit_height(white[rows, cols], 300), "sharp on a white wall"))
        figures["psnr_white"][name] = scores
        files.append(write_image(out / f"fabric_{name}_side_by_side.png", hstack(panels)))
    labels = [title for title, _, _ in SURFACE_VIEWS]
    lines = ["### Coloured, textured walls (virtual `fabric`, oracle calibration)", "",
             "| figure | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels),
             "| grey field: CoV (lower: more uniform) | "
             + " | ".join(f"{figures['cov'][k]:.3f}" for k in labels) + " |"]
    for name, sc in figures["psnr_white"].items():
        lines.append(f"| {name}: PSNR vs white wall (gain + offset) | "
                     + " | ".join(f"{sc[k]:.2f} dB" for k in labels) + " |")
    clipped = ", ".join(f"{n} {100 * c:.1f} %" for n, c in figures["clipped"].items()
                        if c is not None)
    lines += ["", f"*defocus + flatten*: `surface=\"flatten\"`, brightness auto; "
              f"clipped pixels: {clipped}."]
    return files, "\n".join(lines) + "\n", figures
