"""Short bursts of calibration patterns during a show, for what the content cannot mend.

A :class:`Burst` is a list of pattern frames the Player shows instead of the content (asked
for by :meth:`~rtdefocus.watch.Watcher.pattern`), each captured through the watcher's own look.
Once all are captured, the calibration stage that owns the patterns runs on those captures,
replayed to it through a :class:`~rtdefocus.calib.capture.Capturer` (:class:`Replay`), so the
patterns and their decoding are the stages' own:

* :func:`dot_burst` (focus): one pattern of the PSF stage's dots on a grid over the frame,
  averaged over a few frames; :func:`~rtdefocus.calib.psf.dots.measure_psfs` solves each dot's
  kernel, and the one radius scale that best explains them rescales the calibration's kernels
  (:func:`~rtdefocus.watch.mend.rescale_radii`);
* :func:`geometry_burst` (a move too large for the content alignment, or content too plain
  for too long): the geometry stage's line and Gray-code patterns
  (:func:`~rtdefocus.calib.geometry.calibrate_geometry`, the lens and the plane count kept);
  the new homographies become a camera-side correction when one camera homography explains
  every plane, else a projector-side one per plane
  (:func:`~rtdefocus.watch.mend.mend_camera`, :func:`~rtdefocus.watch.mend.mend_projector`).

A burst's result is a new calibration, built whole before the watcher hands it over (the one
in use is never modified), or an error that leaves it as it was.
"""

from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass

import numpy as np

from ..calib.capture import Capturer
from ..calib.file import Calibration
from ..errors import CalibrationError, CaptureError, InputError
from .mend import mend_camera, mend_projector, rescale_radii

log = logging.getLogger(__name__)

__all__ = ["BURSTS", "BurstOptions", "BurstRunner", "Burst", "Replay", "dot_burst",
           "geometry_burst", "fit_kernel_scale", "homographies_mend"]


#: When a focus change gets a dot burst (:attr:`BurstOptions.focus`).
FOCUS_MODES = ("auto", "always", "never")


@dataclass(frozen=True)
class BurstOptions:
    """When the watcher shows pattern bursts, and how long they are.

    Attributes
    ----------
    focus : when a focus change gets a dot burst: ``"auto"`` where the content cannot size it
        (no band-pass level to fit to yet, or no radius scale within [0.5, 2] explains the
        ratio), ``"always"`` on every focus change the content confirms (the band-pass ratio
        moves a little with the content's spectrum; the dots do not), ``"never"``.
    geometry : a geometry burst for a move the content alignment does not mend
        (``geometry_after`` content mends that did not clear it, a mend that could not be
        estimated, or the camera does not see the show as calibrated), or while the model
        is untrusted and the content is too plain to align for ``plain_s`` seconds.
    dot_frames : frames the dot pattern is captured (averaged: the camera's noise).
    dot_spacing : grid step of the dots (projector px; raised where the kernels need more room).
    settle : frames each new pattern is shown before it is captured (the projector-to-camera
        latency in frames: 0 on the virtual set-up, ``ceil(latency · fps) + 1`` on hardware).
    geometry_after : content mends of one geometry change before a burst replaces them.
    plain_s : seconds of looks too plain to align while untrusted before a geometry burst.
    """

    focus: str = "auto"
    geometry: bool = True
    dot_frames: int = 8
    dot_spacing: int = 40
    settle: int = 0
    geometry_after: int = 2
    plain_s: float = 3.0

    @classmethod
    def for_latency(cls, latency_s: float | None, fps: float, **options) -> BurstOptions:
        """Options whose patterns are held ``ceil(latency_s · fps) + 1`` frames before they
        are captured (a camera that sees the wall ``latency_s`` seconds late; None: 0 s)."""
        settle = math.ceil(max(float(latency_s or 0.0), 0.0) * float(fps)) + 1
        return cls(settle=settle, **options)

    def __post_init__(self):
        if self.focus not in FOCUS_MODES:
            raise InputError(f"burst focus must be one of {', '.join(FOCUS_MODES)}; got "
                             f"{self.focus!r}")
        if self.dot_frames < 1 or self.dot_spacing < 8 or self.settle < 0 or \
                self.geometry_after < 1 or not (math.isfinite(self.plain_s) and self.plain_s > 0):
            raise InputError(f"burst options need dot_frames >= 1, dot_spacing >= 8, settle >= 0, "
                             f"geometry_after >= 1 and plain_s > 0; got {self}")


