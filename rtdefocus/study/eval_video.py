"""``rtdefocus eval --video``: the real-time path on a moving clip, frame by frame.

A clip built from the sample photographs (:func:`make_clip`: still, slow pan, fast pan, a cut
to another picture, a zoom, a fade) is shown through :meth:`rtdefocus.Compensator.compensate`
frame after frame, in order, in several *modes*:

``warm-k``     ``k`` iterations per frame, ``warm_start=True`` (what a player does);
``cold-k``     ``k`` iterations per frame, each frame from its own target (``warm_start=False``);
``offline``    :data:`OFFLINE_ITERATIONS` cold iterations per frame (file rendering, the ceiling);
``fps-N``      warm start, iterations per frame chosen from the measured time of the previous
               frames to hold N frames per second, as the player's
               :class:`~rtdefocus.stream.controls.IterationBudget` does (at least 1 iteration);
               every frame is compensated, however long it takes;
``window-N``   what the audience of the projector window sees: the clip played live at N fps
               through the real player (:class:`~rtdefocus.stream.Player`, realtime sink), which
               drops frames it cannot keep up with and shows some with geometry only to keep up
               (its ``catch_up``); a dropped frame's time shows the last frame shown, scored
               against the frame that should be there; a frame shown late (more than two
               periods after it arrived, after an overrun) is scored as shown and counted;
``geowindow-N`` the same window with compensation off (the player's geometry mode): what the
               audience would see instead, drops included (0 dB where it keeps up);
``window-N-sK`` the window on a device K times slower (``slowdown``: :class:`SlowedCompensator`
               makes every compensated frame cost K times what it costs here; geometry only
               costs the same, so ``geowindow-N`` is its comparison too).

Every frame's camera view (``procam.capture(frame)``) is scored against the sharp capture of
the same warp (``procam.capture(comp.warp(image), sharp=True)``) inside the display rectangle,
and so is geometry only (``comp.warp(image)``); the gain is the difference in PSNR. Per segment
the report gives the mean gain and its share of the offline mode's, the still segment's gain
after 1 s, and the frames to recover after the cut. The report (markdown, plot) is
:mod:`rtdefocus.study.eval_video_report`.

Captures and cold solves of identical frames are computed once (a still is many identical
frames); the warm and wall-clock modes are always run frame by frame.
"""

from __future__ import annotations

import hashlib
import logging
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .. import sim
from ..calib.file import Calibration
from ..compensate import Compensator
from ..errors import InputError
from ..sim import oracle_calibration
from ..stream.controls import IterationBudget
from .evalreport import write_report
from .machine import machine_info
from .scores import camera_view, psnr, rect_mask

log = logging.getLogger(__name__)

__all__ = ["SEGMENTS", "QUICK_SEGMENTS", "OFFLINE_ITERATIONS", "Segment", "SlowedCompensator",
           "make_clip", "run_video_eval", "segment_summary"]

#: Cold iterations per frame of the "offline" mode: the default budget of file rendering.
OFFLINE_ITERATIONS = 40
#: Frames per second the clip stands for ("still after 1 s" is frame ``CLIP_FPS`` of the still).
CLIP_FPS = 30


@dataclass(frozen=True)
class Segment:
    """One part of the clip: ``kind`` in still, pan, cut, zoom, fade; ``frames`` long;
    ``speed`` in px/frame at an 800 px wide clip (pans) or the scale per frame (zoom)."""

    name: str
    kind: str
    frames: int
    speed: float = 0.0


#: The clip of ``rtdefocus eval --video`` (78 frames, 40 of them distinct).
SEGMENTS = (Segment("still", "still", 30), Segment("slow pan", "pan", 10, 3.0),
            Segment("fast pan", "pan", 10, 14.0), Segment("cut", "cut", 10),
            Segment("zoom", "zoom", 10, 0.02), Segment("fade", "fade", 8))
