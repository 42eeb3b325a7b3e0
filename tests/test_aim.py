"""`rtdefocus aim` on the virtual set-up: the projected area against the simulator's truth,
clipped pixels, the focus meter ranking a sharper set-up above a blurrier one on each wall,
the preview's composition, the loop with a fake camera and projector, and the windows and the
command under Xvfb."""

from __future__ import annotations

import dataclasses
import time

import cv2
import numpy as np
import pytest
from hardware_fakes import FakeDevice, FakeProjector

from rtdefocus import sim
from rtdefocus.hardware import aim
from rtdefocus.hardware.aim_loop import run_aim

P, C = (400, 300), (480, 360)
BLUR = {"sharp": (0.3, 0.6), "preset": (1.5, 6.0), "blurry": (4.0, 10.0)}


def procam(blur="preset", preset="cubicle", **kwargs):
    scene = dataclasses.replace(sim.PRESETS[preset], blur_range_px=BLUR[blur])
    return sim.VirtualProCam(scene, projector_size=P, camera_size=C, seed=0, **kwargs)


def black(size=P):
    return np.zeros((size[1], size[0], 3), np.uint8)


def area_of(pc):
    return aim.find_projected_area(pc.capture(aim.aim_pattern("white", P)), pc.capture(black()))


def test_projected_area_matches_the_truth():
    from rtdefocus.sim import oracle_calibration

    pc = procam()
    area = area_of(pc)
    truth = np.zeros((C[1], C[0]), np.uint8)
    poly = np.asarray(oracle_calibration(pc).lit_polygon_cam, np.float64)
    cv2.fillPoly(truth, [np.round(poly).astype(np.int32).reshape(-1, 1, 2)], 1)
    truth = truth.astype(bool)
    iou = (area.mask & truth).sum() / (area.mask | truth).sum()
    assert iou > 0.97, f"IoU {iou:.3f}"
    assert 4 <= len(area.outline) <= 12
    ratio = area.projector_px_per_camera_px(P)
    assert ratio == pytest.approx(np.sqrt(P[0] * P[1] / truth.sum()), rel=0.03)


def test_a_camera_that_sees_no_projection_finds_no_area():
    pc = procam()
    dark = pc.capture(black())
    assert aim.find_projected_area(dark, dark) is None
    assert aim.find_projected_area(np.full((C[1], C[0], 3), 90, np.uint8)) is None


def test_focus_meter_ranks_sharper_set_ups_on_every_wall():
    """The same cubicle with the projector's blur small, as the preset, and large: on each
    wall the meter reads less blur for the sharper set-up."""
    readings = {}
    for blur in BLUR:
        pc = procam(blur)
        area = area_of(pc)
        view = aim.analyse(pc.capture(aim.aim_pattern("checker", P)), area, pattern="checker",
                           projector_size=P)
        assert [r.name for r in view.regions] == ["left", "right"]
        readings[blur] = [r.blur_projector_px for r in view.readings]
        assert all(r.edges > 1000 for r in view.readings)
    for wall in range(2):
        s, m, b = (readings[k][wall] for k in ("sharp", "preset", "blurry"))
        assert s < m < b, readings
        assert b > 1.4 * s, readings


