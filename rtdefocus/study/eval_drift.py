"""``rtdefocus eval --drift``: the show goes on while the set-up changes under it.

A moving clip (a cycle of a still, a slow pan, a cut to a second picture held still, a slow
zoom and a fade; the loop back is another cut) plays on a virtual set-up while a
:class:`~rtdefocus.sim.Timeline` changes it: the projector knocked (turned 0.3° and shifted
3 px), the camera knocked (4 px), the room light risen by 10 % of full white, every blur radius
grown by 15 %, one every :data:`SPACING_S` seconds. The play is frame-stepped on a simulated
show clock (frame ``i`` at ``t = i / fps``), so a run is deterministic and its times are show
times, not this machine's.

Rows, each frame shown to the same camera:

``none``      the original calibration throughout;
``watch``     the :class:`~rtdefocus.watch.Watcher` in synchronous mode on a simulated clock,
              each of its updates applied between two frames; while it does not trust its
              model, the frame goes out with geometry only, and during one of its pattern
              bursts the burst's frame instead (counted per event as pattern frames);
``oracle``    re-calibrated with the truth at each event (:func:`~rtdefocus.sim.oracle_calibration`);
``geometry``  geometry only with the geometry the watch row has at that frame (the floor the
              watch row must not fall below by more than 0.5 dB while a change is unmended).

Every compensated row runs the same fixed budget, :data:`ITERATIONS` warm-started iterations
per frame (``Compensator.compensate_warped(..., warm_start=True)``, as the fixed-budget rows of
``eval --video``), not the player's real-time budget, so that the figures do not depend on this
machine's load.

The picture stays where it was on the wall: every row shows the clip in the camera rectangle
``R0`` where the original calibration put it, in the original camera's pixels. A knocked
camera moves its view, not the wall: the oracle row shows the truth re-expressed in those
pixels, and the watcher hands the show the calibration it runs with (its own model follows the
moved camera). The reference is the sharp capture (no blur, no noise) of the oracle's warp at
the current truth, scored in the truth's ideal camera pixels inside the rectangle where the
camera now sees ``R0`` (``R0`` itself until the camera moves; camera-view PSNR, as ``eval
--video``). A stale geometry therefore shows as misplaced content, a stale blur or light model
as a worse compensation, and a knocked camera changes nothing the audience sees until the
watcher acts on it.

Scoring every frame renders up to five camera views per frame, the largest cost at 800×600;
with ``score_every`` a play scores every frame for ``full_rate_s`` after each event and every
``score_every``-th frame elsewhere, and still shows, solves and watches every frame: a scored
frame's figures are those of a play scoring all (:mod:`~rtdefocus.study.drift_show`).

A second run plays the unchanged set-up for ``false_alarm_s`` seconds of the same clip (its
cuts included) through the watch row alone and counts the watcher's detections. The report is
:mod:`rtdefocus.study.eval_drift_report`.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import time
from pathlib import Path

import numpy as np

from .. import sim
from ..errors import InputError
from ..sim import Timeline, oracle_calibration
from ..watch import Watcher
from ..watch import camera_view as watch_look
from ..watch.mend import mend_camera
from .drift_show import DriftShow, scored_frames
from .eval_video import Segment, make_clip
from .evalreport import write_report
from .machine import machine_info

log = logging.getLogger(__name__)

__all__ = ["ROWS", "ITERATIONS", "SPACING_S", "WITHIN_DB", "default_events", "drift_segments",
           "event_figures", "held_mean", "run_drift_eval", "run_false_alarm"]

#: The rows of the drift evaluation, in the report's order.
ROWS = ("none", "watch", "oracle", "geometry")
#: Warm-started solver iterations per frame of every compensated row.
ITERATIONS = 4
#: Seconds between two events of the default timeline (each has this long to recover).
SPACING_S = 8.0
#: Seconds after each event scored at full rate when a play scores sparsely (``score_every``).
FULL_RATE_S = 2.0
#: "Back within" margin against the oracle and "worse than geometry only" margin (dB).
WITHIN_DB = 0.5


def default_events(procam, start_s: float = 2.0, spacing_s: float = SPACING_S) -> list:
    """The timeline of the Done-when figures, for ``procam`` (its room light is the base).

    Returns ``[(t, kind, params), ...]``: a projector bump (0.3°, 3 px), a camera bump (4 px),
    the room light up by 0.1 of full white, every blur radius × 1.15.
    """
    return [(start_s, "bump", {"projector_yaw_deg": 0.3, "projector_shift_px": 3.0}),
            (start_s + spacing_s, "bump", {"camera_shift_px": 4.0}),
            (start_s + 2 * spacing_s, "set_light", {"ambient": float(procam.ambient) + 0.1}),
            (start_s + 3 * spacing_s, "refocus", {"scale": 1.15})]


def drift_segments(fps: float) -> tuple[Segment, ...]:
    """One 8 s cycle of the clip at ``fps``: still 1 s, a pan of 60 px/s (at 800 px wide) for
    3 s, a cut to a second picture held 2 s, a zoom of 15 %/s for 1 s, a 1 s fade."""
    n = lambda s: max(1, round(s * fps))    # noqa: E731
    return (Segment("still", "still", n(1)), Segment("pan", "pan", n(3), 60.0 / fps),
            Segment("cut", "cut", n(2)), Segment("zoom", "zoom", n(1), 0.15 / fps),
            Segment("fade", "fade", n(1)))


class _ShowClock:
    """The simulated show clock the watcher reads: the current frame's time."""

    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _new_watcher(calib, procam, clock, watcher_options):
    """The watch row's Watcher: synchronous, on the show clock (set to each frame's time, so
    any number of clock reads per frame agree)."""
    opts = {"period_s": 0.25, **(watcher_options or {})}
    return Watcher(calib, watch_look(procam), clock=clock, threaded=False, **opts)


