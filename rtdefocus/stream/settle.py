"""A still picture's settle, solved beside the live player's frame loop.

On a device too slow to compensate moving frames, the live player compensates a still picture
once, a *settle* (:class:`~rtdefocus.stream.catch_up.CatchUp`), which takes several frame
periods. Run on the frame loop's thread it would hold the loop: a new shot that starts during
it would lose its first frames, which geometry only would have shown. :class:`BackgroundSettle`
solves it on a worker thread of its own instead: the loop warps the still (GL stays on the
thread that owns its context), shows that warp and hands it to the worker, which runs the
Compensator's solve (:meth:`~rtdefocus.Compensator.compensate_warped`: OpenCL or NumPy only).
Meanwhile the loop shows every frame with geometry only (the still's repeats as its warp again,
at no cost) and starts no compensation (the device is busy). At the first frame after the
worker is done, the result is shown if that frame is still the same picture (and the display
mode and calibration did not change); otherwise it is dropped, never shown on another picture.
The Compensator's video state is then that of the still, as after a settle on the loop's
thread: the still's refinements continue its solve and skip its warp (the Compensator keeps it:
``compensate_warped(image=)``), and the next compensated frame starts from it by the motion, or
cold where the motion finds a cut.

The settle runs beside the loop only where the Compensator solves a warped frame itself
(``compensate_warped`` defined on its class: a wrapper that paces ``compensate`` and forwards
the rest would run it unpaced), its OpenCL context does not share the warp's GL context
(``shares_gl``: there the warp's renderbuffer is an OpenCL image, and the two threads would
share it), frames are read on a thread of their own and no watcher swaps the calibration or
takes frames; and where the frames shown meanwhile keep their period. A solver off the CPU
(``solves_off_the_cpu``: an OpenCL GPU) takes nothing from them. A solve on the CPU cores
(NumPy, an OpenCL CPU device) takes the cores from the warps of those frames: there the settle
runs beside the loop only where the loop's own work for a geometry-only frame, as measured on
the frames it showed so (:meth:`BackgroundSettle.timed`: the quantile
:data:`SETTLE_CPU_QUANTILE` of the last :data:`SETTLE_CPU_FRAMES`), times
:data:`SETTLE_CPU_SHARE` (the solve takes the cores from it) and :data:`SETTLE_CPU_HEADROOM`,
fits one frame period. Where that leaves no room (or before it is measured), no settle is made
(:meth:`BackgroundSettle.may_settle`): one on the loop's thread would hold the loop as long, and
one that spans a cut would lose the new shot's first frames; the still stays at geometry only.
Where the settle cannot run beside the loop for a reason of the player's (frames read on the
loop's thread, a watcher, a shared GL context, a wrapper), it runs on the loop's thread as a
compensated frame.
"""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .controls import SPREAD_MIN
from .sources import Frame

log = logging.getLogger(__name__)

