"""The camera's response: codes -> linear light, known or recovered from captures alone.

The model (DESIGN.md §3) is linear in irradiance only after the camera's codes are linearised
by the camera's *inverse response* h: code (0..255) -> linear light, h(0) = 0, h(255) = 1,
monotone. A webcam encodes sRGB (close to gamma 2.2); a machine-vision camera is linear.

Recovery without exposure control, by superposition. Let A and B be two projector patterns
that light *disjoint* sets of pixels (at any levels) and AB their union. In projector-linear
light P_AB = P_A + P_B, and the light the camera receives is affine in P (blur, shading,
albedo and ambient alike), so at every camera pixel::

    h(c_AB) − h(c_0) = (h(c_A) − h(c_0)) + (h(c_B) − h(c_0))       (c_0: the black frame)

i.e. ``h(c_AB) − h(c_A) − h(c_B) + h(c_0) = 0`` — linear in h. A linear h satisfies it only
when the camera is linear. The patterns: AB is the radiometry stage's grey-patch ramp (levels
15..255) and A, B split its pixels by a seeded random mask, so the blur mixes lit and dark
pixels in every proportion and each camera pixel of the lit area is one equation. h is
the parametric family :func:`response_curve` (linear, power laws and sRGB), fitted per
channel by least squares to these equations with h(0) = 0 and h(255) = 1: the equations fix
h only up to an affine map, and the family's shape fixes the rest.
"""

from __future__ import annotations

import logging

import numpy as np

from ...errors import CalibrationError, InputError

log = logging.getLogger(__name__)

__all__ = ["CAMERA_RESPONSES", "srgb_to_linear", "linear_to_srgb", "known_response",
           "split_pattern", "response_curve", "fit_inverse_response", "linearize"]

#: Accepted values of the ``camera_response`` calibration option.
CAMERA_RESPONSES = ("linear", "srgb", "auto")
_SATURATED = 250.0     # codes at or above this are clipped; left out of the fit
_MAX_SAMPLES = 60000


