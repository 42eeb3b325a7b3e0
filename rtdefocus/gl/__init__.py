"""OpenGL side (moderngl): EGL offscreen context, the warp/stitch pass, the projector window."""

from .runtime import create_context, gl_available

__all__ = ["create_context", "gl_available"]
