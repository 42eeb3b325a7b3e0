"""Where compensated frames go: the projector window, a video file, numbered images, nowhere.

Every sink takes RGB uint8 ``(Hp, Wp, 3)`` frames through :meth:`Sink.write`. Two flags tell the
frame loop how to drive it:

``realtime``
    A viewer is watching (the window): the loop paces file sources to their frame rate, holds
    the frame rate by adapting the iteration budget and drops stale frames.
    File sinks are not realtime: every frame is written, in order, fully solved.
``interactive``
    :meth:`Sink.poll` returns key presses (the window's), which the loop dispatches.
``threaded``
    :meth:`Sink.write` may run on a thread of its own (:mod:`rtdefocus.stream.threads`): the
    file sinks, whose OpenCV encode releases the GIL. Not the window (GL stays on its thread).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import InputError, RtDefocusError
from ..imageio import IMAGE_EXTENSIONS, cv2_from_rgb, write_image

log = logging.getLogger(__name__)

VIDEO_EXTENSIONS = frozenset({".mp4", ".avi", ".mkv", ".mov", ".m4v"})


class Sink:
    """Base class of frame sinks; use as a context manager or call :meth:`close`."""

    kind = "sink"
    realtime = False
    interactive = False
    threaded = False

    def write(self, frame: np.ndarray, index: int) -> None:
        """Take one frame ((H, W, 3) uint8 RGB); ``index`` is the source frame it came from."""
        raise NotImplementedError

    def poll(self) -> list[str]:
        """Key names pressed since the last call (interactive sinks); ``[]`` otherwise."""
        return []

    def close(self) -> None:
        """Finish the file or close the window (idempotent)."""

    def describe(self) -> str:
        return self.kind

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _check_frame(frame: np.ndarray) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise InputError(f"sink frames must be (H, W, 3) uint8 RGB; got {frame.shape} {frame.dtype}")
    return frame


class NullSink(Sink):
    """Discards frames (benchmarks); counts them and keeps the last one's shape."""

    kind = "null"

    def __init__(self) -> None:
        self.count = 0
        self.last_shape: tuple[int, ...] | None = None

    def write(self, frame: np.ndarray, index: int) -> None:
        self.last_shape = _check_frame(frame).shape
        self.count += 1


class VideoFileSink(Sink):
    """A video file written by OpenCV (``mp4v`` in .mp4/.mov/.m4v, ``MJPG`` in .avi by default).

    The writer opens on the first frame (its size fixes the video's); later frames must match.
    """

    kind = "video file"
    threaded = True

    def __init__(self, path: str | Path, fps: float = 30.0, fourcc: str | None = None):
        self.path = Path(path)
        self.fps = float(fps) if fps and fps > 0 else 30.0
        if fourcc is None:
            fourcc = {".avi": "MJPG", ".mkv": "MJPG"}.get(self.path.suffix.lower(), "mp4v")
        if len(fourcc) != 4:
            raise InputError(f"fourcc must be 4 characters (e.g. mp4v, MJPG); got {fourcc!r}")
        self.fourcc = fourcc
        self._writer = None
        self._size: tuple[int, int] | None = None
        self.count = 0

    def write(self, frame: np.ndarray, index: int) -> None:
        import cv2

        frame = _check_frame(frame)
        h, w = frame.shape[:2]
        if self._writer is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*self.fourcc),
                                           self.fps, (w, h))
            if not self._writer.isOpened():
                self._writer = None
                raise RtDefocusError(f"OpenCV cannot write {self.fourcc} video to {str(self.path)!r}: "
                                     "check the folder, or use another extension (.avi writes MJPG, "
                                     "or write images to a folder with --out DIR)")
            self._size = (w, h)
        elif (w, h) != self._size:
            raise InputError(f"frame {index} is {w}x{h} but the video is {self._size[0]}x{self._size[1]}")
        self._writer.write(cv2_from_rgb(frame))
        self.count += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def describe(self) -> str:
        return f"video {self.path} ({self.fourcc}, {self.fps:.3g} fps)"


class ImageSequenceSink(Sink):
    """Numbered image files in a folder: ``frame_000000.png``, ... (the number is the source's
    frame index, so a dropped frame leaves a visible gap)."""

    kind = "images"
    threaded = True

    def __init__(self, folder: str | Path, pattern: str = "frame_{index:06d}.png"):
        self.folder = Path(folder)
        if Path(pattern.format(index=0)).suffix.lower() not in IMAGE_EXTENSIONS:
            raise InputError(f"image pattern {pattern!r} must end with an image extension (.png, .jpg)")
        self.pattern = pattern
        self.folder.mkdir(parents=True, exist_ok=True)
        self.count = 0

    def write(self, frame: np.ndarray, index: int) -> None:
        write_image(self.folder / self.pattern.format(index=index), _check_frame(frame))
        self.count += 1

    def describe(self) -> str:
        return f"images in {self.folder}/"