def _as_dict(ev) -> dict:
    if dataclasses.is_dataclass(ev):
        return dataclasses.asdict(ev)
    if isinstance(ev, dict):
        return dict(ev)
    return dict(vars(ev))


def _make_procam(preset, size, camera_size, seed):
    size = tuple(int(v) for v in size)
    camera_size = tuple(camera_size or (round(size[0] * 1.6), round(size[1] * 1.6)))
    return sim.VirtualProCam(preset, projector_size=size, camera_size=camera_size, seed=seed)


def _check(fps, duration_s, rows):
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a positive number; got {fps!r}")
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"duration_s must be a positive number of seconds; got {duration_s!r}")
    bad = [r for r in rows if r not in ROWS]
    if bad or not rows:
        raise InputError(f"unknown drift row(s) {', '.join(map(str, bad)) or '(none given)'}; "
                         f"choose among {', '.join(ROWS)}")


def play_drift(preset: str = "cubicle", size=(800, 600), fps: float = 30.0,
               duration_s: float | None = None, events=None, rows=ROWS, *,
               camera_size=None, iterations: int = ITERATIONS, backend: str = "auto",
               seed: int = 0, watcher_options: dict | None = None, score_every: int = 1,
               full_rate_s: float = FULL_RATE_S, step=None, _start=None) -> dict:
    """The frame-stepped play behind :func:`run_drift_eval` (no files): per-frame PSNR of every
    row, the events applied, the watcher's own events and updates. Arguments as there; a frame
    not scored (``score_every``) has an empty ``psnr``."""
    say = step or (lambda msg: None)
    rows = tuple(rows)
    # _start: (fresh procam, clip) made by play_separately once for all its plays.
    procam, clip = _start or (_make_procam(preset, size, camera_size, seed), None)
    events = default_events(procam) if events is None else list(events)
    timeline = Timeline(events)
    if duration_s is None:
        last = timeline.events[-1].t if len(timeline) else 0.0
        duration_s = last + SPACING_S
    _check(fps, duration_s, rows)
    original = oracle_calibration(procam)
    wp, hp = procam.projector_size
    rect = original.display_rect((wp, hp))
    show = DriftShow(procam, rect, iterations, backend)
    pose = _camera_pose(procam)
    clip = clip or make_clip((wp, hp), drift_segments(fps))
    n = int(round(duration_s * fps))
    scored = scored_frames(n, fps, [e.t for e in timeline.events], score_every, full_rate_s)
    clock = _ShowClock()
    watcher = _new_watcher(original, procam, clock, watcher_options) if "watch" in rows else None
    # The picture's place on the wall is R0 in the original camera's pixels: the oracle row and
    # the reference show the truth there, and it is scored where the camera now sees it.
    oracle = oracle_here = watch_calib = original
    score_rect = rect
    applied, updates, records = [], [], []
    say(f"drift: {n} frames at {fps:g} fps ({duration_s:g} s of show), {wp}x{hp} {preset}, "
        f"{len(timeline)} event(s), rows {', '.join(rows)}")
    for i in range(n):
        t = i / fps
        clock.t = t
        for ev in timeline.advance(procam, t):
            applied.append({"t": t, "kind": ev.kind, "params": ev.params, "frame": i})
            show.changed()
            oracle = show.truth
            oracle_here, score_rect = _in_original_camera(oracle, original, procam, pose, (wp, hp))
            say(f"  {t:6.2f} s: {ev.kind} {ev.params}")
        if watcher is not None:
            upd = watcher.poll()
            if upd is not None:
                watch_calib = upd.calibration
                updates.append(_update_info(upd, t, i))
        show.start_frame()
        seg, image = clip[i % len(clip)]
        # a burst in progress: the watch row shows its pattern frame instead of the content
        pattern = watcher.pattern() if watcher is not None else None
        frames = {}
        for row in rows:
            if row == "none":
                frames[row] = show.compensate(original, image)
            elif row == "oracle":
                frames[row] = show.compensate(oracle_here, image)
            elif row == "geometry":
                frames[row] = show.warp(watch_calib, image)
            elif pattern is not None:
                frames[row] = pattern
            else:
                frames[row] = (show.compensate(watch_calib, image) if watcher.trusted
                               else show.warp(watch_calib, image))
        rec = {"frame": i, "t": t, "segment": seg, "psnr": {}}
        if scored[i]:
            reference = show.view(show.warp(oracle_here, image), sharp=True)
            rec["psnr"] = {row: show.score(frames[row], reference, score_rect) for row in rows}
        else:
            for row in rows:
                show.skip_view(frames[row])
        if watcher is not None:
            rec["trusted"] = bool(watcher.trusted)
            rec["pattern"] = pattern is not None
            rec["watch_geometry_px"] = geometry_error_px(watcher.calib, oracle)
            watcher.offer(frames["watch"], image)
        records.append(rec)
        show.keep_only((original, oracle_here, watch_calib))
        if i % max(1, int(fps)) == 0 and rec["psnr"]:
            say(f"  {t:6.2f} s: " + ", ".join(f"{r} {rec['psnr'][r]:.2f}" for r in rows) + " dB")
    return {"preset": preset, "size": (wp, hp), "camera_size": tuple(procam.camera_size),
            "fps": float(fps), "duration_s": float(duration_s), "rows": rows, "rect": rect,
            "events": applied, "scheduled": [(e.t, e.kind, e.params) for e in timeline.events],
            "updates": updates, "records": records,
            "watch_events": [_as_dict(e) for e in (watcher.events if watcher else ())],
            "backend": next(iter(show.comps.values()))[1].backend if show.comps else backend}