#: ``--quick``: the same story in 30 frames.
QUICK_SEGMENTS = (Segment("still", "still", 8), Segment("slow pan", "pan", 4, 3.0),
                  Segment("fast pan", "pan", 4, 14.0), Segment("cut", "cut", 5),
                  Segment("zoom", "zoom", 5, 0.02), Segment("fade", "fade", 4))


# ------------------------------------------------------------------------------------ the clip
def _canvas(photo: np.ndarray, size: tuple[int, int], extra: float) -> np.ndarray:
    """``photo`` scaled (aspect kept) to cover ``size`` = (w, h) with ``extra`` width to spare."""
    w, h = size
    ph, pw = photo.shape[:2]
    s = max((w * (1.0 + extra)) / pw, h / ph)
    return cv2.resize(photo, (int(np.ceil(pw * s)), int(np.ceil(ph * s))),
                      interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC)


def _crop(canvas: np.ndarray, x: float, y: float, w: float, h: float,
          size: tuple[int, int]) -> np.ndarray:
    """The window (x, y, w, h) of ``canvas`` (sub-pixel) resampled to ``size``."""
    sx, sy = w / size[0], h / size[1]
    m = np.float32([[sx, 0, x + 0.5 * sx - 0.5], [0, sy, y + 0.5 * sy - 0.5]])
    return cv2.warpAffine(canvas, m, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REFLECT)


def make_clip(size: tuple[int, int] = (800, 600), segments=SEGMENTS,
              photos: dict[str, np.ndarray] | None = None) -> list[tuple[str, np.ndarray]]:
    """The moving clip: a list of ``(segment name, (h, w, 3) uint8 RGB frame)``.

    Still and pans show one photograph (the pans move right), the cut switches to a second one
    (held still), the zoom enlarges it by ``speed`` per frame about its centre and the fade
    dissolves into a third one. Pan speeds are in px/frame of an 800 px wide clip (scaled with
    ``size``).

    Parameters
    ----------
    size : (w, h) of the frames.
    segments : sequence of :class:`Segment`.
    photos : name -> RGB uint8; default :func:`rtdefocus.study.samples.photographs`.
    """
    if photos is None:
        from .samples import photographs
        photos = photographs()
    names = list(photos)
    if len(names) < 3:
        raise InputError(f"the clip needs 3 photographs; got {len(names)}")
    w, h = int(size[0]), int(size[1])
    scale = w / 800.0
    pan = sum(s.frames * s.speed * scale for s in segments if s.kind == "pan")
    first = _canvas(photos[names[0]], (w, h), pan / w + 0.02)
    second = _canvas(photos[names[2]], (w, h), 0.0)
    third = _canvas(photos[names[1]], (w, h), 0.0)
    y0 = (first.shape[0] - h) / 2
    x, zoom, picture = 0.0, 1.0, "first"
    fade_from = None
    out: list[tuple[str, np.ndarray]] = []
    for seg in segments:
        for i in range(seg.frames):
            if seg.kind == "pan":
                x += seg.speed * scale
            elif seg.kind == "cut":
                picture = "second"
            elif seg.kind == "zoom":
                picture = "second"
                zoom *= 1.0 + seg.speed
            if picture == "first":
                frame = _crop(first, x, y0, w, h, (w, h))
            else:
                cw, ch = second.shape[1] / zoom, second.shape[0] / zoom
                cw, ch = min(cw, ch * w / h), min(ch, cw * h / w)
                frame = _crop(second, (second.shape[1] - cw) / 2, (second.shape[0] - ch) / 2,
                              cw, ch, (w, h))
            if seg.kind == "fade":
                if fade_from is None:
                    fade_from = frame
                    ch3, cw3 = third.shape[:2]
                    cw, ch = min(cw3, ch3 * w / h), min(ch3, cw3 * h / w)
                    fade_to = _crop(third, (cw3 - cw) / 2, (ch3 - ch) / 2, cw, ch, (w, h))
                a = (i + 1) / seg.frames
                frame = cv2.addWeighted(fade_from, 1.0 - a, fade_to, a, 0.0)
            out.append((seg.name, np.ascontiguousarray(frame)))
    return out


