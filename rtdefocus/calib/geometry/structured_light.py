"""Structured light for the geometry stage: line patterns, Gray-code labels, sub-pixel ridges.

What is projected (DESIGN.md §4, paper §3.1). With line spacing ``S`` (projector px), ``K``
phases and line width ``w``:

* a black and a white frame (normalisation: ``(I - B) / (W - B)`` cancels ambient light,
  albedo, shading and exposure; binary patterns are immune to the projector's response curve);
* for each phase ``p`` a pattern of vertical lines centred at ``x = k S + (p + 1/2) S / K`` and
  one of horizontal lines at ``y = k S + (p + 1/2) S / K`` (so the union of the phases has a
  line every ``S / K`` px over the whole frame, while lines of one pattern stay ``S`` px apart
  and never merge however blurred);
* a Gray code of the *stripe* index ``k = floor(x / S)`` (and of ``floor(y / S)``): a ridge
  found in a line image is named by the stripe it lies in. Lines sit ``S / (2K)`` px or more from
  every stripe boundary, so the label is read far from any Gray-code edge;
* the white frame again at the end: if it moved, the set-up moved during calibration.

Captures: ``3 + 2K + ceil(log2(ceil(Wp/S))) + ceil(log2(ceil(Hp/S)))`` — 20 with the defaults
(S = 48, K = 4) at 800×600 (:func:`LinePatterns.count`).

Detection works on the normalised image of each line pattern: along every camera row (vertical
lines) or column (horizontal lines) the local maxima are found, and each is refined to the
centroid of the part of its profile above 30 % of the peak — the centre of a symmetric profile,
whatever its width, height or the camera's response (no threshold edge is ever used as a
position). Each ridge point takes the Gray-code label read at its pixel; a running median per
label drops the few mislabelled points.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ...errors import CalibrationError, InputError
from ...graycode import decode_gray, gray_code_bit
from ...imageio import to_grey

log = logging.getLogger(__name__)

__all__ = [
    "LinePatterns", "DetectedLine", "LineDetection", "normalise",
    "find_ridge_points", "LineDetector", "image_shift",
]


@dataclass(frozen=True)
class LinePatterns:
    """The geometry stage's pattern set for one projector.

    Parameters
    ----------
    projector_size : (width, height) in projector px.
    spacing : distance ``S`` between the lines of one pattern (projector px); must exceed
        twice the largest blur diameter so neighbouring ridges stay apart.
    phases : number ``K`` of shifted copies per direction; the union has a line every ``S / K`` px.
    width : line width in projector px (1..3 are sensible).
    """

    projector_size: tuple[int, int]
    spacing: int = 48
    phases: int = 4
    width: int = 3

    def __post_init__(self):
        if self.phases < 1 or self.width < 1 or self.spacing < 2 * self.phases * max(2, self.width):
            raise InputError(f"line patterns need phases >= 1, width >= 1 and spacing >= "
                             f"2 * phases * max(2, width) so lines clear the Gray-code edges; got "
                             f"spacing={self.spacing}, phases={self.phases}, width={self.width}")
        if min(self.projector_size) < 2 * self.spacing:
            raise InputError(f"line spacing {self.spacing} px is too large for a "
                             f"{self.projector_size[0]}x{self.projector_size[1]} projector")

    # ------------------------------------------------------------------ layout
    def extent(self, axis: str) -> int:
        """Projector extent across the lines: width for vertical lines ("v"), height for "h"."""
        return self.projector_size[0] if axis == "v" else self.projector_size[1]

    def n_stripes(self, axis: str) -> int:
        return math.ceil(self.extent(axis) / self.spacing)

    def n_bits(self, axis: str) -> int:
        return max(1, math.ceil(math.log2(self.n_stripes(axis))))

    def first_pixel(self, phase: int) -> int:
        """Offset (in a stripe) of the first pixel of a line of this phase."""
        centre = (phase + 0.5) * self.spacing / self.phases
        return int(round(centre - (self.width - 1) / 2.0))

    def centre(self, stripe: int, phase: int) -> float:
        """Projector coordinate of the centre of line (stripe, phase); pixel centres at integers."""
        return stripe * self.spacing + self.first_pixel(phase) + (self.width - 1) / 2.0

    def lines(self, axis: str, phase: int) -> list[tuple[int, float]]:
        """(stripe, centre) of every line of this phase that lies wholly inside the frame."""
        n = self.extent(axis)
        out = []
        for k in range(self.n_stripes(axis)):
            first = k * self.spacing + self.first_pixel(phase)
            if first >= 0 and first + self.width <= n:
                out.append((k, self.centre(k, phase)))
        return out

    def n_lines(self, axis: str) -> int:
        return sum(len(self.lines(axis, p)) for p in range(self.phases))

    # ------------------------------------------------------------------ images
    def _full(self, profile: np.ndarray, axis: str) -> np.ndarray:
        wp, hp = self.projector_size
        img = np.broadcast_to(profile[None, :], (hp, wp)) if axis == "v" \
            else np.broadcast_to(profile[:, None], (hp, wp))
        return np.repeat(np.ascontiguousarray(img)[:, :, None], 3, axis=2)

    def line_pattern(self, axis: str, phase: int) -> np.ndarray:
        """(Hp, Wp, 3) uint8: white lines of one phase on black ("v": vertical lines)."""
        prof = np.zeros(self.extent(axis), np.uint8)
        for k, _ in self.lines(axis, phase):
            first = k * self.spacing + self.first_pixel(phase)
            prof[first:first + self.width] = 255
        return self._full(prof, axis)

    def gray_pattern(self, axis: str, bit: int) -> np.ndarray:
        """(Hp, Wp, 3) uint8: bit ``bit`` (0 = most significant) of the Gray code of the stripe."""
        k = np.arange(self.extent(axis)) // self.spacing
        prof = (gray_code_bit(k, bit, self.n_bits(axis)) * 255).astype(np.uint8)
        return self._full(prof, axis)

    def solid(self, value: int) -> np.ndarray:
        wp, hp = self.projector_size
        return np.full((hp, wp, 3), value, np.uint8)

    def sequence(self) -> list[tuple[str, np.ndarray]]:
        """The patterns in capture order, as (name, (Hp, Wp, 3) uint8).

        Names: ``black``, ``white``, ``v{p}`` / ``h{p}`` (line phases, interleaved so a set-up
        that moves part-way leaves the two families inconsistent), ``gv{b}`` / ``gh{b}``
        (Gray-code bits) and ``white_end`` (stability check).
        """
        seq = [("black", self.solid(0)), ("white", self.solid(255))]
        for p in range(self.phases):
            seq.append((f"v{p}", self.line_pattern("v", p)))
            seq.append((f"h{p}", self.line_pattern("h", p)))
        for axis in ("v", "h"):
            seq += [(f"g{axis}{b}", self.gray_pattern(axis, b)) for b in range(self.n_bits(axis))]
        seq.append(("white_end", self.solid(255)))
        return seq

    def count(self) -> int:
        """Number of patterns in :meth:`sequence`."""
        return 3 + 2 * self.phases + self.n_bits("v") + self.n_bits("h")


# --------------------------------------------------------------------------- image helpers
def normalise(img: np.ndarray, black: np.ndarray, white: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``(I - B) / (W - B)`` on the valid pixels, 0 elsewhere; (H, W) float32.

    1 where the projector's full white reaches, 0 where only black does — independent of the
    wall's albedo, the shading, ambient light and the camera's exposure.
    """
    den = np.where(valid, white - black, 1.0)
    out = (img - black) / den
    out[~valid] = 0.0
    return out.astype(np.float32)


