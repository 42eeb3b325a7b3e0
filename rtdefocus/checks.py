"""Argument checks shared by the public entry points (a leaf: NumPy and :mod:`.errors` only).

Each check returns the argument in its canonical form or raises :class:`~.errors.InputError`
(a ``ValueError``) for a wrong value and :class:`~.errors.InputTypeError` (also a
``TypeError``) for a wrong type, with a message that says what was expected, what was found
and how to fix it.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from .errors import InputError, InputTypeError

__all__ = ["check_size", "check_real", "check_int", "check_choice", "check_coords",
           "check_procam"]


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_size(size, what: str = "size", minimum: int = 1) -> tuple[int, int]:
    """``(width, height)`` in whole pixels, both ``>= minimum``; returned as two ints."""
    if isinstance(size, (str, bytes)) or not hasattr(size, "__len__") or len(size) != 2:
        raise InputTypeError(f"{what} must be a pair (width, height) of whole pixels, e.g. "
                             f"(800, 600); got {_show(size)}")
    out = []
    for v in size:
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise InputTypeError(f"{what} must be (width, height) numbers; got {_show(size)}")
        if not math.isfinite(float(v)) or float(v) != int(v):
            raise InputError(f"{what} must be (width, height) in whole pixels; got {_show(size)}")
        out.append(int(v))
    if min(out) < minimum:
        raise InputError(f"{what} must be (width, height) with both >= {minimum} px; got "
                         f"{_show(size)} (width first, then height)")
    return out[0], out[1]


def check_real(value, what: str, *, lo: float | None = None, hi: float | None = None,
               lo_open: bool = False) -> float:
    """A finite real number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``); returned as float."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputTypeError(f"{what} must be a real number; got {_show(value)} "
                             f"({type(value).__name__})")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{what} must be finite; got {v}")
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise InputError(f"{what} must be {'>' if lo_open else '>='} {lo}; got {v}")
    if hi is not None and v > hi:
        raise InputError(f"{what} must be <= {hi}; got {v}")
    return v


def check_int(value, what: str, *, lo: int | None = None) -> int:
    """A whole number ``>= lo`` (an integral float is accepted); returned as int."""
    v = check_real(value, what)
    if v != int(v):
        raise InputError(f"{what} must be a whole number; got {value!r}")
    if lo is not None and v < lo:
        raise InputError(f"{what} must be >= {lo}; got {int(v)}")
    return int(v)


def check_choice(value, choices, what: str):
    """One of ``choices``; returned unchanged."""
    if not isinstance(value, (str, type(None))) or value not in choices:
        raise InputError(f"{what} must be one of {tuple(choices)}; got {_show(value)}")
    return value


def check_coords(x, y, what: str = "position") -> tuple[np.ndarray, np.ndarray]:
    """Finite real coordinates (scalars or arrays) as float64 arrays."""
    xa, ya = np.asarray(x), np.asarray(y)
    if xa.dtype.kind not in "iuf" or ya.dtype.kind not in "iuf":
        raise InputTypeError(f"{what} (x, y) must be real numbers (projector pixels); got "
                             f"x={_show(x)}, y={_show(y)}")
    xa, ya = xa.astype(np.float64), ya.astype(np.float64)
    if not (np.isfinite(xa).all() and np.isfinite(ya).all()):
        raise InputError(f"{what} (x, y) must be finite projector pixels; got x={_show(x)}, "
                         f"y={_show(y)} (NaN or infinite: check the computation that made it)")
    return xa, ya


def check_procam(procam) -> None:
    """Something that can be calibrated: ``projector_size``, ``camera_size`` (width, height)
    and a callable ``capture(pattern)`` (the :class:`rtdefocus.ProCam` protocol)."""
    name = type(procam).__name__
    missing = [a for a in ("projector_size", "camera_size", "capture") if not hasattr(procam, a)]
    if missing:
        raise InputTypeError(
            f"{name} is not a ProCam: it has no {', '.join(repr(m) for m in missing)}. Pass "
            "rd.sim.VirtualProCam(...), rd.HardwareProCam(...) or an object with "
            "projector_size, camera_size and capture(pattern) (see rtdefocus.ProCam)")
    if not callable(procam.capture):
        raise InputTypeError(f"{name}.capture must be a method capture(pattern) -> frame; got "
                             f"{_show(procam.capture)}")
    check_size(procam.projector_size, f"{name}.projector_size", minimum=16)
    check_size(procam.camera_size, f"{name}.camera_size", minimum=16)
