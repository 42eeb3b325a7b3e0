#!/usr/bin/env python
"""A still's settle beside the live player's frame loop, against the same settle on the loop.

Plays a still of ``--still`` frames then a slow pan of 10 (the clip of ``rtdefocus eval
--video``'s first two segments, 800x600, cubicle, oracle kernels) live through the real player
as the eval's window rows do (``eval_video.play_window``), at each ``--fps`` on a device K
times slower (``--slowdown``): ``rule`` (the player's own choice,
``BackgroundSettle.available`` and ``may_settle``: beside the loop, or no settle), ``beside``
(the settle on its worker thread, forced there also where the solver runs on the CPU:
``available`` made true), ``on the loop`` (the settle where the loop waits for it:
``available`` made false, ``may_settle`` true) and the geometry-only window. A still about as
long as it takes for a settle to be admitted (about 45 frames at 30 fps, 4x slower, on 2 CPU
cores) makes a settle that spans the cut likely.

Example::

    .venv/bin/python tools/bench_settle.py --still 48 --fps 30,60 --slowdown 4 --runs 2

Prints a markdown table: frames lost (dropped, not copies of the picture on the screen) and
the first still frame shown compensated, with how many were; for ``rule`` rows, where the
settle ran and the geometry-only frame's cost (``geometry_cost``, ms) when it started.
"""

from __future__ import annotations

import argparse


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--still", type=int, default=48, help="frames of the still (default 48)")
    ap.add_argument("--slowdown", default="4", help="device speeds K,K (default 4)")
    ap.add_argument("--fps", default="30", help="frame rates F,F (default 30)")
    ap.add_argument("--rows", default="rule,beside,on the loop,geometry only",
                    help="rows to play, of rule, beside, on the loop, geometry only")
    ap.add_argument("--runs", type=int, default=1)
    args = ap.parse_args()

    from rtdefocus import sim
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.stream import settle
    from rtdefocus.study import eval_video as ev

    procam = sim.VirtualProCam("cubicle", projector_size=(800, 600), camera_size=(1280, 960),
                               seed=0)
    calib = oracle_calibration(procam)
    clip = ev.make_clip((800, 600), (ev.Segment("still", "still", args.still),
                                     ev.Segment("slow pan", "pan", 10, 3.0)))
    cls = settle.BackgroundSettle
    available, start, may_settle = cls.available, cls.start, cls.may_settle
    where: list[str] = []

    def recording_start(self, frame, iterations, t_start):
        cost = self.geometry_cost()
        ok = start(self, frame, iterations, t_start)
        where.append(f"{'beside' if ok else 'on the loop'} at {frame.index}"
                     + (f", {1e3 * cost:.1f} ms" if cost is not None else ""))
        return ok

    print("| run | fps | slowdown | settle | shown | dropped (copies) | lost | still compensated "
          "from (frames) | settle ran |")
    print("|---|---|---|---|---|---|---|---|---|")
    try:
        for run in range(1, args.runs + 1):
            for fps in (float(x) for x in args.fps.split(",")):
                for k in (float(x) for x in args.slowdown.split(",")):
                    for row in args.rows.split(","):
                        cls.available = available if row == "rule" else (
                            lambda self, beside=row == "beside": beside)
                        cls.may_settle = may_settle if row == "rule" else (lambda self: True)
                        cls.start = recording_start
                        where.clear()
                        shown, st = ev.play_window(calib, "auto", clip, fps, slowdown=k,
                                                   geometry_only=row == "geometry only")
                        still = [i for i in range(args.still) if i in shown and shown[i][1] > 0]
                        lost = [i for i in range(args.still, len(clip)) if i not in shown]
                        print(f"| {run} | {fps:g} | {k:g}x | {row} | {len(shown)} | {st.dropped} "
                              f"({st.dropped_copies}) | {', '.join(map(str, lost)) or 0} | "
                              f"{f'{still[0]} ({len(still)})' if still else '–'} | "
                              f"{'; '.join(where) or '–'} |", flush=True)
    finally:
        cls.available, cls.start, cls.may_settle = available, start, may_settle

if __name__ == "__main__":
    main()
