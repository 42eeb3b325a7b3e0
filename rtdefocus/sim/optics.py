"""Thin-lens defocus of the virtual projector (DESIGN.md §3): the aperture kernels and the
kernel field rendered on a grid of radii.

Defocus (gather form): a thin lens of aperture radius ``A`` (metres) and focal length ``f``
(projector px) focused at ``D_focus``. The surface point seen by projector pixel x, at depth D
along the projector axis, receives light from every projector pixel within
``r(D) = A f |1/D_focus - 1/D|`` projector px of x, each with equal weight (the cone from the
aperture through the pixel's conjugate point has that radius at depth D, divided by the pixel
size D/f there). So its kernel is the aperture shape (disc, or regular hexagon) of radius r.
On a plane 1/D is affine in projector pixel coordinates, so r is affine per wall, continuous
at the fold with a slope change.

Rendering: the blur is evaluated in projector space on a grid of radii (every ``RADIUS_STEP``
px) — each pixel linearly blends the two neighbouring grid kernels (:class:`BlurPlan`) — and
the ground-truth kernel (:func:`blend_kernel`) is defined as exactly that blend, so rendering
and truth agree to float precision.
"""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np

from ..errors import InputError

RADIUS_STEP = 0.25          # px: spacing of the radius grid the blur is rendered on
_SUPERSAMPLE = 16           # sub-samples per pixel side for the area-antialiased aperture


@lru_cache(maxsize=512)
def _level_kernel(step_index: int, aperture: str) -> np.ndarray:
    """Area-antialiased aperture of radius ``step_index * RADIUS_STEP`` px, unit sum.

    Returns a read-only (k, k) float64 array, ``psf[k//2 + v, k//2 + u] = k(u, v)``.
    """
    rho = step_index * RADIUS_STEP
    # Any pixel whose square can touch the shape: |u| <= rho + sqrt(2)/2.
    h = int(math.ceil(rho + 0.7072)) if rho > 0 else 0
    if rho <= 0:
        ker = np.ones((1, 1))
    else:
        ss = _SUPERSAMPLE
        n = (2 * h + 1) * ss
        c = (np.arange(n) + 0.5) / ss - (h + 0.5)          # sub-sample centres, px
        u, v = np.meshgrid(c, c)
        if aperture == "disc":
            inside = u * u + v * v <= rho * rho
        elif aperture == "triangle":
            # Equilateral triangle of circumradius rho about its centroid, one vertex up (-v):
            # not point-symmetric, so a flipped or transposed kernel is a different kernel.
            inside = np.ones_like(u, dtype=bool)
            for ang in (90.0, 210.0, 330.0):          # outward normals of the three edges
                a = math.radians(ang)
                inside &= u * math.cos(a) + v * math.sin(a) <= rho / 2.0
        else:  # regular hexagon of circumradius rho, vertices at 0°, 60°, ...
            apothem = rho * math.sqrt(3.0) / 2.0
            inside = np.ones_like(u, dtype=bool)
            for ang in (30.0, 90.0, 150.0):
                a = math.radians(ang)
                inside &= np.abs(u * math.cos(a) + v * math.sin(a)) <= apothem
        ker = inside.reshape(2 * h + 1, ss, 2 * h + 1, ss).sum(axis=(1, 3)).astype(np.float64)
        if ker.sum() == 0:          # shape smaller than one sub-sample: a delta
            ker = np.zeros((2 * h + 1, 2 * h + 1))
            ker[h, h] = 1.0
        ker /= ker.sum()
    ker.setflags(write=False)
    return ker


def _pad_to(ker: np.ndarray, k: int) -> np.ndarray:
    """Centre-pad (or centre-crop) a square odd kernel to (k, k)."""
    n = ker.shape[0]
    if n == k:
        return ker.copy()
    if n < k:
        out = np.zeros((k, k), dtype=ker.dtype)
        o = (k - n) // 2
        out[o:o + n, o:o + n] = ker
        return out
    o = (n - k) // 2
    return ker[o:o + k, o:o + k].copy()


def blend_kernel(radius: float, aperture: str = "disc", size: int | None = None) -> np.ndarray:
    """The simulator's kernel for a blur radius: the linear blend of the two grid kernels.

    Parameters
    ----------
    radius : blur radius in projector px (>= 0).
    aperture : "disc", "hex" or "triangle".
    size : odd output size k; None for the full support. A smaller size crops and
        renormalises to unit sum.

    Returns
    -------
    (k, k) float32, unit sum, ``psf[k//2 + v, k//2 + u] = k(u, v)`` (gather form).
    """
    q = float(radius) / RADIUS_STEP
    j = int(math.floor(q))
    t = q - j
    k_lo, k_hi = _level_kernel(j, aperture), _level_kernel(j + 1, aperture)
    n = k_hi.shape[0]
    ker = (1.0 - t) * _pad_to(k_lo, n) + t * k_hi
    if size is not None:
        if size < 1 or size % 2 == 0:
            raise InputError(f"kernel size must be a positive odd integer; got {size}")
        ker = _pad_to(ker, size)
        ker /= ker.sum()
    return ker.astype(np.float32)


