"""A calibration's captures kept on disk, and a calibration redone from them.

:class:`CaptureRecorder` wraps a ProCam: every pattern it is asked to show and the frame the
camera returned go to a folder as lossless PNG files (patterns once per distinct pattern,
frames one per capture, 16-bit PNG for 16-bit frames), and :meth:`CaptureRecorder.finish`
writes the JSON index last, atomically, so a folder with an index is a whole set and a folder
without one is not.

:class:`ReplayProCam` is a ProCam made from such a folder: asked for the n-th capture, it
returns the n-th saved frame, after checking that the pattern asked for is the one saved with
it (and that the camera's exposure is the one it was taken with). A calibration run on it makes
the same calls with the same frames as the live one, so it reproduces the live calibration's
arrays bit for bit (:func:`calibrate_from_captures`). Layout of a set::

    DIR/captures.json                      the index (written last)
    DIR/patterns/p_<sha256[:16]>.png       each distinct pattern, RGB
    DIR/frames/f_00000.png ...             each capture, in the order they were taken
"""

from __future__ import annotations

import datetime
import hashlib
import json
import logging
import math
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from ..errors import CaptureSetError, InputError
from ..imageio import cv2_from_rgb

log = logging.getLogger(__name__)

__all__ = ["INDEX_NAME", "CaptureRecorder", "ReplayProCam", "calibrate_from_captures",
           "read_index"]

INDEX_NAME = "captures.json"
_FORMAT, _VERSION = "rtdefocus-captures", 1


def _digest(arr: np.ndarray) -> str:
    """SHA-256 over an array's dtype, shape and bytes (what a saved file must decode to)."""
    h = hashlib.sha256(f"{arr.dtype.str}{arr.shape}".encode())
    h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def _write_png(path: Path, arr: np.ndarray) -> None:
    arr = np.asarray(arr)
    if arr.dtype not in (np.uint8, np.uint16):
        raise InputError(f"a capture set stores uint8 or uint16 frames; got dtype {arr.dtype} "
                         f"for {path.name}")
    img = cv2_from_rgb(arr) if arr.ndim == 3 and arr.shape[2] == 3 else arr
    ok, data = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise CaptureSetError(f"could not encode {path} as PNG (shape {arr.shape}, {arr.dtype})")
    path.write_bytes(data.tobytes())


def _read_png(path: Path) -> np.ndarray:
    data = np.fromfile(str(path), dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise CaptureSetError(f"{path} is not a PNG image OpenCV can decode (damaged or "
                              "truncated): save the captures again")
    if img.ndim == 3 and img.shape[2] == 3:
        img = img[..., ::-1]                   # BGR -> RGB, the one swap imageio also makes
    return np.ascontiguousarray(img)


def _json_safe(value):
    """Options as JSON: numbers, strings, lists and dicts as they are, anything else by repr."""
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="milliseconds")


def _exposure_of(procam) -> float | None:
    """The camera's exposure when the ProCam says it (the simulator's linear gain, a real
    camera's locked exposure in seconds), else None."""
    value = getattr(procam, "exposure", None)
    if value is None:
        controls = getattr(procam, "controls", None)
        value = getattr(controls, "exposure_s", None)
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


