"""The compensation solve's primitive operations on host arrays: the NumPy twin of
:class:`rtdefocus.cl.solve.ClSolveOps`, and the backend :class:`rtdefocus.compensate.Solver`
runs on without an OpenCL device.

Every method takes and returns what its device twin does (planar ``(3, H, W)`` float32 arrays,
here NumPy ones), so the solver's iteration logic is shared and the two backends differ only in
float32 rounding. Reductions are summed in float64.
"""

from __future__ import annotations

import numpy as np

from ..checks import check_choice
from ..errors import InputError
from .blur import (
    blur_adjoint,
    blur_adjoint_filter2d,
    blur_forward,
    blur_forward_filter2d,
    check_field,
)
from .lut import encode_lut, inverse_lut_tables
from .metric import Metric, metric_field

__all__ = ["ADJOINTS", "NumpyOps", "boost_edges", "boost_field", "carry_field", "check_adjoint",
           "check_carry", "scale_preconditioner"]

#: How FISTA's gradient ``Fᵀ q`` is formed. ``"exact"``: the transpose of F, each tap weighted by
#: the blend at the pixel it came from (``blur_adjoint``). ``"fast"``: the forward blur with the
#: PSFs flipped, blended at the output pixel — the same operator wherever the blend weights are
#: constant over a kernel's support (they vary over hundreds of pixels, kernels span a few), and
#: as cheap as the forward on the device (the exact adjoint's blend at the source pixel costs
#: ~2x). FISTA's steps are accepted on the exact distance (a step that raises it is rejected),
#: so the solve stays monotone either way; PG's exact line search always uses ``"exact"``.
ADJOINTS = ("exact", "fast")


def check_adjoint(adjoint: str) -> None:
    """Raise :class:`InputError` unless ``adjoint`` is one of :data:`ADJOINTS`."""
    check_choice(adjoint, ADJOINTS, "adjoint")


def _vdot(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.add.reduce(a * b, axis=None, dtype=np.float64))


def scale_preconditioner(scale, psfs, idx, wts) -> np.ndarray:
    """The diagonal preconditioner of a residual scaled by S: ``p = 1 / Fᵀ(S² ⊙ F 1)``.

    ``Fᵀ S² F`` (the Hessian of ``‖S (F P − T)‖²``) has nonnegative entries and row sums
    ``Fᵀ(S² ⊙ F 1)``; with ``D = diag(p)`` the matrix ``D Fᵀ S² F`` has unit row sums, so
    ``D^½ Fᵀ S² F D^½`` (similar to it) has spectral norm ≤ 1. Steps ``P − t p ⊙ ∇d`` therefore
    converge at keep's pace wherever S is dark, instead of ``1/S²`` times slower; where S is
    locally constant ``p ≈ 1/S²`` and the preconditioned Hessian is keep's. The box projection
    stays the per-element clamp (a diagonal metric). Both backends use this host array.
    Floored at ``min S²`` (pixels the blur barely reaches: the frame's edges).

    Returns
    -------
    (3, H, W) float32
    """
    scale = np.asarray(scale, dtype=np.float32)
    s2 = scale.astype(np.float64) ** 2
    f1 = blur_forward_filter2d(np.ones(scale.shape, np.float32), psfs, idx, wts)
    w = blur_adjoint_filter2d((s2 * f1).astype(np.float32), psfs, idx, wts).astype(np.float64)
    return (1.0 / np.maximum(w, s2.min())).astype(np.float32)


