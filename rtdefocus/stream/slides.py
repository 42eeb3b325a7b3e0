"""Still pictures and slideshows, played for :class:`~rtdefocus.stream.loop.Player`.

Still pictures (an image, a folder of slides) need no decoder: the current slide is refined
in short chunks (warm-started from the previous chunk) until the solver converges, the result
is cached on disk (:class:`~rtdefocus.stream.cache.SlideCache`) and the next slides are
compensated ahead while the presenter talks, so switching is instant.

The first chunk of a still starts from the picture's own target, so the result does not
depend on what was shown before.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .controls import Controls, IterationBudget
from .sources import SlidesSource
from .stats import LoopStats

log = logging.getLogger(__name__)


@dataclass
class SlideWork:
    """A still picture being refined: its slide index and what was done so far."""

    index: int
    iterations: int = 0
    started: bool = False      # a chunk ran: the next continues from its P (warm start)
    done: bool = False
    last_out: np.ndarray | None = None


class Screen(Protocol):
    """What a :class:`Slideshow` needs of the player that owns it: its controls and statistics,
    and the frame primitives that render, time and show a frame."""

    controls: Controls
    stats: LoopStats

    def handle_keys(self) -> None:
        """Apply the keys pressed since the last call to :attr:`controls`."""

    def idle(self, seconds: float = 0.01) -> None:
        """Wait a little (the window stays responsive)."""

    def render(self, image: np.ndarray) -> np.ndarray:
        """The frame for the projector in the current mode (full / geometry / off)."""

    def present(self, out: np.ndarray, index: int, t_read: float | None, t_start: float) -> None:
        """Show ``out`` (with the overlay when it is on), timed from ``t_start``."""

    def present_unrefined(self, image: np.ndarray, index: int, t_start: float) -> None:
        """Show ``image`` in the current mode other than full (geometry only or off)."""


class StillRefiner:
    """Refines still pictures in chunks of iterations until the solver converges.

    Parameters
    ----------
    compensator : rtdefocus.Compensator
        Read for ``last_info`` after each chunk.
    compensate : callable(image, iterations, warm_start) -> frame
        Runs one chunk (the player's timed compensation).
    measured : callable(t_start)
        Called after each chunk with its start time (the player's iteration budget learns
        from it).
    iterations : int, optional
        A fixed budget: exactly that many iterations, from the picture's own target.
    budget : IterationBudget, optional
        The adaptive budget, whose iterations make a chunk (else ``max_iterations``).
    max_iterations, refine_tol, refine_max
        See :class:`~rtdefocus.stream.loop.Player`.

    Attributes
    ----------
    work : SlideWork or None
        The still being refined; set to None to start the next one afresh.
    """

    def __init__(self, compensator, compensate: Callable[[np.ndarray, int | None, bool], np.ndarray],
                 measured: Callable[[float], None], *, iterations: int | None,
                 budget: IterationBudget | None, max_iterations: int, refine_tol: float,
                 refine_max: int):
        self.comp, self._compensate, self._measured = compensator, compensate, measured
        self.iterations, self.budget = iterations, budget
        self.max_iterations, self.refine_tol, self.refine_max = max_iterations, refine_tol, refine_max
        self.work: SlideWork | None = None

    def _chunk(self) -> int:
        if self.budget is not None:
            return max(1, self.budget.iterations)
        return self.max_iterations

    def hold(self, index: int) -> SlideWork:
        """The work on frame ``index`` (a paused video's held frame), started where it is not:
        its refinement continues from the P just shown."""
        if self.work is None or self.work.index != index:
            self.work = SlideWork(index, started=True)
        return self.work

    def step(self, index: int, image: np.ndarray) -> tuple[np.ndarray, bool]:
        """One chunk of iterations on still ``index``; returns (frame, converged).

        The first chunk of a new still starts from its target (``warm_start=False``), so the
        result does not depend on what was shown before; later chunks continue from the
        previous one's P.
        """
        w = self.work
        if w is None or w.index != index:
            w = self.work = SlideWork(index)
        if w.done and w.last_out is not None:
            return w.last_out, True
        if self.iterations is not None:          # a fixed budget: exactly that, from the target
            w.last_out, w.done = self._compensate(image, self.iterations, False), True
            return w.last_out, True
        t0 = time.perf_counter()
        n = min(self._chunk(), max(1, self.refine_max - w.iterations))
        out = self._compensate(image, n, w.started)
        w.started = True
        self._measured(t0)
        info = getattr(self.comp, "last_info", None) or {}
        its = int(info.get("iterations", n) or 0)
        dist = info.get("distances") or []
        w.iterations += its
        # Converged: the solver says so, stopped early, hit the cap, or barely moves any more.
        done = bool(info.get("converged")) or its < n or w.iterations >= self.refine_max
        if not done and len(dist) >= 2 and dist[0] > 0:
            per_iteration = (float(dist[0]) - float(dist[-1])) / float(dist[0]) / max(its, 1)
            done = per_iteration < self.refine_tol
        w.last_out, w.done = out, done
        if done:
            log.debug("still %d converged after %d iterations", index, w.iterations)
        return out, done

    def finish(self, image: np.ndarray) -> np.ndarray:
        """The finished compensation of ``image`` (see
        :meth:`~rtdefocus.stream.loop.Player.compensate_still`)."""
        if self.iterations is not None:
            return self._compensate(image, self.iterations, False)
        self.work = None
        while True:
            out, done = self.step(-1, image)
            if done:
                self.work = None
                return out


class Slideshow:
    """Plays still pictures: one refined picture into a file sink, or an interactive slideshow.

    Parameters
    ----------
    screen : Screen
        The player that owns the show: keys, rendering and presenting frames.
    source : SlidesSource
    refiner : StillRefiner
    cache : SlideCache, optional
        Where compensated slides are kept across runs.
    ahead : int
        Slides compensated ahead of the current one while the show is idle.
    stop : threading.Event
        Set to end the run.
    progress : callable(done, total), optional
        Called after each slide written into a file sink.
    leave_at_end : bool
        Interactive show: "next" on the last slide ends the run (a playlist moves on) instead
        of staying there; :attr:`left_at_end` then says so.
    """

    def __init__(self, screen: Screen, source: SlidesSource, refiner: StillRefiner, *,
                 cache=None, ahead: int = 2, stop: threading.Event,
                 progress: Callable[[int, int | None], None] | None = None,
                 leave_at_end: bool = False):
        self.screen, self.source, self.refiner = screen, source, refiner
        self.cache, self.ahead, self._stop, self.progress = cache, ahead, stop, progress
        self.leave_at_end = leave_at_end
        self.left_at_end = False

    def run(self, interactive: bool) -> None:
        """Show the slides in a window (``interactive``), else write each one refined."""
        if interactive:
            self._run_show()
            return
        src, screen = self.source, self.screen
        store = _SlideStore(src, self.cache)
        for i in range(src.n_frames):
            if self._stop.is_set():
                break
            t0 = time.perf_counter()
            image = src.load(i)
            screen.stats.frames_in += 1
            if screen.controls.mode != "full":
                out = screen.render(image)
            else:
                out = store.get(i)
                if out is None:
                    out = self.refiner.finish(image)
                    store.put(i, out)
            screen.present(out, i, None, t0)
            if self.progress:
                self.progress(screen.stats.frames_out, src.n_frames)

    def _run_show(self) -> None:
        """Interactive slideshow in the window: refine, cache, compensate ahead, navigate."""
        src, screen, refiner = self.source, self.screen, self.refiner
        c = screen.controls
        n = src.n_frames
        store = _SlideStore(src, self.cache, keep=max(4, 2 * self.ahead + 2))
        current, shown, last_overlay = 0, None, 0.0
        seen: set[int] = set()
        while True:
            screen.handle_keys()
            if c.quit:
                break
            if c.step:
                if self.leave_at_end and current + c.step >= n:
                    c.step = 0
                    self.left_at_end = True
                    break
                current = min(max(current + c.step, 0), n - 1)
                c.step = 0
            if current not in seen:
                seen.add(current)
                screen.stats.frames_in += 1
            want = (current, c.mode, c.version)
            t0 = time.perf_counter()
            if c.mode != "full":
                if shown != want:
                    screen.present_unrefined(src.load(current), current, t0)
                    shown = want
                else:
                    screen.idle(0.02)
                continue
            result = store.get(current)
            if result is None and not c.paused:
                # Refine the current slide, showing each chunk: sharpens in front of the audience.
                image = src.load(current)
                out, done = refiner.step(current, image)
                if done:
                    refiner.work = None
                    store.put(current, out)
                screen.present(out, current, None, t0)
                shown = want
                continue
            if result is None and refiner.work is not None and refiner.work.index == current:
                result = refiner.work.last_out          # paused mid-refinement: hold it
            now = time.perf_counter()
            if result is not None and (shown != want or (c.overlay and now - last_overlay > 0.5)):
                screen.present(result, current, None, t0)
                shown, last_overlay = want, now
                continue
            # Idle: compensate the next slides ahead, one chunk at a time so keys stay live.
            nxt = None if c.paused else next(
                (i for i in range(current + 1, min(n, current + 1 + self.ahead)) if not store.has(i)), None)
            if nxt is None:
                screen.idle(0.02)
                continue
            out, done = refiner.step(nxt, src.load(nxt))
            if done:
                refiner.work = None
                store.put(nxt, out)


class _SlideStore:
    """Compensated slides: a few in memory (LRU), all in the disk cache when one is given.
    Each slide's presence on disk is looked up once (hashing a slide is not free)."""

    def __init__(self, src: SlidesSource, cache=None, keep: int = 4):
        self.src, self.cache, self.keep = src, cache, keep
        self.mem: OrderedDict[int, np.ndarray] = OrderedDict()
        self.on_disk: dict[int, bool] = {}

    def _remember(self, i: int, out: np.ndarray) -> None:
        self.mem[i] = out
        self.mem.move_to_end(i)
        while len(self.mem) > self.keep:
            self.mem.popitem(last=False)

    def has(self, i: int) -> bool:
        if i in self.mem:
            return True
        if self.cache is None:
            return False
        if i not in self.on_disk:
            self.on_disk[i] = self.cache.path(self.src.load(i)).is_file()
        return self.on_disk[i]

    def get(self, i: int) -> np.ndarray | None:
        if i in self.mem:
            self.mem.move_to_end(i)
            return self.mem[i]
        if self.cache is None or self.on_disk.get(i) is False:
            return None
        hit = self.cache.get(self.src.load(i))
        self.on_disk[i] = hit is not None
        if hit is not None:
            self._remember(i, hit)
        return hit

    def put(self, i: int, out: np.ndarray) -> None:
        self._remember(i, out)
        if self.cache is not None:
            self.cache.put(self.src.load(i), out)
            self.on_disk[i] = True
