"""The compensation solve: ``min_P d(F P, I)`` subject to ``0 <= P <= 1`` (DESIGN.md §3).

Two solvers behind one interface (:class:`Solver`), each on two backends with the same maths:

``"pg"``     projected gradient with exact line search — the paper's "constrained steepest
             descent", made monotone. Direction ``s = −∇d`` on the free set (components at a
             bound that would leave [0, 1] are frozen), exact step ``t* = ‖s‖²/⟨Fs, Q Fs⟩``
             (the distance is a quadratic, so one more F gives the parabola), then the clamp.
             If the clamp changed anything, the chord from the old to the clamped P is searched
             exactly too (its parabola needs one more F): the distance never increases.
``"fista"``  FISTA (Beck & Teboulle 2009) with step ``1/L`` and function-value adaptive
             restart (O'Donoghue & Candès 2015): a step that increases ``d`` is rejected and the
             momentum reset, so this variant is monotone as well. ``L`` is estimated from the PSFs
             in the frequency domain (:func:`lipschitz_estimate`) and doubled if even a plain
             projected step fails to decrease ``d``. By linearity the gradient at the
             extrapolated point is ``G_k + β (G_k − G_{k−1})`` with ``G = Fᵀ q`` at the iterates:
             two blurs per iteration (one forward, one adjoint).

Backends: :class:`NumpyOps` (the reference, here) and :class:`rtdefocus.cl.solve.ClSolveOps`
(OpenCL), with the same primitive operations; the iteration logic below is shared, so the
two backends differ only in float32 rounding.

Baselines kept for comparison: :func:`wiener_prefilter` (Brown et al. 2006); the per-channel RGB
least squares of Zhang & Nayar 2006 is this solver with :meth:`Metric.rgb`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..reference.blur import (
    blur_adjoint,
    blur_adjoint_filter2d,
    blur_forward,
    blur_forward_filter2d,
    check_field,
)
from ..reference.metric import Metric, metric_field

log = logging.getLogger(__name__)

__all__ = [
    "SOLVERS", "SolveInfo", "Solver", "NumpyOps", "lipschitz_estimate", "wiener_prefilter",
    "apply_headroom", "increasing_lut", "decode_lut", "encode_lut", "inverse_lut_tables",
    "headroom_params",
]

SOLVERS = ("fista", "pg")


# --------------------------------------------------------------------------- helpers
def _f64sum(x: np.ndarray) -> float:
    return float(np.add.reduce(x, axis=None, dtype=np.float64))


def _vdot(a: np.ndarray, b: np.ndarray) -> float:
    return _f64sum(a * b)


def apply_headroom(target: np.ndarray, headroom: tuple[float, float] | None) -> np.ndarray:
    """Map the target from [0, 1] into ``[lo, hi]`` (``None``: unchanged).

    Compensation needs room above and below the target to pre-sharpen; a target of pure black
    and white (text) has none, so the clamp to [0, 1] limits what the solve can do. Mapping the
    target into [lo, hi] trades contrast for that room.
    """
    lo, scale = headroom_params(headroom)
    if lo == 0.0 and scale == 1.0:
        return target
    return (lo + scale * np.asarray(target, dtype=np.float32)).astype(np.float32)


def headroom_params(headroom: tuple[float, float] | None) -> tuple[float, float]:
    """``(lo, hi − lo)`` of a headroom pair, validated; ``(0, 1)`` for ``None``."""
    if headroom is None:
        return 0.0, 1.0
    try:
        lo, hi = (float(v) for v in headroom)
    except (TypeError, ValueError):
        raise InputError(f"headroom must be a pair (lo, hi); got {headroom!r}") from None
    if not (0.0 <= lo < hi <= 1.0):
        raise InputError(f"headroom must satisfy 0 <= lo < hi <= 1; got ({lo}, {hi})")
    return lo, hi - lo


def increasing_lut(lut: np.ndarray) -> np.ndarray:
    """A strictly increasing copy of a (3, 256) response LUT, fit for inversion.

    A measured response can be flat (saturation, quantisation) or dip by noise; the running
    maximum plus a ramp of 1e-6 per code keeps the order without visibly moving any value.
    """
    lut = np.asarray(lut, dtype=np.float64)
    if lut.shape != (3, 256):
        raise InputError(f"response LUT must be (3, 256); got {lut.shape}")
    mono = np.maximum.accumulate(lut, axis=1) + 1e-6 * np.arange(256)
    return mono.astype(np.float32)


def decode_lut(codes: np.ndarray, lut: np.ndarray, headroom=None) -> np.ndarray:
    """uint8 (H, W, 3) codes -> planar (3, H, W) float32 linear light, mapped into the headroom."""
    codes = np.asarray(codes)
    if codes.dtype != np.uint8 or codes.ndim != 3 or codes.shape[2] != 3:
        raise InputError(f"expected an (H, W, 3) uint8 image; got {codes.dtype} {codes.shape}")
    lo, scale = headroom_params(headroom)
    lut = np.asarray(lut, dtype=np.float32)
    out = np.stack([lut[c][codes[..., c]] for c in range(3)])
    return (np.float32(lo) + np.float32(scale) * out).astype(np.float32)


ENC_T = 16384      # bins of the encoder's start table over P in [0, 1]
ENC_STEPS = 4      # comparisons that finish each code (exact with <= 4 code midpoints per bin)


def inverse_lut_tables(lut_increasing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tables of the encoder (shared by both backends): code midpoints and per-bin start codes.

    The code of P is the number of midpoints ``mid[c, v] = (lut[c, v] + lut[c, v+1]) / 2``
    that are ``<= P`` — the nearest code under piecewise-linear interpolation of the response.
    It is found as ``tab[c, floor(P · ENC_T)]`` (the count at the bin's start) plus
    ``ENC_STEPS`` comparisons, a fixed amount of work a device runs fast.

    Returns
    -------
    mid : (3, 256) float32, ``mid[:, 255] = +inf``
    tab : (3, ENC_T) uint8
    """
    lut = np.asarray(lut_increasing, dtype=np.float32)
    mid = np.full((3, 256), np.inf, np.float32)
    mid[:, :255] = (lut[:, :-1] + lut[:, 1:]) / np.float32(2)
    edges = (np.arange(ENC_T, dtype=np.float32) / np.float32(ENC_T))
    tab = np.stack([np.searchsorted(mid[c], edges, side="right") for c in range(3)])
    per_bin = max(int(np.bincount(np.clip((mid[c, :255] * ENC_T).astype(np.int64), 0, ENC_T - 1),
                                  minlength=ENC_T).max()) for c in range(3))
    if per_bin > ENC_STEPS:
        # Only where the response is flat to ~1e-5 (saturation): any of those codes shows the
        # same light, so a slightly low code there is harmless.
        log.debug("response LUT has %d code midpoints in one encoder bin (> %d): encoding is "
                  "approximate in its flat parts", per_bin, ENC_STEPS)
    return mid, np.minimum(tab, 255).astype(np.uint8)


