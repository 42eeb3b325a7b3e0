"""`rtdefocus eval --drift`: the show played through a timeline of set-up changes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rtdefocus.cli import main
from rtdefocus.study.eval_drift import drift_segments, event_figures, run_drift_eval

TINY = {"size": (160, 120), "fps": 10.0}
BUMP = (0.5, "bump", {"projector_yaw_deg": 0.3, "projector_shift_px": 3.0})


@pytest.fixture(scope="module")
def bumped(tmp_path_factory):
    """2 s of show at 160x120, 10 fps, a projector bump at 0.5 s (during the first still), no
    watcher."""
    out = tmp_path_factory.mktemp("drift")
    result = run_drift_eval(out, **TINY, duration_s=2.0, events=[BUMP],
                            rows=("none", "oracle", "geometry"), false_alarm_s=0)
    return out, result


def _psnr(result, row, t):
    return next(r["psnr"][row] for r in result["frames"] if abs(r["t"] - t) < 1e-9)


def test_clip_cycle_has_pans_a_cut_and_stills():
    segs = drift_segments(30.0)
    assert [s.kind for s in segs] == ["still", "pan", "cut", "zoom", "fade"]
    assert sum(s.frames for s in segs) == 240           # an 8 s cycle at 30 fps


def test_oracle_recovers_and_stale_calibration_degrades(bumped):
    """Before the bump every row shows the original calibration; after it the stale one is far
    worse than the oracle on every frame, and the oracle (re-calibrated, solve restarted) is back
    to its pre-bump quality within 0.4 s on the same still picture."""
    _, result = bumped
    frames = result["frames"]
    before = [r for r in frames if r["t"] < 0.5]
    after = [r for r in frames if r["t"] >= 0.5]
    assert all(r["psnr"]["none"] == r["psnr"]["oracle"] for r in before)
    assert all(r["psnr"]["none"] < r["psnr"]["oracle"] - 3.0 for r in after)
    assert _psnr(result, "oracle", 0.9) > _psnr(result, "oracle", 0.4) - 1.0
    # Compensation still beats geometry only with the fresh calibration.
    assert _psnr(result, "oracle", 0.9) > _psnr(result, "geometry", 0.4)
    (ev,) = result["events"]
    assert ev["kind"] == "bump" and ev["t"] == pytest.approx(0.5)
    assert ev["none_vs_oracle_db"] < -3.0


def test_report_files(bumped):
    out, result = bumped
    assert {p.split("/")[-1] for p in result["files"]} == {"drift.md", "drift.json", "drift.png"}
    md = (out / "drift.md").read_text()
    assert "| bump: projector 0.3°, projector 3 px | 0.5 |" in md
    data = json.loads((out / "drift.json").read_text())
    assert len(data["frames"]) == 20 and data["events"][0]["kind"] == "bump"
    assert data["rows"]["oracle"] == pytest.approx(np.mean([r["psnr"]["oracle"]
                                                            for r in result["frames"]]))
    assert (out / "drift.png").stat().st_size > 10_000


def test_event_figures_from_records():
    """Recovery: the first frame from which the watch row stays within 0.5 dB of the oracle;
    worst vs geometry only: before the first update; detection: the watcher's first detection."""
    psnr = {"oracle": [30, 30, 30, 30, 30], "watch": [29, 28, 29.6, 29.7, 29.8],
            "geometry": [29.0, 28.2, 29, 29, 29], "none": [29, 25, 25, 25, 25]}
    play = {"rows": tuple(psnr), "duration_s": 5.0, "fps": 1.0,
            "records": [{"t": float(i), "psnr": {k: v[i] for k, v in psnr.items()},
                         "trusted": i != 1} for i in range(5)],
            "events": [{"t": 0.0, "kind": "set_light", "params": {"ambient": 0.2}}],
            "watch_events": [{"t": 1.0, "kind": "light", "action": "detect"},
                             {"t": 2.0, "kind": "light", "action": "mend", "pattern_frames": 3}],
            "updates": [{"t": 2.0}]}
    (fig,) = event_figures(play)
    assert fig["recovered_s"] == 2.0
    assert fig["detected_s"] == 1.0 and fig["detected_as"] == "light"
    assert fig["mended_s"] == 2.0 and fig["pattern_frames"] == 3
    assert fig["detections"] == 1 and fig["geometry_only_s"] == 1.0
    assert fig["worst_vs_geometry_db"] == pytest.approx(-0.2)
    assert fig["none_vs_oracle_db"] == pytest.approx(np.mean([-1, -5, -5, -5, -5]))


