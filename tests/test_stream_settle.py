"""A still picture's settle on a slow device runs beside the live player's frame loop: the loop
keeps showing frames while it is solved, the still is shown compensated once it is done, and a
result that comes after the picture changed is dropped (rtdefocus.stream.settle)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from test_stream import PacedCompensator, RecordingSink, synthetic_frames, virtual_calibration

from rtdefocus import Compensator
from rtdefocus.stream import ArraySource, Player
from rtdefocus.stream.settle import BackgroundSettle


@pytest.fixture(scope="module")
def comp():
    return Compensator(virtual_calibration())


FPS = 30.0
MOVING = 0.150          # a moving frame's cost at 30 fps: never compensated, a settle's 4.5 periods
WAIT_S = 20.0           # a bound on a wait that ends at once when the player works


class SettleDevice(PacedCompensator):
    """A device whose frames cost MOVING (the real Compensator, paced): its settle, solved by
    ``compensate_warped``, records the thread it ran on and waits until the player has shown
    ``frames_during`` more frames than when it began (so it spans at least that many frame
    periods, however fast the machine), or until ``shown_index`` is shown. ``cpu``: its solver
    is said to run on the CPU cores (``solves_off_the_cpu`` False); ``warp_cpu``: its warp
    burns that many seconds of CPU on the calling thread first (a geometry-only frame on a
    slow CPU)."""

    def __init__(self, comp, frames_during=0, shown_index=None, cpu=False, warp_cpu=0.0):
        super().__init__(comp, overhead=MOVING - 0.004, per_iteration=0.004)
        self.frames_during, self.shown_index = frames_during, shown_index
        # (the settle waits on the player, not on the CPU: a device of its own, as a GPU is,
        # unless said to be the CPU)
        self.solves_off_the_cpu, self.warp_cpu = not cpu, warp_cpu
        self.player, self.settles, self.threads, self.outs = None, [], [], []
        self.compensate_threads = []

    def warp(self, image):
        end = time.thread_time() + self.warp_cpu
        while time.thread_time() < end:
            pass
        return self.comp.warp(image)

    def compensate(self, image, **kw):
        self.compensate_threads.append(threading.current_thread())
        return super().compensate(image, **kw)

    def compensate_warped(self, warped, **kw):
        self.threads.append(threading.current_thread())
        sink, begun = self.player.sink, len(self.player.sink.indices)
        t0 = time.perf_counter()
        out = self.comp.compensate_warped(warped, **kw)
        end = time.perf_counter() + WAIT_S
        while time.perf_counter() < end and not (
                len(sink.indices) >= begun + self.frames_during
                and (self.shown_index is None or self.shown_index in sink.indices)):
            time.sleep(0.005)
        self.settles.append(len(sink.indices) - begun)
        info = dict(self.comp.last_info)
        info["seconds"] = {"solve": info["iterations"] * self.per_iteration,
                           "total": time.perf_counter() - t0}
        self.last_info = info
        self.outs.append(out.copy())
        return out


def play_settle(comp, still, moving, **device):
    frames = [synthetic_frames(1, seed=1)[0].copy() for _ in range(still)] + synthetic_frames(moving)
    comp.reset()
    dev = SettleDevice(comp, **device)
    player = Player(dev, ArraySource(frames, fps=FPS, live=True), RecordingSink(realtime=True))
    dev.player = player
    stats = player.run()
    return dev, player, stats, frames


@pytest.mark.parametrize("cpu", [False, True], ids=["off the cpu", "on the cpu with room"])
def test_a_settle_beside_the_loop_loses_no_frame_and_shows_the_still_compensated(comp, cpu,
                                                                                monkeypatch):
    """A still of 45 frames then 12 moving ones at 30 fps on a device too slow for moving
    frames: the still is settled on a worker thread while the loop shows at least 3 more
    frames; once done, the still's next frames show the settle's result (not its geometry
    only), and no frame after the still does; no frame is lost (only copies of the still may
    be dropped), every moving frame is shown with geometry only, and the worker is gone when
    the show ends. So on a device off the CPU, and on one on the CPU where the loop's work for
    a geometry-only frame (a 64x48 warp, well under a millisecond) leaves the room. The
    Compensator is left as after compensating the still: a refinement of it (``compensate``)
    continues its solve without warping it again."""
    still, moving = 45, 12
    dev, player, stats, frames = play_settle(comp, still, moving, frames_during=3, cpu=cpu)
    assert player._settle.room_on_the_cpu() or not cpu
    sink = player.sink
    assert len(dev.settles) == 1 and dev.settles[0] >= 3, dev.settles
    assert all(t is not threading.main_thread() for t in dev.threads)
    assert not any(t.is_alive() for t in dev.threads), "the settle's worker outlived the show"
    assert stats.dropped == stats.dropped_copies, stats.summary()
    assert set(range(still, still + moving)) <= set(sink.indices), sink.indices
    settled = [i for i, f in zip(sink.indices, sink.frames, strict=True) if np.array_equal(f, dev.outs[0])]
    assert settled and max(settled) < still, settled          # the still's frames only
    assert not np.array_equal(dev.outs[0], comp.warp(frames[0]))
    shown = dict(zip(sink.indices, sink.frames, strict=True))
    for i in range(still, still + moving):
        assert np.array_equal(shown[i], comp.warp(frames[i])), i
    assert player._settle.dropped == 0
    warps, warp = [], comp.warp
    monkeypatch.setattr(comp, "warp", lambda image: warps.append(image) or warp(image))
    comp.compensate(frames[0], iterations=1)
    assert warps == [] and comp.last_info["start"] == "still", comp.last_info.get("start")


def test_a_settle_that_ends_after_the_picture_changed_is_not_shown(comp):
    """A still of 30 frames then 12 moving ones: the settle is made to end only after the
    first moving frame is shown (which the loop does meanwhile): its result is dropped, never
    shown on a moving frame nor after, and no moving frame is lost."""
    still, moving = 30, 12
    dev, player, stats, _ = play_settle(comp, still, moving, shown_index=still)
    sink = player.sink
    assert len(dev.outs) == 1, dev.settles
    assert not any(np.array_equal(f, dev.outs[0]) for f in sink.frames)
    assert player._settle.dropped == 1
    assert stats.dropped == stats.dropped_copies, stats.summary()
    assert set(range(still, still + moving)) <= set(sink.indices), sink.indices


def test_a_wrapper_without_its_own_solve_of_a_warped_frame_settles_on_the_loop(comp):
    """A wrapper that paces ``compensate`` and forwards the rest would run a settle unpaced
    beside the loop: the settle stays on the loop's thread there."""
    paced = PacedCompensator(comp, overhead=0.1, per_iteration=0.004)
    player = Player(paced, ArraySource(synthetic_frames(2), fps=FPS, live=True),
                    RecordingSink(realtime=True))
    assert not BackgroundSettle(player).available()
    dev = SettleDevice(comp)
    assert BackgroundSettle(Player(dev, ArraySource(synthetic_frames(2), fps=FPS, live=True),
                                   RecordingSink(realtime=True))).available()