def encode_lut(P: np.ndarray, lut_increasing: np.ndarray, tables=None) -> np.ndarray:
    """Planar linear (3, H, W) -> uint8 (H, W, 3) codes through the inverse response: the code
    whose response is nearest P under piecewise-linear interpolation (see
    :func:`inverse_lut_tables`; the device kernel ``encode_lut`` takes the very same steps)."""
    mid, tab = tables if tables is not None else inverse_lut_tables(lut_increasing)
    P = np.asarray(P, dtype=np.float32)
    out = np.empty(P.shape[1:] + (3,), np.uint8)
    for c in range(3):
        p = P[c]
        b = np.clip((p * np.float32(ENC_T)).astype(np.int64), 0, ENC_T - 1)
        code = tab[c][b].astype(np.int64)
        for _ in range(ENC_STEPS):
            code += p >= mid[c][code]
        out[..., c] = code
    return out


def lipschitz_estimate(psfs: np.ndarray, metric: Metric, size: int = 64) -> float:
    """Estimate of ``L``, the Lipschitz constant of ``∇d = 2 Fᵀ Q (F P − I)``.

    For a spatially invariant blur with kernel ψ the Hessian ``2 Fᵀ Q F`` is diagonal in the
    Fourier basis per 3×3 colour block: ``2 |ψ̂(ω)|² (A0 + λ(ω) A1)`` with the Laplacian's
    symbol ``λ(ω) = 4 sin²(ω_x/2) + 4 sin²(ω_y/2)``. The maximum over ω and over the measured
    PSFs is the estimate (a blend of PSFs is no sharper than its sharpest member). It is not a
    strict bound for a spatially varying F, so FISTA doubles L if a plain step fails.

    Parameters
    ----------
    psfs : (N, k, k) float
    metric : Metric
    size : FFT size (≥ k; a finer frequency grid for larger values).

    Returns
    -------
    float
    """
    psfs = np.asarray(psfs, dtype=np.float64)
    n = max(size, psfs.shape[1])
    spec = np.abs(np.fft.rfft2(psfs, s=(n, n))) ** 2          # (N, n, n//2+1)
    gain = spec.max(axis=0)
    wy = 2 * np.pi * np.fft.fftfreq(n)[:, None]
    wx = 2 * np.pi * np.fft.rfftfreq(n)[None, :]
    lam = 4 * np.sin(wx / 2) ** 2 + 4 * np.sin(wy / 2) ** 2
    a0, a1 = metric.qmatrices
    # λ_max(A0 + λ A1) for every frequency: eigenvalues of a batch of symmetric 3×3 matrices.
    mats = a0[None, None] + lam[..., None, None] * a1[None, None]
    top = np.linalg.eigvalsh(mats)[..., -1]
    return float(2.0 * (gain * top).max())


