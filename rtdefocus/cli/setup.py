"""Subcommands that set a projector-camera up: ``info``, ``simulate``, ``calibrate``, ``check``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .. import __version__
from ..errors import InputError, RtDefocusError
from .common import Progress, parse_size, read_image, write_image

log = logging.getLogger("rtdefocus")


# --------------------------------------------------------------------------- info
def add_info(sub):
    p = sub.add_parser("info", help="list OpenCL devices, the OpenGL renderer, monitors and cameras")
    p.set_defaults(func=cmd_info)


def cmd_info(args) -> int:
    from ..cl.runtime import choose_device, list_devices
    from ..errors import DeviceError
    from ..gl.runtime import gl_available

    print(f"rtdefocus {__version__}")
    print("OpenCL:")
    try:
        chosen = choose_device()
        for pi, di, plat, dev in list_devices():
            mark = "*" if dev == chosen else " "
            print(f" {mark} {pi}:{di}  {dev.name.strip()}  [{plat.name.strip()}]  "
                  f"compute units {dev.max_compute_units}, "
                  f"memory {dev.global_mem_size / 2**30:.1f} GiB, {dev.version.strip()}")
        print("   (* = selected; set RTDEFOCUS_DEVICE=P:D or a name to choose)")
    except DeviceError as exc:
        print(f"   none: {exc}")
    ok, renderer = gl_available()
    print("OpenGL (offscreen):")
    print(f"   {renderer}" if ok else f"   unavailable: {renderer}")
    from ..cl.glshare import gl_sharing_status

    shared, why = gl_sharing_status()
    print("GL sharing (warp output to OpenCL on the device):")
    print(f"   available: {why}" if shared else f"   not available, frames go through the host: {why}")
    _print_monitors()
    _print_cameras()
    return 0


def _print_cameras() -> None:
    """The cameras the platform lists by name (``rtdefocus cameras`` also probes indices)."""
    from ..hardware.cameras import enumerate_named

    cameras = enumerate_named()
    print("Cameras (--camera N --camera-backend B):" if cameras else
          "Cameras: none listed by name (`rtdefocus cameras` also tries indices 0-5)")
    for c in cameras:
        print(f"   {c.describe()}")


def _print_monitors() -> None:
    """The monitors glfw sees, with their modes (``--screen`` takes the index)."""
    try:
        from ..gl.window import monitor_info

        monitors = monitor_info()
    except Exception as exc:  # noqa: BLE001 - no display, no glfw library: say so, don't fail
        print(f"Monitors: none found ({exc})")
        return
    print("Monitors (--screen N):" if monitors else "Monitors: none connected")
    for m in monitors:
        scale = m["scale"]
        note = "" if scale == (1.0, 1.0) else f", desktop scaling {scale[0]:g}x (set it to 100 %)"
        print(f"   {m['index']}: {m['name']}  {m['size'][0]}x{m['size'][1]} @ {m['refresh']} Hz "
              f"at {m['position'][0]},{m['position'][1]}{note}")
        modes = ", ".join(f"{w}x{h}@{r}" for w, h, r in m["modes"][:12])
        more = f" (+{len(m['modes']) - 12} more)" if len(m["modes"]) > 12 else ""
        print(f"      modes: {modes}{more}")


# --------------------------------------------------------------------------- cameras
def add_cameras(sub):
    p = sub.add_parser("cameras", help="list the connected cameras: index, name and capture backend",
                       epilog="example:\n  rtdefocus cameras\n  rtdefocus aim --camera 0 "
                       "--camera-backend v4l2 --screen 1",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--probe", type=int, default=6, metavar="N", help="where the platform lists no "
                   "names, open indices 0..N-1 to find cameras (default 6)")
    p.set_defaults(func=cmd_cameras)


def cmd_cameras(args) -> int:
    from ..hardware.cameras import list_cameras, probe_indices

    cameras = list_cameras(probe=lambda: probe_indices(args.probe))
    if not cameras:
        print("Cameras: none found. Plug the webcam in (and close other programs using it); on "
              "Linux check that your user may open /dev/video*")
        return 1
    print("Cameras (--camera N --camera-backend B):")
    for c in cameras:
        print(f"   {c.describe()}")
    return 0


# --------------------------------------------------------------------------- simulate
def add_simulate(sub):
    p = sub.add_parser("simulate", help="show a pattern or image on the virtual set-up, write "
                       "the camera's view (blurred, and sharp with --sharp)")
    p.add_argument("--scene", default="cubicle", help="simulator preset (default: cubicle)")
    p.add_argument("--pattern", default="checker",
                   help="checker | lines | dots | path of an image (resized to the projector)")
    p.add_argument("--sharp", action="store_true", help="render without blur and noise")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", required=True, help="output PNG")
    p.set_defaults(func=cmd_simulate)


def cmd_simulate(args) -> int:
    from .. import sim

    procam = sim.VirtualProCam(args.scene, seed=args.seed)
    pattern = sim.test_pattern(args.pattern, procam.projector_size) \
        if args.pattern in sim.PATTERNS else None
    if pattern is None:
        import cv2
        pattern = cv2.resize(read_image(args.pattern), procam.projector_size,
                             interpolation=cv2.INTER_AREA)
    out = write_image(args.output, procam.capture(pattern, sharp=args.sharp))
    print(f"wrote {out} (camera {procam.camera_size[0]}x{procam.camera_size[1]}, "
          f"scene {args.scene}, {'sharp' if args.sharp else 'defocused'})")
    return 0


# --------------------------------------------------------------------------- calibrate
CALIBRATE_EPILOG = """\
examples:
  rtdefocus calibrate --sim cubicle -o setup.npz              the built-in virtual cubicle
  rtdefocus calibrate --sim pillar -o p.npz --stages geometry --noise 0.01 --seed 3
  rtdefocus calibrate --camera 0 --screen 1 -o setup.npz      a webcam and the second monitor
  rtdefocus calibrate --camera 0 --screen 1 --camera-size 1920x1080 --fourcc MJPG --lock -o s.npz
  rtdefocus calibrate --camera 0 --screen 1 -o s.npz --save-captures caps   keep every capture
  rtdefocus calibrate --from-captures caps -o s2.npz          redo it from them, bit for bit
  rtdefocus calibrate --sim gap -o gap.npz --dense            mask what no wall fits (far wall)
  rtdefocus calibrate --camera 0 --screen 1 -o s.npz --lens-from flat.npz   a lens measured once
