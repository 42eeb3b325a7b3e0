"""Defocus kernels: measured dot PSFs at a few sample points -> the kernel field F.

Gather form (DESIGN.md §3, docs/internals.md): pixel x's kernel is ``k_x = Σ_j w_j ψ_{s_j}``, a
blend of at most 4 measured PSFs of x's *own* plane. A dot at projector pixel y measures column
y of F, m(x) = k_x(x − y) ≈ k_y(x − y), so ``psf[k//2 + v, k//2 + u] = m(y + (u, v))``: a
shift, not a flip.

The stage, step by step (every step only calls ``capture``):

1. **Pilot** (1 capture): 3×3 squares on a coarse grid; their spread gives a blur radius per
   grid point, fitted per plane. For a thin lens r = A·f·|1/D_focus − 1/D| with 1/D affine on
   a plane, so r is affine on each wall (or |affine| where the wall crosses the focus), and its
   lines of equal blur are straight. The fit sets each dot's size and measuring window, the
   dot spacing, how far from the fold the fold samples go, and where samples are needed.
2. **Layout** (``layout``): ``"paper"`` — each plane's 4 corners (inset) plus 2 points on the
   fold, blended bilinearly as in the paper (§2.4); ``"default"`` — the plane's corners,
   points along the fold on *each* side just farther from it than the local blur (each dot
   lights one wall only, yet measures the kernel at the fold; the two sides are staggered so
   they share a pattern), and lines of equal predicted blur ``radius_step`` px of radius apart,
   each sampled every ``max_spacing`` px: blending two discs of different radii is a poor disc
   (Δr = 1 px gives ~15-20 % error mid-way), so the blur's own gradient sets the density;
   ``"dense"`` — a regular grid per plane. Samples that would share a dot's window with a
   corner or fold sample are dropped, so a layout fits in as few patterns as it can (one, on
   the presets). ``cross_fold=True`` is the geometry-blind baseline the paper argues against:
   the frame laid out as one plane (one affine radius fit) and blended across the fold; the
   measurement itself is the same for every layout.
3. **Dots** (a handful of captures): as many per pattern as fit with their light apart; each
   pattern is averaged over ``averages`` captures (the rest of the ``psf_captures`` budget).
   Where the predicted blur is small the dot is one projector pixel (bright enough, measured
   with no deconvolution, so the rim stays sharp); where it is wide a 1-px dot's light spreads
   over ~πr² pixels and drowns in camera noise, so the dot is 2×2 or 3×3 px and the box is
   deconvolved by the next step (with a small ridge) — on the simulator this halves the error
   of the faint, wide kernels and costs a little rim sharpness. The three camera channels are
   summed (one field serves all channels).
4. **Back to projector pixels, exactly**: the camera samples the projector-space light at each
   camera pixel's projector position (through the homography of the wall that camera pixel
   sees, so a dot on the fold is handled too), i.e. bilinearly between projector pixel
   centres. So each dot's kernel is the least-squares solution of ``camera = bilinear(kernel ⊛
   dot) + local affine background`` over the camera pixels of its window, the kernel unknown
   only inside a disc bounded by the pilot's radius (which suppresses the noise tails and
   needs no black frame: the background is fitted around each dot from the same averaged
   captures). With ~2.5 camera pixels per projector pixel this is well determined, sub-pixel,
   and energy-consistent (camera values are radiance).
5. **Averaging and clean-up**: each raw LS kernel (divided by its energy: the albedo is α's
   business) is averaged with its plane's kernels of the same predicted blur nearby
   (:func:`iso_average`): along a line of equal blur a thin lens's kernel is the same, so this
   cuts the noise where it dominates (wide, faint kernels, e.g. at a concave fold). Raw, so
   the zero-mean noise averages away. Then the averaged kernel's equivalent disc radius
   r = sqrt(2 E[u² + v²]) sets a tighter support (1.15 r + 1.2 px); outside it, and below 2
   noise sigmas (the noise ring around a wide kernel), the kernel is 0; the sum is normalised
   to 1. The common window k (odd) is set by the largest support.
6. **F**: per pixel, indices and weights of ≤ 4 PSFs of its plane — barycentric on a per-plane
   Delaunay triangulation (``default``, ``dense``; outside the samples' hull: the nearest hull
   edge, clamped) or bilinear on quads (``paper``). Never across the fold unless ``cross_fold``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import CalibrationError, InputError
from .capture import Capturer
from .file import Calibration
from .geometry import apply_h_per_plane
from .radiometry import linearize_camera, to_projector

log = logging.getLogger(__name__)

OPTIONS = ("layout", "fold_samples", "averages", "cross_fold", "radius_step", "max_spacing",
           "dense_spacing", "edge_inset", "psf_captures", "dot_size", "pilot_spacing",
           "iso_tolerance", "iso_distance")
LAYOUTS = ("default", "paper", "dense")
FOLD = -1          # psf_plane of a sample *on* the fold (paper layout), used by both planes

# Support bound from a predicted radius r: the light of a dot stays within SUPPORT_A r + B px.
# Generous: the pilot is rough, and a hexagonal aperture's corners reach 1.1 r_eq.
_SUPPORT_A, _SUPPORT_B = 1.2, 2.5
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
_RIDGE_EXACT = 1e-6    # 1-px dot: only guards kernel pixels that no camera pixel sees
# Kernel values below this many noise sigmas (of the averaged kernel) are set to 0: inside the
# support a wide kernel's plateau is several sigmas up, while the noise in the ring between its
# rim and the support bound would otherwise add mass (and inflate the radius by ~0.3 px).
# 2 sigmas: on the simulator 0, 1, 2 give interior errors 0.083, 0.081, 0.077 (cubicle).
_NOISE_FLOOR = 2.0


# =========================================================================== polygons, lines
def _clip(poly: np.ndarray, a: float, b: float, c: float) -> np.ndarray:
    """Sutherland-Hodgman: the part of a convex polygon (m, 2) where a x + b y + c <= 0."""
    out = []
    n = len(poly)
    for i in range(n):
        p, q = poly[i], poly[(i + 1) % n]
        fp, fq = a * p[0] + b * p[1] + c, a * q[0] + b * q[1] + c
        if fp <= 0:
            out.append(p)
        if (fp < 0 < fq) or (fq < 0 < fp):
            t = fp / (fp - fq)
            out.append(p + t * (q - p))
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def _rect(size: tuple[int, int], inset: float) -> np.ndarray:
    w, h = size
    e = float(inset)
    return np.array([[e, e], [w - 1 - e, e], [w - 1 - e, h - 1 - e], [e, h - 1 - e]], np.float64)


def _fold_sign(plane: int) -> float:
    """s such that s · fold(x) > 0 inside ``plane`` (plane 0 is where the fold line is negative)."""
    return -1.0 if plane == 0 else 1.0


def plane_polygon(calib: Calibration, plane: int, edge_inset: float = 0.0,
                  fold_inset: float = 0.0) -> np.ndarray:
    """Convex outline (m, 2) of ``plane`` in projector pixels, shrunk by ``edge_inset`` from the
    frame edges and by ``fold_inset`` from the fold. Empty (0, 2) when nothing is left."""
    poly = _rect(calib.projector_size, edge_inset)
    if calib.n_planes == 2:
        a, b, c = calib.fold_proj
        s = _fold_sign(plane)
        poly = _clip(poly, -s * a, -s * b, -s * c + fold_inset)
    return poly


def fold_segment(calib: Calibration, inset: float = 0.0) -> np.ndarray | None:
    """End points (2, 2) of the fold line inside the frame shrunk by ``inset``; None if absent."""
    if calib.n_planes != 2:
        return None
    a, b, c = calib.fold_proj
    p0 = -c * np.array([a, b])
    d = np.array([-b, a])
    wp, hp = calib.projector_size
    lo, hi = -np.inf, np.inf
    for k, (vmin, vmax) in enumerate(((inset, wp - 1 - inset), (inset, hp - 1 - inset))):
        if abs(d[k]) < 1e-12:
            if not vmin <= p0[k] <= vmax:
                return None
            continue
        t1, t2 = (vmin - p0[k]) / d[k], (vmax - p0[k]) / d[k]
        lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
    if not lo < hi:
        return None
    return np.stack([p0 + lo * d, p0 + hi * d])


def _inward(calib: Calibration, plane: int) -> np.ndarray:
    a, b, _ = calib.fold_proj
    return _fold_sign(plane) * np.array([a, b], np.float64)


def _fold_dist(calib: Calibration, pts: np.ndarray, plane: int) -> np.ndarray:
    """Signed distance of points into ``plane`` from the fold (positive inside)."""
    a, b, c = calib.fold_proj
    return _fold_sign(plane) * (pts[:, 0] * a + pts[:, 1] * b + c)


# =========================================================================== pilot: blur size
@dataclass
class RadiusModel:
    """Predicted blur radius (projector px) from the pilot capture, per region.

    ``regions`` maps a region (plane index, or 0 for the whole frame) to a callable
    ``f(xy (M, 2)) -> (M,)``; ``points``/``radii`` are the pilot measurements.
    """

    points: np.ndarray
    radii: np.ndarray
    regions: dict = field(default_factory=dict)
    kind: dict = field(default_factory=dict)
    coef: dict = field(default_factory=dict)     # (gx, gy, c) of the affine fits

    def fit(self, region: int, sel: np.ndarray | None = None, force_affine: bool = False) -> None:
        """Fit ``region`` from the pilot points ``sel`` (all when None)."""
        sel = slice(None) if sel is None else sel
        self.regions[region], self.kind[region], self.coef[region] = _fit_region(
            self.points[sel], self.radii[sel], force_affine)

    def __call__(self, xy: np.ndarray, region: int) -> np.ndarray:
        xy = np.atleast_2d(np.asarray(xy, np.float64))
        if region == FOLD:  # on the fold the radius is continuous: either side's value
            return np.maximum(*(self.regions[r](xy) for r in (0, 1)))
        return np.maximum(self.regions[region](xy), 0.5)

    def signed(self, xy: np.ndarray, region: int) -> np.ndarray:
        """The radius with the sign of (1/D_focus − 1/D) where the fit knows it (|affine|
        fits): negative behind the focus. Kernels in front of and behind the focus need not
        match for a real lens, so they are never averaged together."""
        r = self(xy, region)
        if region != FOLD and self.kind.get(region) == "abs-affine":
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


def pilot_radius(calib: Calibration, capture: Capturer, *, spacing: int = 100, dot: int = 3,
                 camera_gamma: float = 1.0, single_region: bool = False) -> RadiusModel:
    """One capture of ``dot``×``dot`` squares every ``spacing`` px → a blur radius model.

    The radius of each spot comes from its second moment around its centroid, less the dot's
    and the camera resampling's own share: for a disc of radius r, E[u² + v²] = r² / 2.
    """
    import cv2
    from scipy import ndimage

    wp, hp = calib.projector_size
    spacing = int(max(24, min(spacing, wp // 3, hp // 3)))
    half = spacing // 2
    xs = np.arange(half, wp - half + 1, spacing)
    ys = np.arange(half, hp - half + 1, spacing)
    xs += (wp - 1 - xs[-1] - xs[0]) // 2       # centre the grid in the frame
    ys += (hp - 1 - ys[-1] - ys[0]) // 2
    gx, gy = np.meshgrid(xs, ys)
    pts = np.column_stack([gx.ravel(), gy.ravel()]).astype(int)
    pattern = np.zeros((hp, wp, 3), np.uint8)
    o = (dot - 1) // 2
    for x, y in pts:
        pattern[y - o:y - o + dot, x - o:x - o + dot] = 255
    frame = linearize_camera(capture(pattern), camera_gamma).sum(axis=2)
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
        for p in range(2):
            model.fit(p, plane == p)
    log.info("pilot: %d/%d dots, radius %.2f..%.2f px, models %s", ok.sum(), len(pts),
             model.radii.min(), model.radii.max(), model.kind)
    return model


def support_bound(r: np.ndarray) -> np.ndarray:
    """Radius (px) that a dot's light stays within, given the predicted blur radius."""
    return _SUPPORT_A * np.asarray(r, np.float64) + _SUPPORT_B