def carry_field(src, map_xy, valid, fallback, base_prev=None, base_new=None,
                clamp: bool = False) -> np.ndarray:
    """A field of the previous frame moved along the motion (the warm start of a video).

    ``out = base_new + B(src − base_prev)`` where ``valid``, else ``fallback``; clamped to
    [0, 1] when ``clamp``. ``B`` samples bilinearly at ``map_xy`` (the previous frame's pixel
    that each pixel came from), taps outside the frame counting as 0; ``map_xy`` None is the
    identity (no resampling). Without bases (None) the field itself is moved (``base`` 0). The
    twin of ``kernels/solver.cl`` ``carry`` (exact bilinear weights in float32, where
    ``cv2.remap`` quantises them to 1/32).

    Parameters
    ----------
    src, fallback, base_prev, base_new : (C, H, W) float32
    map_xy : (H, W, 2) float32 source coordinates (x, y), or None
    valid : (H, W) bool
    clamp : bool

    Returns
    -------
    (C, H, W) float32
    """
    src = np.asarray(src, np.float32)
    diff = src if base_prev is None else src - np.asarray(base_prev, np.float32)
    c, h, w = diff.shape
    if map_xy is None:
        moved = diff.copy()
    else:
        mx, my = map_xy[..., 0].astype(np.float32), map_xy[..., 1].astype(np.float32)
        x0, y0 = np.floor(mx), np.floor(my)
        fx, fy = mx - x0, my - y0
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        moved = np.zeros_like(diff)
        for dy, wy in ((0, 1.0 - fy), (1, fy)):
            for dx, wx in ((0, 1.0 - fx), (1, fx)):
                xs, ys = x0 + dx, y0 + dy
                inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
                tap = diff[:, np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)]
                moved += np.where(inside, (wy * wx).astype(np.float32), np.float32(0)) * tap
    if base_new is not None:
        moved += np.asarray(base_new, np.float32)
    out = np.where(np.asarray(valid, bool)[None], moved, np.asarray(fallback, np.float32))
    if clamp:
        np.clip(out, 0.0, 1.0, out=out)
    return out.astype(np.float32)


def check_carry(src, fallback, dst, base_prev, base_new, src2, dst2) -> None:
    """Raise :class:`InputError` unless a carry's buffers are consistent (``ops.carry`` of
    either backend): both bases or neither, ``src2`` with ``dst2``, and no destination that is
    a source or ``base_prev`` (the carry reads them around each pixel); with two fields, none
    that is the fallback or ``base_new`` either."""
    if (base_prev is None) != (base_new is None):
        raise InputError("carry takes both bases (base_prev, base_new) or neither")
    if (src2 is None) != (dst2 is None):
        raise InputError("carry takes src2 with dst2 (the second field and where it goes) or "
                         "neither")
    reads = [a for a in (src, base_prev, src2) if a is not None]
    for d in (dst, dst2):
        if d is not None and any(d is a for a in reads):
            raise InputError("carry cannot write over a field it reads (src, src2, base_prev); "
                             "pass another buffer")
    if dst2 is not None and (dst2 is dst or any(d is a for d in (dst, dst2)
                                                for a in (fallback, base_new))):
        raise InputError("a carry of two fields needs two destinations of their own (not dst "
                         "twice, nor fallback or base_new: the second pass reads them)")


def boost_edges(gamma_psf, idx, wts) -> tuple[np.ndarray, np.ndarray]:
    """The edge weights of FISTA's spatial preconditioner ``M = I + ∇ᵀ Γ ∇`` from one weight
    per PSF (:func:`rtdefocus.compensate.solvers.boost_gammas`): each pixel blends its PSFs'
    weights like their kernels, and an edge takes the smaller of its two pixels'.

    Returns
    -------
    gx, gy : (H, W) float32
        ``gx[y, x]``: edge (x, y)–(x + 1, y), 0 in the last column; ``gy[y, x]``: edge
        (x, y)–(x, y + 1), 0 in the last row (``kernels/metric.cl`` ``boost_gradient``).
    """
    g = (np.asarray(gamma_psf, np.float64)[np.asarray(idx)] * np.asarray(wts)).sum(-1)
    gx, gy = np.zeros(g.shape, np.float32), np.zeros(g.shape, np.float32)
    gx[:, :-1] = np.minimum(g[:, 1:], g[:, :-1])
    gy[:-1] = np.minimum(g[1:], g[:-1])
    return gx, gy


