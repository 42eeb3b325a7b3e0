"""The ``rtdefocus`` command (also ``python -m rtdefocus``).

Exit codes: 0 ok, 1 failure (a clear message, no traceback unless -v), 2 usage.
Sizes are written ``WIDTHxHEIGHT`` (e.g. ``800x600``).

Each subcommand is a pair: ``_add_NAME(subparsers)`` declares it, ``cmd_NAME(args)`` runs it;
register both in ``COMMANDS`` below. The subcommands live by what they are for:
:mod:`.setup` (info, simulate, calibrate, check), :mod:`.show` (warp, play), :mod:`.render`
(render), :mod:`.study` (demo, eval); shared helpers in :mod:`.common`.
"""

from __future__ import annotations

import argparse
import logging
import sys

from .. import __version__
from ..errors import RtDefocusError
from .common import parse_size, read_image, write_image
from .render import add_render
from .setup import add_aim, add_calibrate, add_cameras, add_check, add_info, add_simulate
from .show import add_play, add_warp
from .study import add_demo, add_eval, eval_options

__all__ = ["main", "build_parser", "COMMANDS", "parse_size", "read_image", "write_image",
           "eval_options"]

EPILOG = """\
examples:
  rtdefocus info                                   list OpenCL devices and the GL renderer
  rtdefocus cameras                                list cameras: index, name, backend
  rtdefocus simulate --scene cubicle --pattern checker -o out.png
  rtdefocus calibrate --sim cubicle -o setup.npz   calibrate the built-in virtual cubicle
  rtdefocus aim --camera 0 --screen 1              aim the camera, focus the projector (preview)
  rtdefocus check --camera 0 --screen 1            pre-flight of a real camera and projector
  rtdefocus warp setup.npz photo.jpg -o warped.png
  rtdefocus demo -o demo_out                       the whole story on the virtual cubicle
  rtdefocus eval --quick                           ablations: methods x kernel layouts, convergence
  rtdefocus play setup.npz talk/ --screen 1        slides on the projector (also video, camera:0)
  rtdefocus render setup.npz film.mp4 -o out.mp4   the film compensated once, for any player
"""


# --------------------------------------------------------------------------- main
COMMANDS = [add_info, add_cameras, add_aim, add_simulate, add_calibrate, add_warp, add_play,
            add_check, add_demo, add_eval, add_render]


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
