"""The frame loop's reading side: a source read into a bounded queue, on a thread of its own.

The drop policy (see :mod:`rtdefocus.stream.loop`): a live reader removes the oldest queued
frame when the queue is full and counts it (``stats.dropped``, and ``stats.dropped_copies``
when it repeats a picture that reached the screen), so the solver always gets the newest frame
and the source never waits; otherwise the reader blocks on a full queue, so every frame is
compensated. The queue is FIFO and only the reader removes from its head when dropping, so
frames keep their capture order.
"""

from __future__ import annotations

import collections
import queue
import threading
import time

from .repeat import same_picture
from .sources import Frame, Source
from .stats import LoopStats


class End:
    """Queue marker: the source is exhausted."""


class Failure:
    """Queue marker: the reader failed; the main thread re-raises ``exc``."""

    def __init__(self, exc: BaseException):
        self.exc = exc


#: The one end marker a :class:`Decoder` queues.
END = End()


class Decoder:
    """Reads ``source`` into :attr:`queue` (``queue_size`` frames), paced and dropping as asked.

    Parameters
    ----------
    source : Source
    stats : LoopStats
        Counts ``frames_in``, ``dropped``, ``dropped_copies`` and the ``read`` stage, which
        must exist before :meth:`run` starts (the thread never resizes the stages' dict).
    queue_size : int
    live : bool
        Drop the oldest waiting frame instead of waiting on a full queue.
    pace : float, optional
        Seconds between reads (a file shown in real time); None reads as fast as the queue
        takes.
    stop : threading.Event
        Set by the owner to end :meth:`run`.
    hold : threading.Event
        Set while paced reading should wait (paused playback).
    """

    def __init__(self, source: Source, stats: LoopStats, *, queue_size: int, live: bool,
                 pace: float | None, stop: threading.Event, hold: threading.Event):
        self.source, self.stats = source, stats
        self.queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self.live, self.pace = live, pace
        self._stop, self._hold = stop, hold
        self._recent: collections.deque = collections.deque(maxlen=queue_size + 2)  # (copies)
        self._lost: set[int] = set()      # frames dropped that were not copies

    def run(self) -> None:
        """Decoder thread: read, pace, enqueue (drop-oldest when live, blocking otherwise)."""
        src, st, pace = self.source, self.stats, self.pace
        read = st.stages["read"]   # created before the thread starts: no dict resize here
        t_next: float | None = None
        try:
            while not self._stop.is_set():
                if pace is not None:
                    if self._hold.is_set():          # paused file playback: stop reading
                        self._stop.wait(0.02)
                        t_next = None
                        continue
                    now = time.perf_counter()
                    if t_next is None or now - t_next > pace:
                        t_next = now                 # (re)start the clock; never burst to catch up
                    elif t_next > now and self._stop.wait(t_next - now):
                        break
                    t_next += pace
                t0 = time.perf_counter()
                frame = src.read()
                if frame is None:
                    break
                read.add(time.perf_counter() - t0)
                st.frames_in += 1
                if self.live:
                    self._recent.append(frame)
                    self._put_latest(frame)
                else:
                    self._put_blocking(frame)
        except BaseException as exc:  # handed to the main thread, which re-raises it
            if hasattr(exc, "add_note"):
                exc.add_note(f"(raised by {src.describe()} on the decoder thread)")
            self._put_blocking(Failure(exc))
            return
        self._put_blocking(END)

    def read_inline(self):
        """Without a thread: the next frame read on the calling thread (or :data:`END`)."""
        t0 = time.perf_counter()
        frame = self.source.read()
        if frame is None:
            return END
        self.stats.stages["read"].add(time.perf_counter() - t0)
        self.stats.frames_in += 1
        return frame

    def _put_latest(self, item) -> None:
        """Queue ``item``, dropping the oldest waiting frame when the queue is full. A dropped
        frame with the same picture as the frame queued before it, whose picture reached the
        screen, is also counted in ``stats.dropped_copies``."""
        q = self.queue
        while True:
            try:
                q.put_nowait(item)
                return
            except queue.Full:
                try:
                    stale = q.get_nowait()   # the oldest waiting frame: superseded, drop it
                except queue.Empty:
                    continue
                if isinstance(stale, Frame):
                    self.stats.dropped += 1
                    if self._is_copy(stale):
                        self.stats.dropped_copies += 1
                    else:
                        self._lost.add(stale.index)

    def _is_copy(self, stale: Frame) -> bool:
        """``stale`` repeats the picture of the frame queued just before it, and that one's
        picture reached the screen (taken by the main thread, or itself a copy)."""
        before = None
        for f in self._recent:
            if f is stale:
                break
            before = f
        else:
            return False
        return (before is not None and before.index not in self._lost
                and same_picture(before.image, stale.image))

    def _put_blocking(self, item) -> None:
        while not self._stop.is_set():
            try:
                self.queue.put(item, timeout=0.05)
                return
            except queue.Full:
                continue
