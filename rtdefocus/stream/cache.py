"""On-disk cache of compensated slides, so the second show of a deck is instant.

A compensated slide depends on the calibration, on the slide's pixels and on the compensation
settings, so its key hashes exactly those: :func:`calibration_fingerprint` (every array of the
calibration, its sizes and its meta data), the slide's bytes and shape, and the settings
(method, iterations, rtdefocus version). Change any of them and the old entry is simply not
found; nothing is ever served stale. Entries are lossless PNGs written atomically.

Location: ``--cache DIR``, else ``$RTDEFOCUS_CACHE``, else the platform's user cache folder
(``platformdirs``: ``$XDG_CACHE_HOME/rtdefocus`` or ``~/.cache/rtdefocus`` on Linux,
``~/Library/Caches/rtdefocus`` on macOS, ``%LOCALAPPDATA%\\rtdefocus\\Cache`` on Windows);
slides go to ``<root>/slides/<calibration fingerprint>/``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path

import numpy as np

from ..imageio import read_image, write_image

log = logging.getLogger(__name__)

# Meta entries that describe where a calibration came from rather than what it is.
_VOLATILE_META = frozenset({"loaded_from"})


def default_cache_dir() -> Path:
    """``$RTDEFOCUS_CACHE``, else the platform's user cache folder for rtdefocus (module docstring)."""
    if os.environ.get("RTDEFOCUS_CACHE"):
        return Path(os.environ["RTDEFOCUS_CACHE"]).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("rtdefocus", appauthor=False))


def _update_array(h, name: str, arr) -> None:
    arr = np.ascontiguousarray(arr)
    h.update(f"{name}:{arr.dtype.str}:{arr.shape}".encode())
    h.update(arr.tobytes())


def calibration_fingerprint(calib) -> str:
    """SHA-256 (hex) of a calibration's sizes, arrays and meta data (not where it was loaded from).

    Two calibrations with the same content have the same fingerprint whether in memory or
    reloaded from a file; any change to any array or option changes it.
    """
    from ..calib.file import SECTIONS

    h = hashlib.sha256()
    h.update(f"proj{tuple(calib.projector_size)}cam{tuple(calib.camera_size)}".encode())
    for names in SECTIONS.values():
        for name in names:
            value = getattr(calib, name, None)
            if value is not None:
                _update_array(h, name, value)
    meta = {k: v for k, v in (calib.meta or {}).items() if k not in _VOLATILE_META}
    h.update(json.dumps(meta, sort_keys=True, default=str).encode())
    return h.hexdigest()


class SlideCache:
    """Compensated slides on disk, keyed by calibration, slide content and settings.

    Parameters
    ----------
    calib_key : str
        :func:`calibration_fingerprint` of the calibration in use.
    settings : dict
        JSON-serialisable compensation settings that change the result (method, iterations...).
    root : path, optional
        Cache root (default :func:`default_cache_dir`).
    """

    def __init__(self, calib_key: str, settings: dict, root: str | os.PathLike | None = None):
        self.root = Path(root).expanduser() if root is not None else default_cache_dir()
        self.folder = self.root / "slides" / calib_key[:32]
        self._settings = json.dumps(settings, sort_keys=True, default=str)
        self._calib_key = calib_key
        self.hits = 0
        self.misses = 0

    def key(self, image: np.ndarray) -> str:
        """Hex key of ``image`` (RGB uint8) under this cache's calibration and settings."""
        h = hashlib.sha256()
        h.update(self._calib_key.encode())
        h.update(self._settings.encode())
        _update_array(h, "slide", image)
        return h.hexdigest()

    def path(self, image: np.ndarray) -> Path:
        return self.folder / f"{self.key(image)}.png"

    def get(self, image: np.ndarray) -> np.ndarray | None:
        """The cached compensated slide, or None. A damaged entry is removed and reported."""
        path = self.path(image)
        if not path.is_file():
            self.misses += 1
            return None
        try:
            out = read_image(path)
        except Exception as exc:  # a truncated or foreign file: recompute rather than fail the show
            log.warning("slide cache entry %s unreadable (%s); recomputing", path, exc)
            path.unlink(missing_ok=True)
            self.misses += 1
            return None
        self.hits += 1
        return out

    def put(self, image: np.ndarray, result: np.ndarray) -> Path:
        """Store the compensated ``result`` ((Hp, Wp, 3) uint8) for ``image``; atomic."""
        path = self.path(image)
        write_image(path, result, atomic=True)
        return path
