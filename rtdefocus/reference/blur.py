"""The spatially varying blur F and its exact adjoint, in plain NumPy (the reference).

Kernel field, gather form (docs/internals.md "Kernel field F", DESIGN.md §3):

* ``psfs`` float32 (N, k, k), k odd, unit sum; ``psf[k//2 + v, k//2 + u] = k(u, v)`` — the
  image of a dot, *not* flipped;
* ``idx`` int32 (H, W, 4), ``wts`` float32 (H, W, 4): pixel x's kernel is
  ``k_x = sum_j wts[x, j] * psfs[idx[x, j]]``.

Forward ``O(x) = sum_u k_x(u) P(x - u)``; adjoint ``(F^T r)(y) = sum_u k_{y+u}(u) r(y + u)``.
P outside the frame is 0 (no light). Images are planar ``(C, H, W)`` or a single ``(H, W)``
plane; the same F applies to every channel.

Two forms of the same operator are given: the *gather* form (:func:`blur_forward`,
:func:`blur_adjoint`: a loop over the k×k taps with per-pixel blended tap weights), and the
*filter2D* form (:func:`blur_forward_filter2d`, :func:`blur_adjoint_filter2d`: what a Python
user would write with OpenCV — filter with every measured PSF, then blend with the per-pixel
weights). Both are exact; the second is the speed baseline of ``tools/bench.py``.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError

__all__ = [
    "blur_forward", "blur_adjoint", "blur_forward_filter2d", "blur_adjoint_filter2d",
    "check_field", "weight_maps", "pillbox_psf", "synthetic_field", "psf_support", "trim_psfs",
]


def psf_support(psfs: np.ndarray, energy: float = 1.0) -> np.ndarray:
    """Half-width of each PSF's support: the smallest ``s`` whose centred ``(2s+1)²`` window
    holds at least ``energy`` of the PSF's absolute sum.

    Parameters
    ----------
    psfs : (N, k, k), k odd
    energy : in (0, 1]; 1 gives the exact support (the smallest window outside which every tap
        is zero), so a blur restricted to it is the same operator.

    Returns
    -------
    (N,) int32 in ``[0, k // 2]``
    """
    psfs = np.abs(np.asarray(psfs, dtype=np.float64))
    if psfs.ndim != 3 or psfs.shape[1] != psfs.shape[2] or psfs.shape[1] % 2 != 1:
        raise InputError(f"psfs must be (N, k, k) with k odd; got shape {psfs.shape}")
    if not 0.0 < energy <= 1.0:
        raise InputError(f"energy must be in (0, 1]; got {energy}")
    n, k = psfs.shape[:2]
    r = k // 2
    # distance of each tap from the centre in the max norm: tap (i, j) is inside window s iff
    # its ring <= s
    ring = np.maximum.outer(np.abs(np.arange(k) - r), np.abs(np.arange(k) - r))
    per_ring = np.stack([psfs[:, ring == s].sum(-1) for s in range(r + 1)], axis=1)  # (N, r+1)
    total = per_ring.sum(1, keepdims=True)
    if energy >= 1.0:
        nonzero = per_ring > 0
        sup = np.where(nonzero.any(1), r - np.argmax(nonzero[:, ::-1], axis=1), 0)
    else:
        inside = np.cumsum(per_ring, axis=1) >= energy * total - 1e-12 * total
        sup = np.argmax(inside, axis=1)
    return sup.astype(np.int32)


def trim_psfs(psfs: np.ndarray, energy: float = 0.999) -> np.ndarray:
    """The PSFs cut to their energy support (:func:`psf_support`) and renormalised to unit sum,
    in the smallest common odd size.

    With ``energy=1`` the result is the same operator in a tighter array (only zero taps go).
    Below 1 the faint halo beyond each PSF's window is dropped: fewer taps per pixel in every
    blur, at a change of the operator measured by ``tools/bench_video.py`` (section ``trim``).

    Parameters
    ----------
    psfs : (N, k, k) float, k odd, unit sum
    energy : in (0, 1]

    Returns
    -------
    (N, k', k') float32, k' = 2 · max(support) + 1 <= k
    """
    psfs = np.asarray(psfs, dtype=np.float32)
    sup = psf_support(psfs, energy)
    r, r2 = psfs.shape[1] // 2, int(sup.max())
    out = psfs[:, r - r2:r + r2 + 1, r - r2:r + r2 + 1].copy()
    if energy < 1.0:
        ring = np.maximum.outer(np.abs(np.arange(2 * r2 + 1) - r2),
                                np.abs(np.arange(2 * r2 + 1) - r2))
        out[ring[None] > sup[:, None, None]] = 0.0
        sums = out.sum((1, 2), keepdims=True, dtype=np.float64)
        sums[sums == 0] = 1.0
        out = (out / sums).astype(np.float32)
    return np.ascontiguousarray(out)


def check_field(psfs: np.ndarray, idx: np.ndarray, wts: np.ndarray,
                shape: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate a kernel field and return it as contiguous ``(float32, int32, float32)`` arrays.

    Parameters
    ----------
    psfs : (N, k, k) array, k odd
    idx : (H, W, 4) integer array, values in ``[0, N)``
    wts : (H, W, 4) array
    shape : (H, W), optional
        The image size the field must cover.

    Raises
    ------
    InputError
        On a wrong shape, dtype-incompatible value or out-of-range index, naming the fix.
    """
    psfs = np.ascontiguousarray(psfs, dtype=np.float32)
    if psfs.ndim != 3 or psfs.shape[1] != psfs.shape[2] or psfs.shape[1] % 2 != 1:
        raise InputError(f"psfs must be (N, k, k) with k odd; got shape {psfs.shape}. "
                         "Pad the PSFs with zeros to an odd square size.")
    idx = np.asarray(idx)
    if not np.issubdtype(idx.dtype, np.integer):
        raise InputError(f"idx must be an integer array; got dtype {idx.dtype}.")
    idx = np.ascontiguousarray(idx, dtype=np.int32)
    wts = np.ascontiguousarray(wts, dtype=np.float32)
    if idx.ndim != 3 or idx.shape[2] != 4 or wts.shape != idx.shape:
        raise InputError(f"idx and wts must both be (H, W, 4); got {idx.shape} and {wts.shape}.")
    if shape is not None and idx.shape[:2] != tuple(shape):
        raise InputError(f"the kernel field covers {idx.shape[1]}x{idx.shape[0]} pixels but the "
                         f"image is {shape[1]}x{shape[0]} (width x height); use the field of "
                         "the same projector size.")
    if idx.size and (idx.min() < 0 or idx.max() >= psfs.shape[0]):
        raise InputError(f"idx values must lie in [0, {psfs.shape[0]}) (the number of PSFs); "
                         f"found [{idx.min()}, {idx.max()}].")
    return psfs, idx, wts


def _as_planes(img: np.ndarray) -> tuple[np.ndarray, bool]:
    img = np.asarray(img)
    if img.dtype != np.float64:  # float64 stays exact for adjoint checks; the rest is float32
        img = img.astype(np.float32, copy=False)
    if img.ndim == 2:
        return img[None], True
    if img.ndim == 3:
        return img, False
    raise InputError(f"image must be planar (C, H, W) or (H, W); got shape {img.shape}.")


def _tap_weights(psfs: np.ndarray, idx: np.ndarray, wts: np.ndarray, dv: int, du: int,
                 dtype) -> np.ndarray:
    """Per-pixel ``k_x(u)`` for the tap ``u = (du, dv)``: (H, W), blended from the 4 slots."""
    r = psfs.shape[1] // 2
    tap = psfs[:, r + dv, r + du].astype(dtype)          # (N,) this tap of every PSF
    return np.einsum("hwj,hwj->hw", wts.astype(dtype), tap[idx])


def _shift_add(out: np.ndarray, src: np.ndarray, dy: int, dx: int) -> None:
    """``out[..., y, x] += src[..., y - dy, x - dx]`` where ``(y - dy, x - dx)`` is in the frame."""
    h, w = out.shape[-2:]
    ys, yd = slice(max(0, -dy), min(h, h - dy)), slice(max(0, dy), min(h, h + dy))
    xs, xd = slice(max(0, -dx), min(w, w - dx)), slice(max(0, dx), min(w, w + dx))
    out[..., yd, xd] += src[..., ys, xs]


def blur_forward(img: np.ndarray, psfs: np.ndarray, idx: np.ndarray, wts: np.ndarray,
                 dtype=np.float32) -> np.ndarray:
    """Forward blur ``O = F P``: ``O(x) = sum_u k_x(u) P(x - u)``, zero outside the frame.

    Parameters
    ----------
    img : (C, H, W) or (H, W) float array
        P, planar, linear light.
    psfs, idx, wts : the kernel field (see the module docstring).
    dtype : accumulation dtype (float32, or float64 for exactness checks).

    Returns
    -------
    ndarray, same shape as ``img``, of ``dtype``.
    """
    planes, flat = _as_planes(img)
    psfs, idx, wts = check_field(psfs, idx, wts, planes.shape[1:])
    planes = planes.astype(dtype, copy=False)
    r = psfs.shape[1] // 2
    out = np.zeros(planes.shape, dtype)
    for dv in range(-r, r + 1):
        for du in range(-r, r + 1):
            t = _tap_weights(psfs, idx, wts, dv, du, dtype)
            # out(x) += k_x(u) P(x - u): shift P by +u, then weight by the tap at x.
            shifted = np.zeros_like(planes)
            _shift_add(shifted, planes, dv, du)
            out += t * shifted
    return out[0] if flat else out


def blur_adjoint(img: np.ndarray, psfs: np.ndarray, idx: np.ndarray, wts: np.ndarray,
                 dtype=np.float32) -> np.ndarray:
    """Adjoint blur ``F^T r``: ``(F^T r)(y) = sum_u k_{y+u}(u) r(y + u)``, over ``y + u`` in the frame.

    Parameters
    ----------
    img : (C, H, W) or (H, W) float array
        r, planar.
    psfs, idx, wts : the kernel field (see the module docstring).
    dtype : accumulation dtype (float32, or float64 for exactness checks).

    Returns
    -------
    ndarray, same shape as ``img``, of ``dtype``.
    """
    planes, flat = _as_planes(img)
    psfs, idx, wts = check_field(psfs, idx, wts, planes.shape[1:])
    planes = planes.astype(dtype, copy=False)
    r = psfs.shape[1] // 2
    out = np.zeros(planes.shape, dtype)
    for dv in range(-r, r + 1):
        for du in range(-r, r + 1):
            t = _tap_weights(psfs, idx, wts, dv, du, dtype)
            # out(y) += [k_x(u) r(x)] at x = y + u: weight at x, then shift by -u.
            _shift_add(out, t * planes, -dv, -du)
    return out[0] if flat else out


def weight_maps(idx: np.ndarray, wts: np.ndarray) -> dict[int, np.ndarray]:
    """Per-PSF weight maps ``W_n(x) = sum_j wts[x, j] [idx[x, j] == n]`` for every PSF in use.

    Returns
    -------
    dict
        PSF index -> (H, W) float32 map, for the PSFs with a nonzero weight somewhere.
    """
    maps = {}
    for n in np.unique(idx[wts != 0]):
        maps[int(n)] = np.where(idx == n, wts, 0.0).sum(axis=2, dtype=np.float32)
    return maps


def blur_forward_filter2d(img: np.ndarray, psfs: np.ndarray, idx: np.ndarray,
                          wts: np.ndarray, maps: dict[int, np.ndarray] | None = None
                          ) -> np.ndarray:
    """:func:`blur_forward` as a Python user would write it with OpenCV.

    ``O = sum_n W_n * (psi_n conv P)``: ``cv2.filter2D`` correlates, so each PSF is flipped to
    convolve; the border is constant 0 (no light outside the frame). Exactly the gather form,
    since ``k_x = sum_n W_n(x) psi_n``.

    Parameters
    ----------
    img : (C, H, W) or (H, W) float32
    psfs, idx, wts : the kernel field.
    maps : :func:`weight_maps` of ``(idx, wts)``, when the caller keeps them between calls
        (they cost about a third of a call at 800x600).

    Returns
    -------
    ndarray float32, same shape as ``img``.
    """
    planes, flat = _as_planes(img)
    planes = planes.astype(np.float32, copy=False)
    psfs, idx, wts = check_field(psfs, idx, wts, planes.shape[1:])
    out = np.zeros(planes.shape, np.float32)
    for n, wmap in (weight_maps(idx, wts) if maps is None else maps).items():
        kernel = np.ascontiguousarray(psfs[n, ::-1, ::-1])
        for c in range(planes.shape[0]):
            out[c] += wmap * cv2.filter2D(planes[c], cv2.CV_32F, kernel,
                                          borderType=cv2.BORDER_CONSTANT)
    return out[0] if flat else out


def blur_adjoint_filter2d(img: np.ndarray, psfs: np.ndarray, idx: np.ndarray,
                          wts: np.ndarray) -> np.ndarray:
    """:func:`blur_adjoint` as a Python user would write it with OpenCV.

    ``F^T r = sum_n psi_n corr (W_n * r)``: weight r by each PSF's map, correlate (unflipped
    ``cv2.filter2D``, constant-0 border), and sum.

    Parameters
    ----------
    img : (C, H, W) or (H, W) float32
    psfs, idx, wts : the kernel field.

    Returns
    -------
    ndarray float32, same shape as ``img``.
    """
    planes, flat = _as_planes(img)
    planes = planes.astype(np.float32, copy=False)
    psfs, idx, wts = check_field(psfs, idx, wts, planes.shape[1:])
    out = np.zeros(planes.shape, np.float32)
    for n, wmap in weight_maps(idx, wts).items():
        for c in range(planes.shape[0]):
            out[c] += cv2.filter2D(wmap * planes[c], cv2.CV_32F, psfs[n],
                                   borderType=cv2.BORDER_CONSTANT)
    return out[0] if flat else out


def pillbox_psf(radius: float, k: int, supersample: int = 4) -> np.ndarray:
    """A unit-sum disc ("pillbox") of ``radius`` px centred in a (k, k) float32 array.

    The defocus PSF of an ideal thin lens with a circular aperture; edge pixels get the covered
    fraction (``supersample``² samples per pixel).
    """
    r = k // 2
    off = (np.arange(supersample) + 0.5) / supersample - 0.5
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1].astype(np.float64)
    acc = np.zeros((k, k))
    for dy in off:
        for dx in off:
            acc += (xx + dx) ** 2 + (yy + dy) ** 2 <= max(radius, 0.5) ** 2
    return (acc / acc.sum()).astype(np.float32)


