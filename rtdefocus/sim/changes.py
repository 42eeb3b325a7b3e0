"""Set-ups that change during a run: a knocked projector or camera, the room light, the focus.

:class:`SetupChanges` gives :class:`~rtdefocus.sim.VirtualProCam` the methods that change it
between two captures: :meth:`~SetupChanges.bump`, :meth:`~SetupChanges.set_light` and
:meth:`~SetupChanges.refocus`. Each rebuilds exactly what the change affects (projector space,
the camera's maps, the blur plan) and the ground truth with it, so that
:func:`~rtdefocus.sim.oracle_calibration` after a change is the calibration a perfect
re-calibration would find. The walls never move; nothing changes until a method is called.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from ..errors import InputError
from .optics import BlurPlan

_MAX_YAW_DEG = 5.0          # a knock, not a new set-up: larger turns need a new calibration
_MAX_SHIFT_PX = 60.0
_SCALE_RANGE = (0.25, 4.0)


def _pair(value, name: str) -> tuple[float, float]:
    """(dx, dy) from a number (dx, 0) or a pair; finite and within the bump's range."""
    v = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if v.size == 1:
        v = np.array([v[0], 0.0])
    if v.shape != (2,) or not np.all(np.isfinite(v)) or np.max(np.abs(v)) > _MAX_SHIFT_PX:
        raise InputError(f"{name} must be a number or (dx, dy) in px, each within ±{_MAX_SHIFT_PX:g}; "
                         f"got {value!r}")
    return float(v[0]), float(v[1])


def _rotation_taking_z_to(v: np.ndarray) -> np.ndarray:
    """The smallest rotation taking (0, 0, 1) to the direction of ``v`` (Rodrigues)."""
    z = np.array([0.0, 0.0, 1.0])
    v = v / np.linalg.norm(v)
    axis = np.cross(z, v)
    s, c = float(np.linalg.norm(axis)), float(z @ v)
    if s < 1e-15:
        return np.eye(3)
    k = axis / s
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


