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