def boost_field(g, P, gx, gy) -> np.ndarray:
    """``M_F g`` with ``M = I + ∇ᵀ Γ ∇`` per channel on the free set F of the iterate P: an
    element at a bound whose gradient pushes it out (``P <= 0, g > 0`` or ``P >= 1, g < 0``)
    keeps its plain ``g`` and counts as 0 for its neighbours (twin of ``metric.cl``
    ``boost_gradient``).

    Parameters
    ----------
    g, P : (3, H, W) float32
    gx, gy : (H, W) float32, from :func:`boost_edges`
    """
    g = np.asarray(g, np.float32)
    P = np.asarray(P, np.float32)
    act = ((P <= 0) & (g > 0)) | ((P >= 1) & (g < 0))
    f = np.where(act, np.float32(0), g)
    out = f.copy()
    d = gx[None, :, :-1] * (f[:, :, :-1] - f[:, :, 1:])      # γ (f(x) − f(x + 1))
    out[:, :, :-1] += d
    out[:, :, 1:] -= d
    d = gy[None, :-1] * (f[:, :-1] - f[:, 1:])
    out[:, :-1] += d
    out[:, 1:] -= d
    out[act] = g[act]
    return out


class NumpyOps:
    """The solve's primitive operations on host arrays (the reference twin of ClSolveOps).

    Parameters
    ----------
    psfs, idx, wts : the kernel field F; ``idx`` (H, W, 4) fixes the size.
    metric : Metric
    blur : "gather" (:func:`blur_forward`, the readable reference) or "filter2d" (the same
        operator through cv2.filter2D per PSF, several times faster on a CPU).
    scale : (3, H, W) float32, optional
        Per-pixel scale S of every residual (the surface's albedo when the compensation flattens
        it, DESIGN.md §3): the distance is ``d(S (F P − target))`` and the field ``q = S Q S e``,
        so that ``2 Fᵀ q`` stays its gradient. None: no scale (``kernels/metric.cl`` HAS_SCALE).
        With a scale the steps are preconditioned by :func:`scale_preconditioner` (``precond``;
        ``kernels/solver.cl`` PRECOND).
    adjoint : "exact" | "fast"
        How :meth:`gradient` forms FISTA's ``Fᵀ q`` (:data:`ADJOINTS`).

    Attributes
    ----------
    psfs : (N, k, k) float32, the field's PSFs (the solver's step size is estimated from them).
    metric : Metric
    shape : ``(3, H, W)`` of every image.
    scale_max : the largest scale (1.0 without one).
    has_scale : whether the residual is scaled.
    precond : (3, H, W) float32 or None, the diagonal preconditioner p of the steps (with a scale).
    colour_pc : (3, 3) float32 or None, the metric's colour preconditioner
        (:meth:`metric_residual` with ``colour=True``); None with a scale.
    lipschitz_factor : the solver's Lipschitz estimate for the plain blur times this one: 1.0
        without a scale and with the preconditioner (see :func:`scale_preconditioner`).
    """

    backend = "numpy"

    def __init__(self, psfs, idx, wts, metric: Metric, blur: str = "gather", scale=None,
                 adjoint: str = "exact"):
        self.psfs, self.idx, self.wts = check_field(psfs, idx, wts)
        check_choice(blur, ("gather", "filter2d"), "blur")
        check_adjoint(adjoint)
        self.adjoint_form = adjoint
        self._psfs_flipped = np.ascontiguousarray(self.psfs[:, ::-1, ::-1])
        self.metric = metric
        self.blur_form = blur
        self._fwd = blur_forward if blur == "gather" else blur_forward_filter2d
        self._adj = blur_adjoint if blur == "gather" else blur_adjoint_filter2d
        h, w = self.idx.shape[:2]
        self.shape = (3, h, w)
        self.scale = None
        self.scale_max = 1.0
        self.has_scale = scale is not None
        self.precond = None
        self.lipschitz_factor = 1.0
        pc = metric.colour_preconditioner        # (not with a residual scale: DESIGN.md §3)
        self.colour_pc = None if pc is None or scale is not None else pc.astype(np.float32)
        if scale is not None:
            self.scale = np.ascontiguousarray(scale, dtype=np.float32)
            if self.scale.shape != self.shape:
                raise InputError(f"scale must be {self.shape} (3, H, W); got {self.scale.shape}")
            self.scale_max = float(self.scale.max())
            self.precond = scale_preconditioner(self.scale, self.psfs, self.idx, self.wts)
        self._pending_d: float | None = None    # metric_residual's d, for fista_set_d / decide
        self._state: dict | None = None          # FISTA's state (fista_state_write)
        self._enc_key: bytes | None = None      # the LUT whose encoder tables are cached
        self._enc_tables = None

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

    def gradient(self, src, dst) -> None:
        """FISTA's ``Fᵀ src``: the exact :meth:`adjoint`, or with ``adjoint="fast"`` the forward
        blur with flipped PSFs blended at the output pixel (:data:`ADJOINTS`)."""
        if self.adjoint_form == "exact":
            self.adjoint(src, dst)
        else:
            dst[...] = self._fwd(src, self._psfs_flipped, self.idx, self.wts)

    def metric_residual(self, fp, target, q, reduce: bool = True,
                        colour: bool = False) -> float | None:
        """q = Q (fp − target); returns d (``reduce=False``: None, d kept for
        :meth:`fista_set_d` / :meth:`fista_decide`, as the device keeps its partial sums).
        ``colour``: q = C Q (fp − target) with the metric's
        :attr:`~rtdefocus.reference.metric.Metric.colour_preconditioner` C (FISTA's field; d is
        the same). Not with a scale."""
        e = fp - target
        if colour:
            if self.scale is not None or self.colour_pc is None:
                raise InputError("the colour preconditioner needs a metric that has one and no "
                                 "residual scale")
            qe = metric_field(e, self.metric)
            d = _vdot(e, qe)
            q[...] = np.tensordot(self.colour_pc, qe, axes=1)
        elif self.scale is None:
            q[...] = metric_field(e, self.metric)
            d = _vdot(e, q)
        else:
            e *= self.scale                              # e = S (F P − target)
            qe = metric_field(e, self.metric)
            np.multiply(qe, self.scale, out=q)           # q = S Q e
            d = _vdot(e, qe)
        self._pending_d = d
        return d if reduce else None

    def set_boost(self, gamma_psf) -> None:
        """FISTA's spatial preconditioner from one weight per PSF (:func:`boost_edges`)."""
        self._boost = boost_edges(gamma_psf, self.idx, self.wts)

    def boost_gradient(self, P, g, out) -> None:
        """out = :func:`boost_field` (g, P) with the weights of :meth:`set_boost`."""
        out[...] = boost_field(g, P, *self._boost)

    def metric_update(self, fp, fs, t, target, fp_out, q) -> float:
        fp_out[...] = fp + np.float32(t) * fs
        return self.metric_residual(fp_out, target, q)

    def metric_curvature(self, fs, v=None) -> tuple[float, float]:
        e = fs if self.scale is None else fs * self.scale
        qf = metric_field(e, self.metric)
        return _vdot(e, qf), (_vdot(fs, v) if v is not None else 0.0)

    def pg_direction(self, P, g, s) -> float:
        blocked = ((P <= 0) & (g > 0)) | ((P >= 1) & (g < 0))
        if self.precond is None:
            np.negative(g, out=s)
            s[blocked] = 0.0
            return _vdot(s, s)
        np.multiply(g, -self.precond, out=s)         # s = −p g; returns −⟨g, s⟩ = Σ p g²
        s[blocked] = 0.0
        return -_vdot(g, s)

    def pg_step(self, P, s, t, delta) -> tuple[float, float, int]:
        moved = P + np.float32(t) * s
        new = np.clip(moved, 0.0, 1.0)
        np.subtract(new, P, out=delta)
        P[...] = new
        return _vdot(delta, delta), _vdot(new, new), int(np.count_nonzero(new != moved))

    def axpy(self, x, y, a) -> None:
        x += np.float32(a) * y

    def fista_step(self, P, P_prev, G, G_prev, beta, step, P_out, sums=True) -> tuple[float, float]:
        if beta is None:                             # from the state (fista_decide)
            beta, step = self._state["beta"], self._state["step"]
        y, gy = P, G
        if beta != 0.0:
            y = P + np.float32(beta) * (P - P_prev)
            gy = G + np.float32(beta) * (G - G_prev)
        if self.precond is not None:
            gy = gy * self.precond
        np.clip(y - np.float32(step) * gy, 0.0, 1.0, out=P_out)
        if not sums:
            return float("nan"), float("nan")
        d = P_out - P
        return _vdot(d, d), _vdot(P_out, P_out)

    # FISTA's restart test, as ``kernels/solver.cl`` runs it on the device (fista_decide).
    def fista_state_write(self, d, theta, beta, step, iterations) -> None:
        self._state = {"d": d, "theta": float(theta), "beta": float(beta), "step": float(step),
                       "accept": True, "restarts": 0, "log": [d]}

    def fista_set_d(self) -> None:
        self._state["d"] = self._pending_d
        self._state["log"][0] = self._pending_d

    def fista_decide(self, k) -> None:
        st, d_new = self._state, self._pending_d
        if d_new > st["d"]:
            st["accept"] = False
            st["restarts"] += 1
            if st["beta"] == 0.0:
                st["step"] *= 0.5
            st["theta"], st["beta"] = 1.0, 0.0
        else:
            theta_next = (1.0 + np.sqrt(1.0 + 4.0 * st["theta"] ** 2)) / 2.0
            st["accept"], st["d"] = True, d_new
            st["beta"], st["theta"] = (st["theta"] - 1.0) / theta_next, theta_next
        st["log"].append(st["d"])

    def fista_undo(self, P, P_out, q, q_out) -> None:
        if not self._state["accept"]:
            P_out[...] = P
            q_out[...] = q

    def fista_accepted(self) -> bool:
        return self._state["accept"]

    def fista_state_read(self, iterations) -> dict:
        st = self._state
        return {"d": st["d"], "theta": st["theta"], "beta": st["beta"], "step": st["step"],
                "restarts": st["restarts"], "log": list(st["log"][:1 + iterations])}

    def set_motion(self, map_xy, valid) -> None:
        """The motion :meth:`carry` moves fields along: ``(H, W, 2)`` float32 source
        coordinates (None: the picture did not move) and the ``(H, W)`` bool mask of valid
        pixels."""
        self._motion = (None if map_xy is None else np.asarray(map_xy, np.float32),
                        np.asarray(valid, bool))

    def carry(self, src, fallback, dst, base_prev=None, base_new=None, clamp=False,
              src2=None, dst2=None) -> None:
        """dst = :func:`carry_field` of ``src`` along the motion of :meth:`set_motion` (and
        ``dst2`` the same of ``src2``)."""
        check_carry(src, fallback, dst, base_prev, base_new, src2, dst2)
        map_xy, valid = self._motion
        dst[...] = carry_field(src, map_xy, valid, fallback, base_prev, base_new, clamp)
        if src2 is not None:          # (check_carry: dst is none of what this one reads)
            dst2[...] = carry_field(src2, map_xy, valid, fallback, base_prev, base_new, clamp)

    def decode(self, codes, lut, lo, scale, dst) -> None:
        lut = np.asarray(lut, dtype=np.float32)
        for c in range(3):
            dst[c] = np.float32(lo) + np.float32(scale) * lut[c][codes[..., c]]

    def encode(self, P, lut_increasing) -> np.ndarray:
        key = np.asarray(lut_increasing, np.float32).tobytes()
        if self._enc_key != key:
            self._enc_key, self._enc_tables = key, inverse_lut_tables(lut_increasing)
        return encode_lut(P, lut_increasing, self._enc_tables)
