"""`rtdefocus eval --video`: the moving clip, and a quick run through the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rtdefocus.study.eval_video import QUICK_SEGMENTS, Segment, make_clip, segment_summary


def _photos():
    rng = np.random.default_rng(0)
    return {n: rng.integers(0, 256, (90 + 10 * i, 120, 3), dtype=np.uint8)
            for i, n in enumerate(("a", "b", "c"))}


def test_clip_segments_and_motion():
    """Frame count and size per segment; a still repeats its frame; a pan by p px/frame moves
    the picture by p px (found by phase correlation); the cut changes the picture."""
    import cv2

    segs = (Segment("still", "still", 3), Segment("pan", "pan", 3, 8.0), Segment("cut", "cut", 2),
            Segment("zoom", "zoom", 2, 0.02), Segment("fade", "fade", 2))
    clip = make_clip((160, 120), segs, photos=_photos())
    assert [s for s, _ in clip] == ["still"] * 3 + ["pan"] * 3 + ["cut"] * 2 + ["zoom"] * 2 + \
        ["fade"] * 2
    assert all(f.shape == (120, 160, 3) and f.dtype == np.uint8 for _, f in clip)
    assert np.array_equal(clip[0][1], clip[2][1])
    a, b = (clip[i][1][..., 1].astype(np.float32) for i in (3, 4))
    (dx, dy), _ = cv2.phaseCorrelate(a, b)
    assert abs(abs(dx) - 8.0 * 160 / 800) < 0.3 and abs(dy) < 0.3
    assert np.abs(clip[6][1].astype(int) - clip[5][1].astype(int)).mean() > 20      # the cut
    assert np.array_equal(clip[6][1], clip[7][1])                                     # held
    assert not np.array_equal(clip[-1][1], clip[-2][1])                               # the fade


def test_recovery_after_cut():
    """Frames to recover: from the first frame on which the mode stays at least as good as the
    1-iteration cold start."""
    segs = (Segment("cut", "cut", 4),)
    gains = {"cold-1": [1.0, 1.0, 1.0, 1.0], "warm-1": [-5.0, 0.5, 1.2, 1.5],
             "offline": [3.0, 3.0, 3.0, 3.0]}
    records = [{"segment": "cut", "gain": {m: g[i] for m, g in gains.items()},
                "iterations": {m: 1 for m in gains}, "ms": {m: 1.0 for m in gains}}
               for i in range(4)]
    summ = segment_summary(records, segs, list(gains))
    assert summ["warm-1"]["cut_recovery_frames"] == 2
    assert summ["cold-1"]["cut_recovery_frames"] == 0
    assert summ["warm-1"]["share"]["cut"] == pytest.approx(np.mean(gains["warm-1"]) / 3.0)


# Camera-view PSNR gains (dB) per segment of the quick clip at 1 iteration a frame, warm and
# cold, and the offline ceiling (10 cold iterations): `tools/measure_gains.py --sections video`
# (OpenCL on PoCL; fixed budgets, deterministic). The wall-clock modes and the window depend on
# the machine's speed: their figures are benchmarks (docs/test-figures.md).
MEASURED_VIDEO = {
    "warm-1": {"still": 2.924, "slow pan": 3.365, "fast pan": 3.061, "cut": 3.275, "zoom": 3.866,
               "fade": 2.579},
    "cold-1": {"still": 1.907, "slow pan": 1.961, "fast pan": 1.948, "cut": 2.44, "zoom": 2.733,
               "fade": 2.378},
    "offline": {"still": 3.768, "slow pan": 3.683, "fast pan": 3.771, "cut": 4.218, "zoom": 4.589,
                "fade": 4.079},
}
MARGIN = 0.85


@pytest.mark.slow
def test_eval_video_quick(tmp_path):
    """`rtdefocus eval --video --quick` writes the table, JSON and plot; the offline ceiling
    beats geometry only on every segment, and a cold start's gain does not depend on motion."""
    from rtdefocus import cli

    code = cli.main(["-q", "eval", "--video", "--quick", "-o", str(tmp_path), "--budgets", "1",
                     "--fps", "30"])
    assert code == 0
    for name in ("video.md", "video.json", "video.png"):
        assert (tmp_path / name).stat().st_size > 0
    result = json.loads((tmp_path / "video.json").read_text())
    segments = [s.name for s in QUICK_SEGMENTS]
    assert result["segments"] == segments
    assert result["modes"] == ["warm-1", "cold-1", "fps-30", "window-30", "geowindow-30",
                               "offline"]
    assert len(result["frames"]) == sum(s.frames for s in QUICK_SEGMENTS)
    md = (tmp_path / "video.md").read_text()
    table = [line for line in md.splitlines() if line.startswith("|")]
    assert table[0] == "| mode | " + " | ".join(segments) + " | still @1 s | cut | it | ms |"
    assert len(table) == 2 + len(result["modes"])
    assert all(line.count("|") == len(segments) + 6 for line in table)
    summ = result["summary"]
    for seg in segments:
        assert summ["offline"]["gain"][seg] > summ["cold-1"]["gain"][seg] > 0, seg
        # The deterministic modes keep MARGIN of their measured gains, and the warm start of
        # its measured share of the offline gain, on every segment.
        for mode in ("warm-1", "cold-1", "offline"):
            need = MARGIN * MEASURED_VIDEO[mode][seg]
            assert summ[mode]["gain"][seg] >= need, (mode, seg, summ[mode]["gain"][seg], need)
        need = MARGIN * MEASURED_VIDEO["warm-1"][seg] / MEASURED_VIDEO["offline"][seg]
        assert summ["warm-1"]["share"][seg] >= need, (seg, summ["warm-1"]["share"][seg], need)
    assert summ["cold-1"]["cut_recovery_frames"] == 0
    for f in result["frames"]:
        assert f["iterations"]["fps-30"] >= 1
    for m in ("window-30", "geowindow-30"):
        w = result["window"][m]
        assert w["shown"] + w["dropped"] == len(result["frames"]) and w["shown"] > 0
    geo = [line for line in md.splitlines() if line.startswith("the window at 30 fps, geometry only:")]
    assert len(geo) == 1 and "to keep up" not in geo[0]
    assert all(f["iterations"]["geowindow-30"] == 0 for f in result["frames"])