@dataclass
class SolveInfo:
    """What one solve did.

    Attributes
    ----------
    solver : "pg" | "fista"
    iterations : iterations run (FISTA counts rejected steps too).
    distances : d at the start and after every iteration (float, non-increasing).
    converged : stopped because the relative change ‖ΔP‖/‖P‖ fell below ``tol`` (or a KKT point).
    rel_change : the last relative change.
    restarts : FISTA momentum restarts (steps rejected because d increased).
    clipped_steps : PG iterations whose clamp triggered the chord search.
    seconds : wall time of the solve (device synchronised).
    """

    solver: str
    iterations: int = 0
    distances: list = field(default_factory=list)
    converged: bool = False
    rel_change: float = float("nan")
    restarts: int = 0
    clipped_steps: int = 0
    seconds: float = 0.0


# --------------------------------------------------------------------------- NumPy backend
class NumpyOps:
    """The solve's primitive operations on host arrays (the reference twin of ClSolveOps).

    Parameters
    ----------
    psfs, idx, wts : the kernel field F; ``idx`` (H, W, 4) fixes the size.
    metric : Metric
    blur : "gather" (:func:`blur_forward`, the readable reference) or "filter2d" (the same
        operator through cv2.filter2D per PSF, several times faster on a CPU).
    """

    backend = "numpy"

    def __init__(self, psfs, idx, wts, metric: Metric, blur: str = "gather"):
        self.psfs, self.idx, self.wts = check_field(psfs, idx, wts)
        if blur not in ("gather", "filter2d"):
            raise InputError(f"blur must be 'gather' or 'filter2d'; got {blur!r}")
        self.metric = metric
        self.blur_form = blur
        self._fwd = blur_forward if blur == "gather" else blur_forward_filter2d
        self._adj = blur_adjoint if blur == "gather" else blur_adjoint_filter2d
        h, w = self.idx.shape[:2]
        self.shape = (3, h, w)

    def new(self) -> np.ndarray:
        return np.zeros(self.shape, np.float32)

    def upload(self, host, dst) -> None:
        host = np.asarray(host, dtype=np.float32)
        if host.shape != self.shape:
            raise InputError(f"expected a {self.shape} (3, H, W) image, got {host.shape}")
        dst[...] = host

    def download(self, src) -> np.ndarray:
        return src.copy()

    def copy(self, src, dst) -> None:
        dst[...] = src

    def clamp_copy(self, src, dst) -> None:
        np.clip(src, 0.0, 1.0, out=dst)

    def finish(self) -> None:
        pass

    def forward(self, src, dst) -> None:
        dst[...] = self._fwd(src, self.psfs, self.idx, self.wts)

    def adjoint(self, src, dst) -> None:
        dst[...] = self._adj(src, self.psfs, self.idx, self.wts)

    def metric_residual(self, fp, target, q) -> float:
        e = fp - target
        q[...] = metric_field(e, self.metric)
        return _vdot(e, q)

    def metric_update(self, fp, fs, t, target, fp_out, q) -> float:
        fp_out[...] = fp + np.float32(t) * fs
        return self.metric_residual(fp_out, target, q)

    def metric_curvature(self, fs, v=None) -> tuple[float, float]:
        qf = metric_field(fs, self.metric)
        return _vdot(fs, qf), (_vdot(fs, v) if v is not None else 0.0)

    def pg_direction(self, P, g, s) -> float:
        blocked = ((P <= 0) & (g > 0)) | ((P >= 1) & (g < 0))
        np.negative(g, out=s)
        s[blocked] = 0.0
        return _vdot(s, s)

    def pg_step(self, P, s, t, delta) -> tuple[float, float, int]:
        moved = P + np.float32(t) * s
        new = np.clip(moved, 0.0, 1.0)
        np.subtract(new, P, out=delta)
        P[...] = new
        return _vdot(delta, delta), _vdot(new, new), int(np.count_nonzero(new != moved))

    def axpy(self, x, y, a) -> None:
        x += np.float32(a) * y

    def fista_step(self, P, P_prev, G, G_prev, beta, step, P_out, sums=True) -> tuple[float, float]:
        y, gy = P, G
        if beta != 0.0:
            y = P + np.float32(beta) * (P - P_prev)
            gy = G + np.float32(beta) * (G - G_prev)
        np.clip(y - np.float32(step) * gy, 0.0, 1.0, out=P_out)
        if not sums:
            return float("nan"), float("nan")
        d = P_out - P
        return _vdot(d, d), _vdot(P_out, P_out)

    def decode(self, codes, lut, lo, scale, dst) -> None:
        lut = np.asarray(lut, dtype=np.float32)
        for c in range(3):
            dst[c] = np.float32(lo) + np.float32(scale) * lut[c][codes[..., c]]

    def encode(self, P, lut_increasing) -> np.ndarray:
        key = np.asarray(lut_increasing, np.float32).tobytes()
        if getattr(self, "_enc_key", None) != key:
            self._enc_key, self._enc_tables = key, inverse_lut_tables(lut_increasing)
        return encode_lut(P, lut_increasing, self._enc_tables)


