"""The operator's view (``play --preview``): a small window on the laptop with what the
projector shows and the live figures, while the projector's own window stays clean.

:func:`compose_preview` makes the picture (pure, tested); :class:`PreviewSink` wraps the
projector's :class:`~rtdefocus.stream.sinks.WindowSink`: every frame goes to the projector
untouched, and at most ``rate`` times a second a copy, scaled down, goes to the preview with
the figures under it. Keys pressed in the preview drive the show as the projector's do;
closing the preview only closes the preview.
"""

from __future__ import annotations

import logging
import time

import cv2
import numpy as np

from .sinks import Sink

log = logging.getLogger(__name__)

#: Height of one line of figures in the preview, in pixels.
LINE_PX = 18


def preview_lines(stats, mode: str = "full", paused: bool = False) -> list[str]:
    """The figures under the picture: frame rate, iterations per frame, frames shown and how
    many of them with geometry only, dropped and late frames, the mode."""
    its = stats.iterations
    last = f"{int(its.last)}" if its.count else "-"
    mean = f"{its.mean:.1f}" if its.count else "-"
    share = (f" ({stats.geometry_frames / stats.frames_out:.0%})" if stats.frames_out else "")
    return [f"{stats.fps_now:.1f} fps   iterations {last} (mean {mean})",
            f"shown {stats.frames_out}   geometry only {stats.geometry_frames}{share}   "
            f"dropped {stats.dropped}   late {stats.late}",
            f"mode {mode}{'   PAUSED' if paused else ''}   keys: space c g s arrows q"]


def compose_preview(frame: np.ndarray, lines: list[str], size: tuple[int, int]) -> np.ndarray:
    """``frame`` (what the projector shows) scaled into the top of a ``size = (w, h)`` picture,
    aspect kept, with ``lines`` of text in a black band below it. (h, w, 3) uint8 RGB."""
    w, h = (int(v) for v in size)
    band = LINE_PX * len(lines) + 6
    if h - band < 16 or w < 32:
        raise ValueError(f"preview size {w}x{h} is too small for {len(lines)} lines of figures")
    out = np.zeros((h, w, 3), np.uint8)
    fh, fw = frame.shape[:2]
    scale = min(w / fw, (h - band) / fh)
    tw, th = max(1, round(fw * scale)), max(1, round(fh * scale))
    thumb = cv2.resize(np.ascontiguousarray(frame), (tw, th), interpolation=cv2.INTER_AREA)
    x0 = (w - tw) // 2
    out[0:th, x0:x0 + tw] = thumb
    for i, text in enumerate(lines):
        org = (6, th + 4 + LINE_PX * (i + 1) - 5)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


class PreviewSink(Sink):
    """The projector's sink plus the operator's preview window.

    Parameters
    ----------
    inner : Sink
        The projector's window sink; everything is delegated to it.
    window : ProjectorWindow-like
        The preview (``size``, ``show(frame)``, ``poll()``, ``close()``).
    rate : float
        Most preview updates per second (each one costs a downscale and an upload).
    """

    def __init__(self, inner: Sink, window, *, rate: float = 5.0):
        self.inner, self.preview = inner, window
        self.rate = float(rate)
        self.kind, self.realtime, self.interactive = inner.kind, inner.realtime, inner.interactive
        self.window = getattr(inner, "window", None)
        self.player = None
        self._last: np.ndarray | None = None
        self._shown_at = -1e9
        self.updates = 0

    def attach(self, player) -> None:
        """Read the figures from ``player`` (its ``stats`` and ``controls``)."""
        self.player = player

    def _lines(self) -> list[str]:
        p = self.player
        if p is None:
            return ["(no player attached)"]
        return preview_lines(p.stats, p.controls.mode, p.controls.paused)

    def _update(self, force: bool = False) -> None:
        if self.preview is None:
            return
        now = time.perf_counter()
        if not force and now - self._shown_at < 1.0 / self.rate:
            return
        frame = self._last
        if frame is None:
            if self.window is None or not hasattr(self.window, "read"):
                return
            frame = self.window.read()     # geometry drawn by the shader: read what is shown
        self.preview.show(compose_preview(frame, self._lines(), tuple(self.preview.size)))
        self._shown_at = now
        self.updates += 1

    def write(self, frame: np.ndarray, index: int) -> None:
        self.inner.write(frame, index)
        self._last = frame
        self._update()

    def can_warp(self, calib) -> bool:
        return bool(getattr(self.inner, "can_warp", lambda c: False)(calib))

    def write_warped(self, image: np.ndarray, index: int, calib) -> None:
        self.inner.write_warped(image, index, calib)
        self._last = None
        self._update()

    def poll(self) -> list[str]:
        keys = list(self.inner.poll())
        if self.preview is not None:
            mine = self.preview.poll()
            if "close" in mine:       # the operator closed the preview: the show goes on
                self.preview.close()
                self.preview = None
            keys += [k for k in mine if k != "close"]
        return keys

    def close(self) -> None:
        if self.preview is not None:
            self.preview.close()
            self.preview = None
        self.inner.close()

    def describe(self) -> str:
        return f"{self.inner.describe()} with a preview"