# ------------------------------------------------------------------------------------ the run
def _key(a: np.ndarray) -> bytes:
    return hashlib.blake2b(np.ascontiguousarray(a).data, digest_size=16).digest()


class _Memo:
    """Captures and cold solves keyed on the bytes of their input (a still = one computation)."""

    def __init__(self):
        self.store: dict = {}

    def get(self, tag, array: np.ndarray, fn):
        k = (tag, _key(array))
        if k not in self.store:
            self.store[k] = fn()
        return self.store[k]


class SlowedCompensator:
    """A Compensator on a device ``factor`` times slower than this one, for measuring the live
    player at other device speeds: every :meth:`compensate` and :meth:`compensate_warped` (a
    live player's settle, on its worker thread) sleeps ``factor - 1`` times its own time after
    the real work, and reports its stage times scaled by ``factor`` in
    ``last_info``, as a slower device would; :meth:`warm_up` reports its scaled times. The
    geometry-only :meth:`warp` (the GL pass, not the compensation device) keeps its cost.
    Anything else is the wrapped Compensator's."""

    def __init__(self, comp, factor: float):
        if not factor >= 1.0:
            raise InputError(f"a slowdown is a factor >= 1 (1: this machine); got {factor}")
        self.comp, self.factor = comp, float(factor)
        self.last_info: dict = {}

    def __getattr__(self, name):
        return getattr(self.comp, name)

    def _scaled(self, info: dict | None) -> dict | None:
        if not info:
            return info
        info = dict(info)
        info["seconds"] = self._times(info.get("seconds"))
        if "moving" in info:                 # (a warm-up's timed frames)
            info["moving"] = [self._times(sec) for sec in info["moving"]]
        return info

    def _times(self, seconds: dict | None) -> dict:
        return {k: v * self.factor for k, v in (seconds or {}).items()}

    def _slowed(self, solve, frame, **kw):
        t0 = time.perf_counter()
        out = solve(frame, **kw)
        time.sleep((self.factor - 1.0) * (time.perf_counter() - t0))
        self.last_info = self._scaled(self.comp.last_info)
        return out

    def compensate(self, image, **kw):
        return self._slowed(self.comp.compensate, image, **kw)

    def compensate_warped(self, warped, **kw):
        return self._slowed(self.comp.compensate_warped, warped, **kw)

    def warm_up(self, iterations: int = 1, frames: int = 1):
        return self._scaled(self.comp.warm_up(iterations=iterations, frames=frames))


def play_window(calib, backend: str, clip, fps: float, geometry_only: bool = False,
                slowdown: float = 1.0):
    """The clip played live at ``fps`` through the real player into a realtime sink
    (``geometry_only``: in the player's geometry mode, compensation off; ``slowdown``: on a
    device that many times slower, :class:`SlowedCompensator`).

    Returns
    -------
    shown : dict
        Per frame index shown: the projector frame and its solver iterations (0: shown with
        geometry only to keep up).
    stats : rtdefocus.stream.LoopStats
    """
    from ..stream import ArraySource, Player
    from ..stream.sinks import Sink

    comp = Compensator(calib, backend=backend)     # (the live player warms it up itself)
    if slowdown != 1.0:
        comp = SlowedCompensator(comp, slowdown)

    class WindowSink(Sink):
        kind, realtime = "window (recorded)", True

        def __init__(self):
            self.shown: dict[int, tuple[np.ndarray, int]] = {}
            self.player = None
            self._geometry = 0
            self.start_only = 0     # compensated frames shown from their start (0 iterations)

        def write(self, frame: np.ndarray, index: int) -> None:
            g = self.player.stats.geometry_frames
            solved = g == self._geometry and self.player.controls.mode == "full"
            its = int(comp.last_info.get("iterations", 0)) if solved else 0
            self.start_only += solved and its == 0
            self._geometry = g
            self.shown[index] = (frame.copy(), its)

    sink = WindowSink()
    player = Player(comp, ArraySource([image for _, image in clip], fps=fps, live=True), sink)
    sink.player = player
    if geometry_only:
        player.controls.mode = "geometry"
    stats = player.run()
    stats.start_only = sink.start_only
    return sink.shown, stats


