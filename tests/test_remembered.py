"""The calibration remembers its monitor and camera: recorded by `calibrate` on the fake
projector and camera, used by `check` (and `play`) when no option names them, found again
after a re-plug, refused when missing or different; `check` prints the complete calibrate
command; `rtdefocus cameras` from a fake camera list; older files still load."""

from __future__ import annotations

import dataclasses
import shlex

import pytest
from hardware_fakes import FakeDevice, FakeProjector

from rtdefocus.errors import CaptureError, InputError
from rtdefocus.hardware import cameras as cameras_mod
from rtdefocus.hardware import remembered as rem
from rtdefocus.hardware.cameras import CameraEntry

P, C = (200, 150), (320, 240)
LAPTOP = {"index": 0, "name": "Built-in Retina", "size": (1440, 900), "refresh": 60,
          "position": (0, 0), "scale": (1.0, 1.0), "modes": [(1440, 900, 60)]}
PROJECTOR = {"index": 1, "name": "EPSON PJ", "size": P, "refresh": 60, "position": (1440, 0),
             "scale": (1.0, 1.0), "modes": [(*P, 60)]}


def monitors(*entries):
    return [dict(m, index=i) for i, m in enumerate(entries)]


@pytest.fixture()
def rig(monkeypatch):
    """The fake projector and camera behind HardwareProCam, a fake monitor list and a fake
    camera list; ``rig["opened"]`` collects the camera index and backend each open asked for."""
    import rtdefocus.hardware.hardware_procam as procam_mod
    from rtdefocus import sim

    world = sim.VirtualProCam("cubicle", projector_size=P, camera_size=C, seed=0)
    proj = FakeProjector(P)
    dev = FakeDevice(proj, delay=0.05, fourcc="MJPG", size=C, noise=0,
                     world=lambda pattern: world.capture(pattern))
    state = {"monitors": monitors(LAPTOP, PROJECTOR),
             "cameras": [CameraEntry(0, "USB Camera HD", "v4l2", "/dev/video0")], "opened": []}
    real = procam_mod.HardwareProCam

    def hw(**kwargs):
        state["opened"].append((kwargs.get("camera"), kwargs.get("camera_backend"),
                                kwargs.get("screen")))
        return real(window=proj, capture_factory=dev, **kwargs)

    monkeypatch.setattr(procam_mod, "HardwareProCam", hw)
    monkeypatch.setattr(rem, "connected_monitors", lambda: state["monitors"])
    monkeypatch.setattr(cameras_mod, "enumerate_named", lambda *a, **k: state["cameras"])
    return state


_CALIBRATED: dict = {}


