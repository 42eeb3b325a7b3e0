"""Public entry points answer odd calls with the project's errors (which subclass the
builtins) and a message that names the fix, before any work is done."""

from __future__ import annotations

import math

import numpy as np
import pytest

import rtdefocus as rd
from rtdefocus.errors import InputError, InputTypeError
from rtdefocus.gl.warp import warp_image
from rtdefocus.sim import oracle_calibration


@pytest.fixture(scope="module")
def small():
    procam = rd.sim.VirtualProCam("cubicle", projector_size=(96, 72), camera_size=(160, 120))
    return procam, oracle_calibration(procam)


# --------------------------------------------------------------------------- Compensator
@pytest.mark.parametrize("calib", [None, "setup.npz", {"psfs": None}],
                         ids=["none", "a-path", "a-dict"])
def test_compensator_needs_a_calibration(calib):
    with pytest.raises(InputTypeError, match=r"needs an rtdefocus Calibration.*Calibration\.load"):
        rd.Compensator(calib)


@pytest.mark.parametrize("kwargs,pattern", [
    (dict(method="sharp"), r"method must be one of \('ycbcr'"),
    (dict(solver="adam"), "solver must be one of"),
    (dict(backend="cuda"), "backend must be one of"),
    (dict(warp_backend="vulkan"), "warp_backend must be one of"),
    (dict(blur_variant="fast"), "blur_variant must be one of"),
    (dict(iterations=-1), "iterations must be >= 0"),
    (dict(iterations=2.5), "iterations must be a whole number"),
    (dict(iterations="10"), "iterations must be a real number"),
    (dict(tol=-0.1), "tol must be >= 0"),
    (dict(tol=math.nan), "tol must be finite"),
    (dict(wiener_nsr=0.0), "wiener_nsr must be > 0"),
    (dict(weights=(1.0, 1.0, 1.0)), r"four Eq. 4 weights"),
    (dict(weights=(1.0, -1.0, 1.0, 1.0)), r"weights\[1\] must be >= 0"),
    (dict(weights=(1.0, math.inf, 1.0, 1.0)), r"weights\[1\] must be finite"),
], ids=lambda v: v if isinstance(v, str) else None)
def test_compensator_rejects_bad_options(small, kwargs, pattern):
    with pytest.raises(InputError, match=pattern):
        rd.Compensator(small[1], backend=kwargs.pop("backend", "numpy"), **kwargs)


def test_compensate_checks_the_image_and_budget(small):
    _, calib = small
    comp = rd.Compensator(calib, backend="numpy", method="none", warp_backend="cv2")
    good = np.zeros((30, 40, 3), np.uint8)
    cases = [
        (None, InputTypeError, "RGB uint8 array"),
        (np.zeros((30, 40), np.uint8), InputError, r"np\.dstack"),
        (np.zeros((30, 40, 4), np.uint8), InputError, r"img\[\.\.\., :3\]"),
        (np.zeros((30, 40, 3), np.float32), InputError, r"np\.clip\(img, 0, 1\) \* 255"),
        (np.zeros((3, 30, 40), np.uint8), InputError, r"np\.moveaxis"),
        (np.zeros((0, 40, 3), np.uint8), InputError, "empty"),
    ]
    for image, err, pattern in cases:
        with pytest.raises(err, match=pattern):
            comp.compensate(image)
        with pytest.raises(err, match=pattern):
            comp.warp(image)
    with pytest.raises(InputError, match="iterations must be >= 0"):
        comp.compensate(good, iterations=-3)
    wp, hp = calib.projector_size
    assert comp.compensate(good).shape == (hp, wp, 3)      # and a good call still works


def test_solve_checks_its_arrays(small):
    _, calib = small
    comp = rd.Compensator(calib, backend="numpy", method="none")
    wp, hp = calib.projector_size
    target = np.full((3, hp, wp), 0.5, np.float32)
    with pytest.raises(InputError, match=r"target_linear must be planar \(3, 72, 96\)"):
        comp.solve(target.transpose(1, 2, 0))
    bad = target.copy()
    bad[0, 3, 4] = np.nan
    with pytest.raises(InputError, match="NaN or infinite"):
        comp.solve(bad)
    with pytest.raises(InputError, match=r"P0 must be planar \(3, 72, 96\)"):
        comp.solve(target, P0=target[:, :10])


def test_warp_image_needs_a_calibration():
    with pytest.raises(InputTypeError, match="needs an rtdefocus Calibration"):
        warp_image(None, np.zeros((4, 4, 3), np.uint8), backend="cv2")


