"""What a calibration remembers of its hardware, and finding that hardware again.

A calibration of a real set-up stores, in ``meta["hardware"]``:

``monitor``  ``name``, ``size`` and ``refresh`` of its video mode, ``position`` on the
             desktop, and the ``index`` it had;
``camera``   ``name`` (where the platform says), ``index``, ``backend`` (``--camera-backend``),
             the ``size``, ``fourcc`` and ``fps`` it delivered, ``lock`` and the locked
             ``exposure_s`` and control values, and the projector-to-camera ``latency_s``
             measured at start-up (a watcher takes the show's pictures by it).

``play``, ``check`` and ``aim`` take the monitor and camera from there when no option names
them; a monitor that is missing or is not the calibrated one is an error listing the
connected ones. Calibrations without the record (simulated ones, older files) remember
nothing and the options keep their defaults.
"""

from __future__ import annotations

import logging
import shlex

from ..errors import InputError
from .cameras import CameraEntry, find_camera, missing_camera_error

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- records
def monitor_record(monitor: dict) -> dict:
    """The part of :func:`rtdefocus.gl.window.monitor_info`'s entry a calibration keeps."""
    return {"name": str(monitor["name"]), "index": int(monitor["index"]),
            "size": [int(v) for v in monitor["size"]], "refresh": int(monitor["refresh"]),
            "position": [int(v) for v in monitor["position"]]}


def camera_record(camera, *, source, backend: str = "auto", name: str = "",
                  controls=None) -> dict:
    """A camera's record from an open :class:`~rtdefocus.hardware.Camera` (its negotiated mode)
    and the :class:`~rtdefocus.hardware.ControlReport` of a ``lock``."""
    n = camera.negotiated or {}
    rec = {"name": name, "index": source if isinstance(source, int) else str(source),
           "backend": backend, "size": list(camera.size) if camera.size else None,
           "fourcc": n.get("fourcc"), "fps": n.get("fps"), "lock": controls is not None}
    if controls is not None:
        rec["exposure_s"] = controls.exposure_s
        rec["controls"] = {str(k): v for k, v in (controls.applied or {}).items()}
    return rec


def hardware_record(procam, *, monitors: list[dict] | None = None,
                    cameras: list[CameraEntry] | None = None) -> dict:
    """``{"monitor": ..., "camera": ...}`` for an open :class:`rtdefocus.HardwareProCam`.

    ``monitors`` default to the connected ones, ``cameras`` to those listed by name (no
    probing: the camera is open). A monitor missing from the list is recorded from the
    window (name and size) so that it is still found by name.
    """
    if monitors is None:
        monitors = connected_monitors() or []
    screen = procam.screen
    match = [m for m in monitors if m["index"] == screen]
    win = procam.window
    if match:
        monitor = monitor_record(match[0])
    else:
        size = list(getattr(win, "size", procam.projector_size))
        monitor = {"name": getattr(win, "monitor_name", None) or "", "index": int(screen),
                   "size": [int(v) for v in size],
                   "refresh": int(round(getattr(win, "refresh_rate", 60.0) or 60.0)),
                   "position": None}
    backend = getattr(procam, "camera_backend", "auto") or "auto"
    name = ""
    if isinstance(procam.camera, int):
        if cameras is None:
            from .cameras import enumerate_named

            cameras = enumerate_named()
        same = [c for c in cameras if c.index == procam.camera
                and (backend == "auto" or c.backend == backend)]
        name = same[0].name if same else ""
    camera = camera_record(procam.cam, source=procam.camera, backend=backend, name=name,
                           controls=procam.controls)
    latency = getattr(procam, "latency_s", None)
    camera["latency_s"] = None if latency is None else round(float(latency), 4)
    return {"monitor": monitor, "camera": camera}


def remembered(calib) -> dict:
    """``{"monitor": ..., "camera": ...}`` a calibration recorded (empty dict for none)."""
    rec = calib.meta.get("hardware") if calib is not None else None
    return rec if isinstance(rec, dict) else {}


def remembered_latency(calib) -> float | None:
    """The projector-to-camera latency (s) the calibration measured, or None (a simulated or
    older calibration, or a camera file): ``HardwareProCam(..., latency=...)`` takes it."""
    value = (remembered(calib).get("camera") or {}).get("latency_s")
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        log.warning("the calibration's camera latency %r is not a number; measuring it again",
                    value)
        return None


# --------------------------------------------------------------------------- monitors
def describe_monitors(monitors: list[dict]) -> str:
    if not monitors:
        return "none"
    return "; ".join(f"{m['index']}: {m['name']} {m['size'][0]}x{m['size'][1]} at "
                     f"{m['position'][0]},{m['position'][1]}" for m in monitors)


def _same_monitor(rec: dict, m: dict) -> bool:
    return m["name"] == rec.get("name")


