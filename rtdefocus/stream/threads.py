"""The writer thread: a file sink's encode and write overlap the next frame's solve.

:class:`SinkWriter` runs ``sink.write`` on its own thread behind a small bounded queue. OpenCV's
encoders (``VideoWriter.write``, ``imwrite``) release the GIL, so the encode of frame *i* runs
while the main thread warps and solves frame *i + 1*; with the decoder thread of
:mod:`rtdefocus.stream.loop` the frame rate is set by the slowest of decode, solve and encode
instead of their sum.

Order: one writer thread takes frames from a FIFO queue, so they reach the sink in the order
they were handed over. Errors: a failing ``write`` stops the thread; the exception (the sink's
own, with a note naming the frame) is raised in the main thread by the next :meth:`write` or by
:meth:`finish`. Shutdown: :meth:`finish` writes what is queued and joins the thread;
:meth:`abort` (an error or Ctrl-C in the main thread) drops what is queued and joins it. Neither
closes the sink: whoever opened it closes it (the player closes neither source nor sink).

Only sinks whose ``threaded`` flag is set get a writer: the projector window draws with GL,
which must stay on the thread that owns its context.
"""

from __future__ import annotations

import logging
import queue
import threading
import time

import numpy as np

from .sinks import Sink
from .stats import Series

log = logging.getLogger(__name__)

_STOP = object()
#: Seconds between checks of the other side while blocked on the queue.
_POLL = 0.05


def _note(exc: BaseException, text: str) -> None:
    if hasattr(exc, "add_note"):      # Python >= 3.11; 3.10 keeps the plain message
        exc.add_note(text)


class SinkWriter:
    """``sink.write`` on a thread of its own, behind a queue of ``maxsize`` frames.

    Parameters
    ----------
    sink : Sink
        Written only from the writer thread while it runs.
    maxsize : int
        Frames waiting for the writer; :meth:`write` blocks while the queue is full (file
        rendering keeps every frame), so memory stays bounded.
    series : Series, optional
        Receives the seconds of each ``sink.write`` (the ``write`` stage of the loop's stats);
        only the writer thread adds to it.

    Notes
    -----
    The frames handed to :meth:`write` must not be modified afterwards (the loop hands over
    fresh arrays: every Compensator call returns a new one).
    """

    def __init__(self, sink: Sink, maxsize: int = 2, series: Series | None = None):
        self.sink = sink
        self.series = series if series is not None else Series()
        self._q: queue.Queue = queue.Queue(maxsize=max(1, int(maxsize)))
        self._error: BaseException | None = None
        self._abort = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rtdefocus-write", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is _STOP or self._abort.is_set():
                return
            frame, index = item
            t0 = time.perf_counter()
            try:
                self.sink.write(frame, index)
            except BaseException as exc:  # raised again in the main thread
                _note(exc, f"(raised by {self.sink.describe()} writing frame {index} on the "
                      "writer thread)")
                self._error = exc
                return
            self.series.add(time.perf_counter() - t0)

    # ------------------------------------------------------------------ main thread
    def _raise_error(self) -> None:
        if self._error is not None:
            exc, self._error = self._error, None
            raise exc

    def write(self, frame: np.ndarray, index: int) -> None:
        """Queue one frame; raises the writer's error if an earlier frame failed."""
        self._raise_error()
        while True:
            try:
                self._q.put((frame, index), timeout=_POLL)
                return
            except queue.Full:
                self._raise_error()
                if not self._thread.is_alive():
                    raise RuntimeError("the writer thread stopped unexpectedly") from None

    def _stop(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while self._thread.is_alive():
            try:
                self._q.put(_STOP, timeout=_POLL)
                break
            except queue.Full:
                if time.monotonic() > deadline:
                    break
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive():
            log.warning("the writer thread of %s did not stop within %.0f s (a blocked write?)",
                        self.sink.describe(), timeout)

    def finish(self, timeout: float = 60.0) -> None:
        """Write every queued frame, stop the thread and raise its error if it had one."""
        self._stop(timeout)
        self._raise_error()

    def abort(self, timeout: float = 10.0) -> None:
        """Stop without writing what is queued (the main thread is failing or was interrupted);
        the writer's own error, if any, is logged rather than raised over the main one."""
        self._abort.set()
        while True:                       # make room for the stop marker
            try:
                self._q.get_nowait()
            except queue.Empty:
                break
        self._stop(timeout)
        if self._error is not None:
            log.error("the writer thread had failed too: %s", self._error)
            self._error = None

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()