# --------------------------------------------------------------------------- the solver
class Solver:
    """Projected-gradient / FISTA solve of ``min d(F P, I), 0 <= P <= 1`` for one frame size.

    Parameters
    ----------
    psfs, idx, wts : the kernel field F (docs/internals.md); ``idx`` (H, W, 4) fixes the size.
    metric : Metric, optional
        Default: :meth:`Metric.ycbcr` with the Compensator's default weights.
    backend : "numpy" | "opencl"
    solver : "fista" | "pg"
    runtime : rtdefocus.cl.runtime.ClRuntime, optional (OpenCL; default: the process runtime)
    blur : "gather" | "filter2d" (NumPy backend only; see :class:`NumpyOps`)
    blur_variant : "cpu" | "gpu" (OpenCL backend only; default by device type)

    Notes
    -----
    All working buffers are allocated here, once; :meth:`solve` and :meth:`run` only enqueue
    work. ``self.target`` and ``self.P`` are the backend's arrays of the current target and
    solution; :meth:`run` starts from whatever ``self.P`` holds (warm start).
    """

    def __init__(self, psfs, idx, wts, metric: Metric | None = None, *, backend: str = "numpy",
                 solver: str = "fista", runtime=None, blur: str = "gather",
                 blur_variant: str | None = None):
        if solver not in SOLVERS:
            raise InputError(f"solver must be one of {SOLVERS}; got {solver!r}")
        if metric is None:
            from .compensator import DEFAULT_WEIGHTS
            metric = Metric.ycbcr(DEFAULT_WEIGHTS)
        self.metric = metric
        self.solver = solver
        if backend == "numpy":
            self.ops = NumpyOps(psfs, idx, wts, metric, blur=blur)
        elif backend == "opencl":
            from ..cl.runtime import get_runtime
            from ..cl.solve import ClSolveOps
            self.ops = ClSolveOps(runtime or get_runtime(), psfs, idx, wts, metric,
                                  blur_variant=blur_variant)
        else:
            raise InputError(f"backend must be 'numpy' or 'opencl'; got {backend!r}")
        self.backend = backend
        self.shape = self.ops.shape
        # 5 % over the estimate: it is not a strict bound for a spatially varying F (see there).
        self.L = lipschitz_estimate(psfs, metric) * 1.05
        new = self.ops.new
        self.target = new()
        self.P, self._P_prev, self._P_alt = new(), new(), new()
        self._q, self._q_alt = new(), new()
        self._fp, self._fp_alt = new(), new()
        self._G, self._G_prev = new(), new()         # F^T q at P and at P_prev (FISTA)
        self._s, self._fs = new(), new()

    # ------------------------------------------------------------------ public
    def solve(self, target: np.ndarray, P0: np.ndarray | None = None, *, iterations: int = 30,
              tol: float = 0.0, headroom=None) -> tuple[np.ndarray, SolveInfo]:
        """Solve for one target given on the host.

        Parameters
        ----------
        target : (3, H, W) float32
            I, planar linear light in [0, 1].
        P0 : (3, H, W) float32, optional
            Warm start (clamped to [0, 1]); default the (headroom-mapped) target itself.
        iterations : iteration budget.
        tol : stop when ``‖P_{k+1} − P_k‖ / ‖P_{k+1}‖ < tol`` (0: run the whole budget).
        headroom : (lo, hi), optional; see :func:`apply_headroom`.

        Returns
        -------
        P : (3, H, W) float32 in [0, 1]
        info : SolveInfo
        """
        target = np.asarray(target, dtype=np.float32)
        if target.shape != self.shape:
            raise InputError(f"target must be planar {self.shape} (3, H, W) to match the kernel "
                             f"field; got {target.shape}")
        self.ops.upload(apply_headroom(target, headroom), self.target)
        if P0 is None:
            self.ops.clamp_copy(self.target, self.P)
        else:
            P0 = np.asarray(P0, dtype=np.float32)
            if P0.shape != self.shape:
                raise InputError(f"P0 must be {self.shape}; got {P0.shape}")
            self.ops.upload(np.clip(P0, 0.0, 1.0), self.P)
        info = self.run(iterations, tol)
        return self.ops.download(self.P), info

    def start_from_target(self) -> None:
        """``P = clamp(target)`` on the backend (the cold start, P_0 = I_ip)."""
        self.ops.clamp_copy(self.target, self.P)

    def run(self, iterations: int, tol: float = 0.0) -> SolveInfo:
        """Iterate from the current ``self.P`` towards ``self.target`` (both on the backend)."""
        if iterations < 0:
            raise InputError(f"iterations must be >= 0; got {iterations}")
        t0 = time.perf_counter()
        info = SolveInfo(self.solver)
        ops = self.ops
        ops.forward(self.P, self._fp)
        info.distances.append(ops.metric_residual(self._fp, self.target, self._q))
        if iterations > 0:
            (self._run_pg if self.solver == "pg" else self._run_fista)(iterations, tol, info)
        ops.finish()
        info.seconds = time.perf_counter() - t0
        return info

    # ------------------------------------------------------------------ PG
    def _run_pg(self, iterations: int, tol: float, info: SolveInfo) -> None:
        ops = self.ops
        d = info.distances[-1]
        for _ in range(iterations):
            g, s, fs, delta = self._G, self._s, self._fs, self._G
            ops.adjoint(self._q, g)                   # ∇d = 2 g
            ss = ops.pg_direction(self.P, g, s)       # ⟨∇d, s⟩ = −2 ss
            if ss <= 0.0:                             # KKT point: nothing can move
                info.converged = True
                break
            ops.forward(s, fs)
            curv, _ = ops.metric_curvature(fs)
            if not curv > 0.0:
                info.converged = True
                break
            t = ss / curv                             # argmin of d − 2 t ss + t² curv
            dd, pp, nclip = ops.pg_step(self.P, s, t, delta)
            info.iterations += 1
            if nclip == 0:                            # the step taken is exactly t s
                d_new = ops.metric_update(self._fp, fs, t, self.target, self._fp_alt, self._q)
                rel = math.sqrt(dd / max(pp, 1e-30))
            else:
                # The clamp bent the step: search the chord old P -> clamped P exactly.
                # d(λ) = d + 2 λ ⟨F Δ, q⟩ + λ² ⟨F Δ, Q F Δ⟩, minimised on [0, 1].
                info.clipped_steps += 1
                ops.forward(delta, fs)
                curv, slope = ops.metric_curvature(fs, self._q)
                lam = min(1.0, max(0.0, -slope / curv)) if curv > 0 else 0.0
                if lam < 1.0:
                    ops.axpy(self.P, delta, lam - 1.0)   # P = P_old + λ Δ
                d_new = ops.metric_update(self._fp, fs, lam, self.target, self._fp_alt, self._q)
                rel = lam * math.sqrt(dd / max(pp, 1e-30))
            self._fp, self._fp_alt = self._fp_alt, self._fp
            d = d_new
            info.distances.append(d)
            info.rel_change = rel
            if rel < tol:
                info.converged = True
                break

    # ------------------------------------------------------------------ FISTA
    def _run_fista(self, iterations: int, tol: float, info: SolveInfo) -> None:
        ops = self.ops
        d = info.distances[-1]
        theta, beta = 1.0, 0.0
        have_grad = False                 # G holds F^T q at the current P
        for _ in range(iterations):
            if not have_grad:
                ops.adjoint(self._q, self._G)
            # By linearity the gradient at y = P + β (P − P_prev) is G + β (G − G_prev): one
            # adjoint per iteration, at the accepted iterate.
            # The step sizes are only needed for the tol test: skip that host round trip otherwise.
            dd, pp = ops.fista_step(self.P, self._P_prev, self._G, self._G_prev, beta,
                                    2.0 / self.L, self._P_alt, sums=tol > 0)
            ops.forward(self._P_alt, self._fp)
            d_new = ops.metric_residual(self._fp, self.target, self._q_alt)
            info.iterations += 1
            if d_new > d:
                # Adaptive restart: reject the step, drop the momentum; if even a plain projected
                # step went uphill, L was underestimated.
                info.restarts += 1
                if beta == 0.0:
                    self.L *= 2.0
                    log.debug("FISTA: plain step increased d; L doubled to %.4g", self.L)
                theta, beta = 1.0, 0.0
                have_grad = True
                info.distances.append(d)
                continue
            self._P_prev, self.P, self._P_alt = self.P, self._P_alt, self._P_prev
            self._q, self._q_alt = self._q_alt, self._q
            self._G_prev, self._G = self._G, self._G_prev
            have_grad = False
            d = d_new
            info.distances.append(d)
            theta_next = (1.0 + math.sqrt(1.0 + 4.0 * theta * theta)) / 2.0
            beta = (theta - 1.0) / theta_next
            theta = theta_next
            if tol > 0:
                rel = math.sqrt(dd / max(pp, 1e-30))
                info.rel_change = rel
                if rel < tol:
                    info.converged = True
                    break


# --------------------------------------------------------------------------- Wiener baseline
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
    psf_plane : (N,) int, plane of each PSF
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