def resolve_screen(screen: int | None, monitors: list[dict], record: dict | None = None) -> int:
    """The monitor index to open: ``screen`` when given, else the remembered monitor, else 0.

    Parameters
    ----------
    screen : int or None
        ``--screen``; None when the option was not given.
    monitors : list of dict
        The connected monitors (:func:`rtdefocus.gl.window.monitor_info`).
    record : dict, optional
        The calibration's ``monitor`` record.

    Raises
    ------
    InputError
        The remembered monitor is not connected, or ``screen`` is a different monitor from the
        calibrated one; the message lists the connected monitors.
    """
    listing = describe_monitors(monitors)
    if record:
        pos = record.get("position")
        want = (f"{record.get('name')!r} ({record['size'][0]}x{record['size'][1]}"
                + (f" at {pos[0]},{pos[1]})" if pos else ")"))
        if screen is None:
            found = [m for m in monitors if _same_monitor(record, m)]
            if not found:
                raise InputError(f"the calibrated monitor {want} is not connected; monitors: "
                                 f"{listing}. Connect the projector as an extended display, or "
                                 "pass --screen N and calibrate again")
            # Two monitors of one model: the one at the remembered position.
            found.sort(key=lambda m: (list(m["position"]) != list(pos or []),
                                      m["index"] != record.get("index")))
            if found[0]["index"] != record.get("index"):
                log.info("the calibrated monitor %s is now screen %d", want, found[0]["index"])
            return int(found[0]["index"])
        match = [m for m in monitors if m["index"] == screen]
        if match and not _same_monitor(record, match[0]):
            raise InputError(f"--screen {screen} is {match[0]['name']!r}, not the calibrated "
                             f"monitor {want}; monitors: {listing}. Leave out --screen to use "
                             "the calibrated one, or calibrate again on this monitor")
    if screen is None:
        return 0
    if monitors and not any(m["index"] == screen for m in monitors):
        raise InputError(f"screen {screen} is not connected; monitors: {listing}. Pick the "
                         "projector's index with --screen")
    return int(screen)


def default_screen(monitors: list[dict]) -> int:
    """The projector's likely index with no option and nothing remembered: the second of
    exactly two monitors (a laptop and its projector), else 0."""
    return 1 if len(monitors) == 2 else 0


def connected_monitors() -> list[dict] | None:
    """:func:`rtdefocus.gl.window.monitor_info`, or None where there is no display to ask."""
    from ..errors import DeviceError

    try:
        from ..gl.window import monitor_info

        return monitor_info()
    except (DeviceError, ImportError, OSError) as exc:
        log.info("no monitor list (%s): the window reports what it finds", exc)
        return None


# --------------------------------------------------------------------------- cameras
def resolve_camera(camera, record: dict | None, cameras: list[CameraEntry] | None):
    """``(camera, backend)`` to open: ``camera`` (``--camera``) when given, else the remembered
    one, found again by name when its index changed (a camera plugged into another port).

    Raises
    ------
    InputError
        No ``--camera`` and nothing remembered.
    CaptureError
        The remembered camera has a name and is not among the connected ``cameras``.
    """
    record = record or {}
    if camera is not None:
        return camera, None
    if not record or record.get("index") is None:
        raise InputError("which camera? pass --camera N (`rtdefocus cameras` lists them) or a "
                         "calibration file that remembers it")
    index, backend, name = record["index"], record.get("backend") or "auto", record.get("name")
    if name and cameras:
        found = find_camera(name, backend, cameras)
        if found is None:
            raise missing_camera_error(name, cameras)
        if found.index != index:
            log.info("the calibrated camera %r is now index %d (%s)", name, found.index,
                     found.backend)
        return found.index, found.backend
    if name and cameras is not None and not cameras:
        raise missing_camera_error(name, cameras)
    return index, backend


def camera_options(record: dict | None) -> dict:
    """The remembered camera mode as option values: ``camera_size``, ``fourcc``, ``lock``,
    ``exposure`` (milliseconds, as ``--exposure`` takes it)."""
    record = record or {}
    size = record.get("size")
    out = {"camera_size": tuple(size) if size else None, "fourcc": record.get("fourcc"),
           "lock": bool(record.get("lock")), "exposure": None}
    if record.get("lock") and record.get("exposure_s"):
        out["exposure"] = round(float(record["exposure_s"]) * 1e3, 3)
    return out


# --------------------------------------------------------------------------- command line
def calibrate_command(*, camera, screen: int, camera_size=None, fourcc=None, lock=False,
                      exposure_ms=None, camera_backend=None, output: str = "setup.npz") -> str:
    """The complete ``rtdefocus calibrate`` command for these settings (what ``check`` prints),
    so that copying it calibrates in the mode that was checked."""
    parts = ["rtdefocus", "calibrate", "--camera", str(camera), "--screen", str(screen)]
    if camera_backend and camera_backend != "auto":
        parts += ["--camera-backend", camera_backend]
    if camera_size:
        parts += ["--camera-size", f"{camera_size[0]}x{camera_size[1]}"]
    if fourcc:
        parts += ["--fourcc", fourcc]
    if lock:
        parts.append("--lock")
        if exposure_ms:
            parts += ["--exposure", f"{exposure_ms:g}"]
    parts += ["-o", output]
    return " ".join(shlex.quote(p) for p in parts)