class CaptureRecorder:
    """A ProCam that passes every capture to ``procam`` and keeps the pattern and the frame in
    ``directory`` (see the module's docstring for the layout).

    Every other attribute (``setup_record``, ``close``, a camera's controls, the simulator's
    ``set_light``) is the wrapped ProCam's. ``stage`` is a function returning the name of the
    stage taking the capture (the calibration sets it to its :class:`~.capture.Capturer`'s).

    Raises
    ------
    CaptureSetError
        ``directory`` holds files that are not a capture set (nothing is overwritten then).
    """

    def __init__(self, procam, directory: str | os.PathLike):
        self.procam = procam
        self.directory = Path(directory)
        self.projector_size = tuple(procam.projector_size)
        self.camera_size = tuple(procam.camera_size)
        self.stage = lambda: None
        self.records: list[dict] = []
        self._patterns: set[str] = set()
        d = self.directory
        if d.exists():
            if not d.is_dir():
                raise CaptureSetError(f"--save-captures {d}: that is a file, not a folder; name "
                                      "a new or empty folder")
            foreign = [p.name for p in d.iterdir()
                       if p.name not in (INDEX_NAME, "patterns", "frames")]
            if foreign:
                raise CaptureSetError(f"--save-captures {d}: the folder holds other files "
                                      f"({', '.join(sorted(foreign)[:3])}...); name a new or empty "
                                      "folder, or one that holds only a capture set")
            # An older set in the folder: its index goes first, so that until the new index is
            # written the folder never looks like a whole set.
            (d / INDEX_NAME).unlink(missing_ok=True)
        (d / "patterns").mkdir(parents=True, exist_ok=True)
        (d / "frames").mkdir(parents=True, exist_ok=True)

    def __getattr__(self, name):
        if name == "procam":            # not set yet (during unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.procam, name)

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        """Show ``pattern`` through the wrapped ProCam, keep it and the returned frame."""
        pattern = np.ascontiguousarray(pattern)
        exposure = _exposure_of(self.procam)
        when = _now()
        frame = np.asarray(self.procam.capture(pattern))
        pat_digest = _digest(pattern)
        pat_file = f"patterns/p_{pat_digest[:16]}.png"
        if pat_digest not in self._patterns:
            _write_png(self.directory / pat_file, pattern)
            self._patterns.add(pat_digest)
        frame_file = f"frames/f_{len(self.records):05d}.png"
        _write_png(self.directory / frame_file, frame)
        self.records.append({"stage": self.stage(), "pattern": pat_file, "frame": frame_file,
                             "pattern_sha256": pat_digest, "frame_sha256": _digest(frame),
                             "exposure": exposure, "time": when})
        return frame

    def finish(self, options: dict, stages, outcome: str = "calibrated") -> Path:
        """Write the index (atomically: a temporary file renamed into place) and return its
        path; ``outcome`` is "calibrated" or the message of the error the calibration ended
        with (a failed calibration's captures replay to the same failure)."""
        setup = None
        if hasattr(self.procam, "setup_record"):
            try:
                setup = _json_safe(self.procam.setup_record())
            except Exception as exc:  # noqa: BLE001 - the record is a convenience
                log.warning("the set-up record could not be kept with the captures: %s", exc)
        from .. import __version__

        index = {"format": _FORMAT, "version": _VERSION, "rtdefocus": __version__,
                 "created": _now(), "projector_size": list(self.projector_size),
                 "camera_size": list(self.camera_size), "stages": list(stages),
                 "options": _json_safe(options), "outcome": outcome, "setup_record": setup,
                 "exposure_control": callable(getattr(self.procam, "set_exposure", None)),
                 "captures": self.records}
        fd, tmp = tempfile.mkstemp(prefix=".captures.", suffix=".tmp", dir=self.directory)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(index, f, indent=1)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.directory / INDEX_NAME)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        log.info("kept %d captures (%d distinct patterns) in %s", len(self.records),
                 len(self._patterns), self.directory)
        return self.directory / INDEX_NAME


def read_index(directory: str | os.PathLike) -> dict:
    """The index of the capture set in ``directory``, after checking that it is one and that
    every file it names is there.

    Raises
    ------
    CaptureSetError
        No index (not a capture set, or one whose saving did not finish), a damaged or foreign
        index, or files missing (all of them named, up to 10).
    """
    d = Path(directory)
    path = d / INDEX_NAME
    if not path.is_file():
        what = ("holds pattern and frame files but no index: the saving did not finish, so the "
                "set is incomplete" if (d / "frames").is_dir() else "is not a capture set")
        raise CaptureSetError(f"{d} {what} (no {INDEX_NAME}); calibrate again with "
                              "--save-captures to make one")
    try:
        index = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CaptureSetError(f"{path} is damaged ({exc}); save the captures again") from None
    if not isinstance(index, dict) or index.get("format") != _FORMAT:
        raise CaptureSetError(f"{path} is not an rtdefocus capture index (format "
                              f"{index.get('format') if isinstance(index, dict) else None!r})")
    if index.get("version") != _VERSION:
        raise CaptureSetError(f"{path} is a capture set of version {index.get('version')!r}; "
                              f"this rtdefocus reads version {_VERSION}")
    try:
        records = list(index["captures"])
        for key in ("projector_size", "camera_size", "stages", "options"):
            index[key]
        names = sorted({r[k] for r in records for k in ("pattern", "frame")})
    except (KeyError, TypeError) as exc:
        raise CaptureSetError(f"{path} is damaged: an entry lacks {exc}; save the captures "
                              "again") from None
    missing = [n for n in names if not (d / n).is_file()]
    if missing:
        shown = ", ".join(missing[:10]) + (f" and {len(missing) - 10} more" if len(missing) > 10
                                           else "")
        raise CaptureSetError(f"the capture set {d} is incomplete: {len(missing)} of its "
                              f"{len(names)} files are missing ({shown}); copy the whole folder "
                              "again or save the captures again")
    return index