#: The default: bursts on, as :class:`BurstOptions` sets them.
BURSTS = BurstOptions()


def _key(pattern: np.ndarray) -> bytes:
    return hashlib.blake2b(np.ascontiguousarray(pattern).data, digest_size=16).digest()


class Replay:
    """A ProCam that answers a calibration stage with a burst's captures: each pattern's
    captures in the order they were taken, round again when a stage asks for more."""

    def __init__(self, projector_size, camera_size, captured: list[tuple[np.ndarray, np.ndarray]]):
        self.projector_size, self.camera_size = tuple(projector_size), tuple(camera_size)
        self._frames: dict[bytes, list[np.ndarray]] = {}
        for pattern, frame in captured:
            self._frames.setdefault(_key(pattern), []).append(frame)
        self._next: dict[bytes, int] = {}

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        k = _key(pattern)
        frames = self._frames.get(k)
        if not frames:
            raise CaptureError("the burst did not capture this pattern")
        i = self._next.get(k, 0)
        self._next[k] = i + 1
        return frames[i % len(frames)]


class Burst:
    """Pattern frames to show and capture, and what turns their captures into a calibration.

    Parameters
    ----------
    kind : "focus" | "geometry".
    patterns : (pattern, captures) in show order: each (Hp, Wp, 3) uint8 pattern is shown
        ``settle`` frames, then captured ``captures`` times.
    solve : ``solve(calib, replay_capturer) -> (calibration, detail)``.
    settle : see :class:`BurstOptions`.

    Attributes
    ----------
    shown : pattern frames shown so far (the Player showed what :meth:`pattern` returned).
    """

    def __init__(self, kind: str, patterns: list[tuple[np.ndarray, int]], solve, settle: int = 0):
        self.kind = kind
        self.solve_fn = solve
        # frame to show, and whether it is captured
        self.plan = [(p, j >= settle) for p, n in patterns for j in range(settle + n)]
        self.captured: list[tuple[np.ndarray, np.ndarray]] = []
        self.shown = 0
        self.solving = False       # every frame captured; the stage runs on them

    @property
    def frames(self) -> int:
        """Pattern frames the whole burst shows."""
        return len(self.plan)

    @property
    def complete(self) -> bool:
        return self.shown >= len(self.plan)

    def pattern(self) -> np.ndarray | None:
        """The pattern frame to show next (None once all are shown)."""
        return None if self.complete else self.plan[self.shown][0]

    def shows(self, look) -> None:
        """The Player showed :meth:`pattern`: count it, and capture it through ``look`` when
        the plan says so."""
        pattern, capture = self.plan[self.shown]
        self.shown += 1
        if capture:
            self.captured.append((pattern, np.asarray(look(pattern))))

    def solve(self, calib: Calibration) -> tuple[Calibration, dict]:
        """Run the stage on the captures: the new calibration and what was measured."""
        capturer = Capturer(Replay(calib.projector_size, calib.camera_size, self.captured))
        new, detail = self.solve_fn(calib, capturer)
        detail["pattern_frames"] = self.shown
        return new, detail


# ---------------------------------------------------------------------------- focus
def kernel_radii(calib: Calibration, points: np.ndarray) -> np.ndarray:
    """Equivalent disc radius (px) of the calibration's kernel at each projector point (N, 2)
    int: the blend of the kernel field there."""
    from ..calib.psf.dots import equivalent_radius

    return np.array([equivalent_radius(_kernel_at(calib, x, y)) for x, y in points])


