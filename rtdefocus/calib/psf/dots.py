"""Steps 3-5 of the PSF stage: dot patterns, each dot's kernel solved in projector pixels,
cleaned and averaged along lines of equal blur (:func:`measure_psfs`; see
:mod:`rtdefocus.calib.psf`)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ...errors import CalibrationError, InputError
from ...planar import apply_h_per_plane
from ..capture import Capturer
from ..file import Calibration
from ..geometry.lens import ideal_points, lens_k, observed_points
from ..radiometry.stage import linearize_camera
from .pilot import support_bound

log = logging.getLogger(__name__)

__all__ = ["Measurement", "measure_psfs", "solve_dot", "pack_patterns", "dot_sizes",
           "camera_to_projector_maps", "equivalent_radius", "common_window", "iso_average"]

# Tight support of a measured kernel from its equivalent radius (disc: exact rim + AA pixels).
_TIGHT_A, _TIGHT_B = 1.15, 1.2
# dot_size="auto": side of the square dot by predicted radius — 1 px below _DOT2_RADIUS
# (bright enough, and exact: no deconvolution), 2 px below _DOT3_RADIUS, else 3 px.
_DOT2_RADIUS, _DOT3_RADIUS = 3.25, 7.0
# Ridge (relative to the mean diagonal of AᵀA) of the LS deconvolution of a dot larger than
# one pixel: the box's spectrum dips at high frequencies; this damps the noise there. Chosen
# on the simulator (noise 0.6 % of full scale, 19 averages): 0.05 halves the kernel error
# at r ≈ 5 px against a 1-px dot; 0.02..0.1 are within 10 % of each other.
_RIDGE_DECONV = 0.05
# 1-px dot: no deconvolution, but where the camera barely samples the projector's pixels (a
# camera of 4/3 the projector's size on a foreshortened wall) some kernel patterns (rows of
# + - + -) are seen by no camera pixel and the noise grew them without bound: at 1e-6 the
# fabric preset (dark partition, room light) failed at 240x180 and 400x300 with "no light
# within its support". 1e-2 tames them; with a 1.6x camera the kernels did not change
# (inside / near the fold: cubicle 800x600 0.080 / 0.116 both; webcam 320x240 0.073 / 0.071
# -> 0.073 / 0.067; fabric 400x300 0.065 / 0.138 -> 0.065 / 0.136), at 4/3: 0.133 / 0.209.
_RIDGE_EXACT = 1e-2
# A dot whose light (the kernel's sum) is below this many sigmas of a sum of noise over its LS
# disc is skipped (too faint to measure); filled from its neighbours by the PSF stage.
MIN_SNR = 3.0


def pack_patterns(points: np.ndarray, support: np.ndarray, window: np.ndarray) -> list[list[int]]:
    """Greedy packing of dots into patterns: in one pattern, no dot's light (within
    ``support``) reaches another dot's measuring window (half-size ``window``), Chebyshev."""
    order = np.argsort(-support, kind="stable")
    patterns: list[list[int]] = []
    for i in order:
        for pat in patterns:
            d = np.max(np.abs(points[pat] - points[i]), axis=1)
            if np.all((d > window[pat] + support[i] + 1) & (d > window[i] + support[pat] + 1)):
                pat.append(int(i))
                break
        else:
            patterns.append([int(i)])
    return patterns


