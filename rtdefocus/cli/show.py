"""Subcommands that show pictures through a calibration: ``warp``, ``play``."""

from __future__ import annotations

import argparse
import logging
import sys

from .common import parse_size, read_image, write_image
from .setup import add_camera_options

log = logging.getLogger("rtdefocus")


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


def add_warp(sub):
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
    from ..calib.file import Calibration
    from ..gl.warp import warp_image

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


def _brightness(text: str) -> str | float:
    """``--flatten`` brightness: ``auto`` or a positive number (camera linear light)."""
    if text == "auto":
        return text
    try:
        value = float(text)
        if not value > 0:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"brightness must be 'auto' or a positive number (e.g. 0.3); got {text!r}") from None
    return value


def add_play(sub):
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
    p.add_argument("--flatten", nargs="?", const="auto", type=_brightness, metavar="BRIGHTNESS",
                   help="show the input as on a uniform white wall (the calibration's albedo and "
                   "ambient); optional brightness, camera linear light (default auto)")
    p.add_argument("--psf-energy", type=float, metavar="E",
                   help="cut each kernel to the window holding this share of its energy, e.g. "
                   "0.999: faster solves, a slightly different blur model (default: as calibrated)")
    p.add_argument("--precondition", default="colour+spatial",
                   choices=("colour+spatial", "colour", "none"),
                   help="how the solver's steps are preconditioned (default colour+spatial: "
                   "the most picture per iteration; none: plain FISTA steps, for comparison)")
    p.add_argument("--iterations", type=int,
                   help="solver iterations per frame (default: adaptive in the window, the "
                   "Compensator's budget for files, until converged for slides)")
    p.add_argument("--stats", metavar="FILE", help="also write the run's statistics as JSON")
    p.add_argument("--cache", metavar="DIR", help="slide cache folder (default ~/.cache/rtdefocus)")
    p.add_argument("--no-cache", action="store_true", help="do not read or write the slide cache")
    add_camera_options(p, capture=False)
    p.add_argument("--overlay", action="store_true", help="start with the stats overlay on (key s)")
    p.add_argument("--sequential", action="store_true",
                   help="decode, compensate and encode one after another on one thread (for "
                   "comparison; default: decode and file encode on threads of their own)")
    p.set_defaults(func=cmd_play)


def cmd_play(args) -> int:
    from ..calib.file import Calibration
    from ..compensate.compensator import Compensator
    from ..stream import Player, open_sink, open_source

    calib = Calibration.load(args.calibration)
    flat = {} if args.flatten is None else {"surface": "flatten", "brightness": args.flatten}
    comp = Compensator(calib, backend=args.backend, method=args.method,
                       psf_energy=args.psf_energy, **flat,
                       precondition=None if args.precondition == "none" else args.precondition)
    bar = None
    with open_source(args.source, camera_size=args.camera_size, fourcc=args.fourcc,
                     camera_fps=args.camera_fps) as source:
        with open_sink(args.out, fps=args.fps or source.fps, screen=args.screen,
                       fullscreen=args.windowed is None, window_size=args.windowed,
                       expect_size=calib.projector_size) as sink:
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
                            cache=cache, progress=progress, overlay=args.overlay,
                            threads=not args.sequential)
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
