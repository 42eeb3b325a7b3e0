"""Watching the show: what the camera should see of the frame on the wall, what a capture says
changed (:mod:`~rtdefocus.watch.residual`), prepared once per calibration
(:mod:`~rtdefocus.watch.predictor`), the mends that explain it (:mod:`~rtdefocus.watch.mend`),
the short pattern bursts for what the content cannot mend (:mod:`~rtdefocus.watch.burst`), the
:class:`Watcher` the Player drives (:mod:`~rtdefocus.watch.watcher`) and what a watched show
needs around it (:mod:`~rtdefocus.watch.session`)."""

from .burst import BurstOptions
from .mend import mend_camera, mend_light, mend_projector, rescale_kernels, rescale_radii
from .predictor import ResidualPredictor
from .residual import ResidualReport, observe_proj, predict_proj, predictor_for, residual_report
from .session import FrameClock, LiveView, camera_view, save_watched, timeline_view, watched_path
from .watcher import Thresholds, Watcher, WatchEvent, WatchUpdate

__all__ = ["BurstOptions", "FrameClock", "LiveView", "ResidualPredictor", "ResidualReport",
           "Thresholds", "WatchEvent", "WatchUpdate", "Watcher", "camera_view", "mend_camera",
           "mend_light", "mend_projector", "observe_proj", "predict_proj", "predictor_for",
           "rescale_kernels", "rescale_radii", "residual_report", "save_watched", "timeline_view",
           "watched_path"]