def synthetic_field(width: int, height: int, radius: float, grid: int = 3,
                    planes: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A realistic kernel field for tests and benchmarks (no calibration needed).

    The frame is split into ``planes`` vertical bands (the walls either side of a fold); each has
    a ``grid`` × ``grid`` lattice of pillbox PSFs whose radii vary between 0.6 and 1.0 times
    ``radius``, and every pixel blends the 4 PSFs of its lattice cell bilinearly — never across
    a band edge, as DESIGN.md §3 asks.

    Returns
    -------
    psfs : (planes * grid², k, k) float32, k = 2 ceil(radius) + 1
    idx : (height, width, 4) int32
    wts : (height, width, 4) float32, each pixel's weights sum to 1
    """
    k = 2 * int(np.ceil(radius)) + 1
    psfs = np.stack([
        pillbox_psf(radius * (0.6 + 0.2 * ((i + j + p) % 3)), k)
        for p in range(planes) for j in range(grid) for i in range(grid)])
    yy, xx = np.mgrid[0:height, 0:width]
    band = np.minimum(xx * planes // width, planes - 1)
    x_lo = (band * width) // planes
    x_hi = ((band + 1) * width) // planes - 1
    fx = (xx - x_lo) / np.maximum(x_hi - x_lo, 1) * (grid - 1)
    fy = yy / max(height - 1, 1) * (grid - 1)
    ix = np.minimum(fx.astype(int), grid - 2)
    iy = np.minimum(fy.astype(int), grid - 2)
    ax, ay = fx - ix, fy - iy
    base = band * grid * grid + iy * grid + ix
    idx = np.stack([base, base + 1, base + grid, base + grid + 1], axis=-1).astype(np.int32)
    wts = np.stack([(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay],
                   axis=-1).astype(np.float32)
    return psfs, idx, wts
