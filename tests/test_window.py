"""The projector window (glfw + moderngl through EGL) under Xvfb, key handling through the real
callback and injected events, the player in a window, and HardwareProCam against a camera backed
by a video file."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import skip_or_fail

from rtdefocus.errors import CaptureError, InputError

SCREEN = (320, 240)       # the virtual monitor


def _free_display() -> int:
    for n in range(90, 200):
        if not Path(f"/tmp/.X{n}-lock").exists() and not Path(f"/tmp/.X11-unix/X{n}").exists():
            return n
    raise RuntimeError("no free X display number in 90..199")


@pytest.fixture(scope="module")
def xvfb():
    """A virtual X server (``:N``) for the module; skipped with the reason when it cannot start."""
    exe = shutil.which("Xvfb") or "/usr/bin/Xvfb"
    if not Path(exe).exists():
        skip_or_fail("Xvfb is not installed (Debian/Ubuntu: apt-get install xvfb)")
    n = _free_display()
    proc = subprocess.Popen([exe, f":{n}", "-screen", "0", f"{SCREEN[0]}x{SCREEN[1]}x24",
                             "-nolisten", "tcp"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    sock = Path(f"/tmp/.X11-unix/X{n}")
    deadline = time.time() + 10
    while not sock.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    if not sock.exists():
        err = proc.stderr.read().decode(errors="replace")[-500:] if proc.poll() is not None else ""
        proc.kill()
        skip_or_fail(f"Xvfb :{n} did not start: {err or 'timeout'}")
    yield f":{n}"
    proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()


@pytest.fixture(scope="module")
def probe(gl_ctx):
    """A tiny framebuffer of the offscreen EGL context, kept for the module (moderngl reports
    GL_INVALID_OPERATION when a bound framebuffer is released and another one created)."""
    fbo = gl_ctx.simple_framebuffer((2, 2))

    def check(color):
        fbo.use()
        gl_ctx.clear(*(c / 255 for c in color), 1.0)
        px = np.frombuffer(fbo.read(components=3), np.uint8)[:3]
        assert gl_ctx.error == "GL_NO_ERROR"
        assert tuple(int(v) for v in px) == color, "the offscreen EGL context was disturbed"
    yield check


@pytest.fixture()
def display(xvfb, monkeypatch, probe):
    """DISPLAY set for this test only. The EGL offscreen context exists first (as in the
    player) and must work before and after the window comes and goes."""
    monkeypatch.setenv("DISPLAY", xvfb)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    probe((0, 0, 255))
    yield xvfb
    probe((0, 255, 0))


def _noise(h, w, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


# --------------------------------------------------------------------------- window
def test_window_shows_frame_pixel_exact_and_closes(display, probe):
    from rtdefocus.gl.window import ProjectorWindow

    img = _noise(48, 64)
    with ProjectorWindow(fullscreen=False, size=(64, 48), vsync=False) as win:
        assert win.size == (64, 48)
        win.show(img)
        assert np.array_equal(win.read(), img), "a frame of the window's size is shown pixel for pixel"
        probe((255, 0, 0))   # the offscreen context is current again between window operations
        # a smaller frame is letterboxed: black bars, the picture centred
        small = np.full((12, 32, 3), 200, np.uint8)
        win.show(small)
        shown = win.read()
        assert shown[0, 32].tolist() == [0, 0, 0] and shown[24, 32].tolist() == [200, 200, 200]
        with pytest.raises(InputError, match="uint8"):
            win.show(img.astype(np.float32))
    assert win.should_close
    assert win.poll() == ["close"]


def test_fullscreen_takes_the_monitor_video_mode(display):
    from rtdefocus.gl.window import ProjectorWindow, list_monitors

    mons = list_monitors()
    assert len(mons) == 1 and mons[0][2] == SCREEN
    with ProjectorWindow(0, fullscreen=True, vsync=False) as win:
        assert win.size == SCREEN
        pattern = _noise(SCREEN[1], SCREEN[0], 1)
        win.show(pattern)
        assert np.array_equal(win.read(), pattern)
    with pytest.raises(InputError, match="screen 2 is not connected"):
        ProjectorWindow(2)


def test_keys_through_glfw_callback_and_injection(display):
    import glfw

    from rtdefocus.gl.window import ProjectorWindow

    with ProjectorWindow(fullscreen=False, size=(32, 24), vsync=False) as win:
        # the callback glfw calls on a key press (the X server delivers none under Xvfb)
        for key in (glfw.KEY_SPACE, glfw.KEY_RIGHT, glfw.KEY_PAGE_UP, glfw.KEY_C, glfw.KEY_ESCAPE):
            win._on_key(None, key, 0, glfw.PRESS, 0)
        win._on_key(None, glfw.KEY_G, 0, glfw.RELEASE, 0)     # releases are ignored
        win.inject_key("q")
        assert win.poll() == ["space", "right", "left", "c", "escape", "q"]
        assert win.poll() == []


@pytest.mark.timeout(120)
def test_player_in_window_with_injected_keys(display, tmp_path):
    from test_stream import PROJ, synthetic_frames, virtual_calibration

    import rtdefocus as rd
    from rtdefocus.gl.window import ProjectorWindow
    from rtdefocus.imageio import fit_image, write_image
    from rtdefocus.stream import Player, SlidesSource, WindowSink

    slides = [synthetic_frames(1, size=(40, 30), seed=s)[0] for s in (1, 2)]
    for i, s in enumerate(slides):
        write_image(tmp_path / "deck" / f"{i}.png", s)
    comp = rd.Compensator(virtual_calibration())
    script = ["right", "c", "g", "q"]
    seen = []

    class ScriptedWindowSink(WindowSink):
        """Reads back what the window shows after each frame, then 'presses' the next key."""

        def _after(self, index, path, sent=None):
            seen.append((index, player.controls.mode, path, self.window.read(), sent))
            if script:
                self.window.inject_key(script.pop(0))

        def write(self, frame, index):
            super().write(frame, index)
            self._after(index, "texture", np.array(frame, copy=True))

        def write_warped(self, image, index, calib):
            super().write_warped(image, index, calib)
            self._after(index, "direct")

    with ProjectorWindow(fullscreen=False, size=PROJ, vsync=False) as win:
        player = Player(comp, SlidesSource(tmp_path / "deck"), ScriptedWindowSink(win), iterations=2)
        stats = player.run()
    assert player.controls.quit and stats.frames_out == len(seen) >= 4
    by_state = {(i, m): shown for i, m, _, shown, _ in seen}
    # every frame sent to the window as a texture is what the window shows, pixel for pixel
    for i, m, path, shown, sent in seen:
        if path == "texture":
            assert np.array_equal(shown, sent), f"slide {i} ({m}): the window shows another frame"
    assert np.array_equal(by_state[(1, "off")], fit_image(slides[1], PROJ))
    # 'g': the warp shader rendered straight into the window = the offscreen warp
    assert [p for _, m, p, _, _ in seen if m == "geometry"] == ["direct"]
    assert np.array_equal(by_state[(1, "geometry")], comp.warp(slides[1]))
    assert (0, "full") in by_state and (1, "full") in by_state


# --------------------------------------------------------------------------- hardware
def _camera_file(path: Path, n: int, size=(160, 120), step=10) -> Path:
    """A video whose frame i is uniformly grey at ``step * i``: a camera with a known history."""
    w, h = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (w, h))
    assert writer.isOpened()
    for i in range(n):
        writer.write(np.full((h, w, 3), step * i, np.uint8))
    writer.release()
    return path


def test_hardware_procam_with_file_camera(display, tmp_path):
    import rtdefocus as rd

    cam = _camera_file(tmp_path / "cam.avi", 12)
    with rd.HardwareProCam(camera=str(cam), screen=0, settle=0.01, flush=1, average=2,
                           retries=1) as pc:
        assert isinstance(pc, rd.ProCam)
        assert pc.projector_size == SCREEN          # the monitor's video mode
        assert pc.camera_size == (160, 120)
        pattern = _noise(SCREEN[1], SCREEN[0], 2)
        frame = pc.capture(pattern)
        assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
        # frame 0 was read at start-up, frame 1 flushed, frames 2 and 3 averaged: (20 + 30) / 2
        assert abs(float(frame.mean()) - 25.0) < 1.5
        assert np.array_equal(pc.window.read(), pattern), "the window shows the pattern"
        frame = pc.capture(pattern)                 # flush 4, average 5 and 6
        assert abs(float(frame.mean()) - 55.0) < 1.5
        with pytest.raises(InputError, match="pattern must be"):
            pc.capture(pattern[:10])
        # the file runs out: a camera that stops delivering gives the clear error
        with pytest.raises(CaptureError, match="delivered no frame in 2 attempts"):
            for _ in range(5):
                pc.capture(pattern)


def test_hardware_procam_camera_that_cannot_open(display, tmp_path):
    import rtdefocus as rd

    with pytest.raises(CaptureError, match="cannot open camera"):
        rd.HardwareProCam(camera=str(tmp_path / "no_camera.avi"), screen=0)


def test_hardware_procam_calibration_capture_wrapper(display, tmp_path):
    """The calibration's capture wrapper accepts HardwareProCam frames (shape, dtype)."""
    import rtdefocus as rd
    from rtdefocus.calib.capture import Capturer
    from rtdefocus.gl.window import ProjectorWindow

    cam = _camera_file(tmp_path / "cam.avi", 8, size=(96, 64), step=20)
    with ProjectorWindow(fullscreen=False, size=(64, 48), vsync=False) as win:
        pc = rd.HardwareProCam(camera=str(cam), window=win, settle=0.0, flush=0, average=1)
        assert pc.projector_size == (64, 48)
        cap = Capturer(pc)
        cap.begin("test", 2)
        frames = [cap(np.full((48, 64, 3), v, np.uint8)) for v in (0, 255)]
        assert [f.shape for f in frames] == [(64, 96, 3)] * 2
        assert abs(float(frames[1].mean()) - float(frames[0].mean()) - 20.0) < 2.0
        pc.close()
        assert not win.should_close, "a window passed in stays open"
    assert os.environ["DISPLAY"] == display


