"""screen:N and window:TITLE sources on a virtual display (Xvfb): a window showing a known
picture is grabbed pixel for pixel, whole-monitor grabs hold it where the window is, the player
compensates what it grabs, and a missing window or monitor is a one-line error that lists what
is there."""

from __future__ import annotations

import time

import numpy as np
import pytest
import test_window
from test_stream import PROJ, RecordingSink, virtual_calibration

import rtdefocus as rd
from rtdefocus import cli
from rtdefocus.errors import InputError

SCREEN = test_window.SCREEN
xvfb, probe, display = test_window.xvfb, test_window.probe, test_window.display
TITLE = "Quarterly review - Viewer"


@pytest.fixture
def shown(display):
    """A window titled TITLE on the virtual display, showing a known 64x48 picture."""
    from rtdefocus.gl.window import ProjectorWindow

    img = np.random.default_rng(7).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    with ProjectorWindow(fullscreen=False, size=(64, 48), title=TITLE, vsync=False) as win:
        for _ in range(3):                     # mapped and drawn (no window manager under Xvfb)
            win.show(img)
            win.poll()
            time.sleep(0.05)
        yield img


def test_window_source_grabs_the_window_pixel_exact(shown):
    from rtdefocus.stream import open_source
    from rtdefocus.stream.capture import list_windows

    wins = [w for w in list_windows() if w.title == TITLE]
    assert len(wins) == 1 and (wins[0].width, wins[0].height) == (64, 48)
    with open_source("window:quarterly") as src:        # part of the title, any case
        assert src.live and src.kind == "window"
        frames = [src.read() for _ in range(2)]
    assert [f.index for f in frames] == [0, 1]
    for f in frames:
        assert np.array_equal(f.image, shown)


def test_screen_source_grabs_the_whole_monitor(shown):
    from rtdefocus.stream import open_source
    from rtdefocus.stream.capture import list_windows

    win = next(w for w in list_windows() if w.title == TITLE)
    with open_source("screen:0", capture_fps=50) as src:
        assert src.live and src.fps == 50
        img = src.read().image
    assert img.shape == (SCREEN[1], SCREEN[0], 3)
    assert np.array_equal(img[win.top:win.top + 48, win.left:win.left + 64], shown)


def test_player_compensates_what_it_grabs(shown):
    from rtdefocus.stream import Player, open_source

    comp = rd.Compensator(virtual_calibration())
    sink = RecordingSink(realtime=True, keys=["x", "q"])
    with open_source(f"window:{TITLE}") as src:
        Player(comp, src, sink, iterations=2, threads=False).run()
    assert len(sink.frames) == 2 and sink.frames[0].shape == (PROJ[1], PROJ[0], 3)
    expect = rd.Compensator(virtual_calibration()).compensate(shown, iterations=2)
    assert np.abs(sink.frames[0].astype(int) - expect).max() <= 1


def test_missing_window_lists_the_open_ones(shown, tmp_path, capsys):
    from rtdefocus.stream import open_source

    with pytest.raises(InputError, match=r"no window titled 'Keynote' is open\. Open windows: .*Quarterly"):
        open_source("window:Keynote")
    setup = virtual_calibration().save(tmp_path / "setup.npz")
    assert cli.main(["play", str(setup), "window:Keynote", "--out", "null"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and TITLE in err


def test_missing_screen_lists_the_monitors(display):
    from rtdefocus.stream import open_source

    listed = rf"no monitor 2 to capture; connected: screen:0 {SCREEN[0]}x{SCREEN[1]}"
    with pytest.raises(InputError, match=listed):
        open_source("screen:2")
    with pytest.raises(InputError, match="screen:INDEX"):
        open_source("screen:left")


def test_no_display_says_what_capture_needs(monkeypatch):
    from rtdefocus.stream import open_source

    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(InputError, match="X11"):
        open_source("screen:0")
