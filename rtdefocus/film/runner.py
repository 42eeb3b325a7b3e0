"""``rtdefocus.render``: a film compensated once, at the full budget, into a file any player shows.

The film is cut into chunks of consecutive frames (:mod:`.plan`); each chunk is a task
(:func:`.worker.render_chunk`) run on local worker processes or on a Dask cluster; finished
chunks stay in the work folder, so a render that is stopped resumes where it stopped; the
chunks' packets and the film's audio packets are then copied into the output (:func:`.media.mux`).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from pathlib import Path

from .. import __version__
from ..checks import check_choice, check_int
from ..errors import InputError, RtDefocusError
from .media import QUALITIES, check_container, mux, probe
from .plan import Chunk, WorkFolder, file_digest, plan_chunks
from .worker import Job, render_chunk, watch_parent

log = logging.getLogger(__name__)

__all__ = ["render", "RenderResult", "DEFAULT_CHUNK_FRAMES", "DEFAULT_OVERLAP",
           "RENDER_ITERATIONS"]

#: Frames per chunk: a few seconds of film, long enough that the overlap costs little,
#: short enough that a stopped render loses little and the progress bar moves.
DEFAULT_CHUNK_FRAMES = 48
#: Frames solved before a chunk's first one and thrown away (docs/render.md: the seam).
DEFAULT_OVERLAP = 6
#: Solver iterations per frame: the offline budget of ``rtdefocus eval --video``.
RENDER_ITERATIONS = 40


@dataclass
class RenderResult:
    """What :func:`render` did: the ``output`` file, the film's ``frames`` and ``fps``, the
    ``chunks`` planned, those ``rendered`` now and those ``resumed`` from the work folder,
    ``seconds`` of wall time and the ``work`` sub-folder."""

    output: Path
    frames: int
    fps: float
    chunks: int
    rendered: list[int]
    resumed: list[int]
    seconds: float
    work: Path


def render(setup: str | Path, film: str | Path, output: str | Path, *, quality: str = "high",
           crf: int | None = None,
           workers: int = 2, scheduler=None, chunk_frames: int = DEFAULT_CHUNK_FRAMES,
           overlap: int = DEFAULT_OVERLAP, iterations: int = RENDER_ITERATIONS,
           method: str = "ycbcr", backend: str = "auto", work: str | Path | None = None,
           keep_work: bool = False,
           progress: Callable[[int, int], None] | None = None) -> RenderResult:
    """Render ``film`` through the calibration ``setup`` into ``output``, with its sound.

    Every frame is compensated at ``iterations`` per frame, warm-started from the previous
    frame of its chunk along the motion; the output is the projector's framebuffer (the
    calibrated size) at the film's frame rate, its audio streams copied packet for packet.

    Parameters
    ----------
    setup : calibration file (``rtdefocus calibrate``).
    film : any video file FFmpeg reads, with or without sound.
    output : ``.mp4`` / ``.mkv`` / ``.mov`` (``quality="archive"``: ``.mkv``).
    quality : "high" | "compatible" | "archive"
        :data:`~rtdefocus.film.media.QUALITIES`: H.264 4:4:4 crf 4 (default), H.264 4:2:0
        crf 12 for players that decode nothing else, FFV1 lossless RGB.
    crf : int, optional
        The H.264 qualities' constant rate factor instead of theirs (0-51, lower: larger files,
        closer to the uncompressed frames; docs/render.md gives the cost in dB per crf).
    workers : local worker processes (each opens its own devices); 0: in this process.
    scheduler : a Dask scheduler address (``"tcp://host:8786"``) or a ``distributed.Client``:
        the chunks run on its workers instead (they read ``setup`` and ``film`` and write the
        work folder at the same paths: shared storage).
    chunk_frames, overlap : frames per chunk, and frames solved before each and thrown away.
    iterations, method, backend : the Compensator's (``backend`` is resolved on each worker).
    work : the work folder (default ``OUTPUT.render/`` beside the output).
    keep_work : keep the chunk files after the output is written (default: delete them).
    progress : ``progress(frames_done, frames_total)``, called as chunks finish (and once at
        the start with the frames resumed).

    Returns
    -------
    RenderResult

    Notes
    -----
    Local workers are spawned processes, which import the calling script again: call
    ``render`` from a script under ``if __name__ == "__main__":``.

    Raises
    ------
    InputError
        The film does not open or decode, the output's folder or the work folder is not
        writable, the output's container does not fit ``quality``.
    CalibrationFileError
        The set-up file is missing or not a calibration.
    """
    t0 = time.perf_counter()
    check_choice(quality, tuple(QUALITIES), "quality")
    coding = QUALITIES[quality]
    if crf is not None:
        if not 0 <= check_int(crf, "crf", lo=0) <= 51:
            raise InputError(f"crf must be 0-51 (H.264's scale; lower is closer to the frames); "
                             f"got {crf}")
        if coding.codec != "libx264":
            raise InputError(f"crf applies to the H.264 qualities (high, compatible); quality "
                             f"{quality!r} is lossless: leave crf out")
        coding = replace(coding, options=tuple((k, str(crf) if k == "crf" else v)
                                               for k, v in coding.options))
    check_int(workers, "workers", lo=0)
    check_int(chunk_frames, "chunk_frames", lo=1)
    check_int(overlap, "overlap", lo=0)
    check_int(iterations, "iterations", lo=1)
    output = Path(output)
    check_container(output, coding)
    _check_writable(output.parent)
    calib = _load_setup(setup)
    if coding.pix_fmt == "yuv420p" and any(v % 2 for v in calib.projector_size):
        raise InputError(f"quality {quality!r} (4:2:0) needs an even frame size; the projector is "
                         f"{calib.projector_size[0]}x{calib.projector_size[1]}: use --quality high")
    info = probe(film)
    settings = {"setup": file_digest(setup), "film": file_digest(film), "quality": quality,
                "crf": crf, "chunk_frames": chunk_frames, "overlap": overlap, "iterations": iterations,
                "method": method, "backend": backend, "rtdefocus": __version__}
    folder = WorkFolder(work or output.with_name(output.name + ".render"), settings)
    chunks = plan_chunks(info.n_frames, chunk_frames, overlap)
    done = folder.done(chunks)
    todo = [c for c in chunks if c.index not in done]
    job = Job(str(Path(setup).resolve()), settings["setup"],
              replace(info, path=str(Path(film).resolve())), coding,
              str(folder.path.resolve()),
              {"iterations": iterations, "method": method, "backend": backend})
    wp, hp = calib.projector_size
    log.info("render %s: %d frames at %.3g fps -> %dx%d, %d chunks (%d finished before), %s",
             film, info.n_frames, float(info.fps), wp, hp, len(chunks), len(done),
             coding.description + ("" if crf is None else f" (crf {crf})"))
    frames_done = sum(c.frames for c in chunks if c.index in done)
    if progress is not None:
        progress(frames_done, info.n_frames)
    rendered = []
    for chunk, result in _run(job, todo, workers, scheduler):
        folder.record(chunk, result)
        rendered.append(chunk.index)
        frames_done += chunk.frames
        if progress is not None:
            progress(frames_done, info.n_frames)
    mux(output, job.film, [(c.start, folder.chunk_path(c)) for c in chunks])
    if not keep_work:
        for c in chunks:
            folder.chunk_path(c).unlink(missing_ok=True)
        (folder.path / "manifest.json").unlink(missing_ok=True)
        for p in (folder.path, folder.path.parent):
            try:
                p.rmdir()
            except OSError:
                pass                  # not empty: another render's chunks are there
    return RenderResult(output, info.n_frames, float(info.fps), len(chunks), sorted(rendered),
                        sorted(done), time.perf_counter() - t0, folder.path)


def _load_setup(setup):
    from ..calib.file import Calibration

    calib = Calibration.load(setup)
    if not calib.has_psf:
        raise InputError(f"{str(setup)!r} has no defocus kernels (PSF section): calibrate with the "
                         "psf stage (`rtdefocus calibrate ...`)")
    return calib


def _check_writable(folder: Path) -> None:
    """A real write (a permission bit says little for root or a read-only mount)."""
    folder = folder if str(folder) else Path(".")
    if not folder.is_dir():
        raise InputError(f"the output folder {str(folder)!r} does not exist; create it or "
                         "write the output elsewhere (-o)")
    probe = folder / f".rtdefocus-write-test-{os.getpid()}"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise InputError(f"the output folder {str(folder)!r} is not writable ({exc.strerror}); "
                         "write the output elsewhere (-o) or fix its permissions") from None


def _run(job: Job, todo: list[Chunk], workers: int, scheduler):
    """Yield ``(chunk, result)`` as chunks finish, wherever they run."""
    if not todo:
        return
    if scheduler is not None:
        yield from _run_dask(job, todo, scheduler)
    elif workers == 0:
        for c in todo:
            yield c, render_chunk(job, c)
    else:
        import multiprocessing

        # spawn: a worker must not inherit this process's OpenCL or GL state (fork would).
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx,
                                 initializer=watch_parent, initargs=(os.getpid(),)) as pool:
            futures = {pool.submit(render_chunk, job, c): c for c in todo}
            try:
                for f in as_completed(futures):
                    yield futures[f], f.result()
            except BrokenProcessPool:
                raise RtDefocusError(
                    "a render worker process died (out of memory, killed, or a script that "
                    "calls rd.render without `if __name__ == '__main__':`); the finished chunks "
                    "are kept: run the render again to resume") from None
            except BaseException:
                for f in futures:
                    f.cancel()
                raise


def _run_dask(job: Job, todo: list[Chunk], scheduler):
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise RtDefocusError("rendering on a Dask cluster needs dask.distributed: "
                             "pip install 'rtdefocus[render]'") from None
    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout="20s") if own else scheduler
    except OSError as exc:
        raise InputError(f"cannot reach the Dask scheduler at {scheduler!r} ({exc}); start one "
                         "(`dask scheduler`) or check the address") from None
    try:
        futures = {}
        for c in todo:
            f = client.submit(render_chunk, job, c, pure=False,
                              key=f"rtdefocus-{os.path.basename(job.work)}-{c.index}")
            futures[f.key] = (f, c)
        try:
            for f in dask_completed([f for f, _ in futures.values()]):
                yield futures[f.key][1], f.result()
        except BaseException:
            client.cancel([f for f, _ in futures.values()])
            raise
    finally:
        if own:
            client.close()
