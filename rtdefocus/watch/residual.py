"""What the camera should see of a shown frame, and what a capture says changed.

The calibration's forward model predicts the camera's linear light at every projector pixel:
``L(x) = albedo(x) · (F P)(x) + ambient(x)`` with ``P`` the frame decoded through the projector
response and ``F`` the calibrated kernel field (DESIGN.md §3). A capture, linearised through
the camera's inverse response and resampled into projector pixels through the calibrated
homographies and lens, is compared with it there:

* geometry: per plane, the content's shift (projector px) inside the plane away from its folds
  and the frame's edge, between the blurred frame ``F P`` and the observation with the room
  light taken off and divided by the albedo: the wall's printed texture stays where it is
  when the projector moves, so only the projected content moves;
* light: ``observed ≈ gain · predicted + added · shape`` by least squares on the aligned
  prediction, ``shape`` the calibrated ambient map normalised to mean 1 (uniform when the
  calibration saw no ambient), so ``added`` is the mean camera light the room added;
* focus: the band-pass energy (difference of Gaussians) of the observation against that of
  the prediction. The resampling into projector pixels smooths the observation, so the ratio
  is below 1 on an unchanged set-up: a change in blur shows as a change of the ratio against
  its value while the calibration was known to be right.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..calib.file import Calibration
from ..calib.radiometry.camera_response import linearize
from ..calib.radiometry.stage import to_projector
from ..errors import InputError
from ..reference.blur import blur_forward_filter2d
from ..reference.lut import decode_lut


@dataclass
class ResidualReport:
    """What one capture says about the calibration (see :func:`residual_report`).

    Attributes
    ----------
    gain : camera light observed per unit predicted (1: unchanged exposure and albedo).
    ambient_added : mean camera-linear light added beyond the prediction (0: unchanged room
        light), over the watched pixels.
    shifts_proj : (n_planes, 2) float64, (dx, dy) projector px by which the content seen on
        each plane moved against the prediction (NaN where the plane had too few pixels).
    confidence : (n_planes,) float64, phase correlation peak (0..1); small on plain content.
    band_ratio : band-pass (DoG, σ = 1 and 2 projector px) RMS of the observation over that of
        the prediction, on the watched pixels; it falls when the blur grows.
    rms_before, rms_after : RMS of observed − predicted before, and after, the alignment and
        the light fit (camera-linear light).
    watched : number of projector pixels compared.
    """

    gain: float
    ambient_added: float
    shifts_proj: np.ndarray
    confidence: np.ndarray
    band_ratio: float
    rms_before: float
    rms_after: float
    watched: int


def predict_proj(calib: Calibration, frame: np.ndarray) -> np.ndarray:
    """The camera's linear light expected at each projector pixel while ``frame`` is shown.

    Parameters
    ----------
    calib : Calibration; without radiometry the albedo is 1 and the ambient 0, without
        kernels the blur is the identity.
    frame : (Hp, Wp, 3) uint8 projector frame.

    Returns
    -------
    (Hp, Wp, 3) float32.
    """
    return _with_light(calib, _blurred(calib, frame))


def _blurred(calib: Calibration, frame: np.ndarray) -> np.ndarray:
    """``F P``: the frame in linear light, blurred by the calibrated kernels, (Hp, Wp, 3)."""
    wp, hp = calib.projector_size
    frame = np.asarray(frame)
    if frame.shape != (hp, wp, 3) or frame.dtype != np.uint8:
        raise InputError(f"the shown frame must be ({hp}, {wp}, 3) uint8 (the projector's size); "
                         f"got {frame.dtype} {frame.shape}")
    lin = decode_lut(frame, calib.lut)                           # (3, Hp, Wp)
    if calib.has_psf:
        lin = blur_forward_filter2d(lin, calib.psfs, calib.pix_idx, calib.pix_wts)
    return np.ascontiguousarray(lin.transpose(1, 2, 0))


def _with_light(calib: Calibration, blurred: np.ndarray) -> np.ndarray:
    """albedo · blurred + ambient, with what the calibration knows of them."""
    out = blurred.copy()
    if calib.albedo_proj is not None:
        out *= calib.albedo_proj
    if calib.ambient_proj is not None:
        out += calib.ambient_proj
    return out


def observe_proj(calib: Calibration, capture: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A camera frame as linear light at each projector pixel, and where the camera sees it.

    The camera's inverse response is ``calib.camera_lut`` (a linear camera when None).

    Returns
    -------
    (Hp, Wp, 3) float32 and (Hp, Wp) bool.
    """
    wc, hc = calib.camera_size
    capture = np.asarray(capture)
    if capture.shape != (hc, wc, 3):
        raise InputError(f"the capture must be ({hc}, {wc}, 3) (the calibration's camera size); "
                         f"got {capture.shape}")
    return to_projector(calib, linearize(capture, calib.camera_lut))


