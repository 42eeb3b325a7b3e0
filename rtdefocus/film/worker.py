"""One chunk of a film, rendered where it is sent: a local worker process or a Dask worker.

Each process opens its own devices (the Compensator's OpenCL context and GL warp) on its first
chunk and keeps them for the next chunks of the same render: building the kernels costs more
than a short chunk. One chunk at a time per process (a Dask worker with several threads
renders them in turn), since a Compensator holds one video's state.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from .media import ChunkWriter, FilmInfo, Quality, read_frames
from .plan import Chunk

log = logging.getLogger(__name__)

__all__ = ["Job", "render_chunk", "watch_parent"]


@dataclass(frozen=True)
class Job:
    """Everything a worker needs to render any chunk of one render (picklable)."""

    setup: str                   # calibration file (.npz), a path every worker can read
    setup_digest: str
    film: FilmInfo               # its path, too, readable by every worker
    quality: Quality             # how the chunks are encoded
    work: str                    # the work sub-folder, writable by every worker
    compensator: dict = field(default_factory=dict)   # Compensator keyword arguments


# This process's Compensator for the job it last served; a lock serialises chunks within it.
_STATE: dict = {}
_LOCK = threading.Lock()


def _compensator(job: Job):
    key = (job.setup_digest, tuple(sorted(job.compensator.items())))
    if _STATE.get("key") != key:
        from ..calib.file import Calibration
        from ..compensate.compensator import Compensator

        _STATE.clear()
        _STATE["comp"] = Compensator(Calibration.load(job.setup), **job.compensator)
        _STATE["key"] = key
    return _STATE["comp"]


#: The render that started this worker (set by :func:`watch_parent` in a local pool's workers).
_PARENT: int | None = None


def _parent_gone() -> bool:
    return _PARENT is not None and os.getppid() != _PARENT


def watch_parent(parent_pid: int, period: float = 0.5) -> None:
    """End this worker process when the render that started it is gone (a local pool's
    initializer): a pool's worker holds both ends of its task pipe and would otherwise wait
    for tasks forever after a SIGKILL of its parent. The chunk it was on is left unfinished
    (under its temporary name), to be rendered again on resume."""

    global _PARENT
    _PARENT = parent_pid

    def watch():
        while True:
            time.sleep(period)
            if _parent_gone():
                os._exit(1)

    threading.Thread(target=watch, name="rtdefocus-watch-parent", daemon=True).start()


def render_chunk(job: Job, chunk: Chunk) -> dict:
    """Render ``chunk``: frames ``lead`` … ``stop - 1`` compensated in order with the warm start,
    frames ``start`` … ``stop - 1`` encoded to the chunk file (written under a temporary name,
    renamed when complete).

    Returns
    -------
    dict with ``index``, ``frames``, ``seconds``, ``pid`` and ``host`` (for the manifest).
    """
    with _LOCK:
        t0 = time.perf_counter()
        comp = _compensator(job)
        comp.reset()
        wp, hp = comp.projector_size
        out = Path(job.work) / chunk.name
        tmp = out.with_name(f".{chunk.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        written = 0
        try:
            with ChunkWriter(tmp, job.quality, job.film.fps, (wp, hp)) as writer:
                for i, image in enumerate(read_frames(job.film, chunk.lead, chunk.stop),
                                          start=chunk.lead):
                    frame = comp.compensate(image, warm_start=True)
                    if i >= chunk.start:
                        writer.write(frame)
                        written += 1
            if _parent_gone():
                # The render died while this chunk was on: a queued task must not finish it
                # in the watcher's period (resume renders it again).
                os._exit(1)
            os.replace(tmp, out)
        finally:
            if tmp.exists():
                tmp.unlink()
        comp.reset()
        seconds = time.perf_counter() - t0
        log.info("chunk %d: frames %d-%d in %.1f s", chunk.index, chunk.start, chunk.stop - 1,
                 seconds)
        return {"index": chunk.index, "frames": written, "seconds": round(seconds, 3),
                "pid": os.getpid(), "host": os.uname().nodename}
