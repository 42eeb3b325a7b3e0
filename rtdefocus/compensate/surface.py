"""The surface in the forward model: ``surface="flatten"`` of :class:`rd.Compensator`.

The camera (the audience's proxy) sees, per channel and in projector coordinates (DESIGN.md §3)

    O = A ⊙ (F P) + E          A: albedo × shading × exposure, E: ambient (calibration)

``"keep"`` aims at what an in-focus projector would show on the same walls (residual
``F P − I``: the walls' colour, texture and ambient light stay). ``"flatten"`` aims at the input
as on a uniform white wall in the same room, ``O ≈ b·I + e`` with one global brightness ``b``
(camera units) and a uniform black level ``e`` (per channel), the room light as a uniform wall
would reflect it:

    min_P d(A ⊙ (F P) + E − b·I − e) = d(A ⊙ (F P − T')),    T' = (b·I + e − E) / A

``e`` is the :data:`AUTO_DARK_SHARE` top percentile of ``E`` over the lit pixels, so a black
input is reachable on nearly all of the wall (with ``e = 0`` every input darker than the room
light on it, half the pixels of a dark photograph on the ``fabric`` preset, asked for negative
light).

The solve keeps its form with the target ``clamp(T', 0, 1)`` (in the projector's units: classic
photometric compensation, also the cold start) and a per-pixel scale ``S = A`` of the residual,
folded into the metric kernels (``kernels/metric.cl`` HAS_SCALE; the NumPy twin in
:class:`rtdefocus.reference.ops.NumpyOps`). Where the projector cannot reach ``T'`` (a dark or
saturated patch lifted to white: ``T' > 1``; a dark input under room light: ``T' < 0``) the
clamp gives it up and :meth:`SurfaceModel.clipped` reports the share; ``brightness="auto"``
chooses ``b`` so that a full-white input clips on a small share of the lit pixels
(:data:`AUTO_CLIP_SHARE`). The brightness also sets how much of the defocus gain the camera
can see: the blur's error scales with the picture while the camera's noise does not, so near
the fold the gain of a dimmer picture is a smaller share of keep's. Pixels the calibration did
not see lit (``A`` ≈ 0, outside the camera's view) keep the plain target (``S = 1``, ``T' = I``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import CalibrationFileError, InputError

__all__ = ["AUTO_CLIP_SHARE", "AUTO_DARK_SHARE", "SURFACES", "SurfaceModel"]

SURFACES = ("keep", "flatten")

# brightness="auto": the share of lit pixels allowed to clip on a full-white input. Lower: a
# dimmer picture that is uniform over more of the wall (a dark poster stripe is lifted rather
# than left darker); higher: brighter, with the darkest patches of the wall left darker.
AUTO_CLIP_SHARE = 0.10
# 0.10 rather than 0.05 (`tools/flatten_eval.py --calib oracle`, fabric, 240×180): every figure
# improved, grey-field CoV 6.4× → 6.6× lower than keep, photographs +0.3 to +0.5 dB, fold gain
# 0.87/0.69/0.72 → 0.96/0.74/0.77 of keep's; photographs clip on 0-2.4 % of their pixels.
# The black level e: the share of lit pixels where a black input stays brighter than e (the room
# light there is above the uniform floor). Lower: a brighter, more washed-out black, reachable
# everywhere; higher: deeper blacks, the brightest-lit patches of the wall left brighter.
AUTO_DARK_SHARE = 0.05
# Lit pixels: albedo above this fraction of the 99th percentile (the rest keep their target).
_LIT_FRACTION = 0.05


@dataclass(frozen=True)
class SurfaceModel:
    """Target map and residual scale of ``surface="flatten"`` for one calibration.

    Attributes
    ----------
    scale : (3, Hp, Wp) float32
        S = A on lit pixels, 1 elsewhere.
    gain, offset : (3, Hp, Wp) float32
        ``T' = gain ⊙ I + offset`` (``b / A`` and ``(e − E) / A`` on lit pixels; 1 and 0
        elsewhere).
    lit : (Hp, Wp) bool
    brightness : float, the global brightness b (camera linear light from black to white).
    black : (3,) float32, the black level e (camera linear light of a black input).
    """

    scale: np.ndarray
    gain: np.ndarray
    offset: np.ndarray
    lit: np.ndarray
    brightness: float
    black: np.ndarray

    @classmethod
    def from_calibration(cls, calib, brightness: str | float = "auto") -> SurfaceModel:
        """Build from ``calib.albedo_proj`` and ``calib.ambient_proj`` ((Hp, Wp, 3) float32).

        Parameters
        ----------
        brightness : "auto" or a number > 0
            b in camera linear light (the camera's full scale is 1): how much brighter than a
            black input a white one should look (white shows at ``b + e``); "auto": the
            :data:`AUTO_CLIP_SHARE` percentile of ``A + E − e`` over the lit pixels, the largest
            b at which a white input clips on at most that share.
        """
        albedo = getattr(calib, "albedo_proj", None)
        ambient = getattr(calib, "ambient_proj", None)
        if albedo is None or ambient is None:
            raise CalibrationFileError(
                "surface='flatten' needs the calibration's radiometry (albedo_proj, ambient_proj); "
                "calibrate with the 'radiometry' stage or use surface='keep'")
        A = np.asarray(albedo, np.float32).transpose(2, 0, 1)
        E = np.asarray(ambient, np.float32).transpose(2, 0, 1)
        if not (np.isfinite(A).all() and np.isfinite(E).all()):
            A, E = np.nan_to_num(A), np.nan_to_num(E)
        a_min = A.min(axis=0)
        ref = float(np.percentile(a_min, 99)) if a_min.size else 0.0
        if not ref > 0:
            raise CalibrationFileError("surface='flatten': the calibration's albedo is zero "
                                       "everywhere; the projector was never seen lit")
        lit = a_min > _LIT_FRACTION * ref
        e = np.percentile(E[:, lit], 100 * (1 - AUTO_DARK_SHARE), axis=1).astype(np.float32)
        if brightness == "auto":
            reach = (A + E - e[:, None, None]).min(axis=0)[lit]
            b = float(np.percentile(reach, 100 * AUTO_CLIP_SHARE))
        else:
            try:
                b = float(brightness)
            except (TypeError, ValueError):
                b = float("nan")
            if not b > 0:
                raise InputError(f"brightness must be 'auto' or a number > 0; got {brightness!r}")
        litc = np.broadcast_to(lit, A.shape)
        safe = np.where(litc, A, 1.0)
        scale = np.where(litc, A, 1.0).astype(np.float32)
        gain = np.where(litc, b / safe, 1.0).astype(np.float32)
        offset = np.where(litc, (e[:, None, None] - E) / safe, 0.0).astype(np.float32)
        return cls(scale, gain, offset, lit, b, e)

    def target(self, I: np.ndarray) -> np.ndarray:
        """The solve's target ``clamp(T', 0, 1)``, ``T' = gain ⊙ I + offset``, for a planar
        (3, Hp, Wp) linear target I.

        Clamped because the part of ``T'`` outside the projector's range is unreachable even in
        focus: solved for as such, the solve pushed light into a clipped patch from its
        neighbours (a halo) and left less of its budget for the defocus; clamped, it aims at
        the in-focus photometric compensation, as ``keep`` aims at an in-focus frame. (On the
        ``fabric`` preset at b = 0.3, coffee: the fold gain rose from 0.36 to 0.74 of keep's.)
        :meth:`clipped` reports what the clamp gives up."""
        T = self.gain * I + self.offset
        return np.clip(T, 0.0, 1.0, out=T).astype(np.float32, copy=False)

    def clipped(self, I: np.ndarray) -> tuple[float, float]:
        """Shares of the lit pixels showing content (``I > 0`` in some channel) whose ``T'`` the
        projector cannot reach in some channel: ``(above, below)`` — above 1 (too bright for the
        wall: brightness-limited), below 0 (darker than the room light on it allows:
        ambient-limited)."""
        T = self.gain * I + self.offset
        shown = self.lit & (I > 0).any(axis=0)
        n = max(int(shown.sum()), 1)
        hi = ((T > 1.0).any(axis=0) & shown).sum() / n
        lo = ((T < 0.0).any(axis=0) & shown).sum() / n
        return float(hi), float(lo)
