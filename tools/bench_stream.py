#!/usr/bin/env python
"""The frame loop's timing and memory figures (the tests in
tests/test_stream.py keep the behaviour — order, drops, cache hits, no growth as a ratio — and this
reports the numbers that depend on the machine).

Rows: a live source ~4x faster than the solver (wall time against the stream's length, 95th
percentile latency against the time per frame); the realtime budget (median main-thread time
per frame against the source period); the second show of a cached slide deck (seconds); 500
frames (Python heap and RSS growth from frame 100 to 500).

Example::

    .venv/bin/python tools/bench_stream.py

Prints one line per figure and writes ``bench_results/stream-<git commit>.json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def main() -> int:
    import test_stream as ts

    import rtdefocus as rd
    from rtdefocus.stream import ArraySource, NullSink, Player, SlidesSource, play
    from rtdefocus.stream.sinks import Sink

    calib = ts.virtual_calibration()
    comp = rd.Compensator(calib)
    out: dict = {}

    times = []
    for _ in range(6):
        comp.compensate(ts.synthetic_frames(1)[0], iterations=20)
        times.append(comp.last_info["seconds"]["total"])
    per_frame = float(np.median(times[1:]))
    n, fps = 120, 4.0 / per_frame
    t0 = time.perf_counter()
    stats = play(comp, ArraySource(ts.synthetic_frames(n), fps=fps, live=True), NullSink(),
                 iterations=20)
    wall = time.perf_counter() - t0
    out["live"] = {"per_frame_s": per_frame, "fps": fps, "wall_s": wall,
                   "stream_s": n / fps, "dropped": stats.dropped,
                   "latency_p95_s": float(stats.stages["latency"].percentile(95))}

    comp.reset()
    frame = ts.synthetic_frames(1)[0]
    for _ in range(3):
        comp.compensate(frame, iterations=10)
    per_it = comp.last_info["seconds"]["solve"] / 10
    fps = 1.0 / (12 * per_it + comp.last_info["seconds"]["total"] - 10 * per_it)
    stats = play(comp, ArraySource(ts.synthetic_frames(80), fps=fps, live=True),
                 ts.RecordingSink(realtime=True), max_iterations=60)
    out["realtime"] = {"fps": fps,
                       "median_frame_over_period": float(np.median(
                           stats.stages["frame"].recent()[20:])) * fps,
                       "median_iterations": float(np.median(stats.iterations.recent()[20:]))}

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ts._slides(tmp / "deck", ["a1.png", "a2.png", "a10.png"])
        for run in ("first", "second"):
            t0 = time.perf_counter()
            Player(rd.Compensator(calib), SlidesSource(tmp / "deck"), NullSink(),
                   cache=tmp / "cache").run()
            out.setdefault("slides", {})[f"{run}_show_s"] = time.perf_counter() - t0

    marks = {}

    class MarkingSink(Sink):
        n = 0

        def write(self, frame, index):
            self.n += 1
            if self.n in (100, 500):
                with open("/proc/self/statm") as fh:
                    rss = int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") // 1024
                marks[self.n] = (tracemalloc.get_traced_memory()[0], rss)

    frames = ts.synthetic_frames(8)
    tracemalloc.start()
    play(comp, ArraySource(frames[i % 8] for i in range(500)), MarkingSink(), iterations=2)
    tracemalloc.stop()
    out["memory"] = {"heap_growth_kib": (marks[500][0] - marks[100][0]) / 1024,
                     "rss_growth_kib": marks[500][1] - marks[100][1]}

    for section, row in out.items():
        print(section, "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                 for k, v in row.items()))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip() or "unknown"
    dest = ROOT / "bench_results" / f"stream-{commit}.json"
    dest.parent.mkdir(exist_ok=True)
    dest.write_text(json.dumps(out, indent=1))
    print("wrote", dest)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
