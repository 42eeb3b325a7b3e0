"""Evaluation helpers: image scores, the near-fold band, and an oracle calibration.

* :func:`psnr`, :func:`ssim` — scores of a camera view against a reference, optionally inside a
  mask (e.g. the display rectangle, or the band around the fold);
* :func:`near_fold_mask` — the pixels within a distance of a fold line;
* :func:`oracle_calibration` — a :class:`rtdefocus.Calibration` built from the simulator's
  ground truth (tests and benchmarks only): what a perfect calibration would measure, so that
  compensation can be judged apart from calibration errors.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError

__all__ = ["psnr", "ssim", "near_fold_mask", "rect_mask", "oracle_calibration", "text_slide",
           "photographs"]


def text_slide(size: tuple[int, int] = (640, 480)) -> np.ndarray:
    """A slide of black text on white: (h, w, 3) uint8 for ``size = (w, h)``.

    Several lines of decreasing size (the smallest strokes are 1–2 px wide): the hardest case
    for compensation, with no room above white or below black to pre-sharpen into.
    """
    import cv2

    w, h = int(size[0]), int(size[1])
    img = np.full((h, w, 3), 255, np.uint8)
    # (text, stroke thickness at 640 px width); each line is scaled to span 88 % of the width,
    # so text crosses the middle of the frame (where a centred fold is).
    lines = [("Defocus compensation", 3), ("on a two-wall corner, sharp", 2),
             ("Projected text stays readable even", 2), ("where the two walls meet: edges, strokes,",
                                                          1),
             ("The quick brown fox jumps over the lazy dog 0123456789", 1),
             ("Pack my box with five dozen liquor jugs - 42", 1),
             ("Sphinx of black quartz, judge my vow! 1/2 3:4", 1)]
    font = cv2.FONT_HERSHEY_SIMPLEX
    y = 0.0
    for text, thick in lines:
        th = max(1, int(round(thick * w / 640.0)))
        (tw, tht), _ = cv2.getTextSize(text, font, 1.0, th)
        fs = 0.88 * w / tw
        y += 1.75 * tht * fs
        cv2.putText(img, text, (int(0.04 * w), int(y)), font, fs, (0, 0, 0), th, cv2.LINE_AA)
    return img


def photographs() -> dict[str, np.ndarray]:
    """The test photographs (scikit-image's chelsea, coffee, astronaut, rocket) as RGB uint8."""
    from skimage import data

    return {name: np.ascontiguousarray(getattr(data, name)())
            for name in ("chelsea", "coffee", "astronaut", "rocket")}


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
    from skimage.metrics import structural_similarity

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


def rect_mask(rect: tuple[int, int, int, int], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool mask of an OpenCV Rect ``(x, y, w, h)`` (clipped to the image)."""
    x, y, w, h = (int(v) for v in rect)
    m = np.zeros(shape, dtype=bool)
    m[max(0, y):max(0, y + h), max(0, x):max(0, x + w)] = True
    return m


def oracle_calibration(procam):
    """A calibration built from a simulator's ground truth, reproducing its blur exactly.

    Geometry: the true homographies and fold lines, and the lit outline from mapping the
    projector frame (cut at the fold) through them. Radiometry: the simulator's projector
    response ``(v/255)^gamma``, its albedo and ambient maps. Kernels: the simulator renders its
    blur on a grid of radii (``rtdefocus.sim.RADIUS_STEP``), each pixel blending the two grid
    kernels that bracket its radius with tent weights; those grid kernels are the PSFs here and
    each pixel's two brackets and weights its ``pix_idx`` / ``pix_wts``, so ``F`` equals the
    simulator's own (green-channel) blur to float precision.

    Parameters
    ----------
    procam : rtdefocus.sim.VirtualProCam

    Returns
    -------
    rtdefocus.calib.file.Calibration
        With ``meta["source"] = "oracle"``.
    """
    from . import sim
    from .calib.file import Calibration
    from .calib.geometry import lit_polygon

    truth = procam.truth
    wp, hp = procam.projector_size
    H = np.asarray(truth.H_cam_from_proj, dtype=np.float64)
    H_inv = np.stack([np.linalg.inv(h) for h in H])
    H_inv /= H_inv[:, 2:3, 2:3]
    if truth.fold_proj is None:
        fold_proj = fold_cam = np.zeros(3)
    else:
        fold_proj = np.asarray(truth.fold_proj, dtype=np.float64)
        fold_cam = np.asarray(truth.fold_cam, dtype=np.float64)
    polygon = lit_polygon((wp, hp), H, fold_proj)

    # Radiometry: the simulator's projector response and its albedo/ambient maps.
    codes = np.arange(256, dtype=np.float64) / 255.0
    lut = np.tile(codes ** truth.projector_gamma, (3, 1)).astype(np.float32)

    # Kernels: the radius grid of the renderer.
    q = truth.radius_map.astype(np.float64) / sim.RADIUS_STEP
    j0 = np.floor(q).astype(np.int64)
    t = (q - j0).astype(np.float32)
    jmin, jmax = int(j0.min()), int(j0.max()) + 1
    levels = np.arange(jmin, jmax + 1)
    full = sim.blend_kernel(jmax * sim.RADIUS_STEP, truth.aperture)   # the largest support
    k = full.shape[0]
    psfs = np.stack([sim.blend_kernel(j * sim.RADIUS_STEP, truth.aperture, size=k)
                     for j in levels]).astype(np.float32)
    idx = np.zeros((hp, wp, 4), np.int32)
    wts = np.zeros((hp, wp, 4), np.float32)
    idx[..., 0] = j0 - jmin
    idx[..., 1] = np.minimum(j0 + 1 - jmin, len(levels) - 1)
    wts[..., 0] = 1.0 - t
    wts[..., 1] = t
    # A representative point and plane per PSF: the pixel whose radius is nearest the level
    # among the pixels of the plane that uses it most.
    plane_map = truth.plane_map.astype(np.int64)
    points = np.zeros((len(levels), 2), np.float32)
    planes = np.zeros(len(levels), np.int32)
    use = np.abs(q[None] - levels[:, None, None]) < 1.0              # (L, Hp, Wp)
    for i in range(len(levels)):
        counts = np.bincount(plane_map[use[i]], minlength=2)
        planes[i] = int(np.argmax(counts))
        dist = np.where(plane_map == planes[i], np.abs(q - levels[i]), np.inf)
        yy, xx = np.unravel_index(int(np.argmin(dist)), dist.shape)
        points[i] = (xx, yy)

    calib = Calibration(
        projector_size=(wp, hp), camera_size=tuple(procam.camera_size),
        H_cam_from_proj=H, H_proj_from_cam=H_inv, fold_proj=fold_proj, fold_cam=fold_cam,
        lit_polygon_cam=np.asarray(polygon, dtype=np.float64),
        response_lut=lut, ambient_proj=truth.ambient_proj.astype(np.float32),
        albedo_proj=truth.albedo_proj.astype(np.float32),
        psf_points_proj=points, psf_plane=planes, psfs=psfs, pix_idx=idx, pix_wts=wts,
        meta={"source": "oracle", "preset": getattr(procam, "preset", None)},
    )
    calib.validate()
    return calib
