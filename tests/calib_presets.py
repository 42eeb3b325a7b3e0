"""Calibrations of the simulator presets, made once per test session and shared by
tests/test_radiometry.py and tests/test_psf.py (each costs ~70 simulated captures).

Each preset (camera noise on, projector gamma 2.2) is calibrated end to end with
``rd.calibrate`` (geometry, radiometry, default PSF layout), then the comparison layouts
(``paper`` and the geometry-blind ``cross_fold`` baseline) are measured on top of that
geometry with the same number of averages per pattern, so each PSF has the noise it would
have in a run of its own.
"""

from __future__ import annotations

import copy
import functools
import time
from dataclasses import dataclass, field

import numpy as np

PRESETS = ("cubicle", "tilted", "pillar")
GAMMA = 2.2
NEAR_FOLD = 12.0     # px: "near the fold" in the accuracy criteria


@dataclass
class Calibrated:
    procam: object
    calib: object                      # rd.calibrate(Blind(procam)), default layout
    variants: dict = field(default_factory=dict)   # (layout, cross_fold) -> Calibration
    seconds: float = 0.0


@functools.cache
def calibrated(preset: str) -> Calibrated:
    from helpers import Blind, blind_calibrate

    import rtdefocus as rd
    from rtdefocus.calib.capture import Capturer
    from rtdefocus.study.eval_layouts import calibrate_psf_layouts

    procam = rd.sim.VirtualProCam(preset, projector_gamma=GAMMA)
    t0 = time.perf_counter()
    calib = blind_calibrate(procam)
    blind = Blind(procam)
    variants = calibrate_psf_layouts(
        copy.deepcopy(calib), Capturer(blind),
        layouts=[("paper", False), ("default", True)], averages=calib.meta["psf"]["averages"])
    variants[("default", False)] = calib
    return Calibrated(procam, calib, variants, time.perf_counter() - t0)


def fold_distance(truth, xy: np.ndarray) -> np.ndarray:
    """|distance| (px) of projector points to the true fold (inf for a flat scene)."""
    if truth.fold_proj is None:
        return np.full(len(xy), np.inf)
    a, b, c = truth.fold_proj
    return np.abs(a * xy[:, 0] + b * xy[:, 1] + c)


@functools.cache
def eval_points(preset: str, n: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Integer projector pixels: ``n`` spread over the planes (farther than NEAR_FOLD from the
    fold, frame edges included) and ``n`` within NEAR_FOLD px of the fold, along its length."""
    truth = calibrated(preset).procam.truth
    hp, wp = truth.radius_map.shape
    rng = np.random.default_rng(7)
    xy = np.column_stack([rng.integers(0, wp, 4 * n), rng.integers(0, hp, 4 * n)])
    interior = xy[fold_distance(truth, xy) > NEAR_FOLD][:n]
    a, b, c = truth.fold_proj
    ys = rng.uniform(0, hp - 1, 4 * n)
    off = rng.uniform(-NEAR_FOLD, NEAR_FOLD, 4 * n)
    xs = (-c - b * ys) / a + off * a           # a point on the fold, moved along the normal
    ys = ys + off * b
    near = np.rint(np.column_stack([xs, ys])).astype(int)
    ok = (near[:, 0] >= 0) & (near[:, 0] < wp) & (near[:, 1] >= 0) & (near[:, 1] < hp)
    near = near[ok]
    near = near[fold_distance(truth, near.astype(float)) <= NEAR_FOLD][:n]
    return interior, near


def kernel_errors(calib, truth, pts: np.ndarray) -> np.ndarray:
    """Relative L2 error of ``calib.kernel_at`` against the true kernel (both unit sum, same
    window), per point."""
    out = np.empty(len(pts))
    for i, (x, y) in enumerate(pts):
        k = calib.kernel_at(x, y).astype(np.float64)
        kt = truth.kernel_at(x, y, size=k.shape[0]).astype(np.float64)
        out[i] = np.linalg.norm(k - kt) / np.linalg.norm(kt)
    return out


def truth_geometry(procam):
    """A geometry-only Calibration from the simulator's ground truth."""
    from rtdefocus.sim import oracle_calibration

    calib = oracle_calibration(procam)
    for name in ("response_lut", "ambient_proj", "albedo_proj", "psf_points_proj", "psf_plane",
                 "psfs", "pix_idx", "pix_wts"):
        setattr(calib, name, None)
    calib.meta = {}
    return calib
