"""Live sources from the desktop: a whole monitor (``screen:N``) or one window
(``window:TITLE``), so any application (a presentation program, a browser, a media player, a
virtual display) can be shown through rtdefocus.

Pixels are grabbed with ``mss`` (X11, Windows, macOS). A window is found by its title (a
case-insensitive substring) and its rectangle on the desktop is looked up again every second,
so moving the window is followed; the grab is that rectangle of the screen, so the window must
be on top and uncovered. Windows are listed through the X server (``python-xlib``) on Linux and
through ``pywinctl`` on Windows and macOS. Both come with the ``show`` extra
(``pip install rtdefocus[show]``). Wayland sessions do not allow grabbing the screen: log in to
an X11 session ("GNOME on Xorg") for these sources.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .source import Frame, Pacer, Source

log = logging.getLogger(__name__)

#: Seconds between two look-ups of a captured window's rectangle.
REFRESH = 1.0


def _mss():
    try:
        import mss
    except ImportError:
        raise InputError("capturing a screen or a window needs mss: pip install rtdefocus[show]") from None
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        raise InputError("no X display to capture (DISPLAY is not set): screen and window sources "
                         "need an X11 session (on Wayland, log in with 'GNOME on Xorg' or similar), "
                         "Windows or macOS")
    return getattr(mss, "MSS", None) or mss.mss


def list_monitors() -> list[dict]:
    """The monitors as ``{"left", "top", "width", "height"}`` dicts, ``screen:N`` is entry N."""
    factory = _mss()
    with factory() as sct:
        return [dict(m) for m in sct.monitors[1:]]


@dataclass(frozen=True)
class WindowInfo:
    """A window on the desktop: its title and its rectangle in desktop pixels."""

    title: str
    left: int
    top: int
    width: int
    height: int


def _x11_windows() -> list[WindowInfo]:
    try:
        from Xlib import X, display, error
    except ImportError:
        raise InputError("listing windows needs python-xlib: pip install rtdefocus[show]") from None
    try:
        d = display.Display()
    except Exception as exc:
        raise InputError(f"cannot open the X display {os.environ.get('DISPLAY')!r} ({exc})") from None
    try:
        root = d.screen().root
        net_name, utf8 = d.intern_atom("_NET_WM_NAME"), d.intern_atom("UTF8_STRING")
        out: list[WindowInfo] = []

        def title(w) -> str | None:
            prop = w.get_full_property(net_name, utf8)
            if prop is not None and prop.value:
                v = prop.value
                return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)
            name = w.get_wm_name()
            if isinstance(name, bytes):
                name = name.decode("latin-1")
            return name or None

        def walk(w) -> None:
            for child in w.query_tree().children:
                try:
                    if child.get_attributes().map_state != X.IsViewable:
                        continue
                    name = title(child)
                    if name:
                        g = child.get_geometry()
                        pos = root.translate_coords(child, 0, 0)
                        out.append(WindowInfo(name, int(pos.x), int(pos.y), int(g.width), int(g.height)))
                    walk(child)
                except error.XError:    # the window went away while being looked at
                    continue

        walk(root)
        return out
    finally:
        d.close()


def _pywinctl_windows() -> list[WindowInfo]:
    try:
        import pywinctl
    except ImportError:
        raise InputError("listing windows needs pywinctl: pip install rtdefocus[show]") from None
    out = []
    for w in pywinctl.getAllWindows():
        if w.title and w.isVisible:
            out.append(WindowInfo(w.title, int(w.left), int(w.top), int(w.width), int(w.height)))
    return out


def list_windows() -> list[WindowInfo]:
    """The visible windows with a title, topmost last on X11."""
    if sys.platform.startswith("linux"):
        _mss()                          # the same DISPLAY check as the grab
        return _x11_windows()
    return _pywinctl_windows()


def find_window(title: str) -> WindowInfo:
    """The window whose title holds ``title`` (case-insensitive; an exact match wins, then the
    largest).

    Raises
    ------
    InputError
        No such window; the message lists the open windows' titles.
    """
    wins = [w for w in list_windows() if w.width > 1 and w.height > 1]
    key = title.lower()
    exact = [w for w in wins if w.title.lower() == key]
    hits = exact or [w for w in wins if key in w.title.lower()]
    if not hits:
        titles = sorted({w.title for w in wins})
        listed = "; ".join(repr(t) for t in titles[:20]) or "none"
        raise InputError(f"no window titled {title!r} is open. Open windows: {listed}. Give part "
                         "of one of these titles, e.g. window:Impress")
    return max(hits, key=lambda w: w.width * w.height)


class ScreenSource(Source):
    """A monitor (or a rectangle of the desktop) grabbed live, ``fps`` times a second.

    Parameters
    ----------
    screen : monitor index from 0 (``screen:N``; the order of ``rtdefocus info``).
    fps : grabs per second.
    region : (left, top, width, height) in desktop pixels instead of a whole monitor.

    Raises
    ------
    InputError
        No such monitor (the message lists them), or capture is not possible here.
    """

    kind = "screen"
    live = True

    def __init__(self, screen: int = 0, fps: float = 30.0, region: tuple[int, int, int, int] | None = None):
        self._factory = _mss()
        self.fps = float(fps)
        if not self.fps > 0:
            raise InputError(f"capture fps must be positive; got {fps}")
        self.screen = screen
        if region is None:
            monitors = list_monitors()
            if not 0 <= screen < len(monitors):
                listed = ", ".join(f"screen:{i} {m['width']}x{m['height']}+{m['left']}+{m['top']}"
                                   for i, m in enumerate(monitors)) or "none"
                raise InputError(f"no monitor {screen} to capture; connected: {listed}; give one "
                                 "of these (e.g. screen:0)")
            m = monitors[screen]
            region = (m["left"], m["top"], m["width"], m["height"])
        self.region = tuple(int(v) for v in region)
        self._local = threading.local()   # one grabber per thread (X11 connections are per thread)
        self._grabbers: list = []
        self._index = 0
        self._pacer = Pacer(rebase=True)   # fell behind: grab now, do not burst

    def _grabber(self):
        sct = getattr(self._local, "sct", None)
        if sct is None:
            sct = self._local.sct = self._factory()
            self._grabbers.append(sct)
        return sct

    def _current_region(self) -> tuple[int, int, int, int]:
        return self.region

    def grab(self) -> np.ndarray:
        """One grab of the region, RGB uint8 (H, W, 3)."""
        left, top, width, height = self._current_region()
        sct = self._grabber()
        desk = sct.monitors[0]            # the whole desktop: a grab must stay inside it
        x0, y0 = max(left, desk["left"]), max(top, desk["top"])
        x1 = min(left + width, desk["left"] + desk["width"])
        y1 = min(top + height, desk["top"] + desk["height"])
        if x1 <= x0 or y1 <= y0:
            raise InputError(f"the {self.kind} to capture ({width}x{height}+{left}+{top}) is off the "
                             "desktop; move it onto a monitor")
        shot = sct.grab({"left": x0, "top": y0, "width": x1 - x0, "height": y1 - y0})
        bgra = np.frombuffer(shot.bgra, np.uint8).reshape(shot.height, shot.width, 4)
        return np.ascontiguousarray(bgra[..., 2::-1])

    def read(self) -> Frame | None:
        self._pacer.wait(self._index, self.fps)
        frame = Frame(self._index, self.grab(), time.perf_counter())
        self._index += 1
        return frame

    def close(self) -> None:
        for sct in self._grabbers:
            try:
                sct.close()
            except Exception:             # a grabber of a thread that is gone
                pass
        self._grabbers = []

    def describe(self) -> str:
        left, top, w, h = self.region
        return f"screen {self.screen} ({w}x{h}+{left}+{top}, {self.fps:.3g} fps)"


class WindowSource(ScreenSource):
    """One window grabbed live, found by title; its rectangle is followed as it moves."""

    kind = "window"

    def __init__(self, title: str, fps: float = 30.0):
        win = find_window(title)
        super().__init__(fps=fps, region=(win.left, win.top, win.width, win.height))
        self.title = title
        self.window_title = win.title
        self._looked_up = time.perf_counter()
        self._lost = False

    def _current_region(self) -> tuple[int, int, int, int]:
        now = time.perf_counter()
        if now - self._looked_up > REFRESH:
            self._looked_up = now
            try:
                win = find_window(self.window_title)
                self.region = (win.left, win.top, win.width, win.height)
                self._lost = False
            except InputError:
                if not self._lost:
                    log.warning("window %r is gone; showing where it was", self.window_title)
                self._lost = True
        return self.region

    def describe(self) -> str:
        left, top, w, h = self.region
        return f"window {self.window_title!r} ({w}x{h}+{left}+{top}, {self.fps:.3g} fps)"
