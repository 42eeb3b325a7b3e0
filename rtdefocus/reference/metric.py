"""The perceptual image distance of the solve (paper Eq. 4) and its gradient, in plain NumPy.

This is the reference every device kernel is tested against (``kernels/metric.cl``).

With the residual ``e = F P - I`` (planar ``(3, H, W)``, linear light; DESIGN.md §3) and a
linear colour map ``M`` (BT.601 RGB -> YCbCr for the paper's metric, the identity for the
per-channel RGB baseline), write ``c = M e`` and let ``∇`` be the 4-connected forward
differences (every horizontal and vertical neighbour pair counted once). The distance is

    d = sum_k  a_k · Σ_x c_k(x)²  +  s_k · Σ_(i,j) (c_k(i) − c_k(j))²          (Eq. 4)

with per-channel pixel weights ``a = (w1, w2, w2)`` and spatial weights ``s = (w3, w4, w4)``
for ``k = Y, Cb, Cr``. It is a quadratic form ``d = ⟨e, Q e⟩`` with

    Q e = Mᵀ (a ⊙ M e + s ⊙ Lap(M e)),     Lap = ∇ᵀ∇  (graph Laplacian, Neumann border),

so the gradient with respect to P is ``2 Fᵀ Q (F P − I)``, and along a direction ``s`` the
distance is the parabola ``d(P + t s) = d + t ⟨∇d, s⟩ + t² ⟨F s, Q F s⟩``: the exact
line-search step is ``t* = −⟨∇d, s⟩ / (2 ⟨F s, Q F s⟩)``, one more application of F.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .blur import blur_adjoint, blur_forward

__all__ = [
    "DEFAULT_WEIGHTS", "M_RGB_TO_YCBCR", "Metric", "rgb_to_ycbcr", "ycbcr_to_rgb", "forward_differences",
    "laplacian", "metric_field", "distance", "distance_and_gradient", "exact_step",
]

# BT.601 full-range luma/chroma as a linear map of RGB (JPEG's YCbCr without the +0.5 chroma
# offset: the metric only ever sees differences, where offsets cancel).
M_RGB_TO_YCBCR = np.array([
    [0.299, 0.587, 0.114],
    [-0.168736, -0.331264, 0.5],
    [0.5, -0.418688, -0.081312],
], dtype=np.float64)


# Eq. 4 weights (w1 luma, w2 chroma, w3 luma gradient, w4 chroma gradient), chosen by
# `tools/tune_metric.py weights --iterations 40` on the simulator (cubicle, tilted, pillar at
# 400x300 with the oracle kernels; four photographs and a text slide; FISTA at the default
# budget): ranked by the luma-SSIM gain of the camera view over geometry only, against the sharp
# reference; ties (within 2e-4) broken by RGB PSNR. The luma-gradient term helps luma (w3 0 ->
# 0.25: luma PSNR gain +4.97 -> +5.19 dB) until it over-smooths (w3 = 1: +5.14 dB); w4 and a
# lower w2 only trade colour PSNR. Per-channel RGB least squares: luma PSNR +5.07 dB, luma SSIM
# +0.0258, RGB PSNR +4.86 dB; these weights: +5.19 dB, +0.0258, +4.64 dB.
DEFAULT_WEIGHTS = (1.0, 0.5, 0.25, 0.0)


@dataclass(frozen=True)
class Metric:
    """A quadratic image distance ``d(e) = Σ_k a_k ‖(M e)_k‖² + s_k ‖∇(M e)_k‖²``.

    Attributes
    ----------
    matrix : (3, 3) float64
        Colour map M applied to planar RGB residuals.
    pixel : (3,) float64
        Per-channel weights ``a`` of the squared values.
    spatial : (3,) float64
        Per-channel weights ``s`` of the squared neighbour differences.
    """

    matrix: np.ndarray
    pixel: np.ndarray
    spatial: np.ndarray

    def __post_init__(self):
        m = np.asarray(self.matrix, dtype=np.float64)
        a = np.asarray(self.pixel, dtype=np.float64)
        s = np.asarray(self.spatial, dtype=np.float64)
        if m.shape != (3, 3) or a.shape != (3,) or s.shape != (3,):
            raise InputError(f"Metric needs a (3, 3) matrix and (3,) weights; got {m.shape}, "
                             f"{a.shape}, {s.shape}")
        if (a < 0).any() or (s < 0).any() or not (a.sum() + s.sum() > 0):
            raise InputError(f"metric weights must be non-negative and not all zero; got pixel "
                             f"{a.tolist()}, spatial {s.tolist()}")
        object.__setattr__(self, "matrix", m)
        object.__setattr__(self, "pixel", a)
        object.__setattr__(self, "spatial", s)

    @classmethod
    def ycbcr(cls, weights=(1.0, 1.0, 0.0, 0.0)) -> Metric:
        """The paper's Eq. 4 on BT.601 YCbCr with ``weights = (w1, w2, w3, w4)``."""
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (4,):
            raise InputError(f"weights must be (w1, w2, w3, w4); got {weights!r}")
        return cls(M_RGB_TO_YCBCR, np.array([w[0], w[1], w[1]]), np.array([w[2], w[3], w[3]]))

    @classmethod
    def rgb(cls) -> Metric:
        """Per-channel least squares on RGB (Zhang & Nayar 2006): ``d = ‖F P − I‖²``."""
        return cls(np.eye(3), np.ones(3), np.zeros(3))

    @property
    def qmatrices(self) -> tuple[np.ndarray, np.ndarray]:
        """``(Mᵀ diag(a) M, Mᵀ diag(s) M)``: Q e = A0 e + A1 Lap(e) (Lap acts per plane and
        commutes with the colour map, so Q folds into two 3×3 matrices)."""
        m = self.matrix
        return m.T @ np.diag(self.pixel) @ m, m.T @ np.diag(self.spatial) @ m

    @property
    def colour_preconditioner(self) -> np.ndarray | None:
        """``C = λ_max(A0) A0⁻¹`` (3×3, symmetric positive definite), or None where it would
        change nothing (A0 a multiple of the identity, e.g. :meth:`rgb`) or is undefined (A0
        singular: a zero pixel weight).

        The pixel term's colour directions are unequally stiff: with the default weights
        (chroma at half the luma weight) A0's eigenvalues span 0.13 … 0.52, so a plain gradient
        step, sized for the stiffest (luma) direction, moves chroma errors 2.5–4× slower. FISTA
        on ``C ∇d`` (the colour map commutes with the blur, whose PSFs are the same for every
        channel) moves every colour direction at the luma's pace, at no extra cost
        (:class:`~rtdefocus.compensate.solvers.Solver`, ``precondition="colour"``).
        """
        a0 = self.qmatrices[0]
        lam = np.linalg.eigvalsh(a0)
        if lam[0] <= 1e-9 * lam[-1] or np.allclose(a0, lam[-1] * np.eye(3), rtol=1e-9, atol=0):
            return None
        return lam[-1] * np.linalg.inv(a0)