class ImageFileSink(Sink):
    """One image file: for a single still image (``play setup.npz photo.jpg --out out.png``)."""

    kind = "image"

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.count = 0

    def write(self, frame: np.ndarray, index: int) -> None:
        if self.count:
            raise InputError(f"--out {str(self.path)!r} holds one image but the source has more "
                             "frames: give a folder or a video file instead")
        write_image(self.path, _check_frame(frame))
        self.count += 1

    def describe(self) -> str:
        return f"image {self.path}"


class WindowSink(Sink):
    """The projector window (:class:`rtdefocus.gl.window.ProjectorWindow`): presents frames and
    reports key presses. Closes the window on :meth:`close` only if it opened it."""

    kind = "window"
    realtime = True
    interactive = True

    def __init__(self, window=None, *, screen: int = 0, fullscreen: bool = True,
                 size: tuple[int, int] | None = None, vsync: bool = True,
                 expect_size: tuple[int, int] | None = None):
        from ..gl.window import ProjectorWindow

        self._own = window is None
        self.window = window if window is not None else ProjectorWindow(
            screen, fullscreen=fullscreen, size=size, vsync=vsync)
        self.count = 0
        if expect_size is not None:
            try:
                check_window_size(self.window, expect_size, screen)
            except BaseException:
                self.close()
                raise

    def write(self, frame: np.ndarray, index: int) -> None:
        self.window.show(_check_frame(frame))
        self.count += 1

    def poll(self) -> list[str]:
        return self.window.poll()

    def can_warp(self, calib) -> bool:
        """Whether :meth:`write_warped` can render for ``calib`` (the window is its projector's size)."""
        return self.window is not None and tuple(calib.projector_size) == tuple(self.window.size)

    def write_warped(self, image: np.ndarray, index: int, calib) -> None:
        """Geometry-only display: the warp shader renders ``image`` straight into the window."""
        self.window.show_warped(image, calib)
        self.count += 1

    def close(self) -> None:
        if self._own and self.window is not None:
            self.window.close()
        self.window = None

    def describe(self) -> str:
        w = self.window
        return f"window {w.size[0]}x{w.size[1]}" if w is not None else "window (closed)"


def check_window_size(window, expect_size: tuple[int, int], screen: int = 0) -> tuple[int, int]:
    """Refuse a projector window whose framebuffer is not ``expect_size`` (the calibration's
    projector size), once its size has settled (:meth:`ProjectorWindow.final_size`): a scaled
    frame loses the pixel-exact compensation. Returns the size.

    Raises
    ------
    DeviceError
        Naming both sizes and the fix.
    """
    from ..errors import DeviceError

    size = tuple(window.final_size()) if hasattr(window, "final_size") else tuple(window.size)
    want = tuple(int(v) for v in expect_size)
    if size != want:
        raise DeviceError(
            f"the projector window on screen {screen} is {size[0]}x{size[1]} but the calibration "
            f"is for a {want[0]}x{want[1]} projector: frames would be rescaled and the compensation "
            f"would no longer line up with the projector's pixels. Set that output to "
            f"{want[0]}x{want[1]} at 100 % scaling (display settings, or `xrandr --output NAME "
            f"--mode {want[0]}x{want[1]} --scale 1x1`), check --screen (`rtdefocus info` lists "
            f"the monitors), or calibrate again at {size[0]}x{size[1]}")
    return size


def open_sink(out: str | Path | None, *, fps: float | None = None, screen: int = 0,
              fullscreen: bool = True, window_size: tuple[int, int] | None = None,
              expect_size: tuple[int, int] | None = None) -> Sink:
    """The sink ``--out`` names: none -> the projector window on ``screen``; ``null`` -> discard;
    a video extension (.mp4 .avi .mkv .mov) -> :class:`VideoFileSink`; an image extension -> one
    image (a single-frame source); anything else -> a folder of numbered PNGs.

    ``expect_size``: a full-screen window must end up this size (the calibration's projector
    size), else :class:`DeviceError` (:func:`check_window_size`)."""
    if out is None:
        return WindowSink(screen=screen, fullscreen=fullscreen, size=window_size,
                          expect_size=expect_size if fullscreen else None)
    text = str(out)
    if text.lower() in ("null", "none", "-"):
        return NullSink()
    path = Path(text).expanduser()
    if path.suffix.lower() in VIDEO_EXTENSIONS:
        return VideoFileSink(path, fps=fps or 30.0)
    if path.suffix.lower() in IMAGE_EXTENSIONS:
        return ImageFileSink(path)
    return ImageSequenceSink(path)
