"""The live player's catch-up: per frame, compensate it or show it with geometry only.

Realtime playback with the adaptive iteration budget
(:class:`~rtdefocus.stream.controls.IterationBudget`): where even the budget's minimum does not
fit, a frame whose compensation, by its measured cost times a safety margin, would end after
the frame after next has arrived is shown with geometry only. A warp costs a fraction of a
solve, so the loop keeps up instead of dropping the next frame and leaving a late one on the
screen (on moving content a repeated frame looks far worse than an uncompensated fresh one).
:class:`CatchUp` holds the decision and the state it learns from (the safety margin, the
current picture); :class:`~rtdefocus.stream.loop.Player` owns one and asks it per frame.
"""

from __future__ import annotations

import inspect
import logging
import time

from .controls import SPREAD_MIN, IterationBudget
from .sources import Frame

log = logging.getLogger(__name__)

#: Catch-up: a moving frame is compensated only when its expected cost times a safety margin
#: ends before the frame after next arrives (two periods after it arrived); otherwise it is
#: shown with geometry only. A repeated picture's refinement must end before the next frame
#: arrives (one period), so a new picture after a still starts with its whole window. The
#: margin is the measured spread of the device's costs for frames of the same kind (moving,
#: or a repeated picture's refinement): the CATCH_UP_QUANTILE of the
#: last compensated frames' measured / expected costs (:meth:`IterationBudget.cost_ratio`) with
#: CATCH_UP_HEADROOM on top, at least CATCH_UP_MARGIN_MIN, so a steady device runs close to its
#: deadline and a jittery one keeps the room its spikes need (one rare spike does not move a
#: quantile: the late-frame step below answers it). A still picture's steady refinements never
#: lower a moving frame's margin; the live player's warm-up times WARM_UP_FRAMES moving frames,
#: so the first moving frames of a show are admitted by a moving frame's measured spread.
#: Until enough frames of the kind are measured, and for the first CATCH_UP_FRESH moving frames
#: after a still picture or at the start (a new shot's motion, its deadline estimate from other
#: content), the margin is at least 1 / CATCH_UP_SHARE (1.43): a moving frame's spread on a CPU
#: device (50-62 ms for the same work at 800x600 on 2 idle PoCL cores). Each compensated frame
#: that still ends late multiplies it by CATCH_UP_MARGIN_STEP at once; that steps back after
#: CATCH_UP_CALM moving frames without a late one, a wait that doubles with each late frame
#: while it is raised (up to CATCH_UP_CALM_MAX). The margin stays within [CATCH_UP_MARGIN_MIN,
#: CATCH_UP_MARGIN_MAX]. There are no blind probes: every piece of work beside the warp
#: (iterations, or the start alone: the motion estimate and the carried correction) is done only
#: where the measured costs with the margin say it will be on time, so on a device that cannot
#: keep up, moving content settles to geometry only and no frame is lost to a probe.
CATCH_UP_SHARE = 0.7
CATCH_UP_QUANTILE, CATCH_UP_HEADROOM = 0.95, 1.2
CATCH_UP_MARGIN_MIN, CATCH_UP_MARGIN_MAX = 1.1, 4.0
CATCH_UP_MARGIN_STEP = 1.25
CATCH_UP_CALM, CATCH_UP_CALM_MAX = 8, 256
CATCH_UP_FRESH = 2
#: Moving frames in a row shown with geometry only after which the deadline's estimate of a
#: moving frame's cost, frozen since none was compensated, is the median of the longer history
#: (:meth:`IterationBudget.frame_seconds` ``stale``): two slow frames in a row (a first moving
#: frame after a still, another program's burst) then do not keep a device that usually fits
#: at geometry only for the rest of the shot; a frame admitted so measures the device afresh
#: (the old rests give way: :meth:`IterationBudget.forget_recent`). A device whose usual cost
#: does not fit stays at geometry only.
CATCH_UP_STALE = 24
#: A still picture (the same frame again: a paused file, a still shot) whose compensation does
#: not fit two periods is compensated once (a "settle"), when it has stayed this many times as
#: long as that compensation takes with the safety margin. The live player solves it beside the
#: frame loop where the frames shown meanwhile keep their period (:mod:`rtdefocus.stream.settle`:
#: a solver off the CPU, or on the CPU where the loop's measured work for a geometry-only frame
#: leaves the room; no frame is dropped for it, and its result is dropped if the picture changes
#: first); a CPU device without that room makes none (``can_settle``); on the loop (where the
#: player cannot settle beside it), the frames it drops are copies of the picture unless the
#: picture changes during it. Either way a still that lasted that long seldom ends during it, so the
#: work (which shares the device with the warps) is seldom wasted. Before it the picture is
#: shown with geometry only, after it as compensated (refined further only where a refinement
#: fits two periods).
CATCH_UP_STILL_WAIT = 4
#: Moving frames a live player's warm-up times (:meth:`rtdefocus.Compensator.warm_up`): the
#: first sets the expected cost, the others measure its spread (SPREAD_MIN of them), so the
#: first moving frames of a show are admitted by a moving frame's measured spread.
WARM_UP_FRAMES = SPREAD_MIN + 1