@pytest.fixture()
def setup_file(rig, tmp_path, capsys):
    """A file written by `calibrate` through the rig. The calibration runs once per module (it
    costs seconds of fake-camera frames); each test gets its own copy of the file."""
    from rtdefocus import cli

    out = tmp_path / "setup.npz"
    if "file" not in _CALIBRATED:
        rc = cli.main(["calibrate", "--camera", "0", "--screen", "1", "--camera-size", "320x240",
                       "--fourcc", "MJPG", "--lock", "--exposure", "16.7", "--average", "1",
                       "--stages", "geometry", "-o", str(out)])
        assert rc == 0, capsys.readouterr()
        _CALIBRATED["file"] = out.read_bytes()
    else:
        out.write_bytes(_CALIBRATED["file"])
    capsys.readouterr()
    rig["opened"].clear()
    return out


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_calibrate_records_the_monitor_and_the_camera(setup_file):
    from rtdefocus.calib.file import Calibration

    hw = rem.remembered(Calibration.load(setup_file))
    assert hw["monitor"] == {"name": "EPSON PJ", "index": 1, "size": list(P), "refresh": 60,
                             "position": [1440, 0]}
    cam = hw["camera"]
    assert (cam["name"], cam["index"], cam["backend"], cam["size"], cam["fourcc"]) == \
        ("USB Camera HD", 0, "auto", list(C), "MJPG")
    assert cam["lock"] is True and cam["exposure_s"] == pytest.approx(1 / 60, rel=0.05)
    assert cam["controls"], "the locked control values are recorded"


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_check_uses_the_remembered_set_up_and_prints_the_complete_command(rig, setup_file,
                                                                          capsys):
    """Re-plugged: the camera is index 3 now and the projector screen 2; `check setup.npz`
    finds both by name and prints a calibrate line with the size, format and lock."""
    from rtdefocus import cli

    rig["monitors"] = monitors(LAPTOP, dict(LAPTOP, name="Dell U2415", position=(-1920, 0)),
                               PROJECTOR)
    rig["cameras"] = [CameraEntry(0, "Integrated Webcam", "v4l2"),
                      CameraEntry(3, "USB Camera HD", "v4l2")]
    rc = cli.main(["check", str(setup_file)])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert rig["opened"] == [(3, "v4l2", 2)]
    ready = [line for line in out.splitlines() if line.startswith("ready: ")]
    assert len(ready) == 1, out
    argv = shlex.split(ready[0][len("ready: "):])
    assert argv[:2] == ["rtdefocus", "calibrate"]
    opts = dict(zip(argv[2::1], argv[3::1], strict=False))
    assert (opts["--camera"], opts["--screen"], opts["--camera-backend"], opts["--camera-size"],
            opts["--fourcc"]) == ("3", "2", "v4l2", "320x240", "MJPG")
    assert "--lock" in argv and float(opts["--exposure"]) == pytest.approx(1e3 / 60, rel=0.05)
    # The printed command parses as a calibrate command line.
    args = cli.build_parser().parse_args(argv[1:])
    assert args.camera_size == (320, 240) and args.lock and args.camera_backend == "v4l2"


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_check_refuses_a_missing_or_different_monitor(rig, setup_file, capsys):
    from rtdefocus import cli

    rig["monitors"] = monitors(LAPTOP, dict(PROJECTOR, name="BenQ MW560"))
    assert cli.main(["check", str(setup_file)]) == 1
    err = capsys.readouterr().err
    assert "the calibrated monitor 'EPSON PJ'" in err and "is not connected" in err
    assert "0: Built-in Retina 1440x900" in err and "1: BenQ MW560" in err
    rig["monitors"] = monitors(LAPTOP, PROJECTOR)
    assert cli.main(["check", str(setup_file), "--screen", "0"]) == 1
    err = capsys.readouterr().err
    assert "--screen 0 is 'Built-in Retina', not the calibrated monitor 'EPSON PJ'" in err
    assert rig["opened"] == [], "nothing opened on a wrong monitor"


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_check_refuses_a_missing_camera(rig, setup_file, capsys):
    from rtdefocus import cli

    rig["cameras"] = [CameraEntry(0, "Integrated Webcam", "v4l2")]
    assert cli.main(["check", str(setup_file)]) == 1
    err = capsys.readouterr().err
    assert "the calibrated camera 'USB Camera HD' is not connected" in err
    assert "0: Integrated Webcam" in err and "--camera N" in err


def test_check_without_camera_or_calibration_says_what_to_pass(rig, capsys):
    from rtdefocus import cli

    assert cli.main(["check"]) == 1
    err = capsys.readouterr().err
    assert "pass --camera N" in err and "rtdefocus cameras" in err


def test_resolve_screen_rules():
    mons = monitors(LAPTOP, PROJECTOR)
    rec = rem.monitor_record(PROJECTOR)
    assert rem.resolve_screen(None, mons, rec) == 1
    assert rem.resolve_screen(1, mons, rec) == 1
    assert rem.resolve_screen(None, mons, None) == 0
    assert rem.default_screen(mons) == 1 and rem.default_screen(mons[:1]) == 0
    with pytest.raises(InputError, match="screen 5 is not connected; monitors: 0: Built-in"):
        rem.resolve_screen(5, mons, None)
    # Two projectors of one model: the one at the remembered position.
    twin = dict(PROJECTOR, position=(3000, 0))
    assert rem.resolve_screen(None, monitors(LAPTOP, twin, PROJECTOR), rec) == 2
    assert rem.resolve_screen(None, monitors(LAPTOP, PROJECTOR, twin), rec) == 1


