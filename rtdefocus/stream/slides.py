"""Still pictures and slideshows: the stills half of :class:`~rtdefocus.stream.loop.Player`.

Still pictures (an image, a folder of slides) need no decoder: the current slide is refined
in short chunks (warm-started from the previous chunk) until the solver converges, the result
is cached on disk (:class:`~rtdefocus.stream.cache.SlideCache`) and the next slides are
compensated ahead while the presenter talks, so switching is instant.

The first chunk of a still starts from the picture's own target, so the result does not
depend on what was shown before.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .sources import SlidesSource

log = logging.getLogger(__name__)


@dataclass
class SlideWork:
    """A still picture being refined: its slide index and what was done so far."""

    index: int
    iterations: int = 0
    started: bool = False      # a chunk ran: the next continues from its P (warm start)
    done: bool = False
    last_out: np.ndarray | None = None


class SlidesMixin:
    """Plays still pictures: one refined picture into a file sink, or an interactive slideshow.

    Mixed into :class:`~rtdefocus.stream.loop.Player`, which provides the state and the frame
    primitives used here: ``comp``, ``source``, ``sink``, ``controls``, ``stats``, ``cache``,
    ``budget``, ``iterations``, ``max_iterations``, ``refine_tol``, ``refine_max``, ``ahead``,
    ``progress``, ``_stop``, ``_work`` (all set in ``Player.__init__``) and ``_compensate``,
    ``_render``, ``_present``, ``_present_warped``, ``_direct_geometry``, ``_handle_keys``,
    ``_idle``, ``_update_budget``.
    """

    _work: SlideWork | None
    #: Interactive show: "next" on the last slide ends the run (a playlist moves on) instead of
    #: staying there; :attr:`left_at_end` then says so.
    leave_at_end = False
    left_at_end = False

    def _chunk(self) -> int:
        if self.budget is not None:
            return max(1, self.budget.iterations)
        return self.max_iterations

    def _refine_step(self, index: int, image: np.ndarray) -> tuple[np.ndarray, bool]:
        """One chunk of iterations on still ``index``; returns (frame, converged).

        The first chunk of a new still starts from its target (``warm_start=False``), so the
        result does not depend on what was shown before; later chunks continue from the
        previous one's P.
        """
        w = self._work
        if w is None or w.index != index:
            w = self._work = SlideWork(index)
        if w.done and w.last_out is not None:
            return w.last_out, True
        if self.iterations is not None:          # a fixed budget: exactly that, from the target
            w.last_out, w.done = self._compensate(image, self.iterations, warm_start=False), True
            return w.last_out, True
        t0 = time.perf_counter()
        n = min(self._chunk(), max(1, self.refine_max - w.iterations))
        out = self._compensate(image, n, warm_start=w.started)
        w.started = True
        self._update_budget(t0)
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
        if self.iterations is not None:
            return self._compensate(image, self.iterations, warm_start=False)
        self._work = None
        while True:
            out, done = self._refine_step(-1, image)
            if done:
                self._work = None
                return out

    def _run_still(self) -> None:
        src: SlidesSource = self.source  # type: ignore[assignment]
        if self.sink.realtime:
            self._run_show(src)
            return
        store = _SlideStore(src, self.cache)
        for i in range(src.n_frames):
            if self._stop.is_set():
                break
            t0 = time.perf_counter()
            image = src.load(i)
            self.stats.frames_in += 1
            if self.controls.mode != "full":
                out = self._render(image)
            else:
                out = store.get(i)
                if out is None:
                    out = self.compensate_still(image)
                    store.put(i, out)
            self._present(out, i, None, t0)
            if self.progress:
                self.progress(self.stats.frames_out, src.n_frames)

    def _run_show(self, src: SlidesSource) -> None:
        """Interactive slideshow in the window: refine, cache, compensate ahead, navigate."""
        c = self.controls
        n = src.n_frames
        store = _SlideStore(src, self.cache, keep=max(4, 2 * self.ahead + 2))
        current, shown, last_overlay = 0, None, 0.0
        seen: set[int] = set()
        while True:
            self._handle_keys()
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
                self.stats.frames_in += 1
            want = (current, c.mode, c.version)
            t0 = time.perf_counter()
            if c.mode != "full":
                if shown != want:
                    if self._direct_geometry():
                        self._present_warped(src.load(current), current, None, t0)
                    else:
                        self._present(self._render(src.load(current)), current, None, t0)
                    shown = want
                else:
                    self._idle(0.02)
                continue
            result = store.get(current)
            if result is None and not c.paused:
                # Refine the current slide, showing each chunk: sharpens in front of the audience.
                image = src.load(current)
                out, done = self._refine_step(current, image)
                if done:
                    self._work = None
                    store.put(current, out)
                self._present(out, current, None, t0)
                shown = want
                continue
            if result is None and self._work is not None and self._work.index == current:
                result = self._work.last_out            # paused mid-refinement: hold it
            now = time.perf_counter()
            if result is not None and (shown != want or (c.overlay and now - last_overlay > 0.5)):
                self._present(result, current, None, t0)
                shown, last_overlay = want, now
                continue
            # Idle: compensate the next slides ahead, one chunk at a time so keys stay live.
            nxt = None if c.paused else next(
                (i for i in range(current + 1, min(n, current + 1 + self.ahead)) if not store.has(i)), None)
            if nxt is None:
                self._idle(0.02)
                continue
            out, done = self._refine_step(nxt, src.load(nxt))
            if done:
                self._work = None
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
