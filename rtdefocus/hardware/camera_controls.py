"""Camera controls locked for calibration: exposure, white balance, focus, sharpening.

Automatic exposure, white balance and focus change the picture from one pattern to the next
and ruin the radiometric calibration; sharpening and backlight compensation add halos that
look like blur the compensation would then try to undo. :func:`lock_controls` turns them off
and fixes the values, then reads every one back: drivers often accept a value and ignore it,
and a property the backend does not know reads back 0 or -1.

OpenCV passes the values through to the driver, so their meaning depends on the backend:

========  ======================  ===================================  =====================
backend   auto-exposure off / on  exposure unit                        notes
========  ======================  ===================================  =====================
V4L2      1 / 3 (menu index)      100 µs (``exposure_time_absolute``)  Linux webcams
DSHOW     0.25 / 0.75             log2(seconds): -5 = 1/32 s           Windows, DirectShow
MSMF      0.25 / 0.75             log2(seconds)                        Windows, Media Found.
========  ======================  ===================================  =====================

Other backends (AVFoundation on macOS, FFmpeg/GStreamer streams) cannot set controls through
OpenCV; the report says so and the fix is the camera's own tool (docs/hardware.md).

The exposure is a whole number of projector frame periods: DLP projectors draw each frame as a
sequence of colour and bit-plane flashes, and an exposure that is not a multiple of the frame
period catches a varying part of that sequence (banding, colour flicker between captures).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

from ..errors import CaptureError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BackendControls:
    """How one capture backend spells the controls."""

    auto_exposure_off: float
    auto_exposure_on: float
    exposure_unit: str          # "100us" or "log2s"


BACKENDS: dict[str, BackendControls] = {
    "V4L2": BackendControls(auto_exposure_off=1, auto_exposure_on=3, exposure_unit="100us"),
    "DSHOW": BackendControls(auto_exposure_off=0.25, auto_exposure_on=0.75, exposure_unit="log2s"),
    "MSMF": BackendControls(auto_exposure_off=0.25, auto_exposure_on=0.75, exposure_unit="log2s"),
}


def exposure_to_property(seconds: float, unit: str) -> float:
    """Seconds -> the value of ``CAP_PROP_EXPOSURE`` for a backend's unit."""
    if unit == "100us":
        return float(round(seconds * 1e4))
    return float(round(math.log2(seconds)))


def exposure_from_property(value: float, unit: str) -> float | None:
    """``CAP_PROP_EXPOSURE`` -> seconds (None when the value cannot be an exposure)."""
    if unit == "100us":
        return value * 1e-4 if value > 0 else None
    return 2.0 ** value if -20 < value < 5 else None


def exposure_for_period(seconds: float, frame_period: float, unit: str) -> float:
    """The exposure (seconds) nearest ``seconds`` that is a whole number (>= 1) of projector
    frame periods and that the backend's unit can express (log2 units: the nearest power of two
    to such a multiple)."""
    n = max(1, round(seconds / frame_period))
    wanted = n * frame_period
    if unit == "log2s":
        return 2.0 ** round(math.log2(wanted))
    return wanted


@dataclass
class ControlReport:
    """What :func:`lock_controls` asked for and what the camera reads back.

    Attributes
    ----------
    backend : str
    applied : dict name -> value read back, for the controls that took.
    failed : dict name -> reason, for those that did not (refused, ignored, unsupported).
    exposure_s : float or None
        The locked exposure in seconds (None when it could not be set).
    """

    backend: str
    applied: dict = field(default_factory=dict)
    failed: dict = field(default_factory=dict)
    exposure_s: float | None = None
    wanted: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.failed

    def summary(self) -> str:
        parts = [f"camera controls ({self.backend}):"]
        if self.applied:
            parts.append("locked " + ", ".join(f"{k}={_fmt(v)}" for k, v in self.applied.items()))
        if self.exposure_s:
            parts.append(f"exposure {self.exposure_s * 1e3:.1f} ms")
        if self.failed:
            parts.append("NOT set: " + "; ".join(f"{k} ({v})" for k, v in self.failed.items())
                         + " — set these in the camera's own tool (v4l2-ctl, the vendor app) and "
                         "close it before calibrating")
        return " ".join(parts)


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _props():
    import cv2

    return {
        "auto_exposure": cv2.CAP_PROP_AUTO_EXPOSURE, "exposure": cv2.CAP_PROP_EXPOSURE,
        "auto_white_balance": cv2.CAP_PROP_AUTO_WB, "white_balance": cv2.CAP_PROP_WB_TEMPERATURE,
        "autofocus": cv2.CAP_PROP_AUTOFOCUS, "focus": cv2.CAP_PROP_FOCUS,
        "sharpness": cv2.CAP_PROP_SHARPNESS, "backlight": cv2.CAP_PROP_BACKLIGHT,
    }


