"""The hardware path against a projector and a camera that misbehave like real ones
(tests/hardware_fakes.py): format negotiation, draining by time, latency, the content check,
camera controls per backend, stream restarts."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest
from hardware_fakes import FakeDevice, FakeProjector

from rtdefocus.errors import CaptureError, InputError
from rtdefocus.hardware import CameraSettings, open_camera

PROJ = (160, 120)


def _lit(frame, rect=(0.15, 0.1, 0.7, 0.8)):
    """Mean grey level inside the projected area of a fake camera frame (inner part)."""
    h, w = frame.shape[:2]
    x, y, rw, rh = rect
    return float(frame[int((y + 0.2 * rh) * h):int((y + 0.8 * rh) * h),
                       int((x + 0.2 * rw) * w):int((x + 0.8 * rw) * w)].mean())


def _halves(left: bool) -> np.ndarray:
    img = np.zeros((PROJ[1], PROJ[0], 3), np.uint8)
    img[:, : PROJ[0] // 2] = 255 if left else 0
    img[:, PROJ[0] // 2:] = 0 if left else 255
    return img


# --------------------------------------------------------------------------- camera helper
def test_fourcc_is_set_before_size_and_the_mode_is_logged(caplog):
    dev = FakeDevice(FakeProjector(PROJ), delay=0.0)
    with caplog.at_level(logging.INFO, logger="rtdefocus.hardware.camera"):
        cam = open_camera(0, CameraSettings(size=(1280, 720), fourcc="MJPG", fps=30),
                          capture_factory=dev)
    log = [(p, v) for p, v in dev.cap.set_log]
    props = [p for p, _ in log]
    assert props.index(cv2.CAP_PROP_FOURCC) < props.index(cv2.CAP_PROP_FRAME_WIDTH) \
        < props.index(cv2.CAP_PROP_FPS), "FOURCC, then size, then rate"
    assert cam.size == (1280, 720)
    assert cam.negotiated["fourcc"] == "MJPG" and cam.negotiated["fps"] == 30.0
    assert cam.negotiated["backend"] == "V4L2" and cam.negotiated["buffersize"] == 4
    assert "1280x720 MJPG at 30 fps" in caplog.text
    assert "drained by time" in caplog.text, "an ignored CAP_PROP_BUFFERSIZE is reported"
    cam.release()


def test_without_fourcc_720p_is_slow_and_the_log_says_how_to_fix_it(caplog):
    dev = FakeDevice(FakeProjector(PROJ), delay=0.0)
    with caplog.at_level(logging.WARNING):
        cam = open_camera(0, CameraSettings(size=(1280, 720), fps=30), capture_factory=dev)
    assert cam.negotiated["fourcc"] == "YUYV" and cam.fps == 10.0
    assert "runs at 10 fps, not the 30" in caplog.text and "--fourcc MJPG" in caplog.text
    cam.release()
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        cam = open_camera(0, size=(1000, 1000), fourcc="MJPG", capture_factory=dev)
    assert cam.size != (1000, 1000) and "not the 1000x1000 asked for" in caplog.text
    cam.release()
    with pytest.raises(InputError, match="four characters"):
        CameraSettings(fourcc="MJPEG")


def test_failed_reads_reopen_the_stream():
    dev = FakeDevice(FakeProjector(PROJ), delay=0.0)
    cam = open_camera(0, retries=3, capture_factory=dev)
    restarted = []
    cam.on_restart = restarted.append
    dev.cap.fail_reads = 10                   # this stream is dead; a re-opened one works
    frame = cam.read()
    assert frame.shape == (240, 320, 3) and cam.restarts == 1 and restarted == [cam]
    assert len(dev.opened) == 2
    dev.cap.fail_reads = 10
    dev.kwargs["fail_reads"] = 10             # the device is gone: the clear error
    with pytest.raises(CaptureError, match="delivered no frame in 4 attempts"):
        cam.read()


def test_drain_by_time_skips_the_stale_queue_a_frame_count_keeps():
    proj = FakeProjector(PROJ)
    dev = FakeDevice(proj, delay=0.0, queue=4)
    cam = open_camera(0, capture_factory=dev)
    white = np.full((PROJ[1], PROJ[0], 3), 255, np.uint8)
    import time
    time.sleep(0.3)                           # the queue fills with black frames
    proj.show(white)
    cam.grab()                                # the old way: flush a frame count
    assert _lit(cam.read()) < 40, "a frame-count flush leaves stale frames"
    time.sleep(0.3)
    proj.show(np.zeros_like(white))
    t = proj.show(white)
    n = cam.drain(t + 0.05, min_frames=1)
    assert n >= 4 and _lit(cam.read()) > 150, "draining by time empties the queue"
    cam.release()


# --------------------------------------------------------------------------- HardwareProCam
def _procam(**kwargs):
    import rtdefocus as rd

    proj = kwargs.pop("projector", None) or FakeProjector(PROJ)
    dev = FakeDevice(proj, **kwargs.pop("camera", {}))
    return rd.HardwareProCam(0, window=proj, capture_factory=dev, **kwargs), proj, dev


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_stale_camera_latency_measured_and_patterns_captured_in_order(caplog):
    """A camera that shows the previous pattern for 0.5 s after each change and keeps a queue
    of 4 frames: the latency is measured, the settle time follows, every capture shows its
    own pattern."""
    with caplog.at_level(logging.INFO):
        pc, proj, dev = _procam(camera={"delay": 0.5, "queue": 4}, average=2)
    with pc:
        # 0.5 s delay, plus up to the 4 queued frames and a slow reader on a loaded machine
        assert 0.45 <= pc.latency.seconds <= 0.9, pc.latency.seconds
        assert pc.settle >= pc.latency.seconds + 2 / 30
        assert "latency" in caplog.text
        white = np.full((PROJ[1], PROJ[0], 3), 255, np.uint8)
        seq = [white, _halves(True), _halves(False), np.zeros_like(white), white]
        frames = [pc.capture(p) for p in seq]
        lit = [_lit(f) for f in frames]
        assert lit[0] > 150 and lit[3] < 40 and lit[4] > 150, lit
        h, w = frames[1].shape[:2]
        left = frames[1][h // 2, int(0.3 * w)].mean(), frames[1][h // 2, int(0.7 * w)].mean()
        right = frames[2][h // 2, int(0.3 * w)].mean(), frames[2][h // 2, int(0.7 * w)].mean()
        assert left[0] > left[1] + 100 and right[1] > right[0] + 100, (left, right)
        assert pc.recaptured == 0 and pc.report()["latency_s"] == pc.latency.seconds


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_content_check_recaptures_when_the_delay_grows(caplog):
    """The camera's delay jumps from 0.1 s to 0.45 s mid-run (a network hiccup): the frame
    still shows the previous pattern, the check sees it, the capture is taken again with a
    longer settle time."""
    pc, proj, dev = _procam(camera={"delay": 0.1}, settle=0.0, average=2)
    with pc:
        pc.capture(_halves(True))
        settle = pc.settle
        dev.cap.delay = 0.45
        with caplog.at_level(logging.WARNING):
            frame = pc.capture(_halves(False))
        h, w = frame.shape[:2]
        assert frame[h // 2, int(0.7 * w)].mean() > frame[h // 2, int(0.3 * w)].mean() + 100
        assert pc.recaptured >= 1 and pc.settle > settle
        assert "does not show the pattern" in caplog.text


@pytest.mark.slow
def test_content_check_gives_up_with_the_fix():
    pc, proj, dev = _procam(camera={"delay": 0.05}, average=1, recaptures=1)
    with pc:
        pc.capture(_halves(True))
        import time
        dev.cap.frozen_at = time.perf_counter()   # the stream repeats an old picture
        with pytest.raises(CaptureError, match="after 2 attempts.*--settle"):
            pc.capture(_halves(False))


def test_settle_shorter_than_the_latency_is_raised(caplog):
    with caplog.at_level(logging.WARNING):
        pc, _, _ = _procam(camera={"delay": 0.2}, settle=0.05, verify=False)
    with pc:
        assert pc.settle >= 0.2 and "shorter than the measured" in caplog.text


@pytest.mark.slow
def test_camera_that_does_not_see_the_projector():
    proj = FakeProjector(PROJ)
    with pytest.raises(CaptureError, match="does not see the projector"):
        _procam(projector=proj, camera={"delay": 0.0, "rect": (0, 0, 0, 0)})


def test_warns_when_a_camera_pixel_covers_many_projector_pixels(caplog):
    proj = FakeProjector((640, 480))
    with caplog.at_level(logging.WARNING):
        pc, _, _ = _procam(projector=proj, verify=False,
                           camera={"delay": 0.0, "size": (320, 240), "rect": (0.3, 0.3, 0.4, 0.4)})
    with pc:
        assert pc.pixel_ratio > 1.5
    assert "covers" in caplog.text and "--camera-size" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        pc, _, _ = _procam(verify=False, camera={"delay": 0.0})
    with pc:
        assert pc.pixel_ratio < 1.5 and "covers" not in caplog.text


# --------------------------------------------------------------------------- controls
# V4L2 in the fast tier; DirectShow's units (log2 seconds) in the whole suite.
@pytest.mark.parametrize("backend, manual",
                         [("V4L2", 1.0), pytest.param("DSHOW", 0.25, marks=pytest.mark.slow)],
                         ids=["v4l2", "dshow"])
def test_lock_uses_the_backends_values_and_reports_what_did_not_take(backend, manual):
    pc, proj, dev = _procam(camera={"delay": 0.0, "backend": backend}, lock=True, verify=False)
    with pc:
        rep = pc.controls
        assert rep.applied["auto_exposure"] == manual
        assert dev.cap.props[cv2.CAP_PROP_AUTO_EXPOSURE] == manual
        assert rep.applied["auto_white_balance"] == 0.0 and "white_balance" in rep.applied
        assert rep.failed["autofocus"] == "refused by the driver"
        assert rep.failed["sharpness"].startswith("accepted but reads back 128")
        periods = rep.exposure_s / (1 / 60)
        if backend == "V4L2":           # 100 µs units: a whole number of 60 Hz frame periods
            assert abs(periods - round(periods)) < 0.01 and round(periods) >= 1
        else:                           # log2 seconds: a power of two
            assert float(np.log2(rep.exposure_s)).is_integer()
        assert "NOT set: autofocus" in rep.summary()
        assert abs(pc.drift()) < 0.03, "a locked camera keeps its white level"


# The fake camera runs in real time (~2.5 s of frames a test): the V4L2 lock above keeps the
# controls in the fast tier, these variants run in the whole suite.
@pytest.mark.slow
def test_lock_on_a_backend_without_controls_says_so():
    pc, _, _ = _procam(camera={"delay": 0.0, "backend": "AVFOUNDATION"}, lock=True, verify=False)
    with pc:
        assert not pc.controls.ok
        assert "cannot set camera controls" in pc.controls.failed["exposure"]


@pytest.mark.slow
def test_lock_is_reapplied_after_a_stream_restart(caplog):
    pc, proj, dev = _procam(camera={"delay": 0.0}, lock=True, verify=False, retries=3)
    with pc:
        first = dev.cap
        first.fail_reads = 10
        with caplog.at_level(logging.WARNING):
            pc.capture(np.zeros((PROJ[1], PROJ[0], 3), np.uint8))
        assert dev.cap is not first and pc.cam.restarts == 1
        assert dev.cap.props[cv2.CAP_PROP_AUTO_EXPOSURE] == 1.0, "controls re-applied"
        assert dev.cap.props[cv2.CAP_PROP_EXPOSURE] == pc.controls.applied["exposure"]
        assert "re-applied after the stream restart" in caplog.text


def test_a_dead_camera_fails_after_a_bounded_number_of_reads(monkeypatch):
    """Read failures are retried in one place, the Camera: a camera that never delivers fails
    a calibration capture after ``retries + 1`` reads and one stream re-open, as one
    CaptureError; neither HardwareProCam nor the Capturer tries again on top."""
    from hardware_fakes import FakeCapture

    from rtdefocus.calib.capture import Capturer

    pc, _, dev = _procam(camera={"delay": 0.0}, average=2, verify=False, retries=3)
    calls = {"read": 0, "grab": 0}

    def dead(kind, result):
        def attempt(self):
            calls[kind] += 1
            return result
        return attempt

    monkeypatch.setattr(FakeCapture, "read", dead("read", (False, None)))
    monkeypatch.setattr(FakeCapture, "grab", dead("grab", False))
    with pc:
        cap = Capturer(pc)
        cap.begin("geometry", 2)
        opened = len(dev.opened)
        for n in (1, 2):
            with pytest.raises(CaptureError, match="capture 1 of stage geometry: camera 0 "
                                                   "delivered no frame in 4 attempts") as info:
                cap(np.zeros((PROJ[1], PROJ[0], 3), np.uint8))
            assert calls["read"] == 4 * n and calls["grab"] <= n, calls
            assert len(dev.opened) == opened + n, "the stream is re-opened once per capture"
            assert isinstance(info.value.__cause__, CaptureError)
        assert pc.recaptured == 0 and cap.counts["geometry"] == 0


def test_camera_source_shares_the_helper():
    from rtdefocus.stream.sources import CameraSource

    dev = FakeDevice(FakeProjector(PROJ), delay=0.0)
    with CameraSource(0, size=(1280, 720), fourcc="MJPG", capture_factory=dev) as src:
        f0, f1 = src.read(), src.read()
        assert (f0.index, f1.index) == (0, 1) and f0.image.shape == (720, 1280, 3)
        assert src.fps == 30.0 and "MJPG" in src.describe()


# --------------------------------------------------------------------------- projector size
class _LateFullscreenWindow(FakeProjector):
    """A window whose framebuffer changes size a moment after going full-screen (Wayland's
    late switch, desktop scaling): ``final_size`` polls until it settles."""

    def __init__(self, sizes):
        super().__init__(sizes[0])
        self._sizes = list(sizes)

    def final_size(self):
        while len(self._sizes) > 1:
            self.size = self._sizes.pop(0)
        self.size = self._sizes[0]
        return self.size


def test_window_sink_refuses_a_framebuffer_that_is_not_the_calibrations():
    from rtdefocus.errors import DeviceError
    from rtdefocus.stream.sinks import WindowSink

    win = _LateFullscreenWindow([(800, 600), (1280, 800)])     # mapped at 800x600, then 1280x800
    with pytest.raises(DeviceError, match=r"is 1280x800 but the calibration is for a 800x600 "
                       r"projector.*800x600 at 100 % scaling.*calibrate again at 1280x800"):
        WindowSink(win, screen=1, expect_size=(800, 600))
    win = _LateFullscreenWindow([(1280, 800), (800, 600)])     # settles at the right size
    sink = WindowSink(win, expect_size=(800, 600))
    assert sink.window.size == (800, 600)


# --------------------------------------------------------------------------- CLI
@pytest.fixture()
def fake_hardware(monkeypatch):
    """`rtdefocus calibrate/check --camera 0` on the fake projector and camera."""
    import functools

    import rtdefocus.hardware.hardware_procam as procam_mod

    made = {}

    def make(projector_size=PROJ, **camera):
        proj = FakeProjector(projector_size)
        dev = FakeDevice(proj, **{"delay": 0.05, **camera})
        made.update(projector=proj, device=dev)
        monkeypatch.setattr(procam_mod, "HardwareProCam", functools.partial(
            procam_mod.HardwareProCam, window=proj, capture_factory=dev))
        return made
    return make


@pytest.mark.slow
def test_cli_check_reports_mode_latency_clipping(fake_hardware, capsys):
    from rtdefocus import cli

    fake_hardware()
    rc = cli.main(["check", "--camera", "0", "--screen", "1", "--camera-size", "1280x720",
                   "--fourcc", "MJPG", "--lock"])
    out = capsys.readouterr().out
    assert rc == 0, out
    for text in ("1280x720 MJPG at 30 fps", "latency", "white clipping", "black level",
                 "contrast", "camera controls (V4L2)", "NOT set: autofocus", "ready: rtdefocus calibrate"):
        assert text in out, (text, out)


@pytest.mark.slow
def test_cli_check_fails_on_clipping(fake_hardware, capsys):
    from rtdefocus import cli

    fake_hardware()
    rc = cli.main(["check", "--camera", "0", "--lock", "--exposure", "100"])   # far too long
    out = capsys.readouterr().out
    assert rc == 1 and "[FAIL] white clipping" in out and "lower the camera's exposure" in out


def test_cli_calibrate_passes_the_camera_options(monkeypatch):
    import rtdefocus.hardware.hardware_procam as procam_mod
    from rtdefocus import cli

    seen = {}

    class Stop(Exception):
        pass

    def fake(**kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(procam_mod, "HardwareProCam", fake)
    with pytest.raises(Stop):
        cli.main(["calibrate", "--camera", "2", "--screen", "1", "-o", "x.npz", "--camera-size",
                  "1920x1080", "--fourcc", "mjpg", "--fps", "30", "--settle", "0.4", "--flush", "2",
                  "--average", "4", "--lock", "--exposure", "33.3"])
    assert seen == {"camera": 2, "screen": 1, "camera_size": (1920, 1080), "fourcc": "MJPG",
                    "fps": 30.0, "settle": 0.4, "flush": 2, "average": 4, "lock": True,
                    "exposure": pytest.approx(0.0333), "camera_backend": "auto"}
    with pytest.raises(SystemExit) as exc:
        cli.main(["calibrate", "--camera", "0", "-o", "x.npz", "--fourcc", "MJPEG"])
    assert exc.value.code == 2


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_cli_calibrate_through_a_stale_camera_matches_the_direct_calibration(fake_hardware, tmp_path,
                                                                              capsys):
    """`rtdefocus calibrate --camera 0 --lock` on the virtual cubicle filmed by a camera with a
    0.2 s delay and a 4-frame queue that ignores BUFFERSIZE: the same geometry as calibrating
    the simulator directly, no capture taken again, no drift."""
    import rtdefocus as rd
    from rtdefocus import cli, sim
    from rtdefocus.calib.file import Calibration

    P, C = (200, 150), (320, 240)
    world = sim.VirtualProCam("cubicle", projector_size=P, camera_size=C, seed=0)
    direct = rd.calibrate(world, stages=("geometry",))
    fake_hardware(projector_size=P, size=C, delay=0.2, queue=4, noise=0,
                  world=lambda pattern: world.capture(pattern))
    rc = cli.main(["calibrate", "--camera", "0", "--screen", "1", "--lock", "--average", "1",
                   "--stages", "geometry", "-o", str(tmp_path / "setup.npz")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "0 capture(s) taken again" in out and "white level drift during calibration: +0.0%" in out
    calib = Calibration.load(tmp_path / "setup.npz")
    assert calib.n_planes == direct.n_planes == 2
    pts = np.array([[[x, y]] for x in (10, 100, 190) for y in (10, 75, 140)], np.float64)
    for H, H0 in zip(calib.H_cam_from_proj, direct.H_cam_from_proj, strict=True):
        d = cv2.perspectiveTransform(pts, np.asarray(H)) - cv2.perspectiveTransform(pts, np.asarray(H0))
        assert np.abs(d).max() < 0.5, f"camera positions differ by {np.abs(d).max():.2f} px"


def test_a_locked_exposure_can_be_turned_down_for_calibration():
    """The control the calibration uses when white clips: a whole number of frame periods,
    read back, re-applied after a restart; an unlocked camera offers none."""
    from rtdefocus.calib.capture import Capturer

    pc, _, dev = _procam(camera={"delay": 0.0}, lock=True, exposure=4 / 60, verify=False)
    with pc:
        cap = Capturer(pc)
        start = cap.exposure
        assert start == pc.controls.exposure_s and abs(start - 4 / 60) < 1e-3
        got = cap.set_exposure(start * 0.6)
        periods = got / (1 / 60)
        assert got < start and abs(periods - round(periods)) < 0.01
        assert dev.cap.props[cv2.CAP_PROP_EXPOSURE] == pc.controls.wanted["exposure"]
        assert pc.drift() is None, "a white level of another exposure is no drift"
    unlocked, _, _ = _procam(camera={"delay": 0.0}, verify=False)
    with unlocked:
        assert Capturer(unlocked).exposure is None