def test_resolve_camera_rules():
    rec = {"name": "USB Camera HD", "index": 0, "backend": "dshow"}
    cams = [CameraEntry(1, "USB Camera HD", "msmf"), CameraEntry(2, "USB Camera HD", "dshow")]
    assert rem.resolve_camera(None, rec, cams) == (2, "dshow")
    assert rem.resolve_camera("5", rec, cams) == ("5", None)
    assert rem.resolve_camera(None, dict(rec, name=""), []) == (0, "dshow")
    with pytest.raises(CaptureError, match="not connected; connected: no camera found"):
        rem.resolve_camera(None, rec, [])
    with pytest.raises(InputError, match="pass --camera N"):
        rem.resolve_camera(None, {}, cams)
    assert rem.camera_options({"size": [1920, 1080], "fourcc": "MJPG", "lock": True,
                               "exposure_s": 0.0333}) == \
        {"camera_size": (1920, 1080), "fourcc": "MJPG", "lock": True, "exposure": 33.3}


def test_calibrate_command_quotes_a_url():
    line = rem.calibrate_command(camera="rtsp://cam/live?a=1&b=2", screen=1, lock=True,
                                 camera_size=(1280, 720), fourcc="MJPG", exposure_ms=33.3)
    assert shlex.split(line) == ["rtdefocus", "calibrate", "--camera", "rtsp://cam/live?a=1&b=2",
                                 "--screen", "1", "--camera-size", "1280x720", "--fourcc", "MJPG",
                                 "--lock", "--exposure", "33.3", "-o", "setup.npz"]


def test_play_screen_follows_the_calibration(monkeypatch):
    """`play` without --screen goes to the remembered monitor; a calibration without the
    record (simulated, older files) keeps the old default."""
    from test_stream import virtual_calibration

    from rtdefocus.cli.show import _screen

    calib = dataclasses.replace(virtual_calibration(), meta={})    # shared: not edited in place
    monkeypatch.setattr(rem, "connected_monitors",
                        lambda: monitors(LAPTOP, dict(LAPTOP, name="Dell"), PROJECTOR))
    assert _screen(None, calib) == 0
    calib.meta["hardware"] = {"monitor": rem.monitor_record(PROJECTOR)}
    assert _screen(None, calib) == 2
    with pytest.raises(InputError, match="--screen 1 is 'Dell', not the calibrated monitor"):
        _screen(1, calib)
    monkeypatch.setattr(rem, "connected_monitors", lambda: None)      # no display to ask
    assert _screen(None, calib) == 0


def test_a_calibration_without_the_record_loads_and_remembers_nothing(tmp_path):
    from test_stream import virtual_calibration

    from rtdefocus.calib.file import Calibration

    calib = dataclasses.replace(virtual_calibration(), meta={})    # shared: not edited in place
    loaded = Calibration.load(calib.save(tmp_path / "old.npz"))
    assert rem.remembered(loaded) == {}
    calib.meta["hardware"] = {"monitor": rem.monitor_record(PROJECTOR)}
    again = Calibration.load(calib.save(tmp_path / "new.npz"))
    assert rem.remembered(again)["monitor"]["name"] == "EPSON PJ"


# --------------------------------------------------------------------------- cameras
class _Info:
    def __init__(self, index, name, path=""):
        self.index, self.name, self.path = index, name, path


