"""Image scores: how close a camera view is to the sharp reference.

* :func:`psnr`, :func:`ssim` — scores of a camera view against a reference, optionally inside a
  mask: :func:`rect_mask` (the display rectangle), :func:`near_folds_mask` (the band around
  every fold; :func:`near_fold_mask` around one line);
* :func:`edge_pixels` — Canny edge counts, as the paper's Table 1;
* :func:`score_image` — project one image every way on a set-up and score every view
  (:class:`ImageScores`); the demo's table and ``rtdefocus eval`` are built from it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import InputError
from ..reference.lut import decode_lut, encode_lut, increasing_lut
from .extras import need

__all__ = ["psnr", "ssim", "near_fold_mask", "near_folds_mask", "rect_mask", "camera_view",
           "edge_pixels", "ImageScores",
           "score_image", "coefficient_of_variation", "psnr_affine"]

# Canny thresholds for the edge-pixel counts (the paper's Table 1 gives none; OpenCV's usual pair).
CANNY_LO, CANNY_HI = 100, 200


@dataclass
class ImageScores:
    """Scores of one input image on one set-up (camera views against the sharp reference)."""

    name: str
    psnr: dict[str, float] = field(default_factory=dict)        # method -> dB, display rect
    ssim: dict[str, float] = field(default_factory=dict)        # method -> SSIM, display rect
    psnr_fold: dict[str, float] = field(default_factory=dict)   # method -> dB, near-folds band
    edges_input: dict[str, int] = field(default_factory=dict)   # geometry / defocus corrected
    edges_output: dict[str, int] = field(default_factory=dict)  # camera views of the same
    clipped: dict[str, float] = field(default_factory=dict)     # method -> fraction of P at 0 or 1
    seconds: dict[str, float] = field(default_factory=dict)     # method -> compensate() time

    @property
    def edge_increase_input(self) -> float:
        return _percent(self.edges_input["geometry"], self.edges_input["defocus"])

    @property
    def edge_increase_output(self) -> float:
        return _percent(self.edges_output["geometry"], self.edges_output["defocus"])


def _percent(before: int, after: int) -> float:
    """Percent increase; NaN from nothing (no edges before: a ratio would mean nothing)."""
    return 100.0 * (after - before) / before if before > 0 else float("nan")


def edge_pixels(rgb: np.ndarray, mask: np.ndarray | None = None) -> int:
    """Canny edge pixels of an RGB uint8 image (the paper's Table 1 measure), inside ``mask``."""
    edges = cv2.Canny(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), CANNY_LO, CANNY_HI) > 0
    if mask is not None:
        edges &= mask
    return int(edges.sum())


def _pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        raise InputError(f"images to compare must have the same shape; got {a.shape} and {b.shape}")
    return a, b


def _data_range(a: np.ndarray, data_range: float | None) -> float:
    if data_range is not None:
        return float(data_range)
    return 255.0 if a.dtype == np.uint8 else 1.0


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None,
         data_range: float | None = None) -> float:
    """Peak signal-to-noise ratio (dB) of ``a`` against ``b``.

    Parameters
    ----------
    a, b : (H, W) or (H, W, C) arrays of the same shape (uint8: range 255, float: range 1).
    mask : (H, W) bool, optional — only these pixels count.
    data_range : peak value, overriding the dtype's.

    Returns
    -------
    float (inf for identical images).
    """
    a, b = _pair(a, b)
    peak = _data_range(a, data_range)
    diff = a.astype(np.float64) - b.astype(np.float64)
    if mask is not None:
        diff = diff[np.asarray(mask, dtype=bool)]
    mse = float(np.mean(diff ** 2)) if diff.size else float("nan")
    return float("inf") if mse == 0 else 10.0 * np.log10(peak ** 2 / mse)


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None,
         data_range: float | None = None) -> float:
    """Mean structural similarity (``skimage.metrics.structural_similarity``, 7×7 windows,
    colour channels averaged) of ``a`` against ``b``, over ``mask`` when given.

    Parameters
    ----------
    a, b : (H, W) or (H, W, 3) arrays of the same shape.
    mask : (H, W) bool, optional — average the SSIM map over these pixels only.
    data_range : peak value, overriding the dtype's.
    """
    structural_similarity = need("skimage.metrics", "SSIM").structural_similarity

    a, b = _pair(a, b)
    channel_axis = 2 if a.ndim == 3 else None
    score, smap = structural_similarity(a, b, data_range=_data_range(a, data_range),
                                        channel_axis=channel_axis, full=True)
    if mask is None:
        return float(score)
    if smap.ndim == 3:
        smap = smap.mean(axis=2)
    return float(smap[np.asarray(mask, dtype=bool)].mean())


