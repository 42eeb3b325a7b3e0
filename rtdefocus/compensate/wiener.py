"""The per-plane Wiener pre-filter (Brown et al. 2006): a baseline of the compensation, a direct
filter instead of the constrained solve (:mod:`rtdefocus.compensate.solvers`)."""

from __future__ import annotations

import numpy as np

__all__ = ["wiener_prefilter"]


def wiener_prefilter(target: np.ndarray, psfs: np.ndarray, psf_plane: np.ndarray,
                     plane_map: np.ndarray, nsr: float = 0.01) -> np.ndarray:
    """Per-plane Wiener pre-filter (Brown et al. 2006), clamped to [0, 1].

    Each plane gets one representative kernel, the mean of its measured PSFs; the whole frame
    is filtered with ``(1 + nsr) conj(ψ̂) / (|ψ̂|² + nsr)`` (unit gain at DC) per channel (FFT,
    edge-padded against wrap-around) and each pixel takes the result of its own plane
    (``plane_map``).

    Parameters
    ----------
    target : (3, H, W) float32, linear light
    psfs : (N, k, k) float32 (gather kernels, unit sum)
    psf_plane : (N,) int, plane of each PSF (negative: on a fold, left out; any number of
        planes)
    plane_map : (H, W) int, plane of each pixel
    nsr : noise-to-signal constant (larger: less sharpening, less ringing)

    Returns
    -------
    (3, H, W) float32 in [0, 1]
    """
    target = np.asarray(target, dtype=np.float64)
    psfs = np.asarray(psfs, dtype=np.float64)
    _, h, w = target.shape
    k = psfs.shape[1]
    r = k // 2
    pad = 2 * r + 8
    padded = np.pad(target, ((0, 0), (pad, pad), (pad, pad)), mode="edge")
    ph, pw = padded.shape[1:]
    spec = np.fft.rfft2(padded)
    out = np.zeros_like(target)
    planes = np.unique(plane_map)
    for p in planes:
        sel = np.asarray(psf_plane) == p
        psi = psfs[sel].mean(axis=0) if sel.any() else psfs.mean(axis=0)
        # O(x) = Σ_u ψ(u) P(x − u) is a convolution; place ψ(0) at the origin.
        kern = np.zeros((ph, pw))
        kern[:k, :k] = psi
        kern = np.roll(kern, (-r, -r), axis=(0, 1))
        kh = np.fft.rfft2(kern)
        # Scaled to unit gain at DC (|ψ̂(0)| = 1): the plain Wiener filter dims flat areas by
        # 1 / (1 + nsr), which costs more than its sharpening gains.
        filt = np.conj(kh) * (1.0 + nsr) / (np.abs(kh) ** 2 + nsr)
        res = np.fft.irfft2(spec * filt, s=(ph, pw))[:, pad:pad + h, pad:pad + w]
        mask = plane_map == p
        out[:, mask] = res[:, mask]
    return np.clip(out, 0.0, 1.0).astype(np.float32)