class ReplayProCam:
    """A ProCam that serves a saved capture set (:class:`CaptureRecorder`) in its order.

    ``capture(pattern)`` returns the next saved frame when ``pattern`` is the one saved with it
    and, where the set records the camera's exposure, ``exposure`` is the one it was taken
    with. ``exposure`` starts at the first capture's; a set whose camera's exposure was
    controlled has ``set_exposure`` too (a calibration turns a clipping camera down).

    Raises
    ------
    CaptureSetError
        On construction, what :func:`read_index` refuses; on ``capture``, a pattern or
        exposure other than the saved one (which capture, of which stage, and what differs),
        a capture past the end of the set, or a file that does not decode to what was saved.
    """

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        self.index = read_index(self.directory)
        self.projector_size = tuple(int(v) for v in self.index["projector_size"])
        self.camera_size = tuple(int(v) for v in self.index["camera_size"])
        self.records = self.index["captures"]
        self.position = 0
        first = self.records[0].get("exposure") if self.records else None
        self.exposure = first
        self._patterns: dict[str, np.ndarray] = {}
        if self.index.get("setup_record"):
            # The live set-up's monitor and camera, so the calibration remembers them as the
            # live one did (a set-up without a record gets none).
            self.setup_record = lambda: dict(self.index["setup_record"])
        if self.index.get("exposure_control"):
            self.set_exposure = self._set_exposure

    def _set_exposure(self, value: float) -> None:
        """The exposure control of a set whose camera had one: the camera took the exposure
        the next capture records (a real camera rounds what it is asked)."""
        nxt = self.records[self.position].get("exposure") if self.position < len(self.records) \
            else None
        self.exposure = float(value) if nxt is None else nxt

    def _load(self, rec: dict, key: str) -> np.ndarray:
        path = self.directory / rec[key]
        if key == "pattern" and rec[key] in self._patterns:
            return self._patterns[rec[key]]
        arr = _read_png(path)
        if _digest(arr) != rec[f"{key}_sha256"]:
            raise CaptureSetError(f"{path} is damaged: it does not decode to the image saved "
                                  f"({arr.shape} {arr.dtype}); save the captures again")
        if key == "pattern":
            self._patterns[rec[key]] = arr
        return arr

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        """The next saved frame, when ``pattern`` is the pattern saved with it."""
        n = self.position
        if n >= len(self.records):
            raise CaptureSetError(
                f"the calibration asks for capture {n + 1}, but the set {self.directory} holds "
                f"{len(self.records)}: it was made with other options or stages (saved: "
                f"stages {self.index['stages']}, options {self.index['options']})")
        rec = self.records[n]
        saved = self._load(rec, "pattern")
        pattern = np.asarray(pattern)
        if pattern.shape != saved.shape or pattern.dtype != saved.dtype:
            diff = f"shape {pattern.shape} {pattern.dtype} asked, {saved.shape} {saved.dtype} saved"
        elif not np.array_equal(pattern, saved):
            bad = np.argwhere(pattern != saved)
            y, x, c = (int(v) for v in bad[0])
            diff = (f"{len(bad)} values differ, the first at projector pixel (x={x}, y={y}) "
                    f"channel {'RGB'[c]}: {int(pattern[y, x, c])} asked, {int(saved[y, x, c])} saved")
        else:
            diff = None
        if diff is not None:
            raise CaptureSetError(
                f"capture {n + 1} of {len(self.records)} (stage {rec.get('stage')!r}, "
                f"{rec['frame']}) was taken of another pattern ({rec['pattern']}): {diff}. Replay "
                f"with the options the set was saved with (stages {self.index['stages']}, "
                f"options {self.index['options']}) and the same rtdefocus version "
                f"({self.index.get('rtdefocus')})")
        want = rec.get("exposure")
        if want is not None and self.exposure is not None and float(self.exposure) != float(want):
            raise CaptureSetError(
                f"capture {n + 1} (stage {rec.get('stage')!r}, {rec['frame']}) was taken at "
                f"exposure {want}, but the calibration asks for it at {self.exposure}: replay "
                "with the options the set was saved with")
        frame = self._load(rec, "frame")
        self.position += 1
        return frame


def calibrate_from_captures(directory: str | os.PathLike, *, progress=None, **options):
    """Redo the calibration saved in ``directory`` (``rd.calibrate(..., save_captures=DIR)``,
    ``rtdefocus calibrate ... --save-captures DIR``) from its captures, with no camera or
    projector.

    Parameters
    ----------
    directory : a capture set's folder.
    progress : as for :func:`~rtdefocus.calibrate`.
    **options
        Calibration options; by default the saved ones (``stages`` included). An option that
        changes the patterns the calibration asks for makes the replay stop at the first
        pattern that differs, with a :class:`~rtdefocus.errors.CaptureSetError`.

    Returns
    -------
    Calibration
        With the same arrays as the live calibration that saved the set;
        ``meta["from_captures"]`` names the folder.

    Raises
    ------
    CaptureSetError
        The set is incomplete or damaged (the missing or damaged files are named), or was made
        with other options.
    """
    from . import calibrate

    replay = ReplayProCam(directory)
    saved = dict(replay.index["options"])
    stages = tuple(options.pop("stages", replay.index["stages"]))
    saved.update(options)
    calib = calibrate(replay, stages=stages, progress=progress, **saved)
    if replay.position != len(replay.records):
        log.warning("the calibration used %d of the %d saved captures", replay.position,
                    len(replay.records))
    calib.meta["from_captures"] = str(directory)
    return calib
