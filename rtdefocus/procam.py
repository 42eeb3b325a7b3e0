"""The ProCam protocol: a projector and a camera looking at the surface.

Anything that implements it can be calibrated: the built-in virtual set-up
(:mod:`rtdefocus.sim`) and real hardware (:class:`HardwareProCam`).
"""

from __future__ import annotations

import logging
import time
from typing import Protocol, runtime_checkable

import numpy as np

from .errors import CaptureError, InputError

log = logging.getLogger(__name__)


@runtime_checkable
class ProCam(Protocol):
    """A projector and a camera looking at the surface.

    Attributes
    ----------
    projector_size : (width, height) of the projector in pixels.
    camera_size : (width, height) of the camera in pixels.
    """

    projector_size: tuple[int, int]
    camera_size: tuple[int, int]

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        """Show ``pattern`` ((Hp, Wp, 3) uint8 RGB) full-screen; return one camera frame
        ((Hc, Wc, 3) uint8 RGB)."""
        ...


def check_pattern(pattern: np.ndarray, projector_size: tuple[int, int]) -> np.ndarray:
    """Validate a projector pattern: (Hp, Wp, 3) uint8 RGB (a (Hp, Wp) gray one is expanded)."""
    wp, hp = projector_size
    pattern = np.asarray(pattern)
    if pattern.ndim == 2:
        pattern = np.repeat(pattern[:, :, None], 3, axis=2)
    if pattern.shape != (hp, wp, 3):
        raise InputError(f"pattern must be (H, W, 3) = ({hp}, {wp}, 3) for a {wp}x{hp} projector; "
                         f"got shape {pattern.shape}. Resize it or use comp.warp() first.")
    if pattern.dtype != np.uint8:
        raise InputError(f"pattern must be uint8 RGB (0..255); got dtype {pattern.dtype}. "
                         "Convert with np.clip(x * 255, 0, 255).astype(np.uint8) for [0, 1] floats.")
    return pattern


