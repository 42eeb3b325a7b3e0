"""The projector window: a full-screen glfw window on a chosen monitor, presenting RGB frames.

One class serves the player (compensated frames) and :class:`rtdefocus.HardwareProCam`
(calibration patterns). Frames are uploaded as a texture and drawn by ``kernels/present.glsl``
pixel for pixel when their size matches the window.

Contexts. The Compensator's OpenGL work runs in the process's offscreen context
(:func:`rtdefocus.gl.runtime.create_context`) on the same thread as this window, and the window's
context uses the same API (:func:`rtdefocus.gl.runtime.context_api`): EGL on Linux by default
(on X11 a GLX context cannot be made current once an EGL one has been: BadAccess), the
platform's native one (GLX, WGL on Windows, CGL on macOS) otherwise. moderngl runs on the
window's context through glfw's loader. Every window operation saves the thread's current
context, makes the window's current, and restores the saved one afterwards: code that expects
its offscreen context to stay current keeps working.

Keys are collected by glfw's callback into a queue and handed out by :meth:`ProjectorWindow.poll`
as names (``"space"``, ``"left"``, ``"right"``, ``"escape"``, letters ``"a"``..``"z"``);
:meth:`ProjectorWindow.inject_key` puts a name in the same queue, so tests drive the very
same path without a keyboard.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from contextlib import contextmanager

import numpy as np

from ..errors import DeviceError, InputError
from .current import current_context_keeper
from .runtime import load_program, read_rgb

log = logging.getLogger(__name__)

_glfw_users = 0  # glfw is initialised while at least one window is open


def _key_name(key: int) -> str | None:
    import glfw

    names = {glfw.KEY_SPACE: "space", glfw.KEY_LEFT: "left", glfw.KEY_RIGHT: "right",
             glfw.KEY_UP: "up", glfw.KEY_DOWN: "down", glfw.KEY_ESCAPE: "escape",
             glfw.KEY_ENTER: "enter", glfw.KEY_TAB: "tab",
             # presentation clickers send Page Up / Page Down
             glfw.KEY_PAGE_UP: "left", glfw.KEY_PAGE_DOWN: "right"}
    if key in names:
        return names[key]
    if glfw.KEY_A <= key <= glfw.KEY_Z:
        return chr(ord("a") + key - glfw.KEY_A)
    if glfw.KEY_0 <= key <= glfw.KEY_9:
        return chr(ord("0") + key - glfw.KEY_0)
    return None


def monitor_info() -> list[dict]:
    """Every connected monitor: ``index``, ``name``, ``size`` and ``refresh`` of its current
    video mode, ``position`` on the desktop, ``scale`` (the desktop's content scale: 1.0 means
    no scaling) and ``modes``, the distinct ``(width, height, refresh)`` it offers, largest first.

    Raises
    ------
    DeviceError
        No display (glfw cannot start).
    """
    import glfw

    _glfw_acquire()
    try:
        out = []
        for i, mon in enumerate(glfw.get_monitors() or []):
            mode = glfw.get_video_mode(mon)
            name = glfw.get_monitor_name(mon)
            name = name.decode(errors="replace") if isinstance(name, bytes) else str(name)
            try:
                scale = tuple(float(v) for v in glfw.get_monitor_content_scale(mon))
            except Exception:  # noqa: BLE001 - older glfw builds
                scale = (1.0, 1.0)
            modes = sorted({(int(m.size.width), int(m.size.height), int(m.refresh_rate))
                            for m in (glfw.get_video_modes(mon) or [])}, reverse=True)
            out.append({"index": i, "name": name,
                        "size": (int(mode.size.width), int(mode.size.height)),
                        "refresh": int(mode.refresh_rate),
                        "position": tuple(int(v) for v in glfw.get_monitor_pos(mon)),
                        "scale": scale, "modes": modes})
        return out
    finally:
        _glfw_release()


def list_monitors() -> list[tuple[int, str, tuple[int, int]]]:
    """``[(index, name, (width, height)), ...]`` of the connected monitors (current video mode)."""
    return [(m["index"], m["name"], m["size"]) for m in monitor_info()]


def _glfw_acquire() -> None:
    global _glfw_users
    import glfw

    if _glfw_users == 0:
        glfw.set_error_callback(lambda code, desc: log.debug("glfw error %s: %s", code, desc))
        if not glfw.init():
            raise DeviceError("cannot initialise glfw: no display. Run on the machine's desktop, "
                              "or set DISPLAY (X11) / WAYLAND_DISPLAY; for tests use Xvfb")
    _glfw_users += 1


def _glfw_release() -> None:
    global _glfw_users
    import glfw

    _glfw_users -= 1
    if _glfw_users == 0:
        glfw.terminate()


class _WindowLoader:
    """moderngl's context interface over a glfw window: GL functions through glfw, and
    ``with ctx:`` makes the window's context current and restores the previous one."""

    def __init__(self, window, egl):
        self.window, self.egl, self._saved = window, egl, []

    def load_opengl_function(self, name: str) -> int:
        import glfw

        return glfw.get_proc_address(name) or 0

    def __enter__(self):
        import glfw

        self._saved.append(self.egl.save())
        glfw.make_context_current(self.window)

    def __exit__(self, *exc):
        self.egl.restore(self._saved.pop())

    def release(self):
        pass