class BlurPlan:
    """The kernel field of a padded projector grid, cut into radius-grid levels and row strips.

    Parameters
    ----------
    pad_radius : (3, H, W) float32 blur radius per channel (px) on the padded projector grid.
    chromatic : per-channel scale of the radius; channels of equal scale share one pass.
    aperture : "disc", "hex" or "triangle".

    Attributes
    ----------
    levels : per channel group ``(channels, [((y0, y1, x0, x1), weights, half-size, pieces)])``.
    kmax : the largest kernel half-size (px): the padding :meth:`apply` needs.
    """

    def __init__(self, pad_radius: np.ndarray, chromatic: tuple[float, float, float], aperture: str):
        # Per radius-grid level and row strip: the pixels that use it and their blend weights.
        plan = []
        groups: dict[float, list[int]] = {}
        for c, s in enumerate(chromatic):
            groups.setdefault(s, []).append(c)
        hpad = pad_radius.shape[1]
        strip = 48     # row strips keep each level's band tight when the fold is not vertical
        for chans in groups.values():
            q = pad_radius[chans[0]].astype(np.float64) / RADIUS_STEP
            levels = []
            for j in range(int(math.floor(q.min())), int(math.floor(q.max())) + 2):
                w = 1.0 - np.abs(q - j)      # tent weight: the same blend as blend_kernel()
                mask = w > 0
                if not mask.any():
                    continue
                ker = _level_kernel(j, aperture)
                # cv2.filter2D correlates: flip the kernel to convolve, O(x) = sum_u k(u) P(x - u).
                flipped = np.asarray(ker[::-1, ::-1], dtype=np.float32)
                # OpenCV filters kernels of area >= 130 through a DFT, slow on these narrow
                # bands; row pieces of smaller area take the direct path (5-8x faster).
                k = flipped.shape[0]
                rows_per = max(1, min(k, 129 // k))
                pieces = [(a, np.ascontiguousarray(flipped[a:a + rows_per]))
                          for a in range(0, k, rows_per)]
                for s0 in range(0, hpad, strip):
                    sm = mask[s0:s0 + strip]
                    rows, cols = np.flatnonzero(sm.any(axis=1)), np.flatnonzero(sm.any(axis=0))
                    if rows.size == 0:
                        continue
                    y0, y1 = s0 + rows[0], s0 + rows[-1] + 1
                    x0, x1 = cols[0], cols[-1] + 1
                    wc = np.where(mask[y0:y1, x0:x1], w[y0:y1, x0:x1], 0.0).astype(np.float32)
                    levels.append(((y0, y1, x0, x1), wc[..., None], k // 2, pieces))
            plan.append((chans, levels))
        self.levels = plan
        self.kmax = max(lv[2] for _, lvs in plan for lv in lvs)

    def apply(self, lin: np.ndarray, margin: int) -> np.ndarray:
        """F P on the padded projector grid: (Hp+2m, Wp+2m, 3) float32 from (Hp, Wp, 3) linear P."""
        hp, wp = lin.shape[:2]
        m, h = margin, self.kmax
        src = np.zeros((hp + 2 * (m + h), wp + 2 * (m + h), 3), np.float32)
        src[m + h:m + h + hp, m + h:m + h + wp] = lin   # no light comes from outside the frame
        out = np.zeros((hp + 2 * m, wp + 2 * m, 3), np.float32)
        for chans, levels in self.levels:
            sel = slice(chans[0], chans[-1] + 1) if chans == list(range(chans[0], chans[-1] + 1)) \
                else chans
            for (y0, y1, x0, x1), w, k, pieces in levels:
                ny, nx = y1 - y0, x1 - x0
                acc = None
                for a, piece in pieces:
                    # Rows a.. of the flipped kernel, anchored at its first row: the crop starts
                    # a - k rows below the band (out (Y, X) is src (Y + h, X + h)).
                    r0 = y0 + h + a - k
                    crop = np.ascontiguousarray(
                        src[r0:r0 + ny + piece.shape[0] - 1, x0 + h - k:x1 + h + k][..., sel])
                    b = cv2.filter2D(crop, -1, piece, anchor=(k, 0), borderType=cv2.BORDER_CONSTANT)
                    b = b[:ny, k:k + nx]
                    acc = b if acc is None else acc + b
                if acc.ndim == 2:
                    acc = acc[..., None]
                np.multiply(acc, w, out=acc)
                out[y0:y1, x0:x1, sel] += acc
        return out