def find_ridge_points(norm: np.ndarray, valid: np.ndarray, half: int, min_peak: float = 0.06,
                      frac: float = 0.3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel ridge centres along every row of a normalised line image.

    Parameters
    ----------
    norm : (H, W) float32 normalised image; ridges run roughly along the columns (across rows).
    valid : (H, W) bool, pixels the projector lights well enough to measure.
    half : half-window (px): larger than the blurred line's half-width, smaller than half the
        distance between two lines of the pattern.
    min_peak : smallest accepted peak height (normalised units).
    frac : the centroid uses the part of the profile above ``frac`` × peak, contiguous with it.

    Returns
    -------
    rows : (n,) int32 row of each ridge point.
    cols : (n,) float64 sub-pixel column of the ridge centre.
    peak : (n,) float32 peak height.
    """
    # scipy loads on first use (~1 s): `import rtdefocus.calib` (the player loads Calibration) stays fast.
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    h, w = norm.shape
    # Smooth a little across (σ 0.8) and more along (σ 1.5) the ridge: symmetric kernels keep
    # the centre of a symmetric profile where it is and take out most of the camera noise.
    sm = cv2.GaussianBlur(norm, (0, 0), sigmaX=0.8, sigmaY=1.5)
    size = 2 * half + 1
    mx = maximum_filter1d(sm, size, axis=1, mode="constant", cval=0.0)
    mn = minimum_filter1d(sm, size, axis=1, mode="nearest")
    left = np.empty_like(sm)
    left[:, 1:] = sm[:, :-1]
    left[:, 0] = np.inf
    cand = (sm >= mx) & (sm > left) & (sm > min_peak) & valid & (sm - mn > 0.5 * sm)
    cand[:, :half] = False
    cand[:, w - half:] = False
    rows, cols = np.nonzero(cand)
    if rows.size == 0:
        return rows.astype(np.int32), cols.astype(np.float64), np.zeros(0, np.float32)
    offs = np.arange(-half, half + 1)
    win = sm[rows[:, None], cols[:, None] + offs[None, :]]
    pk = sm[rows, cols]
    wt = np.clip(win - frac * pk[:, None], 0.0, None)
    # Only the run of above-threshold samples that contains the peak (not a neighbour's tail).
    pos = wt > 0
    right_run = np.cumprod(pos[:, half:], axis=1)
    left_run = np.cumprod(pos[:, half::-1], axis=1)[:, ::-1]
    keep = np.concatenate([left_run[:, :-1], right_run], axis=1).astype(bool)
    wt = np.where(keep, wt, 0.0)
    s = wt.sum(axis=1)
    ok = s > 0
    sub = (wt * offs[None, :]).sum(axis=1) / np.where(ok, s, 1.0)
    return (rows[ok].astype(np.int32), cols[ok] + sub[ok].astype(np.float64),
            pk[ok].astype(np.float32))


def image_shift(a: np.ndarray, b: np.ndarray, iterations: int = 8, sigma: float = 2.0):
    """Global translation between two views of the same scene: ``b(x) ≈ g · a(x − d) + o``.

    Gauss–Newton on smoothed images (Lucas–Kanade for one translation plus a gain and an offset
    for exposure changes); noise averages out over the whole frame, unlike phase correlation,
    which whitens the spectrum and lets pixel noise pick the peak.

    Parameters
    ----------
    a, b : (H, W) float images (camera codes).

    Returns
    -------
    (dx, dy) : float camera px; gain, offset : floats.
    """
    step = 2                      # half resolution: plenty of edge pixels, 4x less work
    A = cv2.GaussianBlur(np.asarray(a, np.float32), (0, 0), sigma)[::step, ::step]
    B = cv2.GaussianBlur(np.asarray(b, np.float32), (0, 0), sigma)[::step, ::step]
    d = np.zeros(2)
    g, o = 1.0, 0.0
    h, w = A.shape
    for _ in range(iterations):
        m = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        Aw = cv2.warpAffine(A, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        gx = cv2.Sobel(Aw, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        gy = cv2.Sobel(Aw, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        # b ≈ g·Aw + o − g∇Aw·δ: unknowns (g, o, δx, δy), linear least squares
        J = np.stack([Aw.ravel(), np.ones(Aw.size, np.float32), -g * gx.ravel(), -g * gy.ravel()], 1)
        JtJ = J.T.astype(np.float64) @ J
        sol = np.linalg.lstsq(JtJ, J.T.astype(np.float64) @ B.ravel(), rcond=None)[0]
        g, o = float(sol[0]), float(sol[1])
        delta = sol[2:]
        d += delta
        if np.hypot(*delta) < 1e-3 or not np.isfinite(d).all():
            break
    return (float(d[0]) * step, float(d[1]) * step), g, o


# --------------------------------------------------------------------------- results
@dataclass
class DetectedLine:
    """One projected line as seen by the camera.

    Attributes
    ----------
    axis : "v" (a projector column, ``x = coord``) or "h" (a projector row, ``y = coord``).
    coord : projector coordinate of the line centre (px).
    t : (n,) int32 camera row ("v") or column ("h") of each sample, increasing.
    s : (n,) float64 sub-pixel camera column ("v") or row ("h") of the ridge on that row/column.
    """

    axis: str
    coord: float
    t: np.ndarray
    s: np.ndarray

    @property
    def pts_cam_xy(self) -> np.ndarray:
        """(n, 2) float64 camera points (x, y) along the line."""
        if self.axis == "v":
            return np.stack([self.s, self.t.astype(np.float64)], axis=1)
        return np.stack([self.t.astype(np.float64), self.s], axis=1)


@dataclass
class LineDetection:
    """All lines found, plus what the diagnostics need.

    Attributes
    ----------
    lines : list of :class:`DetectedLine` ("v" and "h").
    expected : {"v": n, "h": n} lines projected per family.
    white, black : (Hc, Wc) float32 grey camera frames (code values).
    valid : (Hc, Wc) bool, pixels lit well enough to measure.
    white_rgb : (Hc, Wc, 3) uint8 camera view of the white frame.
    stats : dict of numbers for the log and ``meta``.
    """

    lines: list[DetectedLine]
    expected: dict
    white: np.ndarray
    black: np.ndarray
    valid: np.ndarray
    white_rgb: np.ndarray
    stats: dict = field(default_factory=dict)

    def family(self, axis: str) -> list[DetectedLine]:
        return [ln for ln in self.lines if ln.axis == axis]


# --------------------------------------------------------------------------- detector
class LineDetector:
    """Consumes the captures of :meth:`LinePatterns.sequence` one by one (so only the black,
    white and ridge lists are kept, never the whole stack) and produces a :class:`LineDetection`.

    Parameters
    ----------
    patterns : the :class:`LinePatterns` that were projected.
    min_contrast : smallest white-minus-black difference (camera codes) counted as lit.
    min_peak : smallest ridge height in the normalised image.
    max_shift : largest camera shift (px) between the first and the last white frame before
        calibration stops with "the set-up moved".
    """

    def __init__(self, patterns: LinePatterns, *, min_contrast: float = 8.0, min_peak: float = 0.06,
                 max_shift: float = 0.5):
        self.patterns = patterns
        self.min_contrast = float(min_contrast)
        self.min_peak = float(min_peak)
        self.max_shift = float(max_shift)
        self.black: np.ndarray | None = None
        self.white: np.ndarray | None = None
        self.white_rgb: np.ndarray | None = None
        self.valid: np.ndarray | None = None
        self.half = 12
        self._ridges: dict[str, tuple] = {}
        self._bits: dict[str, list] = {"v": [], "h": []}
        self.stats: dict = {}

    # ------------------------------------------------------------------ feeding
    def add(self, name: str, frame: np.ndarray) -> None:
        """Hand over the capture of pattern ``name`` ((Hc, Wc, 3) uint8 or float codes)."""
        grey = to_grey(frame)
        if name == "black":
            self.black = grey
        elif name == "white":
            self.white = grey
            self.white_rgb = np.clip(np.asarray(frame), 0, 255).astype(np.uint8)
            self._check_light()
        elif name == "white_end":
            self._check_stable(grey)
        elif name[0] in "vh" and name[1:].isdigit():
            self._add_lines(name[0], int(name[1:]), grey)
        elif name[0] == "g" and name[1] in "vh":
            nrm = normalise(grey, self.black, self.white, self.valid)
            self._bits[name[1]].append(nrm > 0.5)
        else:
            raise InputError(f"unknown geometry pattern name {name!r}")

    def _check_light(self) -> None:
        if self.black is None:
            raise InputError("the black frame must be captured before the white one")
        diff = self.white - self.black
        hi = float(np.percentile(diff, 99.5))
        self.stats["white_minus_black_p99"] = round(hi, 1)
        if hi < 2 * self.min_contrast:
            raise CalibrationError(
                f"the camera sees no projector light: the white frame is at most {hi:.1f} codes "
                f"brighter than the black one (need well over {2 * self.min_contrast:.0f}). Check that "
                "the projector is on and shows the calibration window full-screen on the right "
                "display, that the camera looks at the projected area (lens cap off), and that the "
                "exposure is not so low that the picture is black or so high that both are white.")
        # Lit well enough: above the absolute floor and a fair share of the brightest part
        # (shading and albedo vary, but not by 5x inside one set-up).
        valid = diff > max(self.min_contrast, 0.2 * hi)
        valid = cv2.erode(valid.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        frac = float(valid.mean())
        self.stats["lit_fraction"] = round(frac, 4)
        if frac < 0.01:
            raise CalibrationError(
                f"the projector lights only {100 * frac:.2f} % of the camera view (white minus black "
                f"> {max(self.min_contrast, 0.2 * hi):.0f} codes); point the camera at the projected "
                "area so it fills a good part of the frame")
        self.valid = valid
        self._ridge_white = None
        # Window half-width for the ridges: a third of the camera distance between two lines of
        # one pattern, from the camera's mean magnification (lit area / projector area).
        wp, hp = self.patterns.projector_size
        mag = math.sqrt(valid.sum() / (wp * hp))
        self.half = int(np.clip(round(0.3 * self.patterns.spacing * mag), 4, 40))
        self.stats["magnification"] = round(mag, 3)

    def _check_stable(self, white_end: np.ndarray) -> None:
        (dx, dy), gain, offset = image_shift(self.white, white_end)
        shift = math.hypot(dx, dy)
        # What differs beyond an exposure change (gain, offset), relative to the contrast:
        # something moved into the beam, the projector dimmed, ...
        a, b = self.white[self.valid], white_end[self.valid]
        changed = float(np.mean(np.abs(b - (gain * a + offset))) /
                        max(float(np.mean(a - self.black[self.valid])), 1e-6))
        self.stats["white_shift_px"] = round(shift, 3)
        self.stats["white_change"] = round(changed, 4)
        if shift > self.max_shift or changed > 0.15:
            raise CalibrationError(
                f"the set-up moved during calibration: the white frame at the end is shifted by "
                f"{shift:.1f} camera px ({dx:+.1f}, {dy:+.1f}) and differs by {100 * changed:.0f} % "
                "from the one at the start. Fix the camera and the projector firmly (tripod, no "
                "auto-focus or image stabilisation), keep the room still, and calibrate again.")

    def _add_lines(self, axis: str, phase: int, grey: np.ndarray) -> None:
        if self.valid is None:
            raise InputError("the black and white frames must be captured before the line patterns")
        if self._ridge_white is None:
            # The white frame dims within a blur radius of the projector frame's edge, but a
            # line's own light does not: dividing by it there would push the ridges of the
            # outermost lines outwards. Normalise ridges by the white level spread over the ridge
            # window instead (a grey dilation), which keeps the slow shading gradient.
            k = 2 * self.half + 1
            diff = np.where(self.valid, self.white - self.black, 0).astype(np.float32)
            wide = cv2.dilate(diff, np.ones((k, k), np.uint8))
            self._ridge_white = self.black + np.maximum(wide, self.white - self.black)
        nrm = normalise(grey, self.black, self._ridge_white, self.valid)
        if axis == "h":   # horizontal lines: scan the columns of the transposed image
            rows, cols, pk = find_ridge_points(np.ascontiguousarray(nrm.T),
                                               np.ascontiguousarray(self.valid.T), self.half,
                                               self.min_peak)
        else:
            rows, cols, pk = find_ridge_points(nrm, self.valid, self.half, self.min_peak)
        self._ridges[f"{axis}{phase}"] = (rows, cols, pk)

    # ------------------------------------------------------------------ result
    def result(self) -> LineDetection:
        """Label the ridge points with the Gray code and clean each line; see :class:`LineDetection`."""
        pats = self.patterns
        stripe = {}
        for axis in ("v", "h"):
            if len(self._bits[axis]) != pats.n_bits(axis):
                raise InputError(f"expected {pats.n_bits(axis)} Gray-code bits for {axis!r}, "
                                 f"got {len(self._bits[axis])}")
            stripe[axis] = decode_gray(self._bits[axis])
        lines: list[DetectedLine] = []
        expected = {}
        n_points = n_dropped = 0
        for axis in ("v", "h"):
            expected[axis] = pats.n_lines(axis)
            for p in range(pats.phases):
                rows, cols, _ = self._ridges[f"{axis}{p}"]
                ci = np.clip(np.rint(cols).astype(np.int64), 0, None)
                # The stripe map is indexed (row, col) of the camera; for "h" the ridge arrays
                # are in the transposed frame: t = camera column, s = camera row.
                if axis == "v":
                    lab = stripe["v"][rows, np.minimum(ci, stripe["v"].shape[1] - 1)]
                else:
                    lab = stripe["h"][np.minimum(ci, stripe["h"].shape[0] - 1), rows]
                for k, centre in pats.lines(axis, p):
                    sel = lab == k
                    t, s = rows[sel], cols[sel]
                    n_points += t.size
                    t, s, dropped = _clean_line(t, s)
                    n_dropped += dropped
                    if t.size >= 20:
                        lines.append(DetectedLine(axis, centre, t, s))
        self.stats.update(points=int(n_points), dropped_points=int(n_dropped),
                          lines_found={a: sum(ln.axis == a for ln in lines) for a in ("v", "h")},
                          lines_expected=expected)
        for axis, name in (("v", "vertical"), ("h", "horizontal")):
            found = sum(ln.axis == axis for ln in lines)
            if found < max(4, 0.3 * expected[axis]):
                raise CalibrationError(
                    f"only {found} of the {expected[axis]} projected {name} lines were found in the "
                    f"camera images ({n_points} ridge points in all). Check that the camera is in "
                    "focus and sees the whole projected area, that nothing blocks the projector, "
                    "that the exposure does not saturate the white frame, and that the projector "
                    "is not so defocused that lines 48 px apart merge (increase line_spacing).")
        log.info("structured light: %d/%d vertical and %d/%d horizontal lines, %d ridge points "
                 "(%d dropped as mislabelled)", self.stats["lines_found"]["v"], expected["v"],
                 self.stats["lines_found"]["h"], expected["h"], n_points, n_dropped)
        return LineDetection(lines=lines, expected=expected, white=self.white, black=self.black,
                             valid=self.valid, white_rgb=self.white_rgb, stats=dict(self.stats))


def _clean_line(t: np.ndarray, s: np.ndarray, window: int = 15, tol: float = 2.0):
    """Keep one ridge point per row that follows the line; returns (t, s, n_dropped)."""
    # scipy loads on first use (~1 s): `import rtdefocus.calib` (the player loads Calibration) stays fast.
    from scipy.ndimage import median_filter

    n0 = t.size
    if n0 < 5:
        return t[:0], s[:0], n0
    order = np.lexsort((s, t))
    t, s = t[order], s[order]
    med = median_filter(s, size=min(window, n0 | 1), mode="mirror")
    err = np.abs(s - med)
    good = err < tol
    t, s, err = t[good], s[good], err[good]
    # Several points on one row: keep the one nearest the running median.
    order = np.lexsort((err, t))
    t, s = t[order], s[order]
    first = np.ones(t.size, bool)
    first[1:] = t[1:] != t[:-1]
    t, s = t[first], s[first]
    return t.astype(np.int32), s.astype(np.float64), n0 - t.size
