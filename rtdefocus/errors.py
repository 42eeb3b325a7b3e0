"""Exceptions raised by rtdefocus.

Every message says what was expected, what was found, and how to fix it.
"""

from __future__ import annotations


class RtDefocusError(Exception):
    """Base class of every error rtdefocus raises on purpose."""


class DeviceError(RtDefocusError, RuntimeError):
    """No usable OpenCL or OpenGL device, or a program failed to build on it."""


class ProgramBuildError(DeviceError):
    """An OpenCL program failed to build; carries file, options, device and the driver log."""

    def __init__(self, filename: str, options: list[str], device: str, log: str):
        self.filename, self.options, self.device, self.log = filename, options, device, log
        super().__init__(
            f"OpenCL build of {filename!r} failed on {device} with options {options}.\n"
            f"--- driver build log ---\n{log.strip()}\n--- end of log ---"
        )


class CalibrationError(RtDefocusError, RuntimeError):
    """Calibration could not be completed from what the camera saw."""


class CalibrationFileError(RtDefocusError, ValueError):
    """A calibration file is missing, truncated, foreign, of another version or malformed."""


class CaptureError(RtDefocusError, RuntimeError):
    """The camera or projector failed to deliver a frame."""


class CaptureSetError(RtDefocusError, ValueError):
    """A saved capture set is incomplete, damaged, or does not match the calibration asked of
    it (another pattern than the one saved with a capture)."""


class InputError(RtDefocusError, ValueError):
    """An image, pattern or argument has the wrong shape, type or value."""


class InputTypeError(InputError, TypeError):
    """An argument is of the wrong type (``None`` for a calibration, a string for a size);
    both an :class:`InputError` and a ``TypeError``."""
