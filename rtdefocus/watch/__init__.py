"""Watching the show: what the camera should see of the frame on the wall, and what a
capture says changed (:mod:`~rtdefocus.watch.residual`)."""

from .residual import ResidualReport, observe_proj, predict_proj, residual_report

__all__ = ["ResidualReport", "observe_proj", "predict_proj", "residual_report"]
