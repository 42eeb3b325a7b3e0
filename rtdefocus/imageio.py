"""Image files and OpenCV frames, RGB at the edges.

OpenCV reads, writes, decodes and captures BGR; rtdefocus works in RGB everywhere (DESIGN.md
§2). :func:`rgb_from_cv2` and :func:`cv2_from_rgb` are the one place the channel order is
swapped: image files, video files, cameras and video writers all go through them.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from .errors import InputError, RtDefocusError

#: File extensions read as still images (everything else that exists is tried as a video).
IMAGE_EXTENSIONS = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp",
                              ".ppm", ".pgm", ".pnm"})


def rgb_from_cv2(frame: np.ndarray) -> np.ndarray:
    """An OpenCV frame (BGR (H, W, 3), BGRA (H, W, 4) or grey (H, W)) as RGB uint8 (H, W, 3)."""
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise InputError(f"expected an 8-bit frame from OpenCV, got dtype {frame.dtype}; "
                         "16-bit cameras and images are not supported — convert to 8 bits")
    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
    if frame.ndim == 3 and frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2RGB)
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    raise InputError(f"expected an OpenCV image (H, W), (H, W, 3) or (H, W, 4); got {frame.shape}")


def cv2_from_rgb(rgb: np.ndarray) -> np.ndarray:
    """An RGB uint8 (H, W, 3) image (or grey (H, W)) as the BGR array OpenCV writes."""
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        return rgb
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise InputError(f"expected an RGB image (H, W, 3); got shape {rgb.shape}")
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as RGB uint8 (H, W, 3).

    Raises
    ------
    RtDefocusError
        When the file is missing or not an image OpenCV can decode.
    """
    # cv2.imread takes a narrow-character path, which fails on Windows for names outside the
    # ANSI code page; reading the bytes in Python and decoding them works for any name.
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError:
        data = None
    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data is not None and data.size else None
    if img is None:
        raise RtDefocusError(f"cannot read image {str(path)!r}: missing file or unknown format "
                             "(PNG, JPEG, BMP, TIFF are supported)")
    return rgb_from_cv2(img)


def write_image(path: str | os.PathLike, rgb: np.ndarray, *, atomic: bool = False) -> Path:
    """Write an RGB uint8 image (creating parent folders); the format follows the extension.

    With ``atomic=True`` the image is written to a temporary file in the same folder and
    renamed into place, so a reader never sees half a file (the slide cache relies on it).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arr = cv2_from_rgb(np.asarray(rgb))
    target = path
    if atomic:
        fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp" + path.suffix,
                                   dir=path.parent)
        os.close(fd)
        target = Path(tmp)
    try:
        # Encoded in memory and written by Python (not cv2.imwrite): any file name works on
        # every OS, as in read_image.
        try:
            ok, buf = cv2.imencode(path.suffix or ".png", arr)
        except cv2.error:
            ok = False
        if not ok:
            raise RtDefocusError(f"cannot write {str(path)!r}: unknown image extension "
                                 f"{path.suffix!r} (use .png, .jpg, .bmp or .tif)")
        try:
            buf.tofile(str(target))
        except OSError as exc:
            raise RtDefocusError(f"cannot write {str(path)!r} ({exc.strerror}): check the folder "
                                 "and its permissions") from exc
        if atomic:
            os.replace(target, path)
    finally:
        if atomic and target.exists():
            target.unlink()
    return path


def fit_image(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Letterbox ``image`` into a black ``size = (width, height)`` frame, aspect kept, centred.

    This is what a plain projector shows (no geometry, no compensation): the ``off`` side of
    the player's A/B comparison. Returns a new (height, width, 3) uint8 array.
    """
    w, h = size
    ih, iw = image.shape[:2]
    scale = min(w / iw, h / ih)
    nw, nh = max(1, round(iw * scale)), max(1, round(ih * scale))
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    resized = cv2.resize(image, (nw, nh), interpolation=interp) if (nw, nh) != (iw, ih) else image
    out = np.zeros((h, w, 3), np.uint8)
    x0, y0 = (w - nw) // 2, (h - nh) // 2
    out[y0:y0 + nh, x0:x0 + nw] = resized
    return out


def to_grey(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) camera frame -> (H, W) float32 mean of the channels (code values 0..255)."""
    frame = np.asarray(frame)
    if frame.ndim == 3:
        if frame.dtype == np.uint8:     # exact integer sum, then one float scale (fast)
            return frame.sum(axis=2, dtype=np.uint16).astype(np.float32) * np.float32(1.0 / 3.0)
        return frame.astype(np.float32).mean(axis=2, dtype=np.float32)
    return frame.astype(np.float32)
