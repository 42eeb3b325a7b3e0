"""Where frames come from: a still image, a folder of slides, a video file, a live camera.

Every source hands out :class:`Frame` objects holding RGB uint8 ``(H, W, 3)`` images (OpenCV's
BGR is converted in :mod:`rtdefocus.imageio`) with increasing ``index``. Two flags tell the
frame loop how to treat a source:

``live``
    Frames arrive in real time whether or not anyone takes them (a camera). The loop never
    makes a live source wait: when the solver falls behind, stale frames are dropped.
``still``
    The same picture stays up until the viewer moves on (an image, slides): the loop keeps
    refining it until the solver converges instead of asking for the next frame.

:func:`open_source` turns the command line's SOURCE into one of these.
"""

from __future__ import annotations

import logging
import re
import time
from collections import OrderedDict
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..imageio import IMAGE_EXTENSIONS, read_image, rgb_from_cv2

log = logging.getLogger(__name__)

URL_SCHEMES = ("rtsp://", "rtmp://", "http://", "https://", "udp://", "tcp://", "srt://")


@dataclass(frozen=True)
class Frame:
    """One input frame.

    Attributes
    ----------
    index : int
        Position in the source, from 0; strictly increasing in the order frames are read.
    image : ndarray, (H, W, 3) uint8
        RGB.
    t_read : float
        ``time.perf_counter()`` when the frame was read (for latency).
    name : str or None
        File name of a slide.
    """

    index: int
    image: np.ndarray
    t_read: float
    name: str | None = None


