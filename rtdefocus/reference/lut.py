"""Response LUTs of the projector: decode uint8 codes to linear light, encode linear light back.

The decoder looks codes up in the measured response (3, 256); the encoder inverts a strictly
increasing copy of it (:func:`increasing_lut`) through two small tables
(:func:`inverse_lut_tables`), the same steps the device kernel ``encode_lut`` (``solver.cl``)
takes. The headroom maps a target from [0, 1] into ``[lo, hi]`` (:func:`apply_headroom`).
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)

__all__ = [
    "ENC_STEPS", "ENC_T", "apply_headroom", "decode_lut", "encode_lut", "headroom_params",
    "increasing_lut", "inverse_lut_tables",
]

ENC_T = 16384      # bins of the encoder's start table over P in [0, 1]
ENC_STEPS = 4      # comparisons that finish each code (exact with <= 4 code midpoints per bin)


def apply_headroom(target: np.ndarray, headroom: tuple[float, float] | None) -> np.ndarray:
    """Map the target from [0, 1] into ``[lo, hi]`` (``None``: unchanged).

    Compensation needs room above and below the target to pre-sharpen; a target of pure black
    and white (text) has none, so the clamp to [0, 1] limits what the solve can do. Mapping the
    target into [lo, hi] trades contrast for that room.
    """
    lo, scale = headroom_params(headroom)
    if lo == 0.0 and scale == 1.0:
        return target
    return (lo + scale * np.asarray(target, dtype=np.float32)).astype(np.float32)


def headroom_params(headroom: tuple[float, float] | None) -> tuple[float, float]:
    """``(lo, hi − lo)`` of a headroom pair, validated; ``(0, 1)`` for ``None``."""
    if headroom is None:
        return 0.0, 1.0
    try:
        lo, hi = (float(v) for v in headroom)
    except (TypeError, ValueError):
        raise InputError(f"headroom must be a pair (lo, hi); got {headroom!r}") from None
    if not (0.0 <= lo < hi <= 1.0):
        raise InputError(f"headroom must satisfy 0 <= lo < hi <= 1; got ({lo}, {hi})")
    return lo, hi - lo


def increasing_lut(lut: np.ndarray) -> np.ndarray:
    """A strictly increasing copy of a (3, 256) response LUT, fit for inversion.

    A measured response can be flat (saturation, quantisation) or dip by noise; the running
    maximum plus a ramp of 1e-6 per code keeps the order without visibly moving any value.
    """
    lut = np.asarray(lut, dtype=np.float64)
    if lut.shape != (3, 256):
        raise InputError(f"response LUT must be (3, 256); got {lut.shape}")
    mono = np.maximum.accumulate(lut, axis=1) + 1e-6 * np.arange(256)
    return mono.astype(np.float32)


def decode_lut(codes: np.ndarray, lut: np.ndarray, headroom=None) -> np.ndarray:
    """uint8 (H, W, 3) codes -> planar (3, H, W) float32 linear light, mapped into the headroom."""
    codes = np.asarray(codes)
    if codes.dtype != np.uint8 or codes.ndim != 3 or codes.shape[2] != 3:
        raise InputError(f"expected an (H, W, 3) uint8 image; got {codes.dtype} {codes.shape}")
    lo, scale = headroom_params(headroom)
    lut = np.asarray(lut, dtype=np.float32)
    out = np.stack([lut[c][codes[..., c]] for c in range(3)])
    return (np.float32(lo) + np.float32(scale) * out).astype(np.float32)


def inverse_lut_tables(lut_increasing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tables of the encoder (shared by both backends): code midpoints and per-bin start codes.

    The code of P is the number of midpoints ``mid[c, v] = (lut[c, v] + lut[c, v+1]) / 2``
    that are ``<= P`` — the nearest code under piecewise-linear interpolation of the response.
    It is found as ``tab[c, floor(P · ENC_T)]`` (the count at the bin's start) plus
    ``ENC_STEPS`` comparisons, a fixed amount of work a device runs fast.

    Returns
    -------
    mid : (3, 256) float32, ``mid[:, 255] = +inf``
    tab : (3, ENC_T) uint8
    """
    lut = np.asarray(lut_increasing, dtype=np.float32)
    mid = np.full((3, 256), np.inf, np.float32)
    mid[:, :255] = (lut[:, :-1] + lut[:, 1:]) / np.float32(2)
    edges = (np.arange(ENC_T, dtype=np.float32) / np.float32(ENC_T))
    tab = np.stack([np.searchsorted(mid[c], edges, side="right") for c in range(3)])
    per_bin = max(int(np.bincount(np.clip((mid[c, :255] * ENC_T).astype(np.int64), 0, ENC_T - 1),
                                  minlength=ENC_T).max()) for c in range(3))
    if per_bin > ENC_STEPS:
        # Only where the response is flat to ~1e-5 (saturation): any of those codes shows the
        # same light, so a slightly low code there is harmless.
        log.debug("response LUT has %d code midpoints in one encoder bin (> %d): encoding is "
                  "approximate in its flat parts", per_bin, ENC_STEPS)
    return mid, np.minimum(tab, 255).astype(np.uint8)


def encode_lut(P: np.ndarray, lut_increasing: np.ndarray, tables=None) -> np.ndarray:
    """Planar linear (3, H, W) -> uint8 (H, W, 3) codes through the inverse response: the code
    whose response is nearest P under piecewise-linear interpolation (see
    :func:`inverse_lut_tables`; the device kernel ``encode_lut`` takes the very same steps)."""
    mid, tab = tables if tables is not None else inverse_lut_tables(lut_increasing)
    P = np.asarray(P, dtype=np.float32)
    out = np.empty(P.shape[1:] + (3,), np.uint8)
    for c in range(3):
        p = P[c]
        b = np.clip((p * np.float32(ENC_T)).astype(np.int64), 0, ENC_T - 1)
        code = tab[c][b].astype(np.int64)
        for _ in range(ENC_STEPS):
            code += p >= mid[c][code]
        out[..., c] = code
    return out