#: A settle beside the loop on a CPU device: the loop's geometry-only frame, while a solve
#: uses every core, gets about half of the CPU (the solve's threads and the loop's share the
#: cores), so it takes SETTLE_CPU_SHARE times the work measured without a solve beside it
#: (:meth:`BackgroundSettle.timed`); that, times SETTLE_CPU_HEADROOM, must fit one frame period.
#: On 2 PoCL cores an 800x600 geometry-only frame is 17-19 ms of CPU, 9-10 ms a core: 24 ms
#: with both factors, so beside the loop at 24 and 30 fps, where a settle there kept every
#: frame in 3 idle runs, and none at 60 fps, where one beside the loop lost moving frames.
SETTLE_CPU_SHARE, SETTLE_CPU_HEADROOM = 2.0, 1.25
#: ... the geometry-only frames it is measured on (the last SETTLE_CPU_FRAMES shown without a
#: settle beside them, at least SPREAD_MIN), and the quantile of their costs taken.
SETTLE_CPU_FRAMES, SETTLE_CPU_QUANTILE = 24, 0.9


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
        self._geometry: deque[float] = deque(maxlen=SETTLE_CPU_FRAMES)   # seconds each
        self._cores = _cores()

    @property
    def busy(self) -> bool:
        """A settle is in progress or its result not yet taken."""
        return self._job is not None

    def _may_run_beside(self) -> bool:
        """All but the room: a player and Compensator whose settle may run beside the loop."""
        p = self.player
        comp = p.comp
        return (p.threads and p.watcher is None
                and callable(getattr(type(comp), "compensate_warped", None))
                and not getattr(comp, "shares_gl", False))

    def available(self) -> bool:
        """The settle can run beside the loop (see the module)."""
        return self._may_run_beside() and (
            bool(getattr(self.player.comp, "solves_off_the_cpu", False))
            or self.room_on_the_cpu())

    def may_settle(self) -> bool:
        """A settle may be made now (the catch-up asks before it settles a still): beside the
        loop where it can run there (:meth:`available`); on the loop's thread where it cannot
        for a reason of the player's (no decoder thread, a watcher, a shared GL context, a
        wrapper); never on a CPU device whose frame period leaves it no room beside the loop
        (:meth:`room_on_the_cpu`, also while that is not measured yet): there the still stays
        at geometry only, since a settle on the loop's thread would hold the loop as long, and
        one that spans a cut would lose the new shot's first frames."""
        return self.available() or not self._may_run_beside()

    def timed(self, process0: float, thread0: float) -> None:
        """After a frame the loop showed with geometry only: its work, from its CPU clocks
        (``time.process_time()`` and ``time.thread_time()``) taken when it began, as the
        seconds it needs at least with the cores to itself: its CPU time over every thread
        spread over the cores, or its own thread's, whichever is longer (CPU time, not the
        wall: a vsync wait or a core waking from idle takes no core from a solve). Frames
        shown while a settle runs beside the loop are left out (they share the cores)."""
        if self._job is None:
            spread = (time.process_time() - process0) / self._cores
            self._geometry.append(max(spread, time.thread_time() - thread0))

    def geometry_cost(self) -> float | None:
        """The :data:`SETTLE_CPU_QUANTILE` of the loop's work for its last geometry-only frames
        (:meth:`timed`), seconds; None before :data:`~rtdefocus.stream.controls.SPREAD_MIN`
        such frames."""
        if len(self._geometry) < SPREAD_MIN:
            return None
        costs = sorted(self._geometry)
        return costs[min(len(costs) - 1, round(SETTLE_CPU_QUANTILE * (len(costs) - 1)))]

    def room_on_the_cpu(self) -> bool:
        """A solve on the CPU cores beside the loop leaves the frames shown meanwhile their
        period: the loop's measured work for a geometry-only frame (:meth:`geometry_cost`),
        times :data:`SETTLE_CPU_SHARE` and :data:`SETTLE_CPU_HEADROOM`, fits one period
        (False before it is measured)."""
        cost = self.geometry_cost()
        period = (self.player.budget.period if self.player.budget is not None
                  else 1.0 / self.player.fps)
        return cost is not None and SETTLE_CPU_SHARE * SETTLE_CPU_HEADROOM * cost <= period

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
        future = self._pool.submit(_solve, p.comp, warped, iterations, warp_s, frame.image)
        self._job = _Job(future, p.comp, p.controls.version, frame.index, warped)
        log.debug("settle of frame %d started beside the loop (%d iterations; a geometry-only "
                  "frame %.1f ms)", frame.index, iterations or 0,
                  1e3 * (self.geometry_cost() or 0.0))
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


def _solve(comp, warped: np.ndarray, iterations: int | None, warp_s: float, image: np.ndarray):
    """The worker: the settle's solve; returns its output, its info (with the warp's time,
    made on the loop's thread) and its cost (warp and solve, as this thread measured it). The
    Compensator keeps ``image``'s warp, so that the still's refinements skip it."""
    t0 = time.perf_counter()
    out = comp.compensate_warped(warped, iterations=iterations, image=image)
    info = dict(getattr(comp, "last_info", None) or {})
    info["seconds"] = {**(info.get("seconds") or {}), "warp": warp_s}
    return out, info, warp_s + time.perf_counter() - t0


def _cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                   # (not on every OS)
        return max(1, os.cpu_count() or 1)
