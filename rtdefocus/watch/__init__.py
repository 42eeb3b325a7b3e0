"""Watching the show: what the camera should see of the frame on the wall, and what a
capture says changed (:mod:`~rtdefocus.watch.residual`), prepared once per calibration
(:mod:`~rtdefocus.watch.predictor`)."""

from .predictor import ResidualPredictor
from .residual import ResidualReport, observe_proj, predict_proj, predictor_for, residual_report

__all__ = ["ResidualPredictor", "ResidualReport", "observe_proj", "predict_proj",
           "predictor_for", "residual_report"]
