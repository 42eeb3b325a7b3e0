"""GL sharing (rtdefocus.cl.glshare): which path a set-up gets and why; the device-side
conversion of the warp's RGBA renderbuffer equals its NumPy twin and the GL read-back; the
Compensator's on-device path gives the very frames of the read-back path. PoCL has no GL
sharing, so the acquire/release itself runs only on a GPU driver (tools/gpu_check.sh)."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import skip_or_fail
from test_stream import synthetic_frames, virtual_calibration

import rtdefocus as rd
from rtdefocus.cl import glshare
from rtdefocus.cl.glshare import codes_from_rgba, gl_sharing_status, rgba_image_to_codes
from rtdefocus.gl.runtime import read_rgb


def _rgba_image(runtime, rgba):
    import pyopencl as cl

    h, w = rgba.shape[:2]
    fmt = cl.ImageFormat(cl.channel_order.RGBA, cl.channel_type.UNORM_INT8)
    return cl.create_image(runtime.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, fmt,
                    shape=(w, h), hostbuf=np.ascontiguousarray(rgba))


def _to_codes(runtime, rgba):
    import pyopencl.array as cla

    h, w = rgba.shape[:2]
    codes = cla.empty(runtime.queue, (h, w, 3), np.uint8)
    rgba_image_to_codes(runtime, _rgba_image(runtime, rgba), codes, (w, h))
    return codes.get(queue=runtime.queue)


def test_kernel_equals_numpy_twin_every_code(cl_runtime):
    if not cl_runtime.device.image_support:
        skip_or_fail("this OpenCL device has no image support")
    rng = np.random.default_rng(3)
    rgba = rng.integers(0, 256, (23, 37, 4), dtype=np.uint8)   # odd sizes: no tiling luck
    rgba.reshape(-1, 4)[:256, :3] = np.arange(256)[:, None]     # every code goes through once
    got = _to_codes(cl_runtime, rgba)
    assert np.array_equal(got, codes_from_rgba(rgba))
    assert got[0, 0, 2] == rgba[-1, 0, 2], "GL's bottom row must become the top row"


def test_twin_matches_the_gl_read_back(gl):
    """The twin's row order is the read-back's: a raw RGBA read of a framebuffer through the
    twin equals read_rgb of the same framebuffer."""
    w, h = 19, 11
    rng = np.random.default_rng(4)
    pixels = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    tex = gl.texture((w, h), 4, data=pixels.tobytes())
    fbo = gl.framebuffer(color_attachments=[tex])
    raw = np.frombuffer(fbo.read(components=4, alignment=1), np.uint8).reshape(h, w, 4)
    assert np.array_equal(codes_from_rgba(raw), read_rgb(fbo, (w, h)))
    fbo.release()
    tex.release()


def _device(extensions="", vendor="NVIDIA Corporation"):
    return SimpleNamespace(name="Fake GPU", extensions=extensions,
                           platform=SimpleNamespace(vendor=vendor))


def test_status_names_each_missing_piece(monkeypatch):
    import pyopencl as cl

    ok, why = gl_sharing_status(_device("cl_khr_fp64"))
    assert not ok and "no cl_khr_gl_sharing" in why
    monkeypatch.setattr(cl, "have_gl", lambda: False)
    ok, why = gl_sharing_status(_device("cl_khr_gl_sharing"))
    assert not ok and "PyOpenCL was built without" in why
    monkeypatch.setattr(cl, "have_gl", lambda: True)
    monkeypatch.setattr("rtdefocus.gl.runtime.context_api", lambda: "egl")
    mesa = SimpleNamespace(info={"GL_VENDOR": "Mesa", "GL_RENDERER": "llvmpipe"})
    ok, why = gl_sharing_status(_device("cl_khr_gl_sharing"), mesa)
    assert not ok and "one driver" in why
    nv = SimpleNamespace(info={"GL_VENDOR": "NVIDIA Corporation", "GL_RENDERER": "H100"})
    ok, why = gl_sharing_status(_device("cl_khr_gl_sharing cl_khr_gl_event"), nv)
    assert ok and "H100" in why
    monkeypatch.setattr("rtdefocus.gl.runtime.context_api", lambda: "native")
    ok, why = gl_sharing_status(_device("cl_khr_gl_sharing"), nv)
    assert not ok and "EGL" in why


def test_this_device_reports_the_reason():
    from rtdefocus.cl.runtime import choose_device

    dev = choose_device()
    ok, why = gl_sharing_status(dev)
    if "cl_khr_gl_sharing" not in dev.extensions:
        assert not ok and "cl_khr_gl_sharing" in why


@pytest.fixture(scope="module")
def calib():
    return virtual_calibration()


class HostImageShare:
    """The sharing path with GL's part replaced: the warp's renderbuffer is read as raw RGBA and
    handed to OpenCL as an image (what GLRenderBuffer + acquire give on a sharing driver)."""

    def __init__(self, runtime):
        self.runtime, self.calls = runtime, 0

    def fill_codes(self, codes, size):
        from rtdefocus.gl.warp import shared_renderbuffer

        w, h = size
        rbo = shared_renderbuffer(size)
        fbo = rbo.ctx.framebuffer(color_attachments=[rbo])
        raw = np.frombuffer(fbo.read(components=4, alignment=1), np.uint8).reshape(h, w, 4)
        fbo.release()
        rgba_image_to_codes(self.runtime, _rgba_image(self.runtime, raw), codes, size)
        self.calls += 1


def test_fallback_is_chosen_here_and_the_device_path_gives_identical_frames(calib, gl, caplog):
    from rtdefocus.cl.runtime import get_runtime

    with caplog.at_level(logging.INFO, logger=glshare.__name__):
        plain = rd.Compensator(calib, backend="opencl", warp_backend="gl", iterations=3)
    lines = [r.getMessage() for r in caplog.records if r.name == glshare.__name__]
    assert len(lines) == 1, lines
    if plain._gl_share is not None:
        # A sharing driver: the log says so, and the read-back twin is made by hand below.
        assert not lines[0].startswith("warp -> OpenCL: read-back"), lines
        plain._gl_share = None
    else:
        assert lines[0].startswith("warp -> OpenCL: read-back"), lines
    if not get_runtime().device.image_support:
        skip_or_fail("this OpenCL device has no image support")
    shared = rd.Compensator(calib, backend="opencl", warp_backend="gl", iterations=3)
    shared._gl_share = fake = HostImageShare(get_runtime())
    frames = synthetic_frames(4) + synthetic_frames(1)[:1]     # moving, then a cut back
    for i, f in enumerate(frames):
        a = plain.compensate(f, iterations=3)
        b = shared.compensate(f, iterations=3)
        assert np.array_equal(a, b), f"frame {i}: the on-device path differs from the read-back"
        assert plain.last_info["start"] == shared.last_info["start"]
    assert fake.calls == len(frames)
