"""Radiometric calibration: the projector's response g, the ambient term Γ and the albedo α.

The model (DESIGN.md §3), in camera-linear light normalised to [0, 1]::

    O(x) = α(x) · (F P)(x) + Γ(x),        P = g(v) ∈ [0, 1],  g(0) = 0, g(255) = 1

Captures (``capture`` counts them): a black frame and a white frame (each averaged over a few
captures against camera noise) and one *patch ramp*: a grid of uniform grey patches, one level
each. For any pixel inside a patch (farther than the blur from the patch's border) the ratio
``(I_v − I_black) / (I_white − I_black)`` is ``g(v)`` whatever the albedo, shading and ambient
there, so a single capture gives the whole ramp, averaged over thousands of pixels. The three
camera channels give the three projector channels (grey patches; no crosstalk assumed).

The camera's own response comes first (``camera_response``, :mod:`.camera_response`):
``"auto"`` (default) recovers it from captures alone by superposition — the ramp pattern
and the two halves of a random split of it (2 more patterns) — ``"srgb"`` / ``"linear"``
take a known curve, and ``camera_gamma`` ≠ 1 a known power law. Every camera frame is then
linearised with it (``calib.camera_lut``), so g, Γ, α and the PSF stage's kernels are all in
camera-linear light. (Without this, a camera with an unknown curve makes the recovered
exponent wrong — with ambient light the composed curve is not even a power law.)

Γ and α are mapped into projector pixels through each plane's homography (the plane of a
projector pixel is given by its plane layout, as in the warp): Γ = black (smoothed within each
plane: it is a few camera codes, mostly noise in one frame), α = white − black. Within a blur
radius of the frame edge α includes the blurred white frame's fall-off over the edge, i.e. it
is exactly what the projector's full white produces at each pixel (≈ the in-focus α inside).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields

import cv2
import numpy as np

from ...checks import check_choice
from ...errors import CalibrationError, InputError
from ...planar import apply_h_per_plane
from ..capture import Capturer, check_capturer, check_geometry
from ..file import Calibration
from ..geometry.lens import lens_k, lit_mask_observed, observed_points
from ..options import stage_options
from .camera_response import (
    CAMERA_RESPONSES,
    fit_inverse_response,
    known_response,
    linearize,
    split_pattern,
)
from .exposure import check_drift, check_exposure

log = logging.getLogger(__name__)

# 16 levels fill a 4 x 4 patch grid; spaced evenly in code values, which puts most of them
# where g is steep (gamma > 1) and is what an 8-bit LUT is indexed by.
DEFAULT_LEVELS = tuple(range(15, 256, 16))  # 15, 31, ..., 255


@dataclass(frozen=True)
class RadiometryOptions:
    """Options of the radiometry stage, with their defaults (``calibrate(**options)`` routes
    these names to :func:`calibrate_radiometry`).

    Attributes
    ----------
    black_frames, white_frames : captures averaged for the black and the white frame (camera
        noise).
    ramp_levels : grey levels of the ramp, ints in 1..254 (and 255).
    ramp_layout : ``"patches"``: all levels in one capture as a grid of patches (needs no
        interreflection between the walls); ``"frames"``: one full-frame capture per level.
    camera_response : ``"auto"`` (recover it by superposition), ``"srgb"`` or ``"linear"``
        (module docstring); recorded as ``calib.camera_lut``.
    response_frames : captures averaged per superposition pattern (``"auto"``).
    camera_gamma : a known power-law camera (code/255)**camera_gamma; ≠ 1 overrides
        ``camera_response``.
    response_model : ``"auto"`` | ``"gamma"`` | ``"table"``: the LUT is a fitted power law, a
        monotone interpolation of the measurements, or the power law when it fits every level
        within 0.01 (else the table).
    ambient_smooth : Gaussian sigma (projector px) applied to Γ within each plane. Ambient
        light is low-contrast and smooth while the black frame is mostly camera noise (Γ is a
        few codes), so this cuts Γ's noise several-fold; 0 keeps it per pixel.
    """

    black_frames: int = 3
    white_frames: int = 2
    ramp_levels: tuple = DEFAULT_LEVELS
    ramp_layout: str = "patches"
    camera_response: str = "auto"
    response_frames: int = 2
    camera_gamma: float = 1.0
    response_model: str = "auto"
    ambient_smooth: float = 2.0


#: names of the stage's options (the fields of :class:`RadiometryOptions`).
OPTIONS = tuple(f.name for f in fields(RadiometryOptions))
# A camera code at or above this is treated as clipped.
SATURATED = 250.0


# --------------------------------------------------------------------------- helpers
def linearize_camera(codes: np.ndarray, camera_lut: float | np.ndarray | None = 1.0) -> np.ndarray:
    """Camera code values (0..255, any float/uint8 array) -> camera-linear light in [0, 1].

    ``camera_lut``: a (3, 256) inverse-response table (``calib.camera_lut``), interpolated per
    channel; 1 (or None) is a linear camera; a number n the power law ``(code / 255) ** n``.
    """
    return linearize(codes, camera_lut)


def projector_to_camera_maps(calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Camera coordinates of every projector pixel, through its own plane's homography and
    then the lens (ideal -> observed pixels, :func:`~.lens.observed_points`).

    Returns
    -------
    map_x, map_y : (Hp, Wp) float32
        Observed camera (x, y) of projector pixel centre (x, y), ready for ``cv2.remap`` on a
        captured frame.
    """
    wp, hp = calib.projector_size
    ys, xs = np.mgrid[0:hp, 0:wp].astype(np.float64)
    plane = calib.plane_map()
    map_x, map_y = apply_h_per_plane(calib.H_cam_from_proj, plane, xs, ys)
    dense = calib.residual_dense()
    if dense is not None:       # each plane's smooth residual off its homography
        map_x, map_y = map_x + dense[..., 0], map_y + dense[..., 1]
    if lens_k(calib) is not None:
        obs = observed_points(calib, np.stack([map_x, map_y], axis=-1))
        map_x, map_y = obs[..., 0], obs[..., 1]
    return map_x.astype(np.float32), map_y.astype(np.float32)


