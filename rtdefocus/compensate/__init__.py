"""Defocus compensation: the Eq. 4 metric, the constrained solvers and ``rd.Compensator``
(DESIGN.md §2-3). The metric's NumPy reference lives in :mod:`rtdefocus.reference.metric`,
the solve backends' ops in :mod:`rtdefocus.reference.ops` and :mod:`rtdefocus.cl.solve`."""

from ..reference.metric import DEFAULT_WEIGHTS, Metric
from .backends import make_solve_ops, make_solver
from .compensator import DEFAULT_ITERATIONS, METHODS, Compensator
from .solvers import SOLVERS, SolveInfo, Solver, lipschitz_estimate
from .wiener import wiener_prefilter

__all__ = [
    "Compensator", "Metric", "Solver", "SolveInfo", "METHODS", "SOLVERS", "DEFAULT_WEIGHTS",
    "DEFAULT_ITERATIONS", "lipschitz_estimate", "make_solve_ops", "make_solver", "wiener_prefilter",
]
