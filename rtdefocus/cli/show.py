"""Subcommands that show pictures through a calibration: ``warp``, ``play``."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

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
SOURCE is an image, a PDF (one slide per page), a folder of images and PDFs (slides, natural
order: 2 before 10), a video file, a folder that also holds videos (a playlist, in name order),
camera:INDEX (e.g. camera:0), camera:URL, a stream URL (rtsp://, http://...), screen:INDEX (a
monitor, grabbed live) or window:TITLE (a window, by part of its title).
Without --out the frames go full-screen to monitor --screen, with keys:
  space pause   left/right previous/next slide   c compensation on/off (A/B)
  g geometry only   s stats overlay   q/Esc quit
Videos play with their sound, kept in step by the sound card's clock (--no-audio: silent).
At the end the projector stays black until a key (--exit-at-end: leave; --loop: start again).
examples:
  rtdefocus play setup.npz talk/ --screen 1                   slideshow on the projector
  rtdefocus play setup.npz deck.pdf --screen 1 --margin 0.03  a PDF deck, 3 % black margin
  rtdefocus play setup.npz window:Impress --screen 1          another program's window
  rtdefocus play setup.npz show/ --screen 1 --loop            a playlist, over and over
  rtdefocus play setup.npz camera:0 --screen 1 --fps 30       live camera feed
  rtdefocus play setup.npz clip.mp4 --out clip_comp.mp4       render a video file offline
  rtdefocus play setup.npz clip.mp4 --out null --stats s.json benchmark, statistics as JSON
  rtdefocus play sim.npz clip.mp4 --out null --watch --sim cubicle --sim-event 2:refocus:scale=1.15
                                                             watch the virtual set-up change
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
    p.add_argument("source", help="image | PDF | folder | video | camera:INDEX | camera:URL | URL | "
                   "screen:INDEX | window:TITLE")
    p.add_argument("--out", metavar="FILE|DIR", help="video file (.mp4, .avi), image (.png), folder "
                   "(numbered PNGs) or 'null'; default: full-screen window on --screen")
    p.add_argument("--screen", type=int, default=None, help="projector's monitor index (default: "
                   "the monitor the calibration remembers, else the second of two, else 0)")
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
    p.add_argument("--cache", metavar="DIR", help="slide cache folder (default: "
                   "$RTDEFOCUS_CACHE, else the user cache folder, e.g. ~/.cache/rtdefocus)")
    p.add_argument("--no-cache", action="store_true", help="do not read or write the slide cache")
    add_camera_options(p, capture=False)
    p.add_argument("--overlay", action="store_true", help="start with the stats overlay on (key s)")
    p.add_argument("--preview", nargs="?", const=(480, 330), type=parse_size, metavar="WxH",
                   help="an operator's window on the laptop: what the projector shows, with fps, "
                   "iterations and frames shown with geometry only (default size 480x330)")
    p.add_argument("--loop", action="store_true", help="start again after the last item (window only)")
    p.add_argument("--exit-at-end", action="store_true",
                   help="leave at the end instead of holding a black projector until a key")
    p.add_argument("--fit", choices=("contain", "cover"),
                   help="place the content in the projector's frame: whole with black bars "
                   "(contain) or filling it, cropped (cover); default: the largest area of the "
                   "content's own aspect")
    p.add_argument("--margin", metavar="M",
                   help="black margin around the content: a fraction of the frame (0.05) or "
                   "projector pixels (40px); implies --fit contain unless --fit is given")
    p.add_argument("--no-audio", action="store_true", help="play videos without sound")
    p.add_argument("--sequential", action="store_true",
                   help="decode, compensate and encode one after another on one thread (for "
                   "comparison; default: decode and file encode on threads of their own)")
    w = p.add_argument_group("watching the show (the camera checks the calibration as it plays)")
    w.add_argument("--watch", action="store_true",
                   help="look at the wall a few times a second and mend the calibration when the "
                   "room light, the geometry or the focus changed (frames show geometry only "
                   "until mended)")
    w.add_argument("--save-updates", action="store_true",
                   help="with --watch: save the mended calibration beside the original as "
                   "NAME.watched.npz (the original is never touched)")
    w.add_argument("--watch-period", type=float, default=None, metavar="S",
                   help="seconds of show time between looks while the set-up is right (default "
                   "0.25 with --sim; on hardware 0.8, with a look again 0.1 s after one that "
                   "sees a change: under 10 %% of a 30 fps show's time, a change confirmed "
                   "within about a second)")
    w.add_argument("--watch-camera", metavar="CAMERA",
                   help="with --watch on hardware: the camera that watches the show's window, an "
                   "index or a URL (default: the one the calibration remembers, else 0)")
    w.add_argument("--sim", metavar="PRESET",
                   help="with --watch: the camera watches the built-in virtual set-up PRESET "
                   "(of the calibration's sizes) instead of hardware")
    w.add_argument("--sim-event", action="append", default=[], metavar="T:KIND:NAME=V[,NAME=V]",
                   help="with --sim: change the virtual set-up at show time T s, e.g. "
                   "2:bump:projector_shift_px=3 or 4:set_light:ambient=0.2 or 6:refocus:scale=1.15 "
                   "(repeatable)")
    p.set_defaults(func=cmd_play)


def _sim_events(texts: list[str]) -> list:
    """``--sim-event`` values as timeline events ``(t, kind, params)``."""
    from ..errors import InputError

    events = []
    for text in texts:
        try:
            t, kind, params = text.split(":", 2)
            values = dict(kv.split("=", 1) for kv in params.split(",") if kv)
            events.append((float(t), kind, {k: float(v) for k, v in values.items()}))
        except ValueError:
            raise InputError(f"--sim-event must be T:KIND:NAME=VALUE[,NAME=VALUE], e.g. "
                             f"2:bump:projector_shift_px=3; got {text!r}") from None
    return events


def _watcher(args, calib):
    """The Watcher of ``--watch`` (None without it)."""
    from ..errors import InputError

    if not args.watch:
        if args.save_updates or args.sim or args.sim_event or args.watch_camera is not None:
            raise InputError("--save-updates, --watch-camera, --sim and --sim-event go with --watch")
        return None
    if not args.sim:
        if args.sim_event:
            raise InputError("--sim-event goes with --sim PRESET")
        if args.out is not None:
            raise InputError("--watch on hardware watches the show's own window: leave out --out "
                             "(or use --sim PRESET to watch the virtual set-up)")
        return None                  # built on the show's window (_hardware_watcher)
    if args.watch_camera is not None:
        raise InputError("--watch-camera is the hardware camera; leave it out with --sim")
    from .. import sim
    from ..watch import Watcher
    from ..watch.session import FrameClock, timeline_view

    procam = sim.VirtualProCam(args.sim, projector_size=tuple(calib.projector_size),
                               camera_size=tuple(calib.camera_size))
    clock = FrameClock(args.fps or 30.0)
    look = timeline_view(procam, sim.Timeline(_sim_events(args.sim_event)), clock)
    # Show time by frame count: a render to a file is watched at the show's own pace, and
    # deterministically (looks on the frame loop's thread; a window gets a thread of its own).
    period = 0.25 if args.watch_period is None else args.watch_period
    return Watcher(calib, look, period_s=period, clock=clock, threaded=False)


#: Seconds between looks on hardware while the set-up is right, and after a look that sees a
#: change: the report's CPU time over the period stays under 10 % of a 30 fps show's time
#: (docs/performance.md, "Watching the show: the report's cost").
HARDWARE_LOOK_PERIOD, HARDWARE_RECHECK = 0.8, 0.1


def _hardware_watcher(args, calib, sink):
    """``--watch`` on hardware: the camera watches the show's own window, looks taken by time
    with the latency the calibration measured. Returns (Watcher, HardwareProCam)."""
    from ..errors import InputError
    from ..hardware import hardware_procam as procam_mod
    from ..hardware import remembered as rem
    from ..watch import BurstOptions, Watcher, camera_view

    window = getattr(sink, "window", None)
    if window is None:
        raise InputError("--watch on hardware watches the show's own window: leave out --out and "
                         "--preview (or use --sim PRESET to watch the virtual set-up)")
    camera = args.watch_camera
    backend = "auto"
    if camera is None:
        record = rem.remembered(calib).get("camera") or {}
        camera, backend = (rem.resolve_camera(None, record, None) if record.get("index") is not None
                           else (0, "auto"))
    elif str(camera).isdigit():
        camera = int(camera)
    procam = procam_mod.HardwareProCam(camera, window=window, camera_size=tuple(calib.camera_size),
                                       latency=rem.remembered_latency(calib),
                                       camera_backend=backend)
    if tuple(procam.camera_size) != tuple(calib.camera_size):
        procam.close()
        raise InputError(f"the watching camera gives {procam.camera_size[0]}x{procam.camera_size[1]} "
                         f"frames; the calibration's camera was {calib.camera_size[0]}x"
                         f"{calib.camera_size[1]}: use the calibration's camera (--watch-camera)")
    # Threaded on the perf_counter clock: a look's picture is paired with the frame that was
    # on the wall when the camera saw it (HardwareProCam.looked_at).
    period = HARDWARE_LOOK_PERIOD if args.watch_period is None else args.watch_period
    # A burst's patterns are held until the camera sees them (the measured latency).
    bursts = BurstOptions.for_latency(procam.latency_s, args.fps or 30.0)
    return Watcher(calib, camera_view(procam), period_s=period, threaded=True,
                   recheck_s=min(period, HARDWARE_RECHECK), bursts=bursts), procam


def _screen(screen: int | None, calib) -> int:
    """The projector's monitor: ``--screen``, else the one the calibration remembers (which
    must be connected), else the second of two monitors, else 0."""
    from ..hardware import remembered as rem

    monitors = rem.connected_monitors()
    if monitors is None:          # no display to ask: the window says what it finds
        return 0 if screen is None else screen
    record = rem.remembered(calib).get("monitor")
    if screen is None and not record:
        screen = rem.default_screen(monitors)
    return rem.resolve_screen(screen, monitors, record)


def _with_preview(sink, size):
    """``sink`` with the operator's preview window beside it (``--preview``), or as it is."""
    if size is None:
        return sink
    from ..errors import InputError

    if sink.kind != "window":
        raise InputError("--preview shows the projector's window on the laptop: leave out --out, "
                         "or leave out --preview when writing files")
    from ..gl.window import ProjectorWindow
    from ..stream.preview import PreviewSink

    window = ProjectorWindow(fullscreen=False, size=size, title="rtdefocus preview", vsync=False)
    return PreviewSink(sink, window)


