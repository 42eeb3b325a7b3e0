"""moderngl contexts: EGL offscreen (tests, files) and GLSL program loading from ``kernels/``.

GLSL files hold both stages, ``#if defined VERTEX_SHADER`` / ``FRAGMENT_SHADER``; the loader
inserts the ``#version``, the stage define and ``#line 1`` so driver line numbers match the file.
"""

from __future__ import annotations

import logging
import threading

import numpy as np

from ..errors import DeviceError
from ..resources import kernel_source

log = logging.getLogger(__name__)

EGL_HINT = ("Install Mesa's EGL: on Debian/Ubuntu `sudo apt-get install libegl1 libegl-mesa0 "
            "libgl1-mesa-dri` (software llvmpipe works), or run on a machine with a GPU driver.")

_ctx = None
_ctx_lock = threading.Lock()


def create_context(standalone: bool = True, shared: bool = True):
    """An offscreen moderngl context through EGL (GL 3.3 core).

    With ``shared=True`` (default) one context per process is reused.
    Raises :class:`DeviceError` naming the fix when EGL or GL 3.3 is unavailable.
    """
    global _ctx
    import moderngl

    with _ctx_lock:
        if shared and _ctx is not None:
            return _ctx
        try:
            ctx = moderngl.create_context(standalone=standalone, backend="egl", require=330)
        except Exception as exc:  # glcontext raises plain Exception subclasses
            raise DeviceError(f"Cannot create an EGL OpenGL 3.3 context ({exc}). {EGL_HINT}") from exc
        log.info("OpenGL renderer: %s", ctx.info.get("GL_RENDERER"))
        if shared:
            _ctx = ctx
        return ctx


def gl_available() -> tuple[bool, str]:
    """``(True, renderer)`` when an EGL context can be made, else ``(False, reason)``."""
    try:
        ctx = create_context()
        return True, str(ctx.info.get("GL_RENDERER"))
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
