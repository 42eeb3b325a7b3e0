"""The frame-stepped show of ``rtdefocus eval --drift``: compensators, warps and camera views
per frame, each computed once, and the camera views of frames that are not scored skipped
without changing any other (:class:`DriftShow`, :func:`scored_frames`).

A skipped view still takes its place in the camera's noise (:meth:`VirtualProCam.skip_capture`),
so every view that is rendered (those scored, and the watcher's looks through the same camera)
is the one a play scoring every frame renders, bit for bit; a skipped view that is needed later
(the same frame again on a still) is rendered then with the noise it would have had.
"""

from __future__ import annotations

import copy
import hashlib

import numpy as np

from ..calib.geometry.lens import ideal_view
from ..compensate import Compensator
from ..gl.warp import warp_image
from ..sim import oracle_calibration
from .scores import psnr

__all__ = ["DriftShow", "RECENT_VIEWS", "frame_key", "scored_frames"]

#: Camera views kept rendered (a still's frames repeat one after another); an older one seen
#: again is rendered again with its own noise, the same view.
RECENT_VIEWS = 12


def frame_key(a: np.ndarray) -> bytes:
    """A digest of an array's bytes (equal frames, equal keys)."""
    return hashlib.blake2b(np.ascontiguousarray(a).data, digest_size=16).digest()


def scored_frames(n: int, fps: float, event_times, every: int = 1, full_s: float = 2.0) -> np.ndarray:
    """Which of ``n`` frames (frame ``i`` at ``i / fps``) a play scores: every frame from each
    event until ``full_s`` seconds after it (detection, mend and recovery, at full rate), and
    every ``every``-th frame elsewhere (``every`` 1: all). Returns an (n,) bool mask."""
    every = max(1, int(every))
    i = np.arange(int(n))
    keep = i % every == 0
    t = i / float(fps)
    for t0 in event_times:
        keep |= (t >= float(t0) - 1e-9) & (t < float(t0) + float(full_s) - 1e-9)
    return keep


class DriftShow:
    """One frame-stepped play's computations on ``procam``, shown in the camera rectangle
    ``rect``: a compensator per calibration (each runs once per frame, so rows sharing a
    calibration share its warm start), warps per (calibration, frame content) kept while the
    content repeats, camera views per frame content until the set-up changes (each frame's camera noise drawn
    once, at its first showing, so a frame seen again has the same view).

    Parameters
    ----------
    procam : rtdefocus.sim.VirtualProCam
    rect : (x, y, w, h) camera rectangle of the picture (and of the scores).
    iterations : warm-started solver iterations per frame.
    backend : Compensator backend.
    """

    def __init__(self, procam, rect, iterations: int, backend: str):
        self.procam, self.rect = procam, rect
        self.crop = _crop(rect)
        self.iterations, self.backend = iterations, backend
        self.comps: dict[int, tuple] = {}
        self._noise: dict = {}       # (False, frame key) -> that view's camera noise
        self._recent: dict = {}      # (sharp, frame key) -> view, the last RECENT_VIEWS
        self._warps: dict = {}       # id(calib) -> (calib, image key, warped): the last warp
        self.truth = oracle_calibration(procam)
        self._comped: dict = {}

    def changed(self) -> None:
        """The set-up changed: new truth, captures no longer valid."""
        self.truth = oracle_calibration(self.procam)
        self._noise.clear()
        self._recent.clear()

    def start_frame(self) -> None:
        self._comped, self._image_key = {}, None

    def _key_of(self, image) -> bytes:
        if self._image_key is None or self._image_key[0] is not image:
            self._image_key = (image, frame_key(image))
        return self._image_key[1]

    def warp(self, calib, image) -> np.ndarray:
        """The geometry-corrected frame (the last one again while the content repeats)."""
        k, key = id(calib), self._key_of(image)
        hit = self._warps.get(k)
        if hit is None or hit[0] is not calib or hit[1] != key:
            hit = self._warps[k] = (calib, key, warp_image(calib, image, rect=self.rect))
        return hit[2]

    def compensate(self, calib, image) -> np.ndarray:
        k = id(calib)
        if k not in self._comped:
            if k not in self.comps:
                self.comps[k] = (calib, Compensator(calib, backend=self.backend))
            self._comped[k] = self.comps[k][1].compensate_warped(
                self.warp(calib, image), iterations=self.iterations, warm_start=True)
        return self._comped[k]

    def keep_only(self, calibs) -> None:
        """Drop the compensators and warps of calibrations no row uses any more."""
        live = {id(c) for c in calibs}
        self.comps = {k: v for k, v in self.comps.items() if k in live}
        self._warps = {k: v for k, v in self._warps.items() if k in live}

    def view(self, frame, sharp=False) -> np.ndarray:
        """The camera's view of a projector frame at the current truth (ideal camera pixels)."""
        key = (sharp, frame_key(frame))
        got = self._recent.get(key)
        if got is None:
            if sharp:
                raw = self.procam.capture(frame, sharp=True)
            else:
                self._draw(key)
                noise = self._noise[key]
                raw = self.procam.capture(frame, noise=None if noise is None else copy.deepcopy(noise))
            got = ideal_view(self.truth, raw)
            self._recent[key] = got
            while len(self._recent) > RECENT_VIEWS:
                self._recent.pop(next(iter(self._recent)))
        return got

    def skip_view(self, frame) -> None:
        """A frame shown but not scored: its capture's noise is drawn and kept, not rendered."""
        self._draw((False, frame_key(frame)))

    def _draw(self, key) -> None:
        # The first capture of a frame under this truth draws its noise, rendered or not.
        if key not in self._noise:
            self._noise[key] = self.procam.skip_capture()

    def score(self, frame, reference, rect=None) -> float:
        """PSNR of ``frame``'s camera view against ``reference`` inside camera rectangle
        ``rect`` (default :attr:`rect`; as rect_mask, by slicing)."""
        crop = self.crop if rect is None else _crop(rect)
        return psnr(self.view(frame)[crop], reference[crop])


def _crop(rect):
    x, y, w, h = (int(v) for v in rect)
    return np.s_[max(0, y):max(0, y + h), max(0, x):max(0, x + w)]
