"""moderngl contexts: offscreen (EGL or the platform's own OpenGL) and GLSL program loading.

Two context APIs, one per process (``RTDEFOCUS_GL`` picks, else the platform's default):

``egl``     headless EGL (Mesa, NVIDIA): Linux's default; needs no display, so tests, servers
            and file rendering use it. The projector window then uses glfw's EGL context too.
``native``  the platform's own API through a hidden window: GLX on Linux/X11, WGL on Windows,
            CGL on macOS (which has no EGL). Needs a display; the projector window uses glfw's
            native context.

The two cannot be mixed on one thread on X11 (a GLX context cannot be made current once an
EGL one has been: BadAccess), hence one API per process, chosen before the first context.

GLSL files hold both stages, ``#if defined VERTEX_SHADER`` / ``FRAGMENT_SHADER``; the loader
inserts the ``#version``, the stage define and ``#line 1`` so driver line numbers match the file.
"""

from __future__ import annotations

import ctypes.util
import logging
import os
import sys
import threading

import numpy as np

from ..errors import DeviceError
from ..resources import kernel_source

log = logging.getLogger(__name__)

EGL_HINT = ("Install Mesa's EGL: on Debian/Ubuntu `sudo apt-get install libegl1 libegl-mesa0 "
            "libgl1-mesa-dri` (software llvmpipe works), or run on a machine with a GPU driver; "
            "or use the platform's own OpenGL with RTDEFOCUS_GL=native (needs a display).")
NATIVE_HINT = ("The native OpenGL context needs a display (DISPLAY on X11) and an OpenGL 3.3 "
               "driver; on a headless Linux machine use RTDEFOCUS_GL=egl.")
GL_APIS = ("egl", "native")

_ctx = None
_ctx_api: str | None = None
_ctx_lock = threading.Lock()


def egl_library() -> str | None:
    """The EGL library's name when this platform has one (None on Windows, macOS, or when
    libEGL is not installed)."""
    if sys.platform in ("win32", "darwin"):
        return None
    return ctypes.util.find_library("EGL")


def default_api() -> str:
    """``RTDEFOCUS_GL`` when set, else ``"egl"`` where EGL exists, else ``"native"``."""
    env = os.environ.get("RTDEFOCUS_GL", "").strip().lower()
    if env:
        if env not in GL_APIS:
            raise DeviceError(f"RTDEFOCUS_GL must be one of {', '.join(GL_APIS)}; got {env!r}")
        return env
    return "egl" if egl_library() else "native"


def context_api() -> str:
    """The API of this process's shared context, or the one it would get (the projector window
    follows it: :mod:`rtdefocus.gl.window`)."""
    return _ctx_api or default_api()


def create_context(standalone: bool = True, shared: bool = True, api: str | None = None):
    """An offscreen moderngl context (GL 3.3 core) through ``api`` (default :func:`context_api`).

    With ``shared=True`` (default) one context per process is reused.
    Raises :class:`DeviceError` naming the fix when the API or GL 3.3 is unavailable.
    """
    global _ctx, _ctx_api
    import moderngl

    with _ctx_lock:
        if shared and _ctx is not None:
            return _ctx
        api = api or context_api()
        if api not in GL_APIS:
            raise DeviceError(f"OpenGL API must be one of {', '.join(GL_APIS)}; got {api!r}")
        if api == "egl" and egl_library() is None:
            raise DeviceError(f"EGL is not available on this platform ({sys.platform}: macOS and "
                              "Windows have none, and no libEGL was found). Use the platform's own "
                              "OpenGL: RTDEFOCUS_GL=native (the default where EGL is missing). "
                              + (EGL_HINT if sys.platform.startswith("linux") else ""))
        try:
            if api == "egl":
                ctx = moderngl.create_context(standalone=standalone, backend="egl", require=330)
            else:  # glcontext's platform default: x11 (GLX), wgl, darwin (CGL)
                ctx = moderngl.create_context(standalone=standalone, require=330)
        except Exception as exc:  # glcontext raises plain Exception subclasses
            what = "an EGL" if api == "egl" else "a native (GLX/WGL/CGL)"
            raise DeviceError(f"Cannot create {what} OpenGL 3.3 context ({exc}). "
                              f"{EGL_HINT if api == 'egl' else NATIVE_HINT}") from exc
        log.info("OpenGL renderer (%s): %s", api, ctx.info.get("GL_RENDERER"))
        if shared:
            _ctx, _ctx_api = ctx, api
        return ctx


def gl_available() -> tuple[bool, str]:
    """``(True, renderer)`` when an offscreen context can be made, else ``(False, reason)``."""
    try:
        ctx = create_context()
        return True, f"{ctx.info.get('GL_RENDERER')} ({context_api()})"
    except DeviceError as exc:
        return False, str(exc)


def load_program(ctx, filename: str, defines: dict | None = None):
    """Compile ``kernels/<filename>`` (both stages) into a moderngl program."""
    src = kernel_source(filename)
    extra = "".join(f"#define {k} {v}\n" for k, v in (defines or {}).items())

    def stage(name: str) -> str:
        return f"#version 330 core\n#define {name} 1\n{extra}#line 1\n{src}"

    try:
        return ctx.program(vertex_shader=stage("VERTEX_SHADER"),
                           fragment_shader=stage("FRAGMENT_SHADER"))
    except Exception as exc:
        raise DeviceError(f"GLSL program {filename!r} failed to compile/link:\n{exc}") from exc


def read_rgb(fbo, size: tuple[int, int], components: int = 3, dtype: str = "f1") -> np.ndarray:
    """Read a framebuffer back as an ``(H, W, C)`` array, top row first.

    GL's origin is the bottom-left; this is the one place the read-back is flipped.
    """
    w, h = size
    np_dtype = {"f1": np.uint8, "f4": np.float32}[dtype]
    data = fbo.read(components=components, dtype=dtype, alignment=1)
    return np.frombuffer(data, dtype=np_dtype).reshape(h, w, components)[::-1].copy()