def srgb_to_linear(v) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear light in [0, 1] (IEC 61966-2-1)."""
    v = np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x) -> np.ndarray:
    """Linear light in [0, 1] -> sRGB-encoded values in [0, 1] (keeps a float32 input float32)."""
    a = np.asarray(x)
    dt = a.dtype if a.dtype.kind == "f" else np.float64
    a = np.clip(a, 0.0, 1.0)
    out = np.where(a <= 0.0031308, a * 12.92, 1.055 * np.power(a, 1.0 / 2.4) - 0.055)
    return out.astype(dt, copy=False)


def known_response(kind: str | float) -> np.ndarray:
    """(3, 256) float32 inverse response of a known camera: ``"linear"``, ``"srgb"`` or a power
    law exponent (``(code / 255) ** gamma``)."""
    codes = np.arange(256) / 255.0
    if isinstance(kind, str):
        if kind == "linear":
            h = codes
        elif kind == "srgb":
            h = srgb_to_linear(codes)
        else:
            raise InputError(f"camera_response must be one of {CAMERA_RESPONSES}; got {kind!r}")
    else:
        h = codes ** float(kind)
    return np.tile(h, (3, 1)).astype(np.float32)


def linearize(codes: np.ndarray, response: np.ndarray | float | None) -> np.ndarray:
    """Camera codes (0..255, (..., 3) or (...,) float/uint8) -> linear light float32.

    ``response`` is a (3, 256) inverse-response table (interpolated between codes, so averaged
    frames are exact), a power-law exponent, or None (linear camera).
    """
    x = np.asarray(codes, dtype=np.float32)
    if response is None or np.isscalar(response):
        g = 1.0 if response is None else float(response)
        y = x / np.float32(255.0)
        return np.power(np.clip(y, 0.0, None), np.float32(g)) if g != 1.0 else y
    lut = np.asarray(response, dtype=np.float32)
    grid = np.arange(256, dtype=np.float32)
    if x.ndim >= 1 and x.shape[-1] == 3:
        out = np.empty(x.shape, np.float32)
        for c in range(3):
            out[..., c] = np.interp(x[..., c], grid, lut[c])
        return out
    return np.interp(x, grid, lut[1]).astype(np.float32)


def split_pattern(pattern: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Split ``pattern``'s pixels into two disjoint patterns A, B (A + B = pattern) by a seeded
    random mask of 2×2-pixel cells (finer than the blur, so the camera sees mixtures)."""
    hp, wp = pattern.shape[:2]
    rng = np.random.default_rng([seed, 31])
    cells = rng.random(((hp + 1) // 2, (wp + 1) // 2)) < 0.5
    mask = np.repeat(np.repeat(cells, 2, axis=0), 2, axis=1)[:hp, :wp]
    a = np.where(mask[..., None], pattern, 0).astype(np.uint8)
    return a, (pattern - a).astype(np.uint8)


def response_curve(codes: np.ndarray, g: float, a: float) -> np.ndarray:
    """The parametric inverse response ``h(c) = ((t + a)^g − a^g) / ((1 + a)^g − a^g)``, t = c/255.

    It spans the linear camera (g = 1), a power law (a = 0) and sRGB (a ≈ 0.055, g ≈ 2.4,
    within 0.002 of the standard's curve with its linear toe)."""
    t = np.asarray(codes, np.float64) / 255.0
    return ((t + a) ** g - a ** g) / ((1.0 + a) ** g - a ** g)


def fit_inverse_response(c0: np.ndarray, ca: np.ndarray, cb: np.ndarray, cab: np.ndarray,
                         valid: np.ndarray, seed: int = 0) -> tuple[np.ndarray, dict]:
    """Recover the camera's inverse response per channel from a superposition quadruple.

    The superposition equations fix h only up to an affine map (adding a constant or scaling
    h satisfies them too): h(255) = 1 fixes the scale, and the offset — which would need the
    never-seen codes below the ambient light — comes from the shape of the parametric family
    :func:`response_curve` (h(0) = 0), fitted by least squares to the equations.

    Parameters
    ----------
    c0, ca, cb, cab : (Hc, Wc, 3) float camera codes (averaged captures) of black, A, B and
        their union AB.
    valid : (Hc, Wc) bool, camera pixels to use (the lit area).

    Returns
    -------
    lut : (3, 256) float32 code -> linear light, monotone, lut[:, 0] = 0, lut[:, 255] = 1.
    info : per channel ``samples``, ``params`` (g, a), ``rms`` (residual of the superposition
        equations, linear units) and ``lowest_code`` (the darkest black-frame code used).

    Raises
    ------
    CalibrationError
        Too few usable pixels (the projector lights too little of the camera's view, or the
        camera clips everywhere).
    """
    from scipy.optimize import least_squares

    rng = np.random.default_rng([seed, 37])
    lut = np.empty((3, 256), np.float32)
    info: dict = {"samples": [], "params": [], "rms": [], "lowest_code": []}
    for ch in range(3):
        q = [np.asarray(v[..., ch], np.float64)[valid] for v in (c0, ca, cb, cab)]
        ok = (np.max(q, axis=0) < _SATURATED) & (q[3] - q[0] > 6.0)
        idx = np.flatnonzero(ok)
        if idx.size < 500:
            raise CalibrationError(
                f"camera response: only {idx.size} camera pixels show the superposition patterns "
                "unclipped and clearly above the black level (need 500); aim the camera at the "
                "projection, lower the exposure if the picture is blown out, or pass "
                "camera_response='srgb' (webcams) or 'linear' (raw cameras)")
        if idx.size > _MAX_SAMPLES:
            idx = rng.choice(idx, _MAX_SAMPLES, replace=False)
        v0, va, vb, vab = (x[idx] for x in q)

        def resid(p, v0=v0, va=va, vb=vb, vab=vab):
            g, a = p
            return (response_curve(vab, g, a) - response_curve(va, g, a)
                    - response_curve(vb, g, a) + response_curve(v0, g, a))

        best = None
        for start in ((1.0, 0.01), (2.2, 0.0), (2.4, 0.055)):
            sol = least_squares(resid, start, bounds=([0.3, 0.0], [4.0, 0.5]), x_scale=(1.0, 0.05))
            if best is None or sol.cost < best.cost:
                best = sol
        g, a = (float(v) for v in best.x)
        lut[ch] = response_curve(np.arange(256), g, a).astype(np.float32)
        info["samples"].append(int(idx.size))
        info["params"].append([round(g, 4), round(a, 5)])
        info["rms"].append(round(float(np.sqrt(np.mean(best.fun ** 2))), 5))
        info["lowest_code"].append(int(np.floor(v0.min())))
    log.info("camera response recovered from %s pixels per channel: (g, a) %s, superposition "
             "rms %s", info["samples"], info["params"], info["rms"])
    return lut, info
