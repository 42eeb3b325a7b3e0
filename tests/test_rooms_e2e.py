"""Three-plane rooms, end to end: the full ``rd.calibrate`` through ``capture`` only (the
ground truth hidden, helpers.Blind) on the three-plane rooms, every figure measured against the
simulator's truth by tests/setup_figures.py (``tools/preset_table.py`` prints the same figures
for every preset at any size).

Each room is calibrated once per module at SIZE with the preset's blur radii unchanged
(``blur_range_px`` 1.5-6 px, as at 800x600): the kernels keep their size while the planes
shrink, so 480x360 is the harder case (a side wall of the U is 120 px wide and gets few pilot
dots). Measured (tools/preset_table.py, 2 cores, PoCL; kernel L2 inside / near folds, gain
share): u_cubicle 0.070 / 0.076, 99 % at 480x360; 0.082 / 0.104, 99 % at 640x480; 0.098 /
0.150, 98 % at 800x600; corner_ceiling 0.090 / 0.111, 98 %; 0.093 / 0.133, 98 %; 0.095 /
0.199, 98 %. The module takes ~45 s here (each calibration 13-22 s, the rest the figures).
"""

from __future__ import annotations

import functools
import time

import numpy as np
import pytest
from helpers import Blind
from setup_figures import figures, fold_errors, match_planes

import rtdefocus as rd

SIZE = (480, 360)
ROOMS = ["u_cubicle", "corner_ceiling"]


@functools.cache
def _room(preset: str):
    from rtdefocus.study.samples import photographs

    pc = rd.sim.VirtualProCam(preset, projector_gamma=2.2, projector_size=SIZE,
                              camera_size=(int(SIZE[0] * 1.6), int(SIZE[1] * 1.6)))
    t0 = time.perf_counter()
    calib = rd.calibrate(Blind(pc))
    seconds = time.perf_counter() - t0
    photo = photographs()["chelsea"]
    return pc, calib, figures(pc, calib, {"chelsea": photo}), seconds


# `tools/measure_gains.py --sections rooms` (deterministic): errors are asked within 1.5x,
# gains within 85 %.
MEASURED = {
    "u_cubicle": {"fold_px": 0.09296, "homography_rms": 0.02039, "checker_rms": 0.08631,
                  "checker_bend": 0.06013, "kernel_inside": 0.06984, "kernel_fold": 0.07563,
                  "gain_oracle_db": 3.495, "gain_share": 0.9926},
    "corner_ceiling": {"fold_px": 0.2257, "homography_rms": 0.006951, "checker_rms": 0.09624,
                       "checker_bend": 0.09837, "kernel_inside": 0.08998, "kernel_fold": 0.111,
                       "gain_oracle_db": 2.063, "gain_share": 0.966},
}


@pytest.mark.slow
@pytest.mark.parametrize("preset", ROOMS)
def test_room_calibrated_end_to_end_meets_the_done_when(preset):
    """Planes found; every fold, the homographies, the checkerboard through the warp (RMS and
    the worst bend of a row or column across a fold) and the kernels (relative L2 median inside
    the planes and within 12 px of a fold) within 1.5x of their measured errors; the gain with
    the true kernels and the calibrated share of it within 85 % of the measured."""
    pc, calib, f, seconds = _room(preset)
    truth = pc.truth
    print(f"\n{preset} {SIZE[0]}x{SIZE[1]}: calibrated in {seconds:.0f} s; {f}")
    assert f["planes"] == f["planes_true"] == 3, calib.meta["geometry"]["candidates"]
    to_true, agree = match_planes(calib, truth)
    assert sorted(to_true.tolist()) == [0, 1, 2] and agree > 0.99, (to_true, agree)
    errs = fold_errors(calib, truth)
    m = MEASURED[preset]
    assert len(errs) == len(truth.folds_proj) and max(errs) <= 1.5 * m["fold_px"], errs
    for key in ("homography_rms", "checker_rms", "checker_bend", "kernel_inside", "kernel_fold"):
        assert f[key] <= 1.5 * m[key], (key, f[key], m[key])
    for key in ("gain_oracle_db", "gain_share"):
        assert f[key] >= 0.85 * m[key], (key, f[key], m[key])
    assert f["skipped"] == 0, calib.meta["psf"]["skipped"]
    assert np.isfinite(list(f.values())).all(), f
