"""Sound for a video, and the clock that picks its frames.

A video with sound is shown by the *audio clock*: the position of the sample the audience hears
now. The sound card consumes samples at its own pace, so following its position keeps picture
and sound together however long the film is (a wall clock drifts from the card's crystal by
tens of milliseconds per minute, and stalls of the solver would add up).

:class:`AudioOutput` is that contract: the video source writes decoded samples with
:meth:`~AudioOutput.write`, calls :meth:`~AudioOutput.end` after the last one, and asks
:meth:`~AudioOutput.position` which instant of the stream is heard. Once the last sample has
played, the position runs on at wall time (the picture may outlast the sound).

Outputs: :class:`SoundDeviceOutput` (PortAudio through ``sounddevice``, the ``show`` extra),
and :class:`WallClock` (no sound: ``--no-audio``, a video without a sound track, or no sound
device), whose position is wall time. :func:`open_audio_output` picks one.
"""

from __future__ import annotations

import collections
import logging
import threading
import time

import numpy as np

log = logging.getLogger(__name__)


class AudioOutput:
    """Plays float32 samples and counts what was played (the base keeps the count and the
    end-of-stream wall extrapolation; subclasses consume samples with :meth:`_take`).

    Attributes
    ----------
    rate : int
        Samples per second per channel the output wants.
    channels : int
    """

    rate = 48000
    channels = 2

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._chunks: collections.deque[np.ndarray] = collections.deque()
        self._offset = 0               # samples of _chunks[0] already played
        self._buffered = 0
        self._played = 0               # samples consumed, silence after the end included
        self._ended = False
        self._drained_at: float | None = None   # wall time the last sample played

    # -------------------------------------------------------------- producer side
    def write(self, samples: np.ndarray) -> None:
        """Queue ``samples`` ((n, channels) float32 in [-1, 1]) for playback."""
        samples = np.ascontiguousarray(samples, np.float32).reshape(-1, self.channels)
        with self._lock:
            self._chunks.append(samples)
            self._buffered += len(samples)

    def end(self) -> None:
        """No more samples: once the queue has played, the position runs on at wall time."""
        with self._lock:
            self._ended = True
            if self._buffered == 0 and self._drained_at is None:
                self._drained_at = time.perf_counter()

    def buffered(self) -> float:
        """Seconds queued and not yet played."""
        return self._buffered / self.rate

    def position(self) -> float:
        """Seconds of sound played since the first sample."""
        with self._lock:
            pos = self._played / self.rate
            if self._drained_at is not None:
                pos += time.perf_counter() - self._drained_at
            return pos

    def sleep(self, seconds: float) -> None:
        """Wait while the output plays (the video source waits for its next frame here)."""
        time.sleep(max(0.0, seconds))

    def set_paused(self, paused: bool) -> None:
        """Stop or resume playback (the position stops with it)."""

    def close(self) -> None:
        """Stop playback and release the device (idempotent)."""

    def describe(self) -> str:
        return f"{type(self).__name__} {self.rate} Hz x{self.channels}"

    # -------------------------------------------------------------- consumer side
    def _take(self, n: int, out: np.ndarray | None = None) -> int:
        """Consume up to ``n`` samples into ``out`` ((n, channels), zero-filled past the queue);
        returns how many were real samples. Once :meth:`end` was called and the queue has
        played, :meth:`position` runs on at wall time from that moment."""
        with self._lock:
            got = 0
            while got < n and self._chunks:
                head = self._chunks[0]
                k = min(n - got, len(head) - self._offset)
                if out is not None:
                    out[got:got + k] = head[self._offset:self._offset + k]
                got += k
                self._offset += k
                if self._offset == len(head):
                    self._chunks.popleft()
                    self._offset = 0
            self._buffered -= got
            if out is not None:
                out[got:] = 0.0
            self._played += got
            if self._ended and self._buffered == 0 and self._drained_at is None:
                self._drained_at = time.perf_counter()
            return got


class WallClock(AudioOutput):
    """No sound: samples are dropped and the position is wall time since :meth:`start`
    (the first call to :meth:`position`), paused time excluded."""

    def __init__(self, rate: int = 48000, channels: int = 2) -> None:
        super().__init__()
        self.rate, self.channels = int(rate), int(channels)
        self._t0: float | None = None
        self._paused_at: float | None = None

    def write(self, samples: np.ndarray) -> None:
        pass

    def position(self) -> float:
        with self._lock:
            now = time.perf_counter()
            if self._t0 is None:
                self._t0 = now
            return (self._paused_at if self._paused_at is not None else now) - self._t0

    def set_paused(self, paused: bool) -> None:
        with self._lock:
            now = time.perf_counter()
            if self._t0 is None:
                self._t0 = now
            if paused and self._paused_at is None:
                self._paused_at = now
            elif not paused and self._paused_at is not None:
                self._t0 += now - self._paused_at
                self._paused_at = None

    def describe(self) -> str:
        return "no sound (wall clock)"


class SoundDeviceOutput(AudioOutput):
    """The default sound output through PortAudio (``sounddevice``); the position subtracts the
    output's latency, so it is the sample leaving the speaker now.

    Raises
    ------
    ImportError, OSError
        sounddevice or the PortAudio library is missing, or no output device opens.
    """

    def __init__(self, channels: int = 2, rate: int | None = None, device=None) -> None:
        import sounddevice as sd  # OSError when the PortAudio library is missing

        super().__init__()
        info = sd.query_devices(device, kind="output")
        self.channels = max(1, min(int(channels), int(info["max_output_channels"])))
        self.rate = int(rate or info["default_samplerate"])
        self._stream = sd.OutputStream(samplerate=self.rate, channels=self.channels, dtype="float32",
                                       device=device, callback=self._callback)
        self._latency = float(self._stream.latency)
        self._stream.start()

    def _callback(self, outdata, frames, time_info, status) -> None:  # PortAudio's thread
        self._take(frames, outdata)           # after the end, the base runs on at wall time

    def position(self) -> float:
        return max(0.0, super().position() - self._latency)

    def set_paused(self, paused: bool) -> None:
        if self._stream is None:
            return
        if paused and self._stream.active:
            self._stream.stop()
        elif not paused and not self._stream.active:
            self._stream.start()

    def close(self) -> None:
        if self._stream is not None:
            self._stream.close()
            self._stream = None

    def describe(self) -> str:
        return f"sound {self.rate} Hz x{self.channels} (latency {1e3 * self._latency:.0f} ms)"


_warned = False


def open_audio_output(channels: int = 2, *, mute: bool = False) -> AudioOutput:
    """The default sound device, or a :class:`WallClock` when ``mute`` or when no device
    opens (logged once per process, with what to install)."""
    global _warned
    if mute:
        return WallClock(channels=channels)
    try:
        return SoundDeviceOutput(channels)
    except Exception as exc:   # no sounddevice, no PortAudio, no device: play without sound
        if not _warned:
            log.warning("no sound output (%s): the video plays without sound, at wall time. "
                        "Install the show extra (pip install rtdefocus[show]) and PortAudio "
                        "(Debian/Ubuntu: apt-get install libportaudio2), or pass --no-audio",
                        str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            _warned = True
        return WallClock(channels=channels)