# =========================================================================== layouts
@dataclass
class SamplePlan:
    """Where to measure PSFs and how to blend them.

    points : (N, 2) int projector pixels; planes : (N,) int (0/1, ``FOLD`` = on the fold,
    0 for every sample when ``cross_fold``); kinds : (N,) str; radius : (N,) float, pilot
    prediction; quads : for ``paper``, per region a list of 4-index quads (cyclic order) used
    for bilinear blending, each with the half-plane it serves; metric : per region a 2×2
    matrix M, the triangulation is made of the points M x (default layout: stretched along the
    blur gradient, so triangles join neighbouring lines of equal blur, not far ones).
    """

    layout: str
    cross_fold: bool
    points: np.ndarray
    planes: np.ndarray
    kinds: np.ndarray
    radius: np.ndarray
    radius_signed: np.ndarray | None = None
    quads: dict = field(default_factory=dict)
    metric: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)


def _snap(pts: np.ndarray, size) -> np.ndarray:
    wp, hp = size
    p = np.rint(pts).astype(int)
    p[:, 0] = np.clip(p[:, 0], 0, wp - 1)
    p[:, 1] = np.clip(p[:, 1], 0, hp - 1)
    return p


def _dedupe(pts: np.ndarray, kinds: list, min_dist: float) -> tuple[np.ndarray, list]:
    keep_p, keep_k = [], []
    for p, k in zip(pts, kinds, strict=True):
        if keep_p and np.min(np.hypot(*(np.array(keep_p) - p).T)) < min_dist:
            continue
        keep_p.append(p)
        keep_k.append(k)
    return np.array(keep_p, int).reshape(-1, 2), keep_k


