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
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..imageio import IMAGE_EXTENSIONS, read_image, rgb_from_cv2
from .source import Frame, Pacer, Source

log = logging.getLogger(__name__)

URL_SCHEMES = ("rtsp://", "rtmp://", "http://", "https://", "udp://", "tcp://", "srt://")


def natural_key(name: str) -> list:
    """Sort key that orders ``slide2`` before ``slide10`` (digits compare as numbers)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


PDF_EXTENSIONS = frozenset({".pdf"})
#: What a slide deck can hold: images, and PDFs (each page a slide).
STILL_EXTENSIONS = IMAGE_EXTENSIONS | PDF_EXTENSIONS
#: File extensions a playlist folder plays as videos.
VIDEO_EXTENSIONS = frozenset({".mp4", ".m4v", ".mov", ".mkv", ".avi", ".webm", ".mpg", ".mpeg",
                              ".wmv", ".flv", ".ts", ".ogv"})


class SlidesSource(Source):
    """Still images shown one at a time: an image file, a PDF (one slide per page), a folder of
    images and PDFs, or a list of such files.

    Images load on demand and a few stay in memory (``keep``), so a deck of hundreds of large
    slides does not fill the RAM. :meth:`read` walks the slides in order (for rendering them to
    files); the player navigates with :meth:`load`.

    Parameters
    ----------
    path : path of an image file, a PDF, a folder of them (natural sort order: 2 before 10), or
        a list of image and PDF files (shown in that order).
    keep : how many decoded slides to keep in memory.
    size : (width, height) PDF pages are rendered into (aspect kept): the projector's.
    transform : ``transform(image) -> image`` applied to every slide as it loads (placement).
    """

    still = True

    def __init__(self, path, keep: int = 4, *, size: tuple[int, int] | None = None,
                 transform=None):
        if isinstance(path, (list, tuple)):
            files = [Path(p) for p in path]
            self.kind = "slides"
            path = files[0].parent if files else Path(".")
        else:
            path = Path(path)
            if path.is_dir():
                files = [p for p in path.iterdir() if p.suffix.lower() in STILL_EXTENSIONS and p.is_file()]
                if not files:
                    kinds = ", ".join(sorted(STILL_EXTENSIONS))
                    raise InputError(f"folder {str(path)!r} holds no images or PDFs ({kinds}); "
                                     "export the slides there as PNG, JPEG or PDF")
                files = sorted(files, key=lambda p: natural_key(p.name))
                self.kind = "slides"
            elif path.is_file():
                files = [path]
                self.kind = "pdf" if path.suffix.lower() in PDF_EXTENSIONS else "image"
            else:
                raise InputError(f"no image or folder at {str(path)!r}")
        self.path = path
        self._decks: dict[Path, object] = {}
        #: One entry per slide: its file, and its page for a PDF (None for an image).
        self.paths: list[Path] = []
        self.pages: list[int | None] = []
        self._size = size
        try:
            for f in files:
                if f.suffix.lower() in PDF_EXTENSIONS:
                    from .pdf import PdfDeck

                    deck = self._decks[f] = PdfDeck(f, size)
                    self.paths += [f] * deck.n_pages
                    self.pages += list(range(deck.n_pages))
                else:
                    self.paths.append(f)
                    self.pages.append(None)
        except BaseException:
            self.close()
            raise
        if not self.paths:
            raise InputError(f"no slides in {str(path)!r}")
        self.n_frames = len(self.paths)
        self.transform = transform
        self._keep = max(1, keep)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._next = 0

    def load(self, i: int) -> np.ndarray:
        """Slide ``i`` as RGB uint8 (H, W, 3)."""
        if not 0 <= i < self.n_frames:
            raise InputError(f"slide {i} out of range 0..{self.n_frames - 1}")
        img = self._cache.get(i)
        if img is None:
            page = self.pages[i]
            img = read_image(self.paths[i]) if page is None else self._decks[self.paths[i]].render(page)
            if self.transform is not None:
                img = self.transform(img)
            self._cache[i] = img
            while len(self._cache) > self._keep:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(i)
        return img

    def name(self, i: int) -> str:
        page = self.pages[i]
        return self.paths[i].name if page is None else f"{self.paths[i].name} p{page + 1}"

    def read(self) -> Frame | None:
        if self._next >= self.n_frames:
            return None
        i = self._next
        self._next += 1
        return Frame(i, self.load(i), time.perf_counter(), self.name(i))

    def close(self) -> None:
        for deck in self._decks.values():
            deck.close()
        self._decks = {}

    def describe(self) -> str:
        n, unit = self.n_frames, "page" if self.kind == "pdf" else "image"
        return f"{self.kind} {self.path} ({n} {unit}{'s' if n > 1 else ''})"


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
            if self._index == 0:
                raise InputError(f"{str(self.path)!r} opens as a video but no frame could be decoded; "
                                 "re-encode it, e.g. `ffmpeg -i IN -c:v libx264 -pix_fmt yuv420p OUT.mp4`")
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
    at ``t0 + i / fps`` (the first :meth:`read` sets ``t0``; the frame's ``t_read``) and
    :meth:`read` waits for it, so a consumer slower than ``fps`` falls behind exactly as it
    would behind a real camera.
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
        self._pacer = Pacer()

    def read(self) -> Frame | None:
        try:
            img = next(self._it)
        except StopIteration:
            return None
        t_read = time.perf_counter()
        if self.live:
            # Stamped with its time of arrival, not the (later) moment this thread woke up:
            # the frames after it arrive on the same clock, whatever the wake-up's delay
            # (a busy CPU, the other thread holding the GIL), so that is what deadlines count from.
            t_read = self._pacer.wait(self._index, self.fps)
        frame = Frame(self._index, np.asarray(img), t_read)
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


class TransformedSource(Source):
    """Another source's frames passed through ``transform(image) -> image`` (placement)."""

    def __init__(self, inner: Source, transform):
        self.inner, self.transform = inner, transform
        self.kind, self.live, self.still = inner.kind, inner.live, inner.still
        self.fps, self.n_frames = inner.fps, inner.n_frames

    def read(self) -> Frame | None:
        frame = self.inner.read()
        if frame is None:
            return None
        return Frame(frame.index, self.transform(frame.image), frame.t_read, frame.name)

    def close(self) -> None:
        self.inner.close()

    def describe(self) -> str:
        return self.inner.describe()

    def __getattr__(self, name):          # skipped, last_pts, set_paused... of the inner source
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)