class ProjectorWindow:
    """A window that shows RGB uint8 frames: full-screen on monitor ``screen``, or windowed.

    Parameters
    ----------
    screen : int
        Monitor index (0 = primary; :func:`list_monitors` lists them). Full-screen only.
    fullscreen : bool
        Full-screen at the monitor's current video mode (its size is :attr:`size`), or a plain
        window of ``size`` (tests, previews).
    size : (width, height), optional
        Window size when not full-screen (default 800x600).
    title : str
    vsync : bool
        Wait for the monitor's refresh on each frame (no tearing on the projector).
    visible : bool
        Show the window (a hidden one still renders; tests may use it).

    Raises
    ------
    DeviceError
        No display, no EGL (or native) OpenGL, or no OpenGL 3.3 context.
    InputError
        ``screen`` is not a connected monitor.
    """

    def __init__(self, screen: int = 0, *, fullscreen: bool = True, size: tuple[int, int] | None = None,
                 title: str = "rtdefocus", vsync: bool = True, visible: bool = True):
        import glfw
        import moderngl

        from .runtime import context_api

        self.api = context_api()
        self._egl = current_context_keeper(self.api)
        self._win = None
        self._keys: deque[str] = deque(maxlen=256)
        self._frame: np.ndarray | None = None
        self._warped = None            # arguments of the last show_warped (for read())
        self._warp = None
        self._tex = None
        self._prog = self._vao = None
        self.ctx = None
        self._rect_key = self._rect = None   # display rect of the last show_warped input
        self._glfw_held = False
        #: The monitor's refresh rate in Hz (60 when windowed or unknown): the projector's
        #: frame period for camera exposures.
        self.refresh_rate = 60.0
        self.monitor_name: str | None = None
        _glfw_acquire()
        self._glfw_held = True
        saved = self._egl.save()  # creating a glfw window un-currents the caller's context
        try:
            monitor = None
            if fullscreen:
                monitors = glfw.get_monitors() or []
                if not 0 <= screen < len(monitors):
                    listing = "; ".join(f"{i}: {n} {w}x{h}" for i, n, (w, h) in self._describe(monitors))
                    raise InputError(f"screen {screen} is not connected; monitors: {listing or 'none'}. "
                                     "Pick the projector's index with --screen")
                monitor = monitors[screen]
                name = glfw.get_monitor_name(monitor)
                self.monitor_name = name.decode(errors="replace") if isinstance(name, bytes) else str(name)
                mode = glfw.get_video_mode(monitor)
                w, h = int(mode.size.width), int(mode.size.height)
                glfw.window_hint(glfw.RED_BITS, mode.bits.red)
                glfw.window_hint(glfw.GREEN_BITS, mode.bits.green)
                glfw.window_hint(glfw.BLUE_BITS, mode.bits.blue)
                glfw.window_hint(glfw.REFRESH_RATE, mode.refresh_rate)
                self.refresh_rate = float(mode.refresh_rate) or 60.0
                # Do not minimise the projector's window when the operator clicks on the laptop.
                glfw.window_hint(glfw.AUTO_ICONIFY, glfw.FALSE)
            else:
                w, h = size or (800, 600)
            glfw.window_hint(glfw.CONTEXT_CREATION_API, glfw.EGL_CONTEXT_API if self.api == "egl"
                             else glfw.NATIVE_CONTEXT_API)
            glfw.window_hint(glfw.CLIENT_API, glfw.OPENGL_API)
            glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
            glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
            glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
            glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, glfw.TRUE)
            glfw.window_hint(glfw.VISIBLE, glfw.TRUE if visible else glfw.FALSE)
            glfw.window_hint(glfw.RESIZABLE, glfw.FALSE)
            self._win = glfw.create_window(int(w), int(h), title, monitor, None)
            glfw.default_window_hints()
            if not self._win:
                other = "native" if self.api == "egl" else "egl"
                raise DeviceError(f"cannot open an OpenGL 3.3 window through {self.api} on this "
                                  "display; check `rtdefocus info` and the graphics driver, or try "
                                  f"RTDEFOCUS_GL={other}")
            glfw.set_key_callback(self._win, self._on_key)
            glfw.set_framebuffer_size_callback(self._win, self._on_resize)
            if fullscreen:
                glfw.set_input_mode(self._win, glfw.CURSOR, glfw.CURSOR_HIDDEN)
            glfw.make_context_current(self._win)
            glfw.swap_interval(1 if vsync else 0)
            self._loader = _WindowLoader(self._win, self._egl)
            moderngl.init_context(self._loader)
            self.ctx = moderngl.get_context()
            self._prog = load_program(self.ctx, "present.glsl")
            self._vao = self.ctx.vertex_array(self._prog, [])
            fb = glfw.get_framebuffer_size(self._win)
            self.size: tuple[int, int] = (int(fb[0]), int(fb[1]))
            self.ctx.clear(0.0, 0.0, 0.0, 1.0)
            glfw.swap_buffers(self._win)
        except BaseException:
            self._destroy()
            raise
        finally:
            self._egl.restore(saved)
        self.fullscreen, self.screen = fullscreen, screen
        log.info("projector window %dx%d (%s)", *self.size,
                 f"full-screen on monitor {screen}" if fullscreen else "windowed")

    @staticmethod
    def _describe(monitors):
        import glfw

        for i, mon in enumerate(monitors):
            mode = glfw.get_video_mode(mon)
            name = glfw.get_monitor_name(mon)
            name = name.decode(errors="replace") if isinstance(name, bytes) else str(name)
            yield i, name, (mode.size.width, mode.size.height)

    # ------------------------------------------------------------------ size
    def _on_resize(self, window, width, height) -> None:
        size = (int(width), int(height))
        if size != self.size and width > 0 and height > 0:
            log.warning("projector window framebuffer changed from %dx%d to %dx%d", *self.size, *size)
            self.size = size

    def final_size(self, timeout: float = 2.0, stable: float = 0.3) -> tuple[int, int]:
        """Poll the framebuffer size until it has not changed for ``stable`` seconds (at most
        ``timeout``): Wayland compositors switch to full-screen a moment after the window maps,
        and desktop scaling changes the framebuffer then. Returns (and sets) :attr:`size`."""
        import glfw

        if self._win is None:
            return self.size
        end = time.perf_counter() + timeout
        last, since = None, time.perf_counter()
        while True:
            glfw.poll_events()
            fb = glfw.get_framebuffer_size(self._win)
            size = (int(fb[0]), int(fb[1]))
            now = time.perf_counter()
            if size != last:
                last, since = size, now
            if now - since >= stable or now >= end:
                break
            time.sleep(0.02)
        if last[0] > 0 and last[1] > 0:
            self._on_resize(self._win, *last)
        return self.size

    # ------------------------------------------------------------------ keys
    def _on_key(self, window, key, scancode, action, mods) -> None:
        import glfw

        if action in (glfw.PRESS, glfw.REPEAT):
            name = _key_name(key)
            if name is not None:
                self._keys.append(name)

    def inject_key(self, name: str) -> None:
        """Queue a key as if it had been pressed (tests, remote control)."""
        self._keys.append(name)

    def poll(self) -> list[str]:
        """Process window events; return the keys pressed since the last call, oldest first.
        A click on the window's close button comes out as ``"close"``."""
        import glfw

        if self._win is None:
            return ["close"]
        glfw.poll_events()
        keys = list(self._keys)
        self._keys.clear()
        if glfw.window_should_close(self._win):
            keys.append("close")
        return keys

    def wait(self, seconds: float) -> None:
        """Wait ``seconds`` while keeping the window responsive (keys stay queued)."""
        import glfw

        end = time.perf_counter() + max(0.0, seconds)
        while (left := end - time.perf_counter()) > 0:
            glfw.wait_events_timeout(min(left, 0.05))

    @property
    def should_close(self) -> bool:
        import glfw

        return self._win is None or bool(glfw.window_should_close(self._win))

    # ------------------------------------------------------------------ frames
    @contextmanager
    def _current(self):
        with self.ctx:
            yield

    def _draw(self) -> None:
        import moderngl

        frame = self._frame
        ctx = self.ctx
        ctx.screen.use()
        ctx.viewport = (0, 0, *self.size)
        ctx.clear(0.0, 0.0, 0.0, 1.0)
        if frame is None:
            return
        fh, fw = frame.shape[:2]
        W, H = self.size
        scale = min(W / fw, H / fh)
        vw, vh = max(1, round(fw * scale)), max(1, round(fh * scale))
        vx, vy = (W - vw) // 2, (H - vh) // 2
        ctx.viewport = (vx, vy, vw, vh)
        nearest = (vw, vh) == (fw, fh)
        f = moderngl.NEAREST if nearest else moderngl.LINEAR
        self._tex.filter = (f, f)
        self._tex.use(0)
        self._prog["u_frame"] = 0
        self._vao.render(moderngl.TRIANGLES, vertices=3)
        ctx.viewport = (0, 0, W, H)

    def show(self, frame: np.ndarray) -> float:
        """Present ``frame`` ((H, W, 3) uint8 RGB) now: letterboxed when its size differs from
        the window's, pixel for pixel when it matches. Also processes window events.

        Blocks until the swap is done (``glFinish`` after the swap: with vsync, until the frame
        is scanned out) and returns that ``time.perf_counter()``, the moment a camera's settle
        time starts from."""
        import glfw

        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise InputError(f"window frames must be (H, W, 3) uint8 RGB; got {frame.shape} {frame.dtype}")
        if self._win is None:
            raise InputError("the projector window is closed")
        frame = np.ascontiguousarray(frame)
        with self._current():
            fh, fw = frame.shape[:2]
            if self._tex is None or self._tex.size != (fw, fh):
                if self._tex is not None:
                    self._tex.release()
                self._tex = self.ctx.texture((fw, fh), 3, alignment=1)
            self._tex.write(frame, alignment=1)
            self._frame, self._warped = frame, None
            self._draw()
            glfw.swap_buffers(self._win)
            self.ctx.finish()
            shown = time.perf_counter()
        glfw.poll_events()
        return shown

    def show_warped(self, image: np.ndarray, calib, rect=None) -> None:
        """Geometry correction straight into the window: the warp shader
        (:class:`rtdefocus.gl.warp.GLWarp`) renders ``image`` into this window's framebuffer,
        with no offscreen pass, read-back or re-upload.

        Parameters
        ----------
        image : (H, W, 3) uint8 RGB, any size.
        calib : rtdefocus.Calibration whose ``projector_size`` is this window's :attr:`size`.
        rect : (x0, y0, w, h), optional
            Camera-pixel display rectangle; default ``calib.display_rect((W, H))`` (computed
            once per input size and calibration).
        """
        import glfw

        from .warp import GLWarp

        if self._win is None:
            raise InputError("the projector window is closed")
        if tuple(calib.projector_size) != self.size:
            raise InputError(f"the calibration is for a {calib.projector_size[0]}x"
                             f"{calib.projector_size[1]} projector but this window is "
                             f"{self.size[0]}x{self.size[1]}; use show(comp.warp(image))")
        image = np.ascontiguousarray(image)
        if rect is None:
            key = (id(calib), image.shape[1], image.shape[0])
            if self._rect_key != key:
                self._rect_key, self._rect = key, calib.display_rect((image.shape[1], image.shape[0]))
            rect = self._rect
        with self._current():
            if self._warp is None:
                self._warp = GLWarp(self.ctx, self.size)
            self._warped = (image, calib.H_cam_from_proj, calib.layout, rect,
                            calib.residual_dense())
            self._frame = None
            self._warp.render_to(self.ctx.screen, *self._warped)
            glfw.swap_buffers(self._win)
        glfw.poll_events()

    def read(self) -> np.ndarray:
        """What the window shows, read back from its framebuffer: (H, W, 3) uint8, top row first.

        The last picture (:meth:`show` or :meth:`show_warped`) is drawn again into the back
        buffer and read (after a swap the back buffer's content is undefined)."""
        with self._current():
            if self._frame is None and self._warped is not None:
                self._warp.render_to(self.ctx.screen, *self._warped)
            else:
                self._draw()
            self.ctx.finish()
            return read_rgb(self.ctx.screen, self.size)

    # ------------------------------------------------------------------ life
    def _destroy(self) -> None:
        import glfw

        if self._win is not None:
            saved = self._egl.save()
            try:
                if self.ctx is not None:
                    with self._current():
                        for obj in (self._tex, self._vao, self._prog, self._warp):
                            if obj is not None:
                                obj.release()
                    self._tex = self._vao = self._prog = self._warp = None
                glfw.destroy_window(self._win)
            finally:
                self._win = None
                self._egl.restore(saved)
        if self._glfw_held:
            self._glfw_held = False
            _glfw_release()

    def close(self) -> None:
        """Close the window (idempotent); glfw shuts down with the last window."""
        self._destroy()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        if getattr(self, "_win", None) is not None:
            log.debug("projector window garbage-collected without close()")
