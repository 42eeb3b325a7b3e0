#!/usr/bin/env python
"""What a moving frame costs by its iterations, stage by stage (no player, no other thread).

Compensates a slow pan (800x600, cubicle, oracle kernels, the clip of ``rtdefocus eval
--video``) frame after frame with the iterations of ``--pattern`` in turn, as a live player's
catch-up mixes them (0: the previous correction carried along the motion, shown from its start
alone), after the Compensator's warm-up. Prints per iteration count the median of each stage
(``warp``, ``start``: the frame's target, motion and carried correction, ``solve``,
``encode``) and the median and 0.9 quantile of the whole call, in ms.

Example::

    .venv/bin/python tools/bench_moving_frame.py --pattern 1,0,2,0 --frames 80
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pattern", default="1,0,2,0", help="iterations per frame, in turn")
    ap.add_argument("--frames", type=int, default=80)
    ap.add_argument("--backend", default="opencl")
    args = ap.parse_args()

    import numpy as np

    from rtdefocus import Compensator, sim
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.study import eval_video as ev
    from rtdefocus.study.machine import machine_info

    pattern = [int(v) for v in args.pattern.split(",")]
    procam = sim.VirtualProCam("cubicle", projector_size=(800, 600), camera_size=(1280, 960),
                               seed=0)
    calib = oracle_calibration(procam)
    clip = ev.make_clip((800, 600), (ev.Segment("slow pan", "pan", args.frames, 3.0),))
    comp = Compensator(calib, backend=args.backend)
    comp.warm_up(iterations=1, frames=9)
    rows: dict[int, list[list[float]]] = {n: [] for n in sorted(set(pattern))}
    for i, (_, image) in enumerate(clip):
        n = pattern[i % len(pattern)]
        t0 = time.perf_counter()
        comp.compensate(image, iterations=n)
        total = time.perf_counter() - t0
        sec = comp.last_info["seconds"]
        if i >= len(pattern):                 # (the first frame starts cold)
            rows[n].append([1e3 * sec.get(k, 0.0) for k in ("warp", "decode", "solve", "encode")]
                           + [1e3 * total])
    m = machine_info()
    print(f"{m.get('cpu')}, {m.get('cores')} cores, {m.get('device')}; pattern {pattern}, "
          f"{args.frames} frames")
    print("| iterations | frames | warp | start | solve | encode | total | total q0.9 |")
    print("|---|---|---|---|---|---|---|---|")
    for n, r in rows.items():
        a = np.asarray(r)
        med = np.median(a, axis=0)
        print(f"| {n} | {len(a)} | " + " | ".join(f"{v:.1f}" for v in med)
              + f" | {np.quantile(a[:, 4], 0.9):.1f} |")


if __name__ == "__main__":
    main()
