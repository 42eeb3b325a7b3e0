"""Shared fixtures: one OpenCL runtime per available device, a session EGL context,
and the tolerance table every NumPy-vs-device comparison uses."""

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


def _cl_devices():
    try:
        from rtdefocus.cl.runtime import choose_device, list_devices
        if os.environ.get("RTDEFOCUS_DEVICE", "").lower() == "all":
            return [d for _, _, _, d in list_devices()]
        saved = os.environ.pop("RTDEFOCUS_DEVICE", None) if os.environ.get(
            "RTDEFOCUS_DEVICE", "").lower() == "all" else None
        del saved
        return [choose_device()]
    except Exception:  # no platform: tests that need a device skip with the reason
        return []


_DEVICES = _cl_devices()


def pytest_generate_tests(metafunc):
    if "cl_runtime" in metafunc.fixturenames:
        ids = [d.name.strip() for d in _DEVICES] or ["no-opencl-device"]
        metafunc.parametrize("cl_runtime", _DEVICES or [None], ids=ids, indirect=True,
                             scope="session")


_RUNTIMES: dict = {}


@pytest.fixture(scope="session")
def cl_runtime(request):
    """A :class:`rtdefocus.cl.ClRuntime` per available device (``RTDEFOCUS_DEVICE=all``)."""
    dev = request.param
    if dev is None:
        pytest.skip("no OpenCL device (install pocl-opencl-icd)")
    from rtdefocus.cl.runtime import ClRuntime
    if dev.int_ptr not in _RUNTIMES:
        _RUNTIMES[dev.int_ptr] = ClRuntime(dev)
    return _RUNTIMES[dev.int_ptr]


@pytest.fixture(scope="session")
def gl_ctx():
    """The session's EGL context; skips with the reason where EGL is missing."""
    from rtdefocus.errors import DeviceError
    from rtdefocus.gl.runtime import create_context
    try:
        return create_context()
    except DeviceError as exc:
        pytest.skip(str(exc))


@pytest.fixture()
def gl(gl_ctx):
    """The EGL context, checked for GL errors before and after the test."""
    assert gl_ctx.error == "GL_NO_ERROR", f"GL error left by an earlier test: {gl_ctx.error}"
    yield gl_ctx
    assert gl_ctx.error == "GL_NO_ERROR", f"GL error after the test: {gl_ctx.error}"


@pytest.fixture(scope="session")
def rng():
    return np.random.default_rng(12345)
