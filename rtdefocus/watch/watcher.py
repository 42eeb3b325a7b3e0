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
content, with no pattern on the screen:

* light: albedo and ambient re-scaled by the report's gain and added room light;
* geometry: a camera move is one camera-side correction for all planes, a projector move one
  per plane with the folds kept consistent (:mod:`~rtdefocus.watch.mend`); which of the two it
  was is decided by which single homography (in camera or in projector pixels) explains the
  planes' content warps better, and the mend is then refined to a few hundredths of a pixel by
  direct alignment of the content (:mod:`~rtdefocus.watch.refit`);
* focus: every kernel's radius rescaled by the factor that brings the band-pass ratio back to
  its level while the model was right.

The mend becomes a new :class:`~rtdefocus.calib.file.Calibration` (the one in use is never
modified), handed to the Player by :meth:`Watcher.poll` as a :class:`WatchUpdate` that it
applies between two frames. The next look checks it: below the low threshold the kind is
cleared; otherwise what is left is mended the same way (at most ``max_mends`` times; then the
watcher gives up, says so, and frames stay geometry only: the set-up needs a calibration).
A short burst of calibration patterns for changes the content cannot mend is not part of
this watcher.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..calib.file import Calibration
from ..errors import InputError, RtDefocusError
from .levels import BandLevels, band_level
from .mend import camera_motion, mend_camera, mend_light, mend_projector, rescale_kernels
from .refit import content_warps, refit_geometry, which_moved
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
    action : "detect" (a change confirmed: the model is no longer trusted), "mend" (a new
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
    calibration : the new calibration (a new object; the previous one is left as it was).
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

    Attributes
    ----------
    calib : the latest calibration (the one the last update carries).
    events : list of :class:`WatchEvent`, in time order.
    false_alarms : confirmed detections the watcher retracted because the change, once
        estimated, was below the low threshold (nothing applied). An evaluation that knows
        when the set-up changed counts its own: detections with no change since the last one.
    looks : looks made; last_report : the last look's report.
    untrusted_frames : frames offered while the model was not trusted (shown geometry only).
    """

    def __init__(self, calib: Calibration, look: Callable[[np.ndarray], np.ndarray], *,
                 period_s: float = 0.25, clock: Callable[[], float] = time.perf_counter,
                 threaded: bool = True, thresholds: Thresholds | None = None, confirm: int = 2,
                 max_mends: int = 4, band_looks: int = 4,
                 report: Callable[..., ResidualReport] = residual_report,
                 recheck_s: float | None = None):
        if not (math.isfinite(period_s) and period_s >= 0):
            raise InputError(f"period_s must be a number of seconds >= 0; got {period_s!r}")
        if recheck_s is not None and not (math.isfinite(recheck_s) and recheck_s >= 0):
            raise InputError(f"recheck_s must be a number of seconds >= 0 or None; got {recheck_s!r}")
        if confirm < 1:
            raise InputError(f"confirm must be >= 1; got {confirm!r}")
        self.calib = calib
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

    # ------------------------------------------------------------------ the Player's side
    @property
    def trusted(self) -> bool:
        """False while a change is detected and not yet mended and checked (or an update is
        waiting for the Player): show geometry only."""
        with self._lock:
            return self._trusted and self._pending is None

    def offer(self, shown: np.ndarray, source: np.ndarray | None = None) -> bool:
        """The Player showed ``shown`` ((Hp, Wp, 3) uint8, the projector frame) for the input
        ``source``: look now if a look is due. Returns whether a look was started."""
        self._raise_error()
        if not self.trusted:
            self.untrusted_frames += 1
        t = float(self.clock())
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
            self._update_trust()
            return None
        self.last_report = r
        if self._active.pop("lost", None) is not None:
            self._event(t, "lost", "cleared", {})
        frame_informs = self._informative(shown)
        over, under, informative = self._classify(r, frame_informs)
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
                self._suspect[k], self._measured[k] = 0, []
            else:
                blocked = True
                self._suspect[k] += 1
                self._measured[k].append(r)
                if self._suspect[k] >= self.confirm:
                    self._active[k] = 0
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
            was, self._trusted = self._trusted, not self._active
        if self._trusted and not was:
            log.info("watch: the model is trusted again")

    def _informative(self, shown: np.ndarray) -> dict:
        """Per kind, whether the shown frame has the content to judge it (see
        :class:`Thresholds`)."""
        # decode_lut's grey by table and one weighted sum (a tenth of its time per look)
        table = np.ascontiguousarray(np.asarray(self.calib.lut, np.float32).T[None])
        lin = cv2.transform(cv2.LUT(np.ascontiguousarray(shown, np.uint8), table),
                            np.full((1, 3), 1.0 / 3.0, np.float32))
        band = cv2.GaussianBlur(lin, (0, 0), 1.0) - cv2.GaussianBlur(lin, (0, 0), 2.0)
        return {"geometry": True, "light": float(lin.std()) > self.th.min_contrast,
                "focus": float(np.sqrt(np.mean(band ** 2))) > self.th.min_band}

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
        try:
            new, detail = self._estimate(kind, reports, shown, capture)
        except RtDefocusError as exc:
            log.warning("could not mend the %s change: %s", kind, exc)
            self._active[kind] = mends + 1
            return
        if new is None:
            self._event(t, kind, "retract", detail)
            if mends == 0:
                self.false_alarms += 1
            del self._active[kind]
            return
        self._active[kind] = mends + 1
        self.calib = new
        self._event(t, kind, "mend", detail)
        with self._lock:
            kinds = (kind,) if self._pending is None else tuple(dict.fromkeys(
                (*self._pending.kinds, kind)))
            self._pending = WatchUpdate(new, kinds, False, t)

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
            # Planes whose correlation peak is too low say nothing, as in _classify; a plane
            # no look could measure takes the mean of the others.
            seen = np.stack([np.where((r.confidence >= th.min_confidence)[:, None],
                                      r.shifts_proj, np.nan) for r in reports])
            ok = np.isfinite(seen).all(axis=2).any(axis=0)
            if not ok.any():
                raise InputError("no plane's content shift could be measured")
            shifts = np.full((calib.n_planes, 2), np.nan)
            shifts[ok] = np.nanmedian(seen[:, ok], axis=0)
            shifts[~ok] = shifts[ok].mean(axis=0)
            detail = {"shifts_proj": np.round(shifts, 3).tolist()}
            if float(np.linalg.norm(shifts, axis=1).max()) < th.geometry_px[1]:
                return None, detail
            # A camera move shifts the walls with the content, a projector move the content
            # alone: the mend whose model explains the capture better says which it was.
            detail["moved"] = "projector"
            new = mend_projector(calib, shifts)
            cam = camera_motion(calib, shifts)
            # One homography for all planes, in projector or in camera pixels, says which moved.
            moved = which_moved(calib, content_warps(calib, shown, capture, start=shifts))
            if moved == "camera" and np.all(np.isfinite(cam)):
                detail.update(moved="camera", shift_cam=np.round(cam.mean(axis=0), 3).tolist())
                new = mend_camera(calib, cam.mean(axis=0))
            elif moved is None and np.all(np.isfinite(cam)):
                as_cam = mend_camera(calib, cam.mean(axis=0))
                rms = {"camera": self.report(as_cam, shown, capture).rms_after,
                       "projector": self.report(new, shown, capture).rms_after}
                detail["rms"] = {k: round(v, 6) for k, v in rms.items()}
                if rms["camera"] < rms["projector"]:
                    detail.update(moved="camera", shift_cam=np.round(cam.mean(axis=0), 3).tolist())
                    new = as_cam
            # The shifts leave a turn's shear and scale: align the content to the sub-pixel.
            new, left = refit_geometry(new, shown, capture, detail["moved"])
            detail["refit_left_px"] = round(left, 4)
            return new, detail
        base = self._band_base.level(reports[-1])
        if base is None:
            raise InputError("no band-pass level of the unchanged set-up to rescale the kernels to")
        scale = self._fit_scale(shown, capture, base)
        detail = {"kernel_scale": round(scale, 4)}
        if abs(scale - 1.0) < 0.04:
            # The kernels explain this content: its band level is one of a right model (the
            # ratio moves a few per cent with the content's spectrum), measured again from here.
            self._band_base.measure_again(reports)
            return None, detail
        # The band level belongs to the old kernels and to the content it was read on (a
        # compensated frame's spectrum): it is measured again with the new kernels, and until
        # then focus is not judged.
        self._band_base.clear()
        return rescale_kernels(calib, scale), detail

    def _fit_scale(self, shown: np.ndarray, capture: np.ndarray, level: float,
                   lo: float = 0.5, hi: float = 2.0, tol: float = 0.005) -> float:
        """The kernel radius scale whose prediction brings the band ratio of ``capture`` back
        to ``level``, its value while the model was right (the ratio grows with the scale: a
        blurrier prediction has less band-pass energy). Regula falsi (Illinois) on log scale.

        The ratio, not the residual, is matched: the observation is smoothed by its
        resampling into projector pixels, so the least residual lies at a larger scale than
        the true one."""
        def g(log_s: float) -> float:
            c = self.calib if log_s == 0.0 else rescale_kernels(self.calib, math.exp(log_s))
            return math.log(band_level(self.report(c, shown, capture)) / level)

        a, b = 0.0, 0.0
        fa = g(0.0)
        # Bracket the root from s = 1 outwards.
        step = math.log(1.15) if fa < 0 else -math.log(1.15)
        b = step
        fb = g(b)
        while fa * fb > 0:
            if abs(b) >= math.log(hi if step > 0 else 1 / lo):
                return math.exp(b)
            a, fa = b, fb
            b = b + step
            fb = g(b)
        side = 0
        for _ in range(12):
            c = b - fb * (b - a) / (fb - fa)
            fc = g(c)
            if abs(b - a) < tol or fc == 0:
                return math.exp(c)
            if fc * fb < 0:
                a, fa = b, fb
                if side == -1:
                    fa /= 2
                side = -1
            else:
                if side == 1:
                    fa /= 2
                side = 1
            b, fb = c, fc
        return math.exp(b)