def _watched_planes(calib: Calibration, seen: np.ndarray, margin: int) -> list[np.ndarray]:
    """Per plane, the pixels to compare: seen, ``margin`` px inside the frame and the plane."""
    plane = calib.plane_map()
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    out = []
    for p in range(calib.n_planes):
        inside = np.zeros(plane.shape, np.uint8)
        inside[margin:-margin, margin:-margin] = plane[margin:-margin, margin:-margin] == p
        out.append(cv2.erode(inside, kernel).astype(bool) & seen)
    return out


def _coarse_shift(a: np.ndarray, b: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, float]:
    """Whole-pixel (dx, dy) of ``b`` against ``a`` inside ``m`` by phase correlation, and its
    peak (0..1). The whitening is regularised: blurred content has no energy at high
    frequencies, and whitening them fully would only amplify the noise there."""
    h, w = a.shape
    win = np.outer(np.hanning(h), np.hanning(w)) * m
    fa = np.fft.rfft2((a - a[m].mean()) * win)
    fb = np.fft.rfft2((b - b[m].mean()) * win)
    cross = np.conj(fa) * fb
    mag = np.abs(cross)
    corr = np.fft.irfft2(cross / (mag + 1e-3 * mag.max() + 1e-30), s=a.shape)
    py, px = np.unravel_index(int(np.argmax(corr)), corr.shape)
    d = np.array([px - w if px > w / 2 else px, py - h if py > h / 2 else py], np.float64)
    return d, float(corr[py, px])