class SetupChanges:
    """Changes of a :class:`~rtdefocus.sim.VirtualProCam` between two captures (a mixin).

    Every change is kept in :attr:`changes` as ``(kind, parameters)``. A change that would
    leave the set-up invalid (the frame off the walls) raises :class:`~rtdefocus.errors.InputError`
    and leaves the set-up as it was.
    """

    changes: tuple = ()

    def _rebuild(self, change, *, projector: bool, camera: bool) -> None:
        """Apply ``change()`` then rebuild; on any error restore the set-up as it was."""
        saved = dict(self.__dict__)
        try:
            change()
            if projector:
                if self._room:
                    self._depth_range = self._frame_depth_range()
                self._build_projector_space()
                self._blur = BlurPlan(self._pad_radius, self.chromatic, self.aperture)
            if projector or camera:
                self._build_camera_maps()
            self._build_truth()
        except Exception:
            self.__dict__.clear()
            self.__dict__.update(saved)
            raise

    def _log_change(self, kind: str, **params) -> None:
        self.changes = (*self.changes, (kind, params))

    def bump(self, projector_yaw_deg: float = 0.0, projector_shift_px=0.0,
             camera_shift_px=0.0) -> None:
        """Knock the projector or the camera: the walls stay, the device moves.

        Parameters
        ----------
        projector_yaw_deg : turn of the projector about its own vertical axis (degrees, within
            ±5; positive turns the picture to the right).
        projector_shift_px : the projector moved sideways, (dx, dy) or dx, in its own x and y
            axes, by as much as moves the picture ``(dx, dy)`` projector px at the depth of the
            frame's centre (a pure translation: nearer walls see a little more, farther less).
            Applied after the turn.
        camera_shift_px : the camera turned so that its view moves by (dx, dy) (or dx) camera
            px at the image centre: a dot seen at the centre moves to (cx + dx, cy + dy).
        """
        yaw = float(projector_yaw_deg)
        if not math.isfinite(yaw) or abs(yaw) > _MAX_YAW_DEG:
            raise InputError(f"projector_yaw_deg must be within ±{_MAX_YAW_DEG:g}°; "
                             f"got {projector_yaw_deg!r}")
        ps = _pair(projector_shift_px, "projector_shift_px")
        cs = _pair(camera_shift_px, "camera_shift_px")
        moved_projector = yaw != 0.0 or ps != (0.0, 0.0)
        moved_camera = cs != (0.0, 0.0)

        def change():
            if moved_projector:
                wp, hp = self.projector_size
                m = self._margin
                depth = float(self._pad_depth[m + hp // 2, m + wp // 2])
                a = math.radians(yaw)
                # Turn about the projector's own y axis: its new axis is old (sin a, 0, cos a).
                R_y = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0],
                                [-math.sin(a), 0.0, math.cos(a)]])
                self.R_proj = R_y.T @ self.R_proj
                step = np.array([ps[0], ps[1], 0.0]) * depth / self.K_proj[0, 0]
                self._proj_center = self._proj_center + self.R_proj.T @ step
            if moved_camera:
                fc = self.K_cam[0, 0]
                R_d = _rotation_taking_z_to(np.array([cs[0] / fc, cs[1] / fc, 1.0]))
                self.R_cam = R_d @ self.R_cam
                self.t_cam = -self.R_cam @ self._cam_center

        if moved_projector or moved_camera:
            self._rebuild(change, projector=moved_projector, camera=moved_camera)
        self._log_change("bump", projector_yaw_deg=yaw, projector_shift_px=ps, camera_shift_px=cs)

    def set_light(self, ambient: float | None = None, exposure: float | None = None) -> None:
        """Change the room light and / or the camera's exposure.

        Parameters
        ----------
        ambient : the new ambient irradiance on the walls, relative to a full-on projector
            (as the constructor's ``ambient``; e.g. ``procam.ambient + 0.1`` for a room light
            risen by 10 % of full white); None keeps it.
        exposure : the camera's new exposure (linear gain); None keeps it.
        """
        if ambient is not None and not (math.isfinite(float(ambient)) and float(ambient) >= 0):
            raise InputError(f"ambient must be a finite number >= 0; got {ambient!r}")
        if exposure is not None and not (math.isfinite(float(exposure)) and float(exposure) > 0):
            raise InputError(f"exposure must be a finite number > 0; got {exposure!r}")

        def change():
            if ambient is not None:
                self.ambient = float(ambient)
            if exposure is not None:
                # The camera's albedo map has the exposure folded in.
                self._cam_albedo = (self._cam_albedo * np.float32(float(exposure) / self.exposure))
                self.exposure = float(exposure)

        self._rebuild(change, projector=False, camera=False)
        self._log_change("set_light", ambient=self.ambient, exposure=self.exposure)

    def set_exposure(self, exposure: float) -> None:
        """Set the camera's exposure (linear gain): the control a calibration uses to stop
        its captures clipping (``set_light(exposure=...)``)."""
        self.set_light(exposure=exposure)

    def refocus(self, scale: float) -> None:
        """Scale every blur radius by ``scale`` (the lens's blur cone widened or narrowed).

        Parameters
        ----------
        scale : factor on the radius of every pixel and channel, in [0.25, 4] (1.15: 15 %
            more blur); cumulative over calls.
        """
        scale = float(scale)
        lo, hi = _SCALE_RANGE
        if not (math.isfinite(scale) and lo <= scale <= hi):
            raise InputError(f"refocus scale must be within [{lo:g}, {hi:g}]; got {scale!r}")

        def change():
            self.aperture_radius *= scale

        if scale != 1.0:
            self._rebuild(change, projector=True, camera=False)
        self._log_change("refocus", scale=scale)

    def skip_capture(self):
        """Move the noise past one capture unrendered (a capture the caller does not need);
        returns its noise for ``capture(..., noise=)`` to render it later bit for bit (None: no
        noise). Needs exposure_drift 0."""
        if self.exposure_drift != 0.0:
            raise InputError("skip_capture() needs exposure_drift 0 (the gain moves per capture)")
        if self.noise <= 0:
            return None
        saved = copy.deepcopy(self._rng)
        self._rng.standard_normal((self.camera_size[1], self.camera_size[0], 3), dtype=np.float32)
        return saved
