"""The watcher: during a show the camera looks at the wall a few times a second, the
calibration's forward model predicts that view from the frame that was shown, and the
difference says what changed (DESIGN.md §9, "The watcher").

Each look gives a :class:`~rtdefocus.watch.residual.ResidualReport`. The watcher attributes a
difference to **geometry**, then **light**, then **focus** (in that order: a bump also changes
the light fit and the band-pass energy, so a later kind is not judged while an earlier one is
changing), with hysteresis per kind: a kind is *detected* when ``confirm`` successive looks
exceed its high threshold, and *cleared* only by a look below its low threshold. Light and
focus are judged against their levels while the model was right (a calibration is rarely
exact in them; focus on content like the look's). A look compares the camera frame with the
very frame the projector showed when it was taken (the Player hands that frame over), so
moving content and cuts are no change; a look judges only what its frame can show (a plain
frame tells nothing of light or focus, see :class:`Thresholds`).

On a detection the model is no longer trusted (:attr:`Watcher.trusted` False: the Player
shows geometry only, never worse than no compensation) and a mend is estimated from the
content, with no pattern on the screen. A geometry change is distrusted from the first look
over its threshold, before the next confirms it (a stale geometry compensated is worse than
geometry only; a look that does not confirm it puts the compensation back):

* light: albedo and ambient re-scaled by the report's gain and added room light;
* geometry: a camera move is one camera-side correction for all planes, a projector move one
  per plane with the folds kept consistent (:mod:`~rtdefocus.watch.mend`); which of the two it
  was is decided by which single homography (in camera or in projector pixels) explains the
  planes' content warps better, and the mend is then refined to a few hundredths of a pixel by
  direct alignment of the content (:mod:`~rtdefocus.watch.refit`). A camera move changes
  nothing on the wall: it mends the model the looks are judged with (:attr:`Watcher.calib`),
  and the show keeps its calibration, its picture where it was;
* focus: every kernel's radius rescaled by the factor that brings the band-pass ratio back to
  its level while the model was right (:func:`~rtdefocus.watch.mend.rescale_radii`).

What the content cannot mend, a short burst of calibration patterns does
(:mod:`~rtdefocus.watch.burst`, :class:`BurstOptions`): :meth:`Watcher.pattern` hands the Player
the frames to show instead of the content, the watcher captures them through its look and
re-measures: a dot burst for a focus change the band ratio cannot size (or for every one,
``BurstOptions(focus="always")``), a geometry burst for a move the content mends did not clear,
a mend the content cannot estimate, a lost view, or content too plain to align for too long
while the model is untrusted. Each burst is logged as a warning, its pattern frames are
counted in its events, and its mend is handed over whole, as the others.

The mend becomes a new :class:`~rtdefocus.calib.file.Calibration` (the one in use is never
modified), handed to the Player by :meth:`Watcher.poll` as a :class:`WatchUpdate` that it
applies between two frames. The next look checks it: below the low threshold the kind is
cleared; otherwise what is left is mended the same way (at most ``max_mends`` times; then the
watcher gives up, says so, and frames stay geometry only: the set-up needs a calibration).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..calib.file import Calibration
from ..errors import InputError, RtDefocusError
from .burst import BURSTS, Burst, BurstOptions, BurstRunner
from .focus import fit_band_scale
from .levels import BandLevels, band_level, content_informs
from .mend import camera_correction, mend_camera, mend_light, rescale_radii
from .refit import mend_geometry
from .residual import ResidualReport, residual_report

log = logging.getLogger(__name__)

#: Frames kept while a look is in flight (a look takes the camera's latency plus a report).
_HISTORY = 64

#: The kinds of change the watcher tells apart, in the order it attributes a difference.
KINDS = ("geometry", "light", "focus")


@dataclass
class WatchEvent:
    """One thing the watcher did.

    Attributes
    ----------
    t : show time (s, the watcher's clock) of the look that led to it.
    kind : "geometry" | "light" | "focus" | "lost" (the camera no longer sees the frame).
    action : "suspect" (a look saw the geometry move: geometry only until the next look
        says), "dismiss" (the next look did not see it: compensated again), "detect" (a
        change confirmed: the model is no longer trusted), "burst" (pattern
        frames to be shown instead of the content, to re-measure it), "mend" (a new
        calibration handed to the Player), "cleared" (a later look found the model right for
        this kind again), "retract" (a confirmed change whose mend came out too small to
        apply: a false alarm), "give up" (the mends did not converge: a re-calibration is
        needed; frames stay geometry only).
    detail : what was measured or done (JSON-friendly numbers).
    pattern_frames : pattern frames shown for it (0: mended from the content alone).
    """

    t: float
    kind: str
    action: str
    detail: dict = field(default_factory=dict)
    pattern_frames: int = 0


@dataclass
class WatchUpdate:
    """What :meth:`Watcher.poll` hands the Player to apply between two frames.

    Attributes
    ----------
    calibration : the calibration the show runs with from now: a new object, or the one it
        runs with already where only the camera moved (the picture stays where it was on the
        wall; :attr:`Watcher.calib`, the model seen by the moved camera, differs from it by
        that move).
    kinds : what changed, e.g. ("geometry",).
    trusted : whether the model was trusted when the update was made (a fresh mend is not
        yet: the next look checks it).
    t : show time of the look the mend came from.
    """

    calibration: Calibration
    kinds: tuple[str, ...]
    trusted: bool
    t: float


@dataclass
class Thresholds:
    """High (detect) and low (clear) thresholds of each kind, with hysteresis between them.

    geometry_px : largest per-plane content shift (projector px), counted on planes whose
        phase-correlation peak is at least ``min_confidence``.
    gain : |gain / its level while trusted − 1| (exposure or albedo change).
    ambient : |added room light − its level while trusted| (mean camera linear light).
    focus : |band ratio / its value while trusted − 1| (the ratio divided by the gain;
        MEASURED in :mod:`~rtdefocus.watch.levels`).
    min_confidence, min_contrast, min_band : what a look must offer to say anything of a kind:
        geometry, a plane's phase-correlation peak (it falls with the frame's size: about
        0.08 at 240×180, 0.04 at 800×600 on smooth texture, under 0.01 on a plain frame);
        light, the shown frame's standard deviation in linear light (a plain frame cannot tell
        gain from added light); focus, its band-pass
        (difference of Gaussians, σ 1 and 2 px) RMS in linear light (below it the camera's
        noise sets the ratio). A kind a look says nothing of is neither suspected nor cleared.
    band_match : focus is judged against the band level of looks of like content only (band
        RMS within this factor, MEASURED in :mod:`~rtdefocus.watch.levels`).
    """

    geometry_px: tuple[float, float] = (0.6, 0.3)
    gain: tuple[float, float] = (0.04, 0.02)
    ambient: tuple[float, float] = (0.015, 0.0075)
    focus: tuple[float, float] = (0.012, 0.006)
    min_confidence: float = 0.02
    min_contrast: float = 0.03
    min_band: float = 0.008
    band_match: float = 1.10


class Watcher:
    """Watches the show through the camera and mends the calibration it runs with.

    Parameters
    ----------
    calib : the calibration the show starts with (never modified).
    look : ``look(shown_projector_frame) -> (Hc, Wc, 3) uint8`` the camera's view of the frame
        the projector is showing (:func:`camera_view`). A look with a ``looked_at`` attribute
        (:class:`LiveView`: the time, by ``clock``, its picture was on the wall) is paired,
        when threaded, with the frame offered last by then.
    period_s : seconds between looks, by ``clock``.
    recheck_s : seconds to the next look while a change is suspected (a look over a high
        threshold waits for ``confirm``) or being mended (None: ``period_s``). A long
        ``period_s`` with a short ``recheck_s`` keeps the watcher's cost low and still detects
        within about ``period_s + (confirm - 1) · recheck_s`` plus the looks' own time.
    clock : seconds, monotonic (a simulated clock makes an evaluation deterministic).
    threaded : look, report and decide on a background thread (frames are not delayed; a
        look due while the last is still being worked on is skipped); False does it all in
        :meth:`offer` (deterministic).
    thresholds : :class:`Thresholds`.
    confirm : successive looks over a high threshold that make a detection.
    band_looks : looks of a trusted, unchanging set-up that set the levels light and focus
        are judged against (until then neither is detected; a focus mend starts the focus
        level again, and a focus detection retracted starts it from its own looks).
    max_mends : mends of one change before the watcher gives up (the change needs a
        re-calibration; the model stays untrusted, frames geometry only).
    report : the residual report function (``residual_report``'s signature).
    bursts : :class:`BurstOptions` (None: mend from the content alone, never a pattern).

    Attributes
    ----------
    calib : the latest calibration (the one the last update carries).
    events : list of :class:`WatchEvent`, in time order.
    false_alarms : confirmed detections the watcher retracted because the change, once
        estimated, was below the low threshold (nothing applied). An evaluation that knows
        when the set-up changed counts its own: detections with no change since the last one.
    looks : looks made; last_report : the last look's report.
    untrusted_frames : frames offered while the model was not trusted (shown geometry only;
        a burst's pattern frames are counted in its events).
    """

    def __init__(self, calib: Calibration, look: Callable[[np.ndarray], np.ndarray], *,
                 period_s: float = 0.25, clock: Callable[[], float] = time.perf_counter,
                 threaded: bool = True, thresholds: Thresholds | None = None, confirm: int = 2,
                 max_mends: int = 4, band_looks: int = 4,
                 report: Callable[..., ResidualReport] = residual_report,
                 recheck_s: float | None = None, bursts: BurstOptions | None = BURSTS):
        if not (math.isfinite(period_s) and period_s >= 0):
            raise InputError(f"period_s must be a number of seconds >= 0; got {period_s!r}")
        if recheck_s is not None and not (math.isfinite(recheck_s) and recheck_s >= 0):
            raise InputError(f"recheck_s must be a number of seconds >= 0 or None; got {recheck_s!r}")
        if confirm < 1:
            raise InputError(f"confirm must be >= 1; got {confirm!r}")
        self.calib = calib
        # A knocked camera moves its view, not the wall: the calibration the show runs with
        # (_show_calib) keeps its picture where it was, in the original camera's pixels, and the
        # model the looks are judged with (calib) is that one seen by the moved camera.
        self._show_calib, self._camera_moved = calib, np.eye(3)
        self.look = look
        self.period_s = float(period_s)
        self.recheck_s = self.period_s if recheck_s is None else float(recheck_s)
        self.clock = clock
        self.threaded = bool(threaded)
        self.th = thresholds or Thresholds()
        self.confirm = int(confirm)
        self.max_mends = int(max_mends)
        self.report = report
        self.band_looks = int(band_looks)
        self.events: list[WatchEvent] = []
        self.false_alarms = 0
        self.looks = 0
        self.untrusted_frames = 0
        self.last_report: ResidualReport | None = None
        self._trusted = True
        self._active: dict[str, int] = {}     # kinds detected and not yet cleared: mends made
        self._pending: WatchUpdate | None = None
        self._lock = threading.Lock()
        self._last_look = -math.inf
        self._suspect: dict[str, int] = dict.fromkeys(KINDS, 0)
        self._measured: dict[str, list] = {k: [] for k in KINDS}
        self._band_base = BandLevels(self.th.band_match, self.band_looks)
        self._light_base: list[tuple[float, float]] = []
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        # (show time, frame) offered since the look in flight started, for a look that says
        # when its picture was on the wall (LiveView.looked_at)
        self._shown: list[tuple[float, np.ndarray]] = []
        self.bursts = bursts
        self._bursts = BurstRunner(bursts)
        self._before: dict[str, Calibration] = {}   # the calibration a change was detected on

    # ------------------------------------------------------------------ the Player's side
    @property
    def trusted(self) -> bool:
        """False while a change is detected and not yet mended and checked (or an update is
        waiting for the Player), and from a look that sees the geometry move until the next
        look confirms or dismisses it: show geometry only."""
        with self._lock:
            return self._trusted and self._pending is None

    def offer(self, shown: np.ndarray, source: np.ndarray | None = None) -> bool:
        """The Player showed ``shown`` ((Hp, Wp, 3) uint8, the projector frame) for the input
        ``source``: look now if a look is due. Returns whether a look was started."""
        self._raise_error()
        if not self.trusted and not self._bursts.asked:     # (a pattern frame is no picture)
            self.untrusted_frames += 1
        t = float(self.clock())
        if self._bursts.burst is not None:
            b = self._bursts.offered(self.look)
            if b is not None and self.threaded:      # the Player goes on, geometry only
                self._thread = threading.Thread(target=self._finish_burst, args=(b, t),
                                                name="rtdefocus-burst", daemon=True)
                self._thread.start()
            elif b is not None:
                self._finish_burst(b, t)
            return False
        pairs = self.threaded and hasattr(self.look, "looked_at")
        if self.threaded and self._thread is not None and self._thread.is_alive():
            if pairs:
                with self._lock:
                    self._shown = (self._shown + [(t, np.array(shown, copy=True))])[-_HISTORY:]
            return False
        with self._lock:
            hurry = bool(self._active) or any(self._suspect.values())
        if t - self._last_look < (self.recheck_s if hurry else self.period_s):
            return False
        if self.threaded:
            self._last_look = t
            frame = np.array(shown, copy=True)
            with self._lock:
                self._shown = [(t, frame)] if pairs else []
            self._thread = threading.Thread(target=self._work, args=(frame, t),
                                            name="rtdefocus-watch", daemon=True)
            self._thread.start()
            return True
        self._last_look = t
        self.step(shown, self.look(shown), t)
        return True

    def pattern(self) -> np.ndarray | None:
        """The (Hp, Wp, 3) uint8 pattern frame to show next instead of the content (a burst in
        progress; then :meth:`offer` it as shown), or None: show the content."""
        return self._bursts.pattern()

    def poll(self) -> WatchUpdate | None:
        """The update waiting to be applied between two frames (once), or None."""
        self._raise_error()
        with self._lock:
            update, self._pending = self._pending, None
        return update

    def close(self, timeout: float = 10.0) -> None:
        """Wait for a look in progress to finish."""
        if self._thread is not None:
            self._thread.join(timeout)

    def _work(self, frame: np.ndarray, t: float) -> None:
        try:
            capture = self.look(frame)
            frame = self._on_the_wall(frame)
            self.step(frame, capture, t)
        except BaseException as exc:          # handed to the Player's thread by poll / offer
            self._error = exc

    def _on_the_wall(self, frame: np.ndarray) -> np.ndarray:
        """The frame offered last by the time the look's picture was on the wall (``frame``,
        the one the look started with, when the look does not say when that was)."""
        at = getattr(self.look, "looked_at", None)
        with self._lock:
            shown, self._shown = self._shown, []
        if at is None:
            return frame
        before = [f for ts, f in shown if ts <= at]
        return before[-1] if before else frame

    def _raise_error(self) -> None:
        if self._error is not None:
            exc, self._error = self._error, None
            raise exc

    # ------------------------------------------------------------------ one look
    def step(self, shown: np.ndarray, capture: np.ndarray, t: float) -> ResidualReport | None:
        """Compare ``capture`` with the prediction for ``shown`` and act on it (a look without
        the clock: tests and evaluations may call it directly). Returns the report (None when
        the camera no longer sees the frame)."""
        self.looks += 1
        wc, hc = self.calib.camera_size
        if np.shape(capture) != (hc, wc, 3):
            raise InputError(f"the look returned a {np.shape(capture)} frame; the calibration's "
                             f"camera gives ({hc}, {wc}, 3): check the camera the watcher uses")
        try:
            r = self.report(self.calib, shown, capture)
        except InputError as exc:
            if "lost" not in self._active:
                self._active["lost"] = 0
                self._event(t, "lost", "detect", {"error": str(exc)})
                log.warning("the camera no longer sees the show as calibrated (%s): showing "
                            "geometry only; re-calibrate (`rtdefocus calibrate`)", exc)
                self._start_burst("geometry", t)
            self._update_trust()
            return None
        self.last_report = r
        if self._active.pop("lost", None) is not None:
            self._event(t, "lost", "cleared", {})
        frame_informs = self._informative(shown)
        over, under, informative = self._classify(r, frame_informs)
        # Untrusted and too plain to align for too long: the geometry patterns say it.
        if self._bursts.plain_too_long(bool(self._active) and not informative["geometry"], t) \
                and self._start_burst("geometry", t):
            return r
        todo = None
        blocked = False          # an earlier kind is changing: later kinds are not judged
        for k in KINDS:
            if k in self._active:
                self._suspect[k] = 0
                if under[k]:
                    del self._active[k]
                    self._event(t, k, "cleared", {})
                    continue
                blocked = True
                if not informative[k]:
                    continue                 # this look says nothing of it: wait for one that does
                # Mended but not right yet: mend what is left.
                self._measured[k] = [r]
                todo = todo or k
            elif blocked or not over[k]:
                if k == "geometry" and self._suspect[k]:
                    self._event(t, k, "dismiss", self._describe(k, r))
                self._suspect[k], self._measured[k] = 0, []
            else:
                blocked = True
                self._suspect[k] += 1
                self._measured[k].append(r)
                if k == "geometry" and self._suspect[k] == 1 < self.confirm:
                    self._event(t, k, "suspect", self._describe(k, r))
                if self._suspect[k] >= self.confirm:
                    self._active[k], self._before[k] = 0, self.calib
                    self._event(t, k, "detect", self._describe(k, r))
                    todo = todo or k
        if todo is not None:
            self._update_trust()            # geometry only from the next frame on
            self._mend(todo, shown, capture, t)
        elif not self._active and not any(over.values()):
            # The levels of a model known right, each from looks that can tell it.
            if frame_informs["focus"]:
                self._band_base.add(r)
            if informative["light"]:
                self._light_base = (self._light_base + [(r.gain, r.ambient_added)])[-16:]
        self._update_trust()
        return r

    def _light_ref(self) -> tuple[float, float]:
        """The gain and added light the reports read while the model was right (a calibration
        is rarely exact in its light: the levels are judged against these), or (1, 0) before
        ``band_looks`` such looks (then no light change is detected)."""
        if len(self._light_base) < self.band_looks:
            return 1.0, 0.0
        g, a = np.median(np.array(self._light_base), axis=0)
        return float(g), float(a)

    def _update_trust(self) -> None:
        with self._lock:
            # A stale geometry compensated is worse than geometry only (its sharpening lands
            # beside the edges); a stale light or focus model is not: only a geometry
            # suspicion puts the show on geometry only before the change is confirmed.
            was = self._trusted
            self._trusted = not self._active and not self._suspect["geometry"]
        if self._trusted and not was:
            log.info("watch: the model is trusted again")

    def _informative(self, shown: np.ndarray) -> dict:
        """Per kind, whether the shown frame has the content to judge it (see
        :class:`Thresholds`)."""
        return content_informs(shown, self.calib.lut, self.th.min_contrast, self.th.min_band)

    def _classify(self, r: ResidualReport, informative: dict) -> tuple[dict, dict, dict]:
        """Per kind: over its high threshold, under its low one (neither where the look has
        nothing to say of the kind), and whether it has something to say."""
        th = self.th
        ok = np.isfinite(r.shifts_proj).all(axis=1) & (r.confidence >= th.min_confidence)
        informative = dict(informative, geometry=informative["geometry"] and bool(ok.any()))
        geo = float(np.linalg.norm(r.shifts_proj[ok], axis=1).max()) if ok.any() else 0.0
        g_ref, a_ref = self._light_ref()
        gain = abs(r.gain / g_ref - 1.0)
        amb = abs(r.ambient_added - a_ref)
        base, band = self._band_base.level(r), band_level(r)
        focus = abs(band / base - 1.0) if base and math.isfinite(band) else 0.0
        if base is None and self._band_base.known():
            informative = dict(informative, focus=False)    # levels known, not on such content
        psf = self.calib.has_psf
        # Light is judged only against its measured levels: a calibration rarely explains
        # the room's light exactly, and that is no change.
        light_known = len(self._light_base) >= self.band_looks
        over = {"geometry": geo > th.geometry_px[0],
                "light": light_known and (gain > th.gain[0] or amb > th.ambient[0]),
                "focus": psf and focus > th.focus[0]}
        under = {"geometry": geo < th.geometry_px[1],
                 "light": gain < th.gain[1] and amb < th.ambient[1],
                 "focus": not psf or focus < th.focus[1]}
        for k in KINDS:
            if not informative[k]:
                over[k] = under[k] = False
        return over, under, informative

    @staticmethod
    def _describe(kind: str, r: ResidualReport) -> dict:
        if kind == "geometry":
            return {"shifts_proj": np.round(r.shifts_proj, 3).tolist()}
        if kind == "light":
            return {"gain": round(r.gain, 4), "ambient_added": round(r.ambient_added, 5)}
        return {"band_ratio": round(r.band_ratio, 4)}

    def _event(self, t: float, kind: str, action: str, detail: dict, patterns: int = 0) -> None:
        ev = WatchEvent(t, kind, action, detail, patterns)
        self.events.append(ev)
        log.info("watch %.2f s: %s %s %s", t, kind, action, detail)

    # ------------------------------------------------------------------ mends
    def _mend(self, kind: str, shown: np.ndarray, capture: np.ndarray, t: float) -> None:
        reports = self._measured[kind][-self.confirm:]
        self._measured[kind] = []
        self._suspect[kind] = 0
        mends = self._active[kind]
        if mends >= self.max_mends:
            if mends == self.max_mends:
                self._event(t, kind, "give up", {"mends": mends})
                log.warning("the %s change could not be mended from the content after %d tries; "
                            "showing geometry only: re-calibrate (`rtdefocus calibrate`)",
                            kind, mends)
                self._active[kind] = mends + 1
            return
        o = self.bursts
        if o and kind == "geometry" and mends >= o.geometry_after and self._start_burst(kind, t):
            return
        try:
            new, detail = self._estimate(kind, reports, shown, capture)
        except RtDefocusError as exc:
            log.warning("could not mend the %s change: %s", kind, exc)
            self._active[kind] = mends + 1
            # A mend the content cannot even estimate (a light fit with a negative gain: the
            # picture is not where the model puts it): the patterns say what changed.
            self._start_burst("focus" if kind == "focus" else "geometry", t)
            return
        if new is None:
            self._event(t, kind, "retract", detail)
            if mends == 0:
                self.false_alarms += 1
            del self._active[kind]
            return
        # What the content sizes only roughly (a blur change, if asked), or cannot align (a
        # move too large: the refit does not converge), the patterns measure.
        if o and mends == 0 and ((kind == "focus" and o.focus == "always") or (
                kind == "geometry" and not math.isfinite(detail.get("refit_left_px", 0.0)))) \
                and self._start_burst(kind, t, detail):
            return
        self._hand_over(kind, new, detail, t)

    def _hand_over(self, kind: str, new: Calibration, detail: dict, t: float,
                   patterns: int = 0) -> None:
        """A mend made: the new calibration in use, the update waiting for the Player."""
        self._active[kind] = self._active.get(kind, 0) + 1
        if kind == "focus":
            # The band level belongs to the old kernels and to the content it was read on (a
            # compensated frame's spectrum): it is measured again with the new kernels, and
            # until then focus is not judged.
            self._band_base.clear()
        moved = camera_correction(self.calib, new)
        self.calib = new
        if moved is not None:        # the show's picture stays; only the model's camera moved
            self._camera_moved = moved @ self._camera_moved
        else:
            self._show_calib = new if np.array_equal(self._camera_moved, np.eye(3)) else mend_camera(
                new, np.linalg.inv(self._camera_moved))
        self._event(t, kind, "mend", detail, patterns)
        with self._lock:
            kinds = (kind,) if self._pending is None else tuple(dict.fromkeys(
                (*self._pending.kinds, kind)))
            self._pending = WatchUpdate(self._show_calib, kinds, False, t)

    def _estimate(self, kind: str, reports: list[ResidualReport], shown: np.ndarray,
                  capture: np.ndarray) -> tuple[Calibration | None, dict]:
        """The mended calibration and what was done, or (None, detail) when the change is too
        small to apply."""
        calib, th = self.calib, self.th
        if kind == "light":
            gain = float(np.median([r.gain for r in reports]))
            added = float(np.median([r.ambient_added for r in reports]))
            detail = {"gain": round(gain, 4), "ambient_added": round(added, 5)}
            g_ref, a_ref = self._light_ref()
            if abs(gain / g_ref - 1) < th.gain[1] and abs(added - a_ref) < th.ambient[1]:
                return None, detail
            # Relative to the levels read while the model was right (what the calibration
            # never explained exactly stays as it was): the mended model reads those levels
            # again, on any content, so the next look clears the change.
            return mend_light(calib, gain / g_ref, (added - a_ref) / g_ref), detail
        if kind == "geometry":
            return mend_geometry(calib, reports, shown, capture, th.min_confidence,
                                 th.geometry_px[1], self.report)
        base = self._band_base.level(reports[-1])
        if base is None:
            raise InputError("no band-pass level of the unchanged set-up to rescale the kernels to")
        scale = fit_band_scale(self.calib, shown, capture, base, self.report)
        detail = {"kernel_scale": round(scale, 4)}
        if not 0.5 < scale < 2.0:
            raise InputError(f"no radius scale within [0.5, 2] explains the band ratio ({scale:.3g})")
        if abs(scale - 1.0) < 0.06:
            # The kernels explain this content: its band level is one of a right model (the
            # ratio moves a few per cent with the content's spectrum), measured again from here.
            self._band_base.measure_again(reports)
            return None, detail
        return rescale_radii(calib, scale), detail

    # ------------------------------------------------------------------ bursts
    def _start_burst(self, kind: str, t: float, detail: dict | None = None) -> bool:
        b = self._bursts.start(kind, self.calib, t)
        if b is not None:
            self._active.setdefault(kind, 0)
            self._event(t, kind, "burst", {"frames": b.frames, **(detail or {})})
            self._update_trust()
        return b is not None

    def _finish_burst(self, b: Burst, t: float) -> None:
        """The burst's frames are captured: re-measure, and hand the mend over (or give up)."""
        try:
            # A geometry burst measures the whole move: from before the content's mends of it.
            new, detail = b.solve(self._before[b.kind] if b.kind == "geometry"
                                  and self._active.get(b.kind) else self.calib)
            self._hand_over(b.kind, new, detail, t, b.shown)
        except RtDefocusError as exc:
            self._active[b.kind] = self.max_mends + 1
            self._event(t, b.kind, "give up", {"error": str(exc)}, b.shown)
            log.warning("the %s burst could not re-measure the set-up (%s); showing geometry "
                        "only: re-calibrate (`rtdefocus calibrate`)", b.kind, exc)
        except BaseException as exc:          # handed to the Player's thread by poll / offer
            self._error = exc
        finally:
            self._bursts.done()
            self._last_look = t
