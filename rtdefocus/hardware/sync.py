"""Pattern/frame synchronisation: by time, then checked by content.

By time. :func:`measure_latency` shows black, then white, and times the first camera frame that
is bright: the projector's input lag, the camera's exposure and every frame queued on the way
(USB: one or two frames; IP cameras and phones: 0.2–2 s). The settle time after each pattern
is that latency plus two camera frames. :meth:`rtdefocus.hardware.Camera.drain` then discards
frames until that time has passed and the driver's queue is empty.

By content. Timing can still slip (a network hiccup, a projector that changed its processing),
and a frame of the previous pattern silently corrupts a Gray code. :class:`CoarseMap` learns,
with a few coarse Gray-code patterns, which of ``n x n`` projector cells each camera pixel sees;
:meth:`CoarseMap.verify` compares a capture's cell means with the shown pattern and with the
previous one (correlation for patterns with coarse structure, the direction of the change for
uniform ones). Patterns whose differences are all finer than a cell cannot be told apart at
this scale; they are protected by the settle time, which grows after every failed check.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import CaptureError
from ..graycode import decode_gray, gray_code_bit
from ..imageio import to_grey

log = logging.getLogger(__name__)


@dataclass
class Latency:
    """Result of :func:`measure_latency` (seconds, camera levels 0..255)."""

    seconds: float
    black: np.ndarray          # (Hc, Wc) grey float32 camera frame of a black projector
    white: np.ndarray          # (Hc, Wc) same, white
    trace: list                # [(t since the swap, mean level), ...]

    @property
    def contrast(self) -> float:
        return float(np.percentile(self.white - self.black, 95))


def measure_latency(camera, show: Callable[[np.ndarray], float], projector_size: tuple[int, int],
                    *, timeout: float = 3.0) -> Latency:
    """Time from a black→white swap to the first camera frame that shows it.

    ``show(pattern) -> t`` puts a pattern up and returns ``time.perf_counter()`` once the swap
    is done. Frames are read continuously, so the result includes every queued frame.

    Raises
    ------
    CaptureError
        The camera does not see the projector change (no rise within ``timeout``).
    """
    wp, hp = projector_size
    black = np.zeros((hp, wp, 3), np.uint8)
    white = np.full((hp, wp, 3), 255, np.uint8)
    t0 = show(black)
    frames, means = _read_until_stable(camera, t0 + timeout)
    b = frames[-1]
    b_mean = float(b.mean())
    noise = max(2.0, 4.0 * float(np.std(means[-3:]) if len(means) >= 3 else 0.0))
    t0 = show(white)
    trace, t_rise, last = [], None, None
    while True:
        img = to_grey(camera.read())
        t = time.perf_counter() - t0
        m = float(img.mean())
        trace.append((t, m))
        if t_rise is None and m > b_mean + max(noise, 3.0):
            t_rise = t
        if t_rise is not None and len(trace) >= 3 and t - t_rise > 2 * camera.frame_period:
            recent = [v for _, v in trace[-3:]]
            if max(recent) - min(recent) <= max(noise, 0.02 * (recent[-1] - b_mean)):
                last = img
                break
        if t > timeout:
            break
    if t_rise is None or last is None:
        raise CaptureError(f"the camera does not see the projector: its picture stayed at mean "
                           f"level {b_mean:.0f} for {timeout:.0f} s after the screen turned from "
                           "black to white. Aim the camera at the projected area, check --screen "
                           "(the patterns go to that monitor), --camera (`rtdefocus cameras` lists "
                           "them), the lens cap and the exposure: `rtdefocus aim --camera N "
                           "--screen M` shows what the camera sees, live")
    # The first frame whose level is past half way: the rise itself can span two frames.
    half = b_mean + 0.5 * (float(last.mean()) - b_mean)
    seconds = next(t for t, v in trace if v >= half)
    log.info("projector-to-camera latency %.0f ms (black %.0f, white %.0f mean level)",
             seconds * 1e3, b_mean, float(last.mean()))
    return Latency(seconds, b, last, trace)


def _read_until_stable(camera, deadline: float, n: int = 3, at_least: float = 0.5):
    """Read until ``n`` frames in a row agree, and ``at_least`` seconds have passed (frames of
    what was shown before may still be on their way)."""
    frames, means = [], []
    start = time.perf_counter()
    while True:
        img = to_grey(camera.read())
        frames.append(img)
        means.append(float(img.mean()))
        if len(means) >= n + 1 and time.perf_counter() - start >= at_least:
            recent = means[-n:]
            if max(recent) - min(recent) <= max(1.0, 0.01 * max(recent)):
                return frames, means
        if time.perf_counter() > deadline:
            return frames, means


def lit_fraction(latency: Latency) -> float:
    """Fraction of the camera picture the projector lights (white − black above a third of
    the contrast)."""
    diff = latency.white - latency.black
    return float((diff > latency.contrast / 3).mean())


def projector_px_per_camera_px(projector_size: tuple[int, int], camera_size: tuple[int, int],
                               lit: float) -> float:
    """Linear number of projector pixels one camera pixel covers, from the lit area."""
    lit_px = max(1.0, lit * camera_size[0] * camera_size[1])
    return float(np.sqrt(projector_size[0] * projector_size[1] / lit_px))


def gray_code_patterns(projector_size: tuple[int, int], bits: int) -> list[tuple[str, int, np.ndarray]]:
    """Coarse Gray-code stripes: ``[(axis, bit, (Hp, Wp, 3) uint8), ...]``, ``2 * bits`` of them,
    splitting the projector into ``2**bits`` columns and rows."""
    wp, hp = projector_size
    out = []
    for axis, length in (("x", wp), ("y", hp)):
        cell = (np.arange(length) * (1 << bits)) // length
        for b in range(bits):
            on = gray_code_bit(cell, b, bits).astype(np.uint8) * 255
            img = np.broadcast_to(on[None, :] if axis == "x" else on[:, None], (hp, wp))
            out.append((axis, b, np.repeat(img[:, :, None], 3, axis=2).copy()))
    return out


class CoarseMap:
    """Which of ``n x n`` projector cells (n = 2**bits) each camera pixel sees.

    Parameters
    ----------
    black, white : (Hc, Wc) float32 camera frames of a black and a white projector.
    captures : {(axis, bit): (Hc, Wc) camera frame} of :func:`gray_code_patterns`.
    """

    def __init__(self, black: np.ndarray, white: np.ndarray, captures: dict, bits: int):
        self.bits = n = bits
        self.n = 1 << n
        contrast = white - black
        lit = contrast > float(np.percentile(contrast, 95)) / 3
        mid = black + 0.5 * contrast
        cells = {}
        for axis in ("x", "y"):
            cells[axis] = decode_gray([to_grey(captures[(axis, b)]) > mid for b in range(n)])
        self.index = np.where(lit, cells["y"] * self.n + cells["x"], -1).ravel()
        self.counts = np.bincount(self.index[self.index >= 0], minlength=self.n * self.n)
        self.used = self.counts >= 4
        self.black_mean = self._cells(black)
        self.contrast = self._cells(white) - self.black_mean
        if self.used.sum() < 8:
            raise CaptureError(f"the camera sees only {int(self.used.sum())} of the projector's "
                               f"{self.n * self.n} coarse cells; aim it at the whole projected area")

    def _cells(self, img: np.ndarray) -> np.ndarray:
        g = to_grey(img).ravel()
        ok = self.index >= 0
        sums = np.bincount(self.index[ok], weights=g[ok], minlength=self.n * self.n)
        return (sums / np.maximum(self.counts, 1))[self.used]

    def pattern_cells(self, pattern: np.ndarray) -> np.ndarray:
        """Cell means of a projector pattern in linear light (gamma 2.2, 0..1)."""
        import cv2

        lin = (to_grey(pattern) / 255.0) ** 2.2
        return cv2.resize(lin, (self.n, self.n), interpolation=cv2.INTER_AREA).ravel()[self.used]

    def camera_cells(self, frame: np.ndarray) -> np.ndarray:
        """Cell means of a camera frame, 0 = black level, 1 = white level."""
        return (self._cells(frame) - self.black_mean) / np.maximum(self.contrast, 1.0)

    def verify(self, frame_cells: np.ndarray, pattern: np.ndarray, previous: np.ndarray | None,
               previous_cells: np.ndarray | None) -> str | None:
        """None when ``frame_cells`` (of :meth:`camera_cells`) show ``pattern`` rather than
        ``previous`` (with its capture's cells); else the reason."""
        c = self.pattern_cells(pattern)
        if previous is None or previous_cells is None:
            return None
        p = self.pattern_cells(previous)
        if float(np.abs(c - p).max()) < 0.05:
            return None                    # the same at this scale: nothing to tell apart
        varies_c, varies_p = c.std() > 0.05, p.std() > 0.05
        if varies_c and not (varies_p and _corr(c, p) > 0.9):
            rc, rp = _corr(frame_cells, c), _corr(frame_cells, p)
            # Fail only on clear evidence: a blurred, noisy or gamma-curved capture still
            # correlates well with its pattern at this scale; a stale one does not, or has
            # lost the coarse contrast altogether (a uniform previous pattern).
            flat = float(frame_cells.std()) < 0.3 * float(c.std())
            if rc < 0.3 or flat or (varies_p and rp > rc + 0.1):
                return (f"its coarse layout matches the previous pattern (correlation {rp:.2f}) "
                        f"better than the one shown ({rc:.2f})" if rp > rc else
                        f"its coarse layout does not match the pattern shown (correlation {rc:.2f})")
            return None
        if varies_p and not varies_c and _corr(frame_cells, p) > 0.5:
            return ("it still shows the previous pattern's layout (correlation "
                    f"{_corr(frame_cells, p):.2f}) where the pattern shown is uniform")
        expected = float((c - p).mean())
        if abs(expected) < 0.02:
            return None
        seen = float((frame_cells - previous_cells).mean())
        if seen * np.sign(expected) < 0.3 * abs(expected):
            return (f"its level changed by {seen:+.3f} from the previous capture where the patterns "
                    f"differ by {expected:+.3f} (fractions of white)")
        return None


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    d = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / d) if d > 1e-12 else 0.0
