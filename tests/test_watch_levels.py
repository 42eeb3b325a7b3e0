"""Focus judged against the band level of like content: a cut between two photographs of
different spectra on the webcam set-up is no focus change, and a blur change still is."""

from __future__ import annotations

import numpy as np
import pytest

from rtdefocus import sim
from rtdefocus.study.eval_drift import drift_segments
from rtdefocus.study.eval_video import make_clip
from rtdefocus.watch import Thresholds, Watcher, camera_view
from rtdefocus.watch.levels import BandLevels
from rtdefocus.watch.predictor import ResidualReport

PROJ, CAM = (240, 180), (384, 288)


def look(band_rms, band_ratio, gain=1.0):
    return ResidualReport(gain=gain, ambient_added=0.0, shifts_proj=np.zeros((2, 2)),
                          confidence=np.ones(2), band_ratio=band_ratio, rms_before=0.0,
                          rms_after=0.0, watched=1000, band_rms=band_rms)


def test_band_levels_are_read_on_like_content_only():
    levels = BandLevels(match=1.15, looks=3)
    for ratio in (0.94, 0.95, 0.945):
        levels.add(look(0.007, ratio))
    assert levels.known()
    assert levels.level(look(0.0075, 0.9)) == pytest.approx(0.945)    # like content
    assert levels.level(look(0.019, 0.93)) is None                    # another picture
    assert levels.level(look(float("nan"), 0.93)) == pytest.approx(0.945)   # rms not given
    levels.measure_again([look(0.007, 0.93)] * 3)
    assert levels.level(look(0.007, 0.9)) == pytest.approx(0.93)
    levels.clear()
    assert not levels.known() and levels.level(look(0.007, 0.9)) is None


@pytest.fixture(scope="module")
def pictures():
    """The drift evaluation's first picture (still) and the picture after its cut: their
    band ratios on the webcam set-up differ by about 1.2 %, the focus threshold."""
    clip = make_clip(PROJ, drift_segments(30.0))
    return clip[0][1], clip[4 * 30][1]


def play(pc, calib, frames, change_at=None):
    clock = [0.0]
    w = Watcher(calib, camera_view(pc), clock=lambda: clock[0], threaded=False, period_s=0.25)
    for i, frame in enumerate(frames):
        clock[0] = i * 0.25
        if change_at is not None and i == change_at:
            pc.refocus(scale=1.15)
        w.poll()
        w.offer(frame)
    return w


@pytest.mark.parametrize("preset", ["webcam_cubicle"])
def test_cuts_between_pictures_of_other_spectra_raise_no_focus_alarm(pictures, preset):
    """Two pictures, 2 s each, shown twice (the second showing of the first is where the
    level read on one picture alone called the other a focus change)."""
    pc = sim.VirtualProCam(preset, projector_size=PROJ, camera_size=CAM)
    calib = sim.oracle_calibration(pc)
    a, b = pictures
    w = play(pc, calib, [a] * 8 + [b] * 8 + [a] * 8 + [b] * 8)
    assert w.looks == 32
    assert [e for e in w.events if e.action == "detect"] == [] and w.false_alarms == 0
    assert w.trusted and w.calib is calib


def test_focus_change_after_cuts_is_still_detected(pictures):
    pc = sim.VirtualProCam("webcam_cubicle", projector_size=PROJ, camera_size=CAM)
    calib = sim.oracle_calibration(pc)
    a, b = pictures
    w = play(pc, calib, [a] * 8 + [b] * 8 + [a] * 8, change_at=18)
    detects = [e for e in w.events if e.action == "detect"]
    assert [e.kind for e in detects] == ["focus"], w.events
    # within 2 s of the change (looks every 0.25 s)
    assert 18 * 0.25 < detects[0].t <= 18 * 0.25 + 2.0
    assert Thresholds().band_match > 1.0