writes setup.npz and, next to it (or in --diagnostics DIR), setup_geometry.png: the camera view
with the detected lines, kinks, fold, the two planes and the 4:3 / 16:9 display rectangles;
setup_camera.png: the camera's and the projector's response curves, the lens's distortion grid
and the PSF dots that were skipped and why.
"""


def _stages(text: str) -> tuple[str, ...]:
    from ..calib import STAGES

    stages = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in stages if s not in STAGES]
    if bad or "geometry" not in stages:
        raise argparse.ArgumentTypeError(f"stages must include geometry and be among "
                                         f"{','.join(STAGES)}; got {text!r}")
    return stages


def add_calibrate(sub):
    p = sub.add_parser("calibrate", help="calibrate a projector-camera set-up (virtual or real) "
                       "and write the calibration file", epilog=CALIBRATE_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--sim", metavar="PRESET", help="the built-in virtual set-up: cubicle, pillar, "
                     "flat, tilted, offcenter, u_cubicle or corner_ceiling")
    src.add_argument("--camera", metavar="INDEX", help="a real camera (index or URL); the patterns "
                     "go full-screen to --screen")
    src.add_argument("--from-captures", metavar="DIR", help="a capture set kept with "
                     "--save-captures: the calibration is redone from it (no camera or projector), "
                     "with its options unless given here")
    p.add_argument("--save-captures", metavar="DIR", help="keep every pattern and capture in DIR "
                   "(lossless PNG, with a JSON index written last)")
    p.add_argument("--screen", type=int, default=None, help="projector's monitor index (`rtdefocus "
                   "info` lists them; default: the second of two monitors, else 0)")
    add_camera_options(p)
    p.add_argument("-o", "--output", required=True, help="calibration file to write (.npz)")
    from ..calib import STAGES

    default = ",".join(STAGES)
    p.add_argument("--stages", type=_stages, default=None,
                   help=f"comma-separated stages to run (default: {default})")
    p.add_argument("--seed", type=int, default=0, help="simulator noise seed (default 0)")
    p.add_argument("--noise", type=float, default=None,
                   help="simulator camera noise, fraction of full scale (default: the simulator's)")
    p.add_argument("--diagnostics", metavar="DIR",
                   help="folder for the diagnostics pictures (default: next to the output)")
    p.add_argument("--planes", type=_planes, default=None, metavar="auto|N",
                   help="number of flat surfaces (walls, ceiling) the projection covers; auto "
                   "(default) finds it from the lines' kinks")
    p.add_argument("--flat", dest="residual", action="store_false",
                   help="model each surface as an exact plane (no smooth residual for walls that "
                   "bow or sag a little)")
    p.add_argument("--dense", action="store_true", default=None,
                   help="also project Gray code plus phase shift (28 more captures) and fit every "
                   "lit camera pixel; a region no wall fits (a far wall through a gap) is masked")
    lens = p.add_mutually_exclusive_group()
    lens.add_argument("--lens", type=_lens, metavar="K1,K2", help="the camera lens's radial "
                      "distortion, as measured once, instead of estimating it from the walls "
                      "(which pillowed walls mislead); a negative k1 as --lens=-0.05,0")
    lens.add_argument("--lens-from", metavar="FILE.npz", help="take the lens measured by an "
                      "earlier calibration of this camera, e.g. one made on a flat wall")
    p.set_defaults(func=cmd_calibrate, residual=None)


def _lens(text: str) -> tuple[float, float]:
    from ..calib.geometry.lens import check_lens_option

    try:
        return check_lens_option([float(v) for v in text.split(",")])
    except (ValueError, InputError):
        raise argparse.ArgumentTypeError(f"--lens takes k1,k2: two numbers within -1..1 "
                                         f"separated by a comma, e.g. --lens=-0.05,0; got "
                                         f"{text!r}") from None


def _planes(text: str):
    from ..calib.geometry.fit import check_planes_option

    try:
        n = check_planes_option(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return "auto" if n is None else n


def _fourcc(text: str) -> str:
    if len(text) != 4:
        raise argparse.ArgumentTypeError(f"fourcc must be four characters, e.g. MJPG or YUYV; got {text!r}")
    return text.upper() if text.upper() in ("MJPG", "YUYV", "H264", "NV12") else text


def add_camera_options(p, capture: bool = True) -> None:
    """The camera mode (and, for captures, the timing and control) options."""
    p.add_argument("--camera-size", type=parse_size, metavar="WxH",
                   help="camera resolution to ask for, e.g. 1920x1080 (default: the driver's)")
    p.add_argument("--fourcc", type=_fourcc, metavar="CODE", help="camera pixel format, set "
                   "before the size: MJPG (fast at 720p/1080p) or YUYV")
    from ..hardware.camera import CAMERA_BACKENDS

    p.add_argument("--camera-backend", choices=tuple(CAMERA_BACKENDS), default=None,
                   help="OpenCV capture backend: v4l2 (Linux), dshow or msmf (Windows), "
                   "avfoundation (macOS); default auto, or the one the calibration remembers")
    if not capture:
        p.add_argument("--camera-fps", type=float, metavar="FPS", help="camera frame rate to ask for")
        return
    p.add_argument("--fps", type=float, metavar="FPS", help="camera frame rate to ask for")
    p.add_argument("--settle", type=float, metavar="S", help="seconds from a pattern's swap to the "
                   "first usable camera frame (default: measured latency + 2 frames)")
    p.add_argument("--flush", type=int, default=1, metavar="N",
                   help="camera frames discarded at least after each pattern (default 1)")
    p.add_argument("--average", type=int, default=2, metavar="N",
                   help="camera frames averaged per pattern (default 2)")
    p.add_argument("--lock", action="store_true", default=None, help="lock exposure, white "
                   "balance and focus, sharpening off (read back; what could not be set is reported)")
    p.add_argument("--exposure", type=float, metavar="MS", help="exposure for --lock in "
                   "milliseconds, rounded to whole projector frame periods (default: auto's choice)")


def _hardware_procam(hw, args):
    """A HardwareProCam from the command line's camera options."""
    camera = int(args.camera) if str(args.camera).isdigit() else args.camera
    return hw(camera=camera, screen=args.screen, camera_size=args.camera_size, fourcc=args.fourcc,
              fps=args.fps, settle=args.settle, flush=args.flush, average=args.average,
              lock=bool(args.lock), exposure=args.exposure / 1e3 if args.exposure else None,
              camera_backend=args.camera_backend or "auto")


