"""A scripted timeline of set-up changes for evaluation: a clip plays and, at given times, the
virtual set-up is bumped, its light changed or its focus moved (:mod:`~rtdefocus.sim.changes`)."""

from __future__ import annotations

import inspect
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .changes import SetupChanges

#: The changes a timeline can apply: the :class:`SetupChanges` method of each name.
KINDS = ("bump", "set_light", "refocus")


@dataclass(frozen=True)
class Event:
    """One change at time ``t`` (s from the clip's start): ``procam.<kind>(**params)``."""

    t: float
    kind: str
    params: dict = field(default_factory=dict)

    def apply(self, procam) -> None:
        getattr(procam, self.kind)(**self.params)


class Timeline:
    """Changes of a virtual set-up at given times of a clip.

    Parameters
    ----------
    events : iterable of :class:`Event` or ``(t_seconds, kind, params)`` with ``kind`` one of
        :data:`KINDS` and ``params`` the keyword arguments of that method of
        :class:`~rtdefocus.sim.VirtualProCam`, e.g.
        ``Timeline([(2.0, "bump", {"projector_yaw_deg": 0.3, "projector_shift_px": 3}),
        (6.0, "set_light", {"ambient": 0.12}), (10.0, "refocus", {"scale": 1.15})])``.
        Events are kept in time order (ties in the given order).

    Attributes
    ----------
    events : tuple of :class:`Event`, sorted by time.
    applied : how many events have been applied since the last :meth:`reset`.
    """

    def __init__(self, events: Iterable = ()):
        checked = []
        for i, ev in enumerate(events):
            if not isinstance(ev, Event):
                try:
                    t, kind, params = ev
                except (TypeError, ValueError):
                    raise InputError(f"timeline event {i} must be (t_seconds, kind, params); "
                                     f"got {ev!r}") from None
                ev = Event(float(t), str(kind), dict(params or {}))
            if not (math.isfinite(ev.t) and ev.t >= 0):
                raise InputError(f"timeline event {i}: time must be a finite number of seconds >= 0; "
                                 f"got {ev.t!r}")
            if ev.kind not in KINDS:
                raise InputError(f"timeline event {i}: unknown change {ev.kind!r}; "
                                 f"use one of {', '.join(KINDS)}")
            method = getattr(SetupChanges, ev.kind)
            try:
                inspect.signature(method).bind(None, **ev.params)
            except TypeError as exc:
                names = [p for p in inspect.signature(method).parameters if p != "self"]
                raise InputError(f"timeline event {i} ({ev.kind} at {ev.t:g} s): {exc}; its parameters "
                                 f"are {', '.join(names)}") from None
            checked.append(ev)
        self.events = tuple(sorted(checked, key=lambda e: e.t))
        self.applied = 0

    def __len__(self) -> int:
        return len(self.events)

    def reset(self) -> None:
        """Start again from the clip's beginning (on a fresh set-up: changes are not undone)."""
        self.applied = 0

    @property
    def next_time(self) -> float | None:
        """Time (s) of the next event not yet applied; None when all are."""
        return self.events[self.applied].t if self.applied < len(self.events) else None

    def advance(self, procam, t: float) -> list[Event]:
        """Apply, in order, every event not yet applied whose time is <= ``t`` (s).

        Returns the events applied now (an empty list when none falls due).
        """
        done = []
        t = float(t) + 1e-9       # frame times i / fps land on event times despite rounding
        while self.applied < len(self.events) and self.events[self.applied].t <= t:
            ev = self.events[self.applied]
            ev.apply(procam)
            self.applied += 1
            done.append(ev)
        return done

    def play(self, procam, frames: Iterable[np.ndarray], fps: float,
             sharp: bool = False) -> Iterator[tuple[float, np.ndarray, list[Event]]]:
        """Show ``frames`` one by one at ``fps``, applying the events as their times come.

        Frame ``i`` is shown at ``t = i / fps``; the events due by then are applied before it
        is captured.

        Yields
        ------
        (t, camera frame, events applied just before this frame)
        """
        if not (fps > 0 and math.isfinite(fps)):
            raise InputError(f"fps must be a positive number; got {fps!r}")
        for i, frame in enumerate(frames):
            t = i / fps
            done = self.advance(procam, t)
            yield t, procam.capture(frame, sharp=sharp), done
