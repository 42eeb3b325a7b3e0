"""The ``render`` subcommand: a film compensated once into a file for any media player."""

from __future__ import annotations

import argparse
import sys

RENDER_EPILOG = """\
The output is the projector's framebuffer (the calibrated size) at the film's frame rate, with
the film's sound copied unchanged: play it full-screen on the projector with any player.
Finished chunks are kept in the work folder (default OUT.render/): run the same command again
after a stop and it carries on where it stopped.
qualities:
  high        H.264 High 4:4:4, crf 4 (default; .mp4, .mkv, .mov)
  compatible  H.264 4:2:0, crf 12, for players that decode nothing else
  archive     FFV1 lossless RGB (.mkv)
examples:
  rtdefocus render setup.npz film.mp4 -o film_corner.mp4                  2 local workers
  rtdefocus render setup.npz film.mp4 -o film_corner.mkv --quality archive
  rtdefocus render setup.npz film.mp4 -o film_corner.mp4 --scheduler tcp://head:8786
"""


def add_render(sub):
    from ..film.runner import DEFAULT_CHUNK_FRAMES, DEFAULT_OVERLAP, RENDER_ITERATIONS

    p = sub.add_parser("render", help="compensate a film once, at the full budget, into a video "
                       "file (chunks in parallel, resumable)", epilog=RENDER_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("calibration", help="the set-up file from `rtdefocus calibrate` (.npz)")
    p.add_argument("film", help="the film: any video file FFmpeg reads, with or without sound")
    p.add_argument("-o", "--output", required=True, help="output video (.mp4, .mkv, .mov)")
    p.add_argument("--quality", default="high", choices=("high", "compatible", "archive"),
                   help="encoding (default high; see below)")
    p.add_argument("--crf", type=int, metavar="N",
                   help="H.264 constant rate factor instead of the quality's (lower: closer to the "
                   "uncompressed frames, larger files)")
    p.add_argument("--workers", type=int, default=2,
                   help="local worker processes, each with its own device (default 2; 0: this "
                   "process)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the chunks on a Dask cluster instead, e.g. tcp://head:8786 (every "
                   "worker must read the set-up and film and write the work folder at the same "
                   "paths)")
    p.add_argument("--chunk-frames", type=int, default=DEFAULT_CHUNK_FRAMES,
                   help=f"frames per chunk (default {DEFAULT_CHUNK_FRAMES})")
    p.add_argument("--overlap", type=int, default=DEFAULT_OVERLAP,
                   help=f"frames solved before each chunk and thrown away (default "
                   f"{DEFAULT_OVERLAP})")
    p.add_argument("--iterations", type=int, default=RENDER_ITERATIONS,
                   help=f"solver iterations per frame (default {RENDER_ITERATIONS})")
    p.add_argument("--method", default="ycbcr", choices=("ycbcr", "rgb", "wiener", "none"))
    p.add_argument("--backend", default="auto", choices=("auto", "opencl", "numpy"))
    p.add_argument("--work", metavar="DIR", help="work folder for the chunks (default OUT.render)")
    p.add_argument("--keep-work", action="store_true",
                   help="keep the chunk files after the output is written")
    p.set_defaults(func=cmd_render)


def cmd_render(args) -> int:
    from ..film import render

    bar = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if args.quiet:
            return
        if bar is None:
            from tqdm import tqdm

            # initial: the frames of chunks resumed from the work folder (not in the rate)
            bar = tqdm(total=total, initial=done, unit="frame", desc="render", dynamic_ncols=True)
            return
        bar.update(done - bar.n)

    try:
        result = render(args.calibration, args.film, args.output, quality=args.quality,
                        crf=args.crf, workers=args.workers, scheduler=args.scheduler,
                        chunk_frames=args.chunk_frames, overlap=args.overlap,
                        iterations=args.iterations, method=args.method, backend=args.backend,
                        work=args.work, keep_work=args.keep_work, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        resumed = f", {len(result.resumed)} resumed from {result.work}" if result.resumed else ""
        print(f"wrote {result.output}: {result.frames} frames at {result.fps:.3g} fps, "
              f"{result.chunks} chunks ({len(result.rendered)} rendered{resumed}) in "
              f"{result.seconds:.1f} s", file=sys.stdout)
    return 0
