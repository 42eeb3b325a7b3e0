"""The frame loop's threads (rtdefocus.stream.threads, loop): a file sink's encode overlaps the
next frame's solve; frames keep their order; the threaded path equals the sequential one frame
by frame; a failing source or sink, or Ctrl-C, ends the run with the error in the caller and no
thread left behind."""

from __future__ import annotations

import random
import threading
import time

import numpy as np
import pytest
from test_stream import PROJ, RecordingSink, synthetic_frames, virtual_calibration

import rtdefocus as rd
from rtdefocus import cli
from rtdefocus.errors import CaptureError, InputError
from rtdefocus.imageio import read_image
from rtdefocus.stream import ArraySource, NullSink, play
from rtdefocus.stream.threads import SinkWriter


@pytest.fixture(scope="module")
def calib():
    return virtual_calibration()


@pytest.fixture(scope="module")
def comp(calib):
    return rd.Compensator(calib, iterations=3)


def loop_threads() -> list[str]:
    """The player's own threads still alive (a Compensator's motion helper belongs to it and
    lives as long as it does)."""
    return [t.name for t in threading.enumerate()
            if t.name.startswith("rtdefocus-") and not t.name.startswith("rtdefocus-motion")]


class FileLikeSink(RecordingSink):
    """A file sink stand-in: written on the writer thread, each write a little slow and jittery
    (so frames queue up and any reordering would show)."""

    threaded = True

    def __init__(self, delay=0.004, fail_at=None, seed=0, **kw):
        super().__init__(**kw)
        self.delay, self.fail_at = delay, fail_at
        self.rng = random.Random(seed)
        self.thread_names = set()

    def write(self, frame, index):
        self.thread_names.add(threading.current_thread().name)
        if index == self.fail_at:
            raise InputError(f"disk full at frame {index}")
        time.sleep(self.delay * self.rng.random())
        super().write(frame, index)


def run(comp, frames, sink, **kw):
    comp.reset()
    return play(comp, ArraySource(frames), sink, **kw)


def test_threaded_equals_sequential_frame_by_frame_and_in_order(comp):
    frames = synthetic_frames(12)
    seq, thr = FileLikeSink(), FileLikeSink()
    s_seq = run(comp, frames, seq, threads=False)
    s_thr = run(comp, frames, thr)
    assert seq.indices == thr.indices == list(range(12))
    for i, (a, b) in enumerate(zip(seq.frames, thr.frames, strict=True)):
        assert np.array_equal(a, b), f"frame {i} differs between the threaded and sequential paths"
    assert thr.thread_names == {"rtdefocus-write"} and seq.thread_names == {"MainThread"}
    assert s_thr.stages["write"].count == 12 and "write" not in s_seq.stages
    assert s_seq.frames_out == s_thr.frames_out == 12
    assert loop_threads() == []


def test_encode_of_one_frame_overlaps_the_solve_of_the_next(comp):
    """The writer thread runs while the main thread compensates: frame 0's write waits (up to
    5 s) for frame 1's compensate to begin, which only happens if the two overlap."""
    started = {i: threading.Event() for i in range(3)}
    overlapped = []

    class Marking:
        def __init__(self, inner):
            self.inner, self.n = inner, 0

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def compensate(self, image, **kw):
            started[self.n].set()
            self.n += 1
            return self.inner.compensate(image, **kw)

    class WaitingSink(FileLikeSink):
        def write(self, frame, index):
            if index + 1 in started:
                overlapped.append(started[index + 1].wait(5.0))
            super().write(frame, index)

    sink = WaitingSink(delay=0.0)
    run(Marking(comp), synthetic_frames(3), sink)
    assert sink.indices == [0, 1, 2]
    assert overlapped == [True, True], "the encode did not overlap the next frame's solve"


def test_failing_sink_raises_in_the_caller_and_leaves_no_thread(comp):
    sink = FileLikeSink(fail_at=4)
    with pytest.raises(InputError, match="disk full at frame 4") as info:
        run(comp, synthetic_frames(20), sink)
    notes = " ".join(getattr(info.value, "__notes__", []))
    assert "writer thread" in notes or not hasattr(info.value, "add_note")
    assert sink.indices == [0, 1, 2, 3]
    assert loop_threads() == []


def test_failing_source_with_a_writer_raises_and_leaves_no_thread(comp):
    def frames():
        yield from synthetic_frames(3)
        raise CaptureError("camera unplugged")
    sink = FileLikeSink()
    with pytest.raises(CaptureError, match="unplugged"):
        run(comp, frames(), sink)
    assert sink.indices == sorted(sink.indices) and len(sink.indices) <= 3
    assert loop_threads() == []


def test_ctrl_c_in_the_solve_stops_every_thread(comp):
    class Interrupting:
        def __init__(self, inner, at):
            self.inner, self.at, self.n = inner, at, 0

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def compensate(self, image, **kw):
            if self.n == self.at:
                raise KeyboardInterrupt
            self.n += 1
            return self.inner.compensate(image, **kw)

    sink = FileLikeSink(delay=0.02)
    comp.reset()
    # An endless source: the decoder must be stopped, not run dry.
    endless = (f for i in range(10 ** 9) for f in synthetic_frames(1, seed=i))
    with pytest.raises(KeyboardInterrupt):
        play(Interrupting(comp, 5), ArraySource(endless), sink)
    assert sink.indices == list(range(len(sink.indices))) and len(sink.indices) <= 5
    assert loop_threads() == []


def test_window_like_sinks_and_null_get_no_writer(comp):
    sink = RecordingSink()                       # threaded = False (like the window)
    run(comp, synthetic_frames(3), sink)
    stats = run(comp, synthetic_frames(3), NullSink())
    assert "write" not in stats.stages and stats.frames_out == 3
    assert sink.indices == [0, 1, 2]


def test_sink_writer_finish_writes_everything_then_raises_late_errors():
    sink = FileLikeSink(delay=0.002, fail_at=7)
    w = SinkWriter(sink, maxsize=2)
    frame = np.zeros((4, 4, 3), np.uint8)
    with pytest.raises(InputError, match="frame 7"):
        for i in range(10):
            w.write(frame, i)
        w.finish()
    w.abort()                                    # idempotent after a failure
    assert sink.indices == list(range(7)) and not w.alive


def test_cli_sequential_and_threaded_write_the_same_files(tmp_path, calib):
    setup = calib.save(tmp_path / "setup.npz")
    import cv2

    video = tmp_path / "in.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25, PROJ)
    for f in synthetic_frames(5):
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()
    for name, extra in (("seq", ["--sequential"]), ("thr", [])):
        assert cli.main(["-q", "play", str(setup), str(video), "--out", str(tmp_path / name),
                         "--iterations", "2", "--no-cache", *extra]) == 0
    seq = sorted((tmp_path / "seq").glob("frame_*.png"))
    assert [p.name for p in seq] == [p.name for p in sorted((tmp_path / "thr").glob("*.png"))]
    assert len(seq) == 5
    for p in seq:
        assert np.array_equal(read_image(p), read_image(tmp_path / "thr" / p.name)), p.name
    assert loop_threads() == []

