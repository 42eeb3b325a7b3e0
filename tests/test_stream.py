"""The frame loop (rtdefocus.stream): file rendering keeps every frame in order and equals the
Compensator frame by frame; live sources drop stale frames without reordering and keep up; the
adaptive budget; memory stays flat over 500 frames; slides (natural order, refine until
converged, disk cache); key handling; statistics; the `play` command."""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import threading
import time
import tracemalloc

import cv2
import numpy as np
import pytest

import rtdefocus as rd
from rtdefocus import cli
from rtdefocus.calib.file import Calibration
from rtdefocus.errors import CaptureError, InputError
from rtdefocus.imageio import fit_image, read_image, write_image
from rtdefocus.stream import (
    ArraySource,
    Controls,
    ImageSequenceSink,
    IterationBudget,
    KeyDispatcher,
    NullSink,
    Player,
    SlideCache,
    SlidesSource,
    VideoFileSink,
    VideoSource,
    calibration_fingerprint,
    natural_key,
    open_sink,
    open_source,
    play,
)
from rtdefocus.stream.sinks import Sink
from rtdefocus.stream.stats import WINDOW, LoopStats, Series

PROJ = (64, 48)  # small projector: the loop's properties do not depend on size


@functools.cache
def virtual_calibration(preset: str = "cubicle"):
    """The calibration of a small virtual set-up, built from the simulator's truth (two walls,
    a fold, the true kernel field): what `rtdefocus calibrate` would give, without the wait.
    The blur is scaled up so that a 64-px-wide projector blurs by 1.5..3 px, as an 800-px one
    does by 1.5..6 px."""
    from rtdefocus import sim
    from rtdefocus.sim import oracle_calibration

    scene = dataclasses.replace(sim.PRESETS[preset], blur_range_px=(19.0, 38.0))
    return oracle_calibration(sim.VirtualProCam(scene, projector_size=PROJ, camera_size=(96, 72)))


@pytest.fixture(scope="module")
def calib():
    return virtual_calibration()


@pytest.fixture(scope="module")
def comp(calib):
    return rd.Compensator(calib)


def synthetic_frames(n, size=PROJ, seed=0):
    """Frames that differ from each other (a moving bar over noise), so order is visible."""
    w, h = size
    rng = np.random.default_rng(seed)
    base = rng.integers(40, 200, (h, w, 3), dtype=np.uint8)
    out = []
    for i in range(n):
        f = base.copy()
        x = (3 * i) % w
        f[:, x:x + 4] = (255, 230 - 7 * i % 200, 20 + 9 * i % 200)
        f[(2 * i) % h, :] = 0
        out.append(f)
    return out


class RecordingSink(Sink):
    """Keeps what it is given (tests only); optionally realtime/interactive with scripted keys."""

    def __init__(self, realtime=False, keys=None, on_write=None):
        self.realtime = realtime
        self.interactive = keys is not None
        self.frames, self.indices, self.times = [], [], []
        self._keys = list(keys or [])
        self._pending: list[str] = []
        self.on_write = on_write

    def write(self, frame, index):
        self.frames.append(frame.copy())
        self.indices.append(index)
        self.times.append(time.perf_counter())
        if self._keys:                       # one scripted key after each presented frame
            self._pending.append(self._keys.pop(0))
        if self.on_write:
            self.on_write(self)

    def poll(self):
        out, self._pending = self._pending, []
        return out


def max_abs(a, b):
    return int(np.abs(a.astype(np.int16) - b.astype(np.int16)).max())


# --------------------------------------------------------------------------- file rendering
def test_video_file_to_files_every_frame_in_order_equals_compensate(tmp_path, calib):
    n = 12
    frames = synthetic_frames(n)
    video = tmp_path / "in.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25, PROJ)
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()
    # The reference: decode the same file independently, compensate frame after frame with a
    # fresh Compensator (same warm-start chain, full budget).
    cap = cv2.VideoCapture(str(video))
    decoded = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        decoded.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    assert len(decoded) == n
    ref_comp = rd.Compensator(calib)
    expected = [ref_comp.compensate(f) for f in decoded]

    comp = rd.Compensator(calib)          # fresh: the solver adapts its step across calls
    done = []
    with VideoSource(video) as src, ImageSequenceSink(tmp_path / "out") as sink:
        stats = play(comp, src, sink, progress=lambda d, t: done.append((d, t)))
    assert stats.frames_in == stats.frames_out == n and stats.dropped == 0
    assert done[-1] == (n, n) and [d for d, _ in done] == list(range(1, n + 1))
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == [f"frame_{i:06d}.png" for i in range(n)]
    for i in range(n):
        got = read_image(tmp_path / "out" / names[i])
        assert got.shape == (PROJ[1], PROJ[0], 3)
        assert max_abs(got, expected[i]) <= 1, f"frame {i} differs from Compensator.compensate"
        # and not equal to its neighbour's compensation: the order is really checked
        if i:
            assert max_abs(got, expected[i - 1]) > 20
    assert stats.iterations.mean == comp.iterations   # unlimited budget = the Compensator's own


def test_video_file_sink_writes_every_frame(tmp_path, comp):
    frames = synthetic_frames(10)
    out = tmp_path / "o.mp4"
    with VideoFileSink(out, fps=20) as sink:
        stats = play(comp, ArraySource(frames), sink)
    cap = cv2.VideoCapture(str(out))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == stats.frames_out == 10
    assert (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))) == PROJ
    cap.release()