def _load_remembered(args):
    """The calibration file ``args.calibration`` names (None without one), after filling the
    camera and monitor options the command line left out from what it remembers."""
    calib = None
    if args.calibration:
        from ..calib.file import Calibration

        calib = Calibration.load(args.calibration)
    _remembered_hardware(args, calib)
    return calib


def _remembered_hardware(args, calib=None, *, monitors=None, cameras=None) -> None:
    """Fill the camera and monitor options the command line left out from what ``calib``
    remembers (:mod:`rtdefocus.hardware.remembered`), then check the monitor is connected."""
    from ..hardware import remembered as rem
    from ..hardware.cameras import enumerate_named

    rec = rem.remembered(calib)
    cam_rec = rec.get("camera") or {}
    if args.camera is None and cam_rec.get("name") and cameras is None:
        cameras = enumerate_named()
    camera, backend = rem.resolve_camera(args.camera, cam_rec, cameras)
    if args.camera is None:
        args.camera = camera
        if args.camera_backend is None:
            args.camera_backend = backend
        for key, value in rem.camera_options(cam_rec).items():
            if getattr(args, key, None) in (None, False) and value:
                setattr(args, key, value)
    if monitors is None:
        monitors = rem.connected_monitors()
    if args.screen is None and not rec.get("monitor") and monitors:
        args.screen = rem.default_screen(monitors)
    args.screen = rem.resolve_screen(args.screen, monitors or [], rec.get("monitor"))


