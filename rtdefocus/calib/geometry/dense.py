"""Dense structured light: every lit camera pixel's projector coordinates, to a fraction of a
pixel, with a validity mask (Gray code plus phase shift, in both directions).

What is projected, per projector axis (``x``: patterns that vary along the projector's columns,
``y``: along its rows), with period ``P`` and ``N`` phase steps:

* ``N`` sinusoids ``v = 127.5 + 127.5 cos(2π x / P − 2π k / N)``, k = 0 .. N − 1: their phase
  ``φ = atan2(Σ I_k sin δ_k, Σ I_k cos δ_k)`` is ``2π x / P`` modulo 2π, whatever the wall's
  albedo, shading, ambient light or the blur (a symmetric blur lowers a sinusoid's amplitude,
  not its phase); harmonics of the projector's and the camera's response curves alias into
  the phase only from order ``N − 1`` up, which is negligible at ``N = 8``;
* the Gray code (:mod:`rtdefocus.graycode`) of the *half-period* stripe ``q = floor(x / (P/2))``:
  it picks the period. The stripe centre is within ``P/4`` of the truth, and within
  ``P/4`` + the edge's blur where the camera reads a neighbouring stripe at its edge, so
  ``round((x_stripe − x_phase) / P)`` names the period even on Gray-code edges.

The black and white frames are the line patterns' (:mod:`.structured_light`): the images are
normalised the same way. Captures: ``2 (N + bits)`` more, 28 with the defaults at 800×600
(:meth:`DensePatterns.count`).

A pixel is valid where both phases have a modulation of at least :data:`MIN_MODULATION` of the
white-minus-black contrast, the Gray code and the phase agree on the position within ``3P/8``,
and the position is within :data:`MAX_MEDIAN_DEVIATION` of its 5 × 5 neighbourhood's median (a
misread high bit moves it by whole periods); elsewhere (a far wall blurred flat, a shadow, the
unlit frame) the map says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ...errors import InputError
from ...graycode import decode_gray, gray_code_bit
from ...imageio import to_grey
from .structured_light import normalise

__all__ = ["DensePatterns", "DenseMap", "DenseDecoder", "MIN_MODULATION", "MAX_MEDIAN_DEVIATION",
           "decode_phase"]

#: Smallest phase modulation (its amplitude over the white-minus-black contrast) of a valid pixel.
MIN_MODULATION = 0.12
#: Largest distance (projector px) of a valid pixel's coordinate from its 5 × 5 median.
MAX_MEDIAN_DEVIATION = 2.0


@dataclass(frozen=True)
class DensePatterns:
    """The dense patterns for one projector.

    Parameters
    ----------
    projector_size : (width, height) projector px.
    period : sinusoid period ``P`` (projector px, even); longer than about 4 × the largest blur
        radius keeps a good modulation.
    steps : phase steps ``N`` per axis (>= 3).
    """

    projector_size: tuple[int, int]
    period: int = 32
    steps: int = 8

    def __post_init__(self):
        if self.steps < 3 or self.period < 8 or self.period % 2:
            raise InputError(f"dense patterns need steps >= 3 and an even period >= 8 px; got "
                             f"period={self.period}, steps={self.steps}")
        if min(self.projector_size) < self.period:
            raise InputError(f"dense pattern period {self.period} px is too large for a "
                             f"{self.projector_size[0]}x{self.projector_size[1]} projector")

    def extent(self, axis: str) -> int:
        """Projector width ("x") or height ("y")."""
        return self.projector_size[0] if axis == "x" else self.projector_size[1]

    def n_bits(self, axis: str) -> int:
        """Gray-code bits of the half-period stripe index along ``axis``."""
        return max(1, math.ceil(math.log2(math.ceil(self.extent(axis) / (self.period // 2)))))

    def _full(self, profile: np.ndarray, axis: str) -> np.ndarray:
        wp, hp = self.projector_size
        img = np.broadcast_to(profile[None, :], (hp, wp)) if axis == "x" \
            else np.broadcast_to(profile[:, None], (hp, wp))
        return np.repeat(np.ascontiguousarray(img)[:, :, None], 3, axis=2)

    def phase_pattern(self, axis: str, step: int) -> np.ndarray:
        """(Hp, Wp, 3) uint8 sinusoid of phase step ``step`` along ``axis``."""
        x = np.arange(self.extent(axis), dtype=np.float64)
        v = 127.5 + 127.5 * np.cos(2 * np.pi * x / self.period - 2 * np.pi * step / self.steps)
        return self._full(np.clip(np.rint(v), 0, 255).astype(np.uint8), axis)

    def code_pattern(self, axis: str, bit: int) -> np.ndarray:
        """(Hp, Wp, 3) uint8 bit ``bit`` (0 = most significant) of the half-period stripe's
        Gray code along ``axis``."""
        q = np.arange(self.extent(axis)) // (self.period // 2)
        return self._full((gray_code_bit(q, bit, self.n_bits(axis)) * 255).astype(np.uint8), axis)

    def sequence(self) -> list[tuple[str, np.ndarray]]:
        """The patterns in capture order, as (name, (Hp, Wp, 3) uint8): ``dp{axis}{k}`` (phase
        steps), ``dg{axis}{b}`` (Gray-code bits), axis "x" then "y"."""
        seq = []
        for axis in ("x", "y"):
            seq += [(f"dp{axis}{k}", self.phase_pattern(axis, k)) for k in range(self.steps)]
            seq += [(f"dg{axis}{b}", self.code_pattern(axis, b)) for b in range(self.n_bits(axis))]
        return seq

    def count(self) -> int:
        """Number of patterns in :meth:`sequence`."""
        return 2 * self.steps + self.n_bits("x") + self.n_bits("y")


def decode_phase(sin_sum: np.ndarray, cos_sum: np.ndarray, stripe: np.ndarray, period: int,
                 steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Projector coordinate from the phase sums and the half-period stripe index.

    Parameters
    ----------
    sin_sum, cos_sum : (H, W) ``Σ I_k sin δ_k`` and ``Σ I_k cos δ_k`` over the normalised
        captures ``I_k`` of the phase steps ``δ_k = 2π k / N``.
    stripe : (H, W) int half-period stripe index (Gray-decoded).
    period, steps : ``P`` and ``N``.

    Returns
    -------
    coord : (H, W) float64 projector px (pixel centres at integers).
    modulation : (H, W) float32 the sinusoid's amplitude over the white-minus-black contrast.
    agree : (H, W) bool where stripe and phase agree on the position within ``3P/8``.
    """
    phi = np.mod(np.arctan2(sin_sum, cos_sum), 2 * np.pi)
    x_phase = phi * (period / (2 * np.pi))
    x_stripe = (stripe + 0.5) * (period / 2)
    k = np.rint((x_stripe - x_phase) / period)
    coord = k * period + x_phase
    agree = np.abs(coord - x_stripe) <= 0.375 * period
    modulation = (2.0 / steps) * np.hypot(sin_sum, cos_sum)
    return coord, modulation.astype(np.float32), agree