def _camera_pose(procam) -> tuple[np.ndarray, np.ndarray]:
    """The virtual camera's intrinsics and rotation (a knock turns it about its centre)."""
    return np.array(procam.K_cam, np.float64), np.array(procam.R_cam, np.float64)


def _in_original_camera(truth, original, procam, pose, size):
    """The truth re-expressed in the original camera's pixels (what the picture's place on the
    wall, R0 there, needs: the camera knocked moves its view, not the wall) and the camera
    rectangle where that place is now seen (scored there). ``pose``: the camera's at the start."""
    K, R0 = pose
    G = K @ np.asarray(procam.R_cam, np.float64) @ R0.T @ np.linalg.inv(K)
    G /= G[2, 2]
    if np.allclose(G, np.eye(3), atol=1e-9):
        return truth, original.display_rect(size)
    return mend_camera(truth, np.linalg.inv(G)), mend_camera(original, G).display_rect(size)


def geometry_error_px(calib, truth) -> float:
    """Largest distance (camera px) between where ``calib`` and ``truth`` put projector
    points, over a 9x9 grid inset by 5 % of the frame (what a geometry mend left over)."""
    wp, hp = truth.projector_size
    xs, ys = np.meshgrid(np.linspace(0.05 * wp, 0.95 * wp, 9), np.linspace(0.05 * hp, 0.95 * hp, 9))
    d = calib.cam_from_proj(xs, ys) - truth.cam_from_proj(xs, ys)
    return float(np.max(np.hypot(d[:, 0], d[:, 1])))


