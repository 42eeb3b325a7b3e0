"""Which cameras are connected: name, index and capture backend (``rtdefocus cameras``).

The names come from ``cv2-enumerate-cameras`` (V4L2 on Linux, DirectShow and Media Foundation
on Windows, AVFoundation on macOS), whose indices are the ones ``cv2.VideoCapture(index,
backend)`` opens. Where it lists nothing (an OpenCV build or platform it does not know), the
first few indices are probed with OpenCV instead; those cameras have no name.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from ..errors import CaptureError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CameraEntry:
    """One camera as a capture backend sees it.

    Attributes
    ----------
    index : int
        What ``--camera`` takes (with ``--camera-backend`` set to :attr:`backend`).
    name : str
        The device's name ("" when only probed).
    backend : str
        ``--camera-backend`` name: ``"v4l2"``, ``"dshow"``, ``"msmf"``, ``"avfoundation"``,
        or ``"auto"`` for a probed index.
    path : str
        The device path where the OS has one (``/dev/video0``), else "".
    """

    index: int
    name: str
    backend: str
    path: str = ""

    def describe(self) -> str:
        name = self.name or "(no name: found by probing)"
        path = f"  {self.path}" if self.path and self.path != self.name else ""
        return f"{self.index}: {name}  [--camera-backend {self.backend}]{path}"


def _backend_names() -> dict[int, str]:
    import cv2

    from .camera import CAMERA_BACKENDS

    return {int(getattr(cv2, const)): name for name, const in CAMERA_BACKENDS.items()
            if name != "auto" and hasattr(cv2, const)}


def enumerate_named(enumerate_cameras: Callable | None = None,
                    backends: Iterable[int] | None = None) -> list[CameraEntry]:
    """Cameras with names, per backend rtdefocus can open (``--camera-backend``).

    ``enumerate_cameras(api) -> [info with index, name, path]`` and ``backends`` (the
    ``cv2.CAP_*`` codes to ask) default to ``cv2_enumerate_cameras``'s; tests pass fakes.
    """
    if enumerate_cameras is None or backends is None:
        try:
            import cv2_enumerate_cameras as ce
        except (ImportError, OSError) as exc:   # OSError: a platform library that does not load
            log.info("cv2-enumerate-cameras is not usable (%s): cameras are found by probing", exc)
            return []
        enumerate_cameras = enumerate_cameras or ce.enumerate_cameras
        backends = ce.supported_backends if backends is None else backends
    names = _backend_names()
    out = []
    for api in backends:
        if int(api) not in names:
            continue          # e.g. GStreamer: not a --camera-backend choice
        try:
            infos = list(enumerate_cameras(api))
        except Exception as exc:  # noqa: BLE001 - a platform API failing: list the others
            log.info("listing cameras through %s failed: %s", names[int(api)], exc)
            continue
        for info in infos:
            out.append(CameraEntry(int(info.index), str(info.name or ""), names[int(api)],
                                   str(getattr(info, "path", "") or "")))
    return out


def probe_indices(count: int = 6, capture_factory: Callable | None = None) -> list[CameraEntry]:
    """Cameras found by opening indices ``0 .. count-1`` and reading one frame."""
    quiet = None
    if capture_factory is None:
        import cv2

        capture_factory = cv2.VideoCapture
        # OpenCV logs a warning for every index with no camera behind it.
        quiet = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    out = []
    try:
        for i in range(count):
            cap = capture_factory(i)
            try:
                if cap is not None and cap.isOpened() and cap.read()[0]:
                    out.append(CameraEntry(i, "", "auto"))
            finally:
                if cap is not None:
                    cap.release()
    finally:
        if quiet is not None:
            cv2.utils.logging.setLogLevel(quiet)
    return out


def list_cameras(*, enumerate_cameras: Callable | None = None, backends: Iterable[int] | None = None,
                 probe: Callable[[], list[CameraEntry]] | None = None) -> list[CameraEntry]:
    """Every connected camera: by name where the platform can say, else by probing indices."""
    named = enumerate_named(enumerate_cameras, backends)
    if named:
        return named
    return (probe or probe_indices)()


def find_camera(name: str, backend: str, cameras: list[CameraEntry]) -> CameraEntry | None:
    """The camera called ``name`` (on ``backend`` when several backends list it)."""
    same = [c for c in cameras if c.name == name]
    for c in same:
        if c.backend == backend:
            return c
    return same[0] if same else None


def describe_all(cameras: list[CameraEntry]) -> str:
    """The listing ``rtdefocus cameras`` prints (and errors quote)."""
    if not cameras:
        return "no camera found"
    return "; ".join(c.describe() for c in cameras)


def missing_camera_error(name: str, cameras: list[CameraEntry]) -> CaptureError:
    """The error for a remembered camera that is not connected."""
    return CaptureError(f"the calibrated camera {name!r} is not connected; connected: "
                        f"{describe_all(cameras)}. Plug it in, or pass --camera N (and "
                        "calibrate again for another camera)")
