"""GL sharing (``cl_khr_gl_sharing``): the GL warp's output reaches OpenCL on the device.

Without it each frame's warp is read back from GL to the host and uploaded again to OpenCL
(:meth:`rtdefocus.cl.solve.ClSolveOps.decode`). Where the OpenCL device has the extension,
PyOpenCL was built with GL interop and the warp runs in an EGL context of the same vendor, the
solver's OpenCL context is created *sharing* that GL context; the warp's renderbuffer is then an
OpenCL image (``pyopencl.GLRenderBuffer``) which the kernel ``kernels/gl_share.cl`` turns into
the solver's codes buffer between ``enqueue_acquire_gl_objects`` and
``enqueue_release_gl_objects``. Otherwise the read-back path stays (PoCL has no GL sharing, nor
do PyOpenCL's PyPI wheels, built without GL).

:func:`gl_sharing_status` says which path a set-up gets and why; ``rtdefocus info`` prints it
and the Compensator logs it once. The host read-back of the warp is still made on the sharing
path: the motion estimator of the warm start and the still-frame check work on the host copy.
"""

from __future__ import annotations

import ctypes
import logging

import numpy as np

from .runtime import ClRuntime, choose_device, import_pyopencl

log = logging.getLogger(__name__)

__all__ = ["SHARING_EXTENSIONS", "gl_sharing_status", "codes_from_rgba", "rgba_image_to_codes",
           "GLShare"]

SHARING_EXTENSIONS = ("cl_khr_gl_sharing", "cl_APPLE_gl_sharing")


def codes_from_rgba(rgba: np.ndarray) -> np.ndarray:
    """NumPy twin of ``rgba_image_to_codes``: (H, W, 4) uint8 rows bottom-up (GL's order) ->
    (H, W, 3) uint8 top row first (what :func:`rtdefocus.gl.runtime.read_rgb` returns)."""
    return np.ascontiguousarray(np.asarray(rgba, np.uint8)[::-1, :, :3])


def rgba_image_to_codes(runtime, image, codes, size: tuple[int, int]) -> None:
    """Enqueue the conversion of an RGBA8 OpenCL ``image`` (GL's row order) into ``codes``, a
    uint8 (H, W, 3) ``pyopencl.array.Array`` of ``runtime``; ``size`` = (W, H)."""
    w, h = (int(v) for v in size)
    prg = runtime.program("gl_share.cl")       # built once per context (the runtime caches it)
    entry = _kernels.get(id(prg))
    if entry is None:                          # one kernel object per program, reused
        entry = _kernels[id(prg)] = (prg, import_pyopencl().Kernel(prg, "rgba_image_to_codes"))
    entry[1](runtime.queue, (w, h), None, image, codes.data, np.int32(w), np.int32(h))


_kernels: dict[int, tuple] = {}   # id(program) -> (program, kernel); the program is kept alive


def _vendor_key(text: str) -> str:
    t = text.lower()
    for key, names in (("nvidia", ("nvidia",)), ("amd", ("amd", "advanced micro", "ati ")),
                       ("intel", ("intel",)), ("apple", ("apple",)), ("arm", ("arm", "mali"))):
        if any(n in t for n in names):
            return key
    return t.split()[0] if t.split() else ""


