"""The projector window's size and monitors under Xvfb: the framebuffer polled until it
settles, `play` refusing a window that is not the calibration's size, `rtdefocus info`
listing monitors and modes (and saying so when there is no display)."""

from __future__ import annotations

import pytest
import test_window

# The Xvfb fixtures of test_window (a virtual 320x240 monitor, DISPLAY set per test).
SCREEN = test_window.SCREEN
xvfb, probe, display = test_window.xvfb, test_window.probe, test_window.display


def test_final_size_follows_a_late_resize(display):
    import glfw

    from rtdefocus.gl.window import ProjectorWindow

    with ProjectorWindow(fullscreen=False, size=(64, 48), vsync=False) as win:
        assert win.final_size(timeout=1.0, stable=0.1) == (64, 48)
        glfw.set_window_size(win._win, 80, 60)      # what a compositor does after mapping
        assert win.final_size(timeout=2.0, stable=0.2) == (80, 60)
        assert win.size == (80, 60)


def test_monitor_info_lists_modes(display):
    from rtdefocus.gl.window import monitor_info

    mons = monitor_info()
    assert len(mons) == 1
    m = mons[0]
    assert m["size"] == SCREEN and m["index"] == 0 and (SCREEN[0], SCREEN[1]) in \
        [(w, h) for w, h, _ in m["modes"]]


def test_cli_info_lists_monitors(display, capsys):
    from rtdefocus import cli

    assert cli.main(["info"]) == 0
    out = capsys.readouterr().out
    assert "Monitors (--screen N):" in out and "0: " in out and f"{SCREEN[0]}x{SCREEN[1]}" in out
    assert "modes:" in out


def test_cli_info_without_display(monkeypatch, capsys):
    from rtdefocus import cli

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert cli.main(["info"]) == 0
    assert "Monitors: none found" in capsys.readouterr().out


@pytest.mark.timeout(120)
def test_cli_play_refuses_a_screen_of_another_size(display, tmp_path, capsys):
    """The virtual monitor is 320x240, the calibration is for 64x48: full-screen play stops
    with both sizes and the fix instead of rescaling every frame."""
    from test_stream import PROJ, synthetic_frames, virtual_calibration

    from rtdefocus import cli
    from rtdefocus.imageio import write_image

    setup = virtual_calibration().save(tmp_path / "setup.npz")
    write_image(tmp_path / "slide.png", synthetic_frames(1, seed=4)[0])
    rc = cli.main(["play", str(setup), str(tmp_path / "slide.png"), "--screen", "0", "--no-cache"])
    err = capsys.readouterr().err
    assert rc == 1
    assert f"is {SCREEN[0]}x{SCREEN[1]} but the calibration is for a {PROJ[0]}x{PROJ[1]}" in err
    assert "--screen" in err and "calibrate again" in err
