"""The watcher's first piece: the calibration's prediction of the camera view and the residual
report (light and geometry), measured against the virtual set-up's changes."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from rtdefocus import sim
from rtdefocus.errors import InputError
from rtdefocus.planar import apply_h
from rtdefocus.watch import predict_proj, residual_report

SIZES = {"projector_size": (320, 240), "camera_size": (480, 360)}

# The report's errors in these tests' settings (deterministic), per preset:
# `tools/measure_gains.py --sections watch`. Each test bounds an error at ACCURACY x its
# measured figure, a measured effect at EFFECT x it.
ACCURACY, EFFECT = 1.5, 0.85
MEASURED = {
    # unchanged set-up: |gain - 1|, |ambient|, largest shift (px), rms before / noise, watched share
    "unchanged": {"cubicle": (0.0068, 0.00199, 0.0028, 0.429, 0.707),
                  "webcam_cubicle": (0.0131, 0.00186, 0.0063, 0.407, 0.707)},
    # room light +0.1: ambient's relative error, |gain - 1|, largest shift (px), rms after / before
    "light": {"cubicle": (0.0268, 0.0066, 0.0345, 0.0353),
              "webcam_cubicle": (0.0270, 0.0127, 0.0348, 0.0472)},
    # projector shifted 3 px: off [3, 0] (px), off the true motion (px), |ambient|, |gain - 1|
    "projector shift": {"cubicle": (0.549, 0.1605, 0.00170, 0.0067),
                        "webcam_cubicle": (0.545, 0.1562, 0.00131, 0.0099),
                        "fabric": (0.565, 0.1756, 0.00124, 0.0078)},
    # projector turned 0.3 degrees: off the nominal shift (px), off the true motion (px)
    "projector turn": {"cubicle": (0.0711, 0.0096)},
    # band ratio: relative change under room light, relative drop under 15 % more blur
    "band ratio": {"webcam_cubicle": (0.0008, 0.0414)},
    # camera shifted 4 px: off the true motion (px)
    "camera shift": {"cubicle": (0.1334,), "webcam_cubicle": (0.1247,)},
}


def setup(preset, detail_px=3.0):
    """A set-up, its oracle calibration (with the camera's true response) and a frame of
    smooth, aperiodic content (Gaussian-smoothed noise of σ ``detail_px``)."""
    pc = sim.VirtualProCam(preset, **SIZES)
    calib = sim.oracle_calibration(pc)
    calib.camera_lut = np.tile(pc.truth.camera_response, (3, 1)).astype(np.float32)
    img = cv2.GaussianBlur(np.random.default_rng(0).random((240, 320)).astype(np.float32), (0, 0),
                           detail_px)
    img = (img - img.min()) / (img.max() - img.min())
    frame = np.repeat((40 + 180 * img)[..., None], 3, axis=2).astype(np.uint8)
    return pc, calib, frame


def true_motion(calib, pc, plane):
    """Mean projector-px motion of the content on ``plane``: where the old calibration sees
    the light of each projector pixel now, minus the pixel."""
    wp, hp = pc.projector_size
    ys, xs = np.mgrid[hp // 4:3 * hp // 4:8, wp // 8:7 * wp // 8:8]
    sel = pc.truth.plane_map[ys, xs] == plane
    pts = np.stack([xs[sel], ys[sel]], axis=1).astype(np.float64)
    cam = apply_h(pc.truth.H_cam_from_proj[plane], pts)
    back = apply_h(calib.H_proj_from_cam[plane], cam)
    return (back - pts).mean(axis=0)


@pytest.mark.parametrize("preset", ["cubicle", "webcam_cubicle"])
def test_unchanged_set_up_reports_no_change(preset):
    pc, calib, frame = setup(preset)
    r = residual_report(calib, frame, pc.capture(frame))
    gain, ambient, shift, rms, watched = MEASURED["unchanged"][preset]
    assert abs(r.gain - 1) <= ACCURACY * gain, r.gain
    assert abs(r.ambient_added) <= ACCURACY * ambient, r.ambient_added
    assert np.abs(r.shifts_proj).max() <= ACCURACY * shift, r.shifts_proj
    # The prediction explains the capture down to below the camera's noise.
    assert r.rms_before <= ACCURACY * rms * pc.noise, r.rms_before / pc.noise
    assert r.watched >= EFFECT * watched * 320 * 240


@pytest.mark.parametrize("preset", ["cubicle", "webcam_cubicle"])
def test_room_light_rise_is_measured(preset):
    pc, calib, frame = setup(preset)
    gamma0 = pc.truth.ambient_proj.copy()
    pc.set_light(ambient=pc.ambient + 0.1)
    r = residual_report(calib, frame, pc.capture(frame))
    added = float((pc.truth.ambient_proj - gamma0).mean())
    ambient, gain, shift, rest = MEASURED["light"][preset]
    assert r.ambient_added == pytest.approx(added, rel=ACCURACY * ambient)
    assert abs(r.gain - 1) <= ACCURACY * gain, r.gain
    assert np.abs(r.shifts_proj).max() <= ACCURACY * shift, r.shifts_proj
    assert r.rms_after <= ACCURACY * rest * r.rms_before


# fabric: a printed poster and a weave on the walls, which stay put when the projector moves.
@pytest.mark.parametrize("preset", ["cubicle", "webcam_cubicle", "fabric"])
def test_projector_shift_is_measured_per_plane(preset):
    pc, calib, frame = setup(preset)
    pc.bump(projector_shift_px=3.0)
    r = residual_report(calib, frame, pc.capture(frame))
    nominal, true, ambient, gain = MEASURED["projector shift"][preset]
    for p in range(calib.n_planes):
        np.testing.assert_allclose(r.shifts_proj[p], [3.0, 0.0], atol=ACCURACY * nominal)
        np.testing.assert_allclose(r.shifts_proj[p], true_motion(calib, pc, p),
                                   atol=ACCURACY * true)
    assert abs(r.ambient_added) <= ACCURACY * ambient, r.ambient_added
    assert abs(r.gain - 1) <= ACCURACY * gain, r.gain


def test_projector_turn_is_measured():
    pc, calib, frame = setup("cubicle")
    pc.bump(projector_yaw_deg=0.3)
    r = residual_report(calib, frame, pc.capture(frame))
    nominal = pc.K_proj[0, 0] * math.tan(math.radians(0.3))
    off_nominal, off_true = MEASURED["projector turn"]["cubicle"]
    for p in range(calib.n_planes):
        np.testing.assert_allclose(r.shifts_proj[p], [nominal, 0.0], atol=ACCURACY * off_nominal)
        np.testing.assert_allclose(r.shifts_proj[p], true_motion(calib, pc, p),
                                   atol=ACCURACY * off_true)


def test_prediction_is_the_forward_model_and_bad_inputs_are_refused():
    pc, calib, frame = setup("cubicle")
    pred = predict_proj(calib, frame)
    # Black frame: the prediction is the ambient alone.
    np.testing.assert_allclose(predict_proj(calib, np.zeros_like(frame)), calib.ambient_proj, atol=1e-7)
    assert pred.shape == (240, 320, 3) and np.all(pred >= calib.ambient_proj - 1e-7)
    with pytest.raises(InputError, match="shown frame"):
        residual_report(calib, frame[:100], pc.capture(frame))
    with pytest.raises(InputError, match="capture"):
        residual_report(calib, frame, pc.capture(frame)[:, :100])


def test_blur_growth_lowers_the_band_ratio_and_light_does_not():
    # Fine detail: the band the blur change takes away must be in the content.
    pc, calib, frame = setup("webcam_cubicle", detail_px=1.5)
    base = residual_report(calib, frame, pc.capture(frame)).band_ratio
    pc.set_light(ambient=pc.ambient + 0.1)
    lit = residual_report(calib, frame, pc.capture(frame)).band_ratio
    pc.refocus(1.15)
    blurred = residual_report(calib, frame, pc.capture(frame)).band_ratio
    light, drop = MEASURED["band ratio"]["webcam_cubicle"]
    assert lit == pytest.approx(base, rel=ACCURACY * light)
    assert blurred <= (1 - EFFECT * drop) * base, (base, blurred)


@pytest.mark.parametrize("preset", ["cubicle", "webcam_cubicle"])
def test_camera_shift_is_measured_per_plane(preset):
    pc, calib, frame = setup(preset)
    pc.bump(camera_shift_px=(4.0, 0.0))
    r = residual_report(calib, frame, pc.capture(frame))
    for p in range(calib.n_planes):
        expect = true_motion(calib, pc, p)
        assert np.linalg.norm(expect) > 2.5            # 4 camera px are ~3 projector px here
        np.testing.assert_allclose(r.shifts_proj[p], expect,
                                   atol=ACCURACY * MEASURED["camera shift"][preset][0])