def test_a_solve_on_the_cpu_settles_beside_the_loop_only_where_the_loop_leaves_room(comp):
    """A solve on the CPU cores (NumPy, an OpenCL CPU device) takes them from the warps of the
    frames shown meanwhile: it settles beside the loop only once the loop's work for a
    geometry-only frame is measured and, taken SETTLE_CPU_SHARE times with SETTLE_CPU_HEADROOM,
    fits one period: 20 ms of a frame's own thread does not at 30 fps (50 ms > 33 ms), does at
    10 fps (100 ms). Where it does not, no settle is made at all (a settle on the loop's thread
    would hold the loop as long); a player that cannot settle beside the loop for its own reason
    (frames read on the loop's thread) settles on the loop. A solver off the CPU (an OpenCL
    GPU) settles beside it in any case."""
    from rtdefocus.cl.runtime import get_runtime
    from rtdefocus.stream.controls import SPREAD_MIN

    cpu = Compensator(virtual_calibration(), backend="numpy")
    assert not cpu.solves_off_the_cpu
    for fps, room in ((FPS, False), (10.0, True)):
        source = ArraySource(synthetic_frames(2), fps=fps, live=True)
        settle = BackgroundSettle(Player(cpu, source, RecordingSink(realtime=True)))
        for _ in range(SPREAD_MIN):
            assert not settle.available()                # (not measured yet)
            settle.timed(time.process_time(), time.thread_time() - 0.020)
        assert settle.geometry_cost() >= 0.020
        assert settle.available() == settle.may_settle() == room, fps
    # a player whose settle cannot run beside the loop for its own reason settles on the loop
    inline = Player(cpu, source, RecordingSink(realtime=True), threads=False)
    assert not BackgroundSettle(inline).available() and BackgroundSettle(inline).may_settle()
    if comp.backend == "opencl":
        assert comp.solves_off_the_cpu == get_runtime().is_gpu
        player = Player(comp, source, RecordingSink(realtime=True))
        assert BackgroundSettle(player).available() == (get_runtime().is_gpu
                                                        and not comp.shares_gl)


def test_a_cpu_device_without_room_makes_no_settle(comp):
    """Through the real player at 30 fps, a device on the CPU whose geometry-only frame burns
    20 ms of the loop's thread (50 ms with a solve beside it and the headroom: over the 33 ms
    period): the loop measured that frame's work (at least the 20 ms burnt), and the still is
    settled neither beside the loop nor on its thread (which would hold the loop as long): it
    stays at geometry only, every frame of it."""
    dev, player, stats, frames = play_settle(comp, 40, 4, cpu=True, warp_cpu=0.020)
    assert player._settle.geometry_cost() >= 0.020
    assert not player._settle.room_on_the_cpu() and not player._settle.may_settle()
    assert dev.threads == [] and dev.compensate_threads == [], "a settle was made"
    assert stats.iterations.count == 0, stats.summary()
    geometry = comp.warp(frames[0])
    shown = dict(zip(player.sink.indices, player.sink.frames, strict=True))
    assert all(np.array_equal(shown[i], geometry) for i in range(40) if i in shown)
