"""Device runtimes: OpenCL device choice and program building, EGL offscreen rendering."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from helpers import TOLERANCES, assert_close

from rtdefocus.cl import runtime as clrt
from rtdefocus.errors import DeviceError, ProgramBuildError
from rtdefocus.resources import kernel_source, kernels_dir


def test_kernel_sources_ship_with_the_package():
    assert (kernels_dir() / "selftest.cl").is_file()
    assert "__kernel void saxpy" in kernel_source("selftest.cl")
    with pytest.raises(FileNotFoundError, match="available"):
        kernel_source("nope.cl")


def test_saxpy_from_kernels_matches_numpy(cl_runtime, rng):
    n = 1001  # odd on purpose
    x = rng.standard_normal(n).astype(np.float32)
    y = rng.standard_normal(n).astype(np.float32)
    prg = cl_runtime.program("selftest.cl", {"SCALE": "2.0f"})
    assert cl_runtime.program("selftest.cl", {"SCALE": "2.0f"}) is prg, "program not memoised"
    mf = cl.mem_flags
    ctx, q = cl_runtime.context, cl_runtime.queue
    bx = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    by = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=y)
    bo = cl.Buffer(ctx, mf.WRITE_ONLY, x.nbytes)
    prg.saxpy(q, (n,), None, np.float32(1.5), bx, by, bo, np.int32(n))
    out = np.empty_like(x)
    cl.enqueue_copy(q, out, bo).wait()
    assert_close(out, 2.0 * 1.5 * x + y, TOLERANCES["float32"], "saxpy")


def test_build_error_carries_file_options_and_log(cl_runtime, monkeypatch):
    monkeypatch.setattr(clrt, "kernel_source", lambda name: "__kernel void f( { syntax error")
    with pytest.raises(ProgramBuildError) as info:
        clrt.build_program(cl_runtime.context, "broken.cl", ["-DX=1"])
    msg = str(info.value)
    assert "broken.cl" in msg and "-DX=1" in msg and "log" in msg


def test_device_selection_by_env(cl_runtime, monkeypatch):
    name = cl_runtime.device.name.strip()
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    monkeypatch.setenv("RTDEFOCUS_DEVICE", name[:6].lower())
    assert clrt.choose_device().name.strip() == name
    monkeypatch.setenv("RTDEFOCUS_DEVICE", "0:0")
    assert clrt.choose_device() is not None
    monkeypatch.setenv("RTDEFOCUS_DEVICE", "no-such-device-xyz")
    with pytest.raises(DeviceError, match="RTDEFOCUS_DEVICE='no-such-device-xyz' matches no"):
        clrt.choose_device()
    monkeypatch.setenv("RTDEFOCUS_DEVICE", "7:7")
    with pytest.raises(DeviceError, match="available"):
        clrt.choose_device()


def test_pyopencl_ctx_is_honoured(cl_runtime, monkeypatch):
    monkeypatch.delenv("RTDEFOCUS_DEVICE", raising=False)
    monkeypatch.setenv("PYOPENCL_CTX", "99")
    with pytest.raises(DeviceError, match="PYOPENCL_CTX"):
        clrt.choose_device()


def test_no_platform_gives_the_install_hint(monkeypatch):
    def no_platforms():
        raise cl.LogicError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")
    monkeypatch.setattr(cl, "get_platforms", no_platforms)
    with pytest.raises(DeviceError, match="pocl-opencl-icd"):
        clrt.list_devices()


def test_egl_offscreen_render_reads_back_expected_pixels(gl):
    from rtdefocus.gl.runtime import read_rgb
    w, h = 37, 21
    fbo = gl.simple_framebuffer((w, h), components=3)
    fbo.clear(0.0, 0.0, 0.0)
    # Paint the top 5 rows red with a scissor: read_rgb must return them first (top-down).
    fbo.scissor = (0, h - 5, w, 5)
    fbo.clear(1.0, 0.0, 0.0)
    fbo.scissor = None
    img = read_rgb(fbo, (w, h))
    assert img.shape == (h, w, 3)
    assert (img[:5, :, 0] == 255).all() and (img[:5, :, 1:] == 0).all()
    assert (img[5:] == 0).all()
    fbo.release()
