"""A show: one or more items (slides, PDFs, videos, live sources) played in turn into one
sink, optionally in a loop, ending on a black projector.

A folder that holds videos is a *playlist*: its files play in name order (natural order: 2
before 10); consecutive images and PDFs form one deck (the arrow keys move through it, "next"
on its last slide moves on), each video plays to its end. In the projector window the show
then stays black until a key is pressed (``exit_at_end`` leaves at once), so the desktop never
appears on the wall; ``loop`` starts again from the first item instead.

>>> show = Show(comp, "talk/", sink, loop=True)
>>> for stats in show.run():
...     print(stats.summary())
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from ..errors import InputError
from .loop import Player
from .sinks import Sink, VideoFileSink
from .sources import STILL_EXTENSIONS, VIDEO_EXTENSIONS, SlidesSource, natural_key, open_source
from .stats import LoopStats

log = logging.getLogger(__name__)


def playlist(spec: str | Path) -> list:
    """The items a SOURCE plays, in order: a list of file lists (a deck of images and PDFs)
    and single specs (a video file, any other SOURCE). A plain source is a list of one.

    Raises
    ------
    InputError
        A folder with nothing to show.
    """
    text = str(spec)
    path = Path(text).expanduser()
    if not path.is_dir():
        return [text]
    files = sorted((p for p in path.iterdir() if p.is_file()), key=lambda p: natural_key(p.name))
    items: list = []
    for f in files:
        ext = f.suffix.lower()
        if ext in STILL_EXTENSIONS:
            if items and isinstance(items[-1], list):
                items[-1].append(f)
            else:
                items.append([f])
        elif ext in VIDEO_EXTENSIONS:
            items.append(str(f))
        else:
            log.debug("playlist %s: skipping %s (not an image, PDF or video)", path, f.name)
    if not items:
        kinds = ", ".join(sorted(STILL_EXTENSIONS | VIDEO_EXTENSIONS))
        raise InputError(f"folder {text!r} holds nothing to show ({kinds}); put the slides, PDFs "
                         "and videos there")
    if len(items) == 1 and isinstance(items[0], list):
        return [text]                        # a plain deck: the folder itself (its name in stats)
    return items


class _OffsetSink:
    """The show's sink with frame indices counted across items (numbered files do not collide)."""

    def __init__(self, sink: Sink):
        self._sink = sink
        self.offset = 0
        self.written = 0

    def write(self, frame: np.ndarray, index: int) -> None:
        self._sink.write(frame, self.offset + index)
        self.written = max(self.written, index + 1)

    def write_warped(self, image: np.ndarray, index: int, calib) -> None:
        self._sink.write_warped(image, self.offset + index, calib)
        self.written = max(self.written, index + 1)

    def next_item(self) -> None:
        self.offset += self.written
        self.written = 0

    def __getattr__(self, name):
        if name == "_sink":
            raise AttributeError(name)
        return getattr(self._sink, name)


class Show:
    """Plays a SOURCE (or a list of items) through a Compensator into one sink.

    Parameters
    ----------
    compensator : rtdefocus.Compensator
    source : str, path, or list
        A SOURCE as the command line takes it (a folder with videos is a playlist), or a list of
        items as :func:`playlist` returns.
    sink : Sink
    loop : bool
        Start again after the last item (the projector window only).
    exit_at_end : bool
        In the window: leave after the last item instead of holding a black frame until a key.
    placement : callable, optional
        :class:`~rtdefocus.stream.placement.Placement` applied to every frame.
    audio : bool
        Play the sound of videos (False: ``--no-audio``).
    source_options : dict
        More :func:`~rtdefocus.stream.sources.open_source` options (camera settings...).
    **player_options
        :class:`~rtdefocus.stream.loop.Player` options (fps, iterations, cache...).
    """

    def __init__(self, compensator, source, sink: Sink, *, loop: bool = False,
                 exit_at_end: bool = False, placement=None, audio: bool = True,
                 source_options: dict | None = None, **player_options):
        self.comp, self.sink = compensator, sink
        self.items = list(source) if isinstance(source, list) else playlist(source)
        if loop and not sink.realtime:
            raise InputError("--loop plays in the projector window only: a file would never end; "
                             "leave out --out, or leave out --loop")
        self.loop, self.exit_at_end = bool(loop), bool(exit_at_end)
        self.placement, self.audio = placement, bool(audio)
        self.source_options = dict(source_options or {})
        self.player_options = player_options
        self.player: Player | None = None
        self.quit = False

    def open_item(self, item):
        """The :class:`Source` of one item."""
        return open_source(item, projector_size=tuple(self.comp.projector_size),
                           realtime=self.sink.realtime, audio=self.audio, placement=self.placement,
                           **self.source_options) if not isinstance(item, list) else \
            self._deck(item)

    def _deck(self, files):
        return SlidesSource(files, size=tuple(self.comp.projector_size), transform=self.placement)

    def run(self) -> list[LoopStats]:
        """Play every item (again and again with ``loop``) until the end or a quit key; returns
        each item's statistics in the order played."""
        out: list[LoopStats] = []
        sink = _OffsetSink(self.sink)
        controls = None
        options = dict(self.player_options)
        progress = options.get("progress")
        if progress is not None and len(self.items) > 1:   # one count across the items
            options["progress"] = lambda done, total: progress(sink.offset + done, None)
        while True:
            for item in self.items:
                with self.open_item(item) as src:
                    if (isinstance(self.sink, VideoFileSink) and not self.sink.count and src.fps
                            and options.get("fps") is None):
                        self.sink.fps = float(src.fps)     # the file plays at its source's rate
                    player = self.player = Player(self.comp, src, sink, **options)
                    if controls is not None:           # the viewer's mode and overlay carry on
                        player.controls.mode, player.controls.overlay = controls.mode, controls.overlay
                    player.leave_at_end = len(self.items) > 1 or self.loop
                    attach = getattr(self.sink, "attach", None)   # an operator's preview
                    if attach is not None:
                        attach(player)
                    out.append(player.run())
                    controls = player.controls
                    self.comp = player.comp     # a watcher's mended calibration carries on
                sink.next_item()
                if controls.quit:
                    self.quit = True
                    return out
            if not self.loop:
                break
        if self.sink.realtime and not self.exit_at_end:
            self._hold_black()
        return out

    def _hold_black(self) -> None:
        """A black projector until any key (or the window is closed)."""
        w, h = self.comp.projector_size
        self.sink.write(np.zeros((h, w, 3), np.uint8), 0)
        log.info("the show has ended: black until a key is pressed")
        window = getattr(self.sink, "window", None)
        while not self.sink.poll():
            if window is not None and hasattr(window, "wait"):
                window.wait(0.05)
            else:
                time.sleep(0.05)
