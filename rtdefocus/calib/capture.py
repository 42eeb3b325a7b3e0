"""Counting, checking, progress-reporting wrapper around ``ProCam.capture`` for calibration."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import CaptureError, InputError, InputTypeError
from ..procam import ProCam, check_pattern
from .file import Calibration

# progress(stage, done, total): the CLI turns it into a progress bar; the library never prints.
ProgressFn = Callable[[str, int, int], None]


class Capturer:
    """Calls ``procam.capture`` for the calibration stages.

    Counts captures per stage (``counts``) and checks each returned frame. It does not retry:
    a failed camera read is retried where it happens (:meth:`rtdefocus.hardware.Camera.read`,
    ``retries``), a frame that does not show the pattern is taken again by the ProCam that
    can tell (:class:`rtdefocus.hardware.HardwareProCam`, ``recaptures``). A capture that
    fails, or returns a frame of the wrong shape or type, is one :class:`CaptureError` naming
    the stage, the pattern and the cause.
    """

    def __init__(self, procam: ProCam, progress: ProgressFn | None = None):
        for attr in ("projector_size", "camera_size", "capture"):
            if not hasattr(procam, attr):
                raise InputError(f"{type(procam).__name__} is not a ProCam: it has no {attr!r} "
                                 "(see rtdefocus.ProCam)")
        self.procam = procam
        self.progress = progress
        self.counts: dict[str, int] = {}
        #: The first all-white and all-black frames of the calibration (uint8), kept as the
        #: reference :mod:`.diagnose` compares fresh frames with when a stage fails.
        self.first_white: np.ndarray | None = None
        self.first_black: np.ndarray | None = None
        #: The latest all-white frame (uint8): against ``first_white`` it tells whether the
        #: camera's exposure drifted over a stage that took both (the geometry stage's
        #: ``white`` and ``white_end``).
        self.last_white: np.ndarray | None = None
        self.stage = "capture"
        self._done = 0
        self._total = 0
        # key -> (n, mean of n captures): what one stage averaged, a later one reuses.
        self._frames: dict[str, tuple[int, np.ndarray]] = {}

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    @property
    def stage_done(self) -> int:
        """Captures made since the current stage began (for resuming it with :meth:`begin`)."""
        return self._done

    def begin(self, stage: str, expected: int, done: int = 0) -> None:
        """Start (or, with ``done``, resume) a stage that will take about ``expected`` captures
        (for the progress bar)."""
        self.stage, self._done, self._total = stage, done, expected
        self.counts.setdefault(stage, 0)
        if self.progress:
            self.progress(stage, done, expected)

    def __call__(self, pattern: np.ndarray) -> np.ndarray:
        pattern = check_pattern(pattern, self.procam.projector_size)
        wc, hc = self.procam.camera_size
        where = f"capture {self._done + 1} of stage {self.stage}"
        try:
            frame = np.asarray(self.procam.capture(pattern))
        except CaptureError as exc:     # already says what to check
            raise CaptureError(f"{where}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 -- any ProCam's failure, reported as one error
            raise CaptureError(f"{where} failed: {exc}. Check the camera connection and that "
                               "nothing else is using it.") from exc
        if frame.shape != (hc, wc, 3) or frame.dtype != np.uint8:
            raise CaptureError(f"{where}: the camera returned {frame.shape} {frame.dtype}, "
                               f"expected ({hc}, {wc}, 3) uint8 (ProCam.camera_size)")
        if pattern.min() == 255:
            self.last_white = frame.copy()
            if self.first_white is None:
                self.first_white = frame.copy()
        elif self.first_black is None and pattern.max() == 0:
            self.first_black = frame.copy()
        self.counts[self.stage] = self.counts.get(self.stage, 0) + 1
        self._done += 1
        if self.progress:
            self.progress(self.stage, self._done, max(self._total, self._done))
        return frame

    def mean(self, pattern: np.ndarray, n: int) -> np.ndarray:
        """Average of ``n`` captures of the same pattern, float32 in camera code values (0..255)."""
        acc = np.zeros((self.procam.camera_size[1], self.procam.camera_size[0], 3), np.float64)
        for _ in range(n):
            acc += self(pattern)
        return (acc / n).astype(np.float32)

    def mean_frame(self, key: str, pattern: np.ndarray, n: int) -> np.ndarray:
        """Average of ``n`` captures of ``pattern``, kept under ``key`` for this calibration run.

        A later call with the same ``key`` reuses the captures already taken and only adds the
        missing ones. Returns float32 camera codes (Hc, Wc, 3).
        """
        have_n, have = self._frames.get(key, (0, None))
        if have_n >= n:
            return have
        extra = self.mean(pattern, n - have_n)
        mean = extra if have is None else (have * have_n + extra * (n - have_n)) / n
        mean = mean.astype(np.float32)
        self._frames[key] = (n, mean)
        return mean

    def frame_count(self, key: str) -> int:
        """How many captures the kept mean ``key`` holds (0 if none)."""
        return self._frames.get(key, (0, None))[0]


def check_capturer(capture) -> Capturer:
    """``capture`` if it is a :class:`Capturer`, else an InputTypeError saying how to make one."""
    if not isinstance(capture, Capturer):
        raise InputTypeError(f"capture must be a Capturer (rtdefocus.calib.Capturer(procam)); "
                             f"got {type(capture).__name__}")
    return capture


def check_geometry(calib: Calibration, stage: str) -> None:
    """InputTypeError unless ``calib`` is a Calibration (the geometry stage's result)."""
    if not isinstance(calib, Calibration):
        raise InputTypeError(f"the {stage} stage fills a Calibration with its geometry: run the "
                             f"geometry stage first; got {type(calib).__name__}")
