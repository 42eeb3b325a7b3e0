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

With a residual scale S (``surface="flatten"``: ``d(S (F P − T))``, DESIGN.md §3) the ops
precondition both: ``s = −p ⊙ ∇d`` and ``P − (2/L) p ⊙ G`` with the diagonal
``p = 1 / Fᵀ(S² ⊙ F 1)`` (:func:`rtdefocus.reference.ops.scale_preconditioner`), so that dark
pixels of the wall converge as fast as bright ones and ``L`` stays the plain blur's; the exact
line search uses ``−⟨∇d, s⟩ = 2 Σ p g²`` instead of ``2 ‖s‖²``.

Backends: the solver is handed an ops object — :class:`rtdefocus.reference.ops.NumpyOps` (the
reference) or :class:`rtdefocus.cl.solve.ClSolveOps` (OpenCL), with the same primitive
operations (:mod:`rtdefocus.compensate.backends` builds one by name; this module imports
neither); the iteration logic below is shared, so the two backends differ only in float32 rounding.

Baselines kept for comparison: :func:`rtdefocus.compensate.wiener.wiener_prefilter` (Brown et
al. 2006); the per-channel RGB least squares of Zhang & Nayar 2006 is this solver with
:meth:`Metric.rgb`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..reference.lut import apply_headroom
from ..reference.metric import Metric

log = logging.getLogger(__name__)

__all__ = ["BOOST_CAP", "PRECONDITIONERS", "SOLVERS", "SolveInfo", "Solver", "boost_gammas",
           "lipschitz_estimate"]

SOLVERS = ("fista", "pg")
#: FISTA's preconditioners (:class:`Solver`): colour and spatial, colour only, none.
PRECONDITIONERS = ("colour+spatial", "colour", None)


def check_precondition(precondition) -> None:
    """Raise :class:`InputError` unless ``precondition`` is one of :data:`PRECONDITIONERS`."""
    if precondition not in PRECONDITIONERS:
        raise InputError(f"precondition must be one of {PRECONDITIONERS} ('colour+spatial': the "
                         f"default; None: plain FISTA steps); got {precondition!r}")


def check_solver(solver: str) -> None:
    """Raise :class:`InputError` unless ``solver`` is one of :data:`SOLVERS`."""
    if solver not in SOLVERS:
        raise InputError(f"solver must be one of {SOLVERS}; got {solver!r}")


