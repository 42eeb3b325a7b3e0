"""The one place a solve backend is built by name: :func:`make_solve_ops`, and
:func:`make_solver` (ops and :class:`~.solvers.Solver` in one call, for tests and tools).

A backend is an *ops object*, the solve's primitive operations on one frame size:
:class:`rtdefocus.reference.ops.NumpyOps` (host arrays, the reference) or
:class:`rtdefocus.cl.solve.ClSolveOps` (OpenCL device arrays). :class:`~.solvers.Solver`
receives one and never imports either.
"""

from __future__ import annotations

from ..cl.runtime import get_runtime
from ..cl.solve import ClSolveOps
from ..errors import InputError
from ..reference.metric import DEFAULT_WEIGHTS, Metric
from ..reference.ops import NumpyOps
from .solvers import Solver, check_solver

__all__ = ["BACKENDS", "make_solve_ops", "make_solver"]

BACKENDS = ("numpy", "opencl")


def make_solve_ops(backend: str, psfs, idx, wts, metric: Metric, *, runtime=None,
                   blur: str = "gather", blur_variant: str | None = None, scale=None,
                   adjoint: str = "exact"):
    """The ops object of a backend for the kernel field ``(psfs, idx, wts)`` and a metric.

    Parameters
    ----------
    backend : "numpy" | "opencl"
    psfs, idx, wts : the kernel field F (docs/internals.md); ``idx`` (H, W, 4) fixes the size.
    metric : Metric
    runtime : rtdefocus.cl.runtime.ClRuntime, optional
        OpenCL only; default the process runtime (:func:`rtdefocus.cl.runtime.get_runtime`).
    blur : "gather" | "filter2d"
        NumPy only; see :class:`~rtdefocus.reference.ops.NumpyOps`.
    blur_variant : "cpu" | "gpu", optional
        OpenCL only; default by device type.
    scale : (3, H, W) float32, optional
        Per-pixel residual scale (the surface's albedo, ``surface="flatten"``); see
        :class:`~rtdefocus.reference.ops.NumpyOps`.
    adjoint : "exact" | "fast"
        How FISTA's gradient is formed (:data:`rtdefocus.reference.ops.ADJOINTS`).

    Returns
    -------
    NumpyOps or ClSolveOps
    """
    if backend == "numpy":
        return NumpyOps(psfs, idx, wts, metric, blur=blur, scale=scale, adjoint=adjoint)
    if backend == "opencl":
        # (pyopencl itself is imported, and a device opened, only here: by get_runtime and
        # ClSolveOps on first use.)
        return ClSolveOps(runtime or get_runtime(), psfs, idx, wts, metric,
                          blur_variant=blur_variant, scale=scale, adjoint=adjoint)
    raise InputError(f"backend must be one of {BACKENDS}; got {backend!r}")


def make_solver(psfs, idx, wts, metric: Metric | None = None, *, backend: str = "numpy",
                solver: str = "fista", runtime=None, blur: str = "gather",
                blur_variant: str | None = None, scale=None, adjoint: str = "exact",
                precondition: str | None = "colour+spatial") -> Solver:
    """A :class:`~.solvers.Solver` for a kernel field on a backend named by string.

    Parameters
    ----------
    psfs, idx, wts : the kernel field F (docs/internals.md); ``idx`` (H, W, 4) fixes the size.
    metric : Metric, optional
        Default: :meth:`Metric.ycbcr` with :data:`~rtdefocus.reference.metric.DEFAULT_WEIGHTS`.
    backend : "numpy" | "opencl"
    solver : "fista" | "pg"
    runtime, blur, blur_variant, scale, adjoint : as for :func:`make_solve_ops`.
    precondition : "colour+spatial" | "colour" | None, as for :class:`~.solvers.Solver`.
    """
    check_solver(solver)                 # before any device work
    if metric is None:
        metric = Metric.ycbcr(DEFAULT_WEIGHTS)
    ops = make_solve_ops(backend, psfs, idx, wts, metric, runtime=runtime, blur=blur,
                         blur_variant=blur_variant, scale=scale, adjoint=adjoint)
    return Solver(ops, solver=solver, precondition=precondition)
