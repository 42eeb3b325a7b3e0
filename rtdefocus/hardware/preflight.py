"""``rtdefocus check``: seconds of checks before the minutes of calibration.

Opens the camera and the projector window exactly as calibration does
(:class:`rtdefocus.HardwareProCam`), shows white and black, and reports: the camera's
negotiated mode, the monitor the patterns go to, the projector-to-camera latency and the
settle time it implies, how many projector pixels a camera pixel covers, white clipping,
the black level (ambient light), the contrast, and the exposure controls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OK, WARN, FAIL = "ok", "warn", "FAIL"


@dataclass
class Item:
    """One line of the pre-flight report."""

    name: str
    value: str
    verdict: str = OK
    advice: str = ""


def preflight(procam) -> list[Item]:
    """Run the checks on an open :class:`rtdefocus.HardwareProCam` (with a live camera)."""
    from ..imageio import to_grey

    items: list[Item] = []
    cam = procam.cam
    n = cam.negotiated
    items.append(Item("camera", cam.describe()))
    win = procam.window
    mon = getattr(win, "monitor_name", None)
    items.append(Item("projector", f"{procam.projector_size[0]}x{procam.projector_size[1]} at "
                      f"{getattr(win, 'refresh_rate', 60.0):.0f} Hz on screen {procam.screen}"
                      + (f" ({mon})" if mon else "")))
    if n.get("fps") and n["fps"] < 15:
        items.append(Item("camera rate", f"{n['fps']:.3g} fps", WARN,
                          "slow: try --fourcc MJPG (uncompressed formats are slow at large sizes)"))
    if procam.latency is not None:
        items.append(Item("latency", f"{procam.latency.seconds * 1e3:.0f} ms projector to camera; "
                          f"settle {procam.settle * 1e3:.0f} ms per pattern",
                          WARN if procam.latency.seconds > 0.5 else OK,
                          "a long delay (network camera, phone): calibration will be slow; a USB "
                          "camera is faster" if procam.latency.seconds > 0.5 else ""))
    if procam.pixel_ratio is not None:
        r = procam.pixel_ratio
        items.append(Item("resolution", f"one camera pixel covers {r:.2f} projector pixels",
                          WARN if r > 1.5 else OK,
                          "under-sampled blur: raise --camera-size (with --fourcc MJPG) or move "
                          "the camera closer" if r > 1.5 else ""))
    wp, hp = procam.projector_size
    white = procam.capture(np.full((hp, wp, 3), 255, np.uint8))
    black = procam.capture(np.zeros((hp, wp, 3), np.uint8))
    diff = to_grey(white) - to_grey(black)
    lit = diff > float(np.percentile(diff, 95)) / 3
    lit_px = white[lit]
    clipped = float((lit_px >= 254).any(axis=1).mean()) if lit_px.size else 0.0
    items.append(Item("white clipping", f"{clipped:.1%} of the projected area",
                      FAIL if clipped > 0.05 else WARN if clipped > 0.005 else OK,
                      "lower the camera's exposure (--lock --exposure MS) or the projector's "
                      "brightness until no white pixel reaches 255" if clipped > 0.005 else ""))
    level_black = float(np.median(to_grey(black)[lit])) if lit.any() else 0.0
    contrast = float(np.median(diff[lit])) if lit.any() else 0.0
    items.append(Item("black level", f"{level_black:.0f} of 255 (ambient light and projector black)",
                      WARN if level_black > 60 else OK,
                      "darken the room: close the blinds, switch off the lights"
                      if level_black > 60 else ""))
    items.append(Item("contrast", f"white − black {contrast:.0f} of 255",
                      FAIL if contrast < 30 else WARN if contrast < 80 else OK,
                      "too dim: raise the exposure, darken the room, check the lens cap and that "
                      "--screen is the projector and --camera the camera that films it (`rtdefocus "
                      "aim` shows its view live)" if contrast < 80 else ""))
    if procam.controls is not None:
        c = procam.controls
        items.append(Item("camera controls", c.summary(), OK if c.ok else WARN,
                          "" if c.ok else "set the rest in the camera's own tool"))
    else:
        items.append(Item("camera controls", "left to the camera (automatic exposure, white "
                          "balance and focus may change between patterns)", WARN,
                          "pass --lock (or lock them with v4l2-ctl / the camera's tool)"))
    return items


def format_report(items: list[Item]) -> str:
    width = max(len(i.name) for i in items)
    lines = []
    for i in items:
        lines.append(f"[{i.verdict:4s}] {i.name:{width}s}  {i.value}")
        if i.advice:
            lines.append(f"       {'':{width}s}  -> {i.advice}")
    return "\n".join(lines)