def lock_controls(cap, backend: str, *, frame_period: float = 1 / 60, exposure: float | None = None,
                  white_balance: float | None = None, focus: float | None = None) -> ControlReport:
    """Turn off auto-exposure, auto white balance, autofocus, sharpening and backlight
    compensation; fix exposure, white balance and focus; read everything back.

    Parameters
    ----------
    cap : cv2.VideoCapture (or a fake with ``set``/``get``)
    backend : its ``getBackendName()``, upper case.
    frame_period : the projector's frame period in seconds (1 / refresh rate).
    exposure : seconds; default the camera's current (automatic) exposure, rounded to a whole
        number of frame periods.
    white_balance : kelvin; default the current value (frozen where auto left it).
    focus : driver units; default the current value.

    Returns
    -------
    ControlReport
    """
    report = ControlReport(backend=backend)
    spec = BACKENDS.get(backend)
    if spec is None:
        for name in ("auto_exposure", "exposure", "white_balance", "focus", "sharpness"):
            report.failed[name] = f"the {backend} backend cannot set camera controls"
        log.warning(report.summary())
        return report
    props = _props()
    current = {name: cap.get(prop) for name, prop in props.items()}
    if exposure is None:
        exposure = exposure_from_property(current["exposure"], spec.exposure_unit) or 4 * frame_period
    exposure = exposure_for_period(exposure, frame_period, spec.exposure_unit)
    wanted = {
        "auto_exposure": spec.auto_exposure_off,
        "exposure": exposure_to_property(exposure, spec.exposure_unit),
        "auto_white_balance": 0.0,
        "white_balance": white_balance if white_balance is not None else current["white_balance"],
        "autofocus": 0.0,
        "focus": focus if focus is not None else current["focus"],
        "sharpness": 0.0,
        "backlight": 0.0,
    }
    report.wanted = wanted
    apply_controls(cap, wanted, report)
    if "exposure" in report.applied:
        report.exposure_s = exposure
    (log.info if report.ok else log.warning)(report.summary())
    return report


def set_exposure(cap, report: ControlReport, seconds: float, frame_period: float = 1 / 60) -> float:
    """Change a locked exposure (``report`` from :func:`lock_controls`) to the whole number of
    projector frame periods nearest ``seconds`` (at least one); returns the exposure set, in
    seconds (``report`` and its ``wanted`` follow, so a stream restart re-applies it).

    Raises
    ------
    CaptureError
        The exposure is not locked (it did not take when locked), or the camera refused it.
    """
    spec = BACKENDS.get(report.backend)
    if spec is None or report.exposure_s is None:
        raise CaptureError("the camera's exposure is not locked, so it cannot be changed: "
                           f"{report.summary()}")
    seconds = exposure_for_period(float(seconds), frame_period, spec.exposure_unit)
    value = exposure_to_property(seconds, spec.exposure_unit)
    cap.set(_props()["exposure"], float(value))
    got = float(cap.get(_props()["exposure"]))
    if abs(got - value) > 1e-3 * max(1.0, abs(value)):
        raise CaptureError(f"the camera refused exposure {seconds * 1e3:.1f} ms (reads back "
                           f"{_fmt(got)}, not {_fmt(value)}); set it with the camera's own tool")
    report.wanted["exposure"] = value
    report.applied["exposure"] = got
    report.exposure_s = seconds
    return seconds


def apply_controls(cap, wanted: dict, report: ControlReport | None = None) -> ControlReport:
    """Set each control in ``wanted`` (auto switches first) and read it back into ``report``."""
    props = _props()
    report = report or ControlReport(backend="?")
    report.applied.clear()
    report.failed.clear()
    for name, value in wanted.items():       # dict order: each auto switch before its value
        if value is None or (name in ("white_balance", "focus") and value <= 0):
            report.failed[name] = "the camera does not report it"
            continue
        accepted = bool(cap.set(props[name], float(value)))
        got = cap.get(props[name])
        if abs(float(got) - float(value)) <= 1e-3 * max(1.0, abs(float(value))):
            report.applied[name] = float(got)
        elif not accepted:
            report.failed[name] = "refused by the driver"
        else:
            report.failed[name] = f"accepted but reads back {_fmt(float(got))}, not {_fmt(float(value))}"
    return report


def check_controls(cap, report: ControlReport) -> list[str]:
    """Names of the locked controls whose value changed since :func:`lock_controls` (a stream
    restart or another program resets them)."""
    props = _props()
    return [name for name, value in report.applied.items()
            if abs(float(cap.get(props[name])) - value) > 1e-3 * max(1.0, abs(value))]
