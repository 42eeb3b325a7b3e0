"""Kernel error of another rig's dot captures (`rd.calibrate_psf_from_dots`) against the psf
stage's own, on the virtual cubicle, by the steps of tests/test_psf_external.py.

    .venv/bin/python tools/dots_table.py
"""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from calib_presets import NEAR_FOLD, fold_distance, kernel_errors  # noqa: E402
from helpers import Blind  # noqa: E402
from test_psf_external import _frame, _jittered_grid  # noqa: E402

import rtdefocus as rd  # noqa: E402


def main() -> None:
    procam = rd.sim.VirtualProCam("cubicle", projector_size=(200, 150), camera_size=(320, 240))
    calib = rd.calibrate(Blind(procam, exposure=True))
    truth = procam.truth
    rng = np.random.default_rng(3)
    wp, hp = calib.projector_size
    xy = np.column_stack([rng.integers(0, wp, 400), rng.integers(0, hp, 400)])
    inside = xy[fold_distance(truth, xy.astype(float)) > NEAR_FOLD][:80]
    n = calib.meta["psf"]["averages"]
    caps = [(p, _frame(procam, p, n)) for p in _jittered_grid(wp, hp, 10, 8, rng)]
    with tempfile.TemporaryDirectory() as tmp:
        copy = rd.Calibration.load(calib.save(Path(tmp) / "c.npz"))
        t = time.perf_counter()
        out = rd.calibrate_psf_from_dots(copy, caps)
        dt = time.perf_counter() - t
    stage = float(np.median(kernel_errors(calib, truth, inside)))
    given = float(np.median(kernel_errors(out, truth, inside)))
    print("| PSF from | samples | captures | median kernel error | seconds |")
    print("|---|---|---|---|---|")
    print(f"| the stage (`rd.calibrate`) | {len(calib.psfs)} | {calib.meta['psf']['captures']} "
          f"| {stage:.4f} | — |")
    print(f"| given dots (`calibrate_psf_from_dots`) | {len(out.psfs)} | {len(caps)} × {n} "
          f"| {given:.4f} ({given / stage:.2f}× the stage) | {dt:.1f} |")


if __name__ == "__main__":
    main()