# --------------------------------------------------------------------------- live sources
class SlowCompensator:
    """The real Compensator, at least ``delay`` seconds per frame whatever the device: a fast
    GPU would otherwise outrun any source rate a test can set."""

    def __init__(self, comp, delay=0.01):
        self.comp, self.delay = comp, delay

    def __getattr__(self, name):
        return getattr(self.comp, name)

    def compensate(self, image, **kw):
        t0 = time.perf_counter()
        out = self.comp.compensate(image, **kw)
        time.sleep(max(0.0, self.delay - (time.perf_counter() - t0)))
        return out


def test_live_source_faster_than_solver_drops_but_never_reorders(comp):
    """Behaviour only (tools/bench_stream.py reports the wall time and the latency)."""
    comp.reset()
    slow = SlowCompensator(comp)
    times = []
    for _ in range(4):                                            # the first includes warm-up
        t0 = time.perf_counter()
        slow.compensate(synthetic_frames(1)[0], iterations=20)
        times.append(time.perf_counter() - t0)
    per_frame = float(np.median(times[1:]))
    n, fps = 120, 4.0 / per_frame                                 # ~4 frames per solve
    sink = RecordingSink()
    stats = play(slow, ArraySource(synthetic_frames(n), fps=fps, live=True), sink, iterations=20)
    assert stats.dropped > 0, "a source 4x faster than the solver must drop frames"
    assert stats.dropped_copies == 0, "every frame is a new picture: none dropped is a copy"
    assert stats.frames_in == n
    assert stats.frames_out + stats.dropped == n, "every frame is either shown or counted dropped"
    assert np.all(np.diff(sink.indices) > 0), "frames reordered"
    assert sink.indices[-1] >= n - 3, "the loop fell behind the end of the stream"


def test_a_live_array_source_stamps_each_frame_with_its_time_of_arrival():
    """Frame i of a live ArraySource arrives at t0 + i / fps, and that is its ``t_read`` even
    when it is read late (a busy reader): the deadlines the catch-up counts from it are those
    of the frames' own clock."""
    fps = 50.0
    src = ArraySource(synthetic_frames(4), fps=fps, live=True)
    first = src.read()
    time.sleep(3.5 / fps)                               # the reader falls behind
    rest = [src.read() for _ in range(3)]
    for frame in rest:
        assert frame.t_read == pytest.approx(first.t_read + frame.index / fps, abs=1e-9)
    assert time.perf_counter() - rest[-1].t_read > 0   # read after it arrived


def test_decoder_error_reaches_the_caller(comp):
    def frames():
        yield synthetic_frames(1)[0]
        raise CaptureError("camera unplugged")
    with pytest.raises(CaptureError, match="unplugged"):
        play(comp, ArraySource(frames()), NullSink())


def test_iteration_budget_converges_to_what_fits():
    b = IterationBudget(50.0, maximum=40)          # 20 ms per frame
    for _ in range(30):                            # 2 ms per iteration + 5 ms of other work
        n = b.iterations
        b.update(frame_seconds=5e-3 + n * 2e-3, solve_seconds=n * 2e-3, iterations=n)
    assert b.iterations == 7                       # (20 - 5) / 2
    for _ in range(30):                            # the device slows down 3x
        n = b.iterations
        b.update(frame_seconds=5e-3 + n * 6e-3, solve_seconds=n * 6e-3, iterations=n)
    assert b.iterations == 2
    for _ in range(30):                            # nothing fits: the minimum, never zero
        b.update(frame_seconds=0.1, solve_seconds=0.09, iterations=b.iterations)
    assert b.iterations == 1
    with pytest.raises(InputError):
        IterationBudget(0)


class PacedCompensator:
    """The real Compensator, made to cost ``overhead + iterations * per_iteration`` seconds per
    frame (sleeping what the device did not spend) and reporting that split in ``last_info``,
    as the real one does: the budget's behaviour in the loop is then tested at a scale (tens of
    ms) that scheduler jitter cannot decide. (The real per-frame cost of a 64x48 frame is well
    under a millisecond per iteration, where a loaded CI machine's jitter is not.)"""

    def __init__(self, comp, overhead, per_iteration):
        self.comp, self.overhead, self.per_iteration = comp, overhead, per_iteration

    def __getattr__(self, name):
        return getattr(self.comp, name)

    def compensate(self, image, *, iterations=None, warm_start=True):
        t0 = time.perf_counter()
        out = self.comp.compensate(image, iterations=iterations, warm_start=warm_start)
        n = self.comp.last_info["iterations"]
        solve = n * self.per_iteration
        time.sleep(max(0.0, self.overhead + solve - (time.perf_counter() - t0)))
        info = dict(self.comp.last_info)
        info["seconds"] = {"solve": solve, "total": time.perf_counter() - t0}
        self.last_info = info
        return out

    def warm_up(self, iterations=1, frames=1):
        """The real warm-up, reporting the paced cost of its moving frames."""
        info = dict(self.comp.warm_up(iterations=iterations, frames=frames))
        solve = info["iterations"] * self.per_iteration
        info["seconds"] = {"solve": solve, "total": self.overhead + solve}
        info["moving"] = [dict(info["seconds"]) for _ in info["moving"]]
        return info


