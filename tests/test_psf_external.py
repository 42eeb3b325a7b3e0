"""The PSF stage from another rig's dot captures (rd.calibrate_psf_from_dots) on the simulator."""

from __future__ import annotations

import numpy as np
import pytest
from calib_presets import NEAR_FOLD, fold_distance, kernel_errors

import rtdefocus as rd
from rtdefocus.errors import InputError


def _jittered_grid(wp: int, hp: int, nx: int, ny: int, rng) -> list[np.ndarray]:
    """Dot positions on a jittered grid reaching the frame's edges (a layout unlike the
    stage's), split into two frames like a checkerboard so no dot's light reaches its frame's
    neighbours."""
    xs = np.linspace(2, wp - 3, nx).round()
    ys = np.linspace(2, hp - 3, ny).round()
    gx, gy = np.meshgrid(xs, ys)
    pts = np.column_stack([gx.ravel(), gy.ravel()]) + rng.integers(-3, 4, (gx.size, 2))
    pts = np.clip(pts, 2, [wp - 3, hp - 3]).astype(int)
    row = np.repeat(np.arange(len(ys)), len(xs))
    col = np.tile(np.arange(len(xs)), len(ys))
    return [pts[(row + col) % 2 == k] for k in range(2)]


def _frame(procam, pts: np.ndarray, n: int) -> np.ndarray:
    wp, hp = procam.projector_size
    pattern = np.zeros((hp, wp, 3), np.uint8)
    pattern[pts[:, 1], pts[:, 0]] = 255
    # The mean, unrounded (float codes), as the stage's own averaging keeps it.
    return np.mean([procam.capture(pattern) for _ in range(n)], axis=0, dtype=np.float32)


#: Median kernel relative L2 inside the walls (80 projector pixels off the folds), measured by
#: ``.venv/bin/python tools/measure_gains.py --sections dots`` (2026-12-03): the stage's own
#: dots 0.0614, another rig's 80 jittered dots through calibrate_psf_from_dots 0.0498 (0.0487
#: in another run: the shared fixture's noise depends on what captured before). Bounds 1.5x
#: each.
MEASURED = {"stage": 0.0614, "given": 0.0498}


def dot_figures(procam, calib, folder) -> dict:
    """The stage's median kernel error and that of another rig's dots (a jittered grid in two
    frames, each averaged as often as the stage averaged its dot patterns), with the run."""
    truth = procam.truth
    rng = np.random.default_rng(3)
    wp, hp = calib.projector_size
    xy = np.column_stack([rng.integers(0, wp, 400), rng.integers(0, hp, 400)])
    inside = xy[fold_distance(truth, xy.astype(float)) > NEAR_FOLD][:80]
    n = calib.meta["psf"]["averages"]
    captures = [(pts, _frame(procam, pts, n)) for pts in _jittered_grid(wp, hp, 10, 8, rng)]
    mine = rd.Calibration.load(calib.save(folder / "calib.npz"))     # the fixture is shared
    out = rd.calibrate_psf_from_dots(mine, captures)
    return {"stage": float(np.median(kernel_errors(calib, truth, inside))),
            "given": float(np.median(kernel_errors(out, truth, inside))),
            "out": out, "dots": sum(len(p) for p, _ in captures)}


@pytest.mark.slow
def test_dots_from_another_rig_match_the_stage(small_cubicle, tmp_path):
    procam, calib, _ = small_cubicle
    f = dot_figures(procam, calib, tmp_path)
    assert f["out"].meta["psf"]["layout"] == "given"
    assert len(f["out"].psfs) == f["dots"]
    for key, measured in MEASURED.items():
        assert f[key] <= 1.5 * measured, (key, f[key], measured)


def test_dots_input_errors():
    # Refused before any measurement: the small cubicle's oracle calibration has every section
    # a calibrated one has, without the wait.
    calib = rd.sim.oracle_calibration(
        rd.sim.VirtualProCam("cubicle", projector_size=(200, 150), camera_size=(320, 240)))
    wc, hc = calib.camera_size
    frame = np.zeros((hc, wc, 3), np.uint8)
    with pytest.raises(InputError, match="projector frame"):
        rd.calibrate_psf_from_dots(calib, [(np.array([[5000, 3]]), frame)])
    with pytest.raises(InputError, match="camera's size"):
        rd.calibrate_psf_from_dots(calib, [(np.array([[5, 3]]), frame[:10])])
