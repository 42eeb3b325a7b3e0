"""The frame loop: source → compensate → sink, with explicit stages and a documented drop policy.

Stages and threads
------------------
::

    decoder thread                 bounded queue              main thread
    source.read() ──► Frame ──►  [ maxsize = queue_size ]  ──► compensate ──► overlay ──► sink.write
    (paced to fps for a file                                   (GL warp + CL solve: the GL and CL
     shown in real time)                                        contexts live on this thread)

    main thread                    bounded queue (2)          writer thread (file sinks only)
    ... ──► sink hand-off ──►     [ (frame, index) ]  ──►   sink.write (encode + write)

With a file sink the three stages overlap: decode of frame i + 1, solve of frame i and encode of
frame i − 1 run at once (OpenCV's decode and encode and OpenCL's waits release the GIL), so
the frame rate is set by the slowest stage rather than their sum. The projector window is not
given a writer: GL stays on the thread that owns its context. ``threads=False`` runs every
stage in turn on the calling thread (the reference the threaded path must equal frame by frame).

Nothing is shared between the threads except the queues and a few counters each written by
one thread only; in particular there is no "latest frame" attribute that one thread overwrites
and another reads. An error on either side thread reaches the main thread, which raises it
(the original exception, with a note naming the thread and frame); on any exit, Ctrl-C
included, the side threads are stopped and joined before :meth:`Player.run` returns.

Drop policy
-----------
*Realtime* (a live source such as a camera, or any source shown in the projector window):
the queue holds ``queue_size`` frames (default 2). When it is full the decoder removes the
oldest queued frame and counts it in ``stats.dropped`` before adding the new one, so the
solver gets the newest frames, frames keep their capture order (the queue is FIFO and only
the decoder removes from its head when dropping), and the source never waits. The second
place is slack for a frame that overruns its deadline (a device's cost beyond its measured
spread): the frame after it is shown late (``stats.late``), not lost, and the catch-up below
shows geometry only until the loop is on time again. A dropped
frame that repeats the picture of the frame before it (a still, a paused camera) loses nothing
on the screen: ``stats.dropped_copies`` counts those among ``stats.dropped``. The
per-frame iteration budget adapts to hold the target frame rate
(:class:`~rtdefocus.stream.controls.IterationBudget`). Where even its minimum does not fit (a
slow device on moving content), a frame whose compensation, by its measured cost times a safety
margin, would end after the frame after next has arrived is shown with geometry only
(``catch_up``; see :mod:`rtdefocus.stream.catch_up`; a still picture's one compensation, its
settle, is solved beside the loop where the frames shown meanwhile keep their period:
:mod:`rtdefocus.stream.settle`): a warp costs a fraction of a solve, so the loop keeps up
instead of dropping the next frame and leaving a late one on the screen (on moving content a
repeated frame looks far worse than an uncompensated fresh one; ``stats.geometry_frames``
counts them). Before the first frame a live player runs the
Compensator's video path once (:meth:`~rtdefocus.Compensator.warm_up`), so that the first moving
frame neither pays first-use costs nor is timed from a still picture's.

*File rendering* (a file or memory source into a file sink): the decoder blocks on a full
queue, so every frame is compensated and written, in order, with the full iteration budget.

Still pictures (an image, a folder of slides) need no decoder: they are played by
:class:`~rtdefocus.stream.slides.Slideshow`. Keys, display modes, the per-frame iteration
budget and the stats overlay are in :mod:`rtdefocus.stream.controls`.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable

import numpy as np

from .. import __version__
from ..errors import InputError
from ..imageio import fit_image
from .cache import SlideCache, calibration_fingerprint
from .catch_up import CatchUp, warm_up
from .controls import Controls, IterationBudget, KeyDispatcher, draw_overlay
from .decoder import END, Decoder, Failure
from .repeat import same_picture
from .settle import BackgroundSettle
from .sinks import Sink
from .slides import Slideshow, StillRefiner
from .sources import Frame, SlidesSource, Source
from .stats import LoopStats, Series
from .threads import SinkWriter

log = logging.getLogger(__name__)

ProgressFn = Callable[[int, "int | None"], None]

class Player:
    """Runs one source through a Compensator into one sink.

    Parameters
    ----------
    compensator : rtdefocus.Compensator
        Anything with ``compensate(image, *, iterations, warm_start)``, ``warp(image)``,
        ``last_info`` and ``projector_size``.
    source : Source
    sink : Sink
    fps : float, optional
        Target frame rate of realtime playback (default: the source's, else 30). Also the
        pace a video file is played at in the window.
    iterations : int, optional
        Fixed solver iterations per frame. Default: adaptive (:class:`IterationBudget`) for
        realtime playback; the Compensator's own budget for file rendering; stills refine
        until converged.
    live : bool, optional
        Drop stale frames instead of waiting (default: the source is live or the sink is
        realtime).
    queue_size : int, optional
        Frames between decoder and solver (default 2 when live, 4 otherwise).
    cache : SlideCache, path, True or None
        Where compensated stills are kept across runs: a :class:`SlideCache`, a cache root
        folder, True for the default folder, or None (no disk cache). A path or True keys the
        cache on ``compensator.calib`` and :meth:`settings`.
    progress : callable(done, total), optional
        Called after each frame written (``total`` None when unknown): the CLI's progress bar.
    overlay : bool
        Start with the stats overlay on.
    max_iterations : int, optional
        Upper bound of the adaptive budget (default: the Compensator's ``iterations``, else 20).
    refine_tol : float
        A still is converged when a chunk of iterations lowers the distance by less than this
        fraction per iteration (or the solver reports convergence).
    refine_max : int, optional
        Iteration cap per still (default 10 × ``max_iterations``).
    ahead : int
        Slides compensated ahead of the current one while the show is idle.
    threads : bool
        Decode on a thread of its own and, for a file sink, encode/write on another (default);
        False runs every stage in turn on the calling thread (no pacing, no dropping: for
        comparisons and tests).
    catch_up : bool
        Realtime playback with the adaptive budget: show a frame with geometry only when
        compensating it would make the loop drop the next one (default True; see the module's
        drop policy).
    watcher : rtdefocus.watch.Watcher, optional
        Offered every frame shown; its mended calibration is swapped in between two frames (a
        new Compensator, :meth:`~rtdefocus.Compensator.with_calibration`), and while it does not
        trust the model, frames are shown with geometry only; during one of its pattern
        bursts its pattern frames are shown instead (:meth:`~rtdefocus.watch.Watcher.pattern`).

    Notes
    -----
    Call :meth:`run` on the thread that owns the Compensator's GL/CL contexts (normally the
    main thread). The returned :class:`LoopStats` holds the run's summary.
    """

    _source_paused = False        # the source's own clock is paused (see _pause_source)

    def __init__(self, compensator, source: Source, sink: Sink, *, fps: float | None = None,
                 iterations: int | None = None, live: bool | None = None,
                 queue_size: int | None = None, cache=None, progress: ProgressFn | None = None,
                 overlay: bool = False, max_iterations: int | None = None, refine_tol: float = 2e-4,
                 refine_max: int | None = None, ahead: int = 2, keymap: dict[str, str] | None = None,
                 threads: bool = True, catch_up: bool = True, watcher=None):
        if iterations is not None and iterations < 0:
            raise InputError(f"iterations must be >= 0; got {iterations}")
        if fps is not None and fps <= 0:
            raise InputError(f"fps must be positive; got {fps}")
        self.comp, self.source, self.sink = compensator, source, sink
        self.projector_size = tuple(compensator.projector_size)
        self.fps = float(fps or source.fps or 30.0)
        self.iterations = iterations
        self.live = bool(source.live or sink.realtime) if live is None else bool(live)
        self.queue_size = int(queue_size or (2 if self.live else 4))
        if self.queue_size < 1:
            raise InputError(f"queue_size must be >= 1; got {queue_size}")
        self.progress = progress
        self.max_iterations = int(max_iterations or getattr(compensator, "iterations", 0) or 20)
        self.refine_tol = float(refine_tol)
        self.refine_max = int(refine_max or 10 * self.max_iterations)
        self.ahead = int(ahead)
        self.cache = self._make_cache(cache)
        self.controls = Controls(overlay=overlay)
        self.dispatcher = KeyDispatcher(self.controls, keymap)
        self.budget: IterationBudget | None = None
        if iterations is None and sink.realtime:
            self.budget = IterationBudget(self.fps, maximum=self.max_iterations)
        self.stats = LoopStats(source.describe(), sink.describe())
        if self.live and sink.realtime:     # the catch-up's promise: before the frame after next
            self.stats.deadline = 2.0 / self.fps
        self._stop = threading.Event()
        self._hold = threading.Event()       # set while a paced (file) source should wait
        self._last_index = -1
        self._refiner = StillRefiner(compensator, self._compensate, self._update_budget,
                                     iterations=iterations, budget=self.budget,
                                     max_iterations=self.max_iterations,
                                     refine_tol=self.refine_tol, refine_max=self.refine_max)
        #: A slideshow: "next" on the last slide ends the run (a playlist moves on) instead of
        #: staying there; :attr:`left_at_end` then says so.
        self.leave_at_end = False
        self.left_at_end = False
        self.threads = bool(threads)
        self.catch_up = bool(catch_up)
        self._prev_input: np.ndarray | None = None   # the last input (budget kinds, catch-up)
        self._prev_compensated = False               # ... and whether it was compensated
        self._catch_up = CatchUp(self.budget) if self.budget is not None else None
        self._last_out: np.ndarray | None = None     # the last compensated output (reshow)
        self._settle = BackgroundSettle(self)        # a still's settle beside the frame loop
        self._writer: SinkWriter | None = None
        if watcher is not None and not hasattr(compensator, "with_calibration"):
            raise InputError("a watcher needs a compensator with with_calibration(calib) (as "
                             "rtdefocus.Compensator has) to apply its mended calibrations")
        if watcher is not None and source.still and isinstance(source, SlidesSource):
            raise InputError("the watcher watches video and live sources; a slideshow is "
                             "played without it (leave out --watch / watcher=)")
        self.watcher = watcher

    def settings(self) -> dict:
        """What changes a compensated still: the slide cache keys on it (with the calibration)."""
        comp = self.comp
        names = ("method", "solver_name", "weights", "headroom", "tol", "backend", "surface",
                 "brightness", "precondition", "adjoint")
        return {"compensator": {n: getattr(comp, n, None) for n in names},
                "iterations": self.iterations, "refine_tol": self.refine_tol,
                "refine_max": self.refine_max, "rtdefocus": __version__}

    def _make_cache(self, cache):
        if cache is None or cache is False or isinstance(cache, SlideCache):
            return cache or None
        calib = getattr(self.comp, "calib", None)
        if calib is None:
            raise InputError("a slide cache needs the Compensator's calibration (comp.calib)")
        root = None if cache is True else cache
        return SlideCache(calibration_fingerprint(calib), self.settings(), root=root)

    # ------------------------------------------------------------------ public
    def run(self) -> LoopStats:
        """Play the source to the end (or until quit); return the run's statistics."""
        log.info("playing %s -> %s (%s, %s)", self.source.describe(), self.sink.describe(),
                 "live: drop stale frames" if self.live else "every frame",
                 f"{self.iterations} iterations" if self.iterations is not None else
                 (f"adaptive budget at {self.fps:.3g} fps" if self.budget else "full budget"))
        try:
            if self.source.still and isinstance(self.source, SlidesSource):
                self._run_still()
            else:
                self._run_sequence()
        finally:
            self._stop.set()
            self.stats.finish()
            if self.budget is not None:
                self.stats.budget = self.budget.iterations
        log.debug("%s", self.stats.summary())
        return self.stats

    def compensate_still(self, image: np.ndarray) -> np.ndarray:
        """The finished compensation of a still picture, as a slide shows it once refined.

        Starts from the picture's own target (not the previous frame), then runs chunks of
        iterations until the solver converges (see ``refine_tol``, ``refine_max``), or exactly
        ``iterations`` when the player has a fixed budget.

        Parameters
        ----------
        image : (H, W, 3) uint8 RGB

        Returns
        -------
        (Hp, Wp, 3) uint8
        """
        return self._refiner.finish(image)

    def _run_still(self) -> None:
        show = Slideshow(self, self.source, self._refiner, cache=self.cache, ahead=self.ahead,
                         stop=self._stop, progress=self.progress, leave_at_end=self.leave_at_end)
        show.run(interactive=self.sink.realtime)
        self.left_at_end = show.left_at_end

    # ------------------------------------------------------------------ frame primitives
    # (the interface a Slideshow plays through: slides.Screen)
    def handle_keys(self) -> None:
        """Apply the keys pressed since the last call to :attr:`controls`."""
        for key in self.sink.poll():
            self.dispatcher.dispatch(key)

    # ------------------------------------------------------------------ rendering
    def _compensate(self, image: np.ndarray, iterations: int | None, warm_start: bool) -> np.ndarray:
        t0 = time.perf_counter()
        out = self.comp.compensate(image, iterations=iterations, warm_start=warm_start)
        self._count_solve(time.perf_counter() - t0, getattr(self.comp, "last_info", None) or {},
                          iterations)
        return out

    def _count_solve(self, dt: float, info: dict, iterations: int | None) -> None:
        st = self.stats
        st.add("compensate", dt)
        for stage, sec in (info.get("seconds") or {}).items():
            if stage != "total":
                st.add(stage, sec)
        st.iterations.add(info.get("iterations", iterations or 0))
        st.add_surface(info)
        dist = info.get("distances")
        if dist:
            st.residual = float(dist[-1])

    def render(self, image: np.ndarray, *, iterations: int | None = None,
               warm_start: bool = True) -> np.ndarray:
        """The frame for the projector in the current mode (full / geometry / off); full
        compensates with ``iterations`` (default: the Compensator's own budget)."""
        mode = self.controls.mode
        if mode == "off":
            return fit_image(image, self.projector_size)
        if mode == "geometry":
            return self._warp(image)
        return self._compensate(image, iterations, warm_start)

    def _warp(self, image: np.ndarray) -> np.ndarray:
        """Geometry only (the Compensator's warp), timed as the ``warp`` stage."""
        t0 = time.perf_counter()
        out = self.comp.warp(image)
        self.stats.add("warp", time.perf_counter() - t0)
        return out

    def _frame_iterations(self, repeat: bool = False) -> int | None:
        if self.iterations is not None:
            return self.iterations
        if self.budget is not None:
            return self.budget.iterations_for(repeat)
        return None  # the Compensator's own budget

    def _same_as_previous(self, image: np.ndarray) -> bool:
        """Realtime with the adaptive budget: the same picture as the frame before (a paused
        video, a still)."""
        prev, self._prev_input = self._prev_input, image
        return self.budget is not None and prev is not None and same_picture(prev, image)

    def present(self, out: np.ndarray, index: int, t_read: float | None, t_start: float,
                overlay: bool = True) -> None:
        """Show ``out`` as frame ``index`` (with the overlay when it is on and ``overlay``): its
        latency counts from ``t_read`` (None: not a read frame), its frame time from ``t_start``."""
        st = self.stats
        if self.controls.overlay and overlay:
            out = draw_overlay(out, st.overlay_lines(self.controls.mode, self.controls.paused))
        t0 = time.perf_counter()
        (self._writer or self.sink).write(out, index)   # the writer: hand-off only
        t1 = time.perf_counter()
        st.add("present", t1 - t0)
        if self.watcher is not None:
            self.watcher.offer(out)
        st.add("frame", t1 - t_start)
        if t_read is not None:
            st.add_latency(t1 - t_read)
        st.frame_out()

    def _direct_geometry(self, catching_up: bool = False) -> bool:
        """Geometry only (the mode, or a frame shown so to keep up) into a window of the
        projector's size, no overlay: the warp shader can render straight into the window (no
        read-back, no second upload)."""
        calib = getattr(self.comp, "calib", None)
        return ((catching_up or self.controls.mode == "geometry") and not self.controls.overlay
                and calib is not None and self.watcher is None  # (the watcher needs the frame)
                and getattr(self.sink, "can_warp", None) is not None
                and self.sink.can_warp(calib))

    def present_unrefined(self, image: np.ndarray, index: int, t_start: float) -> None:
        """Show ``image`` in the current mode other than full (geometry only or off): straight
        into the window where the warp can render there."""
        if self._direct_geometry():
            self._present_warped(image, index, None, t_start)
        else:
            self.present(self.render(image), index, None, t_start)

    def _present_warped(self, image: np.ndarray, index: int, t_read: float | None, t_start: float) -> None:
        self.sink.write_warped(image, index, self.comp.calib)
        t1 = time.perf_counter()
        st = self.stats
        st.add("warp+present", t1 - t_start)
        st.add("frame", t1 - t_start)
        if t_read is not None:
            st.add_latency(t1 - t_read)
        st.frame_out()

    def _catch_up_iterations(self, frame: Frame, iterations: int | None, still: bool,
                             repeat: bool) -> tuple[str, int | None]:
        """Realtime, full mode, adaptive budget: what to show for ``frame``, as ``(action, n)``
        (:meth:`CatchUp.decide <rtdefocus.stream.catch_up.CatchUp.decide>`). Outside the
        catch-up: ``("compensate", iterations)``."""
        if (self._catch_up is None or iterations is None or not self.catch_up or not self.live
                or self.controls.mode != "full"):
            return "compensate", iterations
        return self._catch_up.decide(frame, iterations, still, repeat,
                                     can_reshow=self._last_out is not None,
                                     can_settle=self._settle.may_settle)

    def _warm_up(self) -> None:
        """Live playback with an adaptive budget: run the Compensator's video path before the
        first frame (:meth:`Compensator.warm_up`), so that its first-use costs do not make the
        first moving frame late, and start the budget from its moving frames' costs and their
        spread (not from a still picture's, a fraction of it and steadier)."""
        if self.budget is None or not self.live or not hasattr(self.comp, "warm_up"):
            return
        t0 = time.perf_counter()
        info = warm_up(self.comp, self.budget)
        if not info:
            return
        sec = info.get("seconds") or {}
        self.stats.restart()                 # the frame rate counts from the first frame
        log.info("warmed up in %.2f s (a moving frame: %.0f ms)", time.perf_counter() - t0,
                 1e3 * sec.get("total", float("nan")))

    def _show_geometry(self, frame: Frame, t_start: float) -> None:
        """``frame`` with geometry only, to keep up (see :meth:`_catch_up_iterations`)."""
        self.stats.geometry_frames += 1
        cpu = time.process_time(), time.thread_time()    # (the room a settle leaves: timed)
        if self._direct_geometry(catching_up=True):
            self._present_warped(frame.image, frame.index, frame.t_read, t_start)
        else:
            self.present(self._warp(frame.image), frame.index, frame.t_read, t_start)
        self._settle.timed(*cpu)

    def _update_budget(self, t_start: float, repeat: bool = False, info: dict | None = None) -> None:
        if self.budget is None or self.controls.mode != "full":
            return
        info = info if info is not None else (getattr(self.comp, "last_info", None) or {})
        sec = info.get("seconds") or {}
        its = int(info.get("iterations", 0) or 0)
        solve = float(sec.get("solve", 0.0)) if "solve" in sec else self.stats.stages["compensate"].last
        # A new frame that started cold (a cut, the first frame) skipped the motion estimate and
        # the warm start: its cost says little about the next moving frame's deadline.
        moving_cost = repeat or info.get("start") not in ("cut", "cold")
        frame_seconds = time.perf_counter() - t_start
        self.budget.update(frame_seconds, solve, its, repeat=repeat, deadline=moving_cost)
        if not repeat and "warp" in sec and "decode" in sec:
            # What the same picture costs again: all but the warp and the start, which a
            # repeat skips (until a repeat is measured; else a slow device never tries one).
            self.budget.expect(frame_seconds - solve - sec["warp"] - sec["decode"], repeat=True)

    def idle(self, seconds: float = 0.01) -> None:
        """Wait ``seconds`` (the window keeps handling its events meanwhile)."""
        window = getattr(self.sink, "window", None)
        if window is not None and hasattr(window, "wait"):
            window.wait(seconds)
        else:
            time.sleep(seconds)

    # ------------------------------------------------------------------ sequences
    def _run_sequence(self) -> None:
        st = self.stats
        self._warm_up()
        st.stages["read"] = Series()  # created here: the decoder never resizes the dict
        pace = (1.0 / self.fps) if (self.sink.realtime and not self.source.live) else None
        decoder = Decoder(self.source, st, queue_size=self.queue_size, live=self.live, pace=pace,
                          stop=self._stop, hold=self._hold)
        thread = None
        if self.threads:
            thread = threading.Thread(target=decoder.run, name="rtdefocus-decode",
                                      daemon=True)
            thread.start()
        ok = False
        try:
            if self.threads and getattr(self.sink, "threaded", False):
                st.stages["write"] = Series()   # the writer thread's own series
                self._writer = SinkWriter(self.sink, maxsize=2, series=st.stages["write"])
            self._play_frames(decoder)
            if self._writer is not None:
                t0 = time.perf_counter()
                self._writer.finish()            # the queued frames, written; its error raised
                st.add("flush", time.perf_counter() - t0)
            ok = True
        finally:
            self._stop.set()
            self._settle.close()                 # the settle's worker, joined
            self._pause_source(False)            # a read waiting on a paused clock returns
            if self._writer is not None:
                if not ok:
                    self._writer.abort()
                self._writer = None
            if self.watcher is not None:
                self.watcher.close()             # a look in progress on its thread
            if thread is not None:
                thread.join(timeout=10)
                if thread.is_alive():
                    log.warning("decoder thread did not stop within 10 s (a blocking camera read?)")

    def _pause_source(self, paused: bool) -> None:
        """A live source with a clock of its own (a video shown by its sound) stops with the
        picture: its sound and clock pause while the viewer pauses."""
        pause = getattr(self.source, "set_paused", None) if self.source.live else None
        if pause is not None and paused != self._source_paused:
            self._source_paused = paused
            pause(paused)

    def _play_frames(self, decoder: Decoder) -> None:
        held: Frame | None = None
        shown_version = -1
        while True:
            self.handle_keys()
            c = self.controls
            if c.quit:
                break
            if c.paused and self.sink.realtime:
                self._hold.set()
                self._pause_source(True)
                if held is not None:
                    self._settle.wait()          # (the refinement needs the solver)
                    shown_version = self._refresh_held(held, shown_version)
                else:
                    self.idle(0.02)
                continue
            self._hold.clear()
            self._pause_source(False)
            self._refiner.work = None
            if self.threads:
                try:
                    item = decoder.queue.get(timeout=0.05 if self.sink.interactive else 1.0)
                except queue.Empty:
                    continue
            else:
                item = decoder.read_inline()
            if item is END:
                break
            if isinstance(item, Failure):
                raise item.exc
            frame: Frame = item
            if frame.index <= self._last_index:  # the queue is FIFO; this would be a bug
                raise RuntimeError(f"frame {frame.index} after {self._last_index}: reordered")
            self._last_index = frame.index
            self._apply_watch()
            t0 = time.perf_counter()
            pattern = self.watcher.pattern() if self.watcher is not None else None
            if pattern is not None:     # a burst: the camera must see the pattern alone
                self.stats.pattern_frames += 1
                self.present(pattern, frame.index, frame.t_read, t0, overlay=False)
            elif self._direct_geometry():
                self._present_warped(frame.image, frame.index, frame.t_read, t0)
            else:
                still = self._same_as_previous(frame.image)   # the picture did not change
                if not still and self._catch_up is not None:
                    self._catch_up.new_picture(frame.index)
                if not self._settle.show(frame, still, t0):  # (one in progress: shown there)
                    self._show_frame(frame, still, t0)
            held, shown_version = frame, c.version
            if self.progress:
                self.progress(self.stats.frames_out, self.source.n_frames)

    def _show_frame(self, frame: Frame, still: bool, t0: float) -> None:
        """``frame`` compensated, or shown so as to keep up (``still``: the same picture as the
        frame before; ``repeat``: nor since the last frame compensated, which then skips the
        warp and the motion estimate)."""
        repeat = still and self._prev_compensated
        action, iters = self._catch_up_iterations(frame, self._frame_iterations(repeat),
                                                  still, repeat)
        geometry = action == "geometry"
        # The watcher knows the model is wrong: geometry only until it is mended.
        distrust = self.watcher is not None and not self.watcher.trusted
        self._prev_compensated = not (geometry or distrust) and self.controls.mode == "full"
        if geometry:
            self._show_geometry(frame, t0)   # (the budget learns from compensated frames)
        elif distrust and self.controls.mode == "full":
            self.present(self._warp(frame.image), frame.index, frame.t_read, t0)
        elif action == "reshow":
            self.present(self._last_out, frame.index, frame.t_read, t0)
        elif action == "settle" and self._settle.start(frame, iters, t0):
            self._prev_compensated = False   # (until its result is shown)
        else:
            out = self.render(frame.image, iterations=iters)
            self._last_out = out if self.controls.mode == "full" else None
            self.present(out, frame.index, frame.t_read, t0)
            self._update_budget(t0, repeat)
        if self._catch_up is not None and (not still or action == "compensate"):
            # (a settle is expected to run long)
            self._catch_up.judge(frame, compensated=action == "compensate")

    def _apply_watch(self) -> None:
        """Between two frames: the watcher's mended calibration, as a new Compensator."""
        update = self.watcher.poll() if self.watcher is not None else None
        if update is not None and update.calibration is not getattr(self.comp, "calib", None):
            self.comp = self._refiner.comp = self.comp.with_calibration(update.calibration)
            log.info("calibration updated by the watcher (%s)", ", ".join(update.kinds))

    def _refresh_held(self, held: Frame, shown_version: int) -> int:
        """Paused video: keep refining the held frame until converged (it continues from the P
        just shown); redraw when a key changes the mode or the overlay."""
        c = self.controls
        w = self._refiner.hold(held.index)
        if c.mode == "full" and not w.done:
            t0 = time.perf_counter()
            out, _ = self._refiner.step(held.index, held.image)
            self.present(out, held.index, None, t0)
            return c.version
        if c.version != shown_version:
            t0 = time.perf_counter()
            out = w.last_out if (c.mode == "full" and w.last_out is not None) else self.render(
                held.image, iterations=self._frame_iterations())
            self.present(out, held.index, None, t0)
            return c.version
        self.idle(0.02)
        return shown_version


def play(compensator, source: Source, sink: Sink, **options) -> LoopStats:
    """Run ``source`` through ``compensator`` into ``sink`` (see :class:`Player` for options);
    closes neither. Returns the run's :class:`LoopStats`."""
    return Player(compensator, source, sink, **options).run()