def test_realtime_budget_holds_the_frame_rate(comp):
    """The loop feeds the budget each frame's solve and frame time: it settles on what fits the
    period, within its bounds (tools/bench_stream.py reports the frame time against the period
    on the real device)."""
    comp.reset()
    paced = PacedCompensator(comp, overhead=0.010, per_iteration=0.004)
    fps = 1.0 / (0.010 + 12 * 0.004)                    # 12 iterations fit the period
    sink = RecordingSink(realtime=True)
    src = ArraySource(synthetic_frames(60), fps=fps, live=True)
    stats = play(paced, src, sink, max_iterations=60)
    its = stats.iterations.recent()[20:]
    assert its.min() >= 1 and its.max() <= 60
    # Sleeps only ever run long, and the loop's own work adds to the overhead: fewer than 12 may
    # fit, never more; a budget that ignored the time would sit at its start (2) or its cap (60).
    assert 6 <= np.median(its) <= 12, f"the budget should use the time available: {its}"
    assert stats.frames_out + stats.dropped == 60


@pytest.mark.slow
def test_realtime_budget_answers_a_slower_device(comp):
    """When each iteration costs 3x more, the budget falls to what still fits (here 4)."""
    comp.reset()
    fps = 1.0 / (0.010 + 12 * 0.004)
    paced = PacedCompensator(comp, overhead=0.010, per_iteration=0.012)
    stats = play(paced, ArraySource(synthetic_frames(40), fps=fps, live=True),
                 RecordingSink(realtime=True), max_iterations=60)
    its = stats.iterations.recent()[15:]
    assert 2 <= np.median(its) <= 4, f"the budget should shrink to what fits: {its}"


def test_a_slow_device_keeps_up_with_geometry_only_frames(comp):
    """A frame that costs more than a period (50 ms at 30 fps): without catch-up every few
    frames one is dropped and a late one stays on the screen; with it (the default) the loop
    shows some frames with geometry only instead and drops (almost) none."""
    fps, n = 30.0, 40
    runs = {}
    for catch_up in (False, True):
        comp.reset()
        paced = PacedCompensator(comp, overhead=0.050, per_iteration=0.004)
        sink = RecordingSink(realtime=True)
        player = Player(paced, ArraySource(synthetic_frames(n), fps=fps, live=True), sink,
                        catch_up=catch_up)
        runs[catch_up] = (player.run(), sink)
    (late, _), (kept, sink) = runs[False], runs[True]
    assert late.dropped >= 5 and late.geometry_frames == 0
    assert kept.geometry_frames >= 5 and kept.dropped <= 2, kept.summary()
    assert kept.frames_out + kept.dropped == n
    # a frame shown with geometry only is exactly the warp of its input
    frames = synthetic_frames(n)
    warps = [i for i, f in zip(sink.indices, sink.frames, strict=True)
             if np.array_equal(f, comp.warp(frames[i]))]
    assert len(warps) >= kept.geometry_frames


def test_catch_up_compensates_a_still_picture_on_a_slow_device_and_leaves_a_fast_one_alone(comp):
    """A picture that does not change is compensated however slow the device, once it has lasted
    (a still that lasted twice as long as its compensation takes), and then shown as compensated;
    the frames dropped meanwhile are copies of the picture on the screen. A device that fits the
    period never falls back."""
    n = 40
    still = [synthetic_frames(1)[0]] * n
    comp.reset()
    slow = PacedCompensator(comp, overhead=0.080, per_iteration=0.004)   # > 2 periods at 30 fps
    sink = RecordingSink(realtime=True)
    stats = play(slow, ArraySource(still, fps=30.0, live=True), sink)
    warp = comp.warp(still[0])
    compensated = [i for i, f in zip(sink.indices, sink.frames, strict=True)
                   if not np.array_equal(f, warp)]
    assert compensated and compensated[-1] == sink.indices[-1], stats.summary()
    assert stats.dropped == stats.dropped_copies, stats.summary()
    assert stats.frames_out + stats.dropped == n
    comp.reset()
    fast = PacedCompensator(comp, overhead=0.004, per_iteration=0.002)
    stats = play(fast, ArraySource(synthetic_frames(30), fps=30.0, live=True),
                 RecordingSink(realtime=True))
    assert stats.geometry_frames == 0 and stats.dropped <= 1


class SlowFramesCompensator(PacedCompensator):
    """A PacedCompensator whose frames listed in ``slow`` cost ``slow_seconds`` instead (a
    cut, another program's burst of load)."""

    def __init__(self, comp, overhead, per_iteration, slow, slow_seconds):
        super().__init__(comp, overhead, per_iteration)
        self.slow, self.slow_seconds, self.calls = set(slow), slow_seconds, 0

    def compensate(self, image, **kw):
        t0 = time.perf_counter()
        out = super().compensate(image, **kw)
        self.calls += 1
        if self.calls in self.slow:
            time.sleep(max(0.0, self.slow_seconds - (time.perf_counter() - t0)))
            self.last_info["seconds"]["total"] = time.perf_counter() - t0
        return out


def test_catch_up_returns_to_compensating_after_one_slow_frame(comp):
    """One frame that costs 5 periods does not hold the loop in geometry only: the deadline
    estimate is the median of the last few frames, and the safety margin it raised steps back
    after a few frames: a device that needs ~1 period a frame compensates again."""
    fps, n = 30.0, 45
    comp.reset()
    paced = SlowFramesCompensator(comp, overhead=0.030, per_iteration=0.004, slow={3},
                                  slow_seconds=0.170)
    sink = RecordingSink(realtime=True)
    player = Player(paced, ArraySource(synthetic_frames(n), fps=fps, live=True), sink)
    stats = player.run()
    compensated = stats.frames_out - stats.geometry_frames
    assert paced.calls >= 3 + 10, (paced.calls, stats.summary())   # >= 10 after the slow one
    assert compensated >= n // 3, stats.summary()
    assert stats.dropped <= 4 + 2, stats.summary()     # the slow frame's own ~4, and few more


