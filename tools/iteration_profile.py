#!/usr/bin/env python
"""Where one FISTA iteration's time goes on the OpenCL device: each kernel of the loop timed
with a ``finish()`` around it, inside the loop (the caches as the solve leaves them), then the
same iterations without the syncs (``Solver.run``), on the cubicle's oracle kernels.

Example (about 20 s at 800x600 on 2 PoCL cores)::

    .venv/bin/python tools/iteration_profile.py --size 800x600 --rounds 6 [--moving]
"""

from __future__ import annotations

import argparse
import collections
import functools
import os
import sys
import time

import numpy as np

import rtdefocus as rd
from rtdefocus import sim
from rtdefocus.cli.common import parse_size
from rtdefocus.study.samples import photographs


def synced(ops, times: dict, name: str, fn):
    """``fn()`` with a ``finish()`` on either side, its seconds appended to ``times[name]``."""
    ops.finish()
    t0 = time.perf_counter()
    out = fn()
    ops.finish()
    times[name].append(time.perf_counter() - t0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="800x600", help="projector WxH")
    ap.add_argument("--rounds", type=int, default=6, help="runs of 8 iterations each")
    ap.add_argument("--moving", action="store_true",
                    help="also time a moving frame's fixed part step by step")
    ap.add_argument("--precondition", default="colour+spatial",
                    choices=("colour+spatial", "colour", "none"))
    a = ap.parse_args(argv)
    wp, hp = parse_size(a.size)
    procam = sim.VirtualProCam("cubicle", projector_size=(wp, hp),
                               camera_size=(int(wp * 1.6), int(hp * 1.6)))
    calib = sim.oracle_calibration(procam)
    comp = rd.Compensator(calib, backend="opencl",
                          precondition=None if a.precondition == "none" else a.precondition)
    comp.compensate(photographs()["astronaut"], iterations=2)
    s, ops = comp._solver, comp._solver.ops
    colour = s.precondition in ("colour", "colour+spatial")
    times = collections.defaultdict(list)
    timed = functools.partial(synced, ops, times)

    for _ in range(a.rounds):
        ops.fista_state_write(s._d, s._theta, s._beta, 2.0 / s.L, 8)
        for k in range(8):              # Solver._run_fista, one kernel at a time
            timed("gradient blur", lambda: ops.gradient(s._q, s._G))
            if s._boost:
                timed("spatial preconditioner", lambda: ops.boost_gradient(s.P, s._G, s._G_alt))
                s._G, s._G_alt = s._G_alt, s._G
            timed("step", lambda: ops.fista_step(s.P, s._P_prev, s._G, s._G_prev, None, None,
                                                 s._P_alt, sums=False))
            timed("forward blur", lambda: ops.forward(s._P_alt, s._fp))
            timed("metric field", lambda: ops.metric_residual(s._fp, s.target, s._q_alt,
                                                              reduce=False, colour=colour))
            timed("restart test", lambda k=k: ops.fista_decide(k))
            timed("undo", lambda: ops.fista_undo(s.P, s._P_alt, s._q, s._q_alt))
            s._P_prev, s.P, s._P_alt = s.P, s._P_alt, s._P_prev
            s._q, s._q_alt = s._q_alt, s._q
            s._G_prev, s._G = s._G, s._G_prev
        ops.fista_state_read(8)
    s._forget_p()                       # the buffers were rotated by hand: start over cleanly
    runs = []
    for _ in range(a.rounds):
        t0 = time.perf_counter()
        s.run(8)
        runs.append((time.perf_counter() - t0) / 8)
    print(f"{wp}x{hp}, cubicle oracle kernels, precondition {s.precondition}, "
          f"{ops.runtime.description}; load average {os.getloadavg()[0]:.1f}")
    total = 0.0
    for name, v in times.items():
        med = 1e3 * float(np.median(v))
        total += med
        print(f"  {name:24s} {med:6.2f} ms  (min {1e3 * min(v):6.2f}, {len(v)} runs)")
    print(f"  {'sum of the medians':24s} {total:6.2f} ms")
    print(f"  Solver.run(8) / 8: median {1e3 * float(np.median(runs)):.2f} ms, "
          f"min {1e3 * min(runs):.2f} ms ({a.rounds} runs, no syncs)")
    if a.moving:
        moving_start(comp, a.rounds)
    return 0


def moving_start(comp, rounds: int) -> None:
    """A moving frame's fixed part, step by step as ``Compensator._start_solve`` takes it (each
    step synchronised, so the motion estimate does not overlap the cold start's blur here), on
    a pan of 6 input px per frame."""
    import cv2

    s, ops = comp._solver, comp._solver.ops
    photo = photographs()["astronaut"]
    times = collections.defaultdict(list)
    timed = functools.partial(synced, ops, times)

    def pan(i):
        m = np.float32([[1, 0, -6 * i], [0, 1, 0]])
        return cv2.warpAffine(photo, m, photo.shape[1::-1], borderMode=cv2.BORDER_REFLECT)

    comp.reset()
    prev = comp.warp(pan(0))
    comp.compensate(pan(0), iterations=2)
    for i in range(1, 3 + 3 * rounds):
        img = pan(i)
        warped = timed("GL warp", lambda img=img: comp.warp(img))
        motion = timed("motion estimate (host)", lambda w=warped, p=prev: comp._motion.estimate(p, w))
        s.begin_frame()
        timed("decode", lambda w=warped: ops.decode(w, comp._lut_inc, 0.0, 1.0, s.target))
        s.target_changed()
        d_cold = timed("cold start's distance", s.cold_distance)
        timed("motion upload", lambda m=motion: ops.set_motion(m.map_xy, m.valid))
        timed("warm start: carries, distance, first gradient",
              lambda d=d_cold: s.start_from_motion(d))
        timed("1 iteration", lambda: s.run(1))
        timed("encode + read-back", lambda: ops.encode(s.P, comp._lut_inc))
        comp._prev_warped, prev = warped, warped
    print("a moving frame's start, each step synchronised (medians):")
    for name, v in times.items():
        print(f"  {name:46s} {1e3 * float(np.median(v[3:])):6.2f} ms")


if __name__ == "__main__":
    sys.exit(main())
