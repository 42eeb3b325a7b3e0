"""The ``rtdefocus`` command (also ``python -m rtdefocus``).

Exit codes: 0 ok, 1 failure (a clear message, no traceback unless -v), 2 usage.
Sizes are written ``WIDTHxHEIGHT`` (e.g. ``800x600``).

Each subcommand is a pair: ``_add_NAME(subparsers)`` declares it, ``cmd_NAME(args)`` runs it;
register both in ``COMMANDS`` at the bottom.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

from . import __version__
from .errors import RtDefocusError

log = logging.getLogger("rtdefocus")

EPILOG = """\
examples:
  rtdefocus info                                   list OpenCL devices and the GL renderer
  rtdefocus simulate --scene cubicle --pattern checker -o out.png
  rtdefocus calibrate --sim cubicle -o setup.npz   calibrate the built-in virtual cubicle
  rtdefocus warp setup.npz photo.jpg -o warped.png
  rtdefocus demo -o demo_out                       the whole story on the virtual cubicle
  rtdefocus eval --quick                           ablations: methods x kernel layouts, convergence
  rtdefocus play setup.npz talk/ --screen 1        slides on the projector (also video, camera:0)
"""


def parse_size(text: str) -> tuple[int, int]:
    """``"800x600"`` -> ``(800, 600)`` (width, height)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"size must be WIDTHxHEIGHT with positive integers, e.g. 800x600; got {text!r}"
        ) from None
    return w, h


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file as RGB uint8 (H, W, 3) (see :func:`rtdefocus.imageio.read_image`)."""
    from .imageio import read_image as _read_image  # cv2 loads on first use: `--help` stays fast

    return _read_image(path)


def write_image(path: str | Path, rgb: np.ndarray) -> Path:
    """Write an RGB uint8 image, creating parent folders (see :func:`rtdefocus.imageio.write_image`)."""
    from .imageio import write_image as _write_image

    return _write_image(path, rgb)


class _Progress:
    """What the long commands show while they work: a tqdm bar per calibration stage, fed by
    the library's ``progress(stage, done, total)`` callback, and ``step(message)`` lines
    between them. Silent with ``-q``; ``close()`` (or ``with``) ends the open bar."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self._bar = None
        self._stage = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.quiet:
            return
        from tqdm import tqdm

        bar = self._bar
        # A new stage, or the same stage starting over (the next preset's calibration): new bar.
        if bar is None or stage != self._stage or done < bar.n:
            self.close()
            bar = self._bar = tqdm(total=max(total, done), desc=f"{stage:10s}", unit="capture",
                                   dynamic_ncols=True, leave=True)
            self._stage = stage
        bar.total = max(total, done)
        bar.update(done - bar.n)

    def step(self, message: str) -> None:
        self.close()
        if not self.quiet:
            print(message, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        self._bar, self._stage = None, None

    def __enter__(self) -> _Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --------------------------------------------------------------------------- info
def _add_info(sub):
    p = sub.add_parser("info", help="list OpenCL platforms/devices and the OpenGL renderer")
    p.set_defaults(func=cmd_info)


def cmd_info(args) -> int:
    from .cl.runtime import choose_device, list_devices
    from .errors import DeviceError
    from .gl.runtime import gl_available

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
    print("OpenGL (EGL offscreen):")
    print(f"   {renderer}" if ok else f"   unavailable: {renderer}")
    return 0


# --------------------------------------------------------------------------- simulate
def _add_simulate(sub):
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
    from . import sim

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
writes setup.npz and, next to it (or in --diagnostics DIR), setup_geometry.png: the camera view
with the detected lines, kinks, fold, the two planes and the 4:3 / 16:9 display rectangles.
"""


def _available_stages() -> tuple[str, ...]:
    """Calibration stages whose module is installed (geometry always)."""
    import importlib.util

    from .calib import STAGES
    return tuple(s for s in STAGES
                 if s == "geometry" or importlib.util.find_spec(f"rtdefocus.calib.{s}") is not None)


def _stages(text: str) -> tuple[str, ...]:
    from .calib import STAGES

    stages = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in stages if s not in STAGES]
    if bad or "geometry" not in stages:
        raise argparse.ArgumentTypeError(f"stages must include geometry and be among "
                                         f"{','.join(STAGES)}; got {text!r}")
    return stages


def _add_calibrate(sub):
    p = sub.add_parser("calibrate", help="calibrate a projector-camera set-up (virtual or real) "
                       "and write the calibration file", epilog=CALIBRATE_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--sim", metavar="PRESET", help="the built-in virtual set-up: cubicle, pillar, "
                     "flat, tilted or offcenter")
    src.add_argument("--camera", metavar="INDEX", help="a real camera (index or URL); the patterns "
                     "go full-screen to --screen")
    p.add_argument("--screen", type=int, default=0, help="projector's monitor index (default 0)")
    p.add_argument("-o", "--output", required=True, help="calibration file to write (.npz)")
    default = ",".join(_available_stages())
    p.add_argument("--stages", type=_stages, default=None,
                   help=f"comma-separated stages to run (default: {default})")
    p.add_argument("--seed", type=int, default=0, help="simulator noise seed (default 0)")
    p.add_argument("--noise", type=float, default=None,
                   help="simulator camera noise, fraction of full scale (default: the simulator's)")
    p.add_argument("--diagnostics", metavar="DIR",
                   help="folder for the diagnostics pictures (default: next to the output)")
    p.set_defaults(func=cmd_calibrate)


def cmd_calibrate(args) -> int:
    import time

    from . import procam as procam_mod
    from .calib import calibrate
    from .calib.geometry_diagnostics import geometry_diagnostics

    stages = args.stages or _available_stages()
    if args.sim is not None:
        from . import sim

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
        camera = int(args.camera) if str(args.camera).isdigit() else args.camera
        procam = hw(camera=camera, screen=args.screen)
        source = f"camera {args.camera!r}, projector on screen {args.screen}"
    t0 = time.perf_counter()
    try:
        with _Progress(args.quiet) as progress:
            calib = calibrate(procam, stages=stages, progress=progress)
    finally:
        if hasattr(procam, "close"):
            procam.close()
    seconds = time.perf_counter() - t0
    out = calib.save(args.output)
    diag_dir = Path(args.diagnostics) if args.diagnostics else out.parent
    picture = write_image(diag_dir / f"{out.stem}_geometry.png", geometry_diagnostics(calib))
    g = calib.meta.get("geometry", {})
    rms = ", ".join(f"{v:.3f}" for v in g.get("rms_px", []))
    print(f"calibrated {source} in {seconds:.1f} s, {sum(calib.meta.get('captures', {}).values())} "
          f"captures {calib.meta.get('captures', {})}")
    fold = (f", fold disagreement {g['fold_disagreement_px']:.3f} projector px"
            if g.get("fold_disagreement_px") is not None else "")
    print(f"geometry: {calib.n_planes} plane(s), reprojection RMS {rms} camera px{fold}, "
          f"{g.get('lines_found')} of {g.get('lines_expected')} lines")
    print(f"wrote {out} (sections: {', '.join(calib.sections())})")
    print(f"wrote {picture}")
    return 0


# --------------------------------------------------------------------------- warp
def _fraction(text: str) -> float:
    try:
        value = float(text)
        if not 0.0 <= value < 0.5:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(f"margin must be a fraction in [0, 0.5), e.g. 0.05; "
                                         f"got {text!r}") from None
    return value


def _add_warp(sub):
    p = sub.add_parser(
        "warp", help="geometry-correct an image for the projector with a calibration",
        description="Warp IMAGE into projector space so that, projected, it appears upright and "
        "undistorted in the largest rectangle of its aspect the projector lights (the display "
        "rect, in camera pixels), stitched across the fold. Geometry only, no defocus "
        "compensation.",
        epilog="example:\n  rtdefocus warp setup.npz photo.jpg -o warped.png --margin 0.05",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("calibration", help="calibration file (.npz) from `rtdefocus calibrate`")
    p.add_argument("image", help="input image, any size (PNG, JPEG, ...)")
    p.add_argument("-o", "--output", required=True, help="output image (projector-sized PNG)")
    p.add_argument("--margin", type=_fraction, default=0.0,
                   help="shrink the display rect by this fraction (default 0)")
    p.add_argument("--backend", choices=("auto", "gl", "cv2"), default="auto",
                   help="gl: OpenGL shader; cv2: the reference; auto (default): gl when EGL works")
    p.set_defaults(func=cmd_warp)


def cmd_warp(args) -> int:
    from .calib.file import Calibration
    from .gl.warp import warp_image

    calib = Calibration.load(args.calibration)
    image = read_image(args.image)
    h, w = image.shape[:2]
    rect = calib.display_rect((w, h), margin=args.margin)
    print(f"display rect (camera px): x={rect[0]} y={rect[1]} w={rect[2]} h={rect[3]} "
          f"for the {w}x{h} input")
    out = write_image(args.output, warp_image(calib, image, rect=rect, backend=args.backend))
    wp, hp = calib.projector_size
    print(f"wrote {out} ({wp}x{hp} projector frame, {calib.n_planes} plane(s))")
    return 0


# --------------------------------------------------------------------------- play
PLAY_EPILOG = """\
SOURCE is an image, a folder of images (slides, natural order: 2 before 10), a video file,
camera:INDEX (e.g. camera:0), camera:URL or a stream URL (rtsp://, http://...).
Without --out the frames go full-screen to monitor --screen, with keys:
  space pause   left/right previous/next slide   c compensation on/off (A/B)
  g geometry only   s stats overlay   q/Esc quit
examples:
  rtdefocus play setup.npz talk/ --screen 1                   slideshow on the projector
  rtdefocus play setup.npz camera:0 --screen 1 --fps 30       live camera feed
  rtdefocus play setup.npz clip.mp4 --out clip_comp.mp4       render a video file offline
  rtdefocus play setup.npz clip.mp4 --out null --stats s.json benchmark, statistics as JSON
"""


def _add_play(sub):
    p = sub.add_parser("play", help="stream a video, a camera or slides through the compensation to "
                       "the projector (or to files)", epilog=PLAY_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("calibration", help="the set-up file from `rtdefocus calibrate` (.npz)")
    p.add_argument("source", help="image | folder | video | camera:INDEX | camera:URL | URL")
    p.add_argument("--out", metavar="FILE|DIR", help="video file (.mp4, .avi), image (.png), folder "
                   "(numbered PNGs) or 'null'; default: full-screen window on --screen")
    p.add_argument("--screen", type=int, default=0, help="projector's monitor index (default 0)")
    p.add_argument("--windowed", type=parse_size, metavar="WxH",
                   help="a plain window of this size instead of full-screen (preview)")
    p.add_argument("--fps", type=float, help="target frame rate (default: the source's, else 30)")
    p.add_argument("--method", default="ycbcr", help="ycbcr (default) | rgb | wiener | none")
    p.add_argument("--backend", default="auto", choices=("auto", "opencl", "numpy"))
    p.add_argument("--iterations", type=int,
                   help="solver iterations per frame (default: adaptive in the window, the "
                   "Compensator's budget for files, until converged for slides)")
    p.add_argument("--stats", metavar="FILE", help="also write the run's statistics as JSON")
    p.add_argument("--cache", metavar="DIR", help="slide cache folder (default ~/.cache/rtdefocus)")
    p.add_argument("--no-cache", action="store_true", help="do not read or write the slide cache")
    p.add_argument("--camera-size", type=parse_size, metavar="WxH", help="camera resolution to ask for")
    p.add_argument("--overlay", action="store_true", help="start with the stats overlay on (key s)")
    p.set_defaults(func=cmd_play)


def cmd_play(args) -> int:
    from .calib.file import Calibration
    from .compensate.compensator import Compensator
    from .stream import Player, open_sink, open_source

    calib = Calibration.load(args.calibration)
    comp = Compensator(calib, backend=args.backend, method=args.method)
    bar = None
    with open_source(args.source, camera_size=args.camera_size) as source:
        with open_sink(args.out, fps=args.fps or source.fps, screen=args.screen,
                       fullscreen=args.windowed is None, window_size=args.windowed) as sink:
            progress = None
            if not sink.realtime and not args.quiet:
                from tqdm import tqdm

                bar = tqdm(total=source.n_frames, unit="frame", desc="play", dynamic_ncols=True)

                def progress(done, total):
                    if total is not None and bar.total != total:
                        bar.total = total
                    bar.update(done - bar.n)
            cache = None if args.no_cache else (args.cache or True)
            player = Player(comp, source, sink, fps=args.fps, iterations=args.iterations,
                            cache=cache, progress=progress, overlay=args.overlay)
            try:
                player.run()
            except KeyboardInterrupt:  # Ctrl+C ends a live show; the summary still counts
                print("interrupted", file=sys.stderr)
            finally:
                if bar is not None:
                    bar.close()
    stats = player.stats
    print(stats.summary())
    if args.stats:
        print(f"wrote {stats.write_json(args.stats)}")
    return 0



# --------------------------------------------------------------------------- demo
def _add_demo(sub):
    p = sub.add_parser("demo", help="the whole story on the built-in virtual cubicle: calibrate, "
                       "compensate photographs and a text slide, write pictures and a table")
    p.add_argument("-o", "--output", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--scene", default="cubicle", help="simulator preset (default cubicle)")
    p.add_argument("--methods", default="ycbcr,rgb,wiener",
                   help="compensation methods compared with geometry only (default ycbcr,rgb,wiener)")
    p.add_argument("--seed", type=int, default=0, help="simulator noise seed (default 0)")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args) -> int:
    import time

    from .demo import run_demo

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    t0 = time.perf_counter()
    with _Progress(args.quiet) as progress:
        result = run_demo(args.output, preset=args.scene, methods=methods, seed=args.seed,
                          progress=progress, step=progress.step)
    print()
    print(result["markdown"])
    print(f"backend: {result['backend']}; done in {time.perf_counter() - t0:.0f} s. Files:")
    for f in result["files"]:
        print(f"  {f}")
    return 0


# --------------------------------------------------------------------------- eval
EVAL_EPILOG = """\
examples:
  rtdefocus eval -o eval_out         3 presets x 5 images x 3 methods x 4 layouts + oracle, 800x600
  rtdefocus eval --quick             cubicle; chelsea and text; 400x300 (about half a minute)
  rtdefocus eval --presets pillar --layouts default,cross_fold --methods ycbcr --size 400x300
writes into the folder: eval.md (tables: PSNR/SSIM per image, method and layout, and the mean
gain over geometry only), eval.json (every score) and convergence.png (distance and PSNR vs
iteration and time, FISTA and PG, OpenCL and NumPy, on cubicle/chelsea).
video (--video): a moving clip from the photographs (still, slow pan 3 px/frame, fast pan
14 px/frame, cut, zoom 2 %/frame, fade) through compensate() frame by frame at fixed budgets
(--budgets, warm and cold starts), wall-clock budgets (--fps) and the offline ceiling; writes
video.md (gain over geometry only per segment, share of the offline gain, still after 1 s,
frames to recover after the cut), video.json and video.png (per-frame gain). Examples:
  rtdefocus eval --video -o video_out            800x600 cubicle, 78 frames (a few minutes)
  rtdefocus eval --video --quick                 400x300, 30 frames (under a minute)
  rtdefocus eval --video --calibration cubicle.npz   calibrated instead of the oracle kernels
layouts: default | paper (corners + fold, as the paper) | dense (grid) | cross_fold (blended
across the fold: the geometry-blind baseline); the oracle (the simulator's true calibration) is
the upper bound, --no-oracle leaves it out.
"""


def _names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated names, e.g. a,b; got {text!r}")
    return names


def _add_eval(sub):
    p = sub.add_parser("eval", help="ablations on the virtual set-ups: presets x images x methods "
                       "x kernel layouts (and the oracle), with a convergence plot",
                       epilog=EVAL_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-o", "--output", default="eval_out", help="output folder (default eval_out)")
    p.add_argument("--presets", type=_names, help="simulator presets (default cubicle,tilted,pillar)")
    p.add_argument("--images", type=_names, help="among chelsea,coffee,astronaut,rocket,text "
                   "(default all)")
    p.add_argument("--methods", type=_names, help="among ycbcr,rgb,wiener (default all three); "
                   "geometry only is always scored")
    p.add_argument("--layouts", type=_names, help="kernel layouts among default,paper,dense,"
                   "cross_fold (default all four)")
    p.add_argument("--no-oracle", action="store_true", help="leave out the oracle calibration")
    p.add_argument("--size", type=parse_size, metavar="WxH",
                   help="projector size (default 800x600); the camera gets 1.6x unless --camera-size")
    p.add_argument("--camera-size", type=parse_size, metavar="WxH", help="camera size")
    p.add_argument("--numpy-iterations", type=int, metavar="N",
                   help="iterations of the (slow) NumPy convergence curves; 0 leaves them out "
                   "(default 2)")
    p.add_argument("--no-convergence", action="store_true", help="skip the convergence plot")
    p.add_argument("--seed", type=int, default=0, help="simulator noise seed (default 0)")
    p.add_argument("--quick", action="store_true", help="one preset (cubicle), two images (chelsea, "
                   "text), 400x300: a check that runs in about half a minute")
    v = p.add_argument_group("video (--video)")
    v.add_argument("--video", action="store_true", help="the real-time path on a moving clip "
                   "instead of the ablations (see below)")
    v.add_argument("--budgets", default=None, metavar="N,N",
                   help="fixed iterations per frame, each warm and cold (default 1,2,4,8)")
    v.add_argument("--fps", default=None, metavar="F,F",
                   help="wall-clock budgets in frames per second (default 24,30,60)")
    v.add_argument("--offline-iterations", type=int, default=None, metavar="N",
                   help="cold iterations per frame of the offline ceiling (default 40)")
    v.add_argument("--calibration", metavar="FILE", help="a calibration file for the preset and "
                   "size instead of the simulator's oracle kernels")
    v.add_argument("--preset", default="cubicle", help="simulator preset (default cubicle)")
    v.add_argument("--no-plot", action="store_true", help="skip video.png")
    p.set_defaults(func=cmd_eval)


def _eval_options(args) -> dict:
    """``run_eval`` keyword arguments from the command line: ``--quick`` first, then whatever
    was given explicitly."""
    from .eval import QUICK

    opts: dict = dict(QUICK) if args.quick else {}
    given = {"presets": args.presets, "images": args.images, "methods": args.methods,
             "layouts": args.layouts, "projector_size": args.size,
             "camera_size": args.camera_size, "numpy_iterations": args.numpy_iterations}
    if args.size is not None and args.camera_size is None:
        opts.pop("camera_size", None)          # run_eval scales the camera with the projector
    opts.update({k: v for k, v in given.items() if v is not None})
    opts["oracle"] = not args.no_oracle
    opts["seed"] = args.seed
    if args.no_convergence:
        opts["convergence"] = None
    return opts


def _numbers(text: str | None, kind):
    if text is None:
        return None
    try:
        return tuple(kind(t) for t in text.split(",") if t.strip())
    except ValueError as exc:
        raise RtDefocusError(f"expected comma-separated numbers, e.g. 1,2,4; got {text!r}") from exc


def cmd_eval_video(args) -> int:
    from .eval_video import run_video_eval

    opts = {"quick": args.quick, "projector_size": args.size, "camera_size": args.camera_size,
            "preset": args.preset, "calibration": args.calibration, "seed": args.seed,
            "plot": not args.no_plot}
    for key, val in (("budgets", _numbers(args.budgets, int)), ("fps", _numbers(args.fps, float)),
                     ("offline", args.offline_iterations)):
        if val is not None:
            opts[key] = val
    with _Progress(args.quiet) as progress:
        result = run_video_eval(args.output, step=progress.step, **opts)
    print()
    print(result["markdown"].rstrip())
    print("\nFiles:")
    for f in result["files"]:
        print(f"  {f}")
    return 0


def cmd_eval(args) -> int:
    if args.video:
        return cmd_eval_video(args)
    from .eval import run_eval

    with _Progress(args.quiet) as progress:
        result = run_eval(args.output, progress=progress, step=progress.step, **_eval_options(args))
    # The summary; the per-preset tables are wide: they are in eval.md.
    parts = result["markdown"].split("\n## ")
    print()
    print("\n## ".join(parts[:2]).rstrip())
    print(f"\ndone in {result['seconds']:.0f} s; per-preset tables in eval.md. Files:")
    for f in result["files"]:
        print(f"  {f}")
    return 0


# --------------------------------------------------------------------------- main
COMMANDS = [_add_info, _add_simulate, _add_calibrate, _add_warp, _add_play, _add_demo, _add_eval]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rtdefocus", description="Real-time projector defocus and geometry compensation "
        "for two-wall corners.", epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"rtdefocus {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    parser.add_argument("-q", "--quiet", action="store_true", help="errors only")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in COMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = (logging.ERROR if args.quiet else logging.WARNING if not args.verbose
             else logging.INFO if args.verbose == 1 else logging.DEBUG)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except RtDefocusError as exc:
        if args.verbose:
            raise
        print(f"rtdefocus {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 1
