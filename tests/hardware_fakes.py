"""A projector and a camera that misbehave the way real ones do, for the hardware tests.

:class:`FakeProjector` stands in for the projector window: it records what was shown and
when. :class:`FakeCapture` stands in for ``cv2.VideoCapture`` and films it:

* frames are exposed at the camera's rate and reach the reader ``delay`` seconds later (an IP
  camera's or phone's buffering: after a pattern change the reader gets stale frames for
  ``delay`` seconds);
* the driver keeps a queue of ``queue`` frames and ignores ``CAP_PROP_BUFFERSIZE`` (it reads
  back 4): after the reader pauses, the oldest frames come out first (V4L2 drops the newest
  when its queue is full);
* modes depend on the pixel format: uncompressed YUYV tops out at 640x480 at 30 fps and gives
  1280x720 at 10 fps only; MJPG gives 1280x720 and 1920x1080 at 30 fps; a change of format,
  size or rate after streaming began restarts the stream, which resets the controls;
* controls with backend-specific values (V4L2 auto-exposure 1/3, DirectShow 0.25/0.75); some
  are refused (``refuse``), some accepted and ignored (``ignore``); auto-exposure drifts;
* a freshly opened device (a re-open after failed reads) starts with the default controls.
"""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np

MODES = {  # fourcc -> {(w, h): fps}
    "YUYV": {(320, 240): 30.0, (640, 480): 30.0, (1280, 720): 10.0},
    "MJPG": {(320, 240): 30.0, (640, 480): 30.0, (1280, 720): 30.0, (1920, 1080): 30.0},
}
AE = {"V4L2": (1.0, 3.0), "DSHOW": (0.25, 0.75), "MSMF": (0.25, 0.75)}  # (manual, auto)


def fourcc_int(text: str) -> int:
    return int(cv2.VideoWriter_fourcc(*text))


class FakeProjector:
    """The projector window's interface (``size``, ``show -> time``, ``poll``, ``wait``,
    ``should_close``, ``refresh_rate``, ``close``) recording a timeline of what was shown."""

    def __init__(self, size=(160, 120), refresh_rate=60.0, lag=0.0):
        self.size = tuple(size)
        self.refresh_rate = refresh_rate
        self.lag = lag                      # the projector's own input lag
        self.should_close = False
        self.timeline = [(0.0, np.zeros((size[1], size[0], 3), np.uint8))]
        self.keys: list[str] = []
        self._lock = threading.Lock()

    def show(self, frame):
        t = time.perf_counter()
        with self._lock:
            self.timeline.append((t + self.lag, np.asarray(frame)))
        return t

    def shown_at(self, t):
        with self._lock:
            shown = self.timeline[0][1]
            for ts, frame in self.timeline:
                if ts <= t:
                    shown = frame
                else:
                    break
            return shown

    def poll(self):
        keys, self.keys = self.keys, []
        return keys

    def wait(self, seconds):
        time.sleep(max(0.0, seconds))

    def close(self):
        self.should_close = True


