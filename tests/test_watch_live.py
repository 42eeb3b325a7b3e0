"""The watcher on a live show: a camera that sees the wall a few frames after the look starts
is compared with the frame that was on the wall then, and ``play --watch`` on hardware builds
its camera from the show's own window."""

from __future__ import annotations

import threading
import time

import numpy as np
from test_watcher import FPS, content, setup

from rtdefocus.watch import Watcher, camera_view
from rtdefocus.watch.watcher import LiveView

DELAY = 3          # frames between a look's start and the picture the camera sees


class DelayedCamera:
    """A hardware-like procam whose ``look()`` returns the wall as it is ``DELAY`` frames after
    the call (the camera's latency and settle), and says when that was (``looked_at``)."""

    def __init__(self, pc, clock, offered):
        self.pc, self.clock, self.offered = pc, clock, offered
        self.captured = threading.Event()
        self.looked_at = None

    def look(self):
        i = int(round(self.clock[0] * FPS)) + DELAY
        deadline = time.monotonic() + 30.0
        while self.offered[0] < i and time.monotonic() < deadline:   # until the show put it up
            time.sleep(0.001)
        self.looked_at = i / FPS
        frame = self.pc.capture(content(i))
        self.captured.set()
        return frame


def watch_pan(pc, calib, paired: bool):
    """Two seconds of a pan (2 px a frame) on an unchanged set-up, watched on a thread."""
    clock, offered = [0.0], [-1]
    cam = DelayedCamera(pc, clock, offered)
    look = camera_view(cam) if paired else (lambda shown: cam.look())
    w = Watcher(calib, look, clock=lambda: clock[0], threaded=True)
    wanted = None
    for i in range(int(2.0 * FPS)):
        clock[0] = i / FPS
        if w.offer(content(i)):
            wanted = i + DELAY
        offered[0] = i
        if i == wanted:
            assert cam.captured.wait(30.0)
            cam.captured.clear()
            w.close()                       # the report done before the next frame
    w.close()
    return w


def test_a_delayed_look_is_compared_with_the_frame_on_the_wall_then():
    pc, calib = setup()
    w = watch_pan(pc, calib, paired=True)
    assert isinstance(w.look, LiveView)
    assert w.looks >= 4
    assert [e for e in w.events if e.action == "detect"] == []
    shifts = np.abs(w.last_report.shifts_proj)
    assert np.nanmax(shifts) < 0.3
    # the same show compared with the frame offered when the look started: a false move
    w = watch_pan(pc, calib, paired=False)
    detects = [e for e in w.events if e.action == "detect"]
    assert detects and detects[0].kind == "geometry"