def _report_hardware(procam, after: bool = False) -> None:
    """Print what the hardware start-up found (and, after calibration, the white-level drift)."""
    r = procam.report()
    cam = procam.cam.describe() if hasattr(procam, "cam") else "camera"
    lat = f", latency {r['latency_s'] * 1e3:.0f} ms" if r.get("latency_s") is not None else ""
    print(f"{cam}{lat}, settle {r['settle_s'] * 1e3:.0f} ms, {r['recaptured']} capture(s) taken "
          f"again, {r['restarts']} stream restart(s)")
    if procam.controls is not None:
        print(procam.controls.summary())
    if after:
        drift = procam.drift()
        if drift is not None:
            verdict = "" if abs(drift) < 0.03 else (
                " — more than 3 %: the exposure or the projector's brightness changed during "
                "calibration; use --lock, let the projector warm up 10 minutes, calibrate again")
            print(f"white level drift during calibration: {drift:+.1%}{verdict}")


def cmd_calibrate(args) -> int:
    import time

    from ..calib import STAGES, calibrate
    from ..calib.camera_diagnostics import camera_diagnostics
    from ..calib.captureset import calibrate_from_captures
    from ..calib.geometry.diagnostics import geometry_diagnostics
    from ..hardware import hardware_procam as procam_mod

    stages = args.stages or STAGES
    # Only the options given: a replay keeps the saved ones for the rest.
    options = {k: v for k, v in (("planes", args.planes), ("residual", args.residual),
                                 ("dense", args.dense), ("lens", args.lens or args.lens_from))
               if v is not None}
    procam = None
    if args.from_captures is not None:
        if args.save_captures:
            raise InputError("--from-captures and --save-captures together would copy the set: "
                             "copy the folder instead")
        if args.stages:
            options["stages"] = args.stages
        source = f"the captures in {args.from_captures}"
    elif args.sim is not None:
        from .. import sim

        kwargs = {"seed": args.seed}
        if args.noise is not None:
            kwargs["noise"] = args.noise
        procam = sim.VirtualProCam(args.sim, **kwargs)
        source = f"simulator preset {args.sim!r}"
    else:
        hw = getattr(procam_mod, "HardwareProCam", None)
        if hw is None:
            raise RtDefocusError("hardware capture needs HardwareProCam (not yet available in this "
                                 "version); use --sim PRESET for the built-in virtual set-up")
        _remembered_hardware(args)
        procam = _hardware_procam(hw, args)
        source = f"camera {args.camera!r}, projector on screen {args.screen}"
    t0 = time.perf_counter()
    try:
        with Progress(args.quiet) as progress:
            if procam is None:
                calib = calibrate_from_captures(args.from_captures, progress=progress, **options)
            else:
                calib = calibrate(procam, stages=stages, progress=progress,
                                  save_captures=args.save_captures, **options)
        if hasattr(procam, "drift"):
            _report_hardware(procam, after=True)
    finally:
        if hasattr(procam, "close"):
            procam.close()
    seconds = time.perf_counter() - t0
    out = calib.save(args.output)
    diag_dir = Path(args.diagnostics) if args.diagnostics else out.parent
    picture = write_image(diag_dir / f"{out.stem}_geometry.png", geometry_diagnostics(calib))
    camera_picture = write_image(diag_dir / f"{out.stem}_camera.png", camera_diagnostics(calib))
    g = calib.meta.get("geometry", {})
    rms = ", ".join(f"{v:.3f}" for v in g.get("rms_px", []))
    print(f"calibrated {source} in {seconds:.1f} s, {sum(calib.meta.get('captures', {}).values())} "
          f"captures {calib.meta.get('captures', {})}")
    fold = (f", fold disagreement {g['fold_disagreement_px']:.3f} projector px"
            if g.get("fold_disagreement_px") is not None else "")
    print(f"geometry: {calib.n_planes} plane(s), reprojection RMS {rms} camera px{fold}, "
          f"{g.get('lines_found')} of {g.get('lines_expected')} lines")
    lens = g.get("distortion") or {}
    if lens.get("given"):
        print(f"lens k1 {lens['k1']:.4f}, k2 {lens['k2']:.4f} as given")
    exposure = calib.meta.get("exposure")
    if exposure:
        print(f"the white frame clipped: the camera's exposure was turned down from "
              f"{exposure['from']:.4g} to {exposure['to']:.4g}, and stays there")
    if args.save_captures:
        print(f"kept the captures in {args.save_captures} (redo with --from-captures)")
    print(f"wrote {out} (sections: {', '.join(calib.sections())})")
    print(f"wrote {picture} and {camera_picture}")
    return 0