def _along(a: np.ndarray, b: np.ndarray, spacing: float, include_ends=True) -> np.ndarray:
    n = max(1, int(math.ceil(np.hypot(*(b - a)) / spacing)))
    t = np.linspace(0, 1, n + 1)
    if not include_ends:
        t = t[1:-1]
    return a + t[:, None] * (b - a)


def pack_distance(r: np.ndarray, dot_size: int | str = "auto") -> np.ndarray:
    """Smallest Chebyshev distance (px) of two dots of predicted radius r in one pattern."""
    r = np.asarray(r, np.float64)
    sup, win = _dot_geometry(r, dot_sizes(r, dot_size))
    return win + sup + 1


def _fold_offset(model: RadiusModel, feet: np.ndarray, plane: int) -> np.ndarray:
    """How far from the fold a fold-side dot goes: just farther than the local blur (from the
    pilot, with a margin for its error and the pixel snap), so that its light stays on its
    own plane. Pixels between these samples and the fold take the nearest fold-side kernel;
    the radius changes by (slope × offset) over that strip, ~0.05 px on the simulator."""
    return np.ceil(1.1 * model(feet, plane) + 2.0)


def _thin(pts: np.ndarray, rank: np.ndarray, radius: np.ndarray, dot_size) -> np.ndarray:
    """Keep-mask of the samples: a sample is dropped when it would share a dot's window with a
    kept sample of a more important kind (lower ``rank``: corners, then fold samples) — it is
    redundant with it, and the set then fits in fewer patterns. Samples of the same kind are
    never dropped for each other (a steep blur gradient may need a second pattern)."""
    pd = pack_distance(radius, dot_size)
    keep = np.zeros(len(pts), bool)
    for i in np.argsort(rank, kind="stable"):
        k = np.flatnonzero(keep & (rank < rank[i]))
        if len(k):
            d = np.max(np.abs(pts[k] - pts[i]), axis=1)
            if np.any(d < np.maximum(pd[k], pd[i])):
                continue
        keep[i] = True
    return keep


def _fold_samples(calib: Calibration, model: RadiusModel, plane: int, count: int | None,
                  spacing: float, edge_inset: float) -> np.ndarray:
    """Samples along the fold on ``plane``'s side. The two planes' samples are staggered by
    half a step along the fold, so that both sides fit in one pattern although each is only
    just farther from the fold than the blur."""
    seg = fold_segment(calib, inset=edge_inset)
    if seg is None:
        return np.zeros((0, 2))
    length = float(np.hypot(*(seg[1] - seg[0])))
    n = count if count is not None else max(2, int(math.ceil(length / spacing)) + 1)
    t = np.linspace(0, 1, n) if plane == 0 else (np.arange(n - 1) + 0.5) / (n - 1)
    feet = seg[0] + t[:, None] * (seg[1] - seg[0])
    d = _fold_offset(model, feet, plane)
    pts = feet + d[:, None] * _inward(calib, plane)
    # Keep them inside the frame: shift along the fold if the offset pushed them out.
    wp, hp = calib.projector_size
    lo, hi = np.array([edge_inset, edge_inset]), np.array([wp - 1 - edge_inset, hp - 1 - edge_inset])
    ok = np.all((pts >= lo) & (pts <= hi), axis=1)
    return pts[ok]


def _iso_stretch(poly: np.ndarray, coef: np.ndarray, radius_step: float,
                 max_spacing: float) -> np.ndarray:
    """2×2 metric that makes the iso-grid's cells square: stretch along the blur gradient by
    (spacing along lines / spacing between lines). Barycentric weights are affine-invariant,
    so this only changes *which* triangles are formed."""
    g = np.asarray(coef[:2], np.float64)
    gn = float(np.hypot(*g))
    if gn < 1e-9:
        return np.eye(2)
    ghat = g / gn
    t = poly @ ghat
    span = float(t.max() - t.min())
    n = max(1, int(math.ceil(gn * span / radius_step)), int(math.ceil(span / max_spacing)))
    stretch = float(np.clip(max_spacing / (span / n), 1.0, 8.0))
    return np.eye(2) + (stretch - 1.0) * np.outer(ghat, ghat)


def _iso_grid(poly: np.ndarray, coef: np.ndarray, radius_step: float, max_spacing: float
              ) -> np.ndarray:
    """Samples on lines of equal predicted radius (r = gx x + gy y + c), ``radius_step`` apart
    in radius (and at most ``max_spacing`` apart), each line sampled every ``max_spacing``
    at common positions so neighbouring lines form near-rectangular cells; clipped to the
    convex ``poly`` whose outline (chord ends) they also cover."""
    g = np.asarray(coef[:2], np.float64)
    gn = float(np.hypot(*g))
    ghat = g / gn if gn > 1e-9 else np.array([1.0, 0.0])
    ehat = np.array([-ghat[1], ghat[0]])
    t, sv = poly @ ghat, poly @ ehat
    span = float(t.max() - t.min())
    n = max(1, int(math.ceil(gn * span / radius_step)), int(math.ceil(span / max_spacing)))
    s_span = float(sv.max() - sv.min())
    m = max(1, int(math.ceil(s_span / max_spacing)))
    s_grid = sv.min() + np.linspace(0, 1, m + 1) * s_span
    out = []
    for ti in t.min() + np.linspace(0, 1, n + 1) * span:
        # The chord of the convex polygon on the line ghat . x = ti.
        chord = _clip(_clip(poly, ghat[0], ghat[1], -ti - 1e-6), -ghat[0], -ghat[1], ti - 1e-6)
        if len(chord) == 0:
            continue
        cs = chord @ ehat
        lo, hi = float(cs.min()), float(cs.max())
        step = s_span / m          # grid points closer than half a step to a chord end go
        ss = np.concatenate([[lo], s_grid[(s_grid > lo + 0.5 * step) &
                                          (s_grid < hi - 0.5 * step)], [hi]])
        out.append(ti * ghat + ss[:, None] * ehat)
    return np.vstack(out) if out else np.zeros((0, 2))