def test_a_frame_past_its_deadline_makes_the_next_late_not_lost(comp):
    """A compensated frame that overruns the two periods its safety margin allowed (a spike of
    the device beyond its measured spread: 85 ms at 30 fps) leaves the frame after it waiting
    while the frame after next arrives: the live player's queue of two keeps both, shows them
    (late, counted) and loses none; with a queue of one the waiting frame is dropped."""
    fps, n = 30.0, 30
    runs = {}
    for queue_size in (None, 1):
        comp.reset()
        paced = SlowFramesCompensator(comp, overhead=0.030, per_iteration=0.004, slow={8},
                                      slow_seconds=0.085)
        player = Player(paced, ArraySource(synthetic_frames(n), fps=fps, live=True),
                        RecordingSink(realtime=True), queue_size=queue_size)
        runs[queue_size] = player.run()
        assert paced.calls >= 8, runs[queue_size].summary()
    kept, one = runs[None], runs[1]
    assert kept.dropped == 0 and kept.late >= 1, kept.summary()
    assert kept.frames_out == n
    assert one.dropped - one.dropped_copies >= 1, one.summary()


# Far over in the fast tier; just over two periods (a live run of ~1.5 s more) in the whole suite.
@pytest.mark.parametrize("frame_ms", [pytest.param(75, marks=pytest.mark.slow), 150],
                         ids=["just-over-two-periods", "far-over"])
def test_catch_up_never_compensates_a_moving_frame_it_expects_late(comp, frame_ms):
    """At 30 fps a moving frame that costs more than two periods (67 ms) would drop the next one:
    the player compensates no such frame, not even to measure the device again (a probe), so
    every frame is shown, with geometry only."""
    n = 45
    comp.reset()
    paced = PacedCompensator(comp, overhead=frame_ms / 1e3 - 0.004, per_iteration=0.004)
    player = Player(paced, ArraySource(synthetic_frames(n), fps=30.0, live=True),
                    RecordingSink(realtime=True))
    stats = player.run()
    assert stats.dropped == 0 and stats.geometry_frames == stats.frames_out == n, stats.summary()


def test_live_playback_warms_the_compensator_up_first(comp):
    """A live player runs ``warm_up`` once, before the first frame, and starts its budget from
    the moving frame it timed; file rendering does not."""
    calls = []

    class Spy(PacedCompensator):
        def warm_up(self, iterations=1):         # (times one moving frame: no ``frames``)
            calls.append(("warm_up", iterations))
            return {"iterations": 1, "seconds": {"solve": 0.004, "total": 0.024}}

        def compensate(self, image, **kw):
            calls.append(("compensate", None))
            return super().compensate(image, **kw)

    comp.reset()
    spy = Spy(comp, overhead=0.005, per_iteration=0.002)
    player = Player(spy, ArraySource(synthetic_frames(3), fps=30.0, live=True),
                    RecordingSink(realtime=True))
    budget = player.budget
    player.run()
    assert calls[0] == ("warm_up", budget.minimum) and calls.count(("warm_up", 1)) == 1
    assert len(calls) > 1 and all(c[0] == "compensate" for c in calls[1:])
    calls.clear()
    play(spy, ArraySource(synthetic_frames(3)), RecordingSink())
    assert calls and all(c[0] == "compensate" for c in calls)
    # a warm-up that times several moving frames gives their spread before the first frame
    paced = PacedCompensator(comp, overhead=0.005, per_iteration=0.002)
    player = Player(paced, ArraySource(synthetic_frames(3), fps=30.0, live=True),
                    RecordingSink(realtime=True))
    assert player.budget.cost_ratio(0.95) is None
    player._warm_up()
    assert player.budget.cost_ratio(0.95) == pytest.approx(1.0)     # (paced: all alike)


def test_budget_deadline_is_the_median_of_the_last_frames():
    """``frame_seconds(deadline=True)`` takes the median of the last RECENT rests: one slow
    frame does not move it, two in a row do."""
    b = IterationBudget(30.0)
    for rest in (0.040, 0.041, 0.039):
        b.update(rest + 0.004, 0.004, 1)
    assert b.frame_seconds(0, deadline=True) == pytest.approx(0.040, abs=1e-9)
    b.update(0.174, 0.004, 1)                         # one slow frame: (0.041, 0.039, 0.170)
    assert b.frame_seconds(0, deadline=True) == pytest.approx(0.041, abs=1e-9)
    assert b.frame_seconds(0) > 0.07                  # (the average does move)
    b.update(0.174, 0.004, 1)                         # a lasting change
    assert b.frame_seconds(0, deadline=True) == pytest.approx(0.170, abs=1e-9)


def test_budget_keeps_a_repeated_frames_budget_apart():
    """A still picture's cheap frames do not raise the budget of the next new frame."""
    b = IterationBudget(50.0, maximum=40)                # 20 ms per frame
    for _ in range(10):                                  # new frames: 12 ms of rest, 2 per it
        n = b.iterations_for(False)
        b.update(0.012 + n * 0.002, n * 0.002, n, repeat=False)
    for _ in range(30):                                  # then a still: 1 ms of rest
        n = b.iterations_for(True)
        b.update(0.001 + n * 0.002, n * 0.002, n, repeat=True)
    assert b.iterations_for(True) == 9                   # (20 - 1) / 2
    assert b.iterations_for(False) == b.iterations == 4  # (20 - 12) / 2, the moving frames' budget
    assert b.frame_seconds(1, repeat=False) == pytest.approx(0.014, rel=0.05)


