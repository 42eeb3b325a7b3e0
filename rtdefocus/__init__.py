"""rtdefocus: real-time projector defocus and geometry compensation on surfaces made of flat
planes: two walls at a corner, a pillar, a room's corner with its ceiling.

>>> import rtdefocus as rd
>>> procam = rd.sim.VirtualProCam("cubicle")         # or rd.HardwareProCam(camera=0, screen=1)
>>> calib = rd.calibrate(procam)                     # everything learnt through procam.capture()
>>> comp = rd.Compensator(calib)                     # OpenCL when a device exists, else NumPy
>>> frame = comp.compensate(image)                   # (Hp, Wp, 3) uint8 for the projector
>>> rd.render("setup.npz", "film.mp4", "film_corner.mp4")   # a film for any player (extra: render)
"""

from __future__ import annotations

import importlib

from .errors import (
    CalibrationError,
    CalibrationFileError,
    CaptureError,
    CaptureSetError,
    DeviceError,
    InputError,
    InputTypeError,
    RtDefocusError,
)
from .procam import ProCam

__version__ = "0.1.0"

# Heavy stages load on first use, so `import rtdefocus` stays fast and a missing
# optional device (EGL, OpenCL) never breaks the import.
_LAZY = {
    "sim": ("rtdefocus.sim", None),
    "calibrate": ("rtdefocus.calib", "calibrate"),
    "calibrate_from_captures": ("rtdefocus.calib.captureset", "calibrate_from_captures"),
    "calibrate_from_correspondences": ("rtdefocus.calib.correspondences",
                                       "calibrate_from_correspondences"),
    "calibrate_psf_from_dots": ("rtdefocus.calib.psf.external", "calibrate_psf_from_dots"),
    "Calibration": ("rtdefocus.calib.file", "Calibration"),
    "Compensator": ("rtdefocus.compensate.compensator", "Compensator"),
    "HardwareProCam": ("rtdefocus.hardware.hardware_procam", "HardwareProCam"),
    "render": ("rtdefocus.film", "render"),
}


def __getattr__(name: str):
    if name in _LAZY:
        module, attr = _LAZY[name]
        mod = importlib.import_module(module)
        value = mod if attr is None else getattr(mod, attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rtdefocus' has no attribute {name!r}")


__all__ = [
    "ProCam", "sim", "calibrate", "calibrate_from_captures",
    "calibrate_from_correspondences", "calibrate_psf_from_dots", "Calibration", "Compensator",
    "HardwareProCam", "render",
    "RtDefocusError", "CalibrationError", "CalibrationFileError", "CaptureError",
    "CaptureSetError", "DeviceError", "InputError", "InputTypeError", "__version__",
]