class Source:
    """Base class of frame sources; use as a context manager or call :meth:`close`."""

    kind = "source"
    live = False
    still = False
    #: Nominal frames per second (None when unknown or not meaningful).
    fps: float | None = None
    #: Number of frames when known in advance (None for cameras and unknown lengths).
    n_frames: int | None = None

    def read(self) -> Frame | None:
        """The next frame, or None at the end of the source."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the file or device (idempotent)."""

    def describe(self) -> str:
        return self.kind

    def __iter__(self) -> Iterator[Frame]:
        while (frame := self.read()) is not None:
            yield frame

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def natural_key(name: str) -> list:
    """Sort key that orders ``slide2`` before ``slide10`` (digits compare as numbers)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


class SlidesSource(Source):
    """Still images shown one at a time: a single image file, or a folder of them.

    Images load on demand and a few stay in memory (``keep``), so a deck of hundreds of large
    slides does not fill the RAM. :meth:`read` walks the slides in order (for rendering them to
    files); the player navigates with :meth:`load`.

    Parameters
    ----------
    path : path of an image file, or of a folder of images (natural sort order: 2 before 10).
    keep : how many decoded slides to keep in memory.
    """

    still = True

    def __init__(self, path: str | Path, keep: int = 4):
        path = Path(path)
        if path.is_dir():
            files = [p for p in path.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]
            if not files:
                kinds = ", ".join(sorted(IMAGE_EXTENSIONS))
                raise InputError(f"folder {str(path)!r} holds no images ({kinds}); "
                                 "export the slides there as PNG or JPEG")
            self.paths = sorted(files, key=lambda p: natural_key(p.name))
            self.kind = "slides"
        elif path.is_file():
            self.paths = [path]
            self.kind = "image"
        else:
            raise InputError(f"no image or folder at {str(path)!r}")
        self.path = path
        self.n_frames = len(self.paths)
        self._keep = max(1, keep)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._next = 0

    def load(self, i: int) -> np.ndarray:
        """Slide ``i`` as RGB uint8 (H, W, 3)."""
        if not 0 <= i < self.n_frames:
            raise InputError(f"slide {i} out of range 0..{self.n_frames - 1}")
        img = self._cache.get(i)
        if img is None:
            img = read_image(self.paths[i])
            self._cache[i] = img
            while len(self._cache) > self._keep:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(i)
        return img

    def name(self, i: int) -> str:
        return self.paths[i].name

    def read(self) -> Frame | None:
        if self._next >= self.n_frames:
            return None
        i = self._next
        self._next += 1
        return Frame(i, self.load(i), time.perf_counter(), self.name(i))

    def describe(self) -> str:
        return f"{self.kind} {self.path} ({self.n_frames} image{'s' if self.n_frames > 1 else ''})"


class VideoSource(Source):
    """A video file decoded by OpenCV (FFmpeg): every frame, in order."""

    kind = "video"

    def __init__(self, path: str | Path):
        import cv2

        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"no video file at {str(self.path)!r}")
        self._cap = cv2.VideoCapture(str(self.path))
        if not self._cap.isOpened():
            raise InputError(f"OpenCV cannot open {str(self.path)!r} as a video: unknown container "
                             "or codec. Convert it, e.g. `ffmpeg -i IN -c:v libx264 OUT.mp4`")
        fps = self._cap.get(cv2.CAP_PROP_FPS)
        self.fps = float(fps) if fps and np.isfinite(fps) and 0 < fps < 1000 else None
        n = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        self.n_frames = n if n > 0 else None  # a container's count is a hint, not a promise
        self._index = 0

    def read(self) -> Frame | None:
        if self._cap is None:
            return None
        ok, bgr = self._cap.read()
        if not ok or bgr is None:
            return None
        frame = Frame(self._index, rgb_from_cv2(bgr), time.perf_counter())
        self._index += 1
        return frame

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def describe(self) -> str:
        fps = f"{self.fps:.3g} fps" if self.fps else "unknown fps"
        return f"video {self.path} ({self.n_frames or '?'} frames, {fps})"


class CameraSource(Source):
    """A live camera (index) or network stream (URL): frames come at the camera's pace.

    Opened and read through the helper :class:`rtdefocus.hardware.Camera` shares with
    calibration: FOURCC before size, the negotiated mode logged, failed reads retried
    ``retries`` times (the stream re-opened half way), then :class:`CaptureError`.

    Parameters
    ----------
    camera : index, URL or video file.
    size : (width, height) to ask for.
    retries : extra attempts per failed read.
    fourcc : pixel format to ask for, e.g. ``"MJPG"``.
    fps : frame rate to ask for.
    backend : OpenCV capture backend for an index (``"auto"``, ``"v4l2"``, ``"dshow"``, ...).
    capture_factory : ``capture_factory(camera) -> cv2.VideoCapture``-like (tests).
    """

    kind = "camera"
    live = True

    def __init__(self, camera: int | str = 0, size: tuple[int, int] | None = None, retries: int = 5,
                 *, fourcc: str | None = None, fps: float | None = None, backend: str = "auto",
                 capture_factory=None):
        from ..hardware.camera import CameraSettings, open_camera

        self.camera = camera
        self.retries = retries
        self._cam = open_camera(camera, CameraSettings(size=size, fourcc=fourcc, fps=fps,
                                                       retries=retries, backend=backend),
                                capture_factory=capture_factory)
        self.fps = self._cam.fps
        self._index = 0

    def read(self) -> Frame | None:
        if self._cam is None:
            return None
        frame = Frame(self._index, self._cam.read(), time.perf_counter())
        self._index += 1
        return frame

    def close(self) -> None:
        if self._cam is not None:
            self._cam.release()
            self._cam = None

    def describe(self) -> str:
        return self._cam.describe() if self._cam is not None else f"camera {self.camera!r}"


class ArraySource(Source):
    """Frames from memory (any iterable of RGB uint8 arrays): for programs and tests.

    With ``live=True`` and ``fps`` set it behaves like a camera: frame ``i`` becomes available
    at ``t0 + i / fps`` (the first :meth:`read` sets ``t0``) and :meth:`read` waits for it, so a
    consumer slower than ``fps`` falls behind exactly as it would behind a real camera.
    """

    kind = "frames"

    def __init__(self, frames: Iterable[np.ndarray], *, fps: float | None = None, live: bool = False,
                 n_frames: int | None = None):
        if live and not fps:
            raise InputError("a live ArraySource needs fps (the rate frames arrive at)")
        self._it = iter(frames)
        self.fps = fps
        self.live = live
        self.n_frames = n_frames if n_frames is not None else (
            len(frames) if hasattr(frames, "__len__") else None)
        self._index = 0
        self._t0: float | None = None

    def read(self) -> Frame | None:
        try:
            img = next(self._it)
        except StopIteration:
            return None
        if self.live:
            now = time.perf_counter()
            if self._t0 is None:
                self._t0 = now
            due = self._t0 + self._index / self.fps
            if due > now:
                time.sleep(due - now)
        frame = Frame(self._index, np.asarray(img), time.perf_counter())
        self._index += 1
        return frame

    def describe(self) -> str:
        return f"frames ({'live, ' if self.live else ''}{self.n_frames or '?'} frames)"


def parse_camera(spec: str) -> int | str | None:
    """``"camera:0"`` -> 0, ``"camera:rtsp://..."`` or a bare stream URL -> the URL; else None."""
    if spec.lower().startswith("camera:"):
        rest = spec[len("camera:"):]
        if rest.isdigit():
            return int(rest)
        if rest:
            return rest
        raise InputError("camera source must be camera:INDEX (e.g. camera:0) or camera:URL")
    if spec.lower().startswith(URL_SCHEMES):
        return spec
    return None


def open_source(spec: str | Path, *, camera_size: tuple[int, int] | None = None,
                fourcc: str | None = None, camera_fps: float | None = None,
                camera_backend: str = "auto") -> Source:
    """The source a command-line SOURCE names.

    ``camera:N`` or ``camera:URL`` or a stream URL (rtsp://, http://, ...) -> :class:`CameraSource`;
    a folder -> slides; an image file -> one slide; any other file -> :class:`VideoSource`.
    """
    text = str(spec)
    camera = parse_camera(text)
    if camera is not None:
        return CameraSource(camera, size=camera_size, fourcc=fourcc, fps=camera_fps,
                            backend=camera_backend)
    path = Path(text).expanduser()
    if path.is_dir():
        return SlidesSource(path)
    if path.is_file():
        if path.suffix.lower() in IMAGE_EXTENSIONS:
            return SlidesSource(path)
        return VideoSource(path)
    raise InputError(f"SOURCE {text!r} not found: give an image, a folder of images, a video file, "
                     "camera:INDEX (e.g. camera:0) or a stream URL")