def _plane_shift(pred: np.ndarray, obs: np.ndarray, mask: np.ndarray,
                 iterations: int = 6) -> tuple[np.ndarray, float]:
    """(dx, dy) such that ``obs(x) ≈ gain · pred(x − d) + offset`` inside ``mask`` (grey
    images), and the phase correlation peak of the whole-pixel start."""
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    m = mask[y0:y1, x0:x1]
    a = np.ascontiguousarray(pred[y0:y1, x0:x1], np.float32)
    b = np.asarray(obs[y0:y1, x0:x1], np.float64)[m]
    d, peak = _coarse_shift(a, obs[y0:y1, x0:x1].astype(np.float64), m)
    # Gauss-Newton on the shift, gain and offset: pred(x − d − δ) ≈ W − ∇W · δ.
    for _ in range(iterations):
        M = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        W = cv2.warpAffine(a, M, (a.shape[1], a.shape[0]), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        gy, gx = np.gradient(W)
        A = np.stack([W[m], np.ones(int(m.sum())), -gx[m], -gy[m]], axis=1)
        (gain, _, u, v), *_ = np.linalg.lstsq(A, b, rcond=None)
        if abs(gain) < 1e-6:
            break
        step = np.array([u, v]) / gain
        d += np.clip(step, -2.0, 2.0)
        if np.abs(step).max() < 1e-3:
            break
    return d, peak


def residual_report(calib: Calibration, frame: np.ndarray, capture: np.ndarray,
                    margin: int | None = None, min_pixels: int = 400) -> ResidualReport:
    """Compare a capture with the calibration's prediction of it: light and geometry.

    Parameters
    ----------
    calib : the calibration the show runs with (geometry; radiometry and kernels when
        present; ``camera_lut`` for a camera that is not linear).
    frame : (Hp, Wp, 3) uint8, the projector frame shown when ``capture`` was taken.
    capture : (Hc, Wc, 3) uint8 camera frame.
    margin : projector px kept away from the frame's edge and the folds (None: 4 % of the
        smaller side, at least 8): content moved across them would read as a change.
    min_pixels : a plane with fewer watched pixels gets a NaN shift.

    Returns
    -------
    ResidualReport
    """
    wp, hp = calib.projector_size
    margin = max(8, int(0.04 * min(wp, hp))) if margin is None else int(margin)
    blurred = _blurred(calib, frame)
    pred = _with_light(calib, blurred)
    obs, seen = observe_proj(calib, capture)
    masks = _watched_planes(calib, seen, margin)
    pred_g, obs_g = pred.mean(axis=2), obs.mean(axis=2)
    # The content alone, as the projector put it on the wall.
    content = obs
    if calib.ambient_proj is not None:
        content = content - calib.ambient_proj
    if calib.albedo_proj is not None:
        content = content / np.maximum(calib.albedo_proj, 1e-3)
    content_g, blurred_g = content.mean(axis=2), blurred.mean(axis=2)
    shifts = np.full((calib.n_planes, 2), np.nan)
    conf = np.zeros(calib.n_planes)
    aligned = pred_g.copy()
    for p, mask in enumerate(masks):
        if mask.sum() < min_pixels:
            continue
        shifts[p], conf[p] = _plane_shift(blurred_g, content_g, mask)
        # The prediction with the content moved as it did, for the light fit.
        M = np.float32([[1, 0, shifts[p][0]], [0, 1, shifts[p][1]]])
        moved = cv2.warpAffine(blurred, M, (wp, hp), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)
        aligned[mask] = _with_light(calib, moved).mean(axis=2)[mask]
    watched = np.any(masks, axis=0) if masks else np.zeros((hp, wp), bool)
    n = int(watched.sum())
    if n < min_pixels:
        raise InputError(f"the camera sees only {n} projector pixels of this calibration; "
                         "check that the capture and the calibration belong to the same set-up")
    if calib.ambient_proj is not None and float(calib.ambient_proj[watched].mean()) > 1e-6:
        shape = calib.ambient_proj.mean(axis=2)
        shape = shape / shape[watched].mean()
    else:
        shape = np.ones((hp, wp), np.float32)
    A = np.stack([aligned[watched], shape[watched]], axis=1).astype(np.float64)
    y = obs_g[watched].astype(np.float64)
    (gain, added), *_ = np.linalg.lstsq(A, y, rcond=None)
    rms_before = float(np.sqrt(np.mean((y - pred_g[watched]) ** 2)))
    rms_after = float(np.sqrt(np.mean((y - A @ [gain, added]) ** 2)))
    return ResidualReport(gain=float(gain), ambient_added=float(added), shifts_proj=shifts,
                          confidence=conf, band_ratio=_band_ratio(aligned, obs_g, watched),
                          rms_before=rms_before, rms_after=rms_after, watched=n)


def _band_ratio(pred: np.ndarray, obs: np.ndarray, mask: np.ndarray) -> float:
    """RMS of the difference of Gaussians (σ 1 and 2 px) of ``obs`` over that of ``pred``."""
    def band(x):
        x = np.asarray(x, np.float32)
        return cv2.GaussianBlur(x, (0, 0), 1.0) - cv2.GaussianBlur(x, (0, 0), 2.0)

    e_pred = float(np.mean(band(pred)[mask] ** 2))
    return float(np.sqrt(np.mean(band(obs)[mask] ** 2) / e_pred)) if e_pred > 0 else float("nan")
