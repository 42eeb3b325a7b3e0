"""Save and restore the calling thread's current OpenGL context, per API.

The projector window makes its own context current for each operation and then puts back
whatever was current before (the process's offscreen context), so code that expects its
context to stay current keeps working. glfw can only restore contexts it created, hence these
small ctypes helpers, one per API: EGL (libEGL), GLX (libGL), WGL (opengl32), CGL (OpenGL
framework). Each has ``save() -> token`` and ``restore(token)``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import sys

from ..errors import DeviceError

log = logging.getLogger(__name__)

_EGL_DRAW, _EGL_READ = 0x3059, 0x305A


def _load_library(name: str, fallback: str, fix: str) -> ctypes.CDLL:
    """``lib<name>`` through ctypes, or a :class:`DeviceError` that says what needs it and the fix."""
    path = ctypes.util.find_library(name) or fallback
    try:
        return ctypes.CDLL(path)
    except OSError as exc:
        raise DeviceError(f"cannot load lib{name} ({exc}); {fix}") from exc


class _EglCurrent:
    """Save and restore the calling thread's current EGL context (ctypes on libEGL).

    Each context keeper (EGL, GLX, WGL, CGL) has ``save() -> token`` and ``restore(token)``."""

    def __init__(self) -> None:
        lib = _load_library("EGL", "libEGL.so.1",
                            "the EGL projector window needs it. On Debian/Ubuntu: `sudo apt-get "
                            "install libegl1 libegl-mesa0`; elsewhere use the native OpenGL "
                            "context (RTDEFOCUS_GL=native)")
        for fn in ("eglGetCurrentDisplay", "eglGetCurrentContext", "eglGetCurrentSurface"):
            getattr(lib, fn).restype = ctypes.c_void_p
        lib.eglGetCurrentSurface.argtypes = [ctypes.c_int]
        lib.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
        lib.eglMakeCurrent.restype = ctypes.c_uint
        self.lib = lib

    def save(self):
        lib = self.lib
        return (lib.eglGetCurrentDisplay(), lib.eglGetCurrentSurface(_EGL_DRAW),
                lib.eglGetCurrentSurface(_EGL_READ), lib.eglGetCurrentContext())

    def restore(self, saved) -> None:
        import glfw

        display, draw, read, context = saved
        if context:
            if not self.lib.eglMakeCurrent(display, draw, read, context):
                log.warning("could not restore the previous EGL context after a window operation")
        else:
            glfw.make_context_current(None)


class _GlxCurrent:
    """Save and restore the thread's current GLX context (ctypes on libGL)."""

    def __init__(self) -> None:
        lib = _load_library("GL", "libGL.so.1",
                            "the native OpenGL window needs it; install the OpenGL driver "
                            "(Debian/Ubuntu: `sudo apt-get install libgl1`) or use RTDEFOCUS_GL=egl")
        for fn in ("glXGetCurrentDisplay", "glXGetCurrentContext"):
            getattr(lib, fn).restype = ctypes.c_void_p
        lib.glXGetCurrentDrawable.restype = ctypes.c_ulong
        lib.glXMakeCurrent.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_void_p]
        self.lib = lib

    def save(self):
        lib = self.lib
        return lib.glXGetCurrentDisplay(), lib.glXGetCurrentDrawable(), lib.glXGetCurrentContext()

    def restore(self, saved) -> None:
        import glfw

        display, drawable, context = saved
        if context:
            if not self.lib.glXMakeCurrent(display, drawable, context):
                log.warning("could not restore the previous GLX context after a window operation")
        else:
            glfw.make_context_current(None)


class _WglCurrent:
    """Save and restore the thread's current WGL context (Windows, opengl32)."""

    def __init__(self) -> None:
        lib = ctypes.WinDLL("opengl32")  # type: ignore[attr-defined]
        lib.wglGetCurrentContext.restype = ctypes.c_void_p
        lib.wglGetCurrentDC.restype = ctypes.c_void_p
        lib.wglMakeCurrent.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        self.lib = lib

    def save(self):
        return self.lib.wglGetCurrentDC(), self.lib.wglGetCurrentContext()

    def restore(self, saved) -> None:
        self.lib.wglMakeCurrent(*saved)


class _CglCurrent:
    """Save and restore the thread's current CGL context (macOS, OpenGL.framework)."""

    def __init__(self) -> None:
        lib = ctypes.CDLL("/System/Library/Frameworks/OpenGL.framework/OpenGL")
        lib.CGLGetCurrentContext.restype = ctypes.c_void_p
        lib.CGLSetCurrentContext.argtypes = [ctypes.c_void_p]
        self.lib = lib

    def save(self):
        return self.lib.CGLGetCurrentContext()

    def restore(self, saved) -> None:
        self.lib.CGLSetCurrentContext(saved)


def current_context_keeper(api: str):
    """The save/restore helper for the window's context API (``"egl"`` or ``"native"``)."""
    if api == "egl":
        return _EglCurrent()
    if sys.platform == "win32":
        return _WglCurrent()
    if sys.platform == "darwin":
        return _CglCurrent()
    return _GlxCurrent()
