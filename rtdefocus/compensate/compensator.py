"""``rd.Compensator``: geometry + defocus compensation of frames for one calibration (DESIGN.md §2).

Per frame: warp the input into projector space (GL pass, geometry only) → decode the uint8
warp to linear light through the projector response (the target I, optionally mapped into a
headroom) → solve ``min d(F P, I), 0 <= P <= 1`` → encode P back through the inverse response
→ uint8 for the projector. With the OpenCL backend the decode, solve and encode all run on the
device in buffers allocated once.

In a video (frames passed in order, ``warm_start=True``) each solve starts from the previous
frame's correction ``P − I`` moved along the picture's motion (:mod:`.motion`), with FISTA's
momentum moved with it; pixels the motion does not explain start cold, a cut restarts from the
target, and a frame identical to the last one simply continues its solve (a paused video or a
slide converges to the full quality). The warm start is kept only when it is at least as close
to the target as the cold start, and every solver step is monotone: a shown frame is never
farther from its target than geometry only.
"""

from __future__ import annotations

import logging
import time
import weakref
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from ..calib.file import Calibration
from ..checks import check_choice, check_int, check_real
from ..cl import runtime as cl_runtime
from ..errors import CalibrationFileError, InputError, InputTypeError
from ..gl.warp import warp_image
from ..reference.blur import trim_psfs
from ..reference.lut import apply_headroom, decode_lut, encode_lut, headroom_params, increasing_lut
from ..reference.metric import DEFAULT_WEIGHTS, Metric
from ..reference.ops import check_adjoint
from .backends import make_solve_ops
from .motion import MotionEstimator
from .solvers import SOLVERS, SolveInfo, Solver, check_precondition
from .surface import SURFACES, SurfaceModel
from .wiener import wiener_prefilter

log = logging.getLogger(__name__)

__all__ = ["Compensator", "METHODS", "DEFAULT_WEIGHTS", "DEFAULT_ITERATIONS"]

METHODS = ("ycbcr", "rgb", "wiener", "none")

# DEFAULT_WEIGHTS (Eq. 4) are defined, with how they were chosen, beside Metric
# (rtdefocus/reference/metric.py).

# Iteration budget per frame (`tools/tune_metric.py solver`, cubicle, oracle kernels, five
# images): camera-view PSNR gain over geometry only for FISTA at 10/20/40/80 iterations was
# +3.2/+4.0/+4.6/+5.0 dB at 400x300 and +1.9/+2.6/+3.3/+3.6 dB at 800x600 — the knee is at 40
# (a further doubling buys < 0.4 dB). PG with exact line search reached +4.2 dB in 40 and
# +4.5 dB in 80 iterations (400x300) at 2-3 blurs per iteration against FISTA's 2, hence FISTA
# is the default solver. In a video the warm start carries the work across frames, so a smaller
# per-frame budget (`iterations=`) still converges on still content.
DEFAULT_ITERATIONS = {"fista": 40, "pg": 40}
DEFAULT_WIENER_NSR = 0.1