@dataclass
class DenseMap:
    """Projector coordinates of every camera pixel, and where they hold.

    Attributes
    ----------
    proj_xy : (Hc, Wc, 2) float32 projector (x, y) seen at each camera pixel (undefined where
        not ``valid``).
    valid : (Hc, Wc) bool.
    modulation : (Hc, Wc, 2) float32 the x and y phase modulations (diagnostics).
    lit : (Hc, Wc) bool the pixels the projector lights at all (white minus black above the
        camera's noise), valid or not.
    """

    proj_xy: np.ndarray
    valid: np.ndarray
    modulation: np.ndarray
    lit: np.ndarray

    def samples(self, step: int = 4) -> tuple[np.ndarray, np.ndarray]:
        """Valid pixels on a ``step``-px camera grid: (cam_xy (n, 2), proj_xy (n, 2)) float64."""
        ys, xs = np.mgrid[0:self.valid.shape[0]:step, 0:self.valid.shape[1]:step]
        ok = self.valid[ys, xs]
        cam = np.stack([xs[ok], ys[ok]], axis=1).astype(np.float64)
        return cam, self.proj_xy[ys[ok], xs[ok]].astype(np.float64)

    def resampled(self, map_x: np.ndarray, map_y: np.ndarray) -> DenseMap:
        """The map seen through ``cv2.remap`` maps (e.g. into ideal camera pixels): bilinear
        coordinates, valid only where all four source pixels were."""
        def remap(a, interp):
            return cv2.remap(np.ascontiguousarray(a), map_x, map_y, interp,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)

        valid = remap(self.valid.astype(np.uint8), cv2.INTER_NEAREST).astype(bool)
        valid &= cv2.erode(remap(self.valid.astype(np.uint8), cv2.INTER_NEAREST),
                           np.ones((3, 3), np.uint8)).astype(bool)
        return replace(self, proj_xy=remap(self.proj_xy, cv2.INTER_LINEAR), valid=valid,
                       modulation=remap(self.modulation, cv2.INTER_LINEAR),
                       lit=remap(self.lit.astype(np.uint8), cv2.INTER_NEAREST).astype(bool))


