"""The surface in the forward model: ``surface="flatten"`` of :class:`rd.Compensator`.

The camera (the audience's proxy) sees, per channel and in projector coordinates (DESIGN.md §3)

    O = A ⊙ (F P) + E          A: albedo × shading × exposure, E: ambient (calibration)

``"keep"`` aims at what an in-focus projector would show on the same walls (residual
``F P − I``: the walls' colour, texture and ambient light stay). ``"flatten"`` aims at the input
as on a uniform white wall, ``O ≈ b·I`` with one global brightness ``b`` (camera units):

    min_P d(A ⊙ (F P) + E − b·I) = d(A ⊙ (F P − T')),    T' = (b·I − E) / A

so the solve keeps its form with the target ``T'`` (in the projector's units: a cold start
``clamp(T')`` is classic photometric compensation) and a per-pixel scale ``S = A`` of the
residual, folded into the metric kernels (``kernels/metric.cl`` HAS_SCALE; the NumPy twin in
:class:`rtdefocus.reference.ops.NumpyOps`). Where the projector cannot reach ``T'`` (a dark or
saturated patch lifted to white: ``T' > 1``; a dark input under room light: ``T' < 0``) the
bound ``0 <= P <= 1`` clips; ``brightness="auto"`` chooses ``b`` so that a full-white input
clips on a small share of the lit pixels (:data:`AUTO_CLIP_SHARE`). Pixels the calibration did
not see lit (``A`` ≈ 0, outside the camera's view) keep the plain target (``S = 1``, ``T' = I``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import CalibrationFileError, InputError

__all__ = ["AUTO_CLIP_SHARE", "SURFACES", "SurfaceModel"]

SURFACES = ("keep", "flatten")

# brightness="auto": the share of lit pixels allowed to clip on a full-white input. Lower: a
# dimmer picture that is uniform over more of the wall (a dark poster stripe is lifted rather
# than left darker); higher: brighter, with the darkest patches of the wall left darker.
AUTO_CLIP_SHARE = 0.05
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
        ``T' = gain ⊙ I + offset`` (``b / A`` and ``−E / A`` on lit pixels; 1 and 0 elsewhere).
    lit : (Hp, Wp) bool
    brightness : float, the global brightness b (camera linear light for a white input).
    """

    scale: np.ndarray
    gain: np.ndarray
    offset: np.ndarray
    lit: np.ndarray
    brightness: float

    @classmethod
    def from_calibration(cls, calib, brightness: str | float = "auto") -> SurfaceModel:
        """Build from ``calib.albedo_proj`` and ``calib.ambient_proj`` ((Hp, Wp, 3) float32).

        Parameters
        ----------
        brightness : "auto" or a number > 0
            b in camera linear light (the camera's full scale is 1): what a white input should
            look like; "auto": the :data:`AUTO_CLIP_SHARE` percentile of ``A + E`` over the lit
            pixels, the largest b at which a white input clips on at most that share.
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
        if brightness == "auto":
            reach = (A + E).min(axis=0)[lit]
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
        offset = np.where(litc, -E / safe, 0.0).astype(np.float32)
        return cls(scale, gain, offset, lit, b)

    def target(self, I: np.ndarray) -> np.ndarray:
        """``T' = gain ⊙ I + offset`` for a planar (3, Hp, Wp) linear target I."""
        return (self.gain * I + self.offset).astype(np.float32)

    def clipped(self, I: np.ndarray, target: np.ndarray) -> tuple[float, float]:
        """Shares of the lit pixels showing content (``I > 0`` in some channel) whose target
        ``T' = target(I)`` the projector cannot reach in some channel: ``(above, below)`` —
        above 1 (too bright for the wall: brightness-limited), below 0 (darker than the room
        light on it: ambient-limited)."""
        shown = self.lit & (I > 0).any(axis=0)
        n = max(int(shown.sum()), 1)
        hi = ((target > 1.0).any(axis=0) & shown).sum() / n
        lo = ((target < 0.0).any(axis=0) & shown).sum() / n
        return float(hi), float(lo)