def _check_planar(img: np.ndarray, what: str) -> np.ndarray:
    img = np.asarray(img)
    if img.ndim != 3 or img.shape[0] != 3:
        raise InputError(f"{what} must be planar (3, H, W); got shape {img.shape}. "
                         "Convert an (H, W, 3) image with img.transpose(2, 0, 1).")
    return img


def _apply(m: np.ndarray, img: np.ndarray) -> np.ndarray:
    """``(m @ img)`` per pixel for planar (3, H, W) ``img``; keeps img's float dtype."""
    return np.tensordot(m.astype(img.dtype), img, axes=1)


def rgb_to_ycbcr(img: np.ndarray) -> np.ndarray:
    """Planar RGB (3, H, W) -> planar YCbCr (3, H, W), BT.601 full range, no chroma offset."""
    img = _check_planar(img, "img")
    return _apply(M_RGB_TO_YCBCR, img.astype(np.result_type(img.dtype, np.float32), copy=False))


def ycbcr_to_rgb(img: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rgb_to_ycbcr`."""
    img = _check_planar(img, "img")
    return _apply(np.linalg.inv(M_RGB_TO_YCBCR),
                  img.astype(np.result_type(img.dtype, np.float32), copy=False))


def forward_differences(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """4-connected forward differences of the last two axes, each neighbour pair once.

    Returns
    -------
    dx : (..., H, W-1)   ``x[..., y, i+1] - x[..., y, i]``
    dy : (..., H-1, W)   ``x[..., j+1, x] - x[..., j, x]``
    """
    return np.diff(x, axis=-1), np.diff(x, axis=-2)


def laplacian(x: np.ndarray) -> np.ndarray:
    """``∇ᵀ∇ x`` for the forward differences above: the graph Laplacian of the 4-connected
    pixel grid, ``Σ_{j ~ i} (x_i − x_j)``, with only in-frame neighbours (Neumann border)."""
    dx, dy = forward_differences(x)
    out = np.zeros_like(x)
    # ∇ᵀ of a forward difference: -d at its left/top end, +d at its right/bottom end.
    out[..., :, :-1] -= dx
    out[..., :, 1:] += dx
    out[..., :-1, :] -= dy
    out[..., 1:, :] += dy
    return out


def metric_field(e: np.ndarray, metric: Metric) -> np.ndarray:
    """``Q e = Mᵀ (a ⊙ M e + s ⊙ Lap(M e))`` — the field the adjoint blur turns into the
    gradient (``∇d = 2 Fᵀ Q e``).

    Parameters
    ----------
    e : (3, H, W) float32 or float64
        Residual ``F P − I``, planar RGB.
    metric : Metric

    Returns
    -------
    (3, H, W) array of e's dtype.
    """
    e = _check_planar(e, "e")
    c = _apply(metric.matrix, e)
    w = metric.pixel.astype(e.dtype)[:, None, None] * c
    if metric.spatial.any():
        w += metric.spatial.astype(e.dtype)[:, None, None] * laplacian(c)
    return _apply(metric.matrix.T, w)


def distance(e: np.ndarray, metric: Metric) -> float:
    """Eq. 4 of the residual ``e = F P − I`` (planar (3, H, W)), accumulated in float64."""
    e = _check_planar(e, "e").astype(np.float64, copy=False)
    c = _apply(metric.matrix, e)
    d = float(np.einsum("k,khw,khw->", metric.pixel, c, c))
    if metric.spatial.any():
        # Eq. 4, with the sign of the spatial term corrected — see DESIGN.md §3: the paper
        # prints [(Y_ip^i − Y_ip^j) + (Y_op^i − Y_op^j)]², but the intended term penalises the
        # *difference* of the two neighbour differences, (Y_op^i − Y_op^j) − (Y_ip^i − Y_ip^j)
        # = ∇e_Y, so that edges of the input are kept rather than smoothed away.
        dx, dy = forward_differences(c)
        d += float(np.einsum("k,khw,khw->", metric.spatial, dx, dx))
        d += float(np.einsum("k,khw,khw->", metric.spatial, dy, dy))
    return d


def distance_and_gradient(P: np.ndarray, target: np.ndarray, psfs: np.ndarray, idx: np.ndarray,
                          wts: np.ndarray, metric: Metric, dtype=np.float32
                          ) -> tuple[float, np.ndarray]:
    """``d(F P, I)`` and ``∇_P d = 2 Fᵀ Q (F P − I)``.

    Parameters
    ----------
    P, target : (3, H, W) float
        Projector image and target I (linear light).
    psfs, idx, wts : the kernel field F (docs/internals.md).
    metric : Metric
    dtype : float32 (as the device) or float64 (for finite-difference checks).

    Returns
    -------
    d : float
    grad : (3, H, W) array of ``dtype``
    """
    P = _check_planar(P, "P").astype(dtype, copy=False)
    target = _check_planar(target, "target").astype(dtype, copy=False)
    e = blur_forward(P, psfs, idx, wts, dtype=dtype) - target
    q = metric_field(e, metric)
    return distance(e, metric), 2 * blur_adjoint(q, psfs, idx, wts, dtype=dtype)


def exact_step(grad: np.ndarray, direction: np.ndarray, f_direction: np.ndarray,
               metric: Metric) -> float:
    """Minimiser ``t*`` of ``d(P + t s)`` (unconstrained): ``−⟨∇d, s⟩ / (2 ⟨F s, Q F s⟩)``.

    Parameters
    ----------
    grad : (3, H, W)  ``∇d`` at P.
    direction : (3, H, W)  s.
    f_direction : (3, H, W)  ``F s``.
    metric : Metric

    Returns
    -------
    float; 0 when ``F s`` carries no weight under the metric.
    """
    curv = distance(f_direction, metric)  # ⟨F s, Q F s⟩ = d of the residual F s
    if curv <= 0:
        return 0.0
    return -float(np.vdot(grad.astype(np.float64), direction.astype(np.float64))) / (2 * curv)