def _update_info(upd, t: float, frame: int) -> dict:
    """An update applied before ``frame`` (show time ``t``): what it says of itself (the time
    of the look it came from as ``look_t``), minus its calibration."""
    info = {k: v for k, v in vars(upd).items() if k != "calibration"
            and isinstance(v, (str, int, float, bool, list, tuple, type(None)))}
    if "t" in info:
        info["look_t"] = info.pop("t")
    return {**info, "t": t, "frame": frame}


def play_separately(preset: str = "cubicle", size=(800, 600), fps: float = 30.0, events=None,
                    rows=ROWS, *, lead_s: float = 2.0, span_s: float = SPACING_S, **options) -> dict:
    """Each event on a fresh set-up of its own: ``lead_s`` seconds of the unchanged show, the
    event, then ``span_s`` seconds to recover (:func:`play_drift` per event). The plays are
    laid end to end on one time axis (play ``k`` starts at ``k * (lead_s + span_s)``), so the
    result reads as :func:`play_drift`'s; ``figures`` holds each event's own
    :func:`event_figures`, undisturbed by what an earlier event left unmended."""
    # One fresh set-up and clip for every play: a copy of a set-up never captured with is a
    # fresh one (its noise starts where a new one's does).
    fresh = _make_procam(preset, size, options.get("camera_size"), options.get("seed", 0))
    clip = make_clip(fresh.projector_size, drift_segments(fps))
    if events is None:
        events = default_events(fresh)
    scheduled = Timeline(events).events
    span = lead_s + span_s
    out: dict = {"records": [], "events": [], "updates": [], "watch_events": [], "figures": [],
                 "scheduled": []}
    for k, ev in enumerate(scheduled):
        p = play_drift(preset, size, fps, span, [(lead_s, ev.kind, ev.params)], rows, **options,
                       _start=(copy.deepcopy(fresh), clip))
        off, first = k * span, len(out["records"])

        def moved(items, off=off):
            return [{**d, "t": d["t"] + off} for d in items]

        out["records"] += [{**r, "t": r["t"] + off, "frame": r["frame"] + first}
                           for r in p["records"]]
        for key in ("events", "updates", "watch_events"):
            out[key] += moved(p[key])
        out["figures"] += moved(event_figures(p))
        out["scheduled"] += [(t + off, kind, params) for t, kind, params in p["scheduled"]]
        out.update({key: p[key] for key in ("preset", "size", "camera_size", "fps", "rows",
                                             "rect", "backend")})
    out["duration_s"] = len(scheduled) * span
    return out


# ---------------------------------------------------------------------------- figures
def _detections(watch_events) -> list[dict]:
    """The watcher's detections (events whose kind or action says a change was found)."""
    out = []
    for e in watch_events:
        what = str(e.get("action", e.get("what", e.get("type", "")))).lower()
        if what.startswith("detect") or (not what and "mend" not in str(e.get("kind", ""))):
            out.append(e)
    return out


def _t(e) -> float:
    return float(e.get("t", e.get("time", e.get("t_show", float("nan")))))


