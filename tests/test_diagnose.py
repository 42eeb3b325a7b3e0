"""Causes, not symptoms: when a stage fails, the error names the likely
cause — the set-up moved, the light changed, the camera sees only part of the projection —
and its fix, checked on the simulator with ProCam wrappers that break one thing."""

from __future__ import annotations

import numpy as np
import pytest

import rtdefocus as rd
from rtdefocus.calib.capture import Capturer
from rtdefocus.calib.diagnose import find_cause
from rtdefocus.errors import CalibrationError

PROJECTOR, CAMERA = (320, 240), (480, 360)
STAGES = ("geometry", "psf")


def _sim():
    return rd.sim.VirtualProCam("cubicle", projector_size=PROJECTOR, camera_size=CAMERA)


class Knocked:
    """The set-up is knocked after ``after`` captures: every later frame is shifted."""

    def __init__(self, inner, after: int, shift=(12, 7)):
        self.inner, self.after, self.shift, self.calls = inner, after, shift, 0
        self.projector_size, self.camera_size = inner.projector_size, inner.camera_size

    def capture(self, pattern):
        self.calls += 1
        frame = self.inner.capture(pattern)
        return np.roll(frame, self.shift[::-1], axis=(0, 1)) if self.calls > self.after else frame


class Cropped:
    """A camera that sees only the left ``share`` of what the simulator's camera sees (part of
    the right wall is outside its frame)."""

    def __init__(self, inner, share: float):
        self.inner = inner
        self.width = int(inner.camera_size[0] * share)
        self.projector_size, self.camera_size = inner.projector_size, (self.width,
                                                                       inner.camera_size[1])

    def capture(self, pattern):
        return np.ascontiguousarray(self.inner.capture(pattern)[:, :self.width])


class Dimmed:
    """The room light and the projector change after ``after`` captures (no movement)."""

    def __init__(self, inner, after: int):
        self.inner, self.after, self.calls = inner, after, 0
        self.projector_size, self.camera_size = inner.projector_size, inner.camera_size

    def capture(self, pattern):
        self.calls += 1
        frame = self.inner.capture(pattern)
        if self.calls > self.after:
            frame = np.clip(frame * 0.6 + 30, 0, 255).astype(np.uint8)
        return frame


@pytest.fixture(scope="module")
def good():
    """The undisturbed set-up calibrates, with no diagnosis (and tells the knock's timing)."""
    calib = rd.calibrate(_sim(), stages=STAGES)
    assert "diagnose" not in calib.meta["captures"]
    return calib


def test_a_set_up_knocked_between_the_stages_is_named_as_moved(good):
    after = good.meta["captures"]["geometry"]
    with pytest.raises(CalibrationError) as info:
        rd.calibrate(Knocked(_sim(), after), stages=STAGES)
    err = info.value
    assert err.cause.kind == "moved"
    assert 12.5 < err.cause.details["shift_px"] < 15.3          # |(12, 7)| = 13.9 px
    msg = str(err)
    assert msg.startswith("the set-up moved since the start of calibration")
    assert "calibrate again from the start" in msg             # the fix
    assert "(The psf stage failed with:" in msg                # and the symptom, kept
    assert isinstance(err.__cause__, CalibrationError)


def test_a_camera_that_sees_most_of_the_projection_calibrates_with_a_warning():
    """With 85 % of the frame in view the kernel stage fills the lost dots from their
    neighbours and calibration succeeds: the user is still told why it is not whole."""
    calib = rd.calibrate(Cropped(_sim(), 0.85), stages=STAGES)
    (warning,) = calib.meta["warnings"]
    assert "does not see the whole projection" in warning and "right edge" in warning


@pytest.mark.parametrize("share", [0.7])
def test_a_camera_that_sees_part_of_one_wall_is_named_as_partial_view(share):
    with pytest.raises(CalibrationError) as info:
        rd.calibrate(Cropped(_sim(), share), stages=STAGES)
    err = info.value
    assert err.cause.kind == "partial-view"
    edges = err.cause.details["edges_lit"]
    assert edges["right"] > 0.3 and max(edges["left"], edges["top"], edges["bottom"]) == 0
    msg = str(err)
    assert "does not see the whole projection" in msg and "right edge" in msg
    assert "whole projected area is inside the frame" in msg


def _reference(procam) -> Capturer:
    cap = Capturer(procam)
    wp, hp = procam.projector_size
    cap(np.zeros((hp, wp, 3), np.uint8))
    cap(np.full((hp, wp, 3), 255, np.uint8))
    assert cap.first_black is not None and cap.first_white is not None
    return cap


def test_a_steady_set_up_in_full_view_has_no_cause():
    cap = _reference(_sim())
    assert find_cause(cap) is None
    assert cap.counts["diagnose"] == 1          # one fresh white; the black was kept


def test_changed_light_is_named_as_such():
    cause = find_cause(_reference(Dimmed(_sim(), after=2)))
    assert cause is not None and cause.kind == "light"
    assert cause.details["shift_px"] < 1.0 and "lock the camera's exposure" in cause.message


def test_a_small_knock_is_seen_too():
    cause = find_cause(_reference(Knocked(_sim(), after=2, shift=(0, 3))))
    assert cause is not None and cause.kind == "moved"
    assert abs(cause.details["dy"] - 3) < 0.5 and abs(cause.details["dx"]) < 0.5