# --------------------------------------------------------------------------- memory
@pytest.mark.slow
def test_500_frames_no_memory_growth(comp):
    """No growth as a ratio within the run (tools/bench_stream.py reports the figures)."""
    comp.reset()
    frames = synthetic_frames(8)
    marks = {}

    def rss_kib():
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") // 1024

    class MarkingSink(Sink):                       # keeps nothing, notes memory at 100 and 500
        n = 0

        def write(self, frame, index):
            self.n += 1
            if self.n in (100, 500):
                marks[self.n] = (tracemalloc.get_traced_memory()[0], rss_kib())

    def cycle():
        for i in range(500):
            yield frames[i % len(frames)]

    tracemalloc.start()
    try:
        stats = play(comp, ArraySource(cycle()), MarkingSink(), iterations=2)
    finally:
        tracemalloc.stop()
    assert stats.frames_out == 500
    (heap100, rss100), (heap500, rss500) = marks[100], marks[500]
    # A leak of one 64x48 frame per frame would add ~3.7 MB over 400 frames.
    assert heap500 < 1.25 * heap100 + 256 * 1024, f"Python heap {heap100} -> {heap500} bytes"
    assert rss500 < 1.10 * rss100, f"RSS {rss100} -> {rss500} KiB over 400 frames"


# --------------------------------------------------------------------------- slides
def _slides(folder, names, size=(40, 30)):
    folder.mkdir(parents=True, exist_ok=True)
    imgs = {}
    for k, name in enumerate(names):
        img = synthetic_frames(1, size=size, seed=k + 1)[0]
        write_image(folder / name, img)
        imgs[name] = img
    return imgs


def test_slides_natural_order(tmp_path):
    _slides(tmp_path, ["s10.png", "s2.png", "S1.jpg"])
    (tmp_path / "notes.txt").write_text("not a slide")
    src = open_source(tmp_path)
    assert isinstance(src, SlidesSource) and src.still
    assert [p.name for p in src.paths] == ["S1.jpg", "s2.png", "s10.png"]
    assert sorted(["a10", "a9", "a100"], key=natural_key) == ["a9", "a10", "a100"]
    assert [f.index for f in src] == [0, 1, 2]


class CountingCompensator:
    """Wraps the real Compensator and counts compensate() calls (a spy, not a stand-in)."""

    def __init__(self, comp):
        self.comp, self.calls = comp, 0

    def __getattr__(self, name):
        return getattr(self.comp, name)

    def compensate(self, image, **kw):
        self.calls += 1
        return self.comp.compensate(image, **kw)


def test_still_refines_until_converged(tmp_path, calib, comp):
    img = synthetic_frames(1, size=(40, 30), seed=3)[0]
    write_image(tmp_path / "s.png", img)
    player = Player(comp, SlidesSource(tmp_path / "s.png"), NullSink())
    out = player.compensate_still(img)
    total = player.stats.iterations.total
    assert total > comp.iterations, "a still gets more than one frame's budget"
    # the refined still is closer to the optimum than one budget's worth
    d_refined = comp.last_info["distances"][-1]
    comp.compensate(img, iterations=comp.iterations, warm_start=False)
    d_one = comp.last_info["distances"][-1]
    assert d_refined < d_one
    # converged: stopped by the tolerance (not the cap), within 1 % of the distance that
    # 400 iterations reach
    assert total < player.refine_max
    comp.compensate(img, iterations=400, warm_start=False)
    d_best = comp.last_info["distances"][-1]
    assert d_refined <= 1.01 * d_best + 1e-6 * comp.last_info["distances"][0]
    assert out.shape == (PROJ[1], PROJ[0], 3)


def test_slide_cache_second_show_is_instant(tmp_path, calib):
    imgs = _slides(tmp_path / "deck", ["a1.png", "a2.png", "a10.png"])
    spy = CountingCompensator(rd.Compensator(calib))   # fresh, like the reference below
    with SlidesSource(tmp_path / "deck") as src, ImageSequenceSink(tmp_path / "o1") as sink:
        s1 = play(spy, src, sink, cache=tmp_path / "cache")
    first_calls = spy.calls
    assert s1.frames_out == 3 and first_calls >= 3
    entries = list((tmp_path / "cache").rglob("*.png"))
    assert len(entries) == 3
    spy.calls = 0
    with SlidesSource(tmp_path / "deck") as src, ImageSequenceSink(tmp_path / "o2") as sink:
        player = Player(spy, src, sink, cache=tmp_path / "cache")
        player.run()
    # "instant" = no solve at all (tools/bench_stream.py times the second show)
    assert spy.calls == 0 and player.cache.hits == 3, "second show must come from the cache"
    for name in ("frame_000000.png", "frame_000001.png", "frame_000002.png"):
        assert np.array_equal(read_image(tmp_path / "o1" / name), read_image(tmp_path / "o2" / name))
    # the slide order is natural: output 2 is a10
    c = rd.Compensator(calib)
    ref = Player(c, SlidesSource(tmp_path / "deck"), NullSink()).compensate_still(imgs["a10.png"])
    assert max_abs(read_image(tmp_path / "o1" / "frame_000002.png"), ref) <= 1


