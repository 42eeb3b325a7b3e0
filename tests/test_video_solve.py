"""A video's solve keeps its pace: the step the solver shrinks near convergence (float32
rounding makes a plain step look uphill) is not carried into the next frames."""

from __future__ import annotations

import rtdefocus as rd
from rtdefocus.sim import oracle_calibration
from rtdefocus.study.eval_video import Segment, make_clip


def test_moving_frames_after_a_still_converge_like_a_cold_start():
    """After ten identical frames (the solve continues to convergence), every frame of a pan
    warm-started at 40 iterations ends at least as close to its target as a cold 40-iteration
    solve of the same frame (the warm start is a head start, never a handicap)."""
    procam = rd.sim.VirtualProCam("cubicle", projector_size=(96, 72), camera_size=(160, 120))
    calib = oracle_calibration(procam)
    clip = make_clip((96, 72), (Segment("still", "still", 10), Segment("pan", "pan", 6, 12.0)))
    warm, cold = rd.Compensator(calib), rd.Compensator(calib)
    for i, (segment, image) in enumerate(clip):
        warm.compensate(image, iterations=40, warm_start=True)
        if segment != "pan":
            continue
        cold.compensate(image, iterations=40, warm_start=False)
        d_warm, d_cold = warm.last_info["distances"][-1], cold.last_info["distances"][-1]
        assert d_warm <= 1.01 * d_cold, (i, warm.last_info["start"], d_warm, d_cold)


def test_a_frame_shown_from_its_start_alone_pays_no_gradient():
    """A moving frame compensated with 0 iterations right after one that iterated (the previous
    correction carried along the motion, what a slow device's catch-up shows) computes no
    gradient and carries no momentum (FISTA's previous iterate): they are the first iteration's
    work, which a frame that iterates does."""
    procam = rd.sim.VirtualProCam("cubicle", projector_size=(96, 72), camera_size=(160, 120))
    calib = oracle_calibration(procam)
    clip = make_clip((96, 72), (Segment("pan", "pan", 7, 3.0),))
    comp = rd.Compensator(calib, backend="numpy")
    ops = comp._solver.ops
    calls, momentum = [], []
    gradient, carry = ops.gradient, ops.carry
    ops.gradient = lambda *a, **k: (calls.append(1), gradient(*a, **k))[1]
    ops.carry = lambda *a, **k: (momentum.append(k.get("src2") is not None), carry(*a, **k))[1]
    for i, (_, image) in enumerate(clip):
        before = len(calls)
        momentum.clear()
        its = 0 if i % 3 == 2 else 2                      # 2, 2, 0, 2, 2, 0, 2
        comp.compensate(image, iterations=its)
        if i == 0:
            continue
        assert comp.last_info["start"] == "motion", comp.last_info
        assert (len(calls) > before) == (its > 0), (i, its, len(calls) - before)
        assert any(momentum) == (its > 0 and i % 3 != 0), (i, its, momentum)
