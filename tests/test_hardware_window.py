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


# --------------------------------------------------------------------------- GL APIs
NATIVE_SCRIPT = r"""
import sys
import numpy as np
from rtdefocus.calib.file import Calibration
from rtdefocus.gl import runtime
from rtdefocus.gl.warp import warp_image
from rtdefocus.gl.window import ProjectorWindow

if sys.argv[2] == "no-egl":             # a platform without EGL: the default becomes native
    runtime.egl_library = lambda: None
calib = Calibration.load(sys.argv[1])
img = np.random.default_rng(3).integers(0, 256, (90, 120, 3), dtype=np.uint8)
gl = warp_image(calib, img, backend="gl")
assert runtime.context_api() == "native", runtime.context_api()
ref = warp_image(calib, img, backend="cv2")
d = np.abs(gl.astype(int) - ref.astype(int))
assert d.mean() < 1.0, d.mean()
with ProjectorWindow(fullscreen=False, size=calib.projector_size, vsync=False) as win:
    assert win.api == "native"
    wp, hp = calib.projector_size
    frame = np.random.default_rng(4).integers(0, 256, (hp, wp, 3), dtype=np.uint8)
    t = win.show(frame)
    assert isinstance(t, float)
    assert np.array_equal(win.read(), frame)
    win.show_warped(img, calib)
    assert np.array_equal(win.read(), gl), "the warp in the window = the offscreen warp"
again = warp_image(calib, img, backend="gl")  # the offscreen context still works after the window
assert np.array_equal(again, gl)
print("native ok", runtime.create_context().info["GL_RENDERER"])
"""


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize("mode", ["RTDEFOCUS_GL=native", "no-egl"], ids=["glx", "no-egl-platform"])
def test_window_and_warp_on_glx(display, tmp_path, mode):
    """The native path (GLX under Xvfb; WGL/CGL on Windows/macOS): offscreen warp = cv2
    reference, the window shows frames pixel for pixel and renders the warp, the offscreen
    context survives the window. Run in a fresh process: this one already made EGL current."""
    import os
    import subprocess
    import sys

    from test_stream import virtual_calibration

    setup = virtual_calibration().save(tmp_path / "setup.npz")
    env = dict(os.environ, DISPLAY=display)
    env.pop("RTDEFOCUS_GL", None)
    if mode.startswith("RTDEFOCUS_GL="):
        env["RTDEFOCUS_GL"] = mode.split("=")[1]
    proc = subprocess.run([sys.executable, "-c", NATIVE_SCRIPT, str(setup), mode], env=env,
                          capture_output=True, text=True, timeout=100)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "native ok" in proc.stdout


def test_egl_missing_is_a_clear_error(monkeypatch):
    from rtdefocus.errors import DeviceError
    from rtdefocus.gl import runtime

    monkeypatch.setattr(runtime, "egl_library", lambda: None)
    monkeypatch.delenv("RTDEFOCUS_GL", raising=False)
    assert runtime.default_api() == "native"
    with pytest.raises(DeviceError, match="EGL is not available on this platform.*RTDEFOCUS_GL=native"):
        runtime.create_context(shared=False, api="egl")
    monkeypatch.setenv("RTDEFOCUS_GL", "glx")
    with pytest.raises(DeviceError, match="RTDEFOCUS_GL must be one of egl, native"):
        runtime.default_api()