# --------------------------------------------------------------------------- aim
AIM_EPILOG = """\
examples:
  rtdefocus aim --camera 0 --screen 1        the webcam and the projector on the second monitor
  rtdefocus aim setup.npz                    the camera and monitor setup.npz remembers
The projector holds a pattern (w white, g grid, c checker; r finds the projected area again);
the preview on the laptop shows the camera's picture with the projected area outlined in green,
clipped pixels in red and, on the checker, a focus meter per wall: the edge blur in projector
pixels. Aim the camera until the outline holds the whole picture and nothing is red, then turn
the projector's focus ring until both walls read low and about equal. q or Esc leaves.
"""


def add_aim(sub):
    p = sub.add_parser("aim", help="live camera preview with the projected area, clipping and a "
                       "focus meter per wall, while the projector holds a pattern",
                       epilog=AIM_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("calibration", nargs="?", help="a calibration file: its camera and monitor are "
                   "used where --camera / --screen are not given (and its walls for the meters)")
    p.add_argument("--camera", metavar="INDEX", help="camera index or stream URL (`rtdefocus "
                   "cameras` lists them)")
    p.add_argument("--screen", type=int, default=None, help="projector's monitor index (default: "
                   "the calibration's monitor, else the second of two, else 0)")
    add_camera_options(p, capture=False)
    p.add_argument("--pattern", choices=("white", "grid", "checker"), default="checker",
                   help="pattern to start with (default checker)")
    p.add_argument("--preview-size", type=parse_size, default=(960, 540), metavar="WxH",
                   help="size of the preview window on the laptop (default 960x540)")
    p.add_argument("--frames", type=int, default=None, metavar="N",
                   help="stop after N camera frames (scripted checks; default: until q)")
    p.set_defaults(func=cmd_aim)


def cmd_aim(args) -> int:
    from ..gl.window import ProjectorWindow
    from ..hardware.aim_loop import run_aim
    from ..hardware.camera import CameraSettings, open_camera

    calib = _load_remembered(args)
    camera = int(args.camera) if str(args.camera).isdigit() else args.camera
    settings = CameraSettings(size=args.camera_size, fourcc=args.fourcc, fps=args.camera_fps,
                              backend=args.camera_backend or "auto")
    with open_camera(camera, settings) as cam, \
            ProjectorWindow(args.screen, fullscreen=True) as projector, \
            ProjectorWindow(fullscreen=False, size=args.preview_size, title="rtdefocus aim",
                            vsync=False) as preview:
        print(f"{cam.describe()}; projector {projector.size[0]}x{projector.size[1]} on screen "
              f"{args.screen}. Keys: w white, g grid, c checker, r find the area again, q quit")
        view = run_aim(cam, projector, preview, calib=calib, pattern=args.pattern,
                       max_frames=args.frames)
    if view is not None and view.area is None:
        raise RtDefocusError("the camera does not see the projection: aim it at the projected "
                             "area, and check --screen and --camera (`rtdefocus cameras`)")
    if view is not None:
        meters = ", ".join(f"{r.name} {x.blur_projector_px:.1f} px" for r, x in
                           zip(view.regions, view.readings, strict=True)
                           if x.blur_projector_px is not None)
        clipped = float(view.clipped[view.area.mask].mean())
        print(f"projected area {view.area.fraction:.0%} of the camera picture, clipped "
              f"{clipped:.1%}" + (f", edge blur {meters}" if meters else ""))
    return 0


# --------------------------------------------------------------------------- check
CHECK_EPILOG = """\
examples:
  rtdefocus check --camera 0 --screen 1                 the webcam and the second monitor
  rtdefocus check --camera 0 --screen 1 --camera-size 1920x1080 --fourcc MJPG --lock
  rtdefocus check setup.npz                             the camera and monitor setup.npz remembers
shows white and black on the projector and reports, in seconds: the camera's negotiated mode,
the monitor, the projector-to-camera latency, the camera-to-projector pixel ratio, white
clipping, the black level, the contrast and the camera controls; then the complete calibrate
command for what was checked. Exit code 1 on a FAIL line.
"""


def add_check(sub):
    p = sub.add_parser("check", help="pre-flight of a real set-up before calibrating: camera mode, "
                       "monitor, latency, clipping, exposure", epilog=CHECK_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("calibration", nargs="?", help="a calibration file: its camera and monitor are "
                   "used where --camera / --screen are not given")
    p.add_argument("--camera", metavar="INDEX", help="camera index or stream URL (`rtdefocus "
                   "cameras` lists them)")
    p.add_argument("--screen", type=int, default=None, help="projector's monitor index (default: "
                   "the calibration's monitor, else the second of two, else 0)")
    add_camera_options(p)
    p.set_defaults(func=cmd_check)


def cmd_check(args) -> int:
    from ..hardware import hardware_procam as procam_mod
    from ..hardware.preflight import FAIL, format_report, preflight

    _load_remembered(args)
    with _hardware_procam(procam_mod.HardwareProCam, args) as procam:
        items = preflight(procam)
        command = _calibrate_command(args, procam)
    print(format_report(items))
    failed = [i.name for i in items if i.verdict == FAIL]
    print("fix the FAIL lines before calibrating" if failed else f"ready: {command}")
    return 1 if failed else 0


def _calibrate_command(args, procam) -> str:
    """The calibrate command for the mode that was checked: the size and format the camera
    delivered, and its controls locked (at the exposure that was locked, when one was)."""
    from ..hardware.remembered import calibrate_command

    n = procam.cam.negotiated or {}
    exposure = (procam.controls.exposure_s * 1e3 if procam.controls is not None
                and procam.controls.exposure_s else args.exposure)
    return calibrate_command(camera=args.camera, screen=args.screen,
                             camera_size=procam.camera_size, fourcc=n.get("fourcc") or args.fourcc,
                             lock=True, exposure_ms=round(exposure, 3) if exposure else None,
                             camera_backend=args.camera_backend)