def near_fold_mask(fold_line: np.ndarray, shape: tuple[int, int], half_width: float) -> np.ndarray:
    """Pixels within ``half_width`` px of the line ``a x + b y + c = 0`` (a² + b² = 1).

    Parameters
    ----------
    fold_line : (3,) float, e.g. ``calib.fold_cam`` or ``truth.fold_proj``.
    shape : (H, W) of the image the mask is for.
    half_width : px.

    Returns
    -------
    (H, W) bool
    """
    a, b, c = (float(v) for v in np.asarray(fold_line, dtype=np.float64))
    norm = np.hypot(a, b)
    if norm == 0:
        raise InputError("the fold line is all zeros (a one-plane set-up has no fold band)")
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    return np.abs(a * xs + b * ys + c) / norm <= half_width


def near_folds_mask(calib, shape: tuple[int, int], half_width: float) -> np.ndarray:
    """Camera pixels within ``half_width`` px of any fold of ``calib`` (ideal camera pixels).

    Each fold's band follows its camera line (``calib.folds_cam``) along the part that really
    separates its two planes (:meth:`~rtdefocus.planar.PlaneLayout.fold_segments` of the
    projector frame, mapped to the camera); where that part ends inside the frame (a vertex
    where folds meet) the band ends in a half disc, where it leaves the frame the band goes on
    (only the display rectangle is scored). One plane: all False.

    Parameters
    ----------
    calib : Calibration with the geometry section.
    shape : (H, W) of the camera image the mask is for.
    half_width : px.

    Returns
    -------
    (H, W) bool
    """
    from ..planar import fold_segments_cam, projector_frame

    out = np.zeros(shape, bool)
    if calib.n_planes == 1:
        return out
    frame = projector_frame(calib.projector_size)
    lo_f, hi_f = frame[0], frame[2]
    segs = calib.layout.fold_segments(frame)
    segs_cam = fold_segments_cam(calib.projector_size, calib.H_cam_from_proj, calib.layout)
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    for j, (seg, ends) in enumerate(zip(segs, segs_cam, strict=True)):
        if seg is None:
            continue
        band = near_fold_mask(calib.folds_cam[j], shape, half_width)
        a, b, _ = np.asarray(calib.folds_cam[j], np.float64) / np.hypot(*calib.folds_cam[j][:2])
        d = np.array([-b, a])
        t_end = ends @ d
        # An end on the frame's border leaves the frame: the band goes on past it.
        border = np.any((np.abs(seg - lo_f) < 1e-6) | (np.abs(seg - hi_f) < 1e-6), axis=1)
        t = xs * d[0] + ys * d[1]
        for k, sign in ((int(np.argmin(t_end)), -1.0), (int(np.argmax(t_end)), 1.0)):
            if border[k]:
                continue
            past = sign * (t - t_end[k]) > 0
            band &= ~past | (np.hypot(xs - ends[k, 0], ys - ends[k, 1]) <= half_width)
        out |= band
    return out


