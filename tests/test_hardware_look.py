"""Watching a show on real hardware: the camera's picture of what the show's own window is
showing, taken by time with the calibrated latency, with nothing projected for it; and the
latency kept in the calibration's hardware record."""

from __future__ import annotations

import types

import numpy as np
import pytest
from hardware_fakes import FakeDevice, FakeProjector

import rtdefocus as rd
from rtdefocus.errors import InputError
from rtdefocus.hardware.remembered import hardware_record, remembered_latency

PROJ = (160, 120)
DELAY = 0.25                     # the fake camera's delay: what the calibration measured


def halves(left: bool) -> np.ndarray:
    img = np.zeros((PROJ[1], PROJ[0], 3), np.uint8)
    img[:, : PROJ[0] // 2] = 255 if left else 0
    img[:, PROJ[0] // 2:] = 0 if left else 255
    return img


def left_minus_right(frame) -> float:
    """Camera level at the left of the projected area less that at the right."""
    h, w = frame.shape[:2]
    row = frame[h // 2, :, 1].astype(float)
    return float(row[int(0.3 * w)] - row[int(0.7 * w)])


def show_procam(latency, delay=DELAY):
    """A HardwareProCam on the show's window (a fake projector), the latency given."""
    window = FakeProjector(PROJ)
    dev = FakeDevice(window, delay=delay, queue=4)
    return rd.HardwareProCam(0, window=window, capture_factory=dev, latency=latency,
                             average=2), window


@pytest.mark.timeout(30)
def test_look_sees_what_the_show_shows_and_projects_nothing():
    pc, window = show_procam(DELAY)
    with pc:
        assert len(window.timeline) == 1          # start-up showed nothing on the wall
        assert pc.settle >= DELAY
        seen = []
        for left in (True, False, True):
            t = window.show(halves(left))          # the player puts up a frame of the show
            frame = pc.look(shown=t)
            seen.append(left_minus_right(frame))
            assert pc.looked_at >= t               # the picture is of the frame just put up
        assert len(window.timeline) == 4          # only the show's own frames were shown
    assert seen[0] > 100 and seen[1] < -100 and seen[2] > 100, seen


@pytest.mark.timeout(30)
def test_look_with_a_latency_too_short_sees_the_previous_frame():
    # The timing is what makes the picture right: without the latency the camera's queue
    # still holds the frame shown before (a long delay: a stalled test machine still reads
    # the camera well within it).
    pc, window = show_procam(0.0, delay=0.8)
    with pc:
        t = window.show(halves(False))
        stale = pc.look(shown=t)
    # the black screen from before, not the halves put up
    assert abs(left_minus_right(stale)) < 30 and stale.mean() < 60, left_minus_right(stale)


def test_the_calibration_record_keeps_the_latency_and_reads_it_back():
    pc, _ = show_procam(0.3)
    with pc:
        rec = hardware_record(pc, monitors=[], cameras=[])
    assert rec["camera"]["latency_s"] == pytest.approx(0.3)
    calib = types.SimpleNamespace(meta={"hardware": rec})
    assert remembered_latency(calib) == pytest.approx(0.3)
    assert remembered_latency(types.SimpleNamespace(meta={})) is None
    with pytest.raises(InputError, match="latency"):
        rd.HardwareProCam(0, window=FakeProjector(PROJ),
                          capture_factory=FakeDevice(FakeProjector(PROJ)), latency=-1.0)