class Compensator:
    """Geometry and defocus compensation of frames for one calibrated set-up.

    Parameters
    ----------
    calib : rtdefocus.Calibration
        Needs the PSF section for every method but ``"none"``.
    backend : "auto" | "opencl" | "numpy"
        ``"auto"``: OpenCL when a device exists, else NumPy (with one logged warning).
    method : "ycbcr" | "rgb" | "wiener" | "none"
        ``"ycbcr"``: the paper's Eq. 4 metric (default); ``"rgb"``: per-channel least squares
        (Zhang & Nayar 2006); ``"wiener"``: per-plane Wiener pre-filter (Brown et al. 2006);
        ``"none"``: geometry only.
    solver : "fista" | "pg"
    iterations : int, optional
        Iteration budget per frame (default :data:`DEFAULT_ITERATIONS` of the solver).
    tol : float
        Stop early when ``‖ΔP‖ / ‖P‖`` falls below this (0: always run the budget).
    weights : (w1, w2, w3, w4)
        Eq. 4 weights of the ``"ycbcr"`` metric.
    headroom : (lo, hi), optional
        Map the target into [lo, hi] before solving: less contrast, fewer clipped pixels.
    warp_backend : "auto" | "gl" | "cv2"
    wiener_nsr : float
        Noise-to-signal constant of the ``"wiener"`` method.
    blur_variant : "cpu" | "gpu", optional
        OpenCL blur kernel shape (default by device type).
    surface : "keep" | "flatten"
        ``"keep"`` (default): the target is what an in-focus projector would show on the same
        walls (their colour, texture and the room light stay). ``"flatten"``: the input as on a
        uniform white wall, through the calibration's albedo and ambient, in the same solve
        (:mod:`.surface`; needs the radiometry section).
    brightness : "auto" | float
        ``surface="flatten"`` only: the global brightness b, how much brighter than black a
        white input shows (camera linear light; black shows at the room light's level); "auto"
        keeps clipping on a white input to a small share of the wall.
    psf_energy : float, optional
        Cut each kernel to the smallest window holding this share of its energy (e.g. 0.999)
        before solving: fewer taps per blur, a slightly different operator. Default: the
        kernels as calibrated (only their all-zero borders are skipped).
    adjoint : "fast" | "exact"
        How FISTA forms its gradient ``Fᵀ q`` (:data:`rtdefocus.reference.ops.ADJOINTS`):
        ``"fast"`` (default) blends the flipped PSFs at the output pixel, one forward blur's
        cost; ``"exact"`` is the true transpose (~2x the cost on a CPU device). Steps are
        accepted on the exact distance either way; on the cubicle the camera-view gain after
        2, 8 and 40 iterations differed by at most 0.01 dB.
    precondition : "colour+spatial" | "colour" | None
        How FISTA's steps are preconditioned (:class:`~rtdefocus.compensate.solvers.Solver`):
        ``"colour+spatial"`` (default) makes chroma converge as fast as luma and the fine
        pre-sharpening of the blurriest regions several times faster, for a better picture at
        every budget, above all the few iterations of live video; ``"colour"`` the first only;
        None: plain steps.

    Attributes
    ----------
    last_info : dict
        Of the last :meth:`compensate` / :meth:`solve`: ``iterations``, ``distances``,
        ``seconds`` (per stage: warp, decode, solve, encode, total), ``solver``, ``method``,
        ``warm_start``, ``restarts``, ``converged``; with ``surface="flatten"`` also
        ``brightness`` and ``clipped`` / ``clipped_dark``, the shares of lit pixels showing
        content whose target is above / below what the projector can reach.
    backend : "opencl" | "numpy" (resolved)
    """

    def __init__(self, calib, backend: str = "auto", method: str = "ycbcr", solver: str = "fista",
                 iterations: int | None = None, tol: float = 0.0,
                 weights: tuple[float, float, float, float] = DEFAULT_WEIGHTS,
                 headroom: tuple[float, float] | None = None, warp_backend: str = "auto",
                 wiener_nsr: float = DEFAULT_WIENER_NSR, blur_variant: str | None = None,
                 surface: str = "keep", brightness: str | float = "auto",
                 psf_energy: float | None = None, adjoint: str = "fast",
                 precondition: str | None = "colour+spatial"):
        _check_args(calib, method=method, solver=solver, backend=backend,
                    iterations=iterations, tol=tol, weights=weights, warp_backend=warp_backend,
                    wiener_nsr=wiener_nsr, blur_variant=blur_variant)
        check_choice(surface, SURFACES, "surface")
        check_adjoint(adjoint)
        check_precondition(precondition)
        self.adjoint = adjoint
        self.precondition = precondition
        self.psf_energy, self.blur_variant = psf_energy, blur_variant
        if psf_energy is not None and not 0.9 <= float(psf_energy) <= 1.0:
            raise InputError(f"psf_energy must be in [0.9, 1] (the share of each kernel's energy "
                             f"kept, e.g. 0.999) or None; got {psf_energy!r}")
        if method != "none" and not calib.has_psf:
            raise CalibrationFileError(
                f"method {method!r} needs the calibration's PSF section (the defocus kernels), "
                "which this calibration lacks; calibrate with the 'psf' stage "
                "(`rtdefocus calibrate ...` or rd.calibrate(procam, stages=('geometry', "
                "'radiometry', 'psf'))), or use method='none' for geometry only")
        self.calib = calib
        self.method = method
        self.solver_name = solver
        self.iterations = DEFAULT_ITERATIONS[solver] if iterations is None else int(iterations)
        self.tol = float(tol)
        self.weights = tuple(float(w) for w in weights)
        self.headroom = headroom
        headroom_params(headroom)                      # validate now, not at the first frame
        self.warp_backend = warp_backend
        self.wiener_nsr = float(wiener_nsr)
        self.backend = _resolve_backend(backend)
        self.surface = surface
        self.brightness = brightness
        self._surface = (SurfaceModel.from_calibration(calib, brightness)
                         if surface == "flatten" else None)
        self._lut = np.asarray(calib.lut, dtype=np.float32)
        self._lut_inc = increasing_lut(self._lut)
        self._solver: Solver | None = None
        self._gl_share, self._gl_fresh = None, False
        # The video state: the last frame the solver worked on (projector space, uint8; its
        # target and solution stay on the solver's backend); None until the first frame and
        # after reset().
        self._prev_warped: np.ndarray | None = None
        # The last input and its warp (compensate): a repeated input (a paused video, a slide)
        # skips the warp, which is a pure function of the input.
        self._warp_cache: tuple[np.ndarray, np.ndarray] | None = None
        self._motion = MotionEstimator()
        self._pool: ThreadPoolExecutor | None = None   # the motion estimate's thread (lazily)
        self.last_info: dict = {}
        self._last_flat: dict = {}
        if method in ("ycbcr", "rgb"):
            metric = Metric.ycbcr(self.weights) if method == "ycbcr" else Metric.rgb()
            # NumPy: the filter2D form of F (exactly the same operator, several times faster).
            scale = None if self._surface is None else self._surface.scale
            # psf_energy: each kernel cut to the window holding that share of its energy (fewer
            # taps per blur; measured kernels carry a faint noisy halo that costs time only).
            psfs = calib.psfs if psf_energy is None else trim_psfs(calib.psfs, float(psf_energy))
            ops = make_solve_ops(self.backend, psfs, calib.pix_idx, calib.pix_wts, metric,
                                 blur="filter2d", blur_variant=blur_variant, scale=scale,
                                 adjoint=adjoint, runtime=self._share_gl(warp_backend))
            self._solver = Solver(ops, solver=solver, precondition=precondition)

    # ------------------------------------------------------------------ public
    @property
    def projector_size(self) -> tuple[int, int]:
        return tuple(self.calib.projector_size)

    @property
    def shares_gl(self) -> bool:
        """The solver's OpenCL context shares the warp's GL context (:mod:`rtdefocus.cl.glshare`):
        the warp's renderbuffer is then an OpenCL image, so the warp and a solve must not run on
        two threads at once."""
        return self._gl_share is not None

    @property
    def solves_off_the_cpu(self) -> bool:
        """The solver runs on a GPU, not on the CPU cores that the frame loop and its warp use:
        a solve on another thread then takes no time from the frames shown meanwhile."""
        return self.backend == "opencl" and cl_runtime.get_runtime().is_gpu

    def display_rect(self, size: tuple[int, int]) -> tuple[int, int, int, int]:
        """Camera pixels ``(x, y, w, h)`` where an input of ``size = (w, h)`` appears."""
        return self.calib.display_rect(size)

    def with_calibration(self, calib) -> Compensator:
        """A new Compensator with this one's options for another calibration of the same
        projector (a mended one): swapping it in between two frames is atomic, and this one
        stays untouched for the frame in progress."""
        return Compensator(calib, backend=self.backend, method=self.method,
                           solver=self.solver_name, iterations=self.iterations, tol=self.tol,
                           weights=self.weights, headroom=self.headroom,
                           warp_backend=self.warp_backend, wiener_nsr=self.wiener_nsr,
                           blur_variant=self.blur_variant, surface=self.surface,
                           brightness=self.brightness, psf_energy=self.psf_energy,
                           adjoint=self.adjoint, precondition=self.precondition)

    def warp(self, image: np.ndarray) -> np.ndarray:
        """Geometry correction only: (H, W, 3) uint8 input -> (Hp, Wp, 3) uint8 projector frame."""
        return warp_image(self.calib, image, backend=self.warp_backend)

    def reset(self) -> None:
        """Forget the previous frame (the next :meth:`compensate` starts from its target): call
        it on a seek or when frames stop coming in order."""
        self._prev_warped = None

    def warm_up(self, iterations: int = 1, frames: int = 1) -> dict | None:
        """Run the video path on synthetic frames of the projector's size, moving, so that its
        first-use costs (kernel builds on the device, the motion estimate's thread and buffers)
        are paid now and not by the first moving frame of a video; then :meth:`reset`.

        Parameters
        ----------
        iterations : solver iterations per frame.
        frames : moving frames timed (at least 1): more of them measure how much the cost of
            one moving frame varies on this device (a live player's safety margin).

        Returns
        -------
        dict or None
            The last moving frame's :attr:`last_info` (its ``seconds`` stand for a moving
            frame's cost at ``iterations``), with ``"moving"``: the ``seconds`` of every timed
            moving frame, in order; None when no solver runs (``method`` ``"wiener"`` /
            ``"none"``).
        """
        if self._solver is None:
            return None
        frames = check_int(frames, "warm_up frames (moving frames timed)", lo=1)
        wp, hp = self.projector_size
        rng = np.random.default_rng(0)
        # smooth texture with edges (a flow estimate has something to follow), moved 4 px a
        # frame; the moving frames after the second are the ones timed (the first still pays
        # some first uses)
        shifts = [4 * k for k in range(frames + 2)]
        base = cv2.resize(rng.integers(0, 256, (hp // 16 + 2, wp // 16 + 2, 3), dtype=np.uint8),
                          (wp + shifts[-1], hp), interpolation=cv2.INTER_CUBIC)
        self.reset()
        moving = []
        try:
            for k, shift in enumerate(shifts):
                self.compensate(np.ascontiguousarray(base[:, shift:shift + wp]),
                                iterations=iterations)
                if k >= 2:
                    moving.append(dict(self.last_info.get("seconds") or {}))
            return {**self.last_info, "moving": moving}
        finally:
            self.reset()
            self._warp_cache = None

    def compensate(self, image: np.ndarray, *, iterations: int | None = None,
                   warm_start: bool = True) -> np.ndarray:
        """Geometry + defocus compensation of one frame.

        Parameters
        ----------
        image : (H, W, 3) uint8 RGB, any size.
        iterations : overrides the constructor's budget for this frame.
        warm_start : frames of a video, passed in order: start from the previous frame's
            correction moved along the motion (see the module docstring); else from the target.

        Returns
        -------
        (Hp, Wp, 3) uint8, for the projector.
        """
        _check_budget(iterations)
        t0 = time.perf_counter()
        self._gl_fresh = False             # set again only if this call renders the warp
        warped = self._warp_cached(image)
        t1 = time.perf_counter()
        out, info = self._compensate_warped(warped, iterations, warm_start)
        info["seconds"]["warp"] = t1 - t0
        info["seconds"]["total"] = time.perf_counter() - t0
        self.last_info = info
        return out

    def _warp_cached(self, image: np.ndarray) -> np.ndarray:
        """:meth:`warp`, or the last warp again when the input is the same as the last one."""
        if not isinstance(image, np.ndarray):
            return self.warp(image)            # (warp names what is wrong with it)
        cache = self._warp_cache
        if (cache is not None and cache[0].shape == image.shape and cache[0].dtype == image.dtype
                and np.array_equal(cache[0], image)):
            return cache[1]
        warped = self.warp(image)
        self._warp_cache = (image.copy(), warped)
        self._gl_fresh = self._gl_share is not None   # the shared renderbuffer holds this frame
        return warped

    def compensate_warped(self, warped: np.ndarray, *, iterations: int | None = None,
                          warm_start: bool = True, image: np.ndarray | None = None) -> np.ndarray:
        """:meth:`compensate` for a frame that is already in projector space ((Hp, Wp, 3) uint8).
        ``image``: the input whose :meth:`warp` ``warped`` is, where known: a later
        :meth:`compensate` of the same input then skips its warp, as after compensating it (a
        live player's still, settled from its warp and refined by :meth:`compensate`)."""
        _check_budget(iterations)
        t0 = time.perf_counter()
        out, info = self._compensate_warped(warped, iterations, warm_start)
        if isinstance(image, np.ndarray):
            self._warp_cache = (image.copy(), warped)
        info["seconds"]["total"] = time.perf_counter() - t0
        self.last_info = info
        return out

    def solve(self, target_linear: np.ndarray, P0: np.ndarray | None = None,
              iterations: int | None = None) -> tuple[np.ndarray, dict]:
        """Solve for a linear-light target given on the host (no warp, no LUTs).

        Parameters
        ----------
        target_linear : (3, Hp, Wp) float32 in [0, 1]
        P0 : (3, Hp, Wp) float32, optional warm start (default: the target).
        iterations : budget (default: the constructor's).

        Returns
        -------
        P : (3, Hp, Wp) float32 in [0, 1]
        info : dict (as :attr:`last_info`)
        """
        _check_budget(iterations)
        target = np.asarray(target_linear, dtype=np.float32)
        wp, hp = self.projector_size
        if target.shape != (3, hp, wp):
            raise InputError(f"target_linear must be planar (3, {hp}, {wp}) linear light; got "
                             f"{target.shape}")
        if not np.isfinite(target).all():
            raise InputError("target_linear contains NaN or infinite values; it must be linear "
                             "light in [0, 1]")
        if P0 is not None and np.shape(P0) != (3, hp, wp):
            raise InputError(f"P0 must be planar (3, {hp}, {wp}) like the target; got "
                             f"{np.shape(P0)}")
        iters = self.iterations if iterations is None else int(iterations)
        t0 = time.perf_counter()
        flat = None
        if self._surface is not None:
            inp = apply_headroom(target, self.headroom)
            target = flat = self._surface.target(inp)
        if self._solver is not None:
            P, sinfo = self._solver.solve(target, P0, iterations=iters, tol=self.tol,
                                          headroom=self.headroom if flat is None else None)
            self.reset()          # the solver no longer holds a video frame
        else:
            P = self._direct(target if flat is not None else apply_headroom(target, self.headroom))
            sinfo = SolveInfo("direct")
        info = self._info(sinfo, warm=P0 is not None)
        if flat is not None:
            self._surface_info(info, inp, flat)
        info["seconds"]["solve"] = time.perf_counter() - t0
        self.last_info = info
        return P, info

    # ------------------------------------------------------------------ internals
    def _share_gl(self, warp_backend: str):
        """GL sharing (:mod:`rtdefocus.cl.glshare`) where the driver allows: the solver's OpenCL
        runtime then shares the warp's GL context. None: the process runtime (read-back path)."""
        self._gl_share, self._gl_fresh = None, False
        if self.backend == "opencl" and warp_backend != "cv2":
            from ..cl.glshare import open_gl_share
            self._gl_share = open_gl_share()
        return None if self._gl_share is None else self._gl_share.runtime

    def _direct(self, target: np.ndarray) -> np.ndarray:
        if self.method == "wiener":
            c = self.calib
            return wiener_prefilter(target, c.psfs, c.psf_plane, c.plane_map(), self.wiener_nsr)
        return np.clip(target, 0.0, 1.0).astype(np.float32)

    def _surface_info(self, info: dict, I: np.ndarray, target: np.ndarray) -> None:
        above, below = self._surface.clipped(I)
        info.update(surface="flatten", brightness=self._surface.brightness, clipped=above,
                    clipped_dark=below)

    def _info(self, sinfo: SolveInfo, warm: bool) -> dict:
        return {"method": self.method, "solver": sinfo.solver, "backend": self.backend,
                "iterations": sinfo.iterations, "distances": list(sinfo.distances),
                "restarts": sinfo.restarts, "converged": sinfo.converged, "warm_start": warm,
                "seconds": {}}

    def _compensate_warped(self, warped: np.ndarray, iterations, warm_start: bool):
        warped = np.asarray(warped)
        wp, hp = self.projector_size
        if warped.shape != (hp, wp, 3) or warped.dtype != np.uint8:
            raise InputError(f"the warped frame must be ({hp}, {wp}, 3) uint8; got "
                             f"{warped.dtype} {warped.shape}")
        iters = self.iterations if iterations is None else int(iterations)
        lo, scale = headroom_params(self.headroom)
        sec = {}
        if self._solver is None:
            if self.method == "none" and self.headroom is None and self._surface is None:
                return warped.copy(), self._info(SolveInfo("direct"), False) | {"seconds": sec}
            t0 = time.perf_counter()
            target = decode_lut(warped, self._lut_inc, self.headroom)
            info = self._info(SolveInfo("direct"), False)
            if self._surface is not None:
                inp, target = target, self._surface.target(target)
                self._surface_info(info, inp, target)
            t1 = time.perf_counter()
            P = self._direct(target)
            t2 = time.perf_counter()
            out = encode_lut(P, self._lut_inc)
            sec.update(decode=t1 - t0, solve=t2 - t1, encode=time.perf_counter() - t2)
            return out, info | {"seconds": sec}
        s = self._solver
        ops = s.ops
        t0 = time.perf_counter()
        start = self._start_solve(warped, lo, scale, warm_start, iterate=iters > 0)
        ops.finish()
        flat_info = self._last_flat
        t1 = time.perf_counter()
        sinfo = s.run(iters, self.tol)
        t2 = time.perf_counter()
        out = ops.encode(s.P, self._lut_inc)
        sec.update(decode=t1 - t0, solve=t2 - t1, encode=time.perf_counter() - t2)
        info = self._info(sinfo, start != "cold")
        info["start"] = start
        info["seconds"] = sec
        if self._surface is not None:
            info.update(flat_info)
        return out, info

    def _start_solve(self, warped: np.ndarray, lo: float, scale: float, warm_start: bool,
                     iterate: bool = True) -> str:
        """Load the frame's target and choose the solver's start point (``iterate`` False: the
        frame is shown from its start alone, which needs no momentum).

        Returns how the solve starts: ``"still"`` (the same frame again: the solve continues),
        ``"motion"`` (the previous correction moved along the motion), ``"cold"`` (from the
        target: first frame, ``warm_start=False``, or the warm start was not closer), ``"cut"``.
        """
        s = self._solver
        ops = s.ops
        prev = self._prev_warped if warm_start else None
        if prev is not None and np.array_equal(prev, warped):
            return "still"
        # The previous target and solver state stay on the device: the warm start moves them
        # there (no read-back, no host resampling).
        s.begin_frame()
        # Decode through the same strictly increasing LUT the encoder inverts, so that a frame
        # the solve leaves alone comes back with its very codes.
        codes = warped
        if self._gl_fresh:                 # GL sharing: the warp's renderbuffer, on the device
            self._gl_share.fill_codes(ops.codes, self.projector_size)
            codes, self._gl_fresh = None, False
        ops.decode(codes, self._lut_inc, lo, scale, s.target)
        s.target_changed()
        if self._surface is not None:
            # surface="flatten": T' = (b I − E) / A, solved with the residual scaled by A (the
            # solver's ops carry the scale); the motion and warm start work on T' alike.
            inp = ops.download(s.target)
            target = self._surface.target(inp)
            ops.upload(target, s.target)
            above, below = self._surface.clipped(inp)
            self._last_flat = {"surface": "flatten", "brightness": self._surface.brightness,
                               "clipped": above, "clipped_dark": below}
        self._prev_warped = warped.copy()
        if prev is None:
            s.start_from_target()
            return "cold"
        # The motion estimate (OpenCV, which releases the GIL) runs on a helper thread while
        # a GPU blurs the cold start, which the warm start must beat (a cut uses neither). A
        # CPU device's threads already fill the cores: there the two in turn were steadier and
        # ~3 ms faster a moving frame (800x600, 2 PoCL cores: 56 against 57-60 ms).
        runtime = getattr(ops, "runtime", None)
        if runtime is None or not runtime.is_gpu:
            motion = self._motion.estimate(prev, warped)
            d_cold = None if motion.cut else s.cold_distance()
        else:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=1,
                                                thread_name_prefix="rtdefocus-motion")
                # The thread lives as long as this Compensator, not until the interpreter exits.
                weakref.finalize(self, self._pool.shutdown, wait=False)
            pending = self._pool.submit(self._motion.estimate, prev, warped)
            d_cold = s.cold_distance()
            motion = pending.result()
        if motion.cut:
            s.start_from_target()
            return "cut"
        ops.set_motion(motion.map_xy, motion.valid)
        return "motion" if s.start_from_motion(d_cold, momentum=iterate) else "cold"


def _check_args(calib, *, method, solver, backend, iterations, tol, weights, warp_backend,
                wiener_nsr, blur_variant) -> None:
    """The constructor's argument checks (before anything is built)."""
    if not isinstance(calib, Calibration):
        raise InputTypeError(
            f"Compensator needs an rtdefocus Calibration; got {type(calib).__name__}. Make one "
            "with rd.calibrate(procam) or load one with rd.Calibration.load('setup.npz')")
    check_choice(method, METHODS, "method")
    check_choice(solver, SOLVERS, "solver")
    check_choice(backend, ("auto", "opencl", "numpy"), "backend")
    check_choice(warp_backend, ("auto", "gl", "cv2"), "warp_backend")
    check_choice(blur_variant, (None, "cpu", "gpu"), "blur_variant")
    if iterations is not None:
        check_int(iterations, "iterations", lo=0)
    check_real(tol, "tol", lo=0.0)
    check_real(wiener_nsr, "wiener_nsr", lo=0.0, lo_open=True)
    if isinstance(weights, (str, bytes)) or not hasattr(weights, "__len__") or len(weights) != 4:
        raise InputTypeError(f"weights must be the four Eq. 4 weights (w1, w2, w3, w4); got "
                             f"{weights!r}")
    for i, w in enumerate(weights):
        check_real(w, f"weights[{i}]", lo=0.0)


def _check_budget(iterations) -> None:
    if iterations is not None:
        check_int(iterations, "iterations", lo=0)


def _resolve_backend(backend: str) -> str:
    return cl_runtime.choose_backend(backend, "compensating", log)
