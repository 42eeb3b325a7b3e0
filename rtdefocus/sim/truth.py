"""What the virtual set-up really is: the exact answers calibration should find (tests only)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .optics import blend_kernel


@dataclass
class GroundTruth:
    """The exact answers of a :class:`VirtualProCam` (for tests only; calibration never reads them).

    Attributes
    ----------
    radius_map : (Hp, Wp) float32, blur radius in projector px (green channel).
    radius_rgb : (3, Hp, Wp) float32, blur radius per channel (radius_map × chromatic scale).
    plane_map : (Hp, Wp) int8, wall seen by each projector pixel, 0..n_planes-1, numbered by
        their centroid x in the projector (ties within 5 % of the width by centroid y); for two
        walls the left one is 0; all 0 for ``flat``; -1 where a far wall shows through a gap
        (no plane of the set-up).
    cam_from_proj : (Hp, Wp, 2) float32, the ideal camera pixel (x, y) of the surface point
        each projector pixel centre lights: the exact camera <- projector map, which the
        homographies only approximate where a wall bows (``Scene.bow``) and do not give on a
        far wall.
    depth_map : (Hp, Wp) float32, depth of that surface point along the projector axis (m).
    fold_proj, fold_cam : (3,) float64 line ``a x + b y + c = 0``, ``a² + b² = 1``, plane 0 where
        it is negative, for two planes; None for one (``flat``) or three and more.
    folds_proj, folds_cam : (m, 3) float64, every fold inside the projector frame (one per pair
        of planes that meet there), normalised like ``fold_proj`` and oriented by
        :func:`~rtdefocus.planar.canonical_line` in the projector (normal towards +x; +y
        when ``|b| > |a|``), listed in order of their plane pair; ``folds_cam`` are the same
        folds in ideal camera pixels, with the same planes on the same sides.
    fold_planes : (m, 2) int64, [plane on the fold's negative side, plane on its positive side].
    H_cam_from_proj : (n_planes, 3, 3) float64 plane-induced homographies (H[2, 2] = 1); of
        each wall's plane, which a bowed wall leaves by its bow.
    albedo_proj : (Hp, Wp, 3) float32, α(x): camera linear light added by a full-on projector
        pixel in focus (exposure × albedo × irradiance shading).
    ambient_proj : (Hp, Wp, 3) float32, Γ(x): camera linear light with the projector black.
    K_proj, K_cam : (3, 3) float64 intrinsics; R_cam_from_proj (3, 3), t_cam_from_proj (3,)
        so that X_cam = R X_proj + t (m).
    planes_proj : (n_planes, 4) float64 (n, d) with n · X_proj = d, |n| = 1, per wall (its
        plane, for a bowed one).
    focus_distance : m; blur_scale : A·f in px·m, so r = blur_scale·|1/focus_distance − 1/D|.
    chromatic : per-channel scale of r; aperture : "disc" | "hex".
    projector_gamma, camera_gamma, exposure : response parameters (see VirtualProCam).
    camera_response : (256,) float32, the camera's inverse response: linear light (0..1) of
        each code (what calibration's camera response should recover); ``camera_response_kind``
        "gamma" | "srgb".
    distortion : (k1, k2) radial lens distortion (:func:`rtdefocus.planar.distort_points`);
        ``H_cam_from_proj`` and ``fold_cam`` are in ideal (undistorted) camera pixels.
    exposure_drift : the camera gain's relative change per capture.
    extra : ``camera_in_frame`` (Hc, Wc) bool, camera pixels that see a point lit by the
        projector frame; ``shaped``, whether a wall bows or a far wall shows (so
        ``cam_from_proj`` and not the homographies is the true map);
        ``camera_plane_map`` (Hc, Wc) int8, wall seen by each camera pixel
        (-1: none), numbered like ``plane_map``; ``margin``, projector px simulated beyond the frame edge;
        ``proj_from_cam`` (Hc, Wc, 2) float32, the projector point (x, y) each observed camera
        pixel sees (NaN where none: a dense correspondence map's truth).
    """

    radius_map: np.ndarray
    radius_rgb: np.ndarray
    plane_map: np.ndarray
    depth_map: np.ndarray
    fold_proj: np.ndarray | None
    fold_cam: np.ndarray | None
    H_cam_from_proj: np.ndarray
    albedo_proj: np.ndarray
    ambient_proj: np.ndarray
    K_proj: np.ndarray
    K_cam: np.ndarray
    R_cam_from_proj: np.ndarray
    t_cam_from_proj: np.ndarray
    planes_proj: np.ndarray
    focus_distance: float
    blur_scale: float
    chromatic: tuple[float, float, float]
    aperture: str
    projector_gamma: float
    camera_gamma: float
    exposure: float
    camera_response: np.ndarray | None = None
    camera_response_kind: str = "gamma"
    distortion: tuple[float, float] = (0.0, 0.0)
    exposure_drift: float = 0.0
    folds_proj: np.ndarray | None = None
    folds_cam: np.ndarray | None = None
    fold_planes: np.ndarray | None = None
    extra: dict = field(default_factory=dict)
    cam_from_proj: np.ndarray | None = None

    def kernel_at(self, x: float, y: float, size: int | None = None, channel: int = 1) -> np.ndarray:
        """True gather kernel at projector pixel (x, y) (rounded to the nearest pixel).

        Parameters
        ----------
        x, y : projector pixel coordinates (column, row) inside the frame.
        size : odd kernel size k, or None for the full support (a smaller size crops and
            renormalises).
        channel : 0, 1, 2 = R, G, B (the chromatic scale changes the radius).

        Returns
        -------
        (k, k) float32, unit sum, ``psf[k//2 + v, k//2 + u] = k_x(u, v)``, with
        ``O(x) = sum_u k_x(u) P(x - u)``. It is exactly the kernel the renderer uses.
        """
        return blend_kernel(self.radius_at(x, y, channel), self.aperture, size)

    def radius_at(self, x: float, y: float, channel: int = 1) -> float:
        """Blur radius (projector px) at the projector pixel nearest (x, y), channel 0/1/2."""
        _, hp, wp = self.radius_rgb.shape
        xi, yi = int(round(float(x))), int(round(float(y)))
        if not (0 <= xi < wp and 0 <= yi < hp):
            raise InputError(f"projector pixel ({x}, {y}) is outside the {wp}x{hp} frame; "
                             f"use 0 <= x < {wp}, 0 <= y < {hp}")
        if channel not in (0, 1, 2):
            raise InputError(f"channel must be 0, 1 or 2 (R, G, B); got {channel}")
        return float(self.radius_rgb[channel, yi, xi])

    @property
    def n_planes(self) -> int:
        return int(self.H_cam_from_proj.shape[0])


def projector_map(map_x: np.ndarray, map_y: np.ndarray, margin: int, outside: float) -> np.ndarray:
    """(Hc, Wc, 2) float32: the projector point (x, y) each observed camera pixel sees, from
    the renderer's remap into the projector frame padded by ``margin`` (``outside`` where no
    projector light reaches), NaN where it sees none."""
    xy = np.stack([map_x, map_y], axis=-1) - np.float32(margin)
    xy[map_x == outside] = np.nan
    return xy