def cmd_play(args) -> int:
    from ..calib.file import Calibration
    from ..compensate.compensator import Compensator
    from ..stream import Show, open_sink
    from ..stream.placement import Placement, parse_margin

    calib = Calibration.load(args.calibration)
    placement = None
    if args.fit or args.margin is not None:
        placement = Placement(tuple(calib.projector_size), args.fit or "contain",
                              parse_margin(args.margin) if args.margin is not None else 0.0)
    flat = {} if args.flatten is None else {"surface": "flatten", "brightness": args.flatten}
    watcher = _watcher(args, calib)
    comp = Compensator(calib, backend=args.backend, method=args.method,
                       psf_energy=args.psf_energy, **flat,
                       precondition=None if args.precondition == "none" else args.precondition)
    screen = (_screen(args.screen, calib) if args.out is None and args.windowed is None
              else (args.screen or 0))
    bar = None
    with open_sink(args.out, fps=args.fps, screen=screen,
                   fullscreen=args.windowed is None, window_size=args.windowed,
                   expect_size=calib.projector_size) as sink:
        progress = None
        if not sink.realtime and not args.quiet:
            from tqdm import tqdm

            def progress(done, total):     # the bar starts with the first frame (not before an error)
                nonlocal bar
                if bar is None:
                    bar = tqdm(total=total, unit="frame", desc="play", dynamic_ncols=True)
                if total is not None and bar.total != total:
                    bar.total = total
                bar.update(done - bar.n)
        cache = None if args.no_cache else (args.cache or True)
        shown = _with_preview(sink, args.preview)
        watch_procam = None
        if args.watch and not args.sim:
            watcher, watch_procam = _hardware_watcher(args, calib, sink)
        elif watcher is not None:
            watcher.threaded = sink.realtime     # a window's frames must not wait for a look
        show = Show(comp, args.source, shown, loop=args.loop, exit_at_end=args.exit_at_end,
                    placement=placement, audio=not args.no_audio,
                    source_options={"camera_size": args.camera_size, "fourcc": args.fourcc,
                                    "camera_fps": args.camera_fps,
                                    "camera_backend": args.camera_backend or "auto"},
                    fps=args.fps, iterations=args.iterations, cache=cache, progress=progress,
                    overlay=args.overlay, threads=not args.sequential, watcher=watcher)
        all_stats = []
        try:
            all_stats = show.run()
        except KeyboardInterrupt:  # Ctrl+C ends a live show; the summary still counts
            print("interrupted", file=sys.stderr)
            if show.player is not None:
                all_stats = [show.player.stats]
        finally:
            if bar is not None:
                bar.close()
            if shown is not sink:
                shown.close()
            if watcher is not None:
                watcher.close()
                _watch_summary(watcher, calib, args)
            if watch_procam is not None:
                watch_procam.close()
    for stats in all_stats:
        print(stats.summary())
    if args.stats and all_stats:
        print(f"wrote {_stats_json(all_stats, args.stats)}")
    return 0


def _watch_summary(watcher, calib, args) -> None:
    """What the watcher did; with --save-updates, the mended calibration saved beside the
    original (only when it changed)."""
    done = [e for e in watcher.events if e.action in ("detect", "mend", "give up")]
    print(f"watch: {watcher.looks} looks, {len(done)} events, {watcher.false_alarms} retracted, "
          f"{watcher.untrusted_frames} frames shown with geometry only until mended")
    for e in done:
        print(f"  {e.t:7.2f} s  {e.kind:8s} {e.action:7s} {e.detail}")
    if args.save_updates and watcher.calib is not calib:
        from ..watch.session import save_watched

        print(f"wrote {save_watched(watcher.calib, args.calibration)}")


def _stats_json(all_stats, path):
    """One item: its statistics; a playlist: ``{"items": [...]}``, one per item played."""
    if len(all_stats) == 1:
        return all_stats[0].write_json(path)
    import json

    path = Path(path)
    path.write_text(json.dumps({"items": [st.as_dict() for st in all_stats]}, indent=2))
    return path