def camera_to_projector_maps(calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Projector (x, y) of every (observed) camera pixel: undistorted by the lens, then
    through the homography of the wall it sees (its plane in ``calib.layout_cam``). Returns two
    (Hc, Wc) float64 arrays."""
    wc, hc = calib.camera_size
    ys, xs = np.mgrid[0:hc, 0:wc].astype(np.float64)
    if lens_k(calib) is not None:
        ideal = ideal_points(calib, np.stack([xs, ys], axis=-1))
        xs, ys = ideal[..., 0], ideal[..., 1]
    plane = calib.layout_cam.label(xs, ys).astype(int)
    if calib.residual_cam is not None:      # homography plus each plane's residual
        return calib.proj_from_cam(xs, ys, plane)
    return apply_h_per_plane(calib.H_proj_from_cam, plane, xs, ys)


def _camera_bbox(calib: Calibration, x: int, y: int, h: int) -> tuple[slice, slice] | None:
    wc, hc = calib.camera_size
    corners = np.array([[x - h - 1, y - h - 1, 1], [x + h + 1, y - h - 1, 1],
                        [x + h + 1, y + h + 1, 1], [x - h - 1, y + h + 1, 1]], np.float64)
    cam = []
    Hs = calib.H_cam_from_proj
    if calib.n_planes > 2:
        # Only the walls near the window: a far wall's plane, extended, may pass behind the camera.
        # (A plane meeting the square is within sqrt(2) half-sides of its nearest corner.)
        Hs = Hs[calib.layout.outside(corners[:, 0], corners[:, 1]).min(axis=1) <= 1.5 * (h + 1)]
    for H in Hs:  # both walls: a window near the fold may span the two
        q = corners @ H.T
        cam.append(q[:, :2] / q[:, 2:3])
    if calib.residual_cam is not None:
        # The corners' own plane's residual moves where they land (a few px).
        cam.append(calib.cam_from_proj(corners[:, 0], corners[:, 1]))
    # The window is small: its corners, seen through the lens, bound it (the margins below
    # cover the slight bend of its edges).
    cam = observed_points(calib, np.vstack(cam))
    x0, y0 = np.floor(cam.min(0)).astype(int) - 1
    x1, y1 = np.ceil(cam.max(0)).astype(int) + 2
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, wc), min(y1, hc)
    if x1 <= x0 or y1 <= y0:
        return None
    return slice(y0, y1), slice(x0, x1)


def solve_dot(img_cam: np.ndarray, cam_px: np.ndarray, cam_py: np.ndarray, x: int, y: int,
              h: int, support: float, bbox: tuple[slice, slice], dot: int = 1
              ) -> tuple[np.ndarray, float, int]:
    """Least-squares projector-pixel image of one dot (step 4 of the module docstring).

    Model per camera pixel c of the window: ``img(c) = Σ_n bil_n(c) g(n) + b0 + b1 du + b2 dv``
    where (du, dv) is c's projector position relative to the dot, n the 4 projector pixels
    around it, g = k ⊛ dot-box the dot's light on projector pixels, and the kernel k is
    unknown only within ``support`` px of the dot.

    Returns
    -------
    k : (2h+1, 2h+1) float64, the unnormalised kernel, ``k[h + v, h + u] = m(y + (u, v))``
    sigma : rms residual (camera-linear units), the noise level
    rows : camera pixels used
    """
    # scipy loads on first use (~1 s): `import rtdefocus.calib` (the player loads Calibration) stays fast.
    from scipy import sparse
    from scipy.sparse.linalg import spsolve

    sy, sx = bbox
    du = cam_px[sy, sx].ravel() - x
    dv = cam_py[sy, sx].ravel() - y
    b = img_cam[sy, sx].ravel().astype(np.float64)
    ok = (du >= -h) & (du < h) & (dv >= -h) & (dv < h) & np.isfinite(b)
    du, dv, b = du[ok], dv[ok], b[ok]
    n = 2 * h + 1
    vv, uu = np.mgrid[-h:h + 1, -h:h + 1]
    o0 = -(dot // 2)                                      # the dot covers y + o0 .. y + o0 + dot - 1
    offs = [(oy, ox) for oy in range(o0, o0 + dot) for ox in range(o0, o0 + dot)]
    inner = (uu ** 2 + vv ** 2 <= support ** 2)
    col = np.full(n * n, -1, int)
    col[inner.ravel()] = np.arange(int(inner.sum()))
    nk = int(inner.sum())
    fu, fv = np.floor(du), np.floor(dv)
    tu, tv = du - fu, dv - fv
    iu, iv = fu.astype(int) + h, fv.astype(int) + h
    rows, cols, vals = [], [], []
    ridx = np.arange(len(b))
    for (ju, jv, wgt) in ((0, 0, (1 - tu) * (1 - tv)), (1, 0, tu * (1 - tv)),
                          (0, 1, (1 - tu) * tv), (1, 1, tu * tv)):
        gu, gv = iu + ju, iv + jv                         # projector node of the light image g
        for oy, ox in offs:                               # g(n) = sum_o k(n - o)
            ku, kv = gu - ox, gv - oy
            inb = (ku >= 0) & (ku < n) & (kv >= 0) & (kv < n)
            c = np.full(len(b), -1)
            c[inb] = col[kv[inb] * n + ku[inb]]
            use = c >= 0
            rows.append(ridx[use])
            cols.append(c[use])
            vals.append(wgt[use])
    # Local affine background (ambient x albedo, projector black level): smooth at this scale.
    for j, v in enumerate((np.ones_like(du), du / h, dv / h)):
        rows.append(ridx)
        cols.append(np.full(len(b), nk + j))
        vals.append(v)
    A = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(len(b), nk + 3))
    AtA = (A.T @ A).tocsc()
    Atb = A.T @ b
    ridge = _RIDGE_EXACT if dot == 1 else _RIDGE_DECONV
    diag = AtA.diagonal()
    reg = np.zeros(nk + 3)
    reg[:nk] = ridge * max(float(diag[:nk].mean()), 1e-12)
    # Sparse: each kernel pixel couples only to its neighbours (and the 3 background terms).
    sol = spsolve(AtA + sparse.diags(reg, format="csc"), Atb)
    resid = b - A @ sol
    sigma = float(np.sqrt(np.mean(resid ** 2))) if len(b) > nk + 3 else float("nan")
    k = np.zeros(n * n)
    k[inner.ravel()] = sol[:nk]
    return k.reshape(n, n), sigma, int(len(b))


def equivalent_radius(psf: np.ndarray) -> float:
    """Equivalent disc radius sqrt(2 E[u² + v²]) of a kernel (about its centre pixel), in px."""
    k = psf.shape[0] // 2
    vv, uu = np.mgrid[-k:k + 1, -k:k + 1]
    s = float(psf.sum())
    if s <= 0:
        return 0.0
    m2 = float((psf * (uu ** 2 + vv ** 2)).sum()) / s
    return math.sqrt(max(2.0 * m2, 0.0))


def clean_kernel(k: np.ndarray, support: float, floor: float = 0.0) -> tuple[np.ndarray, float, float]:
    """Tight support from the kernel's own radius, zero what is below ``floor`` (negative
    noise always), unit sum (step 5). Returns (kernel, its equivalent radius, support)."""
    h = k.shape[0] // 2
    vv, uu = np.mgrid[-h:h + 1, -h:h + 1]
    rho2 = uu ** 2 + vv ** 2
    s = k.sum()
    if s <= 0:
        raise CalibrationError("a measured PSF has no light: the dot was not seen (occluded, "
                               "outside the camera view, or far too faint)")
    r = equivalent_radius(k)
    tight = min(_TIGHT_A * r + _TIGHT_B, support)
    out = np.where((rho2 <= tight ** 2) & (k > max(floor, 0.0)), k, 0.0)
    if out.sum() <= 0:
        raise CalibrationError("a measured PSF has no light within its support: the dot was "
                               "not seen (occluded, outside the camera view, or far too faint)")
    out /= out.sum()
    return out, equivalent_radius(out), tight


@dataclass
class Measurement:
    """Measured PSFs of a set of points, before cropping to a common window."""

    psfs: list          # per point, (2h+1, 2h+1) float64 unit sum, cleaned
    raw: list           # per point, the LS kernel / its energy: unclipped, zero-mean noise
    bound: np.ndarray   # the LS disc radius per point (px)
    radius: np.ndarray  # equivalent disc radius per PSF (px)
    support: np.ndarray  # tight support radius per PSF (px)
    sigma: np.ndarray   # LS residual rms per PSF (camera-linear)
    snr: np.ndarray     # kernel peak / noise of one kernel pixel (rough)
    dots: np.ndarray    # dot side (px) per point
    noise: np.ndarray   # rms noise of one pixel of the unit-sum kernel
    patterns: int
    averages: int
    captures: int
    skipped: np.ndarray | None = None   # (N,) bool: too faint to measure (a delta placeholder)


def dot_sizes(radius_pred: np.ndarray, dot_size: int | str = "auto") -> np.ndarray:
    """Side (px) of the square dot for each predicted blur radius (see ``_DOT2_RADIUS``)."""
    r = np.asarray(radius_pred, np.float64)
    if dot_size == "auto":
        return np.where(r < _DOT2_RADIUS, 1, np.where(r < _DOT3_RADIUS, 2, 3)).astype(int)
    if not isinstance(dot_size, (int, np.integer)) or dot_size < 1:
        raise InputError(f"dot_size must be 'auto' or a positive integer; got {dot_size!r}")
    return np.full(len(r), int(dot_size))


def dot_geometry(radius_pred: np.ndarray, dots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Light support and measuring-window half-size of each dot (px)."""
    sup = support_bound(radius_pred) + dots / 2.0
    return sup, np.ceil(sup).astype(int) + 3