class HardwareProCam:
    """A real projector (a full-screen window on monitor ``screen``) and a camera (OpenCV).

    ``capture(pattern)`` shows the pattern, waits ``settle`` seconds for the projector and the
    camera's exposure to follow, discards ``flush`` frames the camera had already buffered
    (they may show the previous pattern), reads ``average`` frames and returns their mean.
    A failed read is retried ``retries`` times before :class:`CaptureError` says what to check.
    Lock the camera's exposure, white balance and focus before calibrating (docs/hardware.md).

    Parameters
    ----------
    camera : int or str
        Camera index (0 = first; ``ls /dev/video*`` on Linux), a stream URL, or a video file.
    screen : int
        Monitor index of the projector (0 = primary).
    settle : float
        Seconds between showing a pattern and reading the camera.
    flush : int
        Frames read and discarded after settling.
    average : int
        Frames averaged per capture (less noise).
    retries : int
        Extra attempts for each failed camera read.
    camera_size : (width, height), optional
        Resolution to ask the camera for (it may pick another; :attr:`camera_size` is what it
        delivers).
    projector_size : (width, height), optional
        Default: the monitor's current video mode (:attr:`window` size).
    window : ProjectorWindow, optional
        An open window to draw the patterns in (then ``screen`` is ignored and the window is
        not closed by :meth:`close`).
    fullscreen : bool
        Open the window full-screen (default) or windowed (previews, tests).

    Attributes
    ----------
    projector_size, camera_size : (width, height)
    window : ProjectorWindow

    Raises
    ------
    CaptureError
        The camera cannot be opened or delivers no frame.
    """

    def __init__(self, camera: int | str = 0, screen: int = 0, *, settle: float = 0.3,
                 flush: int = 3, average: int = 2, retries: int = 3,
                 camera_size: tuple[int, int] | None = None,
                 projector_size: tuple[int, int] | None = None, window=None, fullscreen: bool = True):
        from .stream.sources import open_capture

        if settle < 0 or flush < 0 or average < 1 or retries < 0:
            raise InputError(f"need settle >= 0, flush >= 0, average >= 1, retries >= 0; got "
                             f"{settle}, {flush}, {average}, {retries}")
        self.camera, self.screen = camera, screen
        self.settle, self.flush = float(settle), int(flush)
        self.average, self.retries = int(average), int(retries)
        self.captures = 0
        self._stopped = False
        self._cap = open_capture(camera, camera_size)
        self._own_window = window is None
        self.window = None
        try:
            first = self._read()                    # learn the real frame size (and wake it up)
            self.camera_size: tuple[int, int] = (first.shape[1], first.shape[0])
            if window is None:
                from .gl.window import ProjectorWindow
                window = ProjectorWindow(screen, fullscreen=fullscreen, size=projector_size)
            self.window = window
        except BaseException:
            self.close()
            raise
        self.projector_size: tuple[int, int] = tuple(projector_size or window.size)
        if self.projector_size != tuple(window.size):
            log.warning("projector_size %s differs from the window's %s: every pattern will be "
                        "scaled, which blurs the calibration; leave projector_size unset",
                        self.projector_size, window.size)
        log.info("hardware procam: camera %r %dx%d, projector %dx%d on screen %s", camera,
                 *self.camera_size, *self.projector_size, screen)

    def _read(self) -> np.ndarray:
        """One camera frame as RGB uint8, retried; CaptureError after ``retries`` extra attempts."""
        from .imageio import rgb_from_cv2

        if self._cap is None:
            raise CaptureError("the camera is closed (HardwareProCam.close() was called)")
        for attempt in range(self.retries + 1):
            ok, bgr = self._cap.read()
            if ok and bgr is not None:
                rgb = rgb_from_cv2(bgr)
                size = getattr(self, "camera_size", None)
                if size is not None and (rgb.shape[1], rgb.shape[0]) != size:
                    raise CaptureError(f"camera {self.camera!r} changed resolution from {size[0]}x{size[1]} "
                                       f"to {rgb.shape[1]}x{rgb.shape[0]} mid-run; fix it with "
                                       "camera_size=(w, h) (--camera-size) and recalibrate")
                return rgb
            log.warning("camera %r: read failed (attempt %d of %d)", self.camera, attempt + 1,
                        self.retries + 1)
            time.sleep(0.05 * (attempt + 1))
        raise CaptureError(f"camera {self.camera!r} delivered no frame in {self.retries + 1} attempts. "
                           "Check that it is connected and that no other program uses it; for a "
                           "stream URL check the network; then run the command again")

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        """Show ``pattern`` ((Hp, Wp, 3) uint8 RGB), settle, flush, average ``average`` frames;
        return (Hc, Wc, 3) uint8 RGB."""
        pattern = check_pattern(pattern, self.projector_size)
        if self.window is None or self.window.should_close:
            raise CaptureError("the projector window was closed; calibration stopped")
        if {"escape", "q", "close"} & set(self.window.poll()):
            self._stopped = True          # sticky: a retrying caller must not show the next one
        if self._stopped:
            raise CaptureError("stopped from the projector window (q/Esc)")
        self.window.show(pattern)
        self.window.wait(self.settle)
        for _ in range(self.flush):
            # Frames the driver buffered before the pattern was up; a failed grab is harmless.
            self._cap.grab()
        acc = self._read().astype(np.float32)
        for _ in range(self.average - 1):
            acc += self._read()
        self.captures += 1
        return np.clip(np.rint(acc / self.average), 0, 255).astype(np.uint8)

    def close(self) -> None:
        """Release the camera and close the window if this object opened it (idempotent)."""
        if getattr(self, "_cap", None) is not None:
            self._cap.release()
            self._cap = None
        if self._own_window and self.window is not None:
            self.window.close()
        self.window = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"HardwareProCam(camera={self.camera!r}, screen={self.screen}, "
                f"projector_size={getattr(self, 'projector_size', None)}, "
                f"camera_size={getattr(self, 'camera_size', None)})")