def event_figures(play: dict, within_db: float = WITHIN_DB) -> list[dict]:
    """Per applied event: detection delay (s), recovery time (s: from the event to the first
    frame from which the watch row stays within ``within_db`` of the oracle until the next
    event), pattern frames shown, the worst frame of the watch row against geometry only
    between the event and its mend (the first update after it) and between the first look that
    saw it (``seen_s``: a geometry suspicion or a detection) and its mend, the none and watch
    rows' mean PSNR against the oracle's over the event's span, and the watch row's geometry error
    at the span's end (:func:`geometry_error_px`), the detections in the span and the seconds
    of it the watch row showed with geometry only."""
    recs, evs = play["records"], play["events"]
    rows = play["rows"]
    t_end = play["duration_s"]
    out = []
    for k, ev in enumerate(evs):
        t0 = ev["t"]
        t1 = evs[k + 1]["t"] if k + 1 < len(evs) else t_end
        span = [r for r in recs if t0 <= r["t"] < t1]
        fig = {"t": t0, "kind": ev["kind"], "params": ev["params"], "label": event_label(ev)}
        scored = [r for r in span if r["psnr"]]
        if "oracle" in rows:
            for row in ("none", "watch"):
                if row in rows:
                    fig[f"{row}_vs_oracle_db"] = held_mean(
                        span, lambda r, row=row: r["psnr"][row] - r["psnr"]["oracle"])
        if "watch" in rows:
            wev = [e for e in play["watch_events"] if t0 <= _t(e) < t1]
            det = [e for e in _detections(wev)]
            fig["detected_s"] = _t(det[0]) - t0 if det else None
            fig["detected_as"] = str(det[0].get("kind")) if det else None
            fig["detections"] = len(det)
            # the first look that put the show on geometry only (a geometry suspicion or a
            # detection): the frames up to it went out before any look could see the change
            seen = [e for e in wev if str(e.get("action")) in ("suspect", "detect")]
            fig["seen_s"] = _t(seen[0]) - t0 if seen else None
            fig["geometry_only_s"] = sum(not r.get("trusted", True) for r in span) / play["fps"]
            # the frames the watch row showed as patterns (else what the watcher's events say)
            fig["pattern_frames"] = (sum(bool(r["pattern"]) for r in span) if span and "pattern"
                                     in span[0] else int(sum(int(e.get("pattern_frames", 0) or 0)
                                                             for e in wev)))
            ups = [u for u in play["updates"] if t0 <= u["t"] < t1]
            fig["mended_s"] = ups[0]["t"] - t0 if ups else None
            fig["updates"] = len(ups)
            if span and "watch_geometry_px" in span[-1]:
                fig["geometry_error_px"] = span[-1]["watch_geometry_px"]
            if "oracle" in rows:
                ok = [r["psnr"]["watch"] >= r["psnr"]["oracle"] - within_db for r in scored]
                first = next((j for j in range(len(scored)) if all(ok[j:])), None)
                fig["recovered_s"] = scored[first]["t"] - t0 if first is not None else None
            if "geometry" in rows:
                mend = t0 + fig["mended_s"] if ups else t1
                # (a burst's pattern frames are no picture: counted above, not compared)
                before = [r["psnr"]["watch"] - r["psnr"]["geometry"] for r in scored
                          if r["t"] < mend and not r.get("pattern")]
                fig["worst_vs_geometry_db"] = float(min(before)) if before else None
                after = [r["psnr"]["watch"] - r["psnr"]["geometry"] for r in scored
                         if seen and t0 + fig["seen_s"] < r["t"] < mend and not r.get("pattern")]
                fig["worst_after_seen_db"] = float(min(after)) if after else None
        out.append(fig)
    return out


def held_mean(records, value) -> float:
    """Mean of ``value(record)`` over the scored records (non-empty ``psnr``), each standing for
    the frames up to the next scored one (the last to the end of ``records``): the mean over
    every frame when every frame is scored, its sample-and-hold estimate when not."""
    idx = [k for k, r in enumerate(records) if r["psnr"]]
    if not idx:
        return float("nan")
    vals = [value(records[k]) for k in idx]
    weights = np.diff(idx + [len(records)])
    if np.all(weights == 1):
        return float(np.mean(vals))
    return float(np.average(vals, weights=weights))


