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
    assert r.gain == pytest.approx(1.0, abs=0.02)
    assert abs(r.ambient_added) < 0.005
    assert np.abs(r.shifts_proj).max() < 0.1, r.shifts_proj
    # The prediction explains the capture down to about the camera's noise.
    assert r.rms_before < 2 * pc.noise
    assert r.watched > 0.5 * 320 * 240


@pytest.mark.parametrize("preset", ["cubicle", "webcam_cubicle"])
def test_room_light_rise_is_measured(preset):
    pc, calib, frame = setup(preset)
    gamma0 = pc.truth.ambient_proj.copy()
    pc.set_light(ambient=pc.ambient + 0.1)
    r = residual_report(calib, frame, pc.capture(frame))
    added = float((pc.truth.ambient_proj - gamma0).mean())
    assert r.ambient_added == pytest.approx(added, rel=0.2)
    assert r.gain == pytest.approx(1.0, abs=0.02)
    assert np.abs(r.shifts_proj).max() < 0.1
    assert r.rms_after < 0.2 * r.rms_before


# fabric: a printed poster and a weave on the walls, which stay put when the projector moves.
@pytest.mark.parametrize("preset", ["cubicle", "webcam_cubicle", "fabric"])
def test_projector_shift_is_measured_per_plane(preset):
    pc, calib, frame = setup(preset)
    pc.bump(projector_shift_px=3.0)
    r = residual_report(calib, frame, pc.capture(frame))
    for p in range(calib.n_planes):
        np.testing.assert_allclose(r.shifts_proj[p], [3.0, 0.0], atol=1.0)
        np.testing.assert_allclose(r.shifts_proj[p], true_motion(calib, pc, p), atol=0.35)
    assert abs(r.ambient_added) < 0.01
    assert r.gain == pytest.approx(1.0, abs=0.02)


def test_projector_turn_is_measured():
    pc, calib, frame = setup("cubicle")
    pc.bump(projector_yaw_deg=0.3)
    r = residual_report(calib, frame, pc.capture(frame))
    nominal = pc.K_proj[0, 0] * math.tan(math.radians(0.3))
    for p in range(calib.n_planes):
        np.testing.assert_allclose(r.shifts_proj[p], [nominal, 0.0], atol=0.5)
        np.testing.assert_allclose(r.shifts_proj[p], true_motion(calib, pc, p), atol=0.35)


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
    assert lit == pytest.approx(base, rel=0.01)
    assert blurred < 0.97 * base, (base, blurred)


@pytest.mark.parametrize("preset", ["cubicle", "webcam_cubicle"])
def test_camera_shift_is_measured_per_plane(preset):
    pc, calib, frame = setup(preset)
    pc.bump(camera_shift_px=(4.0, 0.0))
    r = residual_report(calib, frame, pc.capture(frame))
    for p in range(calib.n_planes):
        expect = true_motion(calib, pc, p)
        assert np.linalg.norm(expect) > 2.5            # 4 camera px are ~3 projector px here
        np.testing.assert_allclose(r.shifts_proj[p], expect, atol=0.35)
