"""Video files decoded by PyAV (FFmpeg), with their sound, shown by the audio clock.

Two ways to read a file:

* **every frame** (file rendering, ``clock=None``): frames in order, the sound ignored.
* **by the clock** (the projector window): the source is *live*. :meth:`AvVideoSource.read`
  returns the frame whose presentation time has come on the clock (an
  :class:`~rtdefocus.stream.audio.AudioOutput`: the sound card's position, or wall time without
  sound), waiting for it when early, and skipping the frames whose successor is already due
  when late. The decoded sound is handed to the output as the file is read, so picture and
  sound are taken from one demuxer and stay together whatever the solver's speed: a slow frame
  is repeated on the screen (the window keeps the last one), the frames that would come too
  late are never shown.

PyAV comes with the ``show`` extra (``pip install rtdefocus[show]``); without it videos are
decoded by OpenCV, without sound (:class:`~rtdefocus.stream.sources.VideoSource`).
"""

from __future__ import annotations

import collections
import logging
import time
from pathlib import Path

import numpy as np

from ..errors import InputError
from .audio import AudioOutput, WallClock
from .source import Frame, Source

log = logging.getLogger(__name__)

#: Sound decoded ahead of the frame waited for (seconds): the output never runs dry while the
#: source sleeps.
AUDIO_LEAD = 0.3
#: Longest single wait for the clock (keeps a stop request answered).
WAIT_STEP = 0.01
#: Decoded frames held while looking for the sound that goes with them (a broken or lagging
#: sound track must not pull the whole film into memory).
MAX_AHEAD = 240

REENCODE = "re-encode it, e.g. `ffmpeg -i IN -c:v libx264 -pix_fmt yuv420p -c:a aac OUT.mp4`"


def have_pyav() -> bool:
    """Whether PyAV is installed."""
    try:
        import av  # noqa: F401
    except ImportError:
        return False
    return True


