"""The compensation solve's device operations (``kernels/metric.cl``, ``kernels/solver.cl``).

:class:`ClSolveOps` is the OpenCL twin of :class:`rtdefocus.reference.ops.NumpyOps`: the
same primitive operations (blur, metric field, projected steps, reductions, LUT decode/encode)
on planar ``(3, H, W)`` float32 device arrays. Everything is sized for one projector frame and
allocated once; programs are built once per (context, constants) by the runtime's cache, so a
frame loop neither allocates nor compiles. Reductions run in two stages on the device (per
work-group partial sums, then one work-group per quantity) and only the final scalars (≤ 4
floats) come back to the host, which needs them to pick the next step length.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import InputError
from ..reference.blur import check_field
from ..reference.lut import ENC_STEPS, ENC_T, inverse_lut_tables
from ..reference.metric import Metric
from ..reference.ops import boost_edges, check_adjoint, check_carry, scale_preconditioner
from .blur import ClBlur

log = logging.getLogger(__name__)

__all__ = ["ClSolveOps", "metric_defines"]


def _pow2_floor(n: int) -> int:
    return 1 << (max(1, int(n)).bit_length() - 1)


def metric_defines(metric: Metric, colour=None) -> dict:
    """The ``-D`` constants of ``metric.cl`` for a :class:`Metric` (Q = A0 + A1 Lap), and with
    ``colour`` (a 3x3 colour preconditioner C) those of its COLOUR_PC build."""
    a0, a1 = metric.qmatrices
    out = {"HAS_SPATIAL": int(bool(metric.spatial.any()))}
    mats = (("A0", a0), ("A1", a1)) + ((("PC", colour),) if colour is not None else ())
    for name, m in mats:
        for r in range(3):
            for c in range(3):
                out[f"{name}_{r}{c}"] = f"{float(m[r, c]):.9e}f"
    if colour is not None:
        out["COLOUR_PC"] = 1
    return out


class ClSolveOps:
    """Device buffers and kernels for solving one ``(3, H, W)`` frame.

    Parameters
    ----------
    runtime : rtdefocus.cl.runtime.ClRuntime
    psfs, idx, wts : the kernel field F (docs/internals.md), ``idx`` (H, W, 4) fixes the size.
    metric : Metric
    blur_variant : {"cpu", "gpu"}, optional
        Passed to :class:`ClBlur` (default: by device type).
    scale : (3, H, W) float32, optional
        Per-pixel scale S of the residual (``metric.cl`` with HAS_SCALE; the surface's albedo
        when the compensation flattens it): d = d(S (F P − target)). None: no scale. With a
        scale the steps are preconditioned (``solver.cl`` PRECOND, the host array of
        :func:`~rtdefocus.reference.ops.scale_preconditioner`, as in the NumPy twin).
    adjoint : "exact" | "fast"
        How :meth:`gradient` forms FISTA's ``Fᵀ q`` (:data:`rtdefocus.reference.ops.ADJOINTS`).

    Attributes
    ----------
    psfs : (N, k, k) float32, the field's PSFs on the host (the solver's step size is estimated
        from them).
    metric : Metric
    shape : ``(3, H, W)`` of every image.

    Notes
    -----
    Buffers are ``pyopencl.array.Array`` objects; :meth:`new` allocates one (zeroed) and is meant
    for set-up only.
    """

    backend = "opencl"

    def __init__(self, runtime, psfs, idx, wts, metric: Metric, blur_variant: str | None = None,
                 scale=None, adjoint: str = "exact"):
        # pyopencl on first use, not at import: NumPy-only runs skip its start-up cost.
        import pyopencl as cl
        import pyopencl.array as cla

        self._cl, self._cla = cl, cla
        self.runtime = runtime
        self.queue = runtime.queue
        self.metric = metric
        self.blur = ClBlur(runtime, psfs, idx, wts, channels=3, variant=blur_variant)
        check_adjoint(adjoint)
        self.adjoint_form = adjoint
        # adjoint="fast": FISTA's gradient is the forward kernel with the PSFs flipped
        # (rtdefocus.reference.ops.ADJOINTS); its own ClBlur, the same field otherwise.
        self._gblur = (self.blur if adjoint == "exact" else
                       ClBlur(runtime, np.ascontiguousarray(np.asarray(psfs)[:, ::-1, ::-1]), idx,
                              wts, channels=3, variant=blur_variant))
        self._grad = self._gblur.adjoint if adjoint == "exact" else self._gblur.forward
        self.psfs = self.blur.psfs
        self.shape = self.blur.shape
        _, h, w = self.shape
        self._h, self._w = np.int32(h), np.int32(w)
        self.n = 3 * h * w
        dev = runtime.device
        variant = self.blur.variant           # the same shape choice as the blur's
        self.variant = variant
        # Work-group sizes from the device limits (powers of two). CPU (PoCL): a few work-items
        # per group, each on 16-float vectors, so that many groups spread over the cores; GPU:
        # up to 256 items per group, one element / pixel each.
        maxwg = _pow2_floor(dev.max_work_group_size)
        if variant == "cpu":
            wg, items, vec = min(8, maxwg), 4, 16
            lx, ly = min(8, maxwg), 1
            mdef = {"VARIANT_CPU": 1}
            nx = -(-w // 16)                     # 16-pixel row chunks per row
        else:
            wg, items, vec = min(256, maxwg), 4, 1
            lx = min(16, wg)
            ly = max(1, min(16, wg // lx))
            mdef = {"VARIANT_GPU": 1}
            nx = w
        if scale is not None:
            mdef["HAS_SCALE"] = 1
        self._prg_m = runtime.program("metric.cl", {**metric_defines(metric), **mdef,
                                                    "LX": lx, "LY": ly})
        # FISTA's field q = C Q e (metric_residual(colour=True)): the same program built with
        # the colour preconditioner C (metric.cl COLOUR_PC); not with a residual scale.
        pc = metric.colour_preconditioner if scale is None else None
        self.colour_pc = None if pc is None else pc.astype(np.float32)
        self._prg_mc = None
        if pc is not None:
            self._prg_mc = runtime.program("metric.cl", {**metric_defines(metric, pc), **mdef,
                                                         "LX": lx, "LY": ly})
        sdef = {"ITEMS": items, "VEC": vec, "ENC_T": ENC_T, "ENC_STEPS": ENC_STEPS}
        pdef = {} if scale is None else {"PRECOND": 1}
        self._prg_s = runtime.program("solver.cl", {"WG": wg, **sdef, **pdef})
        self._wg, self._items = wg, items
        self._m_local = (lx, ly)
        self._m_global = (-(-nx // lx) * lx, -(-h // ly) * ly)
        self._m_groups = (self._m_global[0] // lx) * (self._m_global[1] // ly)
        self._e_groups = -(-self.n // (vec * items * wg))
        self._e_global = (self._e_groups * wg,)
        # fista_undo strides over the arrays from a few groups (see solver.cl): enough to keep
        # every compute unit busy on the rare rejected step.
        self._undo_global = (min(self._e_groups, 4 * max(1, dev.max_compute_units)) * wg,)
        npix = h * w
        items_p = -(-npix // vec)              # decode_lut, carry: VEC pixels per work-item
        self._p_global = (-(-items_p // wg) * wg,)
        n_enc = -(-npix // 16)                  # encode_lut: 16 pixels per work-item
        self._enc_global = (-(-n_enc // wg) * wg,)
        # The second reduction stage: one group per quantity, as wide as the device allows (<= 256).
        self._r_wg = min(256, maxwg)
        prg_r = runtime.program("solver.cl", {"WG": self._r_wg, **sdef})
        self._partials = cla.zeros(self.queue, 4 * max(self._m_groups, self._e_groups), np.float32)
        self._sums = cla.zeros(self.queue, 4, np.float32)
        self._sums_host = np.zeros(4, np.float32)
        self._codes = cla.zeros(self.queue, (h, w, 3), np.uint8)
        self.scale_max = 1.0
        self.has_scale = scale is not None
        self.precond = None
        self.lipschitz_factor = 1.0                 # with the preconditioner, as in NumpyOps
        self._scale = self._partials                # never read without HAS_SCALE
        self._pc = self._partials                   # never read without PRECOND
        if scale is not None:
            scale = np.ascontiguousarray(scale, dtype=np.float32)
            if scale.shape != self.shape:
                raise InputError(f"scale must be {self.shape} (3, H, W); got {scale.shape}")
            self._scale = cla.to_device(self.queue, scale)
            self.scale_max = float(scale.max())
            self.precond = scale_preconditioner(scale, *check_field(psfs, idx, wts))
            self._pc = cla.to_device(self.queue, self.precond)
        self._luts: dict = {}
        # Own kernel objects (cl.Kernel): kernel arguments are per-object state, and programs are
        # shared between instances through the runtime's cache.
        self._k = {name: cl.Kernel(self._prg_m, name) for name in
                   ("metric_residual", "metric_update", "metric_curvature", "boost_gradient")}
        self._field = (idx, wts)                  # for set_boost (ClBlur checked them)
        self._boost = None
        if self._prg_mc is not None:
            self._k["metric_residual_colour"] = cl.Kernel(self._prg_mc, "metric_residual")
        self._k.update({name: cl.Kernel(self._prg_s, name) for name in
                        ("pg_direction", "pg_step", "axpy", "fista_step", "clamp_copy",
                         "decode_lut", "encode_lut", "carry")})
        self._map = cla.zeros(self.queue, (h, w, 2), np.float32)     # set_motion's, reused
        self._valid = cla.zeros(self.queue, (h, w), np.uint8)
        self._identity = True
        self._k_reduce = cl.Kernel(prg_r, "reduce_partials")
        self._k.update({name: cl.Kernel(prg_r, name) for name in ("fista_set_d", "fista_decide")})
        self._k["fista_undo"] = cl.Kernel(self._prg_s, "fista_undo")
        # FISTA's state on the device (solver.cl fista_decide): 8 slots, then the distance log;
        # grown (reallocated) only when a run asks for more iterations than it holds.
        self._state = None
        self._state_host = np.zeros(0, np.float32)
        log.debug("ClSolveOps %dx%d on %s: metric local %s, element WG %d x %d items",
                  w, h, runtime.description, self._m_local, wg, items)

    # ------------------------------------------------------------------ buffers
    def new(self):
        """A zeroed ``(3, H, W)`` float32 device array (set-up only)."""
        return self._cla.zeros(self.queue, self.shape, np.float32)

    def upload(self, host: np.ndarray, dst) -> None:
        host = np.ascontiguousarray(host, dtype=np.float32)
        if host.shape != self.shape:
            raise InputError(f"expected a {self.shape} (3, H, W) image, got {host.shape}")
        dst.set(host, queue=self.queue)

    def download(self, src) -> np.ndarray:
        return src.get(queue=self.queue)

    def copy(self, src, dst) -> None:
        self._cl.enqueue_copy(self.queue, dst.data, src.data)

    def clamp_copy(self, src, dst) -> None:
        """dst = clamp(src, 0, 1)."""
        self._k["clamp_copy"](self.queue, self._e_global, (self._wg,), src.data, dst.data,
                              np.int32(self.n))

    def finish(self) -> None:
        self.queue.finish()

    # ------------------------------------------------------------------ reductions
    def _reduce(self, n_groups: int, nq: int) -> np.ndarray:
        self._k_reduce(self.queue, (nq * self._r_wg,), (self._r_wg,), self._partials.data,
                       np.int32(n_groups), self._sums.data)
        self._cl.enqueue_copy(self.queue, self._sums_host, self._sums.data)  # blocking
        return self._sums_host[:nq].astype(np.float64)

    # ------------------------------------------------------------------ blur
    def forward(self, src, dst) -> None:
        self.blur.forward(src, dst)

    def adjoint(self, src, dst) -> None:
        self.blur.adjoint(src, dst)

    def gradient(self, src, dst) -> None:
        """FISTA's ``Fᵀ src``: the exact adjoint, or the flipped-PSF forward (``adjoint="fast"``,
        :data:`rtdefocus.reference.ops.ADJOINTS`; twin ``NumpyOps.gradient``)."""
        self._grad(src, dst)

    # ------------------------------------------------------------------ metric
    def metric_residual(self, fp, target, q, reduce: bool = True,
                        colour: bool = False) -> float | None:
        """q = Q (fp − target); returns d = ⟨e, Q e⟩ (``reduce=False``: None, the distance left
        in the partial sums for :meth:`fista_set_d` / :meth:`fista_decide`, no read-back).
        ``colour``: q = C Q e (twin :meth:`rtdefocus.reference.ops.NumpyOps.metric_residual`)."""
        name = "metric_residual"
        if colour:
            if "metric_residual_colour" not in self._k:
                raise InputError("the colour preconditioner needs a metric that has one and no "
                                 "residual scale")
            name = "metric_residual_colour"
        self._k[name](self.queue, self._m_global, self._m_local, fp.data, target.data,
                                   q.data, self._scale.data, self._partials.data, self._h, self._w)
        if not reduce:
            return None
        return float(self._reduce(self._m_groups, 1)[0])

    def set_boost(self, gamma_psf) -> None:
        """FISTA's spatial preconditioner from one weight per PSF (twin
        :meth:`rtdefocus.reference.ops.NumpyOps.set_boost`): its edge weights, uploaded once."""
        gx, gy = boost_edges(gamma_psf, *self._field)
        self._boost = (self._cla.to_device(self.queue, gx), self._cla.to_device(self.queue, gy))

    def boost_gradient(self, P, g, out) -> None:
        """out = M_F g (``metric.cl`` ``boost_gradient``; twin
        :func:`rtdefocus.reference.ops.boost_field`)."""
        gx, gy = self._boost
        self._k["boost_gradient"](self.queue, self._m_global, self._m_local, P.data, g.data,
                                  gx.data, gy.data, out.data, self._h, self._w)

    def metric_update(self, fp, fs, t: float, target, fp_out, q) -> float:
        """fp_out = fp + t fs; q = Q (fp_out − target); returns d."""
        self._k["metric_update"](self.queue, self._m_global, self._m_local, fp.data, fs.data,
                                 np.float32(t), target.data, fp_out.data, q.data,
                                 self._scale.data, self._partials.data, self._h, self._w)
        return float(self._reduce(self._m_groups, 1)[0])

    def metric_curvature(self, fs, v=None) -> tuple[float, float]:
        """(⟨fs, Q fs⟩, ⟨fs, v⟩) — the second is 0 when v is None."""
        self._k["metric_curvature"](self.queue, self._m_global, self._m_local, fs.data,
                                    (v if v is not None else fs).data, np.int32(v is not None),
                                    self._scale.data, self._partials.data, self._h, self._w)
        c, dv = self._reduce(self._m_groups, 2)
        return float(c), float(dv)

    # ------------------------------------------------------------------ steps
    def pg_direction(self, P, g, s) -> float:
        self._k["pg_direction"](self.queue, self._e_global, (self._wg,), P.data, g.data, s.data,
                                self._pc.data, self._partials.data, np.int32(self.n))
        return float(self._reduce(self._e_groups, 1)[0])

    def pg_step(self, P, s, t: float, delta) -> tuple[float, float, int]:
        self._k["pg_step"](self.queue, self._e_global, (self._wg,), P.data, s.data, np.float32(t),
                           delta.data, self._partials.data, np.int32(self.n))
        dd, pp, nclip = self._reduce(self._e_groups, 3)
        return float(dd), float(pp), int(round(nclip))

    def axpy(self, x, y, a: float) -> None:
        self._k["axpy"](self.queue, self._e_global, (self._wg,), x.data, y.data, np.float32(a),
                        np.int32(self.n))

    def fista_step(self, P, P_prev, G, G_prev, beta: float | None, step: float | None, P_out,
                   sums: bool = True) -> tuple[float, float]:
        """P_out = clamp(y − step g_y); returns (‖P_out − P‖², ‖P_out‖²), or NaNs without
        ``sums`` (no second reduction stage and no host synchronisation). ``beta`` and
        ``step`` None: both from the device state (:meth:`fista_state_write`, :meth:`fista_decide`)."""
        from_state = beta is None
        state = self._state if from_state else self._partials
        self._k["fista_step"](self.queue, self._e_global, (self._wg,), P.data, P_prev.data, G.data,
                              G_prev.data, np.float32(0.0 if from_state else beta),
                              np.float32(0.0 if from_state else step), self._pc.data,
                              P_out.data, self._partials.data, np.int32(self.n), state.data,
                              np.int32(from_state))
        if not sums:
            return float("nan"), float("nan")
        dd, pp = self._reduce(self._e_groups, 2)
        return float(dd), float(pp)

    # ------------------------------------------------------------------ FISTA on the device
    # The restart test of FISTA runs on the device (solver.cl fista_decide): a run of k
    # iterations synchronises with the host once, at its end (fista_state_read). Twin: NumpyOps.
    def fista_state_write(self, d: float | None, theta: float, beta: float, step: float,
                          iterations: int) -> None:
        """Start a run: the state (d None: set on the device by :meth:`metric_residual` with
        ``reduce=False`` and :meth:`fista_set_d`) with room for ``iterations`` log entries."""
        size = 8 + 1 + int(iterations)
        if self._state is None or self._state.size < size:
            self._state = self._cla.zeros(self.queue, max(size, 64), np.float32)
            self._state_host = np.zeros(self._state.size, np.float32)
        h = self._state_host
        h[:9] = (0.0 if d is None else d, theta, beta, step, 1.0, 0.0, 0.0, 0.0,
                 0.0 if d is None else d)
        # Not blocking: the host array is not touched again before fista_state_read's finish.
        self._cl.enqueue_copy(self.queue, self._state.data, h[:9], is_blocking=False)

    def fista_set_d(self) -> None:
        """state d = the distance of the last ``metric_residual(..., reduce=False)``."""
        self._k["fista_set_d"](self.queue, (self._r_wg,), (self._r_wg,), self._partials.data,
                               np.int32(self._m_groups), self._state.data)

    def fista_decide(self, k: int) -> None:
        """Accept or reject step ``k`` by the distance of the last
        ``metric_residual(..., reduce=False)`` (see ``kernels/solver.cl``)."""
        self._k["fista_decide"](self.queue, (self._r_wg,), (self._r_wg,), self._partials.data,
                                np.int32(self._m_groups), self._state.data, np.int32(k))

    def fista_undo(self, P, P_out, q, q_out) -> None:
        """Where the last step was rejected: P_out = P, q_out = q (else nothing)."""
        self._k["fista_undo"](self.queue, self._undo_global, (self._wg,), self._state.data, P.data,
                              P_out.data, q.data, q_out.data, np.int32(self.n))

    def fista_accepted(self) -> bool:
        """Whether the last step was accepted (a read-back: only for a tolerance test)."""
        out = np.zeros(1, np.float32)
        self._cl.enqueue_copy(self.queue, out, self._state.data, src_offset=4 * 4)
        return bool(out[0] != 0.0)

    def fista_state_read(self, iterations: int) -> dict:
        """End of a run (synchronises): d, theta, beta, step, restarts and the distances log
        (the start and after each of ``iterations`` steps)."""
        h = self._state_host
        self._cl.enqueue_copy(self.queue, h[:9 + iterations], self._state.data)
        return {"d": float(h[0]), "theta": float(h[1]), "beta": float(h[2]),
                "step": float(h[3]), "restarts": int(round(float(h[5]))),
                "log": [float(x) for x in h[8:9 + iterations]]}

    # ------------------------------------------------------------------ motion
    def set_motion(self, map_xy, valid) -> None:
        """Upload the motion :meth:`carry` moves fields along (into buffers allocated once):
        ``(H, W, 2)`` float32 source coordinates (None: the picture did not move) and the
        ``(H, W)`` bool mask of valid pixels."""
        _, h, w = self.shape
        if map_xy is not None:
            self._map.set(np.ascontiguousarray(map_xy, np.float32).reshape(h, w, 2),
                          queue=self.queue)
        self._valid.set(np.ascontiguousarray(valid, np.uint8).reshape(h, w), queue=self.queue)
        self._identity = map_xy is None

    def carry(self, src, fallback, dst, base_prev=None, base_new=None, clamp=False,
              src2=None, dst2=None) -> None:
        """dst = base_new + B(src − base_prev) where valid, else fallback (``kernels/solver.cl``
        ``carry``; twin :func:`rtdefocus.reference.ops.carry_field`); with ``src2``, also
        ``dst2`` = the same of ``src2`` in the same pass. A destination may be ``fallback`` or
        ``base_new``, never a source or ``base_prev``."""
        check_carry(src, fallback, dst, base_prev, base_new, src2, dst2)
        flags = ((1 if base_prev is not None else 0) | (2 if clamp else 0)
                 | (4 if self._identity else 0) | (8 if src2 is not None else 0))
        bp = (base_prev if base_prev is not None else src).data
        bn = (base_new if base_new is not None else src).data
        self._k["carry"](self.queue, self._p_global, (self._wg,), src.data, bp, bn,
                         fallback.data, self._map.data, self._valid.data, dst.data,
                         (src if src2 is None else src2).data,
                         (dst if dst2 is None else dst2).data, np.int32(flags), self._h, self._w)

    # ------------------------------------------------------------------ LUT I/O
    def _lut_buffers(self, lut: np.ndarray, encoder: bool):
        """Device copies of a (3, 256) LUT (decoder) or of its encoder tables, uploaded once
        per distinct LUT."""
        lut = np.ascontiguousarray(lut, np.float32)
        key = (lut.tobytes(), encoder)
        bufs = self._luts.get(key)
        if bufs is None:
            if len(self._luts) >= 8:
                self._luts.clear()
            host = inverse_lut_tables(lut) if encoder else (lut,)
            bufs = self._luts[key] = tuple(self._cla.to_device(self.queue, np.ascontiguousarray(a))
                                           for a in host)
        return bufs

    @property
    def codes(self):
        """The device's uint8 (H, W, 3) codes buffer (:meth:`decode` input, :meth:`encode` output)."""
        return self._codes

    def decode(self, codes: np.ndarray | None, lut: np.ndarray, lo: float, scale: float, dst) -> None:
        """dst = lo + scale · lut[c, codes[..., c]] (planar) from uint8 (H, W, 3) codes; None:
        :attr:`codes` already holds them (filled on the device, GL sharing)."""
        if codes is not None:
            self._codes.set(np.ascontiguousarray(codes, dtype=np.uint8), queue=self.queue)
        (lut_d,) = self._lut_buffers(lut, encoder=False)
        self._k["decode_lut"](self.queue, self._p_global, (self._wg,), self._codes.data,
                              lut_d.data, np.float32(lo), np.float32(scale), dst.data,
                              np.int32(self.n // 3))

    def encode(self, P, lut_increasing: np.ndarray) -> np.ndarray:
        """uint8 (H, W, 3) codes of P through the inverse of a strictly increasing LUT
        (:func:`rtdefocus.reference.lut.encode_lut` is the twin)."""
        mid, tab = self._lut_buffers(lut_increasing, encoder=True)
        self._k["encode_lut"](self.queue, self._enc_global, (self._wg,), P.data, mid.data,
                              tab.data, self._codes.data, np.int32(self.n // 3))
        return self._codes.get(queue=self.queue)