def test_cache_key_follows_calibration_content_and_settings(tmp_path, calib):
    img = synthetic_frames(1, seed=5)[0]
    key = calibration_fingerprint(calib)
    assert key == calibration_fingerprint(Calibration.load(calib.save(tmp_path / "c.npz")))
    other = virtual_calibration("pillar")
    assert calibration_fingerprint(other) != key
    nudged = dataclasses.replace(calib, psfs=calib.psfs.copy())
    nudged.psfs[0, 0, 0] += 1e-6                           # any array change is a new key
    assert calibration_fingerprint(nudged) != key
    a = SlideCache(key, {"method": "ycbcr"}, root=tmp_path)
    out = synthetic_frames(1, seed=6)[0]
    a.put(img, out)
    assert np.array_equal(a.get(img), out)
    assert SlideCache(key, {"method": "rgb"}, root=tmp_path).get(img) is None
    assert SlideCache(calibration_fingerprint(other), {"method": "ycbcr"}, root=tmp_path).get(img) is None
    img2 = img.copy()
    img2[0, 0, 0] ^= 1
    assert a.get(img2) is None
    a.path(img).write_bytes(b"garbage")                    # a damaged entry is recomputed
    assert a.get(img) is None and not a.path(img).exists()


# --------------------------------------------------------------------------- keys
def test_key_dispatcher():
    c = Controls()
    d = KeyDispatcher(c)
    assert d.dispatch("c") == "compensation" and c.mode == "off"
    d.dispatch("c")
    assert c.mode == "full"
    d.dispatch("g")
    assert c.mode == "geometry"
    d.dispatch("c")
    assert c.mode == "full"
    d.dispatch("right"), d.dispatch("right"), d.dispatch("left")
    assert c.step == 1
    d.dispatch("space"), d.dispatch("s")
    assert c.paused and c.overlay
    assert d.dispatch("x") is None
    v = c.version
    d.dispatch("escape")
    assert c.quit and c.version == v + 1


@pytest.mark.timeout(120)
def test_interactive_show_follows_keys(tmp_path, comp):
    imgs = _slides(tmp_path / "deck", ["p1.png", "p2.png", "p3.png"])
    order = [imgs["p1.png"], imgs["p2.png"], imgs["p3.png"]]
    states = []
    sink = RecordingSink(realtime=True, keys=["right", "c", "g", "right", "s", "left", "left", "left", "q"])
    player = Player(comp, SlidesSource(tmp_path / "deck"), sink, iterations=3)
    overlay = []
    sink.on_write = lambda s: (states.append((s.indices[-1], player.controls.mode)),
                               overlay.append(player.controls.overlay))
    stats = player.run()
    assert player.controls.quit
    shown = dict()
    for (idx, mode), frame in zip(states, sink.frames, strict=True):
        shown.setdefault((idx, mode), frame)
    assert [s[0] for s in states][:2] == [0, 1]
    # 'c' on slide 1: the plain projector picture (letterboxed input)
    assert np.array_equal(shown[(1, "off")], fit_image(order[1], PROJ))
    # 'g': geometry only
    assert max_abs(shown[(1, "geometry")], comp.warp(order[1])) == 0
    assert max_abs(shown[(2, "geometry")], comp.warp(order[2])) == 0
    # never beyond the first slide going back
    assert min(s[0] for s in states) == 0 and max(s[0] for s in states) == 2
    # the overlay draws text: the frame after 's' differs from the same slide without it
    with_overlay = [f for (s, on, f) in zip(states, overlay, sink.frames, strict=True)
                    if on and s == (2, "geometry")]
    assert with_overlay, f"no frame of slide 2 (geometry) with the overlay on: {states} {overlay}"
    assert max_abs(with_overlay[0], shown[(2, "geometry")]) > 0, "the overlay left the frame as is"
    assert stats.frames_out == len(sink.frames)


def test_overlay_draws_stats():
    st = LoopStats()
    st.add("solve", 0.012)
    st.iterations.add(7)
    st.residual = 0.5
    lines = st.overlay_lines("full", paused=True)
    assert "dropped 0" in lines[0] and "solve 12.0" in lines[1] and "PAUSED" in lines[2]
    from rtdefocus.stream import draw_overlay
    frame = np.zeros((120, 200, 3), np.uint8)
    out = draw_overlay(frame, lines)
    assert out.shape == frame.shape and out.max() == 255 and frame.max() == 0


# --------------------------------------------------------------------------- stats
def test_series_mean_p95_constant_memory():
    s = Series()
    for v in range(1, 101):
        s.add(v)
    assert s.mean == pytest.approx(50.5)
    assert s.percentile(95) == pytest.approx(np.percentile(np.arange(1, 101), 95))
    for v in range(WINDOW * 2):
        s.add(1000 + v)
    assert s.count == 100 + 2 * WINDOW
    assert s.recent()[0] == 1000 + WINDOW and s.recent()[-1] == 1000 + 2 * WINDOW - 1
    assert s._ring.nbytes == WINDOW * 8


def test_frames_past_the_deadline_count_late():
    """A live player's deadline (two periods) counts the frames shown after it; without one
    (file rendering) nothing is late."""
    st = LoopStats()
    st.add_latency(0.5)
    assert st.late == 0 and st.stages["latency"].count == 1
    st.deadline = 2 / 30
    for seconds in (0.010, 0.066, 0.070, 0.120):
        st.add_latency(seconds)
    assert st.late == 2 and st.as_dict()["late"] == 2
    assert "2 frames shown more than 67 ms" in st.summary()


def test_summary_and_json(tmp_path, comp):
    stats = play(comp, ArraySource(synthetic_frames(5)), NullSink())
    text = stats.summary()
    assert "5 frames out, 5 in, 0 dropped" in text and "solve" in text and "p95" in text
    data = json.loads(stats.write_json(tmp_path / "s.json").read_text())
    assert data["frames_out"] == 5 and data["dropped"] == 0
    assert data["iterations_per_frame"]["mean"] == comp.iterations
    assert data["stages_ms"]["solve"]["count"] == 5 and data["stages_ms"]["solve"]["p95"] > 0