def gl_sharing_status(device=None, gl_ctx=None) -> tuple[bool, str]:
    """``(True, what)`` when the warp output can reach ``device`` through GL sharing, else
    ``(False, why not)``.

    Checks, in order: the device lists ``cl_khr_gl_sharing``; PyOpenCL was built with GL
    interop (``pyopencl.have_gl()``); the warp's GL context is EGL (the context handles are
    taken from EGL); the GL renderer and the OpenCL platform come from the same vendor (GL
    sharing works within one driver). ``device`` defaults to the chosen OpenCL device and
    ``gl_ctx`` to the shared offscreen GL context (created if need be).
    """
    cl = import_pyopencl()
    from ..errors import DeviceError

    try:
        device = device if device is not None else choose_device()
    except DeviceError as exc:
        return False, f"no OpenCL device ({exc})"
    name = device.name.strip()
    exts = set(device.extensions.split())
    if not exts.intersection(SHARING_EXTENSIONS):
        return False, f"{name} has no cl_khr_gl_sharing"
    if not cl.have_gl():
        return False, ("PyOpenCL was built without OpenGL interop (pyopencl.have_gl() is "
                       "False; the PyPI wheels are): build it with CL_ENABLE_GL=1")
    from ..gl.runtime import context_api, create_context

    if gl_ctx is None:
        try:
            gl_ctx = create_context()
        except DeviceError as exc:
            return False, f"no OpenGL context ({exc})"
    if context_api() != "egl":
        return False, "the GL warp runs in a native (GLX/WGL/CGL) context; sharing is wired for EGL"
    gl_vendor = str(gl_ctx.info.get("GL_VENDOR", ""))
    cl_vendor = device.platform.vendor.strip()
    if _vendor_key(gl_vendor) != _vendor_key(cl_vendor):
        return False, (f"the GL warp runs on {gl_vendor!r} but the OpenCL device is from "
                       f"{cl_vendor!r} (sharing needs one driver)")
    return True, f"cl_khr_gl_sharing on {name} with {gl_ctx.info.get('GL_RENDERER')}"


def _egl_current() -> tuple[int, int]:
    """The current EGL context and display handles (the shared GL context is current)."""
    from ..gl.runtime import egl_library

    lib = ctypes.CDLL(egl_library())
    lib.eglGetCurrentContext.restype = ctypes.c_void_p
    lib.eglGetCurrentDisplay.restype = ctypes.c_void_p
    return lib.eglGetCurrentContext() or 0, lib.eglGetCurrentDisplay() or 0


class GLShare:
    """An OpenCL runtime sharing the warp's EGL context, and the warp's renderbuffer as an image.

    Only built where :func:`gl_sharing_status` is true. :attr:`runtime` replaces the process
    runtime for the Compensator's solver (its buffers must live in the sharing context).
    """

    def __init__(self, gl_ctx, device):
        cl = import_pyopencl()
        gl_ctx.__enter__()                      # make it current: EGL reports the current one
        egl_ctx, egl_dpy = _egl_current()
        if not egl_ctx or not egl_dpy:
            raise RuntimeError("no current EGL context to share")
        cp = cl.context_properties
        props = [(cp.PLATFORM, device.platform), (cp.GL_CONTEXT_KHR, ctypes.c_void_p(egl_ctx)),
                 (cp.EGL_DISPLAY_KHR, ctypes.c_void_p(egl_dpy))]
        self.gl_ctx = gl_ctx
        self.runtime = ClRuntime(device, properties=props)
        self._image = None
        self._rbo = None

    def fill_codes(self, codes, size: tuple[int, int]) -> None:
        """Convert the shared warp's renderbuffer (RGBA8, its last frame) into ``codes`` (the
        solver's uint8 buffer, :attr:`ClSolveOps.codes`) on the device. GL must be finished with
        it first: without cl_khr_gl_event the acquire does not wait for GL (the spec asks for
        glFinish)."""
        from ..gl.warp import shared_renderbuffer

        cl = import_pyopencl()
        rbo = shared_renderbuffer(size)
        if rbo is None:
            raise RuntimeError("the GL warp has not rendered a frame yet")
        if self._rbo is not rbo:                  # one CL image per GL renderbuffer
            self._image = cl.GLRenderBuffer(self.runtime.context, cl.mem_flags.READ_ONLY, rbo.glo)
            self._rbo = rbo
        self.gl_ctx.finish()
        q = self.runtime.queue
        cl.enqueue_acquire_gl_objects(q, [self._image])
        rgba_image_to_codes(self.runtime, self._image, codes, size)
        cl.enqueue_release_gl_objects(q, [self._image])


def open_gl_share(gl_ctx=None, device=None) -> GLShare | None:
    """A :class:`GLShare` where the driver allows, else None; logs one line naming the path."""
    ok, why = gl_sharing_status(device, gl_ctx)
    if ok:
        try:
            from ..gl.runtime import create_context

            share = GLShare(gl_ctx or create_context(), device or choose_device())
            log.info("warp -> OpenCL: GL sharing (%s)", why)
            return share
        except Exception as exc:  # the driver refused after all: the read-back path works
            why = f"creating the sharing context failed: {exc}"
    log.info("warp -> OpenCL: read-back to the host (%s)", why)
    return None