# --------------------------------------------------------------------------- Calibration
@pytest.mark.parametrize("x,y", [(math.nan, 0), (0, math.inf), (-math.inf, 3.0)],
                         ids=["nan-x", "inf-y", "-inf-x"])
def test_kernel_at_and_plane_of_reject_non_finite_positions(small, x, y):
    _, calib = small
    with pytest.raises(InputError, match="must be finite projector pixels"):
        calib.kernel_at(x, y)
    with pytest.raises(InputError, match="must be finite projector pixels"):
        calib.plane_of(np.array([1.0, x]), np.array([2.0, y]))


def test_kernel_at_rejects_non_numbers_and_arrays(small):
    _, calib = small
    with pytest.raises(InputTypeError, match="must be real numbers"):
        calib.kernel_at("10", None)
    with pytest.raises(InputError, match="once per position"):
        calib.kernel_at(np.arange(3), np.arange(3))
    k = calib.kernel_at(np.float32(10.4), 7)                # NumPy scalars are numbers too
    assert k.ndim == 2 and abs(float(k.sum()) - 1.0) < 1e-5


@pytest.mark.parametrize("size,err,pattern", [
    ((0, 600), InputError, "both >= 1"),
    ((-800, 600), InputError, "both >= 1"),
    ((800.5, 600), InputError, "whole pixels"),
    ((800, math.nan), InputError, "whole pixels"),
    ((800,), InputTypeError, r"pair \(width, height\)"),
    ("800x600", InputTypeError, r"pair \(width, height\)"),
    (None, InputTypeError, r"pair \(width, height\)"),
    ((800, "600"), InputTypeError, "numbers"),
], ids=["zero", "negative", "fractional", "nan", "one-number", "string", "none", "str-height"])
def test_display_rect_checks_the_size(small, size, err, pattern):
    _, calib = small
    with pytest.raises(err, match=pattern):
        calib.display_rect(size)
    comp = rd.Compensator(calib, backend="numpy", method="none")
    with pytest.raises(err, match=pattern):
        comp.display_rect(size)


@pytest.mark.parametrize("margin,pattern", [(-0.1, "must be >= 0"), (0.5, r"\[0, 0\.5\)"),
                                            (math.nan, "finite")])
def test_display_rect_checks_the_margin(small, margin, pattern):
    with pytest.raises(InputError, match=pattern):
        small[1].display_rect((16, 9), margin=margin)


def test_display_rect_accepts_numpy_sizes(small):
    _, calib = small
    assert calib.display_rect(np.array([16, 9])) == calib.display_rect((16, 9))


# --------------------------------------------------------------------------- calibrate
class _NoCapture:
    projector_size = (96, 72)
    camera_size = (160, 120)


class _NoSizes:
    def capture(self, pattern):
        return pattern


class _BadSize(_NoCapture):
    projector_size = (0, 72)

    def capture(self, pattern):
        return pattern


class _CaptureNotCallable(_NoCapture):
    capture = "not a method"


@pytest.mark.parametrize("procam,pattern", [
    (None, r"NoneType is not a ProCam: it has no 'projector_size', 'camera_size', 'capture'"),
    (_NoCapture(), r"_NoCapture is not a ProCam: it has no 'capture'"),
    (_NoSizes(), r"it has no 'projector_size', 'camera_size'\. Pass rd\.sim\.VirtualProCam"),
    (_CaptureNotCallable(), r"capture must be a method capture\(pattern\)"),
], ids=["none", "no-capture", "no-sizes", "capture-not-callable"])
def test_calibrate_needs_a_procam(procam, pattern):
    with pytest.raises(InputTypeError, match=pattern):
        rd.calibrate(procam)


def test_calibrate_checks_the_procam_sizes_and_stages(small):
    with pytest.raises(InputError, match=r"_BadSize\.projector_size must be .* both >= 16"):
        rd.calibrate(_BadSize())
    procam, _ = small
    with pytest.raises(InputTypeError, match=r"stages must be a tuple of stage names"):
        rd.calibrate(procam, stages="geometry")
    with pytest.raises(InputTypeError, match=r"progress must be a function"):
        rd.calibrate(procam, progress="bar")


def test_the_errors_are_also_the_builtins():
    assert issubclass(InputTypeError, TypeError) and issubclass(InputTypeError, ValueError)
    assert issubclass(InputTypeError, rd.RtDefocusError)
    with pytest.raises(TypeError):
        rd.Compensator(None)
