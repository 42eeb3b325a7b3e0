"""A held-out check: compensation on a set-up the defaults were not tuned on.

The defaults (iterations, weights, kernel layout) were tuned on the cubicle / tilted / pillar
presets at 400x300, on the photographs chelsea / coffee / astronaut / rocket and the text slide,
with a linear projector and camera, a disc aperture, no chromatic blur and untextured walls.
Here everything differs at once: the off-centre fold, 320x240, projector gamma 2.2, camera gamma
1.8, a hexagonal aperture with lateral chromatic blur, textured walls and a picture none of the
tuning saw (scikit-image's immunohistochemistry). Calibrated through capture() only."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import blind_calibrate

from rtdefocus import sim
from rtdefocus.compensate import Compensator
from rtdefocus.study.scores import psnr, rect_mask, ssim

PROJECTOR, CAMERA = (320, 240), (512, 384)
CAMERA_GAMMA = 1.8

# Measured with this test's own code (OpenCL on PoCL, 2 cores, 2026-11-29):
# the body below run with the gains printed (`.venv/bin/python -m pytest tests/test_heldout.py`
# shows them in the assertion messages when it fails): +2.47 dB PSNR, +0.0412 SSIM over
# geometry only (the same set-up with the response table replaced by the
# identity: -5.08 dB). The test asks for 70 % of each. Not in the suite (about a minute per
# picture here): the same set-up at 800x600 / 1024x768 with camera gamma 1 gained only +1.18 dB
# PSNR (+0.064 SSIM) at the default 40 iterations, against +2.73 dB at 320x240: larger kernels
# in projector px need more iterations.
MEASURED_PSNR, MEASURED_SSIM = 2.47, 0.0412
MARGIN = 0.7


@pytest.mark.slow
def test_held_out_setup_gains_most_of_the_measured_gain():
    from skimage import data

    procam = sim.VirtualProCam("offcenter", projector_size=PROJECTOR, camera_size=CAMERA, seed=5,
                               projector_gamma=2.2, camera_gamma=CAMERA_GAMMA, aperture="hex",
                               chromatic=(0.85, 1.0, 1.2), texture=True)
    calib = blind_calibrate(procam, camera_gamma=CAMERA_GAMMA)
    image = np.ascontiguousarray(data.immunohistochemistry())
    geometry = Compensator(calib, method="none")
    warped = geometry.warp(image)
    mask = rect_mask(geometry.display_rect((image.shape[1], image.shape[0])), (CAMERA[1], CAMERA[0]))
    sharp, none = procam.capture(warped, sharp=True), procam.capture(warped)
    seen = procam.capture(Compensator(calib).compensate(image))
    gain = psnr(seen, sharp, mask) - psnr(none, sharp, mask)
    gain_s = ssim(seen, sharp, mask) - ssim(none, sharp, mask)
    assert gain > MARGIN * MEASURED_PSNR, f"PSNR gain {gain:.2f} dB (measured {MEASURED_PSNR})"
    assert gain_s > MARGIN * MEASURED_SSIM, f"SSIM gain {gain_s:.4f} (measured {MEASURED_SSIM})"