def _refine(pts: np.ndarray, kinds: list, rfun, radius_step: float, max_spacing: float,
            max_points: int) -> tuple[np.ndarray, list]:
    """Longest-edge bisection of the Delaunay triangulation until, in every triangle, the
    predicted radius varies by <= radius_step (checked at vertices and edge midpoints) and no
    edge is longer than max_spacing."""
    from scipy.spatial import Delaunay

    pts = pts.astype(np.float64)
    for _ in range(40):
        if len(pts) >= max_points or len(pts) < 3:
            break
        tri = Delaunay(pts)
        S = tri.simplices
        P = pts[S]                                               # (T, 3, 2)
        r = rfun(P.reshape(-1, 2)).reshape(-1, 3)
        e_idx = np.array([[0, 1], [1, 2], [2, 0]])
        A, B = P[:, e_idx[:, 0]], P[:, e_idx[:, 1]]              # (T, 3, 2)
        L = np.hypot(*(B - A).transpose(2, 0, 1))                # (T, 3)
        M = (A + B) / 2
        rm = rfun(M.reshape(-1, 2)).reshape(-1, 3)
        dr = np.abs(r[:, e_idx[:, 0]] - r[:, e_idx[:, 1]])
        # An edge is split where the radius changes too much along it, or bends (a wall
        # crossing the focus), or where it is too long; the radius criterion splits the edge
        # that changes most, so triangles may stay long along lines of equal blur.
        lin_err = np.abs(rm - (r[:, e_idx[:, 0]] + r[:, e_idx[:, 1]]) / 2)
        score = np.maximum(dr / radius_step, 2 * lin_err / radius_step)
        split_r = (score.max(1) > 1) & (L[np.arange(len(L)), score.argmax(1)] > 6.0)
        split_l = ~split_r & (L.max(1) > max_spacing)
        if not (split_r.any() or split_l.any()):
            break
        which = np.where(split_r, score.argmax(1), L.argmax(1))
        bad = split_r | split_l
        new = M[np.flatnonzero(bad), which[bad]]
        new = np.unique(np.rint(new), axis=0)
        d = np.min(np.hypot(new[:, None, 0] - pts[None, :, 0], new[:, None, 1] - pts[None, :, 1]),
                   axis=1)
        new = new[d >= 3.0]
        if len(new) == 0:
            break
        new = new[: max_points - len(pts)]
        pts = np.vstack([pts, new])
        kinds = kinds + ["refine"] * len(new)
    return pts, kinds


def plan_samples(calib: Calibration, model: RadiusModel, layout: str = "default", *,
                 cross_fold: bool = False, fold_samples: int | None = None,
                 radius_step: float = 0.5, max_spacing: float = 150.0, dense_spacing: float = 50.0,
                 edge_inset: float = 2.0, max_points: int = 150,
                 dot_size: int | str = "auto") -> SamplePlan:
    """Choose the PSF sample points of a layout (see the module docstring).

    Parameters
    ----------
    calib : Calibration with the geometry section.
    model : RadiusModel from :func:`pilot_radius` (fitted per plane, or as one region when
        ``cross_fold``).
    layout : ``"default"`` | ``"paper"`` | ``"dense"``.
    cross_fold : lay out and blend over the whole frame as one region (ignore the planes).
    fold_samples : samples along the fold per side (default: one every ``max_spacing / 2``).
    radius_step : default layout: predicted radius step between lines of equal blur (px).
    max_spacing : default layout: largest spacing along and across those lines (px).
    dense_spacing : dense layout: grid step (px).
    edge_inset : distance of the samples from the frame edges (px).
    max_points : cap on the samples per region (refinement of a non-affine radius only).
    dot_size : as in :func:`calibrate_psf` (sets how close dots may be in one pattern).

    Samples closer than two dots may be in one pattern are thinned out (corners first, then
    fold samples, then the rest), so that a layout fits in as few patterns as possible.
    """
    if layout not in LAYOUTS:
        raise InputError(f"layout must be one of {LAYOUTS}; got {layout!r}")
    size = calib.projector_size
    one_region = cross_fold or calib.n_planes == 1
    regions = [0] if one_region else [0, 1]
    all_pts, all_planes, all_kinds = [], [], []
    metric: dict = {}

    fold_pts_paper = None
    if layout == "paper" and not one_region:
        seg = fold_segment(calib, inset=edge_inset)
        if seg is None:
            raise CalibrationError("the fold does not cross the projector frame; calibrate the "
                                   "geometry again or use a single plane")
        fold_pts_paper = _snap(seg, size)

    for p in regions:
        if one_region:
            poly = _rect(size, edge_inset)
            def rfun(xy):
                return model(xy, 0)
        else:
            seg = fold_segment(calib, inset=edge_inset)
            feet = seg if seg is not None else np.zeros((0, 2))
            d_max = 0.0
            if len(feet):
                pd = float(pack_distance(model(feet, p), dot_size).max())
                # Corners: the two planes' fold-side corners face each other across the fold;
                # half a dot spacing each keeps them in one pattern. The paper's corners keep
                # a full spacing from its fold points.
                d_max = pd + 2 if layout == "paper" else max(
                    float(_fold_offset(model, feet, p).max()), math.ceil(pd / 2) + 1)
            poly = plane_polygon(calib, p, edge_inset, d_max)
            def rfun(xy, p=p):
                return model(xy, p)
        if len(poly) < 3:
            raise CalibrationError(f"plane {p} leaves no room for PSF samples after insetting "
                                   "from the frame and the fold; is the fold near the frame edge?")
        kinds: list[str]
        if layout == "paper":
            pts = poly.copy()
            kinds = ["corner"] * len(pts)
        elif layout == "dense":
            wp, hp = size
            gx = np.arange(edge_inset, wp - edge_inset, dense_spacing)
            gy = np.arange(edge_inset, hp - edge_inset, dense_spacing)
            gx += (wp - 1 - edge_inset - gx[-1]) / 2 - (gx[0] - edge_inset) / 2
            gy += (hp - 1 - edge_inset - gy[-1]) / 2 - (gy[0] - edge_inset) / 2
            G = np.array(np.meshgrid(gx, gy)).reshape(2, -1).T
            inside = np.ones(len(G), bool)
            for i in range(len(poly)):        # inside the convex (inset) polygon
                a, b = poly[i], poly[(i + 1) % len(poly)]
                inside &= ((b[0] - a[0]) * (G[:, 1] - a[1]) - (b[1] - a[1]) * (G[:, 0] - a[0])) \
                    >= -1e-9 * _orient(poly)
            pts = np.vstack([poly, G[inside]])
            kinds = ["corner"] * len(poly) + ["grid"] * int(inside.sum())
        else:  # default
            base = [poly]
            kinds = ["corner"] * len(poly)
            if not one_region:
                fs = _fold_samples(calib, model, p, fold_samples, max_spacing / 2, edge_inset)
                base.append(fs)
                kinds += ["fold-side"] * len(fs)
            reg = 0 if one_region else p
            if model.kind.get(reg) in ("affine", "abs-affine", "constant"):
                grid = _iso_grid(poly, model.coef[reg], radius_step, max_spacing)
                metric[p] = _iso_stretch(poly, model.coef[reg], radius_step, max_spacing)
                base.append(grid)
                kinds += ["grid"] * len(grid)
                pts = np.vstack(base)
            else:  # radius not affine: refine a triangulation where it varies
                for i in range(len(poly)):
                    mid = _along(poly[i], poly[(i + 1) % len(poly)], max_spacing, False)
                    base.append(mid)
                    kinds += ["edge"] * len(mid)
                pts, kinds = _refine(np.vstack(base), kinds, rfun, radius_step, max_spacing,
                                     max_points)
        pts_i, kinds = _dedupe(_snap(pts, size), list(kinds), 3.0)
        all_pts.append(pts_i)
        all_planes.append(np.full(len(pts_i), p, int))
        all_kinds += kinds

    points = np.vstack(all_pts)
    planes = np.concatenate(all_planes)
    kinds_arr = np.array(all_kinds)
    if layout != "paper":
        # Thin across both planes, most important kinds first.
        radius = np.array([model(pt[None].astype(np.float64), 0 if one_region else int(pl))[0]
                           for pt, pl in zip(points, planes, strict=True)])
        rank = np.array([{"corner": 0, "fold-side": 1}.get(k, 2) for k in kinds_arr])
        keep = _thin(points, rank, radius, dot_size)
        points, planes, kinds_arr = points[keep], planes[keep], kinds_arr[keep]
    if fold_pts_paper is not None:
        points = np.vstack([points, fold_pts_paper])
        planes = np.concatenate([planes, [FOLD, FOLD]])
        kinds_arr = np.concatenate([kinds_arr, ["fold", "fold"]])
    radius = np.empty(len(points))
    signed = np.empty(len(points))
    for p in np.unique(planes):
        sel = planes == p
        radius[sel] = model(points[sel].astype(np.float64), 0 if one_region else int(p))
        signed[sel] = model.signed(points[sel].astype(np.float64), 0 if one_region else int(p))
    plan = SamplePlan(layout=layout, cross_fold=cross_fold, points=points.astype(np.int32),
                      planes=planes.astype(np.int32), kinds=kinds_arr, radius=radius,
                      radius_signed=signed,
                      metric=metric)
    if layout == "paper":
        plan.quads = _paper_quads(calib, plan, one_region)
    return plan