class FakeCapture:
    """``cv2.VideoCapture``-like camera filming a :class:`FakeProjector`."""

    def __init__(self, projector: FakeProjector, *, backend="V4L2", fourcc="YUYV", size=(320, 240),
                 delay=0.5, queue=4, rect=(0.15, 0.1, 0.7, 0.8), refuse=(cv2.CAP_PROP_AUTOFOCUS,),
                 ignore=(cv2.CAP_PROP_SHARPNESS,), noise=1.0, fail_reads=0, seed=0, world=None):
        self.projector, self.backend = projector, backend
        self.delay, self.queue, self.rect = delay, queue, rect
        self.refuse, self.ignore = set(refuse), set(ignore)
        self.noise, self.fail_reads = noise, fail_reads
        self._noise: np.ndarray | None = None     # a noise field reused frame to frame
        self.frozen_at: float | None = None   # a stuck stream repeats what it saw then
        # world(pattern) -> RGB camera frame at the nominal exposure (e.g. the simulator's
        # capture); rendered once per pattern shown.
        self.world, self._world_cache = world, (None, None)
        self.fourcc, self.size = fourcc, tuple(size)
        self.fps = MODES[fourcc][self.size]
        self.rng = np.random.default_rng(seed)
        self.opened = True
        self.restarts = 0
        self.set_log: list[tuple[int, float]] = []
        self._reset_controls()
        self._start()

    # --------------------------------------------------------------- device state
    def _reset_controls(self):
        ae_auto = AE.get(self.backend, (1.0, 3.0))[1]
        self.props = {cv2.CAP_PROP_AUTO_EXPOSURE: ae_auto, cv2.CAP_PROP_EXPOSURE: 156.0
                      if self.backend == "V4L2" else -6.0,
                      cv2.CAP_PROP_AUTO_WB: 1.0, cv2.CAP_PROP_WB_TEMPERATURE: 4600.0,
                      cv2.CAP_PROP_AUTOFOCUS: 1.0, cv2.CAP_PROP_FOCUS: 30.0,
                      cv2.CAP_PROP_SHARPNESS: 128.0, cv2.CAP_PROP_BACKLIGHT: 1.0,
                      cv2.CAP_PROP_BUFFERSIZE: 4.0, cv2.CAP_PROP_GAIN: 0.0}

    def _start(self):
        self.t0 = time.perf_counter()
        self.produced = 0                   # next frame index to arrive
        self.queued: list[int] = []
        self.streaming = False

    def _restart(self):
        """A format change after streaming began restarts the stream: controls reset."""
        self.restarts += 1
        self._reset_controls()
        self._start()

    # --------------------------------------------------------------- cv2 API
    def isOpened(self):
        return self.opened

    def getBackendName(self):
        return self.backend

    def release(self):
        self.opened = False

    def get(self, prop):
        if prop == cv2.CAP_PROP_FRAME_WIDTH:
            return float(self.size[0])
        if prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return float(self.size[1])
        if prop == cv2.CAP_PROP_FPS:
            return float(self.fps)
        if prop == cv2.CAP_PROP_FOURCC:
            return float(fourcc_int(self.fourcc))
        return float(self.props.get(prop, -1.0))

    def set(self, prop, value):
        self.set_log.append((prop, value))
        if prop in self.refuse:
            return False
        if prop in self.ignore or prop == cv2.CAP_PROP_BUFFERSIZE:
            return True                     # accepted, no effect
        if prop in (cv2.CAP_PROP_FOURCC, cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT,
                    cv2.CAP_PROP_FPS):
            self._set_format(prop, value)
            return True
        if prop == cv2.CAP_PROP_AUTO_EXPOSURE and value not in AE.get(self.backend, ()):
            return False                    # a value of another backend's convention
        self.props[prop] = float(value)
        return True

    def _set_format(self, prop, value):
        fourcc, (w, h) = self.fourcc, self.size
        if prop == cv2.CAP_PROP_FOURCC:
            code = int(value)
            text = "".join(chr((code >> 8 * i) & 0xFF) for i in range(4))
            if text in MODES and text != fourcc:
                fourcc, w, h = text, 640, 480   # a new format starts at its default size
        elif prop == cv2.CAP_PROP_FRAME_WIDTH:
            w = int(value)
        elif prop == cv2.CAP_PROP_FRAME_HEIGHT:
            h = int(value)
        elif prop == cv2.CAP_PROP_FPS:
            return                          # the rate follows the mode
        modes = MODES[fourcc]
        # The nearest mode of this format (a width set before its height lands on some mode).
        size = min(modes, key=lambda m: abs(m[0] - w) + abs(m[1] - h))
        changed = (fourcc, size) != (self.fourcc, self.size)
        self.fourcc, self.size, self.fps = fourcc, size, modes[size]
        if changed and self.streaming:
            self._restart()

    def _advance(self, now):
        period = 1.0 / self.fps
        last = int(np.floor((now - self.delay - self.t0) / period))
        while self.produced <= last:
            if len(self.queued) < self.queue:
                self.queued.append(self.produced)
            self.produced += 1              # else dropped: the queue keeps its old frames

    def _next_index(self):
        self.streaming = True
        now = time.perf_counter()
        self._advance(now)
        if not self.queued:
            due = self.t0 + self.produced / self.fps + self.delay
            time.sleep(max(0.0, due - now))
            self._advance(max(time.perf_counter(), due))
        return self.queued.pop(0)

    def grab(self):
        if not self.opened:
            return False
        if self.fail_reads > 0:
            self.fail_reads -= 1
            return False
        self._next_index()
        return True

    def read(self):
        if not self.opened:
            return False, None
        if self.fail_reads > 0:
            self.fail_reads -= 1
            return False, None
        k = self._next_index()
        return True, self._render(self.t0 + k / self.fps)

    # --------------------------------------------------------------- picture
    def gain(self, t):
        manual = AE.get(self.backend, (1.0, 3.0))[0]
        if self.props[cv2.CAP_PROP_AUTO_EXPOSURE] == manual:
            e = self.props[cv2.CAP_PROP_EXPOSURE]
            seconds = e * 1e-4 if self.backend == "V4L2" else 2.0 ** e
            return min(4.0, seconds / 0.02)
        return 0.7 + 0.25 * np.sin(2 * np.pi * t / 2.0)   # auto-exposure hunting

    def _render(self, t):
        """Grey picture of what the projector showed at ``t`` (cheap: a reader at 30 fps must
        keep up, as with a real camera)."""
        pattern = self.projector.shown_at(t if self.frozen_at is None else min(t, self.frozen_at))
        if self.world is not None:
            if self._world_cache[0] is not pattern:
                self._world_cache = (pattern, self.world(pattern).astype(np.float32))
            scale = self.gain(t) / (1 / 60 / 0.02)        # 1 at one 60 Hz frame period
            rgb = np.clip(self._world_cache[1] * scale, 0, 255).astype(np.uint8)
            return rgb[:, :, ::-1].copy()
        w, h = self.size
        x, y, rw, rh = self.rect
        x0, y0, x1, y1 = int(x * w), int(y * h), int((x + rw) * w), int((y + rh) * h)
        levels = np.arange(256, dtype=np.float32) / 255.0
        lut = 255.0 * np.clip(0.01 + self.gain(t) * 0.8 * levels ** 2.2, 0, 1) ** (1 / 2.2)
        out = np.full((h, w), 255.0 * 0.01 ** (1 / 2.2), np.float32)
        if x1 > x0 and y1 > y0:
            g = pattern[:, :, 1]
            inside = cv2.GaussianBlur(cv2.resize(g, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA),
                                      (5, 5), 1.0)
            out[y0:y1, x0:x1] = lut[inside]
        if self.noise:
            if self._noise is None or self._noise.shape != out.shape:
                self._noise = self.rng.normal(0, self.noise, (2 * h, w)).astype(np.float32)
            k = int(self.rng.integers(0, h))
            out += self._noise[k:k + h]
        g8 = np.clip(out, 0, 255).astype(np.uint8)
        return cv2.merge([g8, g8, g8])          # BGR, as OpenCV


class FakeDevice:
    """A camera that can be opened several times (``capture_factory``): each open is a fresh
    stream with the default controls, as a re-plugged or re-opened webcam."""

    def __init__(self, projector: FakeProjector, **kwargs):
        self.projector, self.kwargs = projector, kwargs
        self.opened: list[FakeCapture] = []

    def __call__(self, source):
        cap = FakeCapture(self.projector, **self.kwargs)
        self.kwargs["fail_reads"] = 0        # only the first stream has the hiccup
        self.opened.append(cap)
        return cap

    @property
    def cap(self) -> FakeCapture:
        return self.opened[-1]
