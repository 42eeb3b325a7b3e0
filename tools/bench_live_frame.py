#!/usr/bin/env python
"""The live player's own work per frame beside the warp, in wall and CPU time.

Plays the clip of ``rtdefocus eval --video`` (800x600, cubicle, oracle kernels) through the real
player as the eval's window rows do (``eval_video.play_window``): ``sK`` on a device K times
slower (the catch-up shows most moving frames with geometry only), ``geo`` in the player's
geometry mode. Every step of the main thread's frame is timed: wall (``time.perf_counter``)
and the main thread's CPU (``time.thread_time``), which another program's load changes far less
than wall time. It also reports the CPU each kind of thread spent per frame shown during the
play (``/proc/self/task``: ``python`` = the main and decoder threads, ``llvmpipe`` = the GL
warp's rasteriser) and the garbage collector's pauses during the play.

Example::

    .venv/bin/python tools/bench_live_frame.py --fps 30 --rows s4,geo

Prints a markdown table per row.
"""

from __future__ import annotations

import argparse
import collections
import gc
import os
import threading
import time

import numpy as np

STEPS = {"Player": ("_same_as_previous", "_catch_up_iterations", "_show_geometry", "_warp",
                    "present", "_update_budget", "render"),
         "CatchUp": ("new_picture", "decide", "judge")}


def thread_cpu() -> collections.Counter:
    """CPU seconds so far per kind of thread (its name without a trailing number)."""
    out: collections.Counter = collections.Counter()
    tick = os.sysconf("SC_CLK_TCK")
    for tid in os.listdir("/proc/self/task"):
        try:
            stat = open(f"/proc/self/task/{tid}/stat").read()
        except OSError:
            continue
        name = stat[stat.index("(") + 1:stat.rindex(")")].rstrip("0123456789:-")
        fields = stat[stat.rindex(")") + 2:].split()
        out[name] += (int(fields[11]) + int(fields[12])) / tick
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--rows", default="s4,geo", help="sK (a device K times slower) or geo")
    args = ap.parse_args()

    from rtdefocus import sim
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.stream import catch_up, loop
    from rtdefocus.stream.stats import LoopStats
    from rtdefocus.study import eval_video

    times: dict[str, list] = collections.defaultdict(list)
    play = {}
    pauses = []

    def timed(cls, name):
        fn = getattr(cls, name)

        def wrapper(*a, **k):
            t0, c0 = time.perf_counter(), time.thread_time()
            out = fn(*a, **k)
            label = f"{cls.__name__}.{name}"
            if name == "_same_as_previous":      # a repeated picture, or a new one
                label += " (same)" if out else " (new picture)"
            times[label].append((time.perf_counter() - t0, time.thread_time() - c0))
            return out
        setattr(cls, name, wrapper)

    for name in STEPS["Player"]:
        timed(loop.Player, name)
    for name in STEPS["CatchUp"]:
        timed(catch_up.CatchUp, name)
    frame_out = LoopStats.frame_out

    def counted_frame_out(self):
        if threading.current_thread() is threading.main_thread() and "start" not in play:
            play["start"] = (thread_cpu(), time.perf_counter())     # the first frame shown
        return frame_out(self)
    LoopStats.frame_out = counted_frame_out

    def on_gc(phase, info):
        if phase == "start":
            on_gc.t0 = time.perf_counter()
        elif "start" in play:
            pauses.append((info["generation"], time.perf_counter() - on_gc.t0))
    gc.callbacks.append(on_gc)

    procam = sim.VirtualProCam("cubicle", projector_size=(800, 600), camera_size=(1280, 960))
    calib = oracle_calibration(procam)
    clip = eval_video.make_clip((800, 600), eval_video.SEGMENTS)
    for row in args.rows.split(","):
        times.clear()
        play.clear()
        pauses.clear()
        slowdown = 1.0 if row == "geo" else float(row.lstrip("s"))
        _, st = eval_video.play_window(calib, "auto", clip, args.fps,
                                       geometry_only=row == "geo", slowdown=slowdown)
        cpu0, t0 = play["start"]
        cpu1, t1 = thread_cpu(), time.perf_counter()
        n = st.frames_out
        print(f"\n{row} at {args.fps:g} fps: {n} shown ({st.geometry_frames} geometry only "
              f"to keep up), {st.dropped} dropped ({st.dropped_copies} copies)\n")
        print("| step | calls | wall ms mean / p95 / max | main-thread CPU ms mean / max |")
        print("|---|---|---|---|")
        for name, rec in sorted(times.items()):
            a = 1e3 * np.asarray(rec)
            print(f"| {name} | {len(a)} | {a[:, 0].mean():.2f} / {np.percentile(a[:, 0], 95):.2f}"
                  f" / {a[:, 0].max():.2f} | {a[:, 1].mean():.2f} / {a[:, 1].max():.2f} |")
        per_kind = {k: round(1e3 * (cpu1[k] - cpu0.get(k, 0.0)) / n, 1) for k in cpu1
                    if cpu1[k] > cpu0.get(k, 0.0)}
        print(f"\nCPU per frame shown during the play ({t1 - t0:.2f} s), ms by thread: {per_kind}")
        gens = collections.Counter(g for g, _ in pauses)
        print(f"garbage collections during the play: {dict(gens)}, longest pause "
              f"{1e3 * max((p for _, p in pauses), default=0.0):.2f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
