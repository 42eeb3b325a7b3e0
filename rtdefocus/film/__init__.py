"""A film rendered once through a calibration, for any media player (DESIGN.md §9, Rendering).

>>> import rtdefocus as rd
>>> rd.render("setup.npz", "film.mp4", "film_corner.mp4", workers=2)

:func:`render` (:mod:`.runner`) cuts the film into chunks (:mod:`.plan`), compensates each on a
local worker process or a Dask worker (:mod:`.worker`) and muxes the encoded chunks with the
film's sound (:mod:`.media`, PyAV). Needs the ``render`` extra (PyAV, dask.distributed).
"""

from __future__ import annotations

from .media import QUALITIES
from .runner import DEFAULT_CHUNK_FRAMES, DEFAULT_OVERLAP, RENDER_ITERATIONS, RenderResult, render

__all__ = ["render", "RenderResult", "QUALITIES", "DEFAULT_CHUNK_FRAMES", "DEFAULT_OVERLAP",
           "RENDER_ITERATIONS"]
