"""Pictures of the PSF stage's result: the measured kernels and the blur-size map."""

from __future__ import annotations

import cv2
import numpy as np

from ...errors import CalibrationError, InputError
from ..file import Calibration
from .dots import equivalent_radius
from .sampling import fold_segments

__all__ = ["radius_map", "psf_diagnostics"]

# Background of each plane in the PSF panel: dark, apart enough to see the planes, and dim
# under the kernels' inferno colours (plane 0 grey, plane 1 blue-grey).
_PLANE_SHADES = np.array([[24, 24, 24], [40, 40, 56], [56, 36, 36], [32, 52, 36],
                          [52, 48, 24], [48, 28, 52], [24, 48, 52], [56, 56, 56]], np.uint8)


def radius_map(calib: Calibration) -> np.ndarray:
    """(Hp, Wp) float32 equivalent disc radius of every pixel's blended kernel (px).

    The second moment about the centre is linear in the kernel, so the blend's moment is the
    weighted sum of the measured PSFs' moments: r = sqrt(2 Σ_j w_j E_j[u² + v²]).
    """
    if calib.psfs is None:
        raise CalibrationError("this calibration has no PSF section; run the kernel stage")
    r2 = np.array([equivalent_radius(p) ** 2 for p in calib.psfs], np.float64)
    return np.sqrt((calib.pix_wts * r2[calib.pix_idx]).sum(axis=2)).astype(np.float32)


def psf_diagnostics(calib: Calibration, truth_radius: np.ndarray | None = None,
                    magnify: int = 2) -> np.ndarray:
    """A picture of the kernel field: the PSFs at their sample points, the blur-size map, and
    the true radius map (when simulated) on the same colour scale.

    Parameters
    ----------
    calib : Calibration with the psf section.
    truth_radius : (Hp, Wp) true blur radius (px), e.g. ``procam.truth.radius_map``; optional.
    magnify : zoom of each PSF drawn on the frame.

    Returns
    -------
    (H, W, 3) uint8 RGB: panels side by side, each the projector frame's size, labelled.
    """
    if calib.psfs is None:
        raise CalibrationError("this calibration has no PSF section; run the kernel stage")
    wp, hp = calib.projector_size
    # Panel 1: PSFs (each scaled to its own peak), magnified, over the plane map (each plane
    # its own dark shade).
    panel = np.full((hp, wp, 3), 24, np.uint8)
    if calib.n_planes > 1:
        panel[:] = _PLANE_SHADES[calib.plane_map() % len(_PLANE_SHADES)]
    k = calib.psfs.shape[1]
    for (x, y), psf in zip(calib.psf_points_proj, calib.psfs, strict=True):
        img = (255 * psf / max(float(psf.max()), 1e-12)).astype(np.uint8)
        img = cv2.resize(img, (k * magnify, k * magnify), interpolation=cv2.INTER_NEAREST)
        col = cv2.applyColorMap(img, cv2.COLORMAP_INFERNO)[..., ::-1]
        s = k * magnify
        x0, y0 = int(round(x)) - s // 2, int(round(y)) - s // 2
        xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + s, wp), min(y0 + s, hp)
        if xb > xa and yb > ya:
            sub = col[ya - y0:yb - y0, xa - x0:xb - x0]
            m = img[ya - y0:yb - y0, xa - x0:xb - x0] > 0
            panel[ya:yb, xa:xb][m] = sub[m]
        cv2.circle(panel, (int(round(x)), int(round(y))), 1, (0, 255, 0), -1)
    for seg in fold_segments(calib):
        if seg is not None:
            a, b = np.rint(seg).astype(int)
            cv2.line(panel, tuple(int(v) for v in a), tuple(int(v) for v in b), (0, 160, 255), 1)
    panels = [(panel, f"measured PSFs (x{magnify})")]
    est = radius_map(calib)
    lo = 0.0
    hi = float(max(est.max(), truth_radius.max() if truth_radius is not None else 0.0, 1e-6))

    def colour(r):
        u8 = np.clip(255 * (r - lo) / (hi - lo), 0, 255).astype(np.uint8)
        return np.ascontiguousarray(cv2.applyColorMap(u8, cv2.COLORMAP_VIRIDIS)[..., ::-1])

    panels.append((colour(est), f"estimated blur radius (0..{hi:.1f} px)"))
    if truth_radius is not None:
        truth_radius = np.asarray(truth_radius, np.float32)
        if truth_radius.shape != (hp, wp):
            raise InputError(f"truth_radius must be ({hp}, {wp}); got {truth_radius.shape}")
        panels.append((colour(truth_radius), "true blur radius"))
        err = np.abs(est - truth_radius)
        panels.append((colour(np.clip(err * (hi / max(1.0, 1e-6)), 0, hi)),
                       f"|error| (0..1 px), median {np.median(err):.2f}"))
    out = []
    for img, label in panels:
        img = img.copy()
        cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1,
                    cv2.LINE_AA)
        out.append(img)
        out.append(np.full((hp, 4, 3), 255, np.uint8))
    return np.concatenate(out[:-1], axis=1)
