"""Helpers shared by the subcommands: sizes, image files, progress bars."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

log = logging.getLogger("rtdefocus")



def parse_size(text: str) -> tuple[int, int]:
    """``"800x600"`` -> ``(800, 600)`` (width, height)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"size must be WIDTHxHEIGHT with positive integers, e.g. 800x600; got {text!r}"
        ) from None
    return w, h


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file as RGB uint8 (H, W, 3) (see :func:`rtdefocus.imageio.read_image`)."""
    from ..imageio import read_image as _read_image  # cv2 loads on first use: `--help` stays fast

    return _read_image(path)


def write_image(path: str | Path, rgb: np.ndarray) -> Path:
    """Write an RGB uint8 image, creating parent folders (see :func:`rtdefocus.imageio.write_image`)."""
    from ..imageio import write_image as _write_image

    return _write_image(path, rgb)


class Progress:
    """What the long commands show while they work: a tqdm bar per calibration stage, fed by
    the library's ``progress(stage, done, total)`` callback, and ``step(message)`` lines
    between them. Silent with ``-q``; ``close()`` (or ``with``) ends the open bar."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self._bar = None
        self._stage = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.quiet:
            return
        from tqdm import tqdm

        bar = self._bar
        # A new stage, or the same stage starting over (the next preset's calibration): new bar.
        if bar is None or stage != self._stage or done < bar.n:
            self.close()
            bar = self._bar = tqdm(total=max(total, done), desc=f"{stage:10s}", unit="capture",
                                   dynamic_ncols=True, leave=True)
            self._stage = stage
        bar.total = max(total, done)
        bar.update(done - bar.n)

    def step(self, message: str) -> None:
        self.close()
        if not self.quiet:
            print(message, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        self._bar, self._stage = None, None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
