"""The built-in virtual projector-camera set-up (DESIGN.md §3 and §6).

A pinhole projector at the world origin looks along +z at two vertical half-planes (walls)
that meet at a vertical fold line about 2.5 m away; a pinhole camera beside the projector looks
at the lit area. :class:`VirtualProCam` implements the :class:`rtdefocus.ProCam` protocol, so
calibration learns everything through :meth:`VirtualProCam.capture`; the exact answers are kept
in :attr:`VirtualProCam.truth` (a :class:`GroundTruth`) for tests only.

Optics, from first principles:

* Defocus (gather form, DESIGN.md §3): a thin lens of aperture radius ``A`` (metres) and focal
  length ``f`` (projector px) focused at ``D_focus``. The surface point seen by projector pixel
  x, at depth D along the projector axis, receives light from every projector pixel within
  ``r(D) = A f |1/D_focus - 1/D|`` projector px of x, each with equal weight (the cone from the
  aperture through the pixel's conjugate point has that radius at depth D, divided by the pixel
  size D/f there). So its kernel is the aperture shape (disc, or regular hexagon) of radius r.
  On a plane 1/D is affine in projector pixel coordinates, so r is affine per wall, continuous
  at the fold with a slope change.
* Irradiance: pixels of an ideal projector carry equal flux, i.e. a radiant intensity
  proportional to 1/cos^3(psi) (psi the angle to the axis). At distance d = D/cos(psi) on a
  surface tilted by theta to the ray that gives E = I cos(theta)/d^2 ∝ cos(theta) / (cos(psi) D^2),
  which is uniform on a screen square to the axis. It is normalised to mean ``SHADING_MEAN``.
* Lambertian walls of (slightly coloured) albedo, uniform ambient irradiance, projector and
  camera response curves (gamma), camera exposure, Gaussian camera noise, uint8 quantisation.

Rendering: the blur is evaluated in projector space on a grid of radii (every ``RADIUS_STEP``
px) — each pixel linearly blends the two neighbouring grid kernels — and the ground-truth
kernel (:meth:`GroundTruth.kernel_at`) is defined as exactly that blend, so rendering and truth
agree to float precision. The projector-space irradiance is computed on the frame plus a margin
(blurred light spills over the frame edge) and resampled into the camera through per-pixel maps
found by ray casting once at construction.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .errors import InputError
from .procam import check_pattern

log = logging.getLogger(__name__)

PATTERNS = ("checker", "lines", "dots")
RADIUS_STEP = 0.25          # px: spacing of the radius grid the blur is rendered on
SHADING_MEAN = 0.85         # mean relative irradiance over the projector frame
_SUPERSAMPLE = 16           # sub-samples per pixel side for the area-antialiased aperture
_OUTSIDE = -1.0e5           # remap coordinate of camera pixels that see no projector light


@dataclass(frozen=True)
class Scene:
    """One arrangement of walls, projector and camera (world frame: x right, y down, z ahead).

    Attributes
    ----------
    kind : "concave" (corner seen from inside, fold deepest), "convex" (pillar, fold nearest)
        or "flat" (one plane, no fold).
    fold_x_frac : where the fold crosses the projector's centre row, as a fraction of the width.
    fold_depth : depth of the fold line along the projector axis (m).
    wall_angles_deg : (left, right) angle of each wall to the plane square to the projector axis
        (degrees); for "flat" only the first is used (positive: the right side recedes).
    roll_deg : roll of the projector (and the camera mounted on it) about the projector axis
        (degrees).
    focus_distance, aperture_radius : projector lens focus depth and aperture radius A (m);
        None (default) derives both from ``blur_range_px``.
    blur_range_px : (min, max) blur radius over the frame of an 800-px-wide projector, used when
        focus_distance / aperture_radius are None; the focus then lies in front of every wall
        point (no wall in focus). Radii scale with the projector width (f = 1.2 W).
    camera_position : camera centre (m) in the projector's frame, beside and a bit above it; the
        camera is mounted on the projector (rolls with it) and looks at the lit area.
    albedo : RGB albedo of the (left, right) wall.
    """

    kind: str
    fold_x_frac: float = 0.5
    fold_depth: float = 2.5
    wall_angles_deg: tuple[float, float] = (35.0, 40.0)
    roll_deg: float = 0.0
    focus_distance: float | None = None
    aperture_radius: float | None = None
    blur_range_px: tuple[float, float] = (1.5, 6.0)
    camera_position: tuple[float, float, float] = (0.4, -0.25, 0.0)
    albedo: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.86, 0.85, 0.81), (0.74, 0.76, 0.79))
    description: str = ""


PRESETS: dict[str, Scene] = {
    "cubicle": Scene("concave", description="concave 105° corner, fold at the centre, deepest and "
                     "blurriest; focus in front of both walls"),
    "pillar": Scene("convex", wall_angles_deg=(30.0, 30.0),
                    description="convex 120° corner (pillar): fold nearest and least blurred"),
    "flat": Scene("flat", wall_angles_deg=(30.0, 0.0), description="one oblique plane, no fold"),
    "tilted": Scene("concave", roll_deg=8.0,
                    description="cubicle with the projector-camera rig rolled 8°: the fold is not vertical "
                    "in either image"),
    "offcenter": Scene("concave", fold_x_frac=0.3, wall_angles_deg=(35.0, 35.0),
                       description="concave corner with the fold at 30% of the projector width"),
}


# --------------------------------------------------------------------------- kernels
@lru_cache(maxsize=512)
def _level_kernel(step_index: int, aperture: str) -> np.ndarray:
    """Area-antialiased aperture of radius ``step_index * RADIUS_STEP`` px, unit sum.

    Returns a read-only (k, k) float64 array, ``psf[k//2 + v, k//2 + u] = k(u, v)``.
    """
    rho = step_index * RADIUS_STEP
    # Any pixel whose square can touch the shape: |u| <= rho + sqrt(2)/2.
    h = int(math.ceil(rho + 0.7072)) if rho > 0 else 0
    if rho <= 0:
        ker = np.ones((1, 1))
    else:
        ss = _SUPERSAMPLE
        n = (2 * h + 1) * ss
        c = (np.arange(n) + 0.5) / ss - (h + 0.5)          # sub-sample centres, px
        u, v = np.meshgrid(c, c)
        if aperture == "disc":
            inside = u * u + v * v <= rho * rho
        else:  # regular hexagon of circumradius rho, vertices at 0°, 60°, ...
            apothem = rho * math.sqrt(3.0) / 2.0
            inside = np.ones_like(u, dtype=bool)
            for ang in (30.0, 90.0, 150.0):
                a = math.radians(ang)
                inside &= np.abs(u * math.cos(a) + v * math.sin(a)) <= apothem
        ker = inside.reshape(2 * h + 1, ss, 2 * h + 1, ss).sum(axis=(1, 3)).astype(np.float64)
        if ker.sum() == 0:          # shape smaller than one sub-sample: a delta
            ker = np.zeros((2 * h + 1, 2 * h + 1))
            ker[h, h] = 1.0
        ker /= ker.sum()
    ker.setflags(write=False)
    return ker


def _pad_to(ker: np.ndarray, k: int) -> np.ndarray:
    """Centre-pad (or centre-crop) a square odd kernel to (k, k)."""
    n = ker.shape[0]
    if n == k:
        return ker.copy()
    if n < k:
        out = np.zeros((k, k), dtype=ker.dtype)
        o = (k - n) // 2
        out[o:o + n, o:o + n] = ker
        return out
    o = (n - k) // 2
    return ker[o:o + k, o:o + k].copy()


def blend_kernel(radius: float, aperture: str = "disc", size: int | None = None) -> np.ndarray:
    """The simulator's kernel for a blur radius: the linear blend of the two grid kernels.

    Parameters
    ----------
    radius : blur radius in projector px (>= 0).
    aperture : "disc" or "hex".
    size : odd output size k; None for the full support. A smaller size crops and
        renormalises to unit sum.

    Returns
    -------
    (k, k) float32, unit sum, ``psf[k//2 + v, k//2 + u] = k(u, v)`` (gather form).
    """
    q = float(radius) / RADIUS_STEP
    j = int(math.floor(q))
    t = q - j
    k_lo, k_hi = _level_kernel(j, aperture), _level_kernel(j + 1, aperture)
    n = k_hi.shape[0]
    ker = (1.0 - t) * _pad_to(k_lo, n) + t * k_hi
    if size is not None:
        if size < 1 or size % 2 == 0:
            raise InputError(f"kernel size must be a positive odd integer; got {size}")
        ker = _pad_to(ker, size)
        ker /= ker.sum()
    return ker.astype(np.float32)


# --------------------------------------------------------------------------- ground truth
@dataclass
class GroundTruth:
    """The exact answers of a :class:`VirtualProCam` (for tests only; calibration never reads them).

    Attributes
    ----------
    radius_map : (Hp, Wp) float32, blur radius in projector px (green channel).
    radius_rgb : (3, Hp, Wp) float32, blur radius per channel (radius_map × chromatic scale).
    plane_map : (Hp, Wp) int8, wall seen by each projector pixel (0/1; all 0 for ``flat``).
    depth_map : (Hp, Wp) float32, depth of that surface point along the projector axis (m).
    fold_proj, fold_cam : (3,) float64 line ``a x + b y + c = 0``, ``a² + b² = 1``, plane 0 where
        it is negative; None for ``flat``.
    H_cam_from_proj : (n_planes, 3, 3) float64 plane-induced homographies (H[2, 2] = 1).
    albedo_proj : (Hp, Wp, 3) float32, α(x): camera linear light added by a full-on projector
        pixel in focus (exposure × albedo × irradiance shading).
    ambient_proj : (Hp, Wp, 3) float32, Γ(x): camera linear light with the projector black.
    K_proj, K_cam : (3, 3) float64 intrinsics; R_cam_from_proj (3, 3), t_cam_from_proj (3,)
        so that X_cam = R X_proj + t (m).
    planes_proj : (n_planes, 4) float64 (n, d) with n · X_proj = d, |n| = 1, per wall.
    focus_distance : m; blur_scale : A·f in px·m, so r = blur_scale·|1/focus_distance − 1/D|.
    chromatic : per-channel scale of r; aperture : "disc" | "hex".
    projector_gamma, camera_gamma, exposure : response parameters (see VirtualProCam).
    extra : ``camera_in_frame`` (Hc, Wc) bool, camera pixels that see a point lit by the
        projector frame; ``camera_plane_map`` (Hc, Wc) int8, wall seen by each camera pixel
        (-1: none); ``margin``, projector px simulated beyond the frame edge.
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
    extra: dict = field(default_factory=dict)

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


# --------------------------------------------------------------------------- geometry helpers
@dataclass(frozen=True)
class _Wall:
    n: np.ndarray        # unit normal (world), pointing towards the projector
    d: float             # n · X = d
    origin: np.ndarray   # a point on the fold (world)
    e: np.ndarray | None  # in-plane direction away from the fold; None = whole plane


def _rot_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _look_at(center: np.ndarray, target: np.ndarray, down: np.ndarray) -> np.ndarray:
    """World-to-camera rotation for a camera at ``center`` looking at ``target``, its image
    y axis as close to ``down`` as possible."""
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(down, z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def _cast(origin: np.ndarray, dirs: np.ndarray, walls: list[_Wall]) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of rays ``origin + t dirs`` (dirs (3, N), world) with the walls.

    Returns t (N,) float64 (inf on a miss) and the wall index (N,) int (-1 on a miss).
    """
    n_rays = dirs.shape[1]
    best_t = np.full(n_rays, np.inf)
    best_w = np.full(n_rays, -1, dtype=np.int64)
    for i, w in enumerate(walls):
        denom = w.n @ dirs
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w.d - w.n @ origin) / denom
        ok = np.isfinite(t) & (t > 1e-9)
        if w.e is not None:
            # Position along the wall away from the fold; a tiny tolerance so the fold itself
            # belongs to both walls.
            along = (origin - w.origin) @ w.e + t * (w.e @ dirs)
            ok &= along >= -1e-9
        better = ok & (t < best_t)
        best_t[better] = t[better]
        best_w[better] = i
    return best_t, best_w


def _line_through(p1: np.ndarray, p2: np.ndarray, neg_point: np.ndarray) -> np.ndarray:
    """Normalised line through two image points, negative at ``neg_point`` (all (x, y))."""
    line = np.cross([p1[0], p1[1], 1.0], [p2[0], p2[1], 1.0])
    line = line / math.hypot(line[0], line[1])
    if line @ [neg_point[0], neg_point[1], 1.0] > 0:
        line = -line
    return line


# --------------------------------------------------------------------------- the set-up
class VirtualProCam:
    """A virtual projector and camera looking at a two-wall corner (a :class:`rtdefocus.ProCam`).

    Parameters
    ----------
    preset : one of :data:`PRESETS` ("cubicle", "pillar", "flat", "tilted", "offcenter") or a
        :class:`Scene`.
    projector_size, camera_size : (width, height) in pixels.
    noise : standard deviation of the camera's Gaussian noise, as a fraction of full scale
        (linear light, before the camera response).
    seed : seed of the noise (and of the faint wall texture).
    projector_gamma : projector response, linear light = (v / 255) ** projector_gamma.
    camera_gamma : camera response, code = 255 · L ** (1 / camera_gamma).
    ambient : ambient irradiance on the walls, relative to a full-on projector (~0.85 mean).
    aperture : "disc" (pillbox) or "hex" (regular hexagon of circumradius r).
    chromatic : per-channel (R, G, B) scale of the blur radius (lateral chromatic defocus).
    texture : add a faint (±4 %) smooth albedo texture to the walls.
    exposure : camera exposure (linear gain before the response curve); None (default) sets
        it so a full white frame peaks at 95 % of full scale.

    Attributes
    ----------
    projector_size, camera_size : (width, height).
    truth : :class:`GroundTruth`.
    scene : the :class:`Scene`.
    """

    def __init__(self, preset: str | Scene = "cubicle", *, projector_size: tuple[int, int] = (800, 600),
                 camera_size: tuple[int, int] = (1280, 960), noise: float = 0.006, seed: int = 0,
                 projector_gamma: float = 1.0, camera_gamma: float = 1.0, ambient: float = 0.02,
                 aperture: str = "disc", chromatic: tuple[float, float, float] = (1.0, 1.0, 1.0),
                 texture: bool = False, exposure: float | None = None):
        if isinstance(preset, Scene):
            scene, name = preset, "custom"
        elif preset in PRESETS:
            scene, name = PRESETS[preset], preset
        else:
            raise InputError(f"unknown simulator preset {preset!r}; choose one of "
                             f"{', '.join(PRESETS)} or pass a sim.Scene")
        for what, size in (("projector_size", projector_size), ("camera_size", camera_size)):
            if len(size) != 2 or min(int(size[0]), int(size[1])) < 16:
                raise InputError(f"{what} must be (width, height) with both >= 16; got {size!r}")
        if aperture not in ("disc", "hex"):
            raise InputError(f"aperture must be 'disc' or 'hex'; got {aperture!r}")
        chromatic = tuple(float(c) for c in chromatic)
        if len(chromatic) != 3 or min(chromatic) <= 0:
            raise InputError(f"chromatic must be three positive radius scales (R, G, B); got {chromatic}")
        if projector_gamma <= 0 or camera_gamma <= 0 or (exposure is not None and exposure <= 0):
            raise InputError("projector_gamma, camera_gamma and exposure must be > 0; got "
                             f"{projector_gamma}, {camera_gamma}, {exposure}")
        if noise < 0 or ambient < 0:
            raise InputError(f"noise and ambient must be >= 0; got {noise}, {ambient}")

        self.scene = scene
        self.preset = name
        self.projector_size = (int(projector_size[0]), int(projector_size[1]))
        self.camera_size = (int(camera_size[0]), int(camera_size[1]))
        self.noise = float(noise)
        self.ambient = float(ambient)
        self.aperture = aperture
        self.chromatic = chromatic
        self.projector_gamma = float(projector_gamma)
        self.camera_gamma = float(camera_gamma)
        self.exposure = None if exposure is None else float(exposure)
        self.texture = bool(texture)
        self._rng = np.random.default_rng(seed)
        tex_rng = np.random.default_rng([seed, 7])
        self._tex_phase = tex_rng.uniform(0, 2 * math.pi, size=(2, 3))
        self._proj_lut = ((np.arange(256) / 255.0) ** self.projector_gamma).astype(np.float32)

        t0 = time.perf_counter()
        self._build_geometry()
        self._build_projector_space()
        self._build_camera_maps()
        self._build_truth()
        self._build_blur_plan()
        log.debug("VirtualProCam(%s) built in %.2f s; green radius %.2f..%.2f px", name,
                  time.perf_counter() - t0, float(self.truth.radius_map.min()),
                  float(self.truth.radius_map.max()))

    # ----------------------------------------------------------------------- construction
    def _build_geometry(self) -> None:
        sc = self.scene
        wp, hp = self.projector_size
        f = 1.2 * wp                       # throw ratio ~1.2: frame ~2.1 m wide at 2.5 m
        self.K_proj = np.array([[f, 0.0, (wp - 1) / 2.0], [0.0, f, (hp - 1) / 2.0], [0.0, 0.0, 1.0]])
        self.R_proj = _rot_z(sc.roll_deg)  # world -> projector
        # Fold: a vertical world line crossing the projector's centre row at fold_x_frac.
        ray = self.R_proj.T @ np.linalg.solve(self.K_proj, [sc.fold_x_frac * wp - 0.5,
                                                            (hp - 1) / 2.0, 1.0])
        fold_pt = ray * (sc.fold_depth / ray[2])
        fold_pt[1] = 0.0
        self._fold_point = fold_pt
        up = np.array([0.0, 1.0, 0.0])
        walls = []
        if sc.kind == "flat":
            a = math.radians(sc.wall_angles_deg[0])
            e = np.array([math.cos(a), 0.0, math.sin(a)])
            walls.append(self._make_wall(fold_pt, e, up, half=False))
        elif sc.kind in ("concave", "convex"):
            sgn = -1.0 if sc.kind == "concave" else 1.0   # concave: walls come towards us
            a0, a1 = (math.radians(v) for v in sc.wall_angles_deg)
            walls.append(self._make_wall(fold_pt, np.array([-math.cos(a0), 0.0, sgn * math.sin(a0)]),
                                         up, half=True))
            walls.append(self._make_wall(fold_pt, np.array([math.cos(a1), 0.0, sgn * math.sin(a1)]),
                                         up, half=True))
        else:
            raise InputError(f"Scene.kind must be 'concave', 'convex' or 'flat'; got {sc.kind!r}")
        self._walls = walls

        # Lens: focus and aperture from the wanted radius range unless the scene fixes them.
        gx, gy = np.meshgrid(np.linspace(-0.5, wp - 0.5, 65), np.linspace(-0.5, hp - 0.5, 49))
        depth = self._depths_of(np.stack([gx.ravel(), gy.ravel()]))
        d_min, d_max = float(depth.min()), float(depth.max())
        r_lo, r_hi = sc.blur_range_px
        fd = sc.focus_distance
        if fd is None:
            # r ∝ 1/fd - 1/D with fd < d_min: r_hi/r_lo = ratio fixes fd.
            ratio = r_hi / r_lo
            fd = (ratio - 1.0) / (ratio / d_min - 1.0 / d_max)
        a = sc.aperture_radius
        if a is None:
            a = r_hi / (1.2 * 800 * max(abs(1 / fd - 1 / d_min), abs(1 / fd - 1 / d_max)))
        self.focus_distance, self.aperture_radius = float(fd), float(a)

    @staticmethod
    def _make_wall(origin, e, up, half: bool) -> _Wall:
        n = np.cross(e, up)
        n /= np.linalg.norm(n)
        if n @ (np.zeros(3) - origin) < 0:       # face the projector
            n = -n
        return _Wall(n=n, d=float(n @ origin), origin=origin.copy(), e=e.copy() if half else None)

    def _build_projector_space(self) -> None:
        wp, hp = self.projector_size
        # Margin of projector space beyond the frame: blurred light spills over the frame edge.
        r_max = float(self._radius_of(self._depths_of(np.array(
            [[-0.5, wp - 0.5, -0.5, wp - 0.5, self.scene.fold_x_frac * wp],
             [-0.5, -0.5, hp - 0.5, hp - 0.5, hp / 2]]))).max())
        self._margin = m = int(math.ceil(r_max * max(self.chromatic) * 1.25)) + 3
        gx, gy = np.meshgrid(np.arange(-m, wp + m, dtype=np.float64),
                             np.arange(-m, hp + m, dtype=np.float64))
        shape = gx.shape
        depth, wall, pts_w, dirs_p = self._cast_projector(np.stack([gx.ravel(), gy.ravel()]))
        if np.any(wall < 0):
            raise InputError(f"scene {self.preset!r}: {int((wall < 0).sum())} projector rays miss the "
                             "walls; make the walls less oblique or the fold nearer")
        self._pad_depth = depth.reshape(shape)
        self._pad_plane = wall.reshape(shape).astype(np.int8)
        # Irradiance (module docstring): cos(theta) / (cos(psi) D^2); |d_p| = 1/cos(psi) as z_p = 1.
        normals_p = (self.R_proj @ np.stack([w.n for w in self._walls], axis=1))[:, wall]
        len_p = np.sqrt(np.sum(dirs_p * dirs_p, axis=0))
        cos_theta = np.abs(np.sum(dirs_p * normals_p, axis=0)) / len_p
        shade = (cos_theta * len_p / depth ** 2).reshape(shape)
        shade *= SHADING_MEAN / shade[m:m + hp, m:m + wp].mean()
        self._pad_shade = shade.astype(np.float32)
        self._pad_albedo = self._albedo(pts_w, wall).T.reshape(shape + (3,)).astype(np.float32)
        r = self._radius_of(self._pad_depth)
        self._pad_radius = np.stack([r * c for c in self.chromatic]).astype(np.float32)

    def _cast_projector(self, pix: np.ndarray):
        """Cast projector pixels (2, N) (x, y); returns depth (N,), wall (N,), world points
        (3, N) and projector-frame directions (3, N) with z = 1."""
        dirs_p = np.linalg.inv(self.K_proj) @ np.vstack([pix, np.ones((1, pix.shape[1]))])
        dirs_w = self.R_proj.T @ dirs_p
        t, wall = _cast(np.zeros(3), dirs_w, self._walls)
        return t, wall, t * dirs_w, dirs_p            # t is the depth along the projector axis

    def _depths_of(self, pix: np.ndarray) -> np.ndarray:
        t, wall, _, _ = self._cast_projector(pix)
        if np.any(wall < 0):
            raise InputError(f"scene {self.preset!r}: the projector frame misses the walls; "
                             "make the walls less oblique or the fold nearer")
        return t

    def _radius_of(self, depth: np.ndarray) -> np.ndarray:
        # Thin lens, DESIGN.md §3: r = A f |1/D_focus - 1/D| in projector px.
        return self.aperture_radius * self.K_proj[0, 0] * np.abs(1.0 / self.focus_distance - 1.0 / depth)

    def _albedo(self, pts_w: np.ndarray, wall: np.ndarray) -> np.ndarray:
        """RGB albedo (3, N) of world points (3, N) on the given walls (0 where wall = -1)."""
        base = np.asarray(self.scene.albedo, dtype=np.float64)
        out = np.zeros((3, wall.size))
        hit = wall >= 0
        out[:, hit] = base[wall[hit]].T
        if self.texture and hit.any():
            s = np.zeros(wall.size)
            for i, w in enumerate(self._walls):
                sel = wall == i
                e = w.e if w.e is not None else np.cross([0.0, 1.0, 0.0], w.n)
                s[sel] = e @ (pts_w[:, sel] - w.origin[:, None])
            y, ph = pts_w[1], self._tex_phase
            # Faint (about ±4 %) smooth pattern fixed to the wall, in metres along it.
            tex = 1.0 + 0.02 * (np.sin(2 * math.pi * s / 0.37 + ph[0, 0])
                                * np.sin(2 * math.pi * y / 0.29 + ph[0, 1])
                                + np.sin(2 * math.pi * (s + y) / 0.61 + ph[0, 2]))
            out[:, hit] *= tex[hit]
        return out

    def _build_camera_maps(self) -> None:
        sc = self.scene
        wc, hc = self.camera_size
        wp, hp = self.projector_size
        m = self._margin
        # The camera is mounted on the projector: its offset and its "down" are given in the
        # projector's frame, so a rolled projector (the tilted preset) rolls the camera too.
        center = self.R_proj.T @ np.asarray(sc.camera_position, dtype=np.float64)
        down = self.R_proj.T @ np.array([0.0, 1.0, 0.0])
        # Outline of the lit area (frame + spill margin), as 3-D points (3, N).
        n = 200
        lo_x, hi_x, lo_y, hi_y = -m, wp - 1 + m, -m, hp - 1 + m
        sx, sy = np.linspace(lo_x, hi_x, n), np.linspace(lo_y, hi_y, n)
        edge = np.concatenate([np.stack([sx, np.full(n, lo_y)]), np.stack([sx, np.full(n, hi_y)]),
                               np.stack([np.full(n, lo_x), sy]), np.stack([np.full(n, hi_x), sy])],
                              axis=1)
        _, _, outline, _ = self._cast_projector(edge)
        # Aim at the centre of the outline's angular bounding box, then choose the focal length
        # so the outline fills 85 % of the frame: the whole lit area with margin.
        target = outline.mean(axis=1)
        for _ in range(3):
            R = _look_at(center, target, down)
            pc = R @ (outline - center[:, None])
            xn, yn = pc[0] / pc[2], pc[1] / pc[2]
            mid = np.array([(xn.min() + xn.max()) / 2, (yn.min() + yn.max()) / 2, 1.0])
            target = center + R.T @ mid
        R = _look_at(center, target, down)
        pc = R @ (outline - center[:, None])
        xn, yn = pc[0] / pc[2], pc[1] / pc[2]
        fc = 0.85 * min((wc / 2) / np.abs(xn).max(), (hc / 2) / np.abs(yn).max())
        self.K_cam = np.array([[fc, 0.0, (wc - 1) / 2.0], [0.0, fc, (hc - 1) / 2.0], [0.0, 0.0, 1.0]])
        self.R_cam = R                               # world -> camera
        self.t_cam = -R @ center

        # Ray-cast every camera pixel to the walls, then to projector pixel coordinates.
        gx, gy = np.meshgrid(np.arange(wc, dtype=np.float64), np.arange(hc, dtype=np.float64))
        dirs_w = (R.T @ np.linalg.inv(self.K_cam)) @ np.stack([gx.ravel(), gy.ravel(),
                                                                np.ones(gx.size)])
        t, wall = _cast(center, dirs_w, self._walls)
        hit = wall >= 0
        t = np.where(hit, t, 1.0)
        pts = center[:, None] + t * dirs_w
        xp = self.K_proj @ (self.R_proj @ pts)
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = xp[0] / xp[2], xp[1] / xp[2]
        # Shadow test: the projector's own ray must reach this very point first (t = 1).
        tp, _ = _cast(np.zeros(3), pts, self._walls)
        lit = hit & (xp[2] > 0) & (np.abs(tp - 1.0) < 1e-6)
        inside = lit & (u >= -m) & (u <= wp - 1 + m) & (v >= -m) & (v <= hp - 1 + m)
        self._map_x = np.where(inside, u + m, _OUTSIDE).reshape(hc, wc).astype(np.float32)
        self._map_y = np.where(inside, v + m, _OUTSIDE).reshape(hc, wc).astype(np.float32)
        self._cam_albedo = self._albedo(pts, np.where(hit, wall, -1)).T.reshape(hc, wc, 3)
        self._cam_plane = np.where(hit, wall, -1).reshape(hc, wc).astype(np.int8)
        in_frame = lit & (u >= -0.5) & (u <= wp - 0.5) & (v >= -0.5) & (v <= hp - 0.5)
        self._cam_in_frame = in_frame.reshape(hc, wc)
        if self.exposure is None:
            # Auto-exposure: a full white frame peaks at 95 % of full scale (no clipping).
            peak = float(np.max(self._pad_albedo * (self._pad_shade[..., None] + self.ambient)))
            self.exposure = 0.95 / peak
        self._cam_albedo = (self.exposure * self._cam_albedo).astype(np.float32)

    def _build_truth(self) -> None:
        wp, hp = self.projector_size
        m = self._margin
        fr = (slice(m, m + hp), slice(m, m + wp))
        R_cp = self.R_cam @ self.R_proj.T
        t_cp = self.t_cam.copy()                     # projector centre is the world origin
        planes, hs = [], []
        Kp_inv = np.linalg.inv(self.K_proj)
        for w in self._walls:
            n_p = self.R_proj @ w.n
            planes.append(np.concatenate([n_p, [w.d]]))
            H = self.K_cam @ (R_cp + np.outer(t_cp, n_p) / w.d) @ Kp_inv
            hs.append(H / H[2, 2])
        fold_proj = fold_cam = None
        if len(self._walls) == 2:
            f0 = self._fold_point
            p_hi, p_lo = f0 + [0.0, -1.0, 0.0], f0 + [0.0, 1.0, 0.0]
            inside0 = f0 + 0.3 * self._walls[0].e + [0.0, 0.0, 0.0]

            def proj(X):
                x = self.K_proj @ (self.R_proj @ X)
                return x[:2] / x[2]

            def cam(X):
                x = self.K_cam @ (self.R_cam @ X + self.t_cam)
                return x[:2] / x[2]

            fold_proj = _line_through(proj(p_hi), proj(p_lo), proj(inside0))
            fold_cam = _line_through(cam(p_hi), cam(p_lo), cam(inside0))
        shade = self._pad_shade[fr]
        alb = self._pad_albedo[fr]
        self.truth = GroundTruth(
            radius_map=self._pad_radius[1][fr].copy(),
            radius_rgb=self._pad_radius[:, fr[0], fr[1]].copy(),
            plane_map=self._pad_plane[fr].copy(),
            depth_map=self._pad_depth[fr].astype(np.float32),
            fold_proj=fold_proj, fold_cam=fold_cam,
            H_cam_from_proj=np.stack(hs),
            albedo_proj=(self.exposure * alb * shade[..., None]).astype(np.float32),
            ambient_proj=(self.exposure * alb * self.ambient).astype(np.float32),
            K_proj=self.K_proj.copy(), K_cam=self.K_cam.copy(),
            R_cam_from_proj=R_cp, t_cam_from_proj=t_cp, planes_proj=np.stack(planes),
            focus_distance=self.focus_distance,
            blur_scale=self.aperture_radius * self.K_proj[0, 0],
            chromatic=self.chromatic, aperture=self.aperture,
            projector_gamma=self.projector_gamma, camera_gamma=self.camera_gamma,
            exposure=self.exposure,
            extra={"margin": m, "camera_in_frame": self._cam_in_frame,
                   "camera_plane_map": self._cam_plane},
        )

    def _build_blur_plan(self) -> None:
        """Per radius-grid level and row strip: the pixels that use it and their blend weights."""
        plan = []
        groups: dict[float, list[int]] = {}
        for c, s in enumerate(self.chromatic):
            groups.setdefault(s, []).append(c)
        hpad = self._pad_radius.shape[1]
        strip = 48     # row strips keep each level's band tight when the fold is not vertical
        for chans in groups.values():
            q = self._pad_radius[chans[0]].astype(np.float64) / RADIUS_STEP
            levels = []
            for j in range(int(math.floor(q.min())), int(math.floor(q.max())) + 2):
                w = 1.0 - np.abs(q - j)      # tent weight: the same blend as blend_kernel()
                mask = w > 0
                if not mask.any():
                    continue
                ker = _level_kernel(j, self.aperture)
                # cv2.filter2D correlates: flip the kernel to convolve, O(x) = sum_u k(u) P(x - u).
                flipped = np.asarray(ker[::-1, ::-1], dtype=np.float32)
                # OpenCV filters kernels of area >= 130 through a DFT, slow on these narrow
                # bands; row pieces of smaller area take the direct path (5-8x faster).
                k = flipped.shape[0]
                rows_per = max(1, min(k, 129 // k))
                pieces = [(a, np.ascontiguousarray(flipped[a:a + rows_per]))
                          for a in range(0, k, rows_per)]
                for s0 in range(0, hpad, strip):
                    sm = mask[s0:s0 + strip]
                    rows, cols = np.flatnonzero(sm.any(axis=1)), np.flatnonzero(sm.any(axis=0))
                    if rows.size == 0:
                        continue
                    y0, y1 = s0 + rows[0], s0 + rows[-1] + 1
                    x0, x1 = cols[0], cols[-1] + 1
                    wc = np.where(mask[y0:y1, x0:x1], w[y0:y1, x0:x1], 0.0).astype(np.float32)
                    levels.append(((y0, y1, x0, x1), wc[..., None], k // 2, pieces))
            plan.append((chans, levels))
        self._blur_plan = plan
        self._kmax = max(lv[2] for _, lvs in plan for lv in lvs)

    # ----------------------------------------------------------------------- rendering
    def _blur_padded(self, lin: np.ndarray) -> np.ndarray:
        """F P on the padded projector grid: (Hp+2m, Wp+2m, 3) float32 from (Hp, Wp, 3) linear P."""
        import cv2

        wp, hp = self.projector_size
        m, h = self._margin, self._kmax
        src = np.zeros((hp + 2 * (m + h), wp + 2 * (m + h), 3), np.float32)
        src[m + h:m + h + hp, m + h:m + h + wp] = lin   # no light comes from outside the frame
        out = np.zeros((hp + 2 * m, wp + 2 * m, 3), np.float32)
        for chans, levels in self._blur_plan:
            sel = slice(chans[0], chans[-1] + 1) if chans == list(range(chans[0], chans[-1] + 1)) \
                else chans
            for (y0, y1, x0, x1), w, k, pieces in levels:
                ny, nx = y1 - y0, x1 - x0
                acc = None
                for a, piece in pieces:
                    # Rows a.. of the flipped kernel, anchored at its first row: the crop starts
                    # a - k rows below the band (out (Y, X) is src (Y + h, X + h)).
                    r0 = y0 + h + a - k
                    crop = np.ascontiguousarray(
                        src[r0:r0 + ny + piece.shape[0] - 1, x0 + h - k:x1 + h + k][..., sel])
                    b = cv2.filter2D(crop, -1, piece, anchor=(k, 0), borderType=cv2.BORDER_CONSTANT)
                    b = b[:ny, k:k + nx]
                    acc = b if acc is None else acc + b
                if acc.ndim == 2:
                    acc = acc[..., None]
                np.multiply(acc, w, out=acc)
                out[y0:y1, x0:x1, sel] += acc
        return out

    def defocus(self, lin: np.ndarray) -> np.ndarray:
        """Apply the true kernel field F to a projector image in linear light.

        Parameters
        ----------
        lin : (Hp, Wp, 3) float array, linear light (P outside the frame is 0).

        Returns
        -------
        (Hp, Wp, 3) float32, ``(F P)(x) = sum_u k_x(u) P(x - u)`` with ``k_x`` =
        ``truth.kernel_at(x, y, channel=c)`` per channel.
        """
        wp, hp = self.projector_size
        lin = np.asarray(lin, dtype=np.float32)
        if lin.shape != (hp, wp, 3):
            raise InputError(f"defocus() needs a ({hp}, {wp}, 3) linear image; got {lin.shape}")
        m = self._margin
        return self._blur_padded(lin)[m:m + hp, m:m + wp]

    def capture(self, pattern: np.ndarray, sharp: bool = False) -> np.ndarray:
        """Show ``pattern`` on the projector and return the camera frame.

        Parameters
        ----------
        pattern : (Hp, Wp, 3) uint8 RGB projector image (a (Hp, Wp) gray one is expanded).
        sharp : render the ideal in-focus display: no blur and no noise, all else equal.

        Returns
        -------
        (Hc, Wc, 3) uint8 RGB camera frame.
        """
        import cv2

        pattern = check_pattern(pattern, self.projector_size)
        lin = self._proj_lut[pattern]
        m = self._margin
        if sharp:
            irr = np.zeros(self._pad_shade.shape + (3,), np.float32)
            irr[m:-m, m:-m] = lin
        else:
            irr = self._blur_padded(lin)
        irr *= self._pad_shade[..., None]
        cam = cv2.remap(irr, self._map_x, self._map_y, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        cam += self.ambient
        cam *= self._cam_albedo                       # Lambertian walls, exposure folded in
        if not sharp and self.noise > 0:
            cam += self._rng.standard_normal(cam.shape, dtype=np.float32) * np.float32(self.noise)
        np.clip(cam, 0.0, 1.0, out=cam)
        if self.camera_gamma != 1.0:
            cam = cam ** np.float32(1.0 / self.camera_gamma)
        return np.rint(cam * 255.0).astype(np.uint8)

    def __repr__(self) -> str:
        return (f"VirtualProCam({self.preset!r}, projector {self.projector_size[0]}x"
                f"{self.projector_size[1]}, camera {self.camera_size[0]}x{self.camera_size[1]})")


# --------------------------------------------------------------------------- patterns, timing
def test_pattern(name: str, size: tuple[int, int]) -> np.ndarray:
    """A named test pattern for a projector of ``size`` = (width, height).

    ``checker``: 40 px squares; ``lines``: 2 px white grid lines every 50 px on black;
    ``dots``: 5×5 px white dots every 60 px on black. Returns (H, W, 3) uint8 RGB.
    """
    w, h = int(size[0]), int(size[1])
    if w <= 0 or h <= 0:
        raise InputError(f"pattern size must be positive (width, height); got {size!r}")
    y, x = np.mgrid[0:h, 0:w]
    if name == "checker":
        img = ((x // 40 + y // 40) % 2).astype(np.uint8) * 255
    elif name == "lines":
        img = (((x - 25) % 50 < 2) | ((y - 25) % 50 < 2)).astype(np.uint8) * 255
    elif name == "dots":
        img = (((x - 28) % 60 < 5) & ((y - 28) % 60 < 5)).astype(np.uint8) * 255
    else:
        raise InputError(f"unknown test pattern {name!r}; choose one of {', '.join(PATTERNS)}")
    return np.repeat(img[:, :, None], 3, axis=2)


test_pattern.__test__ = False   # not a pytest test, despite the name


def capture_seconds(procam: VirtualProCam | None = None, repeats: int = 5,
                    sharp: bool = False) -> float:
    """Median wall time (s) of one ``capture`` of the checker pattern (after one warm-up)."""
    procam = procam or VirtualProCam("cubicle")
    pat = test_pattern("checker", procam.projector_size)
    procam.capture(pat, sharp=sharp)
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        procam.capture(pat, sharp=sharp)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