def rect_mask(rect: tuple[int, int, int, int], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool mask of an OpenCV Rect ``(x, y, w, h)`` (clipped to the image)."""
    x, y, w, h = (int(v) for v in rect)
    m = np.zeros(shape, dtype=bool)
    m[max(0, y):max(0, y + h), max(0, x):max(0, x + w)] = True
    return m


def camera_view(procam, calib, frame: np.ndarray, sharp: bool = False) -> np.ndarray:
    """The camera's view of ``frame`` in ``calib``'s ideal camera pixels (the lens's distortion
    taken out, :func:`rtdefocus.calib.geometry.lens.ideal_view`), so the display rectangle and the fold
    band crop what they say. ``sharp`` is the simulator's option (no blur, no noise)."""
    from ..calib.geometry.lens import ideal_view

    view = procam.capture(frame, sharp=True) if sharp else procam.capture(frame)
    return ideal_view(calib, view)


def score_image(procam, calib, comps: dict, name: str, image: np.ndarray,
                fold_band_px: float = 24.0, headroom: tuple[float, float] | None = None
                ) -> tuple[ImageScores, dict[str, np.ndarray]]:
    """Project ``image`` every way on ``procam`` and score the camera views.

    With ``headroom`` (the compensators' own), geometry only and the sharp reference show the
    same reduced-contrast target the compensators solve for, so the scores say what
    compensation adds at that contrast.

    Returns the scores and the camera views ``{"no correction", "geometry only",
    "geometry + defocus", "sharp reference"}`` (the last three for the ``ycbcr`` method).
    """
    h, w = image.shape[:2]
    rect = calib.display_rect((w, h))
    wc, hc = calib.camera_size
    mask = rect_mask(rect, (hc, wc))
    band = mask & near_folds_mask(calib, (hc, wc), fold_band_px) if calib.n_planes > 1 else None
    geometry = next(iter(comps.values()))
    warped = geometry.warp(image)
    if headroom is not None:
        warped = encode_lut(decode_lut(warped, calib.lut, headroom), increasing_lut(calib.lut))
    reference = camera_view(procam, calib, warped, sharp=True)
    geometry_view = camera_view(procam, calib, warped)
    raw_view = camera_view(procam, calib,
                           cv2.resize(image, calib.projector_size, interpolation=cv2.INTER_AREA))
    scores = ImageScores(name)
    views = {"none": geometry_view}
    frames = {"none": warped}
    for method, comp in comps.items():
        t0 = time.perf_counter()
        frame = comp.compensate(image, warm_start=False)
        scores.seconds[method] = time.perf_counter() - t0
        frames[method] = frame
        views[method] = camera_view(procam, calib, frame)
    for method, view in views.items():
        scores.psnr[method] = psnr(view, reference, mask)
        scores.ssim[method] = ssim(view, reference, mask)
        if band is not None:
            scores.psnr_fold[method] = psnr(view, reference, band)
        scores.clipped[method] = float(np.mean((frames[method] == 0) | (frames[method] == 255)))
    ours = "ycbcr" if "ycbcr" in comps else next(iter(comps))
    pmask = np.ones(frames["none"].shape[:2], bool)
    scores.edges_input = {"geometry": edge_pixels(frames["none"], pmask),
                          "defocus": edge_pixels(frames[ours], pmask)}
    scores.edges_output = {"geometry": edge_pixels(views["none"], mask),
                           "defocus": edge_pixels(views[ours], mask)}
    shown = {"no correction": raw_view, "geometry only": geometry_view,
             "geometry + defocus": views[ours], "sharp reference": reference}
    return scores, shown


def coefficient_of_variation(view: np.ndarray, mask: np.ndarray) -> float:
    """Spatial coefficient of variation (std / mean) of the luma (mean of RGB) of ``view``
    ((H, W, 3)) over ``mask`` ((H, W) bool): how uniform a flat field looks."""
    lum = np.asarray(view, dtype=np.float64).mean(axis=2)[np.asarray(mask, dtype=bool)]
    return float(lum.std() / max(lum.mean(), 1e-12))


def psnr_affine(view: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB, range 1) of ``reference`` against ``α · view + β``, the one global gain and
    offset (shared by the channels) that fit it best in least squares over ``mask``: closeness
    up to brightness and black level (a picture on a dimmer, uniform wall scores as well as on a
    bright one). ``view``, ``reference``: (H, W, 3), uint8 (scaled to [0, 1]) or float."""
    m = np.asarray(mask, dtype=bool)

    def unit(a):
        a = np.asarray(a)
        return a.astype(np.float64) / (255.0 if a.dtype == np.uint8 else 1.0)

    v, r = unit(view)[m].ravel(), unit(reference)[m].ravel()
    X = np.stack([v, np.ones_like(v)], axis=1)
    coef, *_ = np.linalg.lstsq(X, r, rcond=None)
    mse = float(np.mean((X @ coef - r) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)
