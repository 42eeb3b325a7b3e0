"""A camera opened through OpenCV: format negotiation, reads with retry, draining by time.

One helper serves calibration (:class:`rtdefocus.HardwareProCam`) and the player's live source
(:class:`rtdefocus.stream.CameraSource`).

Order matters when asking a camera for a mode. The pixel format (FOURCC) goes first: on V4L2
and DirectShow the list of sizes and rates depends on it (a 720p webcam offers 30 fps in MJPG
but 5–10 fps in uncompressed YUYV), and changing it after the size can reset the size. Then
the size, then the rate. What the camera actually delivers is read back (size from the first
frame, FOURCC and rate from the driver) and logged; differences from what was asked are
warnings, not errors: the calibration works at any size, and the log says what to change.

``CAP_PROP_BUFFERSIZE = 1`` keeps V4L2's queue short; other backends (DirectShow, network
streams, phones) ignore it, which the read-back reveals. Frames that were queued before a
pattern went up are therefore drained by *time* (:meth:`Camera.drain`), not by a frame count.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import CaptureError, InputError
from ..imageio import rgb_from_cv2

log = logging.getLogger(__name__)

#: ``capture_factory(source) -> cv2.VideoCapture``-like object (isOpened, read, grab, set, get,
#: release, getBackendName). Tests pass a fake camera through it.
CaptureFactory = Callable[[int | str], object]


@dataclass(frozen=True)
class CameraSettings:
    """What to ask the camera for. ``None`` leaves the driver's default.

    Attributes
    ----------
    size : (width, height)
        Frame size to request (``--camera-size 1920x1080``).
    fourcc : str
        Four-character pixel format, e.g. ``"MJPG"`` (``--fourcc``); set before the size.
    fps : float
        Frame rate to request (``--fps``).
    retries : int
        Extra attempts for a failed read; half way the stream is re-opened.
    backend : str
        OpenCV capture backend for a camera index (``--camera-backend``): one of
        :data:`CAMERA_BACKENDS`; ``"auto"`` lets OpenCV choose. Streams and files ignore it.
    """

    size: tuple[int, int] | None = None
    fourcc: str | None = None
    fps: float | None = None
    retries: int = 3
    backend: str = "auto"

    def __post_init__(self):
        if self.fourcc is not None and len(self.fourcc) != 4:
            raise InputError(f"fourcc must be four characters, e.g. MJPG or YUYV; got {self.fourcc!r}")
        if self.size is not None and (len(self.size) != 2 or min(self.size) <= 0):
            raise InputError(f"camera size must be (width, height) > 0; got {self.size}")
        if self.fps is not None and not self.fps > 0:
            raise InputError(f"camera fps must be > 0; got {self.fps}")
        if self.retries < 0:
            raise InputError(f"retries must be >= 0; got {self.retries}")
        if self.backend not in CAMERA_BACKENDS:
            raise InputError(f"camera backend must be one of {', '.join(CAMERA_BACKENDS)}; got "
                             f"{self.backend!r}")


#: ``--camera-backend`` names -> the ``cv2.CAP_*`` constant's name. v4l2 is Linux's,
#: dshow and msmf Windows', avfoundation macOS's; auto lets OpenCV pick.
CAMERA_BACKENDS = {"auto": "CAP_ANY", "v4l2": "CAP_V4L2", "dshow": "CAP_DSHOW",
                   "msmf": "CAP_MSMF", "avfoundation": "CAP_AVFOUNDATION"}


def backend_code(name: str) -> int:
    """``"dshow"`` -> ``cv2.CAP_DSHOW`` (see :data:`CAMERA_BACKENDS`)."""
    import cv2

    if name not in CAMERA_BACKENDS:
        raise InputError(f"camera backend must be one of {', '.join(CAMERA_BACKENDS)}; got {name!r}")
    return int(getattr(cv2, CAMERA_BACKENDS[name]))


def fourcc_code(text: str) -> int:
    """``"MJPG"`` -> OpenCV's integer FOURCC."""
    import cv2

    return int(cv2.VideoWriter_fourcc(*text))


def fourcc_text(code: float) -> str | None:
    """OpenCV's FOURCC property value -> ``"MJPG"`` (None when the backend does not say)."""
    code = int(code or 0)
    if code <= 0:
        return None
    text = "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4))
    return text if text.isprintable() and text.strip() else None


def default_factory(backend: str = "auto") -> CaptureFactory:
    """``cv2.VideoCapture`` opening a camera index through ``backend`` (streams and files
    through OpenCV's own choice)."""
    import cv2

    api = backend_code(backend)

    def factory(source: int | str):
        if isinstance(source, int) and api != cv2.CAP_ANY:
            return cv2.VideoCapture(source, api)
        return cv2.VideoCapture(source)

    return factory


def _normalise(source: int | str) -> int | str:
    if isinstance(source, str) and source.strip().isdigit():
        return int(source)            # "0" from a command line means the first camera, not a file
    return source