def lipschitz_estimate(psfs: np.ndarray, metric: Metric, size: int = 64,
                       colour: np.ndarray | None = None) -> float:
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
    colour : (3, 3) symmetric positive definite, optional
        A colour preconditioner C (:attr:`Metric.colour_preconditioner`): the estimate for the
        steps along ``C ∇d``, whose Hessian per frequency is similar to
        ``C^½ (A0 + λ A1) C^½``.

    Returns
    -------
    float
    """
    spec, _, top = _spectra(psfs, metric, size, colour)
    return float(2.0 * (spec.max(axis=0) * top).max())


def _spectra(psfs, metric: Metric, size: int, colour):
    """Per PSF ``|ψ̂(ω)|²`` (N, n, n//2+1), the Laplacian's symbol λ(ω) and
    ``λ_max(C^½ (A0 + λ A1) C^½)`` per frequency, on an n × n grid (n = max(size, k))."""
    psfs = np.asarray(psfs, dtype=np.float64)
    n = max(size, psfs.shape[1])
    spec = np.abs(np.fft.rfft2(psfs, s=(n, n))) ** 2          # (N, n, n//2+1)
    wy = 2 * np.pi * np.fft.fftfreq(n)[:, None]
    wx = 2 * np.pi * np.fft.rfftfreq(n)[None, :]
    lam = 4 * np.sin(wx / 2) ** 2 + 4 * np.sin(wy / 2) ** 2
    a0, a1 = metric.qmatrices
    # λ_max(A0 + λ A1) for every frequency: eigenvalues of a batch of symmetric 3×3 matrices.
    mats = a0[None, None] + lam[..., None, None] * a1[None, None]
    if colour is not None:
        w, v = np.linalg.eigh(np.asarray(colour, dtype=np.float64))
        root = (v * np.sqrt(w)) @ v.T
        mats = root @ mats @ root
    return spec, lam, np.linalg.eigvalsh(mats)[..., -1]


#: The solver's margin over :func:`lipschitz_estimate` (not a strict bound for a spatially
#: varying F): ``L = L_MARGIN * estimate``; :func:`boost_gammas` works within the estimate itself.
L_MARGIN = 1.05

#: The largest weight of the spatial preconditioner (:func:`boost_gammas`). On the 800×600
#: cubicle (oracle kernels, PSF radii 1–6 px; eval-like clip, 2 cores, PoCL) a cap of 2 gave
#: +0.44 dB at 2 iterations per frame on a 14 px/frame pan and +0.26 dB at 40 cold iterations;
#: 8 gave +0.03 dB more at 2 iterations but lost 0.3 dB at 40 (a wider departure from the
#: box-constrained steps).
BOOST_CAP = 2.0


def boost_gammas(psfs: np.ndarray, metric: Metric, L: float, colour=None, cap: float = BOOST_CAP,
                 size: int = 64) -> np.ndarray:
    """One weight γ per PSF for FISTA's spatial preconditioner ``M = I + ∇ᵀ Γ ∇``.

    A blurry PSF passes little of the high frequencies, so there the curvature of d is far
    below the step size's bound ``L`` (set by the sharpest PSF and by low frequencies) and
    those components — the fine pre-sharpening pattern — converge slowly. M multiplies
    frequency ω by ``1 + γ λ(ω)``; each PSF gets the largest γ (up to ``cap``) that keeps its
    own ``2 |ψ̂(ω)|² (1 + γ λ(ω)) λ_max(C^½ Q(ω) C^½)`` within ``L / L_MARGIN`` (the bound
    without its margin): the sharpest PSF gets 0, the blurriest the most, and the step stays ``2/L``.

    Parameters
    ----------
    psfs : (N, k, k); metric : Metric; L : the solver's Lipschitz estimate (with its margin);
    colour : the colour preconditioner C in use, or None; cap : the largest γ.

    Returns
    -------
    (N,) float64, in [0, cap]
    """
    spec, lam, top = _spectra(psfs, metric, size, colour)
    cur = 2.0 * spec * top[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(cur * lam[None] > 0, (L / L_MARGIN - cur) / (cur * lam[None]), np.inf)
    return np.clip(room.reshape(len(spec), -1).min(axis=1), 0.0, float(cap))


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


# --------------------------------------------------------------------------- the solver
class Solver:
    """Projected-gradient / FISTA solve of ``min d(F P, I), 0 <= P <= 1`` for one frame size.

    Parameters
    ----------
    ops : NumpyOps or ClSolveOps
        The backend: the primitive operations on one frame size (its ``shape``), for one kernel
        field (its ``psfs``) and :class:`Metric` (its ``metric``). Build one by name with
        :func:`rtdefocus.compensate.backends.make_solve_ops`, or use
        :func:`~rtdefocus.compensate.backends.make_solver` for both steps.
    solver : "fista" | "pg"
    precondition : "colour+spatial" | "colour" | None
        FISTA only (ignored for PG and where the residual is scaled, ``surface="flatten"``):
        ``"colour"`` steps along ``C ∇d`` with the metric's colour preconditioner
        (:attr:`~rtdefocus.reference.metric.Metric.colour_preconditioner`, where it has one):
        chroma errors fall as fast as luma ones (800×600 cubicle: +0.4 dB camera-view PSNR at
        40 iterations, +0.35–0.45 dB in the live path at 2 iterations per frame). The clamp to
        [0, 1] is then not the exact projection in C's metric, so the limit can sit slightly
        above the plain solver's (0.15–0.4 % in d after 300 iterations at 400×300).
        ``"colour+spatial"`` (default) also applies ``M = I + ∇ᵀ Γ ∇`` to every gradient on
        its free set (with any metric; :attr:`precondition` then reads what is on:
        ``"colour+spatial"``, ``"colour"``, ``"spatial"`` or None; :func:`boost_gammas`,
        :func:`rtdefocus.reference.ops.boost_field`): the
        fine pre-sharpening pattern of the blurriest regions converges several times faster
        (one stencil pass per iteration). Every accepted step still lowers d.

    Notes
    -----
    All working buffers are allocated here, once; :meth:`solve` and :meth:`run` only enqueue
    work. ``self.target`` and ``self.P`` are the backend's arrays of the current target and
    solution; :meth:`run` starts from whatever ``self.P`` holds (warm start).
    """

    def __init__(self, ops, *, solver: str = "fista",
                 precondition: str | None = "colour+spatial"):
        check_solver(solver)
        check_precondition(precondition)
        self.ops = ops
        self.metric = ops.metric
        self.solver = solver
        self.backend = ops.backend
        self.shape = ops.shape
        # FISTA's field q is C Q e throughout (every metric_residual of this solver), so that
        # its gradients G = Fᵀ q and the momentum built from them are all preconditioned.
        colour = ops.colour_pc if precondition is not None and solver == "fista" else None
        self._colour = colour is not None
        # 5 % over the estimate: it is not a strict bound for a spatially varying F (see there).
        # A residual scale S (surface="flatten") comes with a diagonal preconditioner that brings
        # the Hessian back to the plain blur's (ops.lipschitz_factor = 1; NumpyOps.precond).
        self.L = (lipschitz_estimate(ops.psfs, ops.metric, colour=colour) * L_MARGIN
                  * ops.lipschitz_factor)
        self._L_estimate = self.L
        # The spatial preconditioner: the gradient G is M_F Fᵀ q wherever FISTA forms one
        # (_gradient), so that G_prev and the momentum are preconditioned alike.
        # (any metric, also one without a colour preconditioner; not with a residual scale)
        self._boost = False
        if precondition == "colour+spatial" and solver == "fista" and not ops.has_scale:
            gammas = boost_gammas(ops.psfs, ops.metric, self.L, colour)
            if gammas.max() > 0:
                ops.set_boost(gammas)
                self._boost = True
        self.precondition = {(True, True): "colour+spatial", (True, False): "colour",
                             (False, True): "spatial", (False, False): None}[
                                 (self._colour, self._boost)]
        new = self.ops.new
        self.target, self.target_prev = new(), new()
        self.P, self._P_prev, self._P_alt = new(), new(), new()
        self._q, self._q_alt = new(), new()
        self._fp, self._fp_alt = new(), new()
        self._G, self._G_prev = new(), new()         # F^T q at P and at P_prev (FISTA)
        self._G_alt = new() if self._boost else None  # M_F's output (then swapped into _G)
        self._s, self._fs = new(), new()
        # What carries over between calls of run() (a video: one call per frame). ``_d`` is the
        # distance at P for the current target with ``_q`` (and ``_fp``) up to date, or None;
        # ``_grad_ready``: ``_G`` holds Fᵀ q at P; FISTA's momentum: ``_theta``, ``_beta`` and
        # ``_P_prev``/``_G_prev``, valid while ``_momentum`` is set.
        self._d: float | None = None
        self._grad_ready = False
        self._momentum = False
        self._theta, self._beta = 1.0, 0.0
        self._carried = (False, 1.0, 0.0)            # the momentum begin_frame kept
        # A warm start's momentum, moved along the motion but for G_prev (theta, beta), or None:
        # the gradient at the new P and the carry of G_prev are the first iteration's work, so
        # run() does them, and a frame shown from its start alone (0 iterations) never pays them.
        self._pending: tuple[float, float] | None = None
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
            self.start_from_target()
        else:
            self.set_start(P0)
        info = self.run(iterations, tol)
        return self.ops.download(self.P), info

    # ------------------------------------------------------------------ starts (a video)
    def target_changed(self) -> None:
        """Call after writing ``self.target`` directly (e.g. ``ops.decode``): what was known
        about P (its distance, gradient, momentum) no longer holds."""
        self._forget_p()

    def _forget_p(self) -> None:
        """P or the target changed: its distance, gradient and momentum are unknown."""
        self._d = None
        self._grad_ready = False
        self._pending = None
        self.reset_momentum()

    def reset_momentum(self) -> None:
        self._momentum = False
        self._theta, self._beta = 1.0, 0.0

    def start_from_target(self) -> None:
        """``P = clamp(target)`` on the backend (the cold start, P_0 = I_ip)."""
        self.ops.clamp_copy(self.target, self.P)
        self._forget_p()

    def set_start(self, P0: np.ndarray) -> None:
        """Start the next :meth:`run` from ``clamp(P0)`` (host ``(3, H, W)``), without momentum."""
        P0 = np.asarray(P0, dtype=np.float32)
        if P0.shape != self.shape:
            raise InputError(f"P0 must be {self.shape}; got {P0.shape}")
        self.ops.upload(np.clip(P0, 0.0, 1.0), self.P)
        self._forget_p()

    def cold_distance(self) -> float:
        """d at the cold start ``clamp(target)`` (one blur), left with its blur and residual in
        the solver's spare buffers for :meth:`keep_better_than_cold`; a caller may run it while
        another thread does host work (the motion estimate): it waits on the device only."""
        ops = self.ops
        ops.clamp_copy(self.target, self._P_alt)
        ops.forward(self._P_alt, self._fp_alt)
        return ops.metric_residual(self._fp_alt, self.target, self._q_alt, colour=self._colour)

    def keep_better_than_cold(self, d_cold: float | None = None) -> tuple[bool, float, float]:
        """Keep the current start P only if it is at least as close as the cold start.

        Evaluates ``d`` at P and at ``clamp(target)`` (one blur each; ``d_cold`` given: the
        latter came from :meth:`cold_distance` since the target was set, and P is not in its
        buffers) and leaves the better in P, with its residual ready for :meth:`run`; choosing
        the cold start drops the momentum. Since every solver step is monotone, the frame then
        ends no farther from the target than geometry only (the cold start) — whatever the
        warm start was.

        Returns
        -------
        (kept, d_start, d_cold) : whether the warm start was kept, the distance :meth:`run` now
        starts from, and the cold start's.
        """
        ops = self.ops
        if self._d is None:
            ops.forward(self.P, self._fp)
            self._d = ops.metric_residual(self._fp, self.target, self._q, colour=self._colour)
        if d_cold is None:
            d_cold = self.cold_distance()
        if d_cold < self._d:
            self.P, self._P_alt = self._P_alt, self.P
            self._fp, self._fp_alt = self._fp_alt, self._fp
            self._q, self._q_alt = self._q_alt, self._q
            self._d = d_cold
            self._grad_ready = False
            self.reset_momentum()
            return False, d_cold, d_cold
        return True, self._d, d_cold

    def begin_frame(self) -> None:
        """A video's next frame: keep the current target (as ``target_prev``, on the backend)
        and FISTA's momentum for :meth:`start_from_motion`; write the new target into
        ``self.target`` next (then :meth:`target_changed`)."""
        self.target, self.target_prev = self.target_prev, self.target
        self._carried = (self._momentum, self._theta, self._beta)
        # Each frame starts again from the estimated step: near convergence float32 rounding
        # makes plain steps look uphill and halves the step, and carried over frame after frame
        # those halvings stalled a video's solve (the step 4000x too small after a still).
        self.L = self._L_estimate

    def start_from_motion(self, d_cold: float | None = None, momentum: bool = True) -> bool:
        """Start from the previous frame's correction moved along the motion (on the backend,
        no host round trip): ``P = clamp(T + B(P − T_prev))`` where the motion is valid, the
        cold start ``clamp(T)`` elsewhere; B is the motion set by ``ops.set_motion``. Kept only
        when it is at least as close as the cold start (:meth:`keep_better_than_cold`); then
        FISTA's previous iterate and gradient move the same way (``P_prev`` here, ``G_prev``
        with the gradient at the new P in :meth:`run`'s first iteration), with the momentum
        dropped pixel by pixel where the motion is invalid (``P_prev = P``, ``G_prev = G``: a
        plain step there). ``momentum`` False (a frame shown from its start alone, 0
        iterations) carries none: the next frame starts its iterations plain. Call after
        :meth:`begin_frame` and the new target (``d_cold``: from :meth:`cold_distance` on that
        target, see :meth:`keep_better_than_cold`).

        Returns
        -------
        bool : whether the warm start was kept (else the solve starts cold).
        """
        ops = self.ops
        carried, theta, beta = self._carried
        momentum = momentum and carried and self.solver == "fista"
        # P into _s (_P_alt may hold the cold start of cold_distance) and, in the same pass,
        # P_prev into _fs (where the motion is invalid both become the cold start: P_prev = P);
        # the second field costs ~half a carry, and is wasted only when the cold start wins.
        ops.carry(self.P, self.target, self._s, base_prev=self.target_prev,
                  base_new=self.target, clamp=True, src2=self._P_prev if momentum else None,
                  dst2=self._fs if momentum else None)
        self.P, self._s = self._s, self.P
        self._forget_p()
        kept, _, _ = self.keep_better_than_cold(d_cold)
        if not kept or not momentum:
            return kept
        self._P_prev, self._fs = self._fs, self._P_prev
        self._pending = (theta, beta)               # (G and G_prev: run()'s first iteration)
        return True

    def _resume_momentum(self, theta: float, beta: float) -> None:
        """The warm start's momentum, completed: the gradient at the new P and G_prev moved
        along the motion (where it is invalid, G_prev = G: a plain step there)."""
        self._gradient()
        self._grad_ready = True
        self.ops.carry(self._G_prev, self._G, self._fs)
        self._G_prev, self._fs = self._fs, self._G_prev
        self._theta, self._beta, self._momentum = theta, beta, True

    def run(self, iterations: int, tol: float = 0.0) -> SolveInfo:
        """Iterate from the current ``self.P`` towards ``self.target`` (both on the backend).

        Continues where the previous call stopped when nothing changed in between (the same
        target: a paused video, a slide): FISTA keeps its momentum, so k calls of n iterations
        converge like one call of k·n.
        """
        if iterations < 0:
            raise InputError(f"iterations must be >= 0; got {iterations}")
        t0 = time.perf_counter()
        info = SolveInfo(self.solver)
        ops = self.ops
        fista = self.solver == "fista" and iterations > 0
        pending, self._pending = self._pending, None
        if self._d is None:
            ops.forward(self.P, self._fp)
            # FISTA keeps the distance on the device (no read-back until the run ends)
            self._d = ops.metric_residual(self._fp, self.target, self._q, reduce=not fista,
                                          colour=self._colour)
        if pending is not None and fista:
            self._resume_momentum(*pending)
        if fista:
            self._run_fista(iterations, tol, info)
        else:
            info.distances.append(self._d)
            if iterations > 0:
                self._run_pg(iterations, tol, info)
        self._d = info.distances[-1]
        ops.finish()
        info.seconds = time.perf_counter() - t0
        return info

    # ------------------------------------------------------------------ PG
    def _run_pg(self, iterations: int, tol: float, info: SolveInfo) -> None:
        ops = self.ops
        d = info.distances[-1]
        self._grad_ready = False          # PG reuses _G as scratch
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
    def _gradient(self) -> None:
        """``G = Fᵀ q`` at P, through the spatial preconditioner M_F when it is on."""
        self.ops.gradient(self._q, self._G)
        if self._boost:
            self.ops.boost_gradient(self.P, self._G, self._G_alt)
            self._G, self._G_alt = self._G_alt, self._G

    def _run_fista(self, iterations: int, tol: float, info: SolveInfo) -> None:
        """FISTA with its restart test on the backend (``ops.fista_decide``): a step that
        increased d is undone there (``ops.fista_undo`` copies P and q back), so the host
        rotates its buffers the same way after every step and reads the distances, the momentum
        and the step once, at the end. Only a tolerance (``tol > 0``) reads back per iteration."""
        ops = self.ops
        theta, beta = (self._theta, self._beta) if self._momentum else (1.0, 0.0)
        ops.fista_state_write(self._d, theta, beta, 2.0 / self.L, iterations)
        if self._d is None:
            ops.fista_set_d()             # from run()'s metric_residual
        have_grad = self._grad_ready      # G holds F^T q at the current P
        done = 0
        for k in range(iterations):
            if not have_grad:
                self._gradient()
            # By linearity the gradient at y = P + β (P − P_prev) is G + β (G − G_prev): one
            # adjoint per iteration, at the accepted iterate (after a rejected step, the same
            # gradient again). β and the step come from the backend's state.
            dd, pp = ops.fista_step(self.P, self._P_prev, self._G, self._G_prev, None, None,
                                    self._P_alt, sums=tol > 0)
            ops.forward(self._P_alt, self._fp)
            ops.metric_residual(self._fp, self.target, self._q_alt, reduce=False,
                                colour=self._colour)
            ops.fista_decide(k)
            ops.fista_undo(self.P, self._P_alt, self._q, self._q_alt)
            self._P_prev, self.P, self._P_alt = self.P, self._P_alt, self._P_prev
            self._q, self._q_alt = self._q_alt, self._q
            self._G_prev, self._G = self._G, self._G_prev
            have_grad = False
            done = k + 1
            if tol > 0 and ops.fista_accepted():
                rel = math.sqrt(dd / max(pp, 1e-30))
                info.rel_change = rel
                if rel < tol:
                    info.converged = True
                    break
        st = ops.fista_state_read(done)
        info.iterations = done
        info.distances.extend(st["log"])
        info.restarts = st["restarts"]
        # The step halves (L doubles) where even a plain step increased d (the backend's state
        # holds it in float32: count the halvings rather than invert it).
        halvings = round(math.log2(float(np.float32(2.0 / self.L)) / st["step"]))
        if halvings > 0:
            self.L *= 2.0 ** halvings
            log.debug("FISTA: a plain step increased d; L raised to %.4g", self.L)
        # The momentum (and P_prev, G_prev) stay valid for the next call on the same target.
        self._theta, self._beta, self._momentum = st["theta"], st["beta"], True
        self._grad_ready = have_grad