def test_focus_meter_follows_the_focus_ring():
    """One oblique wall: focusing the projector near its left end makes the left half read
    sharper than the right, and the other way round."""
    halves = {}
    base = sim.PRESETS["flat"]
    for end, x in (("near", 0.1), ("far", 0.9)):
        pc0 = sim.VirtualProCam(base, projector_size=P, camera_size=C, seed=0)
        focus = float(pc0.truth.depth_map[P[1] // 2, int(x * (P[0] - 1))])
        scene = dataclasses.replace(base, focus_distance=focus, blur_range_px=(1.5, 6.0))
        pc = sim.VirtualProCam(scene, projector_size=P, camera_size=C, seed=0)
        view = aim.analyse(pc.capture(aim.aim_pattern("checker", P)), area_of(pc),
                           pattern="checker", projector_size=P)
        halves[end] = [r.blur_projector_px for r in view.readings]
    assert halves["near"][0] < halves["near"][1], halves
    assert halves["far"][1] < halves["far"][0], halves


def test_regions_follow_the_calibrations_walls():
    from rtdefocus.sim import oracle_calibration

    pc = procam()
    calib = oracle_calibration(pc)
    area = area_of(pc)
    regions = aim.wall_regions(area, calib)
    assert [r.name for r in regions] == ["left wall", "right wall"]
    a, b = regions[0].mask, regions[1].mask
    assert not (a & b).any() and (a | b).sum() >= 0.98 * area.mask.sum()
    # Each wall's region lies on its own side of the calibrated fold.
    fold = np.asarray(calib.folds_cam, np.float64).reshape(-1, 3)[0]
    for region in regions:
        ys, xs = np.nonzero(region.mask)
        side = np.sign(fold[0] * xs + fold[1] * ys + fold[2])
        assert abs(side.mean()) > 0.98


def test_clipped_pixels_are_marked_in_the_preview():
    pc = procam()
    area = area_of(pc)
    over = np.clip(pc.capture(aim.aim_pattern("white", P)).astype(np.int32) * 3, 0, 255).astype(np.uint8)
    view = aim.analyse(over, area, pattern="white", projector_size=P)
    share = float(view.clipped[area.mask].mean())
    assert share > 0.5
    out = aim.compose_aim_frame(over, area=view.area, clipped=view.clipped, regions=view.regions,
                                readings=view.readings, pattern="white")
    red = (out[:, :, 0] == 255) & (out[:, :, 1] == 40) & (out[:, :, 2] == 40)
    assert red[view.clipped].mean() > 0.9            # the marks, less where text and bars sit
    assert not red[~view.clipped].any()
    # A well exposed frame has none.
    fine = pc.capture(aim.aim_pattern("white", P))
    assert aim.clipped_mask(fine)[area.mask].mean() < 0.005


def test_preview_outlines_the_area_and_draws_a_meter_per_wall():
    pc = procam()
    area = area_of(pc)
    frame = pc.capture(aim.aim_pattern("checker", P))
    view = aim.analyse(frame, area, pattern="checker", projector_size=P)
    out = aim.compose_aim_frame(frame, area=view.area, clipped=view.clipped, regions=view.regions,
                                readings=view.readings, pattern="checker")
    green = (out[:, :, 0] == 60) & (out[:, :, 1] == 220) & (out[:, :, 2] == 60)
    for x, y in area.outline:
        assert green[max(0, y - 2):y + 3, max(0, x - 2):x + 3].any(), (x, y)
    yellow = (out[:, :, 0] == 255) & (out[:, :, 1] == 210) & (out[:, :, 2] == 0)
    for region in view.regions:
        assert (yellow & region.mask).sum() > 50, region.name
    small = aim.compose_aim_frame(frame, area=view.area, clipped=view.clipped,
                                  regions=view.regions, readings=view.readings, pattern="checker",
                                  size=(320, 180))
    assert small.shape == (180, 320, 3)


class FakePreview:
    """The preview window's interface, recording frames and handing out scripted keys."""

    def __init__(self, keys_at=None, size=(320, 180)):
        self.size, self.frames, self.keys_at = size, [], dict(keys_at or {})

    def show(self, frame):
        self.frames.append(frame)

    def poll(self):
        return self.keys_at.pop(len(self.frames), [])


def test_run_aim_switches_patterns_and_stops_on_q():
    from rtdefocus.hardware.camera import open_camera

    world = procam()
    proj = FakeProjector(P)
    dev = FakeDevice(proj, delay=0.02, fourcc="MJPG", size=(640, 480), noise=0,
                     world=lambda pattern: cv2.resize(world.capture(pattern), (640, 480)))
    preview = FakePreview({2: ["w"], 4: ["g"], 6: ["c"], 8: ["q"]})
    with open_camera(0, capture_factory=dev) as cam:
        view = run_aim(cam, proj, preview, settle=0.05)
    assert len(preview.frames) == 8 and all(f.shape == (180, 320, 3) for f in preview.frames)
    shown = [f for _, f in proj.timeline[1:]]
    kinds = []
    for f in shown:
        for kind in ("white", "grid", "checker"):
            if np.array_equal(f, aim.aim_pattern(kind, P)):
                kinds.append(kind)
                break
        else:
            kinds.append("black" if not f.any() else "?")
    assert kinds == ["white", "black", "checker", "white", "grid", "checker"]
    assert view.area is not None and [r.blur_projector_px is not None for r in view.readings] \
        == [True, True]


def test_run_aim_says_so_when_the_camera_sees_nothing(caplog):
    from rtdefocus.hardware.camera import open_camera

    proj = FakeProjector(P)
    dev = FakeDevice(proj, delay=0.02, fourcc="MJPG", size=(640, 480), noise=0,
                     world=lambda pattern: np.full((480, 640, 3), 30, np.uint8))
    with open_camera(0, capture_factory=dev) as cam:
        view = run_aim(cam, proj, FakePreview({1: ["q"]}), settle=0.05)
    assert view.area is None
    assert any("does not see the projection" in r.getMessage() for r in caplog.records)


# --------------------------------------------------------------------------- Xvfb
import test_window  # noqa: E402  (the Xvfb fixtures: a 320x240 virtual monitor)

xvfb, probe, display = test_window.xvfb, test_window.probe, test_window.display


class ScreenCamera:
    """A camera filming the projector window's framebuffer, slightly blurred."""

    def __init__(self, windows):
        self.windows, self.live, self.negotiated = windows, False, {}

    def read(self):
        canvas = np.full((300, 400, 3), 10, np.uint8)      # the room around the projection
        win = self.windows[0] if self.windows else None
        if win is not None and not win.should_close:
            canvas[30:270, 40:360] = cv2.GaussianBlur(win.read(), (5, 5), 1.0)
        return canvas

    def drain(self, until, min_frames=0):
        return 0


@pytest.mark.timeout(120)
def test_run_aim_with_real_windows(display):
    from rtdefocus.gl.window import ProjectorWindow

    with ProjectorWindow(0, vsync=False) as projector, \
            ProjectorWindow(fullscreen=False, size=(200, 150), vsync=False) as preview:
        preview.inject_key("g")
        view = run_aim(ScreenCamera([projector]), projector, preview, settle=0.0, max_frames=3)
        assert np.array_equal(projector.read(), aim.aim_pattern("grid", projector.size))
        seen = preview.read()
    assert view.area is not None and 0.6 < view.area.fraction < 0.7   # 320x240 of 400x300
    assert seen.shape == (150, 200, 3) and seen.any()


@pytest.mark.timeout(120)
def test_cli_aim(display, monkeypatch, capsys):
    from rtdefocus import cli
    from rtdefocus.gl import window as window_mod
    from rtdefocus.hardware import camera as camera_mod

    windows = []
    real_init = window_mod.ProjectorWindow.__init__

    def init(self, *args, **kwargs):
        real_init(self, *args, **kwargs)
        if kwargs.get("fullscreen", True):
            windows.append(self)

    class Cap:
        def __init__(self):
            self.cam = ScreenCamera(windows)

        def isOpened(self):
            return True

        def read(self):
            return True, cv2.cvtColor(self.cam.read(), cv2.COLOR_RGB2BGR)

        def grab(self):
            time.sleep(1 / 30)          # a frame period: the camera drain waits for live frames
            return True

        def set(self, *a):
            return False

        def get(self, *a):
            return 0.0

        def getBackendName(self):
            return "FAKE"

        def release(self):
            pass

    monkeypatch.setattr(window_mod.ProjectorWindow, "__init__", init)
    monkeypatch.setattr(camera_mod, "default_factory", lambda backend="auto": lambda src: Cap())
    rc = cli.main(["aim", "--camera", "0", "--screen", "0", "--frames", "3",
                   "--preview-size", "200x150"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "projector 320x240 on screen 0" in out and "edge blur left" in out
