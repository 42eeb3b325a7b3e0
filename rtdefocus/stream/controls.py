"""What the viewer controls, and what the player shows on top: display modes, key dispatch,
the per-frame iteration budget and the stats overlay.

Keys (window): space pause, ←/→ previous/next slide, ``c`` compensation on/off (A/B),
``g`` geometry only, ``s`` stats overlay, ``q``/Esc quit — see :class:`KeyDispatcher`.
"""

from __future__ import annotations

import collections
import logging
import math
import statistics
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)

#: Display modes: compensated, geometry correction only, plain projector (letterboxed input).
MODES = ("full", "geometry", "off")

#: Key name -> action. Page Up/Down (presentation clickers) arrive as left/right.
DEFAULT_KEYMAP = {
    "space": "pause", "left": "previous", "right": "next", "c": "compensation",
    "g": "geometry", "s": "stats", "q": "quit", "escape": "quit", "close": "quit",
}


@dataclass
class Controls:
    """What the viewer asked for; changed only through :class:`KeyDispatcher` (main thread)."""

    paused: bool = False
    mode: str = "full"
    overlay: bool = False
    quit: bool = False
    step: int = 0          # pending slide navigation, consumed by the player
    version: int = 0       # bumped on every change, so the player knows to redraw


class KeyDispatcher:
    """Turns key names into changes of :class:`Controls`.

    ``c`` toggles between ``full`` and ``off`` (what the audience would see without
    rtdefocus); ``g`` toggles between ``geometry`` and ``full``.
    """

    def __init__(self, controls: Controls, keymap: dict[str, str] | None = None):
        self.controls = controls
        self.keymap = dict(DEFAULT_KEYMAP if keymap is None else keymap)

    def dispatch(self, key: str) -> str | None:
        """Apply ``key``; return the action taken, or None for an unmapped key."""
        action = self.keymap.get(key)
        c = self.controls
        if action is None:
            return None
        if action == "pause":
            c.paused = not c.paused
        elif action == "previous":
            c.step -= 1
        elif action == "next":
            c.step += 1
        elif action == "compensation":
            c.mode = "off" if c.mode == "full" else "full"
        elif action == "geometry":
            c.mode = "full" if c.mode == "geometry" else "geometry"
        elif action == "stats":
            c.overlay = not c.overlay
        elif action == "quit":
            c.quit = True
        else:
            raise InputError(f"unknown key action {action!r} for key {key!r}")
        c.version += 1
        log.debug("key %r -> %s (%s)", key, action, c)
        return action


#: Frames whose rests :meth:`IterationBudget.frame_seconds` takes the median of
#: (``deadline=True``): one slow frame does not hold the estimate up, a lasting change moves it
#: within two frames.
RECENT = 3
#: Frames whose measured / expected costs :meth:`IterationBudget.cost_ratio` takes a quantile
#: of (about a second of video), and how many it needs before it answers.
SPREAD_FRAMES, SPREAD_MIN = 24, 8


