"""The frame loop: sources (image, slides, video, camera) → Compensator → sinks (window, files).

>>> from rtdefocus.stream import open_source, open_sink, play
>>> with open_source("talk/") as src, open_sink(None, screen=1) as sink:
...     stats = play(rd.Compensator(calib), src, sink)
>>> print(stats.summary())
"""

from .cache import SlideCache, calibration_fingerprint, default_cache_dir
from .controls import MODES, Controls, IterationBudget, KeyDispatcher, draw_overlay
from .loop import Player, play
from .placement import Placement
from .show import Show, playlist
from .sinks import (
    ImageFileSink,
    ImageSequenceSink,
    NullSink,
    Sink,
    VideoFileSink,
    WindowSink,
    open_sink,
)
from .sources import (
    ArraySource,
    CameraSource,
    Frame,
    SlidesSource,
    Source,
    VideoSource,
    natural_key,
    open_source,
)
from .stats import LoopStats

__all__ = [
    "ArraySource", "CameraSource", "Controls", "Frame", "ImageFileSink", "ImageSequenceSink",
    "IterationBudget", "KeyDispatcher", "LoopStats", "MODES", "NullSink", "Placement", "Player",
    "Show", "Sink",
    "SlideCache", "SlidesSource", "Source", "VideoFileSink", "VideoSource", "WindowSink",
    "calibration_fingerprint", "default_cache_dir", "draw_overlay", "natural_key", "open_sink",
    "open_source", "play", "playlist",
]