@pytest.mark.slow
def test_window_on_a_slowed_device_keeps_the_promise(tmp_path):
    """The clip played live at 30 fps through the real player on a device 20x slower than this
    machine (every compensated frame costs 20x its time here, over two periods whatever the
    load): no frame that the geometry-only window shows is dropped (only copies of a still
    picture on the screen), no segment is worse than geometry only (camera view against the
    sharp reference, within 0.1 dB), and the long still is compensated once it has lasted."""
    from rtdefocus.study.eval_video import run_video_eval

    segs = (Segment("still", "still", 80), Segment("pan", "pan", 12, 14.0),
            Segment("cut", "cut", 6), Segment("zoom", "zoom", 8, 0.02))
    result = run_video_eval(tmp_path, projector_size=(160, 120), camera_size=(240, 180),
                            segments=segs, budgets=(1,), fps=(30,), slowdown=(20,), offline=0,
                            plot=False)
    mode = "window-30-s20"
    w, geo = result["window"][mode], result["window"]["geowindow-30"]
    assert w["dropped"] == w["dropped_copies"], w
    assert w["shown"] + w["dropped"] == geo["shown"] + geo["dropped"] == 80 + 12 + 6 + 8
    gain, geo_gain = (result["summary"][m]["gain"] for m in (mode, "geowindow-30"))
    for seg in gain:
        assert gain[seg] >= geo_gain[seg] - 0.1, (seg, gain, geo_gain)
    last_still = result["frames"][79]
    assert last_still["segment"] == "still" and last_still["gain"][mode] > 0.3, last_still["gain"]
    assert w["geometry_only"] >= 12 + 8, w          # moving content: geometry only


