"""What the residual report reads after each change of the virtual set-up, and what it costs.

Two tables, at 800x600 (camera 1280x960):

``accuracy`` (per preset): a fresh set-up with its oracle calibration (the camera's true
response added), smooth aperiodic content (Gaussian-smoothed noise, σ 3 px); one change per
row, on a fresh set-up each, against the unchanged calibration. "true" is the content's mean
motion per plane from the simulator's ground truth. "report s" is the median of three calls of
`residual_report` (its cached predictor: OpenCL when a device exists).

``cost`` (cubicle): per backend, the predictor's one-off build and the report's median time
(after three warm-up calls; the device synchronised inside each call, which returns host
numbers), wall-clock and CPU time (all of the process's threads, the OpenCL CPU device's
included: on a machine shared with other jobs the wall clock also counts their time), a whole
look's CPU time (`Watcher.step` at a right model: the report and the watcher's reading of the
shown frame), the
watcher's share of a 30 fps frame period at 2 and 4 looks per second and at the schedule
`play --watch` keeps on hardware while the set-up is right (one look per
``HARDWARE_LOOK_PERIOD`` s; report time x looks per second: the time per second, hence per
period, the watcher takes),
and, for the fastest backend, what a watcher thread does to a 30 fps frame loop on the main
thread: the loop sleeps to each frame's deadline, and its lateness (wake-up delay past the
deadline, median and 95th percentile) is measured with no watcher and with a thread
reporting 2 and 4 times a second.

``levels`` (per preset, at ``--size``): what the focus judgement reads on the drift
evaluation's clip (`rtdefocus eval --drift`), one compensated frame every half second of its
8 s cycle on an unchanged set-up: the prediction's band-pass RMS (`band_rms`, the key of like
content in `rtdefocus.watch.levels.BandLevels`), the band level (band ratio / gain), the gain
and the added light.

    python tools/bench_watch.py [--table accuracy|cost|levels|all] [--size WxH] [preset ...]

Writes ``bench_results/watch-<git commit>.json`` (the cost table).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from rtdefocus import sim
from rtdefocus.cl.runtime import opencl_available
from rtdefocus.cli.show import HARDWARE_LOOK_PERIOD
from rtdefocus.planar import apply_h
from rtdefocus.watch import ResidualPredictor, Watcher, residual_report

ROOT = Path(__file__).resolve().parent.parent
FPS = 30.0
CHANGES = [
    ("unchanged", {}),
    ("projector 0.3° + 3 px", {"bump": {"projector_yaw_deg": 0.3, "projector_shift_px": 3.0}}),
    ("camera 4 px", {"bump": {"camera_shift_px": 4.0}}),
    ("room light +0.1", {"set_light": "+0.1"}),
    ("blur radii ×1.15", {"refocus": {"scale": 1.15}}),
]


def content(size):
    w, h = size
    img = cv2.GaussianBlur(np.random.default_rng(0).random((h, w)).astype(np.float32), (0, 0), 3)
    img = (img - img.min()) / (img.max() - img.min())
    return np.repeat((40 + 180 * img)[..., None], 3, axis=2).astype(np.uint8)


def true_motion(calib, pc, plane):
    wp, hp = pc.projector_size
    ys, xs = np.mgrid[hp // 4:3 * hp // 4:8, wp // 8:7 * wp // 8:8]
    sel = pc.truth.plane_map[ys, xs] == plane
    pts = np.stack([xs[sel], ys[sel]], axis=1).astype(np.float64)
    back = apply_h(calib.H_proj_from_cam[plane], apply_h(pc.truth.H_cam_from_proj[plane], pts))
    return (back - pts).mean(axis=0)


def set_up(preset):
    pc = sim.VirtualProCam(preset)
    calib = sim.oracle_calibration(pc)
    calib.camera_lut = np.tile(pc.truth.camera_response, (3, 1)).astype(np.float32)
    return pc, calib, content(pc.projector_size)


def accuracy(presets) -> None:
    print("| preset | change | change s | report s | gain | ambient added (true) | band ratio "
          "| shift per plane, proj px (true) |")
    print("|---|---|---|---|---|---|---|---|")
    for preset in presets:
        for name, change in CHANGES:
            pc, calib, frame = set_up(preset)
            gamma0 = pc.truth.ambient_proj.copy()
            t0 = time.perf_counter()
            for kind, params in change.items():
                if kind == "set_light":
                    pc.set_light(ambient=pc.ambient + float(params))
                else:
                    getattr(pc, kind)(**params)
            t_change = time.perf_counter() - t0
            cap = pc.capture(frame)
            residual_report(calib, frame, cap)          # builds the cached predictor
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                r = residual_report(calib, frame, cap)
                times.append(time.perf_counter() - t0)
            added = float((pc.truth.ambient_proj - gamma0).mean())
            shifts = "; ".join(
                f"({r.shifts_proj[p][0]:+.2f}, {r.shifts_proj[p][1]:+.2f}) "
                f"({true_motion(calib, pc, p)[0]:+.2f}, {true_motion(calib, pc, p)[1]:+.2f})"
                for p in range(calib.n_planes))
            print(f"| {preset} | {name} | {t_change:.1f} | {np.median(times):.2f} | {r.gain:.3f} "
                  f"| {r.ambient_added:.4f} ({added:.4f}) | {r.band_ratio:.3f} | {shifts} |",
                  flush=True)


def levels(presets, size) -> None:
    from rtdefocus.compensate import Compensator
    from rtdefocus.study.eval_drift import drift_segments
    from rtdefocus.study.eval_video import make_clip
    from rtdefocus.watch.levels import band_level

    clip = make_clip(size, drift_segments(FPS))
    print("| preset | frame | segment | band_rms | band level | gain | ambient added |")
    print("|---|---|---|---|---|---|---|")
    for preset in presets:
        pc = sim.VirtualProCam(preset, projector_size=size,
                               camera_size=(int(size[0] * 1.6), int(size[1] * 1.6)))
        calib = sim.oracle_calibration(pc)
        comp = Compensator(calib)
        for i in range(0, len(clip), int(FPS / 2)):
            name, image = clip[i]
            shown = comp.compensate(image)
            r = residual_report(calib, shown, pc.capture(shown))
            print(f"| {preset} | {i} | {name} | {r.band_rms:.4f} | {band_level(r):.4f} "
                  f"| {r.gain:.4f} | {r.ambient_added:.4f} |", flush=True)


def frame_loop_lateness(predictor, frame, cap, looks: float, seconds: float) -> np.ndarray:
    """Lateness (s) of a 30 fps loop on this thread while another reports ``looks``/s."""
    stop = threading.Event()

    def watch():
        period = 1.0 / looks
        nxt = time.perf_counter()
        while not stop.is_set():
            predictor.report(frame, cap)
            nxt += period
            stop.wait(max(0.0, nxt - time.perf_counter()))

    thread = threading.Thread(target=watch, daemon=True) if looks > 0 else None
    if thread:
        thread.start()
    late = []
    t0 = time.perf_counter()
    for i in range(int(seconds * FPS)):
        deadline = t0 + (i + 1) / FPS
        time.sleep(max(0.0, deadline - time.perf_counter()))
        late.append(time.perf_counter() - deadline)
    stop.set()
    if thread:
        thread.join()
    return np.array(late)


def cost(preset: str, rounds: int = 7, seconds: float = 4.0) -> dict:
    pc, calib, frame = set_up(preset)
    still = pc.capture(frame)                        # the unchanged set-up: a look that acts not
    pc.bump(projector_shift_px=3.0)                  # a report that has something to align
    cap = pc.capture(frame)
    backends = ["numpy"] + (["opencl"] if opencl_available()[0] else [])
    out: dict = {"preset": preset, "fps": FPS, "backends": {}}
    quiet = 1.0 / HARDWARE_LOOK_PERIOD
    print(f"| backend | predictor build s | report ms (median of {rounds}) | report CPU ms "
          "| share of a 30 fps period at 2 looks/s (CPU) | at 4 looks/s (CPU) "
          f"| at `play --watch`'s hardware schedule, {quiet:.2f} looks/s (CPU) |")
    print("|---|---|---|---|---|---|---|")
    best = None
    for backend in backends:
        t0 = time.perf_counter()
        pred = ResidualPredictor(calib, backend=backend)
        build = time.perf_counter() - t0
        for _ in range(3):
            pred.report(frame, cap)
        times, cpu = [], []
        for _ in range(rounds):
            t0, c0 = time.perf_counter(), time.process_time()
            pred.report(frame, cap)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        med, med_cpu = float(np.median(times)), float(np.median(cpu))
        out["backends"][backend] = {"build_s": build, "report_s": med, "report_cpu_s": med_cpu,
                                    "share_2": med * 2, "share_4": med * 4,
                                    "share_schedule": med * quiet,
                                    "share_schedule_cpu": med_cpu * quiet}
        print(f"| {backend} | {build:.2f} | {med * 1e3:.0f} | {med_cpu * 1e3:.0f} "
              f"| {med * 2:.0%} ({med_cpu * 2:.0%}) | {med * 4:.0%} ({med_cpu * 4:.0%}) "
              f"| {med * quiet:.1%} ({med_cpu * quiet:.1%}) |", flush=True)
        if best is None or med < best[1]:
            best = (pred, med, backend)
    # A whole look of a watcher at a right model: the report (its cached predictor: OpenCL
    # when a device exists) and the watcher's own reading of the shown frame.
    watcher = Watcher(calib, lambda f: still, threaded=False)
    for _ in range(3):
        watcher.step(frame, still, 0.0)
    cpu = []
    for _ in range(rounds):
        c0 = time.process_time()
        watcher.step(frame, still, 0.0)
        cpu.append(time.process_time() - c0)
    look = float(np.median(cpu))
    out["look_cpu_s"], out["share_schedule_look_cpu"] = look, look * quiet
    print(f"\nA whole look (`Watcher.step` at a right model: the report and the watcher's reading "
          f"of the shown frame): {look * 1e3:.0f} ms CPU, {look * quiet:.1%} of a 30 fps period "
          f"at `play --watch`'s hardware schedule.")
    pred, _, backend = best
    print(f"\n30 fps loop on the main thread, watcher thread on {backend} "
          f"({seconds:.0f} s per row):\n")
    print("| looks/s | lateness median ms | p95 ms | max ms | p95 share of a period |")
    print("|---|---|---|---|---|")
    out["loop"] = {}
    for looks in (0, 2, 4):
        late = frame_loop_lateness(pred, frame, cap, looks, seconds) * 1e3
        p95 = float(np.percentile(late, 95))
        out["loop"][looks] = {"median_ms": float(np.median(late)), "p95_ms": p95,
                              "max_ms": float(late.max())}
        print(f"| {looks} | {np.median(late):.1f} | {p95:.1f} | {late.max():.1f} "
              f"| {p95 / (1e3 / FPS):.0%} |", flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", choices=["accuracy", "cost", "levels", "all"], default="all")
    ap.add_argument("--size", default="240x180", help="projector size of the levels table")
    ap.add_argument("presets", nargs="*", default=["cubicle", "webcam_cubicle"])
    args = ap.parse_args()
    if args.table in ("accuracy", "all"):
        accuracy(args.presets)
    if args.table in ("levels", "all"):
        levels(args.presets, tuple(int(v) for v in args.size.lower().split("x")))
    if args.table in ("cost", "all"):
        print()
        out = cost(args.presets[0])
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                                capture_output=True, text=True).stdout.strip() or "unknown"
        dest = ROOT / "bench_results" / f"watch-{commit}.json"
        dest.parent.mkdir(exist_ok=True)
        dest.write_text(json.dumps(out, indent=1))
        print("wrote", dest)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
