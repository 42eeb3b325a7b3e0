"""How fast the watcher sees and mends each change of the virtual set-up, in show seconds.

Per preset and change: a fresh virtual set-up with its oracle calibration (the camera's true
response added) plays moving content at 10 fps for 6 s (a pan of smooth aperiodic texture, a
cut to another texture at 2.5 s, a still from 4 s); the change happens at 1.0 s. The frames
go to the projector as they are (the watcher compares the camera's view with whatever frame
was shown). The watcher looks every 0.25 s of show time, synchronously (a simulated clock:
the residual report's own cost does not enter these figures). Columns: the show time from
the change to its detection, to the mend handed to the player, and to the model trusted again
(a look after the mend found it right); what the mend estimated; the error left against the
oracle calibration of the changed set-up in the quantity that changed; false alarms on an
unchanged set-up over 30 s of the same content.

    python tools/bench_watcher.py [--size 400x300] [preset ...]
"""

from __future__ import annotations

import argparse
import sys
import time

import cv2
import numpy as np

from rtdefocus import sim
from rtdefocus.watch import Watcher, camera_view, predict_proj

CHANGES = [
    ("room light +0.1", "set_light", None),
    ("projector 0.3° + 3 px", "bump", {"projector_yaw_deg": 0.3, "projector_shift_px": 3.0}),
    ("camera 4 px", "bump", {"camera_shift_px": 4.0}),
    ("blur radii ×1.15", "refocus", {"scale": 1.15}),
]
FPS = 10.0


def texture(size, seed, detail=2.0):
    w, h = size
    img = cv2.GaussianBlur(np.random.default_rng(seed).random((h, w + 160)).astype(np.float32),
                           (0, 0), detail)
    img = (img - img.min()) / (img.max() - img.min())
    return np.repeat((30 + 190 * img)[..., None], 3, axis=2).astype(np.uint8)


def content(size, i, fps=FPS, cut_s=2.5, still_s=4.0, period_s=6.0):
    """Frame ``i``: a pan (2 px a frame), a cut to another texture, then a still; repeating."""
    w, _ = size
    t = (i / fps) % period_s
    cycle = int((i / fps) // period_s)
    tex = texture(size, 2 * cycle + (t >= cut_s))
    x = int(2 * min(i % int(period_s * fps), int(still_s * fps))) % 160
    return np.ascontiguousarray(tex[:, x:x + w])


def setup(preset, size):
    w, h = size
    pc = sim.VirtualProCam(preset, projector_size=size, camera_size=(3 * w // 2, 3 * h // 2))
    calib = sim.oracle_calibration(pc)
    calib.camera_lut = np.tile(pc.truth.camera_response, (3, 1)).astype(np.float32)
    return pc, calib


def play(pc, calib, seconds, change=None, at=1.0, fps=FPS):
    """Play ``seconds`` of content through a synchronous watcher; apply ``change`` (kind,
    params) at ``at`` s. Returns the watcher."""
    clock = [0.0]
    w = Watcher(calib, camera_view(pc), clock=lambda: clock[0], threaded=False)
    for i in range(int(round(seconds * fps))):
        clock[0] = i / fps
        if change is not None and abs(clock[0] - at) < 0.5 / fps:
            kind, params = change
            getattr(pc, kind)(**params)
        w.poll()
        w.offer(content(pc.projector_size, i, fps))
    return w


def first(events, kind, action, after):
    return next((e for e in events if e.kind == kind and e.action == action and e.t >= after), None)


def error_left(kind, params, calib, oracle, stale):
    """The mended calibration's error in the quantity that changed (and the stale one's)."""
    if kind == "set_light":
        f = lambda c: abs(float(c.ambient_proj.mean()) - float(oracle.ambient_proj.mean()))  # noqa: E731
        return f"ambient {f(calib):.4f} (stale {f(stale):.4f})"
    if kind == "bump":
        wp, hp = oracle.projector_size
        xs, ys = np.meshgrid(np.linspace(0.15 * wp, 0.85 * wp, 6), np.linspace(0.2 * hp, 0.8 * hp, 4))
        f = lambda c: float(np.abs(c.cam_from_proj(xs, ys) - oracle.cam_from_proj(xs, ys)).max())  # noqa: E731
        return f"H max {f(calib):.2f} cam px (stale {f(stale):.2f})"
    # Focus: the forward model's blur against the oracle's, on fine content.
    frame = texture(oracle.projector_size, 99, detail=1.2)[:, :oracle.projector_size[0]]
    ref = predict_proj(oracle, frame)
    f = lambda c: float(np.sqrt(np.mean((predict_proj(c, frame) - ref) ** 2)))  # noqa: E731
    return f"blurred-frame RMS {f(calib):.4f} (stale {f(stale):.4f})"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("presets", nargs="*", default=["cubicle", "webcam_cubicle"])
    ap.add_argument("--size", default="400x300")
    ap.add_argument("--quiet-seconds", type=float, default=30.0)
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    print("| preset | change | detected after s | mended after s | cleared after s | estimate "
          "| error left vs oracle | pattern frames |")
    print("|---|---|---|---|---|---|---|---|")
    for preset in args.presets:
        t0 = time.perf_counter()
        pc, calib = setup(preset, size)
        w = play(pc, calib, args.quiet_seconds)
        n = sum(e.action == "detect" for e in w.events)
        print(f"| {preset} | unchanged, {args.quiet_seconds:g} s ({w.looks} looks) | {n} false alarms "
              f"| | | | | 0 |")
        for name, kind, params in CHANGES:
            pc, calib = setup(preset, size)
            if kind == "set_light":
                params = {"ambient": pc.ambient + 0.1}
            w = play(pc, calib, 6.0, (kind, params))
            oracle = sim.oracle_calibration(pc)
            want = {"set_light": "light", "bump": "geometry", "refocus": "focus"}[kind]
            det, mend = first(w.events, want, "detect", 1.0), first(w.events, want, "mend", 1.0)
            ok = first(w.events, want, "cleared", 1.0)
            cell = lambda e: f"{e.t - 1.0:.2f}" if e is not None else "—"  # noqa: E731
            est = {k: v for k, v in (mend.detail if mend else {}).items() if k != "rms"}
            others = [f"{e.kind} {e.action}" for e in w.events if e.kind != want]
            print(f"| {preset} | {name} | {cell(det)} | {cell(mend)} | {cell(ok)} | {est}"
                  f"{' + ' + ', '.join(others) if others else ''} "
                  f"| {error_left(kind, params, w.calib, oracle, calib)} "
                  f"| {sum(e.pattern_frames for e in w.events)} |")
        print(f"({preset}: {time.perf_counter() - t0:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