class JitteryDevice:
    """The real Compensator on a device whose costs jitter: a new picture costs ``start`` (the
    start alone: warp, motion estimate, carried correction) plus ``per_iteration`` per solver
    iteration, times a factor drawn anywhere in 0.9-1.25 per frame (a CPU device: 50-62 ms for
    the same moving frame at 800x600), a repeated picture ``STILL`` plus its iterations,
    steadily. It sleeps what the real work did not take and reports that split in
    ``last_info``; its warm-up reports its moving frames' costs alike."""

    STILL = 0.020

    def __init__(self, comp, start, per_iteration, seed=0):
        self.comp, self.start, self.per_iteration = comp, start, per_iteration
        self.rng = np.random.default_rng(seed)
        self.last_info: dict = {}

    def __getattr__(self, name):
        return getattr(self.comp, name)

    def _seconds(self, iterations, repeat):
        solve = iterations * self.per_iteration
        if repeat:
            return {"solve": solve, "total": self.STILL + solve}
        f = float(self.rng.uniform(0.9, 1.25))
        return {"solve": f * solve, "total": f * (self.start + solve)}

    def compensate(self, image, **kw):
        import time

        t0 = time.perf_counter()
        out = self.comp.compensate(image, **kw)
        info = dict(self.comp.last_info)
        sec = self._seconds(info["iterations"], info.get("start") == "still")
        time.sleep(max(0.0, sec["total"] - (time.perf_counter() - t0)))
        info["seconds"] = {**sec, "total": time.perf_counter() - t0}
        self.last_info = info
        return out

    def warm_up(self, iterations=1, frames=1):
        info = dict(self.comp.warm_up(iterations=iterations, frames=frames))
        info["moving"] = [self._seconds(info["iterations"], False) for _ in info["moving"]]
        info["seconds"] = info["moving"][-1]
        return info


@pytest.mark.slow
def test_window_on_a_jittery_device_loses_no_frame_to_optional_work(tmp_path, monkeypatch):
    """The clip played live at 10 fps through the real player on a device whose moving frames
    cost 0.9-1.25x their usual, with the start alone (motion estimate and carried correction)
    60 % of the two periods a frame may take and each iteration 7.5 % more, while a still's
    refinements cost the same every time: the player compensates moving frames where they fit,
    and no frame that the geometry-only window shows is lost to that work (only copies of a
    still on the screen are dropped), and no segment is worse than geometry only."""
    from rtdefocus.study import eval_video

    monkeypatch.setattr(eval_video, "SlowedCompensator",
                        lambda comp, k: JitteryDevice(comp, start=0.060, per_iteration=0.010))
    segs = (Segment("still", "still", 16), Segment("pan", "pan", 16, 14.0),
            Segment("cut", "cut", 5))
    result = eval_video.run_video_eval(tmp_path, projector_size=(160, 120),
                                       camera_size=(240, 180), segments=segs, budgets=(1,),
                                       fps=(15,), slowdown=(2,), offline=0, plot=False)
    mode = "window-15-s2"
    w, geo = result["window"][mode], result["window"]["geowindow-15"]
    assert w["dropped"] == w["dropped_copies"], w
    assert w["shown"] + w["dropped"] == geo["shown"] + geo["dropped"] == 16 + 16 + 5
    gain, geo_gain = (result["summary"][m]["gain"] for m in (mode, "geowindow-15"))
    for seg in gain:
        assert gain[seg] >= geo_gain[seg] - 0.1, (seg, gain, geo_gain)
    # MEASURED (2 runs, loaded machine): pan +0.87, +0.90 dB (2-4 of 37 frames geometry only)
    assert gain["pan"] >= 0.74, gain                 # moving frames compensated where they fit


def test_slowdown_below_one_is_a_clear_error(tmp_path, capsys):
    """``--slowdown`` takes factors >= 1 (1: this machine); 0.5 is refused before any work."""
    from rtdefocus import cli

    code = cli.main(["eval", "--video", "--quick", "-o", str(tmp_path), "--slowdown", "1,0.5"])
    assert code != 0
    assert "slowdown" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