class DenseDecoder:
    """Consumes the captures of :meth:`DensePatterns.sequence` (running sums, never the stack)
    and produces a :class:`DenseMap`.

    Parameters
    ----------
    patterns : the projected :class:`DensePatterns`.
    min_modulation : see :data:`MIN_MODULATION`.
    min_contrast : smallest white-minus-black difference (camera codes) of a lit pixel.
    """

    def __init__(self, patterns: DensePatterns, *, min_modulation: float = MIN_MODULATION,
                 min_contrast: float = 8.0):
        self.patterns = patterns
        self.min_modulation = float(min_modulation)
        self.min_contrast = float(min_contrast)
        self._sums: dict[str, list] = {}
        self._bits: dict[str, list] = {"x": [], "y": []}
        self._black = self._white = self._lit = None

    def names(self) -> set[str]:
        """The pattern names this decoder takes."""
        return {name for name, _ in self.patterns.sequence()}

    @property
    def ready(self) -> bool:
        """Whether the black and white frames are set."""
        return self._lit is not None

    def set_frames(self, black: np.ndarray, white: np.ndarray) -> None:
        """The black and white camera frames ((Hc, Wc) float grey codes) to normalise by."""
        self._black = np.asarray(black, np.float32)
        self._white = np.asarray(white, np.float32)
        self._lit = (self._white - self._black) > self.min_contrast

    def add(self, name: str, frame: np.ndarray) -> None:
        """Hand over the capture of pattern ``name`` ((Hc, Wc, 3) uint8 or (Hc, Wc) codes)."""
        if self._lit is None:
            raise InputError("the black and white frames must be set before the dense patterns")
        if not (name.startswith(("dp", "dg")) and len(name) > 3 and name[2] in "xy"):
            raise InputError(f"unknown dense pattern name {name!r}")
        nrm = normalise(to_grey(frame), self._black, self._white, self._lit)
        axis = name[2]
        if name.startswith("dg"):
            self._bits[axis].append(nrm > 0.5)
            return
        delta = 2 * np.pi * int(name[3:]) / self.patterns.steps
        s, c = self._sums.setdefault(axis, [np.zeros_like(nrm), np.zeros_like(nrm), 0])[:2]
        s += np.float32(math.sin(delta)) * nrm
        c += np.float32(math.cos(delta)) * nrm
        self._sums[axis][2] += 1

    def result(self) -> DenseMap:
        """Decode both axes; see :class:`DenseMap`."""
        pats = self.patterns
        coords, mods = [], []
        valid = self._lit.copy()
        for axis in ("x", "y"):
            if axis not in self._sums or self._sums[axis][2] != pats.steps \
                    or len(self._bits[axis]) != pats.n_bits(axis):
                raise InputError(f"dense patterns along {axis}: expected {pats.steps} phase steps "
                                 f"and {pats.n_bits(axis)} Gray-code bits")
            s, c, _ = self._sums[axis]
            coord, mod, agree = decode_phase(s, c, decode_gray(self._bits[axis]), pats.period,
                                             pats.steps)
            valid &= agree & (mod >= self.min_modulation)
            valid &= (coord >= -0.5) & (coord <= pats.extent(axis) - 0.5)
            coord = coord.astype(np.float32)
            # A wrong high Gray-code bit moves a pixel by whole periods, which the phase check
            # cannot see: the map is smooth (a kink at a fold, no jump), so a pixel far from
            # its neighbourhood's median is a misread.
            med = cv2.medianBlur(np.where(valid, coord, 0).astype(np.float32), 5)
            valid &= np.abs(coord - med) <= MAX_MEDIAN_DEVIATION
            coords.append(coord)
            mods.append(mod)
        return DenseMap(proj_xy=np.stack(coords, axis=-1), valid=valid,
                        modulation=np.stack(mods, axis=-1), lit=self._lit)