def measure_psfs(calib: Calibration, capture: Capturer, points: np.ndarray,
                 radius_pred: np.ndarray, *, averages: int, camera_lut=1.0,
                 dot_size: int | str = "auto", normalise=None) -> Measurement:
    """Measure the PSF of a dot at each of ``points`` (N, 2) int (steps 3-5).

    Dots are packed into patterns (no two lights overlap a window), each pattern is averaged
    over ``averages`` captures, and each dot is solved by :func:`solve_dot` and cleaned.
    ``normalise`` (optional): frame codes -> the (Hc, Wc) image the dots are solved on
    (:func:`~rtdefocus.calib.psf.frame_normaliser`; NaN pixels are left out).
    """
    wp, hp = calib.projector_size
    points = np.asarray(points, int)
    dots = dot_sizes(radius_pred, dot_size)
    sup, win = dot_geometry(radius_pred, dots)
    patterns = pack_patterns(points, sup, win)
    cam_px, cam_py = camera_to_projector_maps(calib)
    psfs: list = [None] * len(points)
    raw: list = [None] * len(points)
    sigma = np.zeros(len(points))
    radius = np.zeros(len(points))
    tight = np.zeros(len(points))
    snr = np.zeros(len(points))
    noise = np.zeros(len(points))
    skipped = np.zeros(len(points), bool)
    for pat in patterns:
        pattern = np.zeros((hp, wp, 3), np.uint8)
        for i in pat:
            x, y = points[i]
            d = int(dots[i])
            o0 = -(d // 2)                 # as in solve_dot
            pattern[max(y + o0, 0):y + o0 + d, max(x + o0, 0):x + o0 + d] = 255
        frame = capture.mean(pattern, averages)
        # Sum of the three channels: ~sqrt(3) more signal-to-noise than one, same kernel
        # when the blur is achromatic (the stored F is one field for all channels anyway).
        img = linearize_camera(frame, camera_lut).sum(axis=2) if normalise is None else \
            normalise(frame)
        for i in pat:
            x, y = (int(v) for v in points[i])
            bbox = _camera_bbox(calib, x, y, int(win[i]))
            if bbox is None:
                raise CalibrationError(f"the PSF dot at projector pixel ({x}, {y}) falls outside "
                                       "the camera's view; aim the camera at the whole projection")
            k, sg, nrows = solve_dot(img, cam_px, cam_py, x, y, int(win[i]), float(sup[i]), bbox,
                                     int(dots[i]))
            if nrows < (2 * win[i] + 1) ** 2 // 2:
                log.warning("PSF at (%d, %d): only %d camera pixels see its window", x, y, nrows)
            energy = k.sum()
            try:
                psf, r, t = clean_kernel(k, float(sup[i]))
            except CalibrationError:
                psf = None
            # The dot's total light against the noise of a sum over the LS disc's pixels.
            n_disc = math.pi * float(sup[i]) ** 2
            peak_snr = float(energy) / max(sg * math.sqrt(n_disc), 1e-12)
            if psf is None or energy <= 0 or peak_snr < MIN_SNR:
                # Too faint to measure (a dark wall, strong ambient light): filled from its
                # neighbours later (PsfRun.fill), not fatal here.
                skipped[i] = True
                log.info("PSF at (%d, %d): too faint (energy %.4g, SNR %.1f); skipped",
                         x, y, energy, peak_snr)
                psf = np.zeros_like(k)
                psf[k.shape[0] // 2, k.shape[1] // 2] = 1.0
                psfs[i], raw[i] = psf, psf.copy()
                sigma[i], radius[i], tight[i], snr[i] = sg, 0.0, 1.0, peak_snr
                noise[i] = 1.0
                continue
            # Noise of the unit-sum kernel: the spread of what was fitted outside the kernel's
            # own support (true value 0) but inside the LS disc.
            hh = k.shape[0] // 2
            vv, uu = np.mgrid[-hh:hh + 1, -hh:hh + 1]
            rho = np.hypot(uu, vv)
            ring = (rho > t + 1) & (rho <= sup[i])
            noise[i] = float(np.sqrt(np.mean((k[ring] / energy) ** 2))) if ring.sum() >= 8 \
                else float(sg / max(energy, 1e-12))
            if t >= sup[i] - 0.5:
                log.warning("PSF at (%d, %d): blur radius %.1f px reaches the pilot's bound "
                            "%.1f px; the kernel may be cut (raise pilot_spacing)", x, y, r, sup[i])
            psfs[i] = psf
            raw[i] = k / energy
            sigma[i], radius[i], tight[i] = sg, r, t
            snr[i] = (psf.max() * energy) / max(sg, 1e-12)
    return Measurement(psfs=psfs, raw=raw, bound=sup, radius=radius, support=tight,
                       sigma=sigma, snr=snr, noise=noise, dots=dots, patterns=len(patterns),
                       averages=averages, captures=len(patterns) * averages, skipped=skipped)


def common_window(psfs: list, support: np.ndarray) -> np.ndarray:
    """Crop/pad every PSF to one odd size k = 2 ceil(max support) + 1 → (N, k, k) float32."""
    h = int(math.ceil(float(np.max(support))))
    k = 2 * h + 1
    out = np.zeros((len(psfs), k, k), np.float32)
    for i, p in enumerate(psfs):
        ph = p.shape[0] // 2
        m = min(h, ph)
        out[i, h - m:h + m + 1, h - m:h + m + 1] = p[ph - m:ph + m + 1, ph - m:ph + m + 1]
        out[i] /= out[i].sum()
    return out


def iso_average(psfs: np.ndarray, points: np.ndarray, regions: np.ndarray, radius: np.ndarray,
                noise: np.ndarray, tolerance: float = 0.15, distance: float = 160.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """Average each PSF with those of its region whose predicted blur radius is within
    ``tolerance`` px and which lie within ``distance`` px (inverse-noise-variance weights,
    tapered in radius difference and distance).

    On a plane the radius is affine, so its lines of equal blur are straight; for a thin lens
    the kernel there is the same, and averaging along them cuts the noise of the faint, wide
    kernels (where it dominates the error) without blurring the kernel's change with depth.
    ``distance`` bounds how far a lens's field-dependent shape may be smoothed.

    Returns the averaged (N, k, k) float32 PSFs and the effective number of PSFs averaged.
    """
    out = np.empty_like(psfs)
    n_eff = np.ones(len(psfs))
    inv = 1.0 / np.maximum(noise, 1e-12) ** 2
    for i in range(len(psfs)):
        dr = np.abs(radius - radius[i])
        d = np.hypot(*(points - points[i]).T.astype(np.float64))
        w = (regions == regions[i]) * np.clip(1 - (dr / max(tolerance, 1e-9)) ** 2, 0, None) * \
            np.clip(1 - (d / distance) ** 2, 0, None) * inv
        if tolerance <= 0:
            w = np.zeros(len(psfs))
        w[i] = inv[i]
        out[i] = np.tensordot(w / w.sum(), psfs, axes=1)
        n_eff[i] = w.sum() ** 2 / (w ** 2).sum()
    return out.astype(np.float32), n_eff
