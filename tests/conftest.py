"""Shared fixtures: one OpenCL runtime per available device and a session EGL context.

Plain helpers (the tolerance table, ``assert_close``) live in ``tests/helpers.py``."""

from __future__ import annotations

import os

import numpy as np
import pytest
from helpers import skip_or_fail


def _cl_devices() -> tuple[list, str]:
    """The OpenCL devices to test on, and why there are none. Only a missing device is caught:
    an import error or a bug in the runtime module must fail the run, not skip it."""
    from rtdefocus.cl.runtime import choose_device, list_devices
    from rtdefocus.errors import DeviceError

    try:
        if os.environ.get("RTDEFOCUS_DEVICE", "").lower() == "all":
            return [d for _, _, _, d in list_devices()], ""
        return [choose_device()], ""
    except DeviceError as exc:
        return [], str(exc)


_DEVICES, _NO_DEVICE_REASON = _cl_devices()


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
        skip_or_fail(f"no OpenCL device: {_NO_DEVICE_REASON}")
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
        skip_or_fail(str(exc))


@pytest.fixture()
def gl(gl_ctx):
    """The EGL context, checked for GL errors before and after the test."""
    assert gl_ctx.error == "GL_NO_ERROR", f"GL error left by an earlier test: {gl_ctx.error}"
    yield gl_ctx
    assert gl_ctx.error == "GL_NO_ERROR", f"GL error after the test: {gl_ctx.error}"


@pytest.fixture(scope="session")
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def small_cubicle(tmp_path_factory):
    """A 200x150 cubicle calibrated end to end with its camera's exposure control, its
    captures kept: (procam, calibration, capture folder). Shared by the capture-set and the
    clipping tests (a calibration costs ~4 s)."""
    from helpers import small_cubicle_run

    return small_cubicle_run(tmp_path_factory.mktemp("small_cubicle") / "captures")