def _orient(poly: np.ndarray) -> float:
    """+1 for a counter-clockwise polygon in (x, y) (shoelace sign), -1 for clockwise."""
    x, y = poly[:, 0], poly[:, 1]
    return 1.0 if (x * np.roll(y, -1) - np.roll(x, -1) * y).sum() >= 0 else -1.0


def _paper_quads(calib: Calibration, plan: SamplePlan, one_region: bool) -> dict:
    """Bilinear quads of the paper layout: per plane its corner quad and, between the quad's
    fold-side edge and the fold, a strip quad closed by the two fold points."""
    quads: dict = {}
    regions = [0] if one_region else [0, 1]
    fold_idx = np.flatnonzero(plan.planes == FOLD)
    for p in regions:
        idx = np.flatnonzero(plan.planes == p)
        if len(idx) != 4:
            log.warning("paper layout: plane %d is not a quadrilateral (%d corners); its "
                        "kernels are blended on triangles instead", p, len(idx))
            continue
        quads[p] = [("main", idx.tolist())]
        if one_region or len(fold_idx) != 2:
            continue
        pts = plan.points.astype(np.float64)
        dist = _fold_dist(calib, pts[idx], p)
        near = idx[np.argsort(dist)[:2]]                   # the two fold-side corners
        # Order the strip quad cyclically: corner A, corner B, fold point near B, near A.
        fa = fold_idx[np.argmin(np.hypot(*(pts[fold_idx] - pts[near[0]]).T))]
        fb = fold_idx[fold_idx != fa][0]
        quads[p].append(("strip", [int(near[0]), int(near[1]), int(fb), int(fa)]))
    return quads


# =========================================================================== dot measurement
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
    """Projector (x, y) of every camera pixel through the homography of the wall it sees
    (the side of ``fold_cam``). Returns two (Hc, Wc) float64 arrays."""
    wc, hc = calib.camera_size
    ys, xs = np.mgrid[0:hc, 0:wc].astype(np.float64)
    if calib.n_planes == 2:
        a, b, c = calib.fold_cam
        plane = (a * xs + b * ys + c >= 0).astype(int)
    else:
        plane = np.zeros(xs.shape, int)
    return apply_h_per_plane(calib.H_proj_from_cam, plane, xs, ys)


def _camera_bbox(calib: Calibration, x: int, y: int, h: int) -> tuple[slice, slice] | None:
    wc, hc = calib.camera_size
    corners = np.array([[x - h - 1, y - h - 1, 1], [x + h + 1, y - h - 1, 1],
                        [x + h + 1, y + h + 1, 1], [x - h - 1, y + h + 1, 1]], np.float64)
    cam = []
    for H in calib.H_cam_from_proj:  # both walls: a window near the fold may span the two
        q = corners @ H.T
        cam.append(q[:, :2] / q[:, 2:3])
    cam = np.vstack(cam)
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


def _clean(k: np.ndarray, support: float, floor: float = 0.0) -> tuple[np.ndarray, float, float]:
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


def dot_sizes(radius_pred: np.ndarray, dot_size: int | str = "auto") -> np.ndarray:
    """Side (px) of the square dot for each predicted blur radius (see ``_DOT2_RADIUS``)."""
    r = np.asarray(radius_pred, np.float64)
    if dot_size == "auto":
        return np.where(r < _DOT2_RADIUS, 1, np.where(r < _DOT3_RADIUS, 2, 3)).astype(int)
    if not isinstance(dot_size, (int, np.integer)) or dot_size < 1:
        raise InputError(f"dot_size must be 'auto' or a positive integer; got {dot_size!r}")
    return np.full(len(r), int(dot_size))