class AvVideoSource(Source):
    """A video file decoded by PyAV; with ``clock``, frames are picked by that clock.

    Parameters
    ----------
    path : the video file.
    clock : AudioOutput, optional
        Realtime playback: the output the file's sound goes to, whose position picks the frame
        (see the module). None: every frame in order, no sound.

    Attributes
    ----------
    skipped : int
        Frames passed over because the clock was past them (realtime only).
    last_pts : float or None
        Presentation time (seconds) of the frame returned last.
    last_clock : float or None
        Where the clock was (:meth:`media_time`) when that frame was returned (realtime).

    Raises
    ------
    InputError
        The file does not open as a video, or holds no video stream.
    """

    kind = "video"

    def __init__(self, path: str | Path, *, clock: AudioOutput | None = None):
        import av

        self._av = av
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"no video file at {str(self.path)!r}")
        self.clock = clock
        self._container = None
        try:
            self._container = av.open(str(self.path))
        except av.FFmpegError as exc:
            self.close()
            raise InputError(f"cannot open {str(self.path)!r} as a video ({exc}); {REENCODE}") from None
        vs = self._container.streams.video
        if not vs:
            self.close()
            raise InputError(f"{str(self.path)!r} holds no video stream; {REENCODE}")
        self._vstream = vs[0]
        self._vstream.thread_type = "AUTO"
        rate = self._vstream.average_rate or self._vstream.guessed_rate
        self.fps = float(rate) if rate and 0 < float(rate) < 1000 else None
        self.n_frames = int(self._vstream.frames) or None
        self.live = clock is not None
        self._astream = None
        if clock is not None and not self._container.streams.audio and not isinstance(clock, WallClock):
            clock.close()                  # no sound track: the wall clock picks the frames
            self.clock = clock = WallClock(channels=clock.channels)
        if clock is not None and self._container.streams.audio:
            self._astream = self._container.streams.audio[0]
            layout = "mono" if clock.channels == 1 else "stereo"
            self._resampler = av.AudioResampler(format="flt", layout=layout, rate=clock.rate)
        streams = [s for s in (self._vstream, self._astream) if s is not None]
        self._packets = self._container.demux(*streams)
        self._pending: collections.deque = collections.deque()   # decoded video frames
        self._eof = False
        self._audio_end = None        # media time the queued sound reaches
        self._audio_start = None      # media time of the first sample
        self._t_origin = None         # media time of the clock's zero
        self._index = 0
        self.skipped = 0
        self.last_pts: float | None = None
        self.last_clock: float | None = None

    # -------------------------------------------------------------- demuxing
    def _demux_one(self) -> bool:
        """Read and decode one packet; False at the end of the file."""
        av = self._av
        if self._eof:
            return False
        try:
            packet = next(self._packets)
        except StopIteration:
            self._finish()
            return False
        except av.FFmpegError as exc:
            raise self._decode_error(exc) from None
        try:
            frames = packet.decode()
        except av.FFmpegError as exc:
            raise self._decode_error(exc) from None
        if packet.stream is self._astream:
            for f in frames:
                self._audio(f)
        else:
            self._pending.extend(frames)
        return True

    def _audio(self, frame) -> None:
        if self._audio_start is None and frame is not None and frame.time is not None:
            self._audio_start = float(frame.time)
        for out in self._resampler.resample(frame):
            samples = out.to_ndarray().reshape(-1, self.clock.channels)
            self.clock.write(samples)
            if self._audio_start is not None:
                base = self._audio_end if self._audio_end is not None else self._audio_start
                self._audio_end = base + len(samples) / self.clock.rate

    def _finish(self) -> None:
        self._eof = True
        if self._astream is not None:
            self._audio(None)                  # the resampler's tail
            self.clock.end()
        elif self.clock is not None:
            self.clock.end()

    def _decode_error(self, exc) -> InputError:
        where = f"after frame {self._index}" if self._index else "at its first frame"
        return InputError(f"cannot decode {str(self.path)!r} {where} ({exc}); {REENCODE}")

    def _next_video(self):
        while not self._pending:
            if not self._demux_one():
                return None
        return self._pending[0]

    def _peek_second(self):
        while len(self._pending) < 2:
            if not self._demux_one():
                return None
        return self._pending[1]

    @staticmethod
    def _pts(frame) -> float:
        return float(frame.time) if frame.time is not None else float("nan")

    # -------------------------------------------------------------- the clock
    def media_time(self) -> float:
        """The stream instant the clock is at (seconds, the file's time base)."""
        if self._t_origin is None:
            while self._astream is not None and self._audio_start is None and self._demux_one():
                pass                          # the clock's zero is the first sample
            first = self._audio_start if self._audio_start is not None else None
            if first is None and self._pending:
                first = self._pts(self._pending[0])
            self._t_origin = first if first is not None and np.isfinite(first) else 0.0
        return self._t_origin + self.clock.position()

    def _wait_for(self, pts: float) -> None:
        while True:
            now = self.media_time()
            if now >= pts:
                return
            # keep the sound ahead of the clock while waiting
            while (self._astream is not None and not self._eof
                   and (self._audio_end is None or self._audio_end < pts + AUDIO_LEAD)):
                if len(self._pending) > MAX_AHEAD:
                    # the sound track ends early or lags far behind the picture: go on by the
                    # wall clock rather than read the whole film into memory waiting for it
                    log.warning("%s: no sound near %.1f s; the rest plays by the wall clock",
                                self.path.name, pts)
                    self.clock.end()
                    self._audio_end = float("inf")
                    break
                self._demux_one()
            self.clock.sleep(min(WAIT_STEP, pts - now))

    # -------------------------------------------------------------- Source
    def read(self) -> Frame | None:
        if self._container is None:
            return None
        while True:
            head = self._next_video()
            if head is None:
                if self._index == 0:
                    raise InputError(f"{str(self.path)!r} opens as a video but no frame could be "
                                     f"decoded; {REENCODE}")
                return None
            if self.clock is not None:
                pts = self._pts(head)
                nxt = self._peek_second()
                if nxt is not None and self._pts(nxt) <= self.media_time():
                    self._pending.popleft()     # its successor is due already: never shown
                    self.skipped += 1
                    continue
                if np.isfinite(pts):
                    self._wait_for(pts)
            frame = self._pending.popleft()
            try:
                image = frame.to_ndarray(format="rgb24")
            except self._av.FFmpegError as exc:
                raise self._decode_error(exc) from None
            out = Frame(self._index, np.ascontiguousarray(image), time.perf_counter())
            self.last_pts = self._pts(frame)
            self.last_clock = self.media_time() if self.clock is not None else None
            self._index += 1
            return out

    def set_paused(self, paused: bool) -> None:
        """Pause or resume the clock (and the sound)."""
        if self.clock is not None:
            self.clock.set_paused(paused)

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
            self._container = None
        if self.clock is not None:
            self.clock.close()

    def describe(self) -> str:
        fps = f"{self.fps:.3g} fps" if self.fps else "unknown fps"
        sound = ""
        if self.clock is not None:
            sound = f", {self.clock.describe()}" if self._astream is not None else ", no sound track"
        return f"video {self.path} ({self.n_frames or '?'} frames, {fps}{sound})"
