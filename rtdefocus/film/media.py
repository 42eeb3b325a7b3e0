"""Film files through PyAV: probe, decode a range of frames, encode a chunk, mux the chunks.

Frames are RGB uint8 ``(H, W, 3)`` at this module's edge. A film is taken as constant frame
rate (its average rate); frame ``i`` is the one whose timestamp is ``first + i / fps``.
Chunks are written to NUT files (exact rational time bases, any codec) with timestamps counted
from 0 in frames; :func:`mux` copies their packets, shifted by the chunk's first frame, into
the final container together with the film's audio packets, unchanged.
"""

from __future__ import annotations

import heapq
import logging
import os
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import InputError, RtDefocusError

log = logging.getLogger(__name__)

__all__ = ["QUALITIES", "FilmInfo", "Quality", "require_av", "probe", "read_frames",
           "ChunkWriter", "mux", "check_container", "decode_rgb", "write_film"]


def require_av():
    """The ``av`` module (PyAV), or an error naming the extra that installs it."""
    try:
        import av
    except ImportError:
        raise RtDefocusError("rendering a film needs PyAV: pip install 'rtdefocus[render]'") from None
    return av


@dataclass(frozen=True)
class Quality:
    """How the compensated frames are encoded.

    ``codec`` and ``pix_fmt`` as FFmpeg names them, ``options`` the encoder's private options
    (``crf``, ``preset``), ``container``: the output extensions it fits in.
    """

    name: str
    codec: str
    pix_fmt: str
    options: tuple[tuple[str, str], ...]
    extensions: tuple[str, ...]
    description: str


# crf 4 keeps the camera's view of every frame within 0.3 dB of the uncompressed frame (crf
# 12, "visually lossless" for ordinary video, costs up to 0.9 dB: the compensation is a fine,
# high-contrast pattern; docs/render.md). No B-frames, so that every chunk's timestamps are its
# frame numbers (decode order = display order) and chunks join by copying their packets.
_X264 = (("crf", "4"), ("preset", "medium"), ("bf", "0"))
# 4:2:0 loses ~3 dB of the compensation to the halved chroma, which no crf brings back: the
# lighter crf keeps its files small for the modest players it is for.
_X264_420 = (("crf", "12"), ("preset", "medium"), ("bf", "0"))

#: The encodings ``render`` offers (docs/render.md gives the cost of each in dB).
QUALITIES = {
    # 4:4:4: the compensation is a fine pattern in every channel; halving the chroma resolution
    # (4:2:0) costs more of it than the codec does (docs/render.md).
    "high": Quality("high", "libx264", "yuv444p", _X264, (".mp4", ".mkv", ".mov"),
                    "H.264 High 4:4:4, crf 4"),
    # For players and signage boxes that decode 4:2:0 H.264 only.
    "compatible": Quality("compatible", "libx264", "yuv420p", _X264_420, (".mp4", ".mkv", ".mov"),
                          "H.264 High 4:2:0, crf 12"),
    # Lossless RGB: the projector's framebuffer bit for bit.
    "archive": Quality("archive", "ffv1", "bgr0", (), (".mkv",),
                       "FFV1 lossless RGB"),
}


@dataclass(frozen=True)
class FilmInfo:
    """What :func:`probe` finds in a film: ``n_frames`` video frames of ``size = (w, h)`` at
    ``fps``; ``first_pts`` the first frame's timestamp (in ``time_base``); ``audio`` the number
    of audio streams."""

    path: str
    n_frames: int
    fps: Fraction
    size: tuple[int, int]
    time_base: Fraction
    first_pts: int
    audio: int


def _open(path: str | Path):
    av = require_av()
    p = Path(path)
    if not p.is_file():
        raise InputError(f"no film at {str(p)!r}: give the path of a video file (.mp4, .mkv, ...)")
    try:
        container = av.open(str(p))
    except av.FFmpegError as exc:
        raise InputError(f"cannot open {str(p)!r} as a film ({exc}); convert it, e.g. "
                         "`ffmpeg -i IN -c:v libx264 -c:a copy OUT.mp4`") from None
    if not container.streams.video:
        container.close()
        raise InputError(f"{str(p)!r} holds no video stream; give a film with pictures")
    return container


