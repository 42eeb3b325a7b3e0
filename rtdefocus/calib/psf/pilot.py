"""Step 1 of the PSF stage: the pilot capture and the blur-radius model it fits
(:func:`pilot_radius`, :class:`RadiusModel`; see :mod:`rtdefocus.calib.psf`)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ...errors import CalibrationError
from ..capture import Capturer
from ..file import Calibration
from ..radiometry.stage import linearize_camera, to_projector

log = logging.getLogger(__name__)

__all__ = ["FOLD", "fold_code", "RadiusModel", "pilot_radius", "support_bound"]

FOLD = -1          # psf_plane of a sample *on* the fold (paper layout), used by both planes


def fold_code(j) -> int:
    """psf_plane of a sample on fold ``j`` of the layout (paper layout; used by the fold's two
    planes): ``FOLD - j``, so the one fold of two planes is :data:`FOLD`. Its own inverse."""
    return FOLD - int(j)

# Support bound from a predicted radius r: the light of a dot stays within SUPPORT_A r + B px.
# Generous: the pilot is rough, and a hexagonal aperture's corners reach 1.1 r_eq.
_SUPPORT_A, _SUPPORT_B = 1.2, 2.5

# Pilot dots each plane should get: enough for an |affine| radius fit (6 unknowns' worth).
MIN_PILOT_DOTS = 6


@dataclass
class RadiusModel:
    """Predicted blur radius (projector px) from the pilot capture, per region.

    ``regions`` maps a region (plane index, or 0 for the whole frame) to a callable
    ``f(xy (M, 2)) -> (M,)``; ``points``/``radii`` are the pilot measurements; ``folds`` maps
    a fold's :func:`fold_code` to its two planes (default: planes 0 and 1, the one fold of two
    planes).
    """

    points: np.ndarray
    radii: np.ndarray
    regions: dict = field(default_factory=dict)
    kind: dict = field(default_factory=dict)
    coef: dict = field(default_factory=dict)     # (gx, gy, c) of the affine fits
    folds: dict = field(default_factory=dict)    # fold_code(j) -> (plane, plane)

    def fit(self, region: int, sel: np.ndarray | None = None, force_affine: bool = False) -> None:
        """Fit ``region`` from the pilot points ``sel`` (all when None)."""
        sel = slice(None) if sel is None else sel
        self.regions[region], self.kind[region], self.coef[region] = _fit_region(
            self.points[sel], self.radii[sel], force_affine)

    def __call__(self, xy: np.ndarray, region: int) -> np.ndarray:
        xy = np.atleast_2d(np.asarray(xy, np.float64))
        if region < 0:  # on a fold the radius is continuous: either side's value
            return np.maximum(*(self.regions[r](xy) for r in self.folds.get(region, (0, 1))))
        return np.maximum(self.regions[region](xy), 0.5)

    def signed(self, xy: np.ndarray, region: int) -> np.ndarray:
        """The radius with the sign of (1/D_focus − 1/D) where the fit knows it (|affine|
        fits): negative behind the focus. Kernels in front of and behind the focus need not
        match for a real lens, so they are never averaged together."""
        r = self(xy, region)
        if region >= 0 and self.kind.get(region) == "abs-affine":
            c = self.coef[region]
            r = r * np.where(np.atleast_2d(xy) @ c[:2] + c[2] < 0, -1.0, 1.0)
        return r


def _fit_region(pts: np.ndarray, r: np.ndarray, force_affine: bool = False):
    """Fit the blur radius over a region: r = A·f·|1/D_focus − 1/D| with 1/D affine on a
    plane, so r = |affine|. Tried in turn: affine (the wall does not cross the focus), |affine|
    (it does: r² is then a rank-1 quadratic, fitted and projected onto rank 1), and, when
    neither fits, piecewise-linear interpolation. ``force_affine`` skips the last two.

    Returns (f, kind, coef): f(xy (M, 2)) -> (M,); coef (gx, gy, c) of the affine part, so
    that lines of equal radius are ``gx x + gy y = const`` (None for piecewise-linear)."""
    # scipy loads on first use (~1 s): `import rtdefocus.calib` (the player loads Calibration) stays fast.
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    if len(r) == 0:
        raise CalibrationError("no pilot dot was measured on one of the planes; the plane is too "
                               "small or too dark — check the geometry calibration")
    if len(r) < 4:
        m = float(np.median(r))
        coef = np.array([0.0, 0.0, m])
        return (lambda xy: np.full(len(xy), m)), "constant", coef
    X = np.column_stack([pts, np.ones(len(pts))])
    coef, *_ = np.linalg.lstsq(X, r, rcond=None)
    resid = r - X @ coef
    tol = 0.3 + 0.05 * float(np.mean(r))
    if force_affine or np.sqrt(np.mean(resid ** 2)) <= tol:
        return (lambda xy: xy @ coef[:2] + coef[2]), "affine", coef
    if len(r) >= 6:
        # r² = (v · [x, y, 1])²: fit a full quadratic to r² (coordinates scaled for
        # conditioning), take the dominant eigenvector of its 3x3 form.
        sc = float(np.abs(pts).max()) or 1.0
        x, y = pts[:, 0] / sc, pts[:, 1] / sc
        Q6, *_ = np.linalg.lstsq(np.column_stack([x * x, y * y, np.ones_like(x), 2 * x * y,
                                                  2 * x, 2 * y]), r * r, rcond=None)
        Q = np.array([[Q6[0], Q6[3], Q6[4]], [Q6[3], Q6[1], Q6[5]], [Q6[4], Q6[5], Q6[2]]])
        lam, vec = np.linalg.eigh(Q)
        if lam[-1] > 0:
            v = vec[:, -1] * math.sqrt(lam[-1])
            abs_coef = np.array([v[0] / sc, v[1] / sc, v[2]])
            resid = r - np.abs(X @ abs_coef)
            if np.sqrt(np.mean(resid ** 2)) <= tol:
                return (lambda xy: np.abs(xy @ abs_coef[:2] + abs_coef[2])), "abs-affine", \
                    abs_coef
    lin = LinearNDInterpolator(pts, r)
    near = NearestNDInterpolator(pts, r)

    def f(xy):
        v = lin(xy)
        bad = ~np.isfinite(v)
        if bad.any():
            v[bad] = near(xy[bad])
        return v
    return f, "piecewise-linear", None


def _pilot_grid(wp: int, hp: int, spacing: int) -> np.ndarray:
    """(M, 2) int pilot dot centres every ``spacing`` px, the grid centred in the frame."""
    half = spacing // 2
    xs = np.arange(half, wp - half + 1, spacing)
    ys = np.arange(half, hp - half + 1, spacing)
    xs += (wp - 1 - xs[-1] - xs[0]) // 2       # centre the grid in the frame
    ys += (hp - 1 - ys[-1] - ys[0]) // 2
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()]).astype(int)


def pilot_radius(calib: Calibration, capture: Capturer, *, spacing: int = 100, dot: int = 3,
                 camera_lut=1.0, single_region: bool = False,
                 normalise=None) -> RadiusModel:
    """One capture of ``dot``×``dot`` squares every ``spacing`` px → a blur radius model.

    The radius of each spot comes from its second moment around its centroid, less the dot's
    and the camera resampling's own share: for a disc of radius r, E[u² + v²] = r² / 2.
    ``normalise`` (optional, :func:`~rtdefocus.calib.psf.frame_normaliser`) turns the frame
    into the dots' light relative to the white frame (NaN where unlit, read as 0 here).
    """
    # scipy loads on first use (~1 s): `import rtdefocus.calib` (the player loads Calibration) stays fast.
    from scipy import ndimage

    wp, hp = calib.projector_size
    spacing = int(max(24, min(spacing, wp // 3, hp // 3)))
    # A plane with fewer than MIN_PILOT_DOTS grid dots gets no radius gradient (a narrow side
    # wall of a U: one column of dots), and its kernels would then be sampled and averaged as if
    # its blur were constant. The grid is made finer until every plane has enough, down to
    # half the asked spacing (the window must still hold the blur).
    floor = max(24, spacing // 2)
    pts = _pilot_grid(wp, hp, spacing)
    while calib.n_planes > 1 and spacing > floor:
        counts = np.bincount(calib.plane_of(pts[:, 0], pts[:, 1]).astype(int),
                             minlength=calib.n_planes)
        if counts.min() >= MIN_PILOT_DOTS:
            break
        spacing = max(floor, int(spacing * 0.8))
        pts = _pilot_grid(wp, hp, spacing)
    half = spacing // 2
    pattern = np.zeros((hp, wp, 3), np.uint8)
    o = (dot - 1) // 2
    for x, y in pts:
        pattern[y - o:y - o + dot, x - o:x - o + dot] = 255
    if normalise is None:
        frame = linearize_camera(capture(pattern), camera_lut).sum(axis=2)
    else:
        frame = np.nan_to_num(normalise(capture(pattern)), nan=0.0)
    img, seen = to_projector(calib, frame)
    w = half - 2
    radii = np.full(len(pts), np.nan)
    # Variance added by the dot (box) and by resampling (projector->camera->projector bilinear).
    var_extra = 2 * (dot * dot - 1) / 12.0 + 0.6
    for i, (x, y) in enumerate(pts):
        win = img[y - w:y + w + 1, x - w:x + w + 1].astype(np.float64)
        if not seen[y - w:y + w + 1, x - w:x + w + 1].all():
            continue
        ring = np.concatenate([win[:3].ravel(), win[-3:].ravel(), win[3:-3, :3].ravel(),
                               win[3:-3, -3:].ravel()])
        bg = np.median(ring)
        noise = 1.4826 * np.median(np.abs(ring - bg)) + 1e-6
        s = win - bg
        sm = cv2.GaussianBlur(s.astype(np.float32), (0, 0), 1.0)
        c = slice(w // 2, w + w // 2 + 1)
        peak = float(sm[c, c].max())
        if peak < 4 * noise / 1.5:     # the smoothing lowers the noise by ~1.5x and more
            continue
        lab, _ = ndimage.label(sm > 0.15 * peak)
        iy, ix = np.unravel_index(int(np.argmax(np.where(lab > 0, sm, -np.inf)[c, c])),
                                  sm[c, c].shape)
        comp = lab == lab[iy + w // 2, ix + w // 2]
        comp = ndimage.binary_dilation(comp, iterations=2)
        m = np.where(comp, s, 0.0)
        m0 = m.sum()
        if m0 <= 0:
            continue
        vv, uu = np.mgrid[-w:w + 1, -w:w + 1]
        cu, cv = (m * uu).sum() / m0, (m * vv).sum() / m0
        var = (m * ((uu - cu) ** 2 + (vv - cv) ** 2)).sum() / m0
        radii[i] = math.sqrt(2.0 * max(var - var_extra, 0.1))
    ok = np.isfinite(radii)
    if ok.sum() < 3:
        raise CalibrationError(
            f"the pilot dots were seen at only {int(ok.sum())} of {len(pts)} places: the dots "
            "are too faint for the camera (raise exposure or gain) or the blur exceeds "
            f"{w} px (use a larger pilot_spacing)")
    if np.nanmax(radii) > 0.4 * w:
        log.warning("pilot: blur radius up to %.1f px is large for the pilot spacing %d px; "
                    "use a larger pilot_spacing", np.nanmax(radii), spacing)
    model = RadiusModel(points=pts[ok].astype(np.float64), radii=radii[ok])
    if single_region or calib.n_planes == 1:
        model.fit(0)
    else:
        plane = calib.plane_of(model.points[:, 0], model.points[:, 1])
        for p in range(calib.n_planes):
            model.fit(p, plane == p)
        model.folds = {fold_code(j): (int(a), int(b))
                       for j, (a, b) in enumerate(calib.layout.fold_planes)}
    log.info("pilot: %d/%d dots, radius %.2f..%.2f px, models %s", ok.sum(), len(pts),
             model.radii.min(), model.radii.max(), model.kind)
    return model


def support_bound(r: np.ndarray) -> np.ndarray:
    """Radius (px) that a dot's light stays within, given the predicted blur radius."""
    return _SUPPORT_A * np.asarray(r, np.float64) + _SUPPORT_B
