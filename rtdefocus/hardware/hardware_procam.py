"""HardwareProCam: a real projector (a full-screen window) and a camera (OpenCV), a
:class:`rtdefocus.ProCam`."""

from __future__ import annotations

import logging
import time

import numpy as np

from ..errors import CaptureError, InputError
from ..procam import check_pattern

log = logging.getLogger(__name__)


class HardwareProCam:
    """A real projector (a full-screen window on monitor ``screen``) and a camera (OpenCV).

    Start-up (seconds): open the camera (FOURCC, then size, then rate; the negotiated mode is
    logged), open the window, optionally lock the camera's controls (``lock=True``), then, for
    a live camera, measure the projector-to-camera latency (black→white, timed), warn when one
    camera pixel covers more than ~1.5 projector pixels, and learn a coarse projector→camera
    map from ``2 * coarse_bits`` Gray-code patterns for the content check.

    ``capture(pattern)`` shows the pattern and waits until the swap is done (``glFinish``),
    drains the camera by time (every frame delivered before swap + ``settle`` is discarded, at
    least ``flush`` of them, until the driver's queue is empty), averages ``average`` frames,
    and checks that they show the pattern and not the previous one (:mod:`rtdefocus.hardware.sync`);
    a capture that fails the check is taken again with a longer settle time, up to
    ``recaptures`` times. A video file as camera (replays, tests) has no clock: ``settle`` is
    waited and exactly ``flush`` frames are skipped, with no latency measurement or check.

    Parameters
    ----------
    camera : int or str
        Camera index (0 = first; ``v4l2-ctl --list-devices`` on Linux), a stream URL, or a video file.
    screen : int
        Monitor index of the projector (0 = primary; ``rtdefocus info`` lists them).
    settle : float, optional
        Seconds from the swap to the first usable frame. Default: the measured latency plus two
        camera frames; a given value shorter than the latency is raised to it (with a warning).
    flush : int
        Frames discarded at least after each swap.
    average : int
        Frames averaged per capture (less noise).
    retries : int
        Extra attempts for each failed camera read, made by :class:`~.camera.Camera` (the
        stream is re-opened half way): the only place a read is retried, so a dead camera
        fails a capture after ``retries + 1`` reads with one :class:`CaptureError`.
    camera_size : (width, height), optional
        Resolution to ask for (:attr:`camera_size` is what it delivers).
    fourcc : str, optional
        Pixel format to ask for before the size, e.g. ``"MJPG"`` (fast at 720p and 1080p).
    fps : float, optional
        Camera frame rate to ask for.
    lock : bool
        Fix exposure (a whole number of projector frame periods), white balance and focus; turn
        sharpening and backlight compensation off; read them back (:attr:`controls`) and
        re-apply them after a stream restart.
    exposure : float, optional
        Exposure in seconds for ``lock`` (default: what auto-exposure chose on a white screen).
    verify : bool
        Check each capture's content (live cameras).
    coarse_bits : int
        The content check's map has ``2**coarse_bits`` cells across each projector axis.
    recaptures : int
        Attempts after a failed content check before :class:`CaptureError`.
    projector_size : (width, height), optional
        Default: the monitor's current video mode (:attr:`window` size).
    window : ProjectorWindow, optional
        An open window to draw the patterns in (then ``screen`` is ignored and the window is
        not closed by :meth:`close`). Anything with ``size``, ``show(frame) -> time``,
        ``poll()``, ``wait(s)`` and ``should_close`` works (tests pass a fake).
    fullscreen : bool
        Open the window full-screen (default) or windowed (previews, tests).
    capture_factory : callable, optional
        ``capture_factory(camera) -> cv2.VideoCapture``-like; default ``cv2.VideoCapture``.
    camera_backend : str
        OpenCV capture backend for a camera index: ``"auto"`` (default), ``"v4l2"``,
        ``"dshow"``, ``"msmf"`` or ``"avfoundation"``.

    Attributes
    ----------
    projector_size, camera_size : (width, height)
    window : ProjectorWindow
    cam : rtdefocus.hardware.Camera
    controls : ControlReport or None
    latency : rtdefocus.hardware.sync.Latency or None
    settle : float
        The settle time in use (it grows after a failed content check).
    recaptured : int
        Captures taken again after a failed content check.

    Raises
    ------
    CaptureError
        The camera cannot be opened, delivers no frame, or does not see the projector.
    """

    def __init__(self, camera: int | str = 0, screen: int = 0, *, settle: float | None = None,
                 flush: int = 1, average: int = 2, retries: int = 3,
                 camera_size: tuple[int, int] | None = None, fourcc: str | None = None,
                 fps: float | None = None, lock: bool = False, exposure: float | None = None,
                 verify: bool = True, coarse_bits: int = 3, recaptures: int = 3,
                 projector_size: tuple[int, int] | None = None, window=None,
                 fullscreen: bool = True, capture_factory=None, camera_backend: str = "auto"):
        from .camera import CameraSettings, open_camera

        if (settle is not None and settle < 0) or flush < 0 or average < 1 or retries < 0 \
                or recaptures < 0 or not 1 <= coarse_bits <= 6:
            raise InputError(f"need settle >= 0, flush >= 0, average >= 1, retries >= 0, "
                             f"recaptures >= 0, 1 <= coarse_bits <= 6; got {settle}, {flush}, "
                             f"{average}, {retries}, {recaptures}, {coarse_bits}")
        self.camera, self.screen, self.camera_backend = camera, screen, camera_backend
        self.flush, self.average, self.retries = int(flush), int(average), int(retries)
        self.recaptures, self.verify = int(recaptures), bool(verify)
        self.settle = float(settle or 0.0)
        self.captures = self.recaptured = 0
        self.controls = self.latency = self.coarse = None
        self.pixel_ratio: float | None = None
        self._stopped = False
        self._own_window = window is None
        self._prev = None                         # (pattern, camera cells) of the last capture
        self.window = None
        self.cam = open_camera(camera, CameraSettings(size=camera_size, fourcc=fourcc, fps=fps,
                                                      retries=retries, backend=camera_backend),
                               capture_factory=capture_factory)
        try:
            self.camera_size: tuple[int, int] = self.cam.size
            if window is None:
                from ..gl.window import ProjectorWindow
                window = ProjectorWindow(screen, fullscreen=fullscreen, size=projector_size)
            self.window = window
            self.projector_size: tuple[int, int] = tuple(projector_size or window.size)
            if self.projector_size != tuple(window.size):
                log.warning("projector_size %s differs from the window's %s: every pattern will be "
                            "scaled, which blurs the calibration; leave projector_size unset",
                            self.projector_size, window.size)
            self.frame_period = 1.0 / float(getattr(window, "refresh_rate", None) or 60.0)
            if lock:
                self._lock(exposure)
            if self.cam.live:
                self._measure(settle)
                if self.verify:
                    self._learn_coarse_map(coarse_bits)
        except BaseException:
            self.close()
            raise
        log.info("hardware procam: %s, projector %dx%d on screen %s, settle %.0f ms",
                 self.cam.describe(), *self.projector_size, screen, self.settle * 1e3)

    # ------------------------------------------------------------------ start-up
    def _show(self, pattern: np.ndarray) -> float:
        """Put a pattern up; the time the swap was done (the window blocks until then)."""
        t = self.window.show(pattern)
        return float(t) if t is not None else time.perf_counter()

    def _lock(self, exposure: float | None) -> None:
        from .camera_controls import apply_controls, lock_controls

        wp, hp = self.projector_size
        # Let auto-exposure settle on a white screen: the locked exposure then keeps white
        # below clipping.
        t = self._show(np.full((hp, wp, 3), 255, np.uint8))
        self.cam.drain(t + 1.0 if self.cam.live else 0.0)
        from .camera import backend_name
        self.controls = lock_controls(self.cam.cap, backend_name(self.cam.cap),
                                      frame_period=self.frame_period, exposure=exposure)

        def relock(cam) -> None:      # a stream restart resets the controls on many cameras
            apply_controls(cam.cap, self.controls.wanted, self.controls)
            log.warning("camera controls re-applied after the stream restart: %s",
                        self.controls.summary())

        self.cam.on_restart = relock
        t = self._show(np.zeros((hp, wp, 3), np.uint8))
        self.cam.drain(t + 0.5 if self.cam.live else 0.0)

    def _measure(self, settle: float | None) -> None:
        from .sync import lit_fraction, measure_latency, projector_px_per_camera_px

        self.latency = lat = measure_latency(self.cam, self._show, self.projector_size)
        needed = lat.seconds + 2 * self.cam.frame_period
        if settle is not None and settle < needed:
            log.warning("settle %.0f ms is shorter than the measured projector-to-camera latency "
                        "%.0f ms plus two camera frames: using %.0f ms", settle * 1e3,
                        lat.seconds * 1e3, needed * 1e3)
        self.settle = max(self.settle, needed)
        lit = lit_fraction(lat)
        self.pixel_ratio = ratio = projector_px_per_camera_px(self.projector_size, self.camera_size, lit)
        if ratio > 1.5:
            log.warning("one camera pixel covers %.1f projector pixels (the projection fills %.0f%% "
                        "of the %dx%d camera picture): the blur kernels will be under-sampled. Use "
                        "a higher camera resolution (--camera-size 1920x1080 --fourcc MJPG) or move "
                        "the camera closer", ratio, 100 * lit, *self.camera_size)
        self.white_level = float(np.median(lat.white[lat.white - lat.black > lat.contrast / 3]))

    def _learn_coarse_map(self, bits: int) -> None:
        from .sync import CoarseMap, gray_code_patterns

        caps = {}
        for axis, b, pattern in gray_code_patterns(self.projector_size, bits):
            caps[(axis, b)], _, _ = self._capture_once(pattern)
        self.coarse = CoarseMap(self.latency.black, self.latency.white, caps, bits)
        self._prev = (pattern, self.coarse.camera_cells(caps[(axis, b)]))

    # ------------------------------------------------------------------ capture
    def _capture_once(self, pattern: np.ndarray):
        t = self._show(pattern)
        if self.cam.live:
            self.cam.drain(t + self.settle, min_frames=self.flush)
        else:
            self.window.wait(self.settle)
            self.cam.drain(0.0, min_frames=self.flush)
        first = self.cam.read()
        acc = first.astype(np.float32)
        last = first
        for _ in range(self.average - 1):
            last = self.cam.read()
            acc += last
        return np.clip(np.rint(acc / self.average), 0, 255).astype(np.uint8), first, last

    def _check(self, frame, first, last, pattern) -> tuple[str | None, np.ndarray | None]:
        if self.coarse is None:
            return None, None
        cells = self.coarse.camera_cells(frame)
        if self.average > 1:
            change = float(np.abs(self.coarse.camera_cells(first) - self.coarse.camera_cells(last)).max())
            if change > 0.15:
                return (f"the picture changed by {change:.0%} of white while {self.average} frames "
                        "were averaged"), cells
        prev_pattern, prev_cells = self._prev or (None, None)
        return self.coarse.verify(cells, pattern, prev_pattern, prev_cells), cells

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        """Show ``pattern`` ((Hp, Wp, 3) uint8 RGB), drain, average ``average`` frames, check
        them; return (Hc, Wc, 3) uint8 RGB."""
        pattern = check_pattern(pattern, self.projector_size)
        if self.window is None or self.window.should_close:
            raise CaptureError("the projector window was closed; calibration stopped")
        if {"escape", "q", "close"} & set(self.window.poll()):
            self._stopped = True          # sticky: no later capture shows a pattern either
        if self._stopped:
            raise CaptureError("stopped from the projector window (q/Esc)")
        for attempt in range(self.recaptures + 1):
            frame, first, last = self._capture_once(pattern)
            reason, cells = self._check(frame, first, last, pattern)
            if reason is None:
                break
            self.recaptured += 1
            if attempt == self.recaptures:
                raise CaptureError(f"capture {self.captures + 1} does not show the pattern that was "
                                   f"projected after {self.recaptures + 1} attempts: {reason}. The "
                                   f"camera's delay varies beyond the {self.settle * 1e3:.0f} ms "
                                   "settle time: pass a longer --settle, use a USB camera rather "
                                   "than a network one, and keep the camera and surface still")
            self.settle = self.settle * 1.5 + self.cam.frame_period
            log.warning("capture %d: the camera frame does not show the pattern (%s); taking it "
                        "again with settle %.0f ms", self.captures + 1, reason, self.settle * 1e3)
        self._prev = (pattern, cells)
        self.captures += 1
        return frame

    def drift(self) -> float | None:
        """Relative change of the white level since start-up (a white screen is captured now):
        +0.05 = 5 % brighter. None for a video-file camera. Large values mean the exposure or
        the projector's brightness drifted during calibration (auto controls, eco mode, a lamp
        warming up): lock the camera (``lock=True``) and calibrate again."""
        if self.latency is None:
            return None
        from ..imageio import to_grey

        wp, hp = self.projector_size
        self._prev = None
        now = to_grey(self.capture(np.full((hp, wp, 3), 255, np.uint8)))
        lat = self.latency
        mask = lat.white - lat.black > lat.contrast / 3
        level = float(np.median(now[mask]))
        return level / max(self.white_level, 1.0) - 1.0

    def setup_record(self, *, monitors: list[dict] | None = None, cameras=None) -> dict:
        """What a calibration remembers of this hardware: ``{"monitor": ..., "camera": ...}``
        (:mod:`rtdefocus.hardware.remembered`); ``monitors`` and ``cameras`` default to the
        connected ones."""
        from .remembered import hardware_record

        return hardware_record(self, monitors=monitors, cameras=cameras)

    def report(self) -> dict:
        """What the start-up found: negotiated camera mode, controls, latency, settle, pixel ratio."""
        return {
            "camera": dict(self.cam.negotiated) if getattr(self, "cam", None) else None,
            "controls": ({"applied": self.controls.applied, "failed": self.controls.failed,
                          "exposure_s": self.controls.exposure_s} if self.controls else None),
            "latency_s": self.latency.seconds if self.latency else None,
            "settle_s": self.settle, "projector_px_per_camera_px": self.pixel_ratio,
            "captures": self.captures, "recaptured": self.recaptured,
            "restarts": self.cam.restarts if getattr(self, "cam", None) else 0,
        }

    def close(self) -> None:
        """Release the camera and close the window if this object opened it (idempotent)."""
        if getattr(self, "cam", None) is not None:
            self.cam.release()
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