def probe(path: str | Path) -> FilmInfo:
    """Open ``path``, count its video frames (by demuxing, no decode) and decode its first frame.

    Raises
    ------
    InputError
        The file is missing, no container FFmpeg knows, has no video, or its first frame
        does not decode.
    """
    av = require_av()
    container = _open(path)
    try:
        vs = container.streams.video[0]
        rate = vs.average_rate or vs.guessed_rate or vs.base_rate
        if not rate or rate <= 0:
            raise InputError(f"{str(path)!r}: the video stream has no frame rate; remux it with "
                             "one, e.g. `ffmpeg -r 30 -i IN -c copy OUT.mkv`")
        try:
            first = next(container.decode(vs))
        except (av.FFmpegError, StopIteration) as exc:
            raise InputError(f"{str(path)!r}: its video does not decode ({exc or 'no frame'}); "
                             "convert it, e.g. `ffmpeg -i IN -c:v libx264 OUT.mp4`") from None
        first_pts = 0 if first.pts is None else int(first.pts)
        size = (first.width, first.height)
        container.seek(0)
        n = sum(1 for pkt in container.demux(vs) if pkt.size > 0)
        return FilmInfo(str(path), n, Fraction(rate), size, Fraction(vs.time_base or Fraction(1, 1)),
                        first_pts, len(container.streams.audio))
    except av.FFmpegError as exc:
        raise InputError(f"{str(path)!r} cannot be read as a film ({exc}); convert it, e.g. "
                         "`ffmpeg -i IN -c:v libx264 -c:a copy OUT.mp4`") from None
    finally:
        container.close()


def _index(frame, film: FilmInfo) -> int | None:
    if frame.pts is None:
        return None
    return round(float((frame.pts - film.first_pts) * film.time_base * film.fps))


def read_frames(film: FilmInfo, start: int, stop: int):
    """Yield frames ``start`` … ``stop - 1`` of the film as RGB uint8 ``(H, W, 3)``.

    Seeks to the key frame before ``start`` and places frames by their timestamps; where the
    film does not allow that (no timestamps, or the seek lands after ``start``), decodes from
    the beginning and counts.
    """
    av = require_av()
    want = stop - start
    got = 0
    try:
        if start > 0:
            for i, frame in _decoded(film, start, seek=True):
                if i is None or (got == 0 and i > start):
                    break                     # cannot be placed: count from the start instead
                if i < start:
                    continue
                if i >= stop:
                    return
                yield frame.to_ndarray(format="rgb24")
                got += 1
                if got == want:
                    return
            if got:
                raise InputError(f"{film.path!r}: the video ends at frame {start + got} of the "
                                 f"{film.n_frames} its container lists; convert it, e.g. "
                                 "`ffmpeg -i IN -c:v libx264 -c:a copy OUT.mp4`")
            log.debug("%s: frame %d cannot be found by seeking; decoding from the start",
                      film.path, start)
        for i, frame in _decoded(film, start, seek=False):
            if i >= start:
                yield frame.to_ndarray(format="rgb24")
                got += 1
                if got == want:
                    return
    except av.FFmpegError as exc:
        raise InputError(f"{film.path!r}: frames {start}-{stop - 1} do not decode ({exc}); "
                         "convert the film, e.g. `ffmpeg -i IN -c:v libx264 OUT.mp4`") from None
    raise InputError(f"{film.path!r}: only {start + got} frames decode of the {film.n_frames} its "
                     "container lists; convert it, e.g. `ffmpeg -i IN -c:v libx264 -c:a copy OUT.mp4`")


def _decoded(film: FilmInfo, start: int, seek: bool):
    """(index, frame) pairs: by timestamp after a seek to ``start``, else counted from 0."""
    with _open(film.path) as container:
        vs = container.streams.video[0]
        vs.thread_type = "AUTO"
        if seek:
            t = film.first_pts + int(start / (film.fps * film.time_base))
            container.seek(t, stream=vs, backward=True, any_frame=False)
        for count, frame in enumerate(container.decode(vs)):
            yield (_index(frame, film) if seek else count), frame


def check_container(path: str | Path, quality: Quality) -> None:
    """Raise :class:`InputError` when the output's extension cannot hold ``quality``'s codec."""
    ext = Path(path).suffix.lower()
    if ext not in quality.extensions:
        raise InputError(f"quality {quality.name!r} ({quality.description}) is written to "
                         f"{' / '.join(quality.extensions)} files; got {str(path)!r} "
                         f"(rename the output, e.g. OUT{quality.extensions[0]})")


class ChunkWriter:
    """Encode frames of one chunk to a NUT file, timestamps 0, 1, 2, … in frames.

    Use as a context manager; :meth:`write` takes RGB uint8 ``(Hp, Wp, 3)``.
    """

    def __init__(self, path: str | Path, quality: Quality, fps: Fraction, size: tuple[int, int]):
        av = require_av()
        self._av = av
        self.container = av.open(str(path), mode="w", format="nut")
        s = self.container.add_stream(quality.codec, rate=fps)
        s.width, s.height = size
        s.pix_fmt = quality.pix_fmt
        s.options = dict(quality.options)
        if quality.pix_fmt.startswith("yuv"):
            # BT.709, limited range, flagged: what players assume for HD video.
            cc = s.codec_context
            cc.colorspace, cc.color_range = 1, 1
            cc.color_primaries, cc.color_trc = 1, 1
        self.stream = s
        self.quality = quality
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        if self.quality.pix_fmt.startswith("yuv"):
            frame = frame.reformat(format=self.quality.pix_fmt, dst_colorspace="ITU709")
            frame.colorspace, frame.color_range = 1, 1
        else:
            frame = frame.reformat(format=self.quality.pix_fmt)
        frame.pts = self.frames                      # in the encoder's time base, 1 / fps
        self.frames += 1
        for packet in self.stream.encode(frame):
            self.container.mux(packet)

    def close(self) -> None:
        if self.container is not None:
            try:
                for packet in self.stream.encode(None):
                    self.container.mux(packet)
            finally:
                self.container.close()
                self.container = None

    def __enter__(self) -> ChunkWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def decode_rgb(path: str | Path):
    """Yield the frames of a video file (a rendered film, a chunk) as RGB uint8 (YUV decoded
    with the colour space the stream is flagged with)."""
    av = require_av()
    with av.open(str(path)) as container:
        for frame in container.decode(container.streams.video[0]):
            yield frame.to_ndarray(format="rgb24")


