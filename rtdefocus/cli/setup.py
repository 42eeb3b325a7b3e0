"""Subcommands that set a projector-camera up: ``info``, ``simulate``, ``calibrate``, ``check``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .. import __version__
from ..errors import RtDefocusError
from .common import Progress, parse_size, read_image, write_image

log = logging.getLogger("rtdefocus")


# --------------------------------------------------------------------------- info
def add_info(sub):
    p = sub.add_parser("info", help="list OpenCL platforms/devices and the OpenGL renderer")
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
    return 0


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
    p.add_argument("--screen", type=int, default=0, help="projector's monitor index (default 0)")
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
    p.add_argument("--planes", type=_planes, default="auto", metavar="auto|N",
                   help="number of flat surfaces (walls, ceiling) the projection covers; auto "
                   "(default) finds it from the lines' kinks")
    p.add_argument("--flat", dest="residual", action="store_false",
                   help="model each surface as an exact plane (no smooth residual for walls that "
                   "bow or sag a little)")
    p.set_defaults(func=cmd_calibrate)


def _planes(text: str):
    from ..calib.geometry.fit import check_planes_option
    from ..errors import InputError

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
    p.add_argument("--lock", action="store_true", help="lock exposure, white balance and focus, "
                   "sharpening off (read back; what could not be set is reported)")
    p.add_argument("--exposure", type=float, metavar="MS", help="exposure for --lock in "
                   "milliseconds, rounded to whole projector frame periods (default: auto's choice)")


def _hardware_procam(hw, args):
    """A HardwareProCam from the command line's camera options."""
    camera = int(args.camera) if str(args.camera).isdigit() else args.camera
    return hw(camera=camera, screen=args.screen, camera_size=args.camera_size, fourcc=args.fourcc,
              fps=args.fps, settle=args.settle, flush=args.flush, average=args.average,
              lock=args.lock, exposure=args.exposure / 1e3 if args.exposure else None)


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
    from ..calib.geometry.diagnostics import geometry_diagnostics
    from ..hardware import hardware_procam as procam_mod

    stages = args.stages or STAGES
    if args.sim is not None:
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
        procam = _hardware_procam(hw, args)
        source = f"camera {args.camera!r}, projector on screen {args.screen}"
    t0 = time.perf_counter()
    try:
        with Progress(args.quiet) as progress:
            calib = calibrate(procam, stages=stages, progress=progress, planes=args.planes,
                              residual=args.residual)
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
    print(f"wrote {out} (sections: {', '.join(calib.sections())})")
    print(f"wrote {picture} and {camera_picture}")
    return 0


# --------------------------------------------------------------------------- check
CHECK_EPILOG = """\
examples:
  rtdefocus check --camera 0 --screen 1                 the webcam and the second monitor
  rtdefocus check --camera 0 --screen 1 --camera-size 1920x1080 --fourcc MJPG --lock
shows white and black on the projector and reports, in seconds: the camera's negotiated mode,
the monitor, the projector-to-camera latency, the camera-to-projector pixel ratio, white
clipping, the black level, the contrast and the camera controls. Exit code 1 on a FAIL line.
"""


def add_check(sub):
    p = sub.add_parser("check", help="pre-flight of a real set-up before calibrating: camera mode, "
                       "monitor, latency, clipping, exposure", epilog=CHECK_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--camera", required=True, metavar="INDEX", help="camera index or stream URL")
    p.add_argument("--screen", type=int, default=0, help="projector's monitor index (default 0)")
    add_camera_options(p)
    p.set_defaults(func=cmd_check)


def cmd_check(args) -> int:
    from ..hardware import hardware_procam as procam_mod
    from ..hardware.preflight import FAIL, format_report, preflight

    with _hardware_procam(procam_mod.HardwareProCam, args) as procam:
        items = preflight(procam)
    print(format_report(items))
    failed = [i.name for i in items if i.verdict == FAIL]
    print("fix the FAIL lines before calibrating" if failed else
          f"ready: rtdefocus calibrate --camera {args.camera} --screen {args.screen} -o setup.npz")
    return 1 if failed else 0