# --------------------------------------------------------------------------- sources, sinks
def test_open_source_and_sink_dispatch(tmp_path):
    write_image(tmp_path / "one.png", synthetic_frames(1)[0])
    assert open_source(tmp_path / "one.png").kind == "image"
    from rtdefocus.stream.sources import parse_camera
    assert parse_camera("camera:0") == 0 and parse_camera("camera:rtsp://h/x") == "rtsp://h/x"
    assert parse_camera("http://cam.local/stream") == "http://cam.local/stream"
    assert parse_camera("clip.mp4") is None
    with pytest.raises(InputError, match="not found"):
        open_source(tmp_path / "missing.mp4")
    with pytest.raises(InputError, match="no images"):
        open_source(_empty(tmp_path / "empty"))
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all")
    with pytest.raises(InputError, match="cannot open"):
        VideoSource(tmp_path / "junk.mp4")
    assert open_sink("null").kind == "null"
    assert open_sink(tmp_path / "v.mp4").kind == "video file"
    assert open_sink(tmp_path / "frames").kind == "images"
    assert open_sink(tmp_path / "x.png").kind == "image"


def _empty(p):
    p.mkdir()
    return p


def test_camera_that_cannot_open_is_a_clear_error(tmp_path):
    from rtdefocus.stream.sources import CameraSource
    with pytest.raises(CaptureError, match="cannot open camera"):
        CameraSource(str(tmp_path / "no_such_stream.mp4"))


def test_array_source_live_needs_fps():
    with pytest.raises(InputError, match="fps"):
        ArraySource([], live=True)


@pytest.mark.timeout(120)
def test_quit_key_stops_an_endless_live_source(comp):
    # an endless live source stops on 'q' from the (scripted) viewer
    def endless():
        f = synthetic_frames(1)[0]
        while True:
            yield f
    sink = RecordingSink(realtime=True, keys=["s", "q"])
    stats = play(comp, ArraySource(endless(), fps=200, live=True), sink, iterations=1)
    assert stats.frames_out == 2 and threading.active_count() < 10


# --------------------------------------------------------------------------- CLI
def test_cli_play_video_to_folder_with_stats(tmp_path, calib, capsys):
    setup = calib.save(tmp_path / "setup.npz")
    video = tmp_path / "in.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25, PROJ)
    for f in synthetic_frames(6):
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()
    rc = cli.main(["-q", "play", str(setup), str(video), "--out", str(tmp_path / "out"),
                   "--stats", str(tmp_path / "stats.json"), "--iterations", "3"])
    assert rc == 0
    assert len(list((tmp_path / "out").glob("frame_*.png"))) == 6
    data = json.loads((tmp_path / "stats.json").read_text())
    assert data["frames_out"] == 6 and data["iterations_per_frame"]["mean"] == 3
    assert "6 frames out" in capsys.readouterr().out


def test_cli_play_image_to_image_uses_cache(tmp_path, calib, capsys):
    setup = calib.save(tmp_path / "setup.npz")
    write_image(tmp_path / "slide.png", synthetic_frames(1, seed=9)[0])
    args = ["-q", "play", str(setup), str(tmp_path / "slide.png"), "--out", str(tmp_path / "o.png"),
            "--cache", str(tmp_path / "cache")]
    assert cli.main(args) == 0
    first = read_image(tmp_path / "o.png")
    assert first.shape == (PROJ[1], PROJ[0], 3)
    assert len(list((tmp_path / "cache").rglob("*.png"))) == 1
    assert cli.main(args) == 0
    assert np.array_equal(read_image(tmp_path / "o.png"), first)


def test_cli_play_precondition_reaches_the_compensator(tmp_path, calib):
    """`play --precondition`: the slide comes out as the API's Compensator with that setting
    makes it, the settings differ in their pictures, and the slide cache tells them apart."""
    setup = calib.save(tmp_path / "setup.npz")
    slide = synthetic_frames(1, seed=9)[0]
    write_image(tmp_path / "slide.png", slide)
    outs = {}
    for pc in ("colour+spatial", "none"):
        args = ["-q", "play", str(setup), str(tmp_path / "slide.png"), "--out",
                str(tmp_path / f"{pc}.png"), "--iterations", "3", "--backend", "numpy",
                "--precondition", pc, "--cache", str(tmp_path / "cache")]
        assert cli.main(args) == 0
        outs[pc] = read_image(tmp_path / f"{pc}.png")
        api = rd.Compensator(calib, backend="numpy", precondition=None if pc == "none" else pc)
        expect = api.compensate(slide, iterations=3)
        assert np.abs(outs[pc].astype(int) - expect).max() <= 1, pc
    assert not np.array_equal(outs["colour+spatial"], outs["none"])
    assert len(list((tmp_path / "cache").rglob("*.png"))) == 2
    with pytest.raises(SystemExit) as bad:                 # argparse names the choices
        cli.main(["-q", "play", str(setup), str(tmp_path / "slide.png"), "--out", "null",
                  "--precondition", "luma"])
    assert bad.value.code == 2


def test_cli_play_missing_source_exits_1(tmp_path, calib, capsys):
    setup = calib.save(tmp_path / "setup.npz")
    assert cli.main(["play", str(setup), str(tmp_path / "nope.mp4"), "--out", "null"]) == 1
    assert "not found" in capsys.readouterr().err


