"""The oracle calibration: a :class:`rtdefocus.Calibration` built from the simulator's ground
truth (tests and benchmarks only) — what a perfect calibration would measure, so that
compensation can be judged apart from calibration errors."""

from __future__ import annotations

import numpy as np

from ..calib.file import Calibration
from ..planar import PlaneLayout, lit_polygon
from .optics import RADIUS_STEP, blend_kernel


def oracle_calibration(procam):
    """A calibration built from a simulator's ground truth, reproducing its blur exactly.

    Geometry: the true homographies and folds (one fold line for two planes; every fold, with
    the planes on its sides, for three or more), and the lit outline from mapping the projector
    frame (cut at the folds) through them. Radiometry: the simulator's projector
    response ``(v/255)^gamma``, its albedo and ambient maps, and the camera's inverse
    response (``camera_lut``, as the radiometry stage measures it). Kernels: the simulator
    renders its blur on a grid of radii (:data:`~rtdefocus.sim.optics.RADIUS_STEP`), each
    pixel blending the two grid kernels that bracket its radius with tent weights; those grid
    kernels are the PSFs here and each pixel's two brackets and weights its ``pix_idx`` /
    ``pix_wts``, so ``F`` equals the simulator's own (green-channel) blur to float precision.

    Parameters
    ----------
    procam : rtdefocus.sim.VirtualProCam

    Returns
    -------
    rtdefocus.calib.file.Calibration
        With ``meta["source"] = "oracle"``.
    """
    truth = procam.truth
    wp, hp = procam.projector_size
    H = np.asarray(truth.H_cam_from_proj, dtype=np.float64)
    H_inv = np.stack([np.linalg.inv(h) for h in H])
    H_inv /= H_inv[:, 2:3, 2:3]
    if truth.n_planes > 2:
        # Every fold inside the frame, as the truth lists them (canonical, in plane-pair order).
        folds = {"folds_proj": np.asarray(truth.folds_proj, np.float64),
                 "folds_cam": np.asarray(truth.folds_cam, np.float64),
                 "fold_planes": np.asarray(truth.fold_planes, np.int32)}
        planes = PlaneLayout(truth.n_planes, folds["folds_proj"], folds["fold_planes"])
        make = Calibration
    else:
        # One fold at most, plane 0 on its negative side (the format-2 convention).
        if truth.fold_proj is None:
            fold_proj = fold_cam = np.zeros(3)
        else:
            fold_proj = np.asarray(truth.fold_proj, dtype=np.float64)
            fold_cam = np.asarray(truth.fold_cam, dtype=np.float64)
        folds, planes = {"fold_proj": fold_proj, "fold_cam": fold_cam}, fold_proj
        make = Calibration.with_fold
    polygon = lit_polygon((wp, hp), H, planes)

    # Radiometry: the simulator's projector response and its albedo/ambient maps.
    codes = np.arange(256, dtype=np.float64) / 255.0
    lut = np.tile(codes ** truth.projector_gamma, (3, 1)).astype(np.float32)

    # Kernels: the radius grid of the renderer.
    q = truth.radius_map.astype(np.float64) / RADIUS_STEP
    j0 = np.floor(q).astype(np.int64)
    t = (q - j0).astype(np.float32)
    jmin, jmax = int(j0.min()), int(j0.max()) + 1
    levels = np.arange(jmin, jmax + 1)
    full = blend_kernel(jmax * RADIUS_STEP, truth.aperture)   # the largest support
    k = full.shape[0]
    psfs = np.stack([blend_kernel(j * RADIUS_STEP, truth.aperture, size=k)
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
        labels = plane_map[use[i]]
        labels = labels[labels >= 0]        # -1: a far wall through a gap, no plane
        if labels.size:
            planes[i] = int(np.argmax(np.bincount(labels, minlength=2)))
            dist = np.where(plane_map == planes[i], np.abs(q - levels[i]), np.inf)
        else:                               # a radius only the far wall has
            planes[i] = 0
            dist = np.abs(q - levels[i])
        yy, xx = np.unravel_index(int(np.argmin(dist)), dist.shape)
        points[i] = (xx, yy)

    calib = make(
        projector_size=(wp, hp), camera_size=tuple(procam.camera_size),
        H_cam_from_proj=H, H_proj_from_cam=H_inv, **folds,
        lit_polygon_cam=np.asarray(polygon, dtype=np.float64),
        response_lut=lut, ambient_proj=truth.ambient_proj.astype(np.float32),
        camera_lut=np.tile(truth.camera_response, (3, 1)).astype(np.float32),
        albedo_proj=truth.albedo_proj.astype(np.float32),
        psf_points_proj=points, psf_plane=planes, psfs=psfs, pix_idx=idx, pix_wts=wts,
        meta={"source": "oracle", "preset": getattr(procam, "preset", None)},
    )
    # The truth's homographies, fold and outline are in ideal camera pixels: its lens goes with
    # them, as a calibrated one would.
    calib.camera_distortion = np.asarray(getattr(truth, "distortion", (0.0, 0.0)), np.float64)
    calib.validate()
    return calib