def to_projector(calib: Calibration, img_cam: np.ndarray,
                 maps: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Resample a camera-space image into projector pixels (bilinear, per plane).

    Camera values are *radiance* (light per area), so point sampling at each projector
    pixel's camera position is the right, energy-consistent resampling for the gather model.

    Parameters
    ----------
    calib : Calibration with the geometry section.
    img_cam : (Hc, Wc) or (Hc, Wc, C) float32
    maps : the output of :func:`projector_to_camera_maps` (computed when omitted).

    Returns
    -------
    img_proj : (Hp, Wp[, C]) float32, 0 where the camera does not see the pixel
    seen : (Hp, Wp) bool, True where the projector pixel maps inside the camera frame
    """
    if maps is None:
        maps = projector_to_camera_maps(calib)
    wc, hc = calib.camera_size
    map_x, map_y = maps
    seen = (map_x >= 0) & (map_x <= wc - 1) & (map_y >= 0) & (map_y <= hc - 1)
    out = cv2.remap(np.ascontiguousarray(img_cam, dtype=np.float32), map_x, map_y,
                    interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, seen


def ramp_pattern(projector_size: tuple[int, int], levels, grid: tuple[int, int] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A grid of uniform grey patches, one per level, in reading order.

    Returns
    -------
    pattern : (Hp, Wp, 3) uint8
    cells : (L, 4) int ``(x0, y0, x1, y1)`` of each level's patch (exclusive ends)
    """
    wp, hp = projector_size
    levels = list(levels)
    if grid is None:
        cols = int(np.ceil(np.sqrt(len(levels) * wp / hp)))
        rows = int(np.ceil(len(levels) / cols))
    else:
        cols, rows = grid
    xs = np.linspace(0, wp, cols + 1).round().astype(int)
    ys = np.linspace(0, hp, rows + 1).round().astype(int)
    pattern = np.zeros((hp, wp, 3), np.uint8)
    cells = []
    for i, v in enumerate(levels):
        r, c = divmod(i, cols)
        x0, x1, y0, y1 = xs[c], xs[c + 1], ys[r], ys[r + 1]
        pattern[y0:y1, x0:x1] = v
        cells.append((x0, y0, x1, y1))
    return pattern, np.array(cells, dtype=int)


def fit_gamma(levels: np.ndarray, values: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Least-squares exponent γ of ``values ≈ (levels / 255) ** γ`` (Gauss-Newton, linear domain).

    Fitting in the linear domain (not log) weights each level by its absolute error, so the
    dim levels, whose ratios carry the most relative noise, do not dominate.
    """
    t = np.asarray(levels, np.float64) / 255.0
    y = np.asarray(values, np.float64)
    w = np.ones_like(y) if weights is None else np.asarray(weights, np.float64)
    ok = (t > 0) & (t < 1) & np.isfinite(y)
    t, y, w = t[ok], y[ok], w[ok]
    if t.size == 0:
        raise CalibrationError("no usable grey-ramp level between 0 and 255 to fit the "
                               "projector's response; use ramp_levels inside 1..254")
    pos = y > 1e-3  # log-domain start, then refine where the noise model is right
    g = float(np.polyfit(np.log(t[pos]), np.log(y[pos]), 1, w=np.sqrt(y[pos]))[0]) if \
        pos.sum() >= 2 else 2.2
    g = float(np.clip(g, 0.2, 6.0))
    for _ in range(30):
        f = t ** g
        r = y - f
        J = f * np.log(t)
        step = float((w * J * r).sum() / max((w * J * J).sum(), 1e-300))
        g = float(np.clip(g + step, 0.2, 6.0))
        if abs(step) < 1e-9:
            break
    return g


def _monotone_lut(levels: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(256,) LUT through (0, 0), the measured points and (255, 1): monotone cubic (PCHIP)."""
    # scipy loads on first use (~1 s): `import rtdefocus.calib` (the player loads Calibration) stays fast.
    from scipy.interpolate import PchipInterpolator

    x = np.concatenate([[0.0], np.asarray(levels, np.float64), [255.0]])
    y = np.concatenate([[0.0], np.asarray(values, np.float64), [1.0]])
    order = np.argsort(x, kind="stable")
    x, y = x[order], y[order]
    keep = np.concatenate([[True], np.diff(x) > 0])
    x, y = x[keep], np.clip(y[keep], 0.0, 1.0)
    y = np.maximum.accumulate(y)  # a response never decreases; noise can make it dip
    return PchipInterpolator(x, y)(np.arange(256.0)).astype(np.float32)


def _smooth_per_plane(img: np.ndarray, plane: np.ndarray, valid: np.ndarray, sigma: float
                      ) -> np.ndarray:
    """Normalised Gaussian smoothing of (H, W, C) within each plane's valid pixels, so the
    walls' different albedos do not bleed across a fold (any number of planes)."""
    out = np.zeros_like(img)
    for p in np.unique(plane):
        m = ((plane == p) & valid).astype(np.float32)
        num = cv2.GaussianBlur(img * m[..., None], (0, 0), sigma)
        den = cv2.GaussianBlur(m, (0, 0), sigma)[..., None]
        sel = m > 0
        out[sel] = (num / np.maximum(den, 1e-6))[sel]
    return out


def _lit_camera_mask(calib: Calibration) -> np.ndarray:
    """(Hc, Wc) bool: observed camera pixels inside the lit outline (through the lens)."""
    return lit_mask_observed(calib)


# --------------------------------------------------------------------------- the stage
def calibrate_radiometry(calib: Calibration, capture: Capturer,
                         options: RadiometryOptions | None = None, **overrides) -> Calibration:
    """Measure the projector response, ambient Γ and albedo α; fill ``calib``'s radiometry.

    Parameters
    ----------
    calib : Calibration
        With the geometry section (homographies, folds); its radiometry section is filled in
        place and it is returned.
    capture : Capturer
        The calibration's capturer (the ProCam, counts, progress, frame cache; stage
        ``"radiometry"``).
    options : RadiometryOptions, optional
        The stage's options (default: :class:`RadiometryOptions`' defaults).
    **overrides
        Fields of :class:`RadiometryOptions` (``black_frames=5``, ``camera_response="srgb"``,
        ...) replacing those of ``options``.

    Returns
    -------
    Calibration
        ``calib`` with ``camera_lut`` (3, 256), ``response_lut`` (3, 256) float32,
        ``ambient_proj`` and ``albedo_proj`` (Hp, Wp, 3) float32 in camera-linear units,
        ``meta["radiometry"]`` with the fitted ``gamma`` per channel, fit residuals and the
        coverage.

    Raises
    ------
    InputError
        An option unknown or out of range (before any capture).
    CalibrationError
        When the white frame is not brighter than the black one where the projector lights
        the surface, when the camera saturates on white, or when no ramp patch is usable.
    """
    check_capturer(capture)
    o = stage_options(RadiometryOptions, options, **overrides)
    black_frames, white_frames, ramp_levels = o.black_frames, o.white_frames, o.ramp_levels
    ramp_layout, camera_response, response_frames = o.ramp_layout, o.camera_response, \
        o.response_frames
    camera_gamma, response_model, ambient_smooth = o.camera_gamma, o.response_model, \
        o.ambient_smooth
    check_choice(response_model, ("auto", "gamma", "table"), "response_model")
    check_choice(ramp_layout, ("patches", "frames"), "ramp_layout")
    levels = np.array(sorted({int(v) for v in ramp_levels}), dtype=int)
    if levels.size < 2 or levels.min() < 1 or levels.max() > 255:
        raise InputError(f"ramp_levels needs at least 2 distinct levels in 1..255; got {ramp_levels}")
    if black_frames < 1 or white_frames < 1 or response_frames < 1:
        raise InputError("black_frames, white_frames and response_frames must be >= 1")
    check_choice(camera_response, CAMERA_RESPONSES, "camera_response")
    check_geometry(calib, "radiometry")
    wp, hp = calib.projector_size
    n_ramp = 1 if ramp_layout == "patches" else len(levels)
    auto = camera_response == "auto" and camera_gamma == 1.0
    capture.begin("radiometry", black_frames + white_frames + n_ramp)

    black_pat = np.zeros((hp, wp, 3), np.uint8)
    white_pat = np.full((hp, wp, 3), 255, np.uint8)
    black_c = capture.mean_frame("black", black_pat, black_frames)
    # One white frame now, the rest at the end of the stage: the two must agree (a camera whose
    # auto-exposure or white balance is not locked drifts in between).
    spaced = capture.frame_count("white") == 0 and white_frames >= 2
    # The geometry stage's white frame (its first capture), when it took one: the same frame
    # again now tells whether the exposure moved while the lines were projected.
    geometry_white = capture.first_white
    white_first = capture.mean_frame("white", white_pat, 1)
    in_view = _lit_camera_mask(calib)
    check_exposure(white_first, in_view, SATURATED, black_c)

    # ---- the camera's own response first: every frame below is linearised with it
    response_info: dict = {}
    ramp_pat, ramp_cells = ramp_pattern(calib.projector_size, levels)
    ramp_c = None
    if camera_gamma != 1.0:
        cam_lut, kind = known_response(float(camera_gamma)), f"gamma {camera_gamma:g}"
    elif not auto:
        cam_lut, kind = known_response(camera_response), camera_response
    else:
        # The camera's response is a calibration of its own (a linear camera needs none):
        # its captures are counted apart, as the stage "camera response".
        radiometry_done = capture.stage_done
        capture.begin("camera response", 3 * response_frames)
        pat_a, pat_b = split_pattern(ramp_pat)
        ramp_c = capture.mean_frame("ramp", ramp_pat, response_frames)
        a_c = capture.mean_frame("ramp_a", pat_a, response_frames)
        b_c = capture.mean_frame("ramp_b", pat_b, response_frames)
        cam_lut, response_info = fit_inverse_response(black_c, a_c, b_c, ramp_c, in_view)
        kind = "auto"
        capture.begin("radiometry", black_frames + white_frames + n_ramp, done=radiometry_done)
    calib.camera_lut = cam_lut
    stage_drift = None
    if geometry_white is not None:
        stage_drift = check_drift(geometry_white.astype(np.float32), white_first, black_c,
                                  in_view, cam_lut, stage="geometry")
    if ramp_layout == "patches" and ramp_c is None:
        ramp_c = capture(ramp_pat)
    white_c = capture.mean_frame("white", white_pat, white_frames)
    drift_info = None
    if spaced:
        later = (white_c * white_frames - white_first) / (white_frames - 1)
        drift_info = check_drift(white_first, later, black_c, in_view, cam_lut)

    maps = projector_to_camera_maps(calib)
    black_p, seen = to_projector(calib, linearize_camera(black_c, cam_lut), maps)
    white_p, _ = to_projector(calib, linearize_camera(white_c, cam_lut), maps)
    sat_p, _ = to_projector(calib, (white_c >= SATURATED).astype(np.float32), maps)
    signal = white_p - black_p
    # Pixels the projector visibly lights: white clearly above black in every channel.
    lit = seen & (signal.min(axis=2) > 0.02)
    if lit.mean() < 0.25:
        raise CalibrationError(
            f"the white frame is brighter than the black one on only {100 * lit.mean():.0f}% of "
            "the projector's pixels: is the projector on, the camera pointed at the surface, and "
            "the geometry calibration right?")
    saturated = (sat_p > 0).any(axis=2) & lit
    if saturated.mean() > 0.01 * max(lit.mean(), 1e-9):
        frac = saturated.sum() / max(lit.sum(), 1)
        if frac > 0.05:
            raise CalibrationError(
                f"the camera clips on the white frame at {100 * frac:.0f}% of the lit pixels; "
                "lower the camera's exposure or gain (or the projector's brightness)")
        log.warning("camera clips at %.1f%% of the lit pixels on white; they are left out of the "
                    "ramp", 100 * frac)
    usable = lit & ~saturated

    # ---- the ramp: g(v) per channel as a ratio of sums over each patch's interior
    ratios = np.full((3, levels.size), np.nan)
    support = np.zeros(levels.size, dtype=int)
    if ramp_layout == "patches":
        cells = ramp_cells
        ramp_p, _ = to_projector(calib, linearize_camera(ramp_c, cam_lut), maps)
        frames = [ramp_p] * len(levels)
    else:
        cells = np.tile([0, 0, wp, hp], (len(levels), 1))
        frames = []
        for v in levels:
            frames.append(to_projector(calib, linearize_camera(
                capture(np.full((hp, wp, 3), v, np.uint8)), cam_lut), maps)[0])
    for i, (x0, y0, x1, y1) in enumerate(cells):
        # Stay clear of the patch borders by more than any plausible blur (the PSF stage
        # has not measured it yet): a quarter of the patch, at least 12 px.
        mx = max(12, (x1 - x0) // 4) if ramp_layout == "patches" else 12
        my = max(12, (y1 - y0) // 4) if ramp_layout == "patches" else 12
        sl = (slice(y0 + my, y1 - my), slice(x0 + mx, x1 - mx))
        m = usable[sl]
        support[i] = int(m.sum())
        if support[i] < 50:
            continue
        num = (frames[i][sl] - black_p[sl])[m].sum(axis=0)
        den = signal[sl][m].sum(axis=0)
        ratios[:, i] = num / den
    ok = np.isfinite(ratios[0])
    if ok.sum() < 2:
        raise CalibrationError(
            f"only {int(ok.sum())} grey-ramp patches were seen clearly (need 2); the projector "
            "lights too little of the camera's view — move the camera or use ramp_layout='frames'")

    # ---- response: fit, then the LUT
    gammas, rms, lut = [], [], np.empty((3, 256), np.float32)
    for c in range(3):
        g = fit_gamma(levels[ok], ratios[c, ok], weights=support[ok])
        resid = ratios[c, ok] - (levels[ok] / 255.0) ** g
        gammas.append(g)
        rms.append(float(np.sqrt(np.mean(resid ** 2))))
        use_gamma = response_model == "gamma" or (
            response_model == "auto" and float(np.abs(resid).max()) < 0.01)
        lut[c] = ((np.arange(256) / 255.0) ** g).astype(np.float32) if use_gamma else \
            _monotone_lut(levels[ok], ratios[c, ok])
        log.info("projector response channel %d: gamma %.3f (rms residual %.4f, %s LUT)",
                 c, g, rms[-1], "power-law" if use_gamma else "table")

    calib.response_lut = lut
    ambient = np.where(seen[..., None], black_p, 0).astype(np.float32)
    if ambient_smooth > 0:
        ambient = _smooth_per_plane(ambient, calib.plane_map(), seen, ambient_smooth)
    calib.ambient_proj = ambient
    calib.albedo_proj = np.where(seen[..., None], np.clip(signal, 0, None), 0).astype(np.float32)
    calib.meta["radiometry"] = {
        "gamma": [round(g, 4) for g in gammas],
        "fit_rms": [round(r, 5) for r in rms],
        "response_model": response_model,
        "camera_response": kind,
        "white_drift": None if drift_info is None else np.round(drift_info, 4).tolist(),
        "white_drift_geometry": None if stage_drift is None else np.round(stage_drift, 4).tolist(),
        "camera_response_fit": response_info,
        "camera_lut_at": {str(c): np.round(cam_lut[:, c], 4).tolist() for c in (32, 64, 128, 192)},
        "levels": levels[ok].tolist(),
        "ratios": np.round(ratios[:, ok], 5).tolist(),
        "seen_fraction": round(float(seen.mean()), 4),
        "lit_fraction": round(float(lit.mean()), 4),
        "captures": int(capture.counts.get("radiometry", 0)
                        + capture.counts.get("camera response", 0)),
    }
    return calib


__all__ = ["calibrate_radiometry", "fit_gamma", "linearize_camera",
           "projector_to_camera_maps", "to_projector", "ramp_pattern", "OPTIONS", "DEFAULT_LEVELS",
           "RadiometryOptions"]