def open_source(spec: str | Path, *, camera_size: tuple[int, int] | None = None,
                fourcc: str | None = None, camera_fps: float | None = None,
                camera_backend: str = "auto",
                projector_size: tuple[int, int] | None = None, realtime: bool = False,
                audio: bool = True, placement=None, capture_fps: float | None = None) -> Source:
    """The source a command-line SOURCE names.

    ``camera:N`` or ``camera:URL`` or a stream URL (rtsp://, http://, ...) -> :class:`CameraSource`;
    ``screen:N`` / ``window:TITLE`` -> a monitor or a window grabbed live
    (:mod:`~rtdefocus.stream.capture`); a folder of images and PDFs, an image, a PDF -> slides
    (PDF pages rendered at ``projector_size``); any other file -> a video. A folder that also
    holds videos is a playlist: play it with :class:`~rtdefocus.stream.show.Show`.

    Parameters
    ----------
    camera_backend : OpenCV capture backend of a camera source (``auto``, ``v4l2``, ``dshow``,
        ``msmf``, ``avfoundation``).
    projector_size : (width, height) PDF pages are rendered at.
    realtime : the frames go to the projector window: a video is then shown by its audio clock
        with its sound (PyAV, the ``show`` extra; without it OpenCV decodes it, without sound).
    audio : False: no sound (``--no-audio``); the video runs at wall time.
    placement : ``placement(image) -> image`` applied to every frame
        (:class:`~rtdefocus.stream.placement.Placement`).
    capture_fps : grabs per second of a screen or window source (default 30).
    """
    text = str(spec)
    src = _open(text, camera_size=camera_size, fourcc=fourcc, camera_fps=camera_fps,
                camera_backend=camera_backend, projector_size=projector_size, realtime=realtime,
                audio=audio, capture_fps=capture_fps)
    if placement is None:
        return src
    if isinstance(src, SlidesSource):
        src.transform = placement
        return src
    return TransformedSource(src, placement)


def _open(text: str, *, camera_size, fourcc, camera_fps, camera_backend, projector_size, realtime,
          audio, capture_fps) -> Source:
    camera = parse_camera(text)
    if camera is not None:
        return CameraSource(camera, size=camera_size, fourcc=fourcc, fps=camera_fps,
                            backend=camera_backend)
    low = text.lower()
    if low.startswith("screen:"):
        from .capture import ScreenSource

        rest = text[len("screen:"):]
        if not rest.isdigit():
            raise InputError(f"screen source must be screen:INDEX (e.g. screen:1); got {text!r}")
        return ScreenSource(int(rest), fps=capture_fps or 30.0)
    if low.startswith("window:"):
        from .capture import WindowSource

        title = text[len("window:"):]
        if not title:
            raise InputError("window source must be window:TITLE (part of the window's title)")
        return WindowSource(title, fps=capture_fps or 30.0)
    path = Path(text).expanduser()
    if path.is_dir():
        videos = [p.name for p in path.iterdir() if p.suffix.lower() in VIDEO_EXTENSIONS]
        if videos:
            raise InputError(f"folder {text!r} holds videos ({', '.join(sorted(videos)[:3])}...): it is "
                             "a playlist; play it with rtdefocus.stream.Show (the CLI does)")
        return SlidesSource(path, size=projector_size)
    if path.is_file():
        if path.suffix.lower() in STILL_EXTENSIONS:
            return SlidesSource(path, size=projector_size)
        return open_video(path, realtime=realtime, audio=audio)
    raise InputError(f"SOURCE {text!r} not found: give an image, a PDF, a folder, a video file, "
                     "camera:INDEX (e.g. camera:0), screen:INDEX, window:TITLE or a stream URL")


_told_no_pyav = False


def open_video(path: str | Path, *, realtime: bool = False, audio: bool = True) -> Source:
    """A video file. Realtime (the window): PyAV with its sound, frames picked by the audio
    clock (:class:`~rtdefocus.stream.avvideo.AvVideoSource`); without PyAV, or for rendering to
    files (every frame, no sound): OpenCV (:class:`VideoSource`)."""
    global _told_no_pyav
    if realtime:
        from .avvideo import AvVideoSource, have_pyav

        if have_pyav():
            from .audio import open_audio_output

            return AvVideoSource(path, clock=open_audio_output(mute=not audio))
        if not _told_no_pyav:
            log.warning("videos play without sound and by the wall clock: install PyAV with "
                        "pip install rtdefocus[show]")
            _told_no_pyav = True
    return VideoSource(path)