def _kernel_at(calib: Calibration, x: int, y: int) -> np.ndarray:
    idx, wts = calib.pix_idx[y, x], calib.pix_wts[y, x]
    return np.tensordot(wts, np.asarray(calib.psfs)[idx], axes=1)


def dot_points(calib: Calibration, spacing: int) -> tuple[np.ndarray, np.ndarray]:
    """Projector points of the burst's dots: a grid of ``spacing`` px, each far enough from
    the frame's edges and the folds for its measuring window, and the kernel radius there.
    The grid is widened where the largest kernel (grown by half: the focus may have widened
    it that much) needs more room between dots."""
    from ..calib.psf.dots import dot_geometry, dot_sizes

    wp, hp = calib.projector_size
    r_max = 1.5 * float(max(kernel_radii(calib, [(wp // 2, hp // 2), (2, 2), (wp - 3, 2),
                                                 (2, hp - 3), (wp - 3, hp - 3)])))
    sup, win = dot_geometry(np.array([r_max]), dot_sizes(np.array([r_max])))
    reach = int(win[0]) + int(math.ceil(sup[0])) + 2
    step = max(int(spacing), reach)
    xs = np.arange(reach, wp - reach, step)
    ys = np.arange(reach, hp - reach, step)
    pts = np.array([(x, y) for y in ys for x in xs], int).reshape(-1, 2)
    if calib.n_planes > 1 and len(pts):
        # On its own plane a point is -(its distance to the plane's nearest fold) outside.
        inside = calib.layout.outside(pts[:, 0].astype(float), pts[:, 1].astype(float))
        pts = pts[inside.min(axis=0) < -reach]
    if len(pts):
        # Only dots the camera sees whole (a moved projector may light beyond its view).
        cam = calib.cam_from_proj(pts[:, 0], pts[:, 1])
        wc, hc = calib.camera_size
        m = 2 * reach
        pts = pts[(cam[:, 0] >= m) & (cam[:, 0] < wc - m) & (cam[:, 1] >= m) & (cam[:, 1] < hc - m)]
    if len(pts) < 3:
        raise InputError(f"a dot burst needs room for at least 3 dots the camera sees; the "
                         f"{wp}x{hp} frame has {len(pts)} (kernels too wide for the frame, or "
                         "the projection outside the camera's view)")
    return pts, kernel_radii(calib, pts)


def fit_kernel_scale(calib: Calibration, points: np.ndarray, measured: list,
                     lo: float = 0.5, hi: float = 2.0) -> tuple[float, float]:
    """The one radius scale ``s`` whose kernels (:func:`~rtdefocus.watch.mend.rescale_radii`) best
    explain the kernels ``measured`` at ``points`` (unit-sum, unclipped least-squares
    kernels, each centred on its dot): least squares over all dots' kernel pixels, so the
    measurement's zero-mean noise does not bias it. Returns (s, relative rms left)."""
    from scipy.optimize import minimize_scalar

    def cost(log_s: float) -> float:
        c = calib if log_s == 0.0 else rescale_radii(calib, math.exp(log_s))
        err = 0.0
        for (x, y), k in zip(points, measured, strict=True):
            err += float(np.sum((k - _centred(_kernel_at(c, x, y), k.shape[0])) ** 2))
        return err

    res = minimize_scalar(cost, bounds=(math.log(lo), math.log(hi)), method="bounded",
                          options={"xatol": 2e-3})
    total = float(sum(np.sum(k ** 2) for k in measured))
    return float(math.exp(res.x)), math.sqrt(float(res.fun) / max(total, 1e-12))


def _centred(k: np.ndarray, n: int) -> np.ndarray:
    """``k`` (odd square) cropped or zero-padded to n × n about its centre."""
    out = np.zeros((n, n), np.float64)
    h, hk = n // 2, k.shape[0] // 2
    m = min(h, hk)
    out[h - m:h + m + 1, h - m:h + m + 1] = k[hk - m:hk + m + 1, hk - m:hk + m + 1]
    return out


def dot_burst(calib: Calibration, options: BurstOptions | None = None) -> Burst:
    """A focus burst: the PSF stage's dots on a grid, captured ``dot_frames`` times (one
    pattern where the dots' windows fit; more where they do not), then one kernel radius scale
    fitted to the measured kernels (:func:`fit_kernel_scale`)."""
    from ..calib.psf.dots import dot_geometry, dot_sizes, pack_patterns

    o = options or BurstOptions()
    if not calib.has_psf:
        raise InputError("a dot burst re-measures the calibration's kernels: it has none "
                         "(run the PSF stage)")
    points, radius = dot_points(calib, o.dot_spacing)
    # The kernels' support may have grown: the dots are planned for kernels half as wide again.
    pred = 1.5 * np.maximum(radius, 0.5)
    dots = dot_sizes(pred)
    sup, win = dot_geometry(pred, dots)
    groups = pack_patterns(points, sup, win)
    wp, hp = calib.projector_size
    patterns = []
    for pat in groups:
        img = np.zeros((hp, wp, 3), np.uint8)
        for i in pat:
            x, y = points[i]
            d = int(dots[i])
            o0 = -(d // 2)                 # as measure_psfs draws it
            img[max(y + o0, 0):y + o0 + d, max(x + o0, 0):x + o0 + d] = 255
        patterns.append((img, o.dot_frames))

    def solve(calib: Calibration, capture: Capturer) -> tuple[Calibration, dict]:
        from ..calib.psf.dots import measure_psfs

        meas = measure_psfs(calib, capture, points, pred, averages=o.dot_frames,
                            camera_lut=calib.camera_lut)
        ok = ~np.asarray(meas.skipped, bool) if meas.skipped is not None else \
            np.ones(len(points), bool)
        if ok.sum() < 3:
            raise CalibrationError(f"the dot burst saw {int(ok.sum())} of {len(points)} dots "
                                   "(too faint): the kernels were not re-measured")
        scale, left = fit_kernel_scale(calib, points[ok], [meas.raw[i] for i in np.flatnonzero(ok)])
        detail = {"kernel_scale": round(scale, 4), "dots": int(ok.sum()),
                  "fit_left": round(left, 4)}
        return rescale_radii(calib, scale), detail

    return Burst("focus", patterns, solve, o.settle)


# ---------------------------------------------------------------------------- geometry
def geometry_burst(calib: Calibration, options: BurstOptions | None = None) -> Burst:
    """A geometry burst: the geometry stage's patterns (lines and Gray code), each shown once,
    and the stage's fit with the calibration's lens and plane count; the mend that takes the
    old homographies to the new ones (:func:`homographies_mend`)."""
    from ..calib.geometry.lens import lens_k
    from ..calib.geometry.stage import GeometryOptions
    from ..calib.geometry.structured_light import LinePatterns

    o = options or BurstOptions()
    go = GeometryOptions()
    pats = LinePatterns(tuple(calib.projector_size), go.line_spacing, go.line_phases, go.line_width)
    patterns = [(p, 1) for _, p in pats.sequence()]
    lens = lens_k(calib) or (0.0, 0.0)

    def solve(calib: Calibration, capture: Capturer) -> tuple[Calibration, dict]:
        from ..calib.geometry import calibrate_geometry

        fresh = calibrate_geometry(None, capture, go, planes=calib.n_planes,
                                   lens=tuple(float(v) for v in lens),
                                   residual=calib.residual_cam is not None)
        return homographies_mend(calib, fresh.H_cam_from_proj)

    return Burst("geometry", patterns, solve, o.settle)


def homographies_mend(calib: Calibration, H_new: np.ndarray, tol_px: float = 0.5
                      ) -> tuple[Calibration, dict]:
    """The calibration moved so that plane p's homography becomes ``H_new[p]``: one camera
    homography for all planes when one explains them all within ``tol_px`` camera px (the
    camera moved: the projector-space maps stay), else one projector-side correction per
    plane (the projector moved: the maps move with the wall)."""
    H_old = np.asarray(calib.H_cam_from_proj, np.float64)
    H_new = np.asarray(H_new, np.float64)
    if H_new.shape != H_old.shape:
        raise CalibrationError(f"the geometry burst found {len(H_new)} plane(s), the calibration "
                               f"has {len(H_old)}: re-calibrate (`rtdefocus calibrate`)")
    C = np.stack([h @ np.linalg.inv(g) for h, g in zip(H_new, H_old, strict=True)])
    C /= C[:, 2:3, 2:3]
    wp, hp = calib.projector_size
    xs, ys = np.meshgrid(np.linspace(0, wp - 1, 5), np.linspace(0, hp - 1, 5))
    pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)], axis=1)
    C_mean = C.mean(axis=0)
    spread = 0.0
    for p in range(len(H_old)):
        q = pts @ H_old[p].T
        a, b = q @ C[p].T, q @ C_mean.T
        spread = max(spread, float(np.max(np.hypot(*(a[:, :2] / a[:, 2:] - b[:, :2] / b[:, 2:]).T))))
    moved_px = float(np.max([np.max(np.hypot(*((pts @ h.T)[:, :2] / (pts @ h.T)[:, 2:]
                                                 - (pts @ g.T)[:, :2] / (pts @ g.T)[:, 2:]).T))
                             for h, g in zip(H_new, H_old, strict=True)]))
    detail = {"moved_cam_px": round(moved_px, 3), "spread_px": round(spread, 4)}
    if spread < tol_px:
        detail["moved"] = "camera"
        return mend_camera(calib, C_mean), detail
    detail["moved"] = "projector"
    M = np.stack([np.linalg.inv(g) @ h for h, g in zip(H_new, H_old, strict=True)])
    return mend_projector(calib, M / M[:, 2:3, 2:3]), detail