def warm_up(comp, budget: IterationBudget) -> dict | None:
    """Run ``comp.warm_up`` at the budget's minimum iterations, timing WARM_UP_FRAMES moving
    frames where it takes ``frames`` (a Compensator does), and feed ``budget`` the moving
    frames it timed; return what it returned (see :meth:`rtdefocus.Compensator.warm_up`)."""
    try:
        params = inspect.signature(comp.warm_up).parameters
    except (TypeError, ValueError):
        params = {}
    several = "frames" in params or any(p.kind is p.VAR_KEYWORD for p in params.values())
    info = comp.warm_up(iterations=budget.minimum,
                        **({"frames": WARM_UP_FRAMES} if several else {}))
    if info:
        its = int(info.get("iterations", 0) or 0)
        for sec in info.get("moving") or [info.get("seconds") or {}]:
            if "total" in sec and "solve" in sec:
                budget.update(sec["total"], sec["solve"], its, repeat=False)
    return info


class CatchUp:
    """Decides, frame by frame, what a live player shows to keep up (see the module).

    Parameters
    ----------
    budget : IterationBudget
        The player's adaptive budget: its period and measured costs are what the decisions
        rest on.
    """

    def __init__(self, budget: IterationBudget):
        self.budget = budget
        self._raised = 1.0                   # the margin's factor for late frames
        self._calm = CATCH_UP_CALM           # ... moving frames before it steps back
        self._calm_left = CATCH_UP_CALM
        self._still_since = 0                # index of the current picture's first frame
        self._settled = False                # ... and whether it was settled
        self._fresh = 0                      # moving frames since the last still (0: none)
        self._unmeasured = 0                 # moving frames in a row not compensated

    @property
    def margin(self) -> float:
        """The safety margin on a moving frame's expected cost (see :data:`CATCH_UP_SHARE`)."""
        return self.margin_for(repeat=False)

    def margin_for(self, repeat: bool) -> float:
        """The safety margin on the expected cost of a frame of that kind (``repeat``: the
        picture compensated just before, again)."""
        ratio = self.budget.cost_ratio(CATCH_UP_QUANTILE, repeat=repeat)
        spread = (1.0 / CATCH_UP_SHARE if ratio is None
                  else max(CATCH_UP_MARGIN_MIN, CATCH_UP_HEADROOM * ratio))
        if not repeat and 0 < self._fresh <= CATCH_UP_FRESH:
            spread = max(spread, 1.0 / CATCH_UP_SHARE)
        return min(spread * self._raised, CATCH_UP_MARGIN_MAX)

    def new_picture(self, index: int) -> None:
        """Frame ``index`` shows a picture other than the frame before it."""
        self._still_since, self._settled = index, False

    def decide(self, frame: Frame, iterations: int, still: bool, repeat: bool,
               can_reshow: bool, can_settle=None) -> tuple[str, int | None]:
        """What to show for ``frame``, as ``(action, n)``.

        ``("compensate", n)`` with the iterations n (at most ``iterations``) whose expected
        cost, times the safety margin, lets ``frame`` end before the frame after next arrives
        (one period after the next one), or n = 0 where no iteration fits but the start alone
        does (the previous correction carried along the motion: never farther from the target
        than geometry only). Where nothing fits: ``("geometry", None)`` (the next frame would be
        dropped and this one shown late: geometry only keeps up instead); for a picture that
        did not change since the frame before (``still``; a still, a paused video file):
        ``("reshow", None)`` once it is compensated (``repeat`` and ``can_reshow``: its last
        output again, at no cost); before that, once, ``("settle", n)`` (compensate, though it
        may take several periods: beside the frame loop where the player can) where the
        picture has stayed :data:`CATCH_UP_STILL_WAIT` times as long as that takes and
        ``can_settle()`` (a callable; None: always) allows it, else ``("geometry", None)``.
        Without measured costs: ``("compensate", iterations)``."""
        b = self.budget
        self._fresh = 0 if still else self._fresh + 1
        stale = not repeat and self._unmeasured >= CATCH_UP_STALE
        rest = b.frame_seconds(0, repeat, deadline=True, stale=stale)
        if rest is None:
            return "compensate", iterations
        margin = self.margin_for(repeat)
        # A repeated picture's refinement ends before the next frame arrives, not the one
        # after: should that next frame be a new picture, it starts on time with its whole
        # window (a refinement that spilled into it would drop it).
        window = (1.0 if repeat else 2.0) * b.period
        left = window - (time.perf_counter() - frame.t_read) - margin * rest
        per_it = margin * b.per_iteration
        fit = int(left / per_it) if per_it > 0 else iterations
        if stale and (fit >= b.minimum or left >= 0):
            b.forget_recent()                # (this frame measures the device again)
        if fit >= b.minimum:
            return "compensate", min(iterations, fit)
        if still:
            if repeat and can_reshow:
                return "reshow", None
            # One settle per picture: one that has lasted CATCH_UP_STILL_WAIT times as long as
            # its compensation takes seldom ends during it (a late frame drops copies of it).
            lasted = (frame.index - self._still_since) * b.period
            room = lasted / (CATCH_UP_STILL_WAIT * margin) - rest
            n = int(room / b.per_iteration) if b.per_iteration > 0 else iterations
            if not self._settled and n >= b.minimum and (can_settle is None or can_settle()):
                self._settled = True
                return "settle", min(iterations, n)
            return "geometry", None
        if left >= 0:
            return "compensate", 0
        return "geometry", None


    def judge(self, frame: Frame, compensated: bool) -> None:
        """After a moving frame: a compensated one that ended after the frame after next
        arrived raises the safety margin; moving frames without a late one step it back (see
        :data:`CATCH_UP_SHARE`)."""
        self._unmeasured = 0 if compensated else self._unmeasured + 1
        if compensated and time.perf_counter() - frame.t_read > 2.0 * self.budget.period:
            if self._raised > 1.0:           # late again before the margin was back
                self._calm = min(2 * self._calm, CATCH_UP_CALM_MAX)
            self._raised = min(self._raised * CATCH_UP_MARGIN_STEP,
                               CATCH_UP_MARGIN_MAX / CATCH_UP_MARGIN_MIN)
            self._calm_left = self._calm
            log.debug("catch-up: frame %d ended late; safety margin %.2f", frame.index,
                      self.margin)
            return
        if self._raised <= 1.0:
            self._calm = self._calm_left = CATCH_UP_CALM
            return
        self._calm_left -= 1
        if self._calm_left <= 0:
            self._raised = max(1.0, self._raised / CATCH_UP_MARGIN_STEP)
            self._calm_left = self._calm