def _dot_geometry(radius_pred: np.ndarray, dots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Light support and measuring-window half-size of each dot (px)."""
    sup = support_bound(radius_pred) + dots / 2.0
    return sup, np.ceil(sup).astype(int) + 3


def measure_psfs(calib: Calibration, capture: Capturer, points: np.ndarray,
                 radius_pred: np.ndarray, *, averages: int, camera_gamma: float = 1.0,
                 dot_size: int | str = "auto") -> Measurement:
    """Measure the PSF of a dot at each of ``points`` (N, 2) int (steps 3-5).

    Dots are packed into patterns (no two lights overlap a window), each pattern is averaged
    over ``averages`` captures, and each dot is solved by :func:`solve_dot` and cleaned.
    """
    wp, hp = calib.projector_size
    points = np.asarray(points, int)
    dots = dot_sizes(radius_pred, dot_size)
    sup, win = _dot_geometry(radius_pred, dots)
    patterns = pack_patterns(points, sup, win)
    cam_px, cam_py = camera_to_projector_maps(calib)
    psfs: list = [None] * len(points)
    raw: list = [None] * len(points)
    sigma = np.zeros(len(points))
    radius = np.zeros(len(points))
    tight = np.zeros(len(points))
    snr = np.zeros(len(points))
    noise = np.zeros(len(points))
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
        img = linearize_camera(frame, camera_gamma).sum(axis=2)
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
            psf, r, t = _clean(k, float(sup[i]))
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
                       averages=averages, captures=len(patterns) * averages)


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


# =========================================================================== the field F
def _barycentric(pix: np.ndarray, samples: np.ndarray, ids: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric weights on a Delaunay triangulation of ``samples``; outside the hull, the
    nearest point of the nearest hull edge (clamped extrapolation). Returns (M, 4) idx, wts."""
    from scipy.spatial import Delaunay, QhullError

    M = len(pix)
    idx = np.zeros((M, 4), np.int32)
    wts = np.zeros((M, 4), np.float32)
    if len(samples) == 1:
        idx[:, 0], wts[:, 0] = ids[0], 1.0
        return idx, wts
    try:
        tri = Delaunay(samples)
        simp = tri.find_simplex(pix)
        edges = tri.convex_hull
    except (QhullError, ValueError):      # collinear samples: blend along the polyline
        order = np.argsort(samples[:, 0] + 1e-3 * samples[:, 1])
        edges = np.column_stack([order[:-1], order[1:]])
        simp = np.full(M, -1)
    inside = simp >= 0
    if inside.any():
        T = tri.transform[simp[inside]]
        bc = np.einsum("mij,mj->mi", T[:, :2], pix[inside] - T[:, 2])
        w = np.column_stack([bc, 1 - bc.sum(axis=1)])
        w = np.clip(w, 0, None)
        w /= w.sum(axis=1, keepdims=True)
        idx[inside, :3] = ids[tri.simplices[simp[inside]]]
        wts[inside, :3] = w
    out = np.flatnonzero(~inside)
    if len(out):
        A, B = samples[edges[:, 0]], samples[edges[:, 1]]
        AB = B - A
        L2 = np.maximum((AB ** 2).sum(1), 1e-12)
        for chunk in np.array_split(out, max(1, len(out) // 20000 + 1)):
            P = pix[chunk]
            t = np.clip(((P[:, None, :] - A[None]) * AB[None]).sum(-1) / L2[None], 0, 1)
            Q = A[None] + t[..., None] * AB[None]
            d2 = ((P[:, None, :] - Q) ** 2).sum(-1)
            e = d2.argmin(axis=1)
            te = t[np.arange(len(chunk)), e]
            idx[chunk, 0] = ids[edges[e, 0]]
            idx[chunk, 1] = ids[edges[e, 1]]
            wts[chunk, 0] = 1 - te
            wts[chunk, 1] = te
    return idx, wts


def _inverse_bilinear(quad: np.ndarray, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s, t) in [0, 1]² (clamped) with bilinear(quad; s, t) = pix; quad (4, 2) cyclic order."""
    p00, p10, p11, p01 = quad
    s = np.full(len(pix), 0.5)
    t = np.full(len(pix), 0.5)
    for _ in range(12):
        P = ((1 - s) * (1 - t))[:, None] * p00 + (s * (1 - t))[:, None] * p10 + \
            (s * t)[:, None] * p11 + ((1 - s) * t)[:, None] * p01
        ds = (1 - t)[:, None] * (p10 - p00) + t[:, None] * (p11 - p01)
        dt = (1 - s)[:, None] * (p01 - p00) + s[:, None] * (p11 - p10)
        r = pix - P
        det = ds[:, 0] * dt[:, 1] - ds[:, 1] * dt[:, 0]
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        us = (r[:, 0] * dt[:, 1] - r[:, 1] * dt[:, 0]) / det
        ut = (ds[:, 0] * r[:, 1] - ds[:, 1] * r[:, 0]) / det
        s, t = s + us, t + ut
        if max(np.abs(us).max(), np.abs(ut).max()) < 1e-7:   # Newton: a few steps suffice
            break
    return np.clip(s, 0, 1), np.clip(t, 0, 1)


def _bilinear_weights(quad_ids: list, quad: np.ndarray, pix: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    s, t = _inverse_bilinear(quad, pix)
    w = np.column_stack([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t]).astype(np.float32)
    idx = np.tile(np.asarray(quad_ids, np.int32), (len(pix), 1))
    return idx, w


def interpolation_field(calib: Calibration, plan: SamplePlan, *, mode: str | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Per projector pixel, ≤ 4 PSF indices and weights (step 6).

    Parameters
    ----------
    calib : Calibration (geometry); its fold decides each pixel's plane.
    plan : the samples (PSF i is measured at ``plan.points[i]``).
    mode : ``"planes"`` (per-plane blending; bilinear quads for ``paper``, else triangles),
        ``"cross"`` (one triangulation of all samples, ignoring the planes); default from the
        plan (``cross`` when ``plan.cross_fold``).

    Returns
    -------
    idx : (Hp, Wp, 4) int32, wts : (Hp, Wp, 4) float32 (rows sum to 1, unused slots 0).
    """
    mode = mode or ("cross" if plan.cross_fold else "planes")
    if mode not in ("planes", "cross"):
        raise InputError(f"mode must be 'planes' or 'cross'; got {mode!r}")
    wp, hp = calib.projector_size
    ys, xs = np.mgrid[0:hp, 0:wp]
    pix_all = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    idx = np.zeros((hp * wp, 4), np.int32)
    wts = np.zeros((hp * wp, 4), np.float32)
    pts = plan.points.astype(np.float64)
    if mode == "cross" or calib.n_planes == 1:
        regions = {0: np.ones(hp * wp, bool)}
        members = {0: np.arange(len(pts))}
    else:
        plane = calib.plane_map().ravel()
        regions = {p: plane == p for p in range(2)}
        members = {p: np.flatnonzero((plan.planes == p) | (plan.planes == FOLD)) for p in range(2)}
    for p, sel in regions.items():
        ids = members[p]
        if len(ids) == 0:
            raise CalibrationError(f"no PSF sample on plane {p}; cannot build its kernels")
        pix = pix_all[sel]
        quads = plan.quads.get(p) if (plan.layout == "paper" and mode == "planes") or (
            plan.layout == "paper" and plan.cross_fold) else None
        if quads:
            out_i = np.zeros((len(pix), 4), np.int32)
            out_w = np.zeros((len(pix), 4), np.float32)
            main = quads[0][1]
            use_strip = np.zeros(len(pix), bool)
            if len(quads) > 1:
                strip = quads[1][1]
                a, b = pts[strip[0]], pts[strip[1]]
                # Pixels beyond the line through the fold-side corners (towards the fold).
                n = np.array([a[1] - b[1], b[0] - a[0]])
                inward = _inward(calib, p)
                if n @ inward < 0:
                    n = -n
                use_strip = (pix - a) @ n < 0
                si, sw = _bilinear_weights(strip, pts[strip], pix[use_strip])
                out_i[use_strip], out_w[use_strip] = si, sw
            mi, mw = _bilinear_weights(main, pts[main], pix[~use_strip])
            out_i[~use_strip], out_w[~use_strip] = mi, mw
            idx[sel], wts[sel] = out_i, out_w
        else:
            M = plan.metric.get(p, np.eye(2)) if mode == "planes" or plan.cross_fold else np.eye(2)
            i_, w_ = _barycentric(pix @ M.T, pts[ids] @ M.T, ids.astype(np.int32))
            idx[sel], wts[sel] = i_, w_
    wts /= np.maximum(wts.sum(axis=1, keepdims=True), 1e-12)
    idx[wts == 0] = 0
    return idx.reshape(hp, wp, 4), wts.reshape(hp, wp, 4)


# =========================================================================== the stage
def calibrate_psf(procam, calib: Calibration, *, capture: Capturer, layout: str = "default",
                  fold_samples: int | None = None, averages: int | None = None,
                  cross_fold: bool = False, radius_step: float = 0.5, max_spacing: float = 150.0,
                  dense_spacing: float = 50.0, edge_inset: float = 2.0, psf_captures: int = 20,
                  dot_size: int | str = "auto", pilot_spacing: int = 100,
                  iso_tolerance: float = 0.15, iso_distance: float = 160.0) -> Calibration:
    """Measure the defocus kernels and build the kernel field F; fill ``calib``'s psf section.

    Parameters
    ----------
    procam : ProCam (only used through ``capture``)
    calib : Calibration with the geometry section (radiometry optional: its camera_gamma is
        reused); filled in place and returned.
    capture : Capturer (stage ``"psf"``).
    layout : ``"default"`` | ``"paper"`` | ``"dense"`` (module docstring, step 2).
    fold_samples : samples along the fold on each side (default: one per max_spacing / 2).
    averages : captures averaged per dot pattern (default: the ``psf_captures`` budget left
        after the pilot, shared among the patterns).
    cross_fold : the geometry-blind baseline: one region, blended across the fold.
    radius_step, max_spacing : default layout: predicted blur-radius step between lines of
        equal blur (px), and largest sample spacing along and across them (px).
    dense_spacing : dense layout grid step (px).
    edge_inset : sample distance from the frame edges (px).
    psf_captures : capture budget of the stage when ``averages`` is not given.
    dot_size : ``"auto"`` or the side of the square dot (px). 1 px measures the kernel
        directly; a larger dot gives dot_size² more light and is deconvolved by the LS model
        (with a small ridge). ``"auto"`` uses 1 px where the predicted blur is small (bright
        enough) and 2-3 px where it is large (a 1-px dot is then too faint against the noise).
    pilot_spacing : grid step of the pilot dots (px); must exceed ~3x the largest blur radius.
    iso_tolerance, iso_distance : each PSF is averaged with the PSFs of its plane whose
        predicted radius is within ``iso_tolerance`` px, up to ``iso_distance`` px away
        (:func:`iso_average`); ``iso_tolerance=0`` keeps every PSF as measured.

    Returns
    -------
    Calibration
        ``psf_points_proj`` (N, 2) float32, ``psf_plane`` (N,) int32 (-1: on the fold, both
        planes), ``psfs`` (N, k, k) float32 unit sum, ``pix_idx`` (Hp, Wp, 4) int32,
        ``pix_wts`` (Hp, Wp, 4) float32, and ``meta["psf"]`` (layout, counts, radii, window).
    """
    out = calibrate_psf_layouts(procam, calib, capture=capture,
                                layouts=[(layout, cross_fold)], fold_samples=fold_samples,
                                averages=averages, radius_step=radius_step,
                                max_spacing=max_spacing, dense_spacing=dense_spacing,
                                edge_inset=edge_inset, psf_captures=psf_captures,
                                dot_size=dot_size, pilot_spacing=pilot_spacing,
                                iso_tolerance=iso_tolerance, iso_distance=iso_distance)
    return out[(layout, cross_fold)]


def calibrate_psf_layouts(procam, calib: Calibration, *, capture: Capturer,
                          layouts=(("default", False),), fold_samples: int | None = None,
                          averages: int | None = None, radius_step: float = 0.5,
                          max_spacing: float = 150.0, dense_spacing: float = 50.0,
                          edge_inset: float = 2.0, psf_captures: int = 20,
                          dot_size: int | str = "auto", pilot_spacing: int = 100,
                          iso_tolerance: float = 0.15, iso_distance: float = 160.0) -> dict:
    """:func:`calibrate_psf` for several ``(layout, cross_fold)`` at once, measured together.

    All layouts' dots share one pilot and one set of patterns, each pattern averaged the same
    number of times, so every PSF has the noise it would have in a run of its own layout and
    the layouts can be compared on equal terms at a fraction of the captures. The first
    layout fills ``calib``; the others are filled into copies. Returns {(layout, cross_fold):
    Calibration}.
    """
    import copy

    layouts = [(str(lay), bool(cf)) for lay, cf in layouts]
    for lay, _ in layouts:
        if lay not in LAYOUTS:
            raise InputError(f"layout must be one of {LAYOUTS}; got {lay!r}")
    dot_sizes(np.zeros(1), dot_size)       # validates
    camera_gamma = float(calib.meta.get("radiometry", {}).get("camera_gamma", 1.0))
    capture.begin("psf", psf_captures)
    n0 = capture.counts.get("psf", 0)

    # 1. pilot (per plane, and a blind single-region fit for the cross-fold baseline)
    model = pilot_radius(calib, capture, spacing=pilot_spacing, camera_gamma=camera_gamma)
    blind = None
    if any(cf for _, cf in layouts):
        # What a method unaware of the fold assumes: one plane, so one affine radius.
        blind = RadiusModel(model.points, model.radii)
        blind.fit(0, force_affine=True)

    # 2. layouts, then the union of their points, measured once
    opts = dict(fold_samples=fold_samples, radius_step=radius_step, max_spacing=max_spacing,
                dense_spacing=dense_spacing, edge_inset=edge_inset)
    plans = {key: plan_samples(calib, blind if key[1] else model, key[0], cross_fold=key[1],
                               dot_size=dot_size, **opts) for key in layouts}
    uniq: dict[tuple[int, int], int] = {}
    upts, uplane = [], []
    for plan in plans.values():
        for (x, y), p in zip(plan.points.tolist(), plan.planes, strict=True):
            if (x, y) not in uniq:
                uniq[(x, y)] = len(upts)
                upts.append((x, y))
                uplane.append(int(p))
    upts_a = np.array(upts, int)
    # Every dot is measured the same way whatever layout asked for it: its window and dot size
    # follow the per-plane pilot model (a dot on the fold: the larger of the two sides).
    uplane_a = np.array(uplane)
    if calib.n_planes == 2:
        on_plane = uplane_a != FOLD
        uplane_a[on_plane] = calib.plane_of(upts_a[on_plane, 0], upts_a[on_plane, 1])
    urad_a = np.empty(len(upts_a))
    for p in np.unique(uplane_a):
        sel = uplane_a == p
        urad_a[sel] = model(upts_a[sel].astype(np.float64), int(p) if calib.n_planes == 2 else 0)
    used = capture.counts.get("psf", 0) - n0
    if averages is None:
        # What the first layout would get on its own: its patterns share the budget left.
        first = np.array([uniq[(int(x), int(y))] for x, y in plans[layouts[0]].points])
        n_first = len(pack_patterns(upts_a[first], *_dot_geometry(
            urad_a[first], dot_sizes(urad_a[first], dot_size))))
        averages = max(2, (psf_captures - used) // n_first)
    meas = measure_psfs(calib, capture, upts_a, urad_a, averages=averages,
                        camera_gamma=camera_gamma, dot_size=dot_size)
    log.info("psf: %d dots in %d patterns x %d averages; radius %.2f..%.2f px; snr %.0f..%.0f",
             len(upts_a), meas.patterns, averages, meas.radius.min(), meas.radius.max(),
             meas.snr.min(), meas.snr.max())

    # 3. per layout: its PSFs, a common window, the field
    results = {}
    total = capture.counts.get("psf", 0) - n0
    for n, (key, plan) in enumerate(plans.items()):
        target = calib if n == 0 else copy.deepcopy(calib)
        sel = np.array([uniq[(int(x), int(y))] for x, y in plan.points])
        # Average the raw LS kernels (zero-mean noise averages away; clipped noise would not),
        # then clean: a support from each averaged kernel's radius, and a floor at the noise
        # left after averaging, which removes the faint noise ring around wide kernels.
        raw = common_window([meas.raw[i] for i in sel], meas.bound[sel])
        n_eff = np.ones(len(raw))
        if iso_tolerance > 0:
            signed = plan.radius if plan.radius_signed is None else plan.radius_signed
            raw, n_eff = iso_average(raw, plan.points, plan.planes, signed,
                                     meas.noise[sel], iso_tolerance, iso_distance)
        cleaned, tight = [], np.zeros(len(raw))
        for j in range(len(raw)):
            floor = _NOISE_FLOOR * meas.noise[sel[j]] / math.sqrt(n_eff[j])
            psf_j, _, tight[j] = _clean(raw[j].astype(np.float64), float(meas.bound[sel[j]]),
                                        floor)
            cleaned.append(psf_j)
        psfs = common_window(cleaned, tight)
        idx, wts = interpolation_field(target, plan)
        target.psf_points_proj = plan.points.astype(np.float32)
        target.psf_plane = plan.planes.astype(np.int32)
        target.psfs = psfs
        target.pix_idx = idx
        target.pix_wts = wts
        target.meta["psf"] = {
            "layout": key[0], "cross_fold": key[1], "samples": int(len(plan)),
            "kinds": {k: int((plan.kinds == k).sum()) for k in np.unique(plan.kinds)},
            "window": int(psfs.shape[1]), "patterns": meas.patterns, "averages": averages,
            "captures": int(total),
            "dot_sizes": {str(d): int((meas.dots[sel] == d).sum()) for d in np.unique(meas.dots)},
            "radius_range": [round(min(equivalent_radius(p) for p in psfs), 3),
                             round(max(equivalent_radius(p) for p in psfs), 3)],
            "pilot_model": {str(k): v for k, v in (blind if key[1] else model).kind.items()},
            "median_snr": round(float(np.median(meas.snr[sel])), 1),
            "iso_average": {"tolerance": iso_tolerance, "distance": iso_distance,
                            "median_n_eff": round(float(np.median(n_eff)), 2)},
        }
        results[key] = target
    return results


# =========================================================================== diagnostics
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
    import cv2

    if calib.psfs is None:
        raise CalibrationError("this calibration has no PSF section; run the kernel stage")
    wp, hp = calib.projector_size
    # Panel 1: PSFs (each scaled to its own peak), magnified, over the plane map.
    panel = np.full((hp, wp, 3), 24, np.uint8)
    if calib.n_planes == 2:
        panel[calib.plane_map() == 1] = (40, 40, 56)
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
    if calib.n_planes == 2:
        seg = fold_segment(calib)
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


__all__ = ["calibrate_psf", "calibrate_psf_layouts", "pilot_radius", "plan_samples",
           "measure_psfs", "solve_dot", "interpolation_field", "psf_diagnostics", "radius_map",
           "equivalent_radius", "plane_polygon", "fold_segment", "pack_patterns",
           "camera_to_projector_maps", "RadiusModel", "SamplePlan", "Measurement", "OPTIONS",
           "LAYOUTS", "FOLD"]