def test_cli_play_flatten_reports_the_clipped_share(tmp_path, capsys):
    """`play --flatten` prints and writes the share of clipped pixels the Compensator measured
    on the frames (the fabric preset: a dark partition and a poster, so some content clips);
    without --flatten no such report."""
    calib = virtual_calibration("fabric")
    setup = calib.save(tmp_path / "setup.npz")
    frames = synthetic_frames(3, seed=4)
    video = tmp_path / "in.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25, PROJ)
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()
    # The frames as play decodes them (MJPG is lossy: the clipped share moves with the codes).
    src = VideoSource(str(video))
    decoded = [src.read().image for _ in frames]
    src.close()
    stats_file = tmp_path / "stats.json"
    rc = cli.main(["-q", "play", str(setup), str(video), "--out", "null", "--flatten", "0.3",
                   "--stats", str(stats_file), "--iterations", "2", "--backend", "numpy"])
    assert rc == 0
    out = capsys.readouterr().out
    data = json.loads(stats_file.read_text())["flatten"]
    assert data["brightness"] == pytest.approx(0.3) and data["clipped"]["count"] == 3
    ref = rd.Compensator(Calibration.load(setup), surface="flatten", brightness=0.3,
                         backend="numpy", iterations=1)
    shares = []
    for f in decoded:
        ref.compensate(f)
        shares.append((ref.last_info["clipped"], ref.last_info["clipped_dark"]))
    hi, lo = np.array(shares).T
    assert data["clipped"]["mean"] == pytest.approx(hi.mean(), abs=1e-9), (data, shares)
    assert data["clipped_dark"]["max"] == pytest.approx(lo.max(), abs=1e-9), (data, shares)
    assert data["clipped"]["max"] > 0, "the bright test frames should clip on the dark partition"
    assert f"too bright for the wall: mean {100 * data['clipped']['mean']:.1f} %" in out, out
    assert "darker than the room light allows" in out
    assert cli.main(["-q", "play", str(setup), str(video), "--out", "null"]) == 0
    assert "clipped" not in capsys.readouterr().out


def test_budget_leaves_cheap_new_frames_out_of_the_deadline():
    """A cut's cold start (``deadline=False``) moves the average but not the deadline's median
    of moving frames (unless there is nothing else to go by)."""
    b = IterationBudget(30.0)
    b.update(0.020, 0.004, 1, deadline=False)         # the first frame, cold
    assert b.frame_seconds(0, deadline=True) == pytest.approx(0.016, abs=1e-9)
    for _ in range(3):
        b.update(0.054, 0.004, 1)                     # moving frames
    b.update(0.030, 0.004, 1, deadline=False)         # a cut
    assert b.frame_seconds(0, deadline=True) == pytest.approx(0.050, abs=1e-9)
    assert b.frame_seconds(0) < 0.050


def test_budget_expects_a_repeat_cost_until_one_is_measured():
    """``expect`` gives an unmeasured kind its rest (a still picture's repeat: all but the warp
    and the start); the kind's first measured frame replaces it, and a measured kind keeps its
    own."""
    b = IterationBudget(30.0)
    b.update(0.104, 0.004, 1)                                # a moving frame: rest 0.100
    assert b.frame_seconds(0, repeat=True, deadline=True) == pytest.approx(0.100)
    b.expect(0.010, repeat=True)
    assert b.frame_seconds(0, repeat=True, deadline=True) == pytest.approx(0.010)
    assert b.frame_seconds(0, repeat=False, deadline=True) == pytest.approx(0.100)
    b.update(0.024, 0.004, 1, repeat=True)                   # measured: rest 0.020
    assert b.frame_seconds(0, repeat=True, deadline=True) == pytest.approx(0.020)
    b.expect(0.001, repeat=True)
    assert b.frame_seconds(0, repeat=True, deadline=True) == pytest.approx(0.020)


def test_a_moving_frame_shown_with_geometry_only_costs_no_estimate_and_no_whole_compare(
        comp, monkeypatch):
    """A device whose frames cost 150 ms at 30 fps: the player shows every moving frame with
    geometry only, and beside the warp does no work whose result it would not use: no
    compensation, no motion estimate, and a repeated picture is told from a moving one by a
    few rows (the whole frame is compared only where they are the same, as in a still)."""
    from rtdefocus.stream import repeat

    still, moving = 6, 24
    frames = [synthetic_frames(1, seed=1)[0].copy() for _ in range(still)] + synthetic_frames(moving)
    wholes, estimates, compensated, warmed = [], [], [], []
    whole_equal = repeat._whole_equal
    monkeypatch.setattr(repeat, "_whole_equal", lambda a, b: wholes.append(1) or whole_equal(a, b))
    estimate = comp._motion.estimate
    monkeypatch.setattr(comp._motion, "estimate",
                        lambda *a: estimates.append(bool(warmed)) or estimate(*a))
    comp.reset()

    class Device(PacedCompensator):
        def compensate(self, image, **kw):
            compensated.append(bool(warmed))
            return super().compensate(image, **kw)

        def warm_up(self, iterations=1, frames=1):
            info = super().warm_up(iterations=iterations, frames=frames)
            warmed.append(True)
            return info

    paced = Device(comp, overhead=0.150 - 0.004, per_iteration=0.004)
    player = Player(paced, ArraySource(frames, fps=30.0, live=True), RecordingSink(realtime=True))
    stats = player.run()
    assert warmed and stats.geometry_frames == stats.frames_out, stats.summary()
    assert True not in compensated and True not in estimates, (compensated, estimates)
    # the still's repeats (5), and at most a copy per frame the decoder dropped
    assert len(wholes) <= still - 1 + stats.dropped, (len(wholes), stats.summary())
    assert stats.frames_out + stats.dropped == still + moving
