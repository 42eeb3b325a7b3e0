"""Run statistics of the frame loop: counts, per-stage times, iterations — in constant memory.

A show can run for hours, so nothing here grows with the number of frames: each series keeps
its count, sum and maximum over the whole run plus a fixed ring of the most recent
:data:`WINDOW` samples, from which the p95 is taken.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

#: Samples kept per series for the percentile (the mean covers the whole run).
WINDOW = 2048


class Series:
    """Running statistics of one quantity (seconds of a stage, iterations of a frame)."""

    __slots__ = ("count", "total", "maximum", "_ring", "_pos")

    def __init__(self) -> None:
        self.count = 0
        self.total = 0.0
        self.maximum = 0.0
        self._ring = np.zeros(WINDOW, np.float64)  # allocated once: no growth
        self._pos = 0

    def add(self, value: float) -> None:
        value = float(value)
        self.count += 1
        self.total += value
        self.maximum = max(self.maximum, value)
        self._ring[self._pos] = value
        self._pos = (self._pos + 1) % WINDOW

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else 0.0

    def recent(self) -> np.ndarray:
        """The last ``min(count, WINDOW)`` samples (oldest first)."""
        n = min(self.count, WINDOW)
        if self.count <= WINDOW:
            return self._ring[:n].copy()
        return np.roll(self._ring, -self._pos)

    def percentile(self, q: float) -> float:
        """``q``-th percentile of the most recent :data:`WINDOW` samples (0 when empty)."""
        return float(np.percentile(self.recent(), q)) if self.count else 0.0

    @property
    def last(self) -> float:
        return float(self._ring[(self._pos - 1) % WINDOW]) if self.count else 0.0

    def as_dict(self, scale: float = 1.0) -> dict:
        return {"count": self.count, "mean": self.mean * scale,
                "p95": self.percentile(95) * scale, "max": self.maximum * scale}


class LoopStats:
    """What a run of the frame loop did.

    Attributes
    ----------
    frames_in : int
        Frames taken from the source (decoded).
    frames_out : int
        Frames written to the sink (presented, encoded, saved).
    dropped : int
        Frames decoded but never shown because a newer one arrived first (live sources only).
    dropped_copies : int
        Of ``dropped``, those that repeated the picture of the frame before them, which reached
        the screen (a still, a paused camera): nothing the audience would have seen is lost.
    geometry_frames : int
        Frames shown with geometry only to keep up (realtime playback, ``Player(catch_up=True)``).
    late : int
        Frames shown more than ``deadline`` seconds after they were read: later than a live
        player's promise (a compensated frame ends before the frame after next arrives).
    deadline : float or None
        A live player's two frame periods (None: no promise, nothing counted late).
    pattern_frames : int
        Frames of a watcher's pattern bursts, shown instead of the content.
    stages : dict[str, Series]
        Seconds per frame of each stage: ``read`` (source read + decode, decoder thread),
        ``compensate`` (the whole Compensator call), its own stages (``warp``, ``decode``,
        ``solve``, ``encode`` as it reports them in ``last_info["seconds"]``),
        ``present`` (sink write on the main thread; with a writer thread only the hand-off,
        which waits while the writer's queue is full), ``write`` (the writer thread's
        ``sink.write``: encode + file write), ``flush`` (once: the frames still queued at the
        end), ``frame`` (main-thread time per output frame) and ``latency`` (decode to
        presented, or to handed to the writer).
    iterations : Series
        Solver iterations per compensated frame.
    residual : float or None
        The solver's last reported distance.
    clipped, clipped_dark : Series
        ``surface="flatten"`` only (empty otherwise): per Compensator call, the share of the
        lit pixels showing content that the projector cannot bring to the flattened target —
        too bright for the wall there, or darker than the room light on it allows (the
        Compensator's ``last_info["clipped"]`` / ``["clipped_dark"]``).
    brightness : float or None
        ``surface="flatten"``: the global brightness b in use.
    """

    def __init__(self, source: str = "", sink: str = "") -> None:
        self.source, self.sink = source, sink
        self.frames_in = 0
        self.frames_out = 0
        self.dropped = 0
        self.dropped_copies = 0
        self.geometry_frames = 0
        self.late = 0
        self.deadline: float | None = None
        self.pattern_frames = 0
        self.stages: dict[str, Series] = {}
        self.iterations = Series()
        self.residual: float | None = None
        self.budget: int | None = None
        self.clipped = Series()
        self.clipped_dark = Series()
        self.brightness: float | None = None
        self.t_start = time.perf_counter()
        self.t_end: float | None = None
        self._fps_t = self.t_start
        self._fps_n = 0
        self.fps_now = 0.0

    def add(self, stage: str, seconds: float) -> None:
        series = self.stages.get(stage)
        if series is None:
            series = self.stages[stage] = Series()
        series.add(seconds)

    def add_latency(self, seconds: float) -> None:
        """A frame shown ``seconds`` after it was read: the ``latency`` stage, and :attr:`late`
        when that is past :attr:`deadline`."""
        self.add("latency", seconds)
        if self.deadline is not None and seconds > self.deadline:
            self.late += 1

    def add_surface(self, info: dict) -> None:
        """Count a compensated frame's clipped shares (a no-op unless ``surface="flatten"``)."""
        if info.get("clipped") is None:
            return
        self.clipped.add(info["clipped"])
        self.clipped_dark.add(info.get("clipped_dark") or 0.0)
        self.brightness = info.get("brightness")

    def frame_out(self) -> None:
        """Count one frame written; refresh the displayed frame rate about twice a second."""
        self.frames_out += 1
        self._fps_n += 1
        now = time.perf_counter()
        if now - self._fps_t >= 0.5:
            self.fps_now = self._fps_n / (now - self._fps_t)
            self._fps_t, self._fps_n = now, 0

    def restart(self) -> None:
        """Start the clock again (after work before the first frame, such as a warm-up)."""
        self.t_start = self._fps_t = time.perf_counter()
        self._fps_n = 0

    def finish(self) -> None:
        self.t_end = time.perf_counter()

    @property
    def seconds(self) -> float:
        return (self.t_end or time.perf_counter()) - self.t_start

    @property
    def fps(self) -> float:
        """Frames out per second of wall time, end to end."""
        return self.frames_out / self.seconds if self.seconds > 0 else 0.0

    def overlay_lines(self, mode: str, paused: bool) -> list[str]:
        """Short lines for the on-screen stats overlay."""
        ms = "  ".join(f"{k} {s.last * 1e3:.1f}" for k, s in self.stages.items()
                       if k not in ("latency", "frame", "read"))
        it = f"iterations {int(self.iterations.last)}" if self.iterations.count else "iterations -"
        res = f"residual {self.residual:.4g}" if self.residual is not None else "residual -"
        lines = [f"{self.fps_now:5.1f} fps  in {self.frames_in}  out {self.frames_out}  "
                 f"dropped {self.dropped}  late {self.late}  geometry only {self.geometry_frames}",
                 f"ms: {ms}",
                 f"{it}  {res}  mode {mode}{'  PAUSED' if paused else ''}"]
        if self.pattern_frames:
            lines.append(f"watch: {self.pattern_frames} pattern frames (bursts)")
        if self.clipped.count:
            lines.append(f"clipped {100 * self.clipped.last:.1f} % bright  "
                         f"{100 * self.clipped_dark.last:.1f} % dark")
        return lines

    def as_dict(self) -> dict:
        """JSON-ready summary: counts, fps, per-stage mean/p95/max in milliseconds, iterations."""
        return {
            "source": self.source, "sink": self.sink,
            "frames_in": self.frames_in, "frames_out": self.frames_out, "dropped": self.dropped,
            "dropped_copies": self.dropped_copies, "geometry_frames": self.geometry_frames,
            "late": self.late,
            "pattern_frames": self.pattern_frames,
            "seconds": round(self.seconds, 4), "fps": round(self.fps, 3),
            "stages_ms": {k: {m: round(v, 3) if isinstance(v, float) else v
                              for m, v in s.as_dict(1e3).items()} for k, s in self.stages.items()},
            "iterations_per_frame": self.iterations.as_dict(),
            "last_budget": self.budget,
            "residual": self.residual,
            **({"flatten": {"brightness": self.brightness,
                            "clipped": self.clipped.as_dict(),
                            "clipped_dark": self.clipped_dark.as_dict()}}
               if self.clipped.count else {}),
        }

    def summary(self) -> str:
        """A printable multi-line summary (the CLI prints it at the end of every run)."""
        copies = f" ({self.dropped_copies} copies of the picture shown)" if self.dropped_copies else ""
        lines = [f"{self.frames_out} frames out, {self.frames_in} in, {self.dropped} dropped{copies} in "
                 f"{self.seconds:.2f} s: {self.fps:.2f} fps end to end"]
        if self.geometry_frames:
            lines.append(f"  {self.geometry_frames} frames shown with geometry only to keep up "
                         "(compensating them would have dropped the next)")
        if self.late:
            lines.append(f"  {self.late} frames shown more than {1e3 * self.deadline:.0f} ms (two "
                         "periods) after they arrived: late, not dropped")
        if self.pattern_frames:
            lines.append(f"  {self.pattern_frames} pattern frames shown by the watcher's bursts")
        if self.stages:
            width = max(len(k) for k in self.stages)
            lines.append(f"  {'stage':<{width}}  {'mean ms':>9}  {'p95 ms':>9}  {'frames':>7}")
            for k, s in self.stages.items():
                lines.append(f"  {k:<{width}}  {s.mean * 1e3:9.2f}  {s.percentile(95) * 1e3:9.2f}  "
                             f"{s.count:7d}")
        if self.iterations.count:
            it = self.iterations
            lines.append(f"  iterations per frame: mean {it.mean:.1f}, p95 {it.percentile(95):.0f}, "
                         f"max {it.maximum:.0f}")
        if self.clipped.count:
            c, d = self.clipped, self.clipped_dark
            lines.append(f"  flatten at brightness {self.brightness:.3g}: clipped share of the lit pixels "
                         f"showing content, over {c.count} solves")
            lines.append(f"    too bright for the wall: mean {100 * c.mean:.1f} %, max "
                         f"{100 * c.maximum:.1f} %; darker than the room light allows: mean "
                         f"{100 * d.mean:.1f} %, max {100 * d.maximum:.1f} %")
        return "\n".join(lines)

    def write_json(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.as_dict(), indent=2) + "\n")
        return path
