"""Defocus compensation: the Eq. 4 metric, the constrained solvers and ``rd.Compensator``
(DESIGN.md §2-3). The metric's NumPy reference lives in :mod:`rtdefocus.reference.metric`."""

from ..reference.metric import Metric
from .compensator import DEFAULT_ITERATIONS, DEFAULT_WEIGHTS, METHODS, Compensator
from .solvers import SOLVERS, SolveInfo, Solver, lipschitz_estimate, wiener_prefilter

__all__ = [
    "Compensator", "Metric", "Solver", "SolveInfo", "METHODS", "SOLVERS", "DEFAULT_WEIGHTS",
    "DEFAULT_ITERATIONS", "lipschitz_estimate", "wiener_prefilter",
]