class Camera:
    """An open camera, stream or video file (use :func:`open_camera`).

    Attributes
    ----------
    source : int or str
    settings : CameraSettings
    size : (width, height) of the frames it delivers.
    negotiated : dict
        ``width``, ``height``, ``fourcc``, ``fps``, ``backend``, ``buffersize`` as the driver
        reports them after opening (``None`` where it does not say).
    live : bool
        Frames arrive in real time (a camera or stream); False for a video file (replays and
        tests), where time means nothing and frames are skipped by count.
    restarts : int
        How often the stream was re-opened after failed reads.
    on_restart : callable or None
        Called with the camera after each re-open (a stream restart resets exposure and white
        balance on many cameras: :class:`rtdefocus.HardwareProCam` re-applies its locks here).
    """

    def __init__(self, source: int | str, settings: CameraSettings | None = None, *,
                 capture_factory: CaptureFactory | None = None, what: str = "camera"):
        self.source = _normalise(source)
        self.settings = settings or CameraSettings()
        self.what = what
        self._factory = capture_factory or default_factory(self.settings.backend)
        self.live = not (isinstance(self.source, str) and Path(self.source).is_file())
        self.restarts = 0
        self.on_restart: Callable[[Camera], None] | None = None
        self.size: tuple[int, int] | None = None
        self.negotiated: dict = {}
        self._cap = None
        self._open()

    # ------------------------------------------------------------------ opening
    def _open(self) -> None:
        import cv2

        cap = self._factory(self.source)
        if cap is None or not cap.isOpened():
            hint = ("check that it is plugged in and that no other program (a video call, a "
                    "preview tool, another rtdefocus) is using it; `rtdefocus cameras` lists the "
                    "cameras with their index and backend (--camera-backend)"
                    if isinstance(self.source, int) else
                    "check the URL or path (it should play in a media player such as `ffplay URL`)")
            if cap is not None:
                cap.release()
            raise CaptureError(f"cannot open {self.what} {self.source!r}: {hint}")
        s = self.settings
        # FOURCC first: the sizes and rates on offer depend on it (module docstring).
        if s.fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, fourcc_code(s.fourcc))
        if s.size is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, int(s.size[0]))
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, int(s.size[1]))
        if s.fps:
            cap.set(cv2.CAP_PROP_FPS, float(s.fps))
        # Keep the driver's queue short where the backend supports it; the read-back says.
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        self._cap = cap

    def _negotiate(self, first: np.ndarray) -> None:
        """Read back the mode the camera settled on; log it and what differs from the request."""
        import cv2

        cap, s = self._cap, self.settings
        h, w = first.shape[:2]
        fps = _finite(cap.get(cv2.CAP_PROP_FPS))
        buffersize = _finite(cap.get(cv2.CAP_PROP_BUFFERSIZE))
        self.negotiated = {
            "width": w, "height": h, "fourcc": fourcc_text(cap.get(cv2.CAP_PROP_FOURCC)),
            "fps": fps, "backend": backend_name(cap),
            "buffersize": int(buffersize) if buffersize else None,
        }
        n = self.negotiated
        log.info("%s %r (%s): %dx%d %s at %s fps, driver queue %s", self.what, self.source,
                 n["backend"], w, h, n["fourcc"] or "(format not reported)",
                 f"{fps:.3g}" if fps else "?", n["buffersize"] or "?")
        if s.size is not None and (w, h) != tuple(s.size):
            log.warning("%s %r delivers %dx%d, not the %dx%d asked for (it has no such mode%s); "
                        "`v4l2-ctl -d N --list-formats-ext` lists its modes", self.what, self.source,
                        w, h, *s.size, "" if s.fourcc else ", or needs --fourcc MJPG for it")
        if s.fourcc and n["fourcc"] and n["fourcc"] != s.fourcc:
            log.warning("%s %r delivers %s, not %s", self.what, self.source, n["fourcc"], s.fourcc)
        if s.fps and fps and abs(fps - s.fps) > 0.5:
            log.warning("%s %r runs at %.3g fps, not the %.3g asked for%s", self.what, self.source,
                        fps, s.fps, "" if s.fourcc else " (uncompressed formats are slow at large "
                        "sizes: try --fourcc MJPG)")
        if self.live and (not n["buffersize"] or n["buffersize"] > 1):
            log.info("%s %r keeps a frame queue (CAP_PROP_BUFFERSIZE reads %s): queued frames are "
                     "drained by time after each pattern", self.what, self.source, n["buffersize"])

    def reopen(self) -> None:
        """Release and open again (a stream restart), then call :attr:`on_restart`."""
        if self._cap is not None:
            self._cap.release()
            self._cap = None
        self._open()
        self.restarts += 1
        log.warning("%s %r: stream re-opened (restart %d)", self.what, self.source, self.restarts)
        if self.on_restart is not None:
            self.on_restart(self)

    # ------------------------------------------------------------------ frames
    @property
    def cap(self):
        """The underlying ``cv2.VideoCapture`` (or the fake a test passed in)."""
        if self._cap is None:
            raise CaptureError(f"the {self.what} is closed (release() was called)")
        return self._cap

    @property
    def fps(self) -> float | None:
        return self.negotiated.get("fps")

    @property
    def frame_period(self) -> float:
        """Seconds between frames (1/30 when the driver does not say)."""
        fps = self.fps
        return 1.0 / fps if fps else 1.0 / 30.0

    def read(self) -> np.ndarray:
        """One frame as RGB uint8 ``(H, W, 3)``. A failed read is retried ``settings.retries``
        times, the stream re-opened half way; then :class:`CaptureError` says what to check."""
        tries = self.settings.retries + 1
        for attempt in range(tries):
            ok, bgr = self.cap.read()
            if ok and bgr is not None:
                rgb = rgb_from_cv2(bgr)
                size = (rgb.shape[1], rgb.shape[0])
                if self.size is None:
                    self.size = size
                    self._negotiate(rgb)
                elif size != self.size:
                    raise CaptureError(f"{self.what} {self.source!r} changed resolution from "
                                       f"{self.size[0]}x{self.size[1]} to {size[0]}x{size[1]} mid-run; "
                                       "fix it with --camera-size WxH (camera_size=(w, h)) and "
                                       "calibrate again")
                return rgb
            log.warning("%s %r: read failed (attempt %d of %d)", self.what, self.source,
                        attempt + 1, tries)
            if self.live and attempt + 1 == tries // 2 and tries >= 3:
                try:
                    self.reopen()
                except CaptureError as exc:
                    log.warning("%s", exc)
                    self._cap = None
                    break
                continue
            time.sleep(0.02 * (attempt + 1))
        raise CaptureError(f"{self.what} {self.source!r} delivered no frame in {tries} attempts. "
                           "Check that it is connected and that no other program uses it; for a "
                           "stream URL check the network; then run the command again")

    def grab(self) -> bool:
        """Take one frame off the driver's queue without decoding it."""
        return bool(self.cap.grab())

    def drain(self, until: float, *, min_frames: int = 0, max_seconds: float = 5.0) -> int:
        """Discard frames until ``time.perf_counter() >= until`` and the queue is empty.

        Grabs continuously (a queued frame comes back at once, a live one after about a frame
        period), so frames buffered before ``until`` are gone: the next :meth:`read` returns a
        frame delivered after ``until``. Empty = the last grab waited at least 40 % of a frame
        period. For a video file (not :attr:`live`) exactly ``min_frames`` frames are skipped.
        Returns the number of frames discarded.
        """
        if not self.live:
            for _ in range(min_frames):
                self.grab()          # a failed grab at the end of a file is harmless here
            return min_frames
        n, waited = 0, False
        hard_stop = time.perf_counter() + max(0.0, until - time.perf_counter()) + max_seconds
        while True:
            now = time.perf_counter()
            if now >= until and n >= min_frames and waited:
                return n
            if now >= hard_stop:
                log.warning("%s %r: still draining queued frames after %.1f s; the frames that "
                            "follow may be late", self.what, self.source, max_seconds)
                return n
            t = time.perf_counter()
            if not self.grab():
                self.read()           # a failed grab: let read() retry and re-open
            waited = time.perf_counter() - t >= 0.4 * self.frame_period
            n += 1

    def release(self) -> None:
        """Release the device (idempotent)."""
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def describe(self) -> str:
        n = self.negotiated
        if not n:
            return f"{self.what} {self.source!r}"
        fps = f"{n['fps']:.3g} fps" if n.get("fps") else "? fps"
        return (f"{self.what} {self.source!r} ({n['backend']}): {n['width']}x{n['height']} "
                f"{n['fourcc'] or '?'} at {fps}")

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _finite(value) -> float | None:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if np.isfinite(value) and 0 < value < 1e5 else None


def backend_name(cap) -> str:
    """``"V4L2"``, ``"DSHOW"``, ``"MSMF"``, ``"AVFOUNDATION"``, ``"FFMPEG"``... (``"?"``)."""
    try:
        return str(cap.getBackendName()).upper()
    except Exception:  # noqa: BLE001 - some builds raise when the backend has no name
        return "?"


def open_camera(source: int | str, settings: CameraSettings | None = None, *,
                capture_factory: CaptureFactory | None = None, what: str = "camera",
                **overrides) -> Camera:
    """Open a camera (index), stream (URL) or video file, read one frame to learn its real mode,
    and return the :class:`Camera`.

    ``overrides`` (``size=``, ``fourcc=``, ``fps=``, ``retries=``, ``backend=``) replace fields
    of ``settings``.

    Raises
    ------
    CaptureError
        It cannot be opened or delivers no frame.
    """
    settings = replace(settings or CameraSettings(), **overrides)
    cam = Camera(source, settings, capture_factory=capture_factory, what=what)
    try:
        cam.read()                    # learn the real size and mode; wakes the sensor up
    except BaseException:
        cam.release()
        raise
    return cam
