"""Motion between consecutive projector frames, for the warm start of a video (DESIGN.md §1).

A frame's solve starts from the previous frame's *correction* ``P − I`` moved along the
picture's motion, not from the previous ``P`` itself: a warm start that ignores motion drags the
previous frame's sharpened content behind the picture and makes moving video far worse than no
compensation at all. The motion is dense optical flow (OpenCV's DIS, on downscaled grey frames)
from the current projector frame back to the previous one, so that each pixel knows where its
content was; pixels where the flow does not explain the picture (new content at an edge,
occlusions, a fade, a cut) are marked invalid and start cold.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["Motion", "MotionEstimator"]


@dataclass
class Motion:
    """Where each pixel of the current frame was in the previous one.

    Attributes
    ----------
    map_x, map_y : (H, W) float32 or None
        Source coordinates in the previous frame (``cv2.remap`` maps); None when the picture
        did not move (every pixel stays where it is).
    valid : (H, W) bool
        Pixels whose content the motion explains: the carried correction is used there.
    valid_fraction : float
    cut : bool
        Too little of the frame is explained by the previous one: a new scene, start cold.
    """

    map_x: np.ndarray | None
    map_y: np.ndarray | None
    valid: np.ndarray
    valid_fraction: float
    cut: bool

    def carry(self, field: np.ndarray) -> np.ndarray:
        """Move a planar ``(C, H, W)`` float32 field of the previous frame along the motion; 0
        where the motion is invalid (the cold start's correction)."""
        field = np.asarray(field, dtype=np.float32)
        if self.map_x is None:
            out = field.copy()
        else:
            out = np.stack([cv2.remap(c, self.map_x, self.map_y, cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
                            for c in field])
        out *= self.valid[None]
        return out


class MotionEstimator:
    """Dense motion between consecutive ``(H, W, 3)`` uint8 projector frames.

    Parameters
    ----------
    scale : int
        The flow is computed on frames downscaled by this factor (speed; the correction it moves
        is smooth at that scale) and upsampled.
    error_threshold : float
        A pixel is valid when the previous frame moved by the flow matches the current one
        within this many grey levels (after a small blur, so that noise alone does not reject).
    cut_fraction : float
        Below this share of valid pixels the frame counts as a cut.
    still_px : float
        Flow whose 99th percentile magnitude is below this (pixels) counts as no motion, so
        that a paused live picture does not resample (and blur) the carried correction.
    """

    def __init__(self, *, scale: int = 2, error_threshold: float = 12.0,
                 cut_fraction: float = 0.3, still_px: float = 0.2):
        if int(scale) < 1:
            raise InputError(f"scale must be >= 1; got {scale}")
        self.scale = int(scale)
        self.error_threshold = float(error_threshold)
        self.cut_fraction = float(cut_fraction)
        self.still_px = float(still_px)
        self._dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
        self._grid: tuple[np.ndarray, np.ndarray] | None = None

    def _small_grey(self, frame: np.ndarray) -> np.ndarray:
        grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
        if self.scale == 1:
            return grey
        h, w = grey.shape
        return cv2.resize(grey, (max(1, w // self.scale), max(1, h // self.scale)),
                          interpolation=cv2.INTER_AREA)

    def _pixel_grid(self, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
        if self._grid is None or self._grid[0].shape != (h, w):
            xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
            self._grid = (xs, ys)
        return self._grid

    def estimate(self, previous: np.ndarray, current: np.ndarray) -> Motion:
        """The motion from ``current`` back to ``previous`` (both ``(H, W, 3)`` uint8)."""
        if previous.shape != current.shape or current.ndim != 3:
            raise InputError(f"frames must share an (H, W, 3) shape; got {previous.shape} and "
                             f"{current.shape}")
        h, w = current.shape[:2]
        grey_prev = cv2.cvtColor(previous, cv2.COLOR_RGB2GRAY)
        grey_cur = cv2.cvtColor(current, cv2.COLOR_RGB2GRAY)
        # current(x) ≈ previous(x + flow(x))
        flow = self._dis.calc(self._small_grey(current), self._small_grey(previous), None)
        magnitude = np.hypot(flow[..., 0], flow[..., 1]) * self.scale
        if float(np.percentile(magnitude, 99)) < self.still_px:
            map_x = map_y = None
            moved = grey_prev
            inside = np.ones((h, w), bool)
        else:
            flow = cv2.resize(flow, (w, h), interpolation=cv2.INTER_LINEAR) * self.scale
            xs, ys = self._pixel_grid(h, w)
            map_x, map_y = xs + flow[..., 0], ys + flow[..., 1]
            moved = cv2.remap(grey_prev, map_x, map_y, cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
            inside = (map_x >= 0) & (map_x <= w - 1) & (map_y >= 0) & (map_y <= h - 1)
        error = cv2.absdiff(moved, grey_cur).astype(np.float32)
        error = cv2.GaussianBlur(error, (0, 0), 2.0)
        valid = inside & (error < self.error_threshold)
        fraction = float(valid.mean())
        return Motion(map_x, map_y, valid, fraction, cut=fraction < self.cut_fraction)
