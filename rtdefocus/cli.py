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
    """Read an image file as RGB uint8 (H, W, 3); the one place BGR is converted on input."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise RtDefocusError(f"cannot read image {str(path)!r}: missing file or unknown format "
                             "(PNG, JPEG, BMP, TIFF are supported)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def write_image(path: str | Path, rgb: np.ndarray) -> Path:
    """Write an RGB uint8 image (creating parent folders); the one place BGR is converted on output."""
    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arr = np.asarray(rgb)
    if arr.ndim == 3:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), arr):
        raise RtDefocusError(f"cannot write {str(path)!r}: check the folder and the extension")
    return path


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


# --------------------------------------------------------------------------- main
COMMANDS = [_add_info, _add_simulate]


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