def test_hardware_procam_stops_on_q(display, tmp_path):
    import rtdefocus as rd
    from rtdefocus.gl.window import ProjectorWindow

    cam = _camera_file(tmp_path / "cam.avi", 8, size=(32, 24))
    with ProjectorWindow(fullscreen=False, size=(32, 24), vsync=False) as win, \
            rd.HardwareProCam(camera=str(cam), window=win, settle=0.0, flush=0, average=1) as pc:
        pattern = np.zeros((24, 32, 3), np.uint8)
        pc.capture(pattern)
        win.inject_key("q")
        for _ in range(2):              # sticky: a later capture is refused too
            with pytest.raises(CaptureError, match="stopped from the projector window"):
                pc.capture(pattern)


@pytest.mark.timeout(120)
def test_cli_play_slides_in_window(display, tmp_path, monkeypatch, capsys):
    """`rtdefocus play setup.npz DIR --windowed WxH`: the window opens, shows the compensated
    slide, and 'q' ends the show with the summary printed."""
    from test_stream import PROJ, synthetic_frames, virtual_calibration

    from rtdefocus import cli
    from rtdefocus.gl.window import ProjectorWindow
    from rtdefocus.imageio import write_image

    setup = virtual_calibration().save(tmp_path / "setup.npz")
    write_image(tmp_path / "deck" / "1.png", synthetic_frames(1, seed=4)[0])
    shown, sent = [], []
    real_show, real_poll = ProjectorWindow.show, ProjectorWindow.poll

    def show(self, frame):
        real_show(self, frame)
        shown.append(self.read())
        sent.append(np.array(frame, copy=True))

    def poll(self):                      # the viewer presses q once a frame is up
        return real_poll(self) + (["q"] if shown else [])

    monkeypatch.setattr(ProjectorWindow, "show", show)
    monkeypatch.setattr(ProjectorWindow, "poll", poll)
    rc = cli.main(["play", str(setup), str(tmp_path / "deck"), "--windowed", f"{PROJ[0]}x{PROJ[1]}",
                   "--iterations", "2", "--no-cache"])
    assert rc == 0 and len(shown) >= 1
    assert shown[0].shape == (PROJ[1], PROJ[0], 3) and shown[0].max() > 0
    assert all(np.array_equal(a, b) for a, b in zip(shown, sent, strict=True)), \
        "the window shows what play sent it"
    assert "frames out" in capsys.readouterr().out