# ---------------------------------------------------------------------------- the watcher's side
class BurstRunner:
    """The burst a :class:`~rtdefocus.watch.Watcher` is showing, if any, and when one is due.

    Parameters
    ----------
    options : :class:`BurstOptions` (None: no burst is ever started).
    """

    def __init__(self, options: BurstOptions | None):
        self.options = options
        self.burst: Burst | None = None
        #: The Player took the burst's frame (:meth:`pattern`) to show it next.
        self.asked = False
        self._plain_since: float | None = None

    def start(self, kind: str, calib: Calibration, t: float) -> Burst | None:
        """Plan a burst of ``kind`` ("focus" | "geometry") when the options allow one and none
        is running; logs a warning saying so. Returns it, or None."""
        o = self.options
        allowed = o and (o.geometry if kind == "geometry" else o.focus != "never")
        if not allowed or self.burst is not None:
            return None
        try:
            self.burst = (dot_burst if kind == "focus" else geometry_burst)(calib, o)
        except (InputError, CalibrationError) as exc:
            log.warning("no %s burst: %s", kind, exc)
            return None
        log.warning("watch %.2f s: the %s change is re-measured by a burst of %d pattern frames "
                    "shown instead of the content", t, kind, self.burst.frames)
        return self.burst

    def pattern(self) -> np.ndarray | None:
        """The burst's next frame for the Player to show (it then offers it), or None."""
        frame = self.burst.pattern() if self.burst is not None else None
        self.asked = frame is not None
        return frame

    def offered(self, look) -> Burst | None:
        """A frame was shown during the burst: when it was the burst's, count and capture it
        (through ``look``). Returns the burst once every frame is captured (once)."""
        b = self.burst
        if self.asked and not b.complete:
            self.asked = False
            b.shows(look)
        if b.complete and not b.solving:
            b.solving = True
            return b
        return None

    def done(self) -> None:
        """The burst's result was handed over (or it failed): no burst is running."""
        self.burst = None

    def plain_too_long(self, plain: bool, t: float) -> bool:
        """Whether a geometry burst is due: ``plain`` (the model untrusted and the look too
        plain to align) on every look for ``plain_s`` seconds."""
        if not plain or not self.options:
            self._plain_since = None
            return False
        if self._plain_since is None:
            self._plain_since = t
        if t - self._plain_since >= self.options.plain_s:
            self._plain_since = None
            return True
        return False
