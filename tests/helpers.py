"""Helpers shared by the tests (imported as ``from helpers import ...``; fixtures stay in
conftest.py): the tolerance table every NumPy-vs-device comparison uses, and a closeness check
that reports the largest error and where it is."""

from __future__ import annotations

import os

import numpy as np
import pytest

# One table of tolerances (max relative error vs the NumPy reference), used by every op test.
TOLERANCES = {
    "float32": 1e-4,
    "adjoint_identity": 1e-5,
}


def assert_close(actual, expected, rtol, what="result"):
    """Max error relative to the largest |expected|, reported with where it happens."""
    actual = np.asarray(actual, dtype=np.float64)
    expected = np.asarray(expected, dtype=np.float64)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    scale = max(float(np.abs(expected).max()), 1e-30)
    err = np.abs(actual - expected)
    worst = np.unravel_index(int(np.argmax(err)), err.shape)
    rel = float(err[worst]) / scale
    assert rel <= rtol, (f"{what}: max relative error {rel:.3g} > {rtol:g} at {worst} "
                         f"(got {actual[worst]:.6g}, expected {expected[worst]:.6g})")


# CI sets RTDEFOCUS_REQUIRE_DEVICES=1: there the set-up installs PoCL and Mesa, so a missing
# OpenCL device or EGL context is a broken set-up, not a reason to skip ~50 tests quietly.
REQUIRE_DEVICES = os.environ.get("RTDEFOCUS_REQUIRE_DEVICES", "") not in ("", "0")


def skip_or_fail(reason: str):
    """Skip for a missing device, except where devices are required (then fail loudly)."""
    if REQUIRE_DEVICES:
        pytest.fail(f"{reason} (RTDEFOCUS_REQUIRE_DEVICES is set: the set-up should provide it)",
                    pytrace=False)
    pytest.skip(reason)


class Blind:
    """The ProCam protocol and nothing else: ``projector_size``, ``camera_size`` and
    ``capture``, so that a calibration under test cannot read the simulator's ground truth
    (``truth``, ``scene``, ...). An optional ``post(index, pattern, frame) -> frame`` plays a
    faulty camera; ``exposure=True`` passes the camera's exposure control through. Every test
    that runs ``rd.calibrate`` or a calibration stage passes its set-up through this (the
    truth stays with the test, on the unwrapped simulator)."""

    def __init__(self, inner, post=None, *, exposure: bool = False):
        self._inner, self._post, self._n = inner, post, 0
        self.projector_size, self.camera_size = inner.projector_size, inner.camera_size
        if exposure:
            # The camera's exposure control (a setting of the camera, not ground truth).
            self.set_exposure = inner.set_exposure

    @property
    def exposure(self):
        return self._inner.exposure if hasattr(self, "set_exposure") else None

    def capture(self, pattern):
        frame = self._inner.capture(pattern)
        if self._post is not None:
            frame = self._post(self._n, pattern, frame)
        self._n += 1
        return frame


def blind_calibrate(procam, **options):
    """``rd.calibrate`` through :class:`Blind` (the one way the tests calibrate end to end)."""
    import rtdefocus as rd

    return rd.calibrate(Blind(procam), **options)


class CountingProCam:
    """A set-up that only counts its captures (black frames): options refused before the
    first capture leave ``n`` at 0."""

    def __init__(self, projector_size=(400, 300), camera_size=(640, 480)):
        self.projector_size, self.camera_size = projector_size, camera_size
        self.n = 0

    def capture(self, pattern):
        self.n += 1
        return np.zeros((self.camera_size[1], self.camera_size[0], 3), np.uint8)


def small_cubicle_run(folder):
    """A 200x150 cubicle (camera 320x240) calibrated end to end with its camera's exposure
    control, its captures kept in ``folder``: (procam, calibration, folder). The session
    fixture ``small_cubicle`` and tools/measure_gains.py make it the same way."""
    import rtdefocus as rd

    procam = rd.sim.VirtualProCam("cubicle", projector_size=(200, 150), camera_size=(320, 240))
    calib = rd.calibrate(Blind(procam, exposure=True), save_captures=folder)
    return procam, calib, folder