def test_cameras_lists_names_per_backend(monkeypatch, capsys):
    import cv2

    from rtdefocus import cli

    listing = {cv2.CAP_V4L2: [_Info(0, "Integrated Webcam", "/dev/video0"),
                              _Info(2, "Logitech BRIO", "/dev/video2")],
               cv2.CAP_GSTREAMER: [_Info(0, "Integrated Webcam")]}
    found = cameras_mod.list_cameras(enumerate_cameras=lambda api: listing[api],
                                     backends=(cv2.CAP_V4L2, cv2.CAP_GSTREAMER),
                                     probe=lambda: pytest.fail("no probing when names exist"))
    assert found == [CameraEntry(0, "Integrated Webcam", "v4l2", "/dev/video0"),
                     CameraEntry(2, "Logitech BRIO", "v4l2", "/dev/video2")]
    monkeypatch.setattr(cameras_mod, "list_cameras", lambda probe=None: found)
    assert cli.main(["cameras"]) == 0
    out = capsys.readouterr().out
    assert "2: Logitech BRIO  [--camera-backend v4l2]  /dev/video2" in out


def test_cameras_falls_back_to_probing_indices(monkeypatch, capsys):
    from rtdefocus import cli

    class Cap:
        def __init__(self, i):
            self.i = i
            self.released = False

        def isOpened(self):
            return self.i in (0, 2)

        def read(self):
            return (self.i == 0), None

        def release(self):
            self.released = True

    found = cameras_mod.list_cameras(enumerate_cameras=lambda api: [], backends=(),
                                     probe=lambda: cameras_mod.probe_indices(4, Cap))
    assert found == [CameraEntry(0, "", "auto")]     # index 2 opens but delivers nothing
    monkeypatch.setattr(cameras_mod, "list_cameras", lambda probe=None: [])
    assert cli.main(["cameras"]) == 1
    assert "Cameras: none found" in capsys.readouterr().out


def test_camera_backend_option_opens_through_that_backend(monkeypatch):
    import cv2

    from rtdefocus.hardware import camera as camera_mod

    calls = []

    class Cap:
        def __init__(self, *args):
            calls.append(args)

        def isOpened(self):
            return False

        def release(self):
            pass

    monkeypatch.setattr(cv2, "VideoCapture", Cap)
    for name, code in (("dshow", cv2.CAP_DSHOW), ("msmf", cv2.CAP_MSMF),
                       ("v4l2", cv2.CAP_V4L2), ("avfoundation", cv2.CAP_AVFOUNDATION)):
        with pytest.raises(CaptureError, match="rtdefocus cameras"):
            camera_mod.open_camera(1, backend=name)
        assert calls[-1] == (1, code)
    with pytest.raises(CaptureError):
        camera_mod.open_camera(1)
    assert calls[-1] == (1,)
    with pytest.raises(CaptureError):
        camera_mod.open_camera("rtsp://cam/live", backend="dshow")   # streams: OpenCV's choice
    assert calls[-1] == ("rtsp://cam/live",)
    with pytest.raises(InputError, match="camera backend must be one of auto, v4l2"):
        camera_mod.CameraSettings(backend="directshow")


@pytest.mark.slow
def test_cli_camera_backend_reaches_the_hardware(rig, monkeypatch):
    import rtdefocus.hardware.preflight as pre
    from rtdefocus import cli

    class Stop(Exception):
        pass

    def stop(*a, **k):
        raise Stop

    monkeypatch.setattr(pre, "preflight", stop)
    with pytest.raises(Stop):
        cli.main(["check", "--camera", "0", "--screen", "1", "--camera-backend", "v4l2"])
    assert rig["opened"] == [(0, "v4l2", 1)]



def test_info_lists_the_cameras_by_name(monkeypatch, capsys):
    from rtdefocus import cli

    monkeypatch.setattr(cameras_mod, "enumerate_named",
                        lambda *a, **k: [CameraEntry(1, "Logitech BRIO", "msmf")])
    assert cli.main(["info"]) == 0
    out = capsys.readouterr().out
    assert "Cameras (--camera N --camera-backend B):" in out
    assert "1: Logitech BRIO  [--camera-backend msmf]" in out
