"""A still picture's settle, solved beside the live player's frame loop.

On a device too slow to compensate moving frames, the live player compensates a still picture
once, a *settle* (:class:`~rtdefocus.stream.catch_up.CatchUp`), which takes several frame
periods. Run on the frame loop's thread it would hold the loop: a new shot that starts during
it would lose its first frame, which geometry only would have shown. :class:`BackgroundSettle`
solves it on a worker thread of its own instead: the loop warps the still (GL stays on the
thread that owns its context), shows that warp and hands it to the worker, which runs the
Compensator's solve (:meth:`~rtdefocus.Compensator.compensate_warped`: OpenCL or NumPy only).
Meanwhile the loop shows every frame with geometry only (the still's repeats as its warp again,
at no cost) and starts no compensation (the device is busy). At the first frame after the
worker is done, the result is shown if that frame is still the same picture (and the display
mode and calibration did not change); otherwise it is dropped, never shown on another picture.
The Compensator's video state is then that of the still, as after a settle on the loop's
thread: the next compensated frame starts from it by the motion, or cold where the motion finds
a cut.

The settle runs beside the loop only where the Compensator solves a warped frame itself
(``compensate_warped`` defined on its class: a wrapper that paces ``compensate`` and forwards
the rest would run it unpaced), it solves off the CPU (``solves_off_the_cpu``: a solve on the
CPU cores, NumPy or an OpenCL CPU device, would take them from the warps of the frames shown
meanwhile, and a fast frame rate loses frames to it), its OpenCL context does not share the
warp's GL context (``shares_gl``: there the warp's renderbuffer is an OpenCL image, and the two
threads would share it), frames are read on a thread of their own and no watcher swaps the calibration or
takes frames; elsewhere the settle runs on the loop's thread as a compensated frame.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .sources import Frame

log = logging.getLogger(__name__)


@dataclass
class _Job:
    future: Future
    comp: object            # the Compensator it runs on
    version: int            # the controls' version when it started (mode, overlay)
    index: int              # the frame it settles
    warped: np.ndarray      # its geometry only, on the screen while the picture stays
    stale: bool = False     # the picture changed since: its result is dropped


class BackgroundSettle:
    """The worker thread of a live player's settles and the settle in progress (see the module).

    Parameters
    ----------
    player : rtdefocus.stream.Player
        The player whose frame loop it runs beside (its Compensator, stats, budget, controls).
    """

    def __init__(self, player):
        self.player = player
        self._pool: ThreadPoolExecutor | None = None
        self._job: _Job | None = None
        #: Settles whose result was dropped (the picture changed before it was done).
        self.dropped = 0

    @property
    def busy(self) -> bool:
        """A settle is in progress or its result not yet taken."""
        return self._job is not None

    def available(self) -> bool:
        """The settle can run beside the loop (see the module)."""
        p = self.player
        comp = p.comp
        return (p.threads and p.watcher is None
                and callable(getattr(type(comp), "compensate_warped", None))
                and getattr(comp, "solves_off_the_cpu", False)
                and not getattr(comp, "shares_gl", False))

    def start(self, frame: Frame, iterations: int | None, t_start: float) -> bool:
        """Settle ``frame`` on the worker and show it with geometry only meanwhile; False
        (nothing done) where the settle cannot run beside the loop."""
        if self._job is not None or not self.available():
            return False
        p = self.player
        t0 = time.perf_counter()
        warped = p._warp(frame.image)
        warp_s = time.perf_counter() - t0
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rtdefocus-settle")
        future = self._pool.submit(_solve, p.comp, warped, iterations, warp_s)
        self._job = _Job(future, p.comp, p.controls.version, frame.index, warped)
        log.debug("settle of frame %d started beside the loop (%d iterations)", frame.index,
                  iterations or 0)
        p.stats.geometry_frames += 1
        p.present(warped, frame.index, frame.t_read, t_start)
        return True

    def show(self, frame: Frame, still: bool, t_start: float) -> bool:
        """A frame while a settle is in progress or done (``still``: the same picture as the
        frame before): True when shown here (with geometry only while the worker runs; the
        settle's result when it is done and the picture the same), False when the loop shows
        it as usual (no settle, or its result was just dropped)."""
        job = self._job
        if job is None:
            return False
        p = self.player
        full = p.controls.mode == "full"
        job.stale = (job.stale or not still or not full or p.comp is not job.comp
                     or p.controls.version != job.version)
        if not job.future.done():
            if not full:
                return False                 # (rendered without the solver's device)
            p._prev_compensated = False
            if job.stale:
                p._show_geometry(frame, t_start)
                if not still and p._catch_up is not None:
                    p._catch_up.judge(frame, compensated=False)   # (a calm moving frame)
            else:                            # the same picture: its warp again, at no cost
                p.stats.geometry_frames += 1
                p.present(job.warped, frame.index, frame.t_read, t_start)
            return True
        self._job = None
        out, info, seconds = job.future.result()     # (the worker's error is raised here)
        if job.stale:
            self.dropped += 1
            log.debug("settle of frame %d dropped at frame %d (%.0f ms): the picture changed "
                      "before it was done", job.index, frame.index, 1e3 * seconds)
            return False
        log.debug("settle of frame %d shown at frame %d (%.0f ms)", job.index, frame.index,
                  1e3 * seconds)
        p._count_solve(seconds, info, None)
        p._last_out, p._prev_compensated = out, True
        p.present(out, frame.index, frame.t_read, t_start)
        # the budget learns the settle's cost as the worker measured it
        p._update_budget(time.perf_counter() - seconds, info=info)
        return True

    def wait(self) -> None:
        """Wait for the settle in progress, if any, and drop its result (the loop is about to
        use the solver itself: a paused frame's refinement)."""
        job, self._job = self._job, None
        if job is not None:
            job.future.result()
            self.dropped += 1

    def close(self) -> None:
        """Wait for the worker and end its thread (the end of the show, a quit or an error);
        a result not taken is dropped, and a worker's error is logged, not raised (an error
        of the loop may be on its way)."""
        job, self._job = self._job, None
        if job is not None:
            exc = job.future.exception()
            if exc is not None:
                log.warning("the settle of frame %d failed: %s", job.index, exc)
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


def _solve(comp, warped: np.ndarray, iterations: int | None, warp_s: float):
    """The worker: the settle's solve; returns its output, its info (with the warp's time,
    made on the loop's thread) and its cost (warp and solve, as this thread measured it)."""
    t0 = time.perf_counter()
    out = comp.compensate_warped(warped, iterations=iterations)
    info = dict(getattr(comp, "last_info", None) or {})
    info["seconds"] = {**(info.get("seconds") or {}), "warp": warp_s}
    return out, info, warp_s + time.perf_counter() - t0
