"""Subcommands that tell the story and measure it: ``demo``, ``eval``."""

from __future__ import annotations

import argparse
import logging

from ..errors import RtDefocusError
from .common import Progress, parse_size

log = logging.getLogger("rtdefocus")


# --------------------------------------------------------------------------- demo
def add_demo(sub):
    p = sub.add_parser("demo", help="the whole story on the built-in virtual cubicle: calibrate, "
                       "compensate photographs and a text slide, write pictures and a table")
    p.add_argument("-o", "--output", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--scene", default="cubicle", help="simulator preset (default cubicle)")
    p.add_argument("--methods", default="ycbcr,rgb,wiener",
                   help="compensation methods compared with geometry only (default ycbcr,rgb,wiener)")
    p.add_argument("--seed", type=int, default=0, help="simulator noise seed (default 0)")
    p.add_argument("--surfaces", action="store_true",
                   help="also the coloured, textured 'fabric' walls: geometry only | defocus only "
                        "| defocus + flatten | sharp on a white wall, and uniformity figures")
    p.add_argument("--rooms", default="corner_ceiling", type=_room_names,
                   help="set-ups of more than two planes also calibrated and shown, comma-"
                        "separated (u_cubicle, corner_ceiling; default corner_ceiling; 'none' "
                        "to skip)")
    p.set_defaults(func=cmd_demo)


def _room_names(text: str) -> tuple[str, ...]:
    from ..sim import PRESETS

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if names in ((), ("none",)):
        return ()
    bad = [n for n in names if n != "webcam" and n.removeprefix("webcam_") not in PRESETS]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown preset(s) {', '.join(bad)}; choose among "
                                         f"{', '.join(PRESETS)} or 'none'")
    return names


def cmd_demo(args) -> int:
    import time

    from ..study.demo import run_demo

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    t0 = time.perf_counter()
    with Progress(args.quiet) as progress:
        result = run_demo(args.output, preset=args.scene, methods=methods, seed=args.seed,
                          progress=progress, step=progress.step, surfaces=args.surfaces,
                          rooms=args.rooms)
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
drift (--drift): the clip (pans, a cut, stills) played frame by frame on a simulated clock while
the set-up changes: projector knocked 0.3 deg + 3 px, camera 4 px, room light +10 %, blur radii
x1.15, 8 s apart; rows: no watching, watching, an oracle re-calibrated at each event, geometry
only; writes drift.md (detection delay, recovery, pattern frames per event; false alarms of an
unchanged run), drift.json and drift.png (PSNR over time). Example:
  rtdefocus eval --drift --preset webcam_cubicle --size 400x300 --false-alarm-s 120 -o drift_out
layouts: default | paper (corners + fold, as the paper) | dense (grid) | cross_fold (blended
across the fold: the geometry-blind baseline); the oracle (the simulator's true calibration) is
the upper bound, --no-oracle leaves it out.
"""


def _names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated names, e.g. a,b; got {text!r}")
    return names


def add_eval(sub):
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
    v.add_argument("--slowdown", default=None, metavar="K,K",
                   help="device speeds of the window rows: 2 plays the window on a device that "
                   "compensates a frame 2x slower than this machine (default 1)")
    v.add_argument("--offline-iterations", type=int, default=None, metavar="N",
                   help="cold iterations per frame of the offline ceiling (default 40)")
    v.add_argument("--calibration", metavar="FILE", help="a calibration file for the preset and "
                   "size instead of the simulator's oracle kernels")
    v.add_argument("--preset", default="cubicle", help="simulator preset (default cubicle)")
    v.add_argument("--no-plot", action="store_true", help="skip video.png / drift.png")
    d = p.add_argument_group("drift (--drift)")
    d.add_argument("--drift", action="store_true", help="the show while the set-up changes: "
                   "no watching, watching and an oracle over a timeline of events (see below); "
                   "--preset, --size and --fps (one number, default 30) apply")
    d.add_argument("--false-alarm-s", type=float, default=120.0, metavar="S",
                   help="seconds of the unchanged set-up played to count false alarms (default "
                   "120; 0 leaves it out)")
    d.add_argument("--false-alarm-size", type=parse_size, metavar="WxH",
                   help="projector size of the false-alarm run (default --size)")
    d.add_argument("--separate", action="store_true", help="each event on a fresh set-up of its "
                   "own (2 s, the event, 8 s to recover) instead of one set-up changed event after "
                   "event")
    d.add_argument("--duration", type=float, metavar="S",
                   help="seconds of show (default: the last event + 8 s, 34 s)")
    d.add_argument("--score-every", type=int, default=1, metavar="N",
                   help="score every N-th frame, and every frame for --full-rate-s after each "
                   "event (default 1: all; 6 makes an 800x600 run affordable)")
    d.add_argument("--full-rate-s", type=float, default=2.0, metavar="S",
                   help="seconds after each event scored at full rate (default 2)")
    p.set_defaults(func=cmd_eval)


def eval_options(args) -> dict:
    """``run_eval`` keyword arguments from the command line: ``--quick`` first, then whatever
    was given explicitly."""
    from ..study.eval import QUICK

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
    from ..study.eval_video import run_video_eval

    opts = {"quick": args.quick, "projector_size": args.size, "camera_size": args.camera_size,
            "preset": args.preset, "calibration": args.calibration, "seed": args.seed,
            "plot": not args.no_plot}
    for key, val in (("budgets", _numbers(args.budgets, int)), ("fps", _numbers(args.fps, float)),
                     ("slowdown", _numbers(args.slowdown, float)),
                     ("offline", args.offline_iterations)):
        if val is not None:
            opts[key] = val
    with Progress(args.quiet) as progress:
        result = run_video_eval(args.output, step=progress.step, **opts)
    return _print_result(result)


def cmd_eval_drift(args) -> int:
    from ..study.eval_drift import run_drift_eval

    fps = _numbers(args.fps, float) or (30.0,)
    if len(fps) != 1:
        raise RtDefocusError(f"--drift plays at one frame rate; got --fps {args.fps}")
    with Progress(args.quiet) as progress:
        result = run_drift_eval(args.output, preset=args.preset, size=args.size or (800, 600),
                                camera_size=args.camera_size, fps=fps[0],
                                duration_s=args.duration, separate=args.separate,
                                false_alarm_s=args.false_alarm_s,
                                false_alarm_size=args.false_alarm_size, seed=args.seed,
                                score_every=args.score_every, full_rate_s=args.full_rate_s,
                                plot=not args.no_plot, step=progress.step)
    return _print_result(result)


def cmd_eval(args) -> int:
    if args.drift:
        return cmd_eval_drift(args)
    if args.video:
        return cmd_eval_video(args)
    from ..study.eval import run_eval

    with Progress(args.quiet) as progress:
        result = run_eval(args.output, progress=progress, step=progress.step, **eval_options(args))
    # The summary; the per-preset tables are wide: they are in eval.md.
    parts = result["markdown"].split("\n## ")
    print()
    print("\n## ".join(parts[:2]).rstrip())
    print(f"\ndone in {result['seconds']:.0f} s; per-preset tables in eval.md. Files:")
    for f in result["files"]:
        print(f"  {f}")
    return 0


def _print_result(result: dict) -> int:
    """The report's table and the files it wrote, on stdout (the tables are the output)."""
    print()
    print(result["markdown"].rstrip())
    print("\nFiles:")
    for f in result["files"]:
        print(f"  {f}")
    return 0