class IterationBudget:
    """Solver iterations per frame that hold a target frame period.

    After every frame, the measured seconds per iteration and the rest of the frame's time
    (warp, transfers, overlay, present) update exponential moving averages; the budget is the
    number of iterations that fits in what is left of the period, clamped to
    ``[minimum, maximum]`` and allowed to grow by at most half per frame (a slow frame is
    answered at once, a fast one cautiously).

    For each frame timed for the deadline it also keeps how far its measured cost was from the
    one expected for it (:meth:`cost_ratio`), per kind: the spread a safety margin on expected
    costs must cover (a still picture's steady refinements say nothing of a moving frame's).

    A *repeated* frame (the same picture again: a paused video, a slide) skips the warp and the
    motion estimate, so its rest costs a fraction of a new frame's: the two kinds keep their own
    averages and budgets (``repeat=``), and a still picture's larger budget does not carry over
    to the first new frame after it.
    """

    def __init__(self, fps: float, *, initial: int = 2, minimum: int = 1, maximum: int = 20,
                 smoothing: float = 0.3):
        if not fps or fps <= 0:
            raise InputError(f"target fps must be positive; got {fps}")
        if not 1 <= minimum <= maximum:
            raise InputError(f"need 1 <= minimum <= maximum iterations; got {minimum}, {maximum}")
        self.period = 1.0 / fps
        self.minimum, self.maximum = int(minimum), int(maximum)
        self.alpha = smoothing
        self.per_iteration: float | None = None
        start = int(min(max(initial, minimum), maximum))
        self._overhead: dict[bool, float | None] = {False: None, True: None}
        self._recent: dict[bool, collections.deque] = {k: collections.deque(maxlen=RECENT)
                                                       for k in (False, True)}
        self._history: dict[bool, collections.deque] = {
            k: collections.deque(maxlen=SPREAD_FRAMES) for k in (False, True)}
        self._iterations = {False: start, True: start}
        self._expected = {False: False, True: False}   # the kind's rest is only expected
        self._ratios = {k: collections.deque(maxlen=SPREAD_FRAMES) for k in (False, True)}

    @property
    def iterations(self) -> int:
        """The budget of the next new frame."""
        return self._iterations[False]

    @property
    def overhead(self) -> float | None:
        """The averaged rest (all but the solve) of a new frame, seconds."""
        return self._overhead[False]

    def iterations_for(self, repeat: bool = False) -> int:
        """The budget of the next frame of that kind."""
        return self._iterations[bool(repeat)]

    def frame_seconds(self, iterations: int | None = None, repeat: bool = False,
                      deadline: bool = False, stale: bool = False) -> float | None:
        """Expected seconds of a compensated frame of that kind at ``iterations`` (default its
        budget); ``deadline``: from the median of the last :data:`RECENT` frames' rests
        instead of their moving average, which one slow frame (a cut, a first use) holds up for
        several frames; ``stale`` (the last measurement is old: a catch-up that has compensated
        no frame of the kind for a while), from the median of the last :data:`SPREAD_FRAMES`,
        so that two slow frames in a row are not the estimate for good. None before the first
        measured frame."""
        kind = self._measured_kind(repeat)
        rest = self._overhead[kind]
        if self.per_iteration is None or rest is None:
            return None
        if deadline:
            # (statistics, not NumPy: a few values, asked on every live frame)
            rest = float(statistics.median((self._history if stale else self._recent)[kind]))
        n = self.iterations_for(repeat) if iterations is None else int(iterations)
        return rest + n * self.per_iteration

    def cost_ratio(self, quantile: float, repeat: bool = False) -> float | None:
        """The ``quantile`` (0-1) of measured / expected seconds over the last
        :data:`SPREAD_FRAMES` frames of that kind timed for the deadline, each against the
        kind's :meth:`frame_seconds` (``deadline=True``) just before it was recorded; a kind's
        merely expected rest is no measure. The sample at or below the quantile: one spike
        among a few frames does not lift it. About 1 on a steady device, more on a jittery
        one. None before :data:`SPREAD_MIN` such frames of the kind: a moving frame (warp,
        motion estimate, carry) varies more than a repeated picture's refinement, so one
        kind's spread is no measure of the other's."""
        ratios = self._ratios[bool(repeat)]
        if len(ratios) < SPREAD_MIN:
            return None
        # NumPy's quantile(method="lower") over a few values, asked on every live frame
        return float(sorted(ratios)[math.floor(quantile * (len(ratios) - 1))])

    def expect(self, rest: float, repeat: bool = True) -> None:
        """An expected rest (seconds, all but the solve) for a kind not measured yet; the
        kind's first measured frame replaces it."""
        repeat = bool(repeat)
        if self._overhead[repeat] is None or self._expected[repeat]:
            self._overhead[repeat] = max(0.0, float(rest))
            for rests in (self._recent[repeat], self._history[repeat]):
                rests.clear()
                rests.append(self._overhead[repeat])
            self._expected[repeat] = True

    def forget_recent(self, repeat: bool = False) -> None:
        """Let the last :data:`RECENT` rests of that kind go (old ones, a catch-up's frozen
        estimate): they stand at the median of the longer history until the next frames
        replace them."""
        history = self._history[bool(repeat)]
        if history:
            self._recent[bool(repeat)].clear()
            self._recent[bool(repeat)].append(float(statistics.median(history)))

    def _measured_kind(self, repeat: bool) -> bool:
        """The kind whose averages stand for ``repeat``: its own once measured, else the other."""
        repeat = bool(repeat)
        return repeat if self._overhead[repeat] is not None else not repeat

    def _ema(self, old: float | None, new: float) -> float:
        return new if old is None else (1 - self.alpha) * old + self.alpha * new

    def update(self, frame_seconds: float, solve_seconds: float, iterations: int,
               repeat: bool = False, deadline: bool = True) -> int:
        """Record one frame (``repeat``: the same picture as the frame before; ``deadline``
        False: a new frame cheaper than the kind's usual, such as a cut's cold start, left out
        of the deadline's median); return the budget for the next frame of that kind."""
        repeat = bool(repeat)
        if deadline and self._overhead[repeat] is not None and not self._expected[repeat]:
            expected = self.frame_seconds(iterations, repeat, deadline=True)
            if expected:
                self._ratios[repeat].append(frame_seconds / expected)
        if iterations > 0:
            self.per_iteration = self._ema(self.per_iteration, solve_seconds / iterations)
        rest = max(0.0, frame_seconds - solve_seconds)
        if self._expected[repeat]:                     # the first measured frame of the kind
            self._expected[repeat] = False
            self._overhead[repeat] = None
            self._recent[repeat].clear()
            self._history[repeat].clear()
        self._overhead[repeat] = self._ema(self._overhead[repeat], rest)
        if deadline or not self._recent[repeat]:
            self._recent[repeat].append(rest)
            self._history[repeat].append(rest)
        if self.per_iteration:
            for kind in (False, True):
                rest = self._overhead[self._measured_kind(kind)]
                fit = (self.period - rest) / self.per_iteration
                old = self._iterations[kind]
                grow = max(old + 1, math.ceil(old * 1.5))
                n = min(int(fit) if math.isfinite(fit) else self.maximum, grow)
                self._iterations[kind] = int(min(max(n, self.minimum), self.maximum))
        return self._iterations[repeat]


def draw_overlay(frame: np.ndarray, lines: list[str]) -> np.ndarray:
    """A copy of ``frame`` with ``lines`` of text at the top left (white on a dark outline)."""
    out = np.ascontiguousarray(frame).copy()
    h = out.shape[0]
    scale = max(0.35, h / 1400)
    thick = max(1, round(scale * 2))
    step = int(30 * scale) + 6
    for i, text in enumerate(lines):
        org = (8, 8 + step * (i + 1) - 6)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA)
    return out