def event_label(ev) -> str:
    p = ev["params"]
    if ev["kind"] == "bump":
        parts = []
        if p.get("projector_yaw_deg"):
            parts.append(f"projector {p['projector_yaw_deg']:g}°")
        if np.any(np.asarray(p.get("projector_shift_px", 0)) != 0):
            parts.append(f"projector {_px(p['projector_shift_px'])} px")
        if np.any(np.asarray(p.get("camera_shift_px", 0)) != 0):
            parts.append(f"camera {_px(p['camera_shift_px'])} px")
        return "bump: " + ", ".join(parts or ["none"])
    if ev["kind"] == "set_light":
        return "light: " + ", ".join(f"{k} {v:.3g}" for k, v in p.items() if v is not None)
    if ev["kind"] == "refocus":
        return f"focus: radii x{p.get('scale', 1):g}"
    return ev["kind"]


def _px(v) -> str:
    v = np.atleast_1d(np.asarray(v, dtype=float))
    return f"{v[0]:g}" if v.size == 1 or v[1] == 0 else f"({v[0]:g}, {v[1]:g})"


# ---------------------------------------------------------------------------- false alarms
def run_false_alarm(preset: str = "cubicle", size=(400, 300), fps: float = 30.0,
                    seconds: float = 120.0, *, camera_size=None, iterations: int = ITERATIONS,
                    backend: str = "auto", seed: int = 0, watcher_options: dict | None = None,
                    step=None) -> dict:
    """An unchanged set-up playing the clip (pans, stills, its cuts) for ``seconds`` of show
    through the watch row alone; returns the watcher's detections and updates (each a false
    alarm), its geometry suspicions (each looked at again, geometry only until then), its
    events and how many frames went out with geometry only."""
    say = step or (lambda msg: None)
    _check(fps, seconds, ("watch",))
    procam = _make_procam(preset, size, camera_size, seed)
    calib = oracle_calibration(procam)
    wp, hp = procam.projector_size
    rect = calib.display_rect((wp, hp))
    show = DriftShow(procam, rect, iterations, backend)
    clip = make_clip((wp, hp), drift_segments(fps))
    clock = _ShowClock()
    watcher = _new_watcher(calib, procam, clock, watcher_options)
    n = int(round(seconds * fps))
    updates, geometry_frames, pattern_frames = [], 0, 0
    say(f"false alarms: {n} frames at {fps:g} fps ({seconds:g} s), {wp}x{hp} {preset}, unchanged")
    for i in range(n):
        clock.t = i / fps
        upd = watcher.poll()
        if upd is not None:
            calib = upd.calibration
            updates.append(_update_info(upd, clock.t, i))
        show.start_frame()
        image = clip[i % len(clip)][1]
        pattern = watcher.pattern()
        if pattern is not None:
            frame, pattern_frames = pattern, pattern_frames + 1
        elif watcher.trusted:
            frame = show.compensate(calib, image)
        else:
            frame, geometry_frames = show.warp(calib, image), geometry_frames + 1
        watcher.offer(frame, image)
        show.keep_only((calib,))
        if i and i % int(10 * fps) == 0:
            say(f"  {clock.t:6.1f} s: {len(_detections([_as_dict(e) for e in watcher.events]))} "
                "detection(s)")
    events = [_as_dict(e) for e in watcher.events]
    return {"preset": preset, "size": (wp, hp), "fps": float(fps), "seconds": float(seconds),
            "frames": n, "detections": len(_detections(events)), "updates": len(updates),
            "retracted": int(watcher.false_alarms),
            "suspicions": sum(e["action"] == "suspect" for e in events),
            "geometry_frames": geometry_frames, "pattern_frames": pattern_frames,
            "watch_events": events,
            "update_list": updates}