def test_event_figures_split_the_frames_before_and_after_the_look_that_saw_the_change():
    """A bump suspected by the look at 1 s and confirmed at 2 s: *seen* is the suspicion; the
    frames up to it went out before any look could see the change, those after it count in
    *after seen* (until the first update)."""
    psnr = {"oracle": [30] * 5, "watch": [28.5, 28.7, 28.8, 29.0, 29.9],
            "geometry": [29.0, 29.0, 28.9, 29.0, 29.0]}
    play = {"rows": tuple(psnr), "duration_s": 5.0, "fps": 1.0,
            "records": [{"t": float(i), "psnr": {k: v[i] for k, v in psnr.items()},
                         "trusted": i in (0, 1, 4)} for i in range(5)],
            "events": [{"t": 0.0, "kind": "bump", "params": {"camera_shift_px": 4.0}}],
            "watch_events": [{"t": 1.0, "kind": "geometry", "action": "suspect"},
                             {"t": 2.0, "kind": "geometry", "action": "detect"},
                             {"t": 2.0, "kind": "geometry", "action": "mend"}],
            "updates": [{"t": 3.0}]}
    (fig,) = event_figures(play)
    assert fig["seen_s"] == 1.0 and fig["detected_s"] == 2.0 and fig["mended_s"] == 3.0
    assert fig["worst_vs_geometry_db"] == pytest.approx(-0.5)     # the frame at 0 s
    assert fig["worst_after_seen_db"] == pytest.approx(-0.1)      # the frame at 2 s


def test_cli_drift_runs(tmp_path, capsys):
    """The command line: a short unchanged run writes the report (no events fall due)."""
    rc = main(["-q", "eval", "--drift", "--size", "160x120", "--fps", "10", "--duration", "0.5",
               "--false-alarm-s", "0", "--no-plot", "-o", str(tmp_path)])
    assert rc == 0
    assert (tmp_path / "drift.md").exists() and (tmp_path / "drift.json").exists()
    assert "eval --drift" in capsys.readouterr().out


def test_watch_row_mends_a_light_change(tmp_path):
    """The room light rises by 0.1 of full white: the watcher detects it, and the watch row is
    back within 0.5 dB of the oracle within 2 s, never more than 0.5 dB below geometry only
    before its mend."""
    from rtdefocus import sim

    ambient = sim.VirtualProCam("cubicle", projector_size=TINY["size"],
                                camera_size=(256, 192)).ambient
    result = run_drift_eval(tmp_path, **TINY, duration_s=2.5, false_alarm_s=0, plot=False,
                            events=[(0.5, "set_light", {"ambient": ambient + 0.1})])
    (ev,) = result["events"]
    assert ev["detected_s"] is not None and ev["detected_s"] <= 1.0
    assert ev["detected_as"] == "light"
    # MEASURED 2026-12-03 on this tiny set-up (10 fps, looks every 0.25 s): detected 1.0 s,
    # back within 0.5 dB 1.4 s after the change (deterministic); the bounds are the issue's
    # targets, 1.0x and 1.43x of those figures
    assert ev["recovered_s"] is not None and ev["recovered_s"] <= 2.0
    assert ev["worst_vs_geometry_db"] >= -0.5
    assert ev["pattern_frames"] == 0


def test_unchanged_show_with_a_cut_raises_no_alarm():
    """5 s of the unchanged set-up (still, pan, the cut at 4 s) through the watch row: no
    detection, no geometry suspicion, no update, every frame compensated."""
    from rtdefocus.study.eval_drift import run_false_alarm

    fa = run_false_alarm("cubicle", TINY["size"], TINY["fps"], 5.0)
    assert fa["frames"] == 50
    assert (fa["detections"], fa["suspicions"], fa["updates"], fa["geometry_frames"]) == (0, 0, 0, 0)


def test_separate_plays_start_each_event_on_a_fresh_setup():
    """Two events played separately: each play starts unchanged (none equals the oracle until its
    event), the second event does not inherit the first one's bump, and the figures sit at the
    events' places on the joined time axis."""
    from rtdefocus.study.eval_drift import play_separately

    play = play_separately("cubicle", TINY["size"], TINY["fps"],
                           [BUMP, (3.0, "refocus", {"scale": 1.15})],
                           ("none", "oracle"), lead_s=0.3, span_s=0.5)
    recs = play["records"]
    assert len(recs) == 16 and [r["frame"] for r in recs] == list(range(16))
    assert [f["t"] for f in play["figures"]] == pytest.approx([0.3, 1.1])
    for start in (0, 8):
        assert all(r["psnr"]["none"] == r["psnr"]["oracle"] for r in recs[start:start + 3])
    bumped, refocused = play["figures"]
    assert bumped["none_vs_oracle_db"] < -3.0          # a moved picture
    assert refocused["none_vs_oracle_db"] > -3.0       # a blur change only, no bump left over


#: MEASURED 2026-12-04 (`.venv/bin/python -m pytest tests/test_eval_drift.py -k knocked_camera`
#: prints nothing; the figures come from the same play run by hand, deterministic): after a
#: 4 px camera knock, the stale calibration's worst frame against the oracle -0.043 dB; the
#: watcher's mended model 0.053 camera px from the truth. Bounds 1.5x.
KNOCKED_CAMERA = {"none_vs_oracle_db": -0.0427, "model_left_px": 0.0527}