def mode_names(budgets, fps_list, offline: int, slowdown=(1.0,)) -> list[str]:
    names = [f"warm-{k}" for k in budgets] + [f"cold-{k}" for k in budgets]
    names += [f"fps-{f:g}" for f in fps_list]
    for f in fps_list:
        names += [f"window-{f:g}" if k == 1 else f"window-{f:g}-s{k:g}" for k in slowdown]
        names.append(f"geowindow-{f:g}")
    if offline:
        names.append("offline")
    return names


def run_video_eval(out_dir: str | Path = "eval_video_out", *, quick: bool = False,
                   projector_size: tuple[int, int] | None = None,
                   camera_size: tuple[int, int] | None = None,
                   clip_size: tuple[int, int] | None = None, segments=None,
                   budgets=(1, 2, 4, 8), fps=(24, 30, 60), slowdown=(1.0,),
                   offline: int = OFFLINE_ITERATIONS,
                   preset: str = "cubicle", calibration: str | Path | None = None,
                   backend: str = "auto", seed: int = 0, plot: bool = True,
                   step=None) -> dict:
    """Run the clip through every mode and write ``video.md``, ``video.json``, ``video.png``.

    Parameters
    ----------
    out_dir : output folder (created).
    quick : 400x300 projector, 640x480 camera, the 30-frame :data:`QUICK_SEGMENTS`, budgets
        (1, 2), 30 fps and a 10-iteration offline mode (explicit arguments still win).
    projector_size, camera_size, clip_size : (w, h); defaults 800x600, 1280x960, the projector's.
    segments : sequence of :class:`Segment` (default :data:`SEGMENTS`).
    budgets : fixed iterations per frame (each run warm and cold).
    fps : wall-clock budgets (frames per second on this machine).
    slowdown : device speeds of the window rows: each factor k >= 1 plays the window on a
        device k times slower than this machine (:class:`SlowedCompensator`).
    offline : cold iterations per frame of the ceiling (0: leave it out; shares need it).
    preset : simulator preset.
    calibration : a calibration file (``rtdefocus calibrate``) for the same preset and sizes;
        default the simulator's oracle calibration (true geometry and kernels).
    backend : Compensator backend.
    seed : simulator noise seed.
    plot : write ``video.png`` (needs matplotlib).
    step : callable(message), optional progress lines.

    Returns
    -------
    dict with ``modes``, ``segments``, ``frames`` (per-frame records), ``summary`` (per mode and
    segment), ``markdown``, ``files``, ``seconds``, ``machine``.
    """
    from .eval_video_report import plot_video, video_markdown

    say = step or (lambda msg: None)
    if quick:
        projector_size = projector_size or (400, 300)
        camera_size = camera_size or (640, 480)
        segments = segments or QUICK_SEGMENTS
        if budgets == (1, 2, 4, 8):
            budgets = (1, 2)
        if fps == (24, 30, 60):
            fps = (30,)
        if offline == OFFLINE_ITERATIONS:
            offline = 10
    projector_size = tuple(projector_size or (800, 600))
    camera_size = tuple(camera_size or (1280, 960))
    clip_size = tuple(clip_size or projector_size)
    segments = tuple(segments or SEGMENTS)
    budgets = tuple(int(b) for b in budgets)
    fps = tuple(float(f) for f in fps)
    slowdown = tuple(float(k) for k in slowdown)
    if any(b < 1 for b in budgets) or any(f <= 0 for f in fps) or offline < 0:
        raise InputError(f"budgets must be >= 1, fps > 0 and offline >= 0; got {budgets}, {fps}, "
                         f"{offline}")
    if not slowdown or any(not k >= 1 for k in slowdown):
        raise InputError(f"slowdown factors must be >= 1 (1: this machine); got {slowdown}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()

    procam = sim.VirtualProCam(preset, projector_size=projector_size, camera_size=camera_size,
                               seed=seed)
    if calibration is not None:
        calib = Calibration.load(calibration)
        if tuple(calib.projector_size) != projector_size:
            raise InputError(f"the calibration is for a {calib.projector_size} projector; the run "
                             f"uses {projector_size} (pass --size to match)")
        kernels = f"calibrated ({Path(calibration).name})"
    else:
        calib = oracle_calibration(procam)
        kernels = "oracle (the simulator's true kernels)"
    say(f"clip: {sum(s.frames for s in segments)} frames at {clip_size[0]}x{clip_size[1]}; "
        f"projector {projector_size[0]}x{projector_size[1]}, {preset}, {kernels}")
    clip = make_clip(clip_size, segments)

    modes = mode_names(budgets, fps, offline, slowdown)
    comps = {m: Compensator(calib, backend=backend) for m in modes
             if m.startswith(("warm-", "fps-"))}
    cold = Compensator(calib, backend=backend)
    geometry = cold
    budget_of = {f"fps-{f:g}": IterationBudget(f, maximum=cold.iterations) for f in fps}
    rect = calib.display_rect((clip_size[0], clip_size[1]))
    mask = rect_mask(rect, (camera_size[1], camera_size[0]))
    memo = _Memo()

    def capture(frame, sharp=False):
        return memo.get(("capture", sharp), frame, lambda: camera_view(procam, calib, frame, sharp=sharp))

    def cold_solve(image, iters):
        def solve():
            t0 = time.perf_counter()
            out = cold.compensate(image, iterations=iters, warm_start=False)
            return out, time.perf_counter() - t0
        return memo.get(("cold", iters), image, solve)

    # warm up every compensator (program builds, first-use costs) outside the timings
    for c in (cold, *comps.values()):
        c.compensate(clip[0][1], iterations=1, warm_start=False)
        c.reset()

    # The window first, on an idle machine: the other modes' work would be its load otherwise.
    windows, window_stats = {}, {}
    for m in modes:
        if not m.startswith(("window-", "geowindow-")):
            continue
        _, f, *k = m.split("-")
        k = float(k[0][1:]) if k else 1.0
        say(f"  the player at {f} fps, live (the window's view"
            + (", geometry only)" if m.startswith("geo") else
               f", a device {k:g}x slower)" if k != 1 else ")"))
        windows[m], st = play_window(calib, backend, clip, float(f),
                                     geometry_only=m.startswith("geo"), slowdown=k)
        window_stats[m] = {"shown": st.frames_out, "dropped": st.dropped,
                           "dropped_copies": st.dropped_copies,
                           "geometry_only": st.geometry_frames, "start_only": st.start_only,
                           "late": st.late, "fps": st.fps}
    on_screen = dict.fromkeys(windows)        # what each window shows at the current frame

    records = []
    for i, (seg, image) in enumerate(clip):
        warped = geometry.warp(image)
        reference = capture(warped, sharp=True)
        base = psnr(capture(warped), reference, mask)
        rec = {"frame": i, "segment": seg, "geometry_psnr": base, "psnr": {}, "gain": {},
               "iterations": {}, "ms": {}}
        for m in modes:
            if m.startswith("warm-"):
                iters = int(m.split("-")[1])
                t0 = time.perf_counter()
                frame = comps[m].compensate(image, iterations=iters, warm_start=True)
                secs = time.perf_counter() - t0
            elif m.startswith("fps-"):
                b, c = budget_of[m], comps[m]
                iters = b.iterations
                t0 = time.perf_counter()
                frame = c.compensate(image, iterations=iters, warm_start=True)
                secs = time.perf_counter() - t0
                b.update(secs, c.last_info["seconds"].get("solve", 0.0), iters)
            elif m.startswith(("window-", "geowindow-")):
                if i in windows[m]:
                    on_screen[m] = windows[m][i]
                # (nothing shown yet: scored as geometry only)
                frame, iters = on_screen[m] if on_screen[m] is not None else (warped, 0)
                secs = float("nan")
            else:
                iters = offline if m == "offline" else int(m.split("-")[1])
                frame, secs = cold_solve(image, iters)
            p = psnr(capture(frame), reference, mask)
            rec["psnr"][m] = p
            rec["gain"][m] = p - base
            rec["iterations"][m] = iters
            rec["ms"][m] = 1e3 * secs
        records.append(rec)
        if i % 10 == 0 or i == len(clip) - 1:
            say(f"  frame {i + 1}/{len(clip)} ({seg}): " + ", ".join(
                f"{m} {rec['gain'][m]:+.1f}" for m in modes) + " dB over geometry only")

    summary = segment_summary(records, segments, modes)
    result = {
        "settings": {"projector_size": projector_size, "camera_size": camera_size,
                     "clip_size": clip_size, "preset": preset, "kernels": kernels,
                     "budgets": budgets, "fps": fps, "slowdown": slowdown,
                     "offline_iterations": offline,
                     "backend": cold.backend, "solver": cold.solver_name, "seed": seed,
                     "segments": [s.__dict__ for s in segments], "clip_fps": CLIP_FPS},
        "machine": machine_info(),
        "modes": modes, "segments": [s.name for s in segments], "summary": summary,
        "window": window_stats,
        "frames": records,
    }
    result["seconds"] = time.perf_counter() - t_start
    return write_report(result, out, "video", video_markdown, plot_video if plot else None)


def segment_summary(records: list[dict], segments, modes) -> dict:
    """Per mode: mean gain per segment, its share of the offline gain, the still segment's gain
    after 1 s (frame :data:`CLIP_FPS`, or its last frame when shorter), the frames after the cut
    until the view is at least as good as a 1-iteration cold start (and stays so), and the
    median iterations and milliseconds per frame."""
    names = [s.name for s in segments]
    by_seg = {n: [r for r in records if r["segment"] == n] for n in names}
    out: dict = {}
    for m in modes:
        row = {"gain": {}, "share": {}}
        for n in names:
            rs = by_seg[n]
            row["gain"][n] = float(np.mean([r["gain"][m] for r in rs])) if rs else float("nan")
        if "offline" in modes:
            for n in names:
                ref = float(np.mean([r["gain"]["offline"] for r in by_seg[n]])) if by_seg[n] else 0
                row["share"][n] = row["gain"][n] / ref if ref > 0 else float("nan")
        still = next((s for s in segments if s.kind == "still"), None)
        if still is not None and by_seg[still.name]:
            rs = by_seg[still.name]
            k = min(CLIP_FPS, len(rs) - 1)
            row["still_after_1s"] = {"frame": k, "gain": rs[k]["gain"][m],
                                     "share": (rs[k]["gain"][m] / rs[k]["gain"]["offline"]
                                               if "offline" in modes and rs[k]["gain"]["offline"] > 0
                                               else float("nan"))}
        cut = next((s for s in segments if s.kind == "cut"), None)
        if cut is not None and by_seg[cut.name]:
            row["cut_recovery_frames"] = _recovery(by_seg[cut.name], m, modes)
        row["iterations_median"] = statistics.median(r["iterations"][m] for r in records)
        row["ms_median"] = statistics.median(r["ms"][m] for r in records)
        out[m] = row
    return out


def _recovery(rs: list[dict], m: str, modes) -> int | None:
    """Frames after the cut (0 = the cut frame itself) from which mode ``m``'s gain is at least
    the threshold (a 1-iteration cold start's gain, else 0 dB) on every remaining frame."""
    thresh = [max(0.0, r["gain"]["cold-1"]) if "cold-1" in modes else 0.0 for r in rs]
    ok = [r["gain"][m] >= t - 0.05 for r, t in zip(rs, thresh, strict=True)]
    for k in range(len(rs)):
        if all(ok[k:]):
            return k
    return None