# ---------------------------------------------------------------------------- the run
def run_drift_eval(out_dir: str | Path = "drift_out", *, preset: str = "cubicle",
                   size=(800, 600), fps: float = 30.0, duration_s: float | None = None,
                   events=None, rows=ROWS, camera_size=None, iterations: int = ITERATIONS,
                   separate: bool = False, false_alarm_s: float = 120.0,
                   false_alarm_size=None, backend: str = "auto", seed: int = 0,
                   watcher_options: dict | None = None, score_every: int = 1,
                   full_rate_s: float = FULL_RATE_S, plot: bool = True, step=None) -> dict:
    """Play the clip through a timeline of set-up changes and write ``drift.md``,
    ``drift.json`` and ``drift.png``.

    Parameters
    ----------
    out_dir : output folder (created).
    preset : simulator preset (``cubicle``, ``webcam_cubicle``, ...).
    size : (w, h) of the projector and the clip; the camera gets 1.6x unless ``camera_size``.
    fps : frames per second of the show (simulated clock).
    duration_s : seconds of show; default the last event's time + :data:`SPACING_S`.
    events : ``[(t_seconds, kind, params), ...]`` as :class:`~rtdefocus.sim.Timeline` takes;
        default :func:`default_events` (the four changes 8 s apart from 2 s).
    rows : among :data:`ROWS`.
    iterations : warm-started solver iterations per frame of the compensated rows.
    separate : each event on a fresh set-up of its own, 2 s after the start, with
        :data:`SPACING_S` to recover (:func:`play_separately`; ``duration_s`` does not apply)
        instead of one set-up changing event after event.
    false_alarm_s : seconds of the unchanged run (0: leave it out; it needs the watch row).
    false_alarm_size : (w, h) of that run (default ``size``).
    backend : Compensator backend.
    seed : simulator noise seed.
    watcher_options : extra keyword arguments of the Watcher.
    score_every : score every frame from each event until ``full_rate_s`` after it, and every
        ``score_every``-th frame elsewhere (1: every frame). A frame not scored is still shown,
        solved and watched, and every figure of a scored frame is the one of a play scoring
        all (:mod:`~rtdefocus.study.drift_show`); means and "stays within" read the scored
        frames only.
    full_rate_s : seconds after each event scored at full rate.
    plot : write ``drift.png`` (needs matplotlib, ``rtdefocus[demo]``).
    step : callable(message), optional progress lines.

    Returns
    -------
    dict with ``settings``, ``events`` (per event figures, :func:`event_figures`), ``rows``
    (mean PSNR per row), ``false_alarms``, ``frames`` (per-frame records), ``markdown``,
    ``files``, ``seconds``, ``machine``.
    """
    from .eval_drift_report import drift_markdown, plot_drift

    t_start = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if int(score_every) < 1 or not full_rate_s >= 0:
        raise InputError(f"score_every must be >= 1 and full_rate_s >= 0; got {score_every!r}, "
                         f"{full_rate_s!r}")
    options = {"camera_size": camera_size, "iterations": iterations, "backend": backend,
               "seed": seed, "watcher_options": watcher_options, "step": step,
               "score_every": int(score_every), "full_rate_s": float(full_rate_s)}
    if separate:
        play = play_separately(preset, size, fps, events, rows, **options)
    else:
        play = play_drift(preset, size, fps, duration_s, events, rows, **options)
    recs = play["records"]
    false_alarms = None
    if false_alarm_s and "watch" in play["rows"]:
        false_alarms = run_false_alarm(preset, false_alarm_size or size, fps, false_alarm_s,
                                       iterations=iterations, backend=backend, seed=seed,
                                       watcher_options=watcher_options, step=step)
    result = {
        "settings": {"preset": preset, "size": play["size"], "camera_size": play["camera_size"],
                     "fps": play["fps"], "duration_s": play["duration_s"], "rows": play["rows"],
                     "iterations": iterations, "backend": play["backend"], "seed": seed,
                     "display_rect": play["rect"], "scheduled": play["scheduled"],
                     "within_db": WITHIN_DB, "separate": bool(separate),
                     "score_every": int(score_every), "full_rate_s": float(full_rate_s)},
        "machine": machine_info(),
        "rows": {row: held_mean(recs, lambda r, row=row: r["psnr"][row]) for row in play["rows"]},
        "events": play["figures"] if separate else event_figures(play),
        "updates": play["updates"],
        "watch_events": play["watch_events"],
        "false_alarms": ({k: v for k, v in false_alarms.items() if k != "watch_events"}
                         if false_alarms else None),
        "frames": recs,
    }
    result["seconds"] = time.perf_counter() - t_start
    return write_report(result, out, "drift", drift_markdown, plot_drift if plot else None)