def mux(out_path: str | Path, film: FilmInfo, chunks: list[tuple[int, Path]]) -> None:
    """Write ``out_path``: the chunks' video packets in order, each chunk shifted to start at
    its first frame (``(start, file)`` pairs), and the film's audio packets unchanged.

    Packets are copied, not decoded: no second generation of compression, and seconds for a
    whole film. Written to a temporary file beside ``out_path`` and renamed when complete.
    """
    av = require_av()
    out_path = Path(out_path)
    tmp = out_path.with_name(f".{out_path.name}.partial{out_path.suffix}")
    inputs = [av.open(str(p)) for _, p in chunks]
    film_in = av.open(film.path) if film.audio else None
    try:
        out = av.open(str(tmp), mode="w", format=_format_of(out_path))
        try:
            vs = out.add_stream_from_template(inputs[0].streams.video[0])
            vs.time_base = inputs[0].streams.video[0].time_base
            audio = {}
            if film_in is not None:
                for a in film_in.streams.audio:
                    audio[a.index] = out.add_stream_from_template(a)
                    audio[a.index].time_base = a.time_base
            streams = [_video_packets(inputs, chunks, vs, film.fps)]
            if audio:
                streams.append(_audio_packets(film_in, audio))
            try:
                for _, _, packet in heapq.merge(*streams, key=lambda t: (t[0], t[1])):
                    out.mux(packet)
            except av.FFmpegError as exc:
                raise InputError(f"cannot write {out_path.name!r} ({exc}): its container does not "
                                 "take this audio or video; use an .mkv output") from None
        finally:
            out.close()
        os.replace(tmp, out_path)
    finally:
        for c in inputs:
            c.close()
        if film_in is not None:
            film_in.close()
        if tmp.exists():
            tmp.unlink()


def _format_of(path: Path) -> str:
    return {".mkv": "matroska", ".mp4": "mp4", ".mov": "mov"}.get(path.suffix.lower(), "matroska")


def _video_packets(inputs, chunks, vs, fps):
    for c, (start, _) in zip(inputs, chunks, strict=True):
        s = c.streams.video[0]
        shift = round(start / (fps * s.time_base))        # frames -> the chunk's time base
        for packet in c.demux(s):
            if packet.size == 0:
                continue
            packet.pts = None if packet.pts is None else packet.pts + shift
            packet.dts = None if packet.dts is None else packet.dts + shift
            packet.stream = vs
            t = float((packet.dts if packet.dts is not None else packet.pts) * packet.time_base)
            yield t, 0, packet


def _audio_packets(film_in, audio):
    for packet in film_in.demux(*[film_in.streams[i] for i in audio]):
        if packet.dts is None or packet.size == 0:
            continue
        packet.stream = audio[packet.stream.index]
        yield float(packet.dts * packet.time_base), 1, packet


def write_film(path: str | Path, frames, fps: int = 30, tone_hz: float | None = 440.0) -> None:
    """Write RGB uint8 ``frames`` as an ordinary film: H.264 4:2:0 (crf 16, with B-frames) and,
    unless ``tone_hz`` is None, a mono AAC sine tone as long as the pictures (a test film)."""
    av = require_av()
    frames = list(frames)
    h, w = frames[0].shape[:2]
    with av.open(str(path), "w") as c:
        v = c.add_stream("libx264", rate=fps)
        v.width, v.height, v.pix_fmt = w, h, "yuv420p"
        v.options = {"crf": "16"}
        a = None
        if tone_hz is not None:
            a = c.add_stream("aac", rate=48000)
            a.layout = "mono"
        for f in frames:
            for p in v.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")):
                c.mux(p)
        for p in v.encode(None):
            c.mux(p)
        if a is not None:
            t = np.arange(48000 * len(frames) // fps) / 48000
            pcm = (0.3 * np.sin(2 * np.pi * tone_hz * t)).astype(np.float32)[None]
            fr = av.AudioFrame.from_ndarray(pcm, format="flt", layout="mono")
            fr.sample_rate, fr.pts = 48000, 0
            for p in a.encode(fr):
                c.mux(p)
            for p in a.encode(None):
                c.mux(p)