def test_a_knocked_camera_leaves_the_picture_on_the_wall():
    """A camera knocked moves its view, not the wall: the stale calibration's picture stays
    as good as the oracle's where the camera now sees it (a projector knock, above, moves it:
    -3 dB and worse); the watcher mends its model of the camera, and the show keeps its own
    calibration (the watch row is the none row once the mend is trusted)."""
    from rtdefocus.study.eval_drift import play_drift

    play = play_drift("cubicle", TINY["size"], TINY["fps"], 2.0,
                      [(0.5, "bump", {"camera_shift_px": 4.0})])
    after = [r for r in play["records"] if r["t"] >= 0.5]
    worst = min(r["psnr"]["none"] - r["psnr"]["oracle"] for r in after)
    assert worst > 1.5 * KNOCKED_CAMERA["none_vs_oracle_db"]
    assert after[0]["watch_geometry_px"] > 3.0           # the model's camera moved
    (update,) = play["updates"]
    mended = [r for r in after if r["t"] >= update["t"] and r["trusted"]]
    assert mended and all(r["psnr"]["watch"] == r["psnr"]["none"] for r in mended)
    assert max(r["watch_geometry_px"] for r in mended) < 1.5 * KNOCKED_CAMERA["model_left_px"]


@pytest.fixture(scope="module")
def full_and_sparse():
    """The same 2 s bumped play with every row, scored on every frame and on every third frame
    outside 0.5 s after the bump."""
    from rtdefocus.study.eval_drift import play_drift

    plays = [play_drift("cubicle", TINY["size"], TINY["fps"], 2.0, [BUMP], score_every=k,
                        full_rate_s=0.5) for k in (1, 3)]
    return plays


def test_sparse_scoring_gives_each_scored_frame_the_full_runs_figures(full_and_sparse):
    """Frames not scored still go through the camera's noise: every scored frame's PSNR, and
    every look and update of the watcher, is the one of the play that scores all."""
    from rtdefocus.study.drift_show import scored_frames

    full, sparse = full_and_sparse
    want = scored_frames(20, TINY["fps"], [0.5], every=3, full_s=0.5)
    assert [bool(r["psnr"]) for r in sparse["records"]] == want.tolist()
    assert not want.all() and want[5:10].all() and not want[10:].all()
    for a, b in zip(full["records"], sparse["records"], strict=True):
        if b["psnr"]:
            assert a["psnr"] == b["psnr"]
        assert (a["trusted"], a["watch_geometry_px"]) == (b["trusted"], b["watch_geometry_px"])
    assert full["watch_events"] == sparse["watch_events"] and full["updates"] == sparse["updates"]
    assert len(full["updates"]) >= 1            # the watcher mended the bump in both


def test_drift_show_views_skipped_or_evicted_are_the_same_views():
    """A view skipped and rendered later, or rendered again after more than RECENT_VIEWS other
    frames, equals the view rendered at once."""
    import copy

    from rtdefocus import sim
    from rtdefocus.study.drift_show import RECENT_VIEWS, DriftShow

    procam = sim.VirtualProCam("cubicle", projector_size=TINY["size"], camera_size=(256, 192))
    twin = copy.deepcopy(procam)
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 256, (120, 160, 3), dtype=np.uint8) for _ in range(RECENT_VIEWS + 2)]
    rect = (40, 30, 160, 120)
    at_once, later = DriftShow(procam, rect, 1, "numpy"), DriftShow(twin, rect, 1, "numpy")
    first = [at_once.view(f).copy() for f in frames]
    later.skip_view(frames[0])
    assert all(np.array_equal(later.view(f), v) for f, v in zip(frames[1:], first[1:], strict=True))
    assert np.array_equal(later.view(frames[0]), first[0])          # skipped, rendered now
    assert np.array_equal(at_once.view(frames[0]), first[0])        # evicted, rendered again
    assert not np.array_equal(first[0], procam.capture(frames[0]))  # the noise moved on


def test_held_mean_weights_each_scored_frame_by_the_frames_it_stands_for():
    """Scored frames 0, 3 and 4 of five: frame 0 stands for frames 0-2; all scored: the mean."""
    from rtdefocus.study.eval_drift import held_mean

    recs = [{"psnr": {} if v is None else {"a": v}} for v in (1.0, None, None, 4.0, 5.0)]
    assert held_mean(recs, lambda r: r["psnr"]["a"]) == pytest.approx((3 * 1.0 + 4.0 + 5.0) / 5)
    full = [{"psnr": {"a": v}} for v in (1.0, 2.0, 4.0)]
    assert held_mean(full, lambda r: r["psnr"]["a"]) == np.mean([1.0, 2.0, 4.0])
