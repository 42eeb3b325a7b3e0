"""The virtual projector and camera (:class:`VirtualProCam`, a :class:`rtdefocus.ProCam`).

Radiometry, from first principles:

* Irradiance: pixels of an ideal projector carry equal flux, i.e. a radiant intensity
  proportional to 1/cos^3(psi) (psi the angle to the axis). At distance d = D/cos(psi) on a
  surface tilted by theta to the ray that gives E = I cos(theta)/d^2 ∝ cos(theta) / (cos(psi) D^2),
  which is uniform on a screen square to the axis. It is normalised to mean ``SHADING_MEAN``.
* Lambertian walls of (slightly coloured) albedo, uniform ambient irradiance, projector and
  camera response curves (gamma), camera exposure, Gaussian camera noise, uint8 quantisation.

The projector-space irradiance is computed on the frame plus a margin (blurred light spills
over the frame edge, :class:`~rtdefocus.sim.optics.BlurPlan`) and resampled into the camera
through per-pixel maps found by ray casting once at construction.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import cv2
import numpy as np

from ..calib.radiometry.camera_response import linear_to_srgb, srgb_to_linear
from ..checks import check_choice
from ..errors import InputError
from ..planar import canonical_line, undistort_points
from ..procam import check_pattern
from .changes import SetupChanges
from .memo import LastRender
from .optics import BlurPlan
from .scene import (
    PRESETS,
    ROOM_KINDS,
    Scene,
    cast_rays,
    line_through,
    look_at,
    plane_order,
    room_folds,
    rot_z,
    scene_walls,
)
from .texture import TEXTURES, wall_albedo
from .truth import GroundTruth, projector_map

log = logging.getLogger(__name__)

SHADING_MEAN = 0.85         # mean relative irradiance over the projector frame
_OUTSIDE = -1.0e5           # remap coordinate of camera pixels that see no projector light

#: An ordinary webcam in a lit office (the ``"webcam"`` presets of :class:`VirtualProCam`).
WEBCAM = {"camera_response": "srgb", "projector_gamma": 2.2, "ambient": 0.05, "texture": 0.05,
          "noise": 2.0 / 255.0, "aperture": "hex", "chromatic": (1.03, 1.0, 0.97),
          "distortion": (-0.05, 0.0)}
_DEFAULTS = {"camera_response": "gamma", "projector_gamma": 1.0, "ambient": None,
             "texture": None, "noise": 0.006, "aperture": "disc", "chromatic": (1.0, 1.0, 1.0),
             "distortion": (0.0, 0.0)}


class VirtualProCam(SetupChanges):
    """A virtual projector and camera looking at walls: a two-wall corner, one plane, or a
    room's three planes (a :class:`rtdefocus.ProCam`).

    Parameters
    ----------
    preset : one of :data:`PRESETS` ("cubicle", "pillar", "flat", "tilted", "offcenter",
        "fabric", "u_cubicle", "corner_ceiling"; walls that are planes only nearly: "bowed",
        "sagging", "gap"; a camera exposed too long: "clipping") or a :class:`Scene`.
    projector_size, camera_size : (width, height) in pixels.
    noise : standard deviation of the camera's Gaussian noise, as a fraction of full scale
        (linear light, before the camera response); default 0.006. The options below that
        default to None take the preset's value (the plain defaults given here, or
        :data:`WEBCAM`).
    seed : seed of the noise (and of the faint wall texture).
    projector_gamma : projector response, linear light = (v / 255) ** projector_gamma (1.0).
    camera_gamma : camera response, code = 255 · L ** (1 / camera_gamma).
    ambient : ambient irradiance on the walls, relative to a full-on projector (~0.85 mean);
        None: the preset's (the webcam presets' 0.05, else the scene's ``Scene.ambient``, else
        0.02).
    aperture : "disc" (pillbox, default), "hex" (regular hexagon of circumradius r) or
        "triangle" (equilateral, circumradius r, one vertex up: not point-symmetric).
    chromatic : per-channel (R, G, B) scale of the blur radius (lateral chromatic defocus);
        (1, 1, 1).
    texture : printed albedo texture of the walls: False / "none", True / "faint" (±4 %,
        smooth), a number (the smooth texture's amplitude, a fraction), "fabric" (a woven
        partition: ±8 % weave of 3 cm period on the left wall; a coloured striped poster
        (albedo × 0.45–1.0 per channel) and soft wood-grain bands on the right one; the faint
        texture on both); None (default): the preset's (``Scene.texture``; 5 % for the webcam
        presets). The ground truth's ``albedo_proj`` includes it.
    exposure : camera exposure (linear gain before the response curve); None (default) sets
        it so a full white frame peaks at 95 % of full scale.
    camera_response : ``"gamma"`` (default: code = 255 · L ** (1 / camera_gamma)) or ``"srgb"``
        (the sRGB transfer curve of a webcam; camera_gamma is then ignored).
    exposure_drift : relative change of the camera's gain per capture (auto-exposure that
        could not be locked): capture n is taken with gain ``exp(exposure_drift · n)`` times a
        seeded jitter of 10 % of that step; 0 (default) holds the exposure still.
    distortion : (k1, k2) radial distortion of the camera lens about the image centre, radius
        normalised to 1 at the frame corners (:func:`rtdefocus.planar.distort_points`);
        negative k1 is barrel distortion. The truth's homographies and fold are in the ideal
        (undistorted) camera pixels.

    A preset named ``"webcam"`` (or ``"webcam_<scene>"``: ``webcam_pillar``, ``webcam_tilted``,
    ``webcam_offcenter``, ``webcam_flat``, ``webcam_u_cubicle``, ``webcam_bowed``,
    ``webcam_sagging``, ...) is an ordinary webcam in a lit office
    (:data:`WEBCAM`): sRGB camera, projector gamma 2.2, 5 % ambient, 5 % wall texture, noise
    2/255, a slightly chromatic hexagonal aperture and k1 = -0.05. Arguments that are given
    (not None) override the preset's.

    Attributes
    ----------
    projector_size, camera_size : (width, height).
    truth : :class:`GroundTruth`.
    scene : the :class:`Scene`.
    """

    def __init__(self, preset: str | Scene = "cubicle", *, projector_size: tuple[int, int] = (800, 600),
                 camera_size: tuple[int, int] = (1280, 960), noise: float | None = None,
                 seed: int = 0, projector_gamma: float | None = None, camera_gamma: float = 1.0,
                 ambient: float | None = None, aperture: str | None = None,
                 chromatic: tuple[float, float, float] | None = None,
                 texture: bool | float | str | None = None, exposure: float | None = None,
                 camera_response: str | None = None, exposure_drift: float = 0.0,
                 distortion: tuple[float, float] | None = None):
        webcam = isinstance(preset, str) and (preset == "webcam" or preset.startswith("webcam_"))
        # None: the preset's value (WEBCAM for the webcam presets), else the plain default.
        base = WEBCAM if webcam else _DEFAULTS
        given = dict(noise=noise, projector_gamma=projector_gamma, ambient=ambient,
                     aperture=aperture, chromatic=chromatic, texture=texture,
                     camera_response=camera_response, distortion=distortion)
        given = {k: (base.get(k, _DEFAULTS[k]) if v is None else v) for k, v in given.items()}
        (noise, projector_gamma, ambient, aperture, chromatic, texture, camera_response,
         distortion) = (given[k] for k in ("noise", "projector_gamma", "ambient", "aperture",
                                           "chromatic", "texture", "camera_response", "distortion"))
        if webcam:
            scene_name = preset[len("webcam_"):] if preset != "webcam" else "cubicle"
            if scene_name not in PRESETS:
                raise InputError(f"unknown webcam scene {scene_name!r} in preset {preset!r}; use "
                                 f"webcam or webcam_<scene> with a scene among {', '.join(PRESETS)}")
            scene, name = PRESETS[scene_name], preset
        elif isinstance(preset, Scene):
            scene, name = preset, "custom"
        elif preset in PRESETS:
            scene, name = PRESETS[preset], preset
        else:
            raise InputError(f"unknown simulator preset {preset!r}; choose one of "
                             f"{', '.join(PRESETS)} or pass a sim.Scene")
        for what, size in (("projector_size", projector_size), ("camera_size", camera_size)):
            if len(size) != 2 or min(int(size[0]), int(size[1])) < 16:
                raise InputError(f"{what} must be (width, height) with both >= 16; got {size!r}")
        check_choice(aperture, ("disc", "hex", "triangle"), "aperture")
        chromatic = tuple(float(c) for c in chromatic)
        if len(chromatic) != 3 or min(chromatic) <= 0:
            raise InputError(f"chromatic must be three positive radius scales (R, G, B); got {chromatic}")
        if projector_gamma <= 0 or camera_gamma <= 0 or (exposure is not None and exposure <= 0):
            raise InputError("projector_gamma, camera_gamma and exposure must be > 0; got "
                             f"{projector_gamma}, {camera_gamma}, {exposure}")
        if ambient is None:
            ambient = 0.02 if scene.ambient is None else scene.ambient
        if texture is None:
            texture = scene.texture
        # A name, a bool or the smooth texture's amplitude; "fabric" has the faint one too.
        if isinstance(texture, (bool, np.bool_)):
            texture = "faint" if texture else "none"
        if isinstance(texture, (int, float)):
            if not 0 <= float(texture) <= 0.5:
                raise InputError(f"a texture amplitude must be in [0, 0.5]; got {texture}")
            texture_amplitude = float(texture)
            texture = "faint" if texture_amplitude > 0 else "none"
        elif texture in TEXTURES:
            texture_amplitude = 0.0 if texture == "none" else 0.04
        else:
            raise InputError(f"texture must be one of {TEXTURES}, True/False or an amplitude in "
                             f"[0, 0.5]; got {texture!r}")
        if not scene.exposure_gain > 0:
            raise InputError(f"Scene.exposure_gain must be > 0; got {scene.exposure_gain}")
        if noise < 0 or ambient < 0:
            raise InputError(f"noise and ambient must be >= 0; got {noise}, {ambient}")
        check_choice(camera_response, ("gamma", "srgb"), "camera_response")
        distortion = tuple(float(k) for k in distortion)
        if len(distortion) != 2 or max(abs(k) for k in distortion) > 0.3:
            raise InputError(f"distortion must be (k1, k2) with |k| <= 0.3; got {distortion}")

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
        self.texture = texture
        self.texture_amplitude = texture_amplitude
        self.camera_response = camera_response
        self.exposure_drift = float(exposure_drift)
        self.distortion = distortion
        self._captures = 0
        self._drift_rng = np.random.default_rng([seed, 11])
        self._gain = 1.0
        # Camera code -> linear light at the code's centre (the inverse response; truth).
        if camera_response == "srgb":
            self._cam_inverse = srgb_to_linear(np.arange(256) / 255.0)
        else:
            self._cam_inverse = (np.arange(256) / 255.0) ** self.camera_gamma
        self._rng = np.random.default_rng(seed)
        tex_rng = np.random.default_rng([seed, 7])
        self._tex_phase = tex_rng.uniform(0, 2 * math.pi, size=(2, 3))
        self._proj_lut = ((np.arange(256) / 255.0) ** self.projector_gamma).astype(np.float32)

        t0 = time.perf_counter()
        self._proj_center = np.zeros(3)    # world position of the projector (moved by bump())
        self._build_geometry()
        self._build_projector_space()
        self._place_camera()
        self._build_camera_maps()
        self._build_truth()
        self._blur = BlurPlan(self._pad_radius, self.chromatic, self.aperture)
        log.debug("VirtualProCam(%s) built in %.2f s; green radius %.2f..%.2f px", name,
                  time.perf_counter() - t0, float(self.truth.radius_map.min()),
                  float(self.truth.radius_map.max()))

    # ----------------------------------------------------------------------- construction
    def _build_geometry(self) -> None:
        sc = self.scene
        wp, hp = self.projector_size
        f = 1.2 * wp                       # throw ratio ~1.2: frame ~2.1 m wide at 2.5 m
        self.K_proj = np.array([[f, 0.0, (wp - 1) / 2.0], [0.0, f, (hp - 1) / 2.0], [0.0, 0.0, 1.0]])
        self.R_proj = rot_z(sc.roll_deg)  # world -> projector
        walls, self._fold_point = scene_walls(sc, self.K_proj, self.R_proj, self.projector_size)
        self._walls = walls
        self._room = sc.kind in ROOM_KINDS
        self._shaped = any(w.bow is not None or w.far for w in walls)
        #: walls that are planes of the set-up (a far wall seen through a gap is not one).
        self._n_walls = sum(not w.far for w in walls)
        if self._room and len(sc.albedo) < len(walls):
            raise InputError(f"scene of kind {sc.kind!r} needs {len(walls)} albedos; got {len(sc.albedo)}")

        # Lens: focus and aperture from the wanted radius range unless the scene fixes them.
        self._depth_range = d_min, d_max = self._frame_depth_range()
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

    def _frame_depth_range(self) -> tuple[float, float]:
        """Nearest and farthest depth (m, along the projector axis) over the projector frame."""
        wp, hp = self.projector_size
        gx, gy = np.meshgrid(np.linspace(-0.5, wp - 0.5, 65), np.linspace(-0.5, hp - 0.5, 49))
        depth = self._depths_of(np.stack([gx.ravel(), gy.ravel()]))
        if self._room:
            # 1/D is convex and piecewise affine over a room seen from inside: its extremes lie
            # at the frame corners (on the grid), on the folds or at the vertex.
            fold_depth = [(self.R_proj @ (f.points - self._proj_center).T)[2]
                          for f in self._room_folds()]
            depth = np.concatenate([depth] + fold_depth)
        return float(depth.min()), float(depth.max())

    def _room_folds(self):
        """:func:`~rtdefocus.sim.scene.room_folds` of the projector where it stands (that
        function places the projector at the origin), with the fold points in the world."""
        c = self._proj_center
        walls = [dataclasses.replace(w, d=float(w.d - w.n @ c), origin=w.origin - c)
                 for w in self._walls]
        return [dataclasses.replace(f, points=f.points + c)
                for f in room_folds(walls, self.K_proj, self.R_proj, self.projector_size)]

    def _build_projector_space(self) -> None:
        wp, hp = self.projector_size
        # Margin of projector space beyond the frame: blurred light spills over the frame edge.
        if self._room or self._shaped:
            # r is monotonic in 1/D (the focus lies in front of every wall): its extremes are
            # at the depth extremes; a bowed wall or a far wall may hold them off the corners.
            r_max = float(self._radius_of(np.array(self._depth_range)).max())
        else:
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
        if self._room:
            wall = self._number_planes(wall.reshape(shape)[m:m + hp, m:m + wp], wall)
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

    def _number_planes(self, frame_wall: np.ndarray, wall: np.ndarray) -> np.ndarray:
        """Put a room's walls in calibration order (:func:`~rtdefocus.sim.scene.plane_order`
        of the frame's labels ``frame_wall``); returns the labels ``wall`` renumbered."""
        order = plane_order(frame_wall, len(self._walls))
        self._walls = [self._walls[k] for k in order]
        new = np.empty(len(order), np.int64)
        new[order] = np.arange(len(order))
        return np.where(wall >= 0, new[np.maximum(wall, 0)], wall)

    def _cast_projector(self, pix: np.ndarray):
        """Cast projector pixels (2, N) (x, y); returns depth (N,), wall (N,), world points
        (3, N) and projector-frame directions (3, N) with z = 1."""
        dirs_p = np.linalg.inv(self.K_proj) @ np.vstack([pix, np.ones((1, pix.shape[1]))])
        dirs_w = self.R_proj.T @ dirs_p
        c = self._proj_center
        t, wall = cast_rays(c, dirs_w, self._walls)
        # t is the depth along the projector axis
        return t, wall, c[:, None] + t * dirs_w, dirs_p

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
        return wall_albedo(self.scene.albedo, self._walls, pts_w, wall,
                           amplitude=self.texture_amplitude, texture=self.texture,
                           phase=self._tex_phase)

    def _place_camera(self) -> None:
        """The camera's pose and intrinsics (``_cam_center``, ``R_cam``, ``t_cam``, ``K_cam``)."""
        sc = self.scene
        wc, hc = self.camera_size
        wp, hp = self.projector_size
        m = self._margin
        # The camera is mounted on the projector: its offset and its "down" are given in the
        # projector's frame, so a rolled projector (the tilted preset) rolls the camera too.
        center = self.R_proj.T @ np.asarray(sc.camera_position, dtype=np.float64)
        down = self.R_proj.T @ np.array([0.0, 1.0, 0.0])
        if self._room and any(w.n @ center < w.d for w in self._walls):
            raise InputError(f"scene {self.preset!r}: the camera is outside the room; put it "
                             "nearer the projector (Scene.camera_position)")
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
            R = look_at(center, target, down)
            pc = R @ (outline - center[:, None])
            xn, yn = pc[0] / pc[2], pc[1] / pc[2]
            mid = np.array([(xn.min() + xn.max()) / 2, (yn.min() + yn.max()) / 2, 1.0])
            target = center + R.T @ mid
        R = look_at(center, target, down)
        pc = R @ (outline - center[:, None])
        xn, yn = pc[0] / pc[2], pc[1] / pc[2]
        fc = 0.85 * min((wc / 2) / np.abs(xn).max(), (hc / 2) / np.abs(yn).max())
        self.K_cam = np.array([[fc, 0.0, (wc - 1) / 2.0], [0.0, fc, (hc - 1) / 2.0], [0.0, 0.0, 1.0]])
        self.R_cam = R                               # world -> camera
        self.t_cam = -R @ center
        self._cam_center = center

    def _build_camera_maps(self) -> None:
        """Ray-cast the camera where it stands: its remap into projector space, albedo, planes."""
        wc, hc = self.camera_size
        wp, hp = self.projector_size
        m = self._margin
        center, R = self._cam_center, self.R_cam

        # Ray-cast every camera pixel to the walls, then to projector pixel coordinates.
        gx, gy = np.meshgrid(np.arange(wc, dtype=np.float64), np.arange(hc, dtype=np.float64))
        if self.distortion != (0.0, 0.0):
            # Each observed pixel looks along the ray of its ideal (undistorted) position.
            ideal = undistort_points(np.stack([gx, gy], axis=-1), self.distortion, self.camera_size)
            gx, gy = ideal[..., 0], ideal[..., 1]
        dirs_w = (R.T @ np.linalg.inv(self.K_cam)) @ np.stack([gx.ravel(), gy.ravel(),
                                                                np.ones(gx.size)])
        t, wall = cast_rays(center, dirs_w, self._walls)
        hit = wall >= 0
        t = np.where(hit, t, 1.0)
        pts = center[:, None] + t * dirs_w
        c = self._proj_center
        xp = self.K_proj @ (self.R_proj @ (pts - c[:, None]))
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = xp[0] / xp[2], xp[1] / xp[2]
        # Shadow test: the projector's own ray must reach this very point first (t = 1).
        tp, _ = cast_rays(c, pts - c[:, None], self._walls)
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
            self.exposure = 0.95 / peak * self.scene.exposure_gain
        self._cam_albedo = (self.exposure * self._cam_albedo).astype(np.float32)

    def _build_truth(self) -> None:
        wp, hp = self.projector_size
        m = self._margin
        fr = (slice(m, m + hp), slice(m, m + wp))
        R_cp = self.R_cam @ self.R_proj.T
        c = self._proj_center                        # X_world = R_proj^T X_proj + c
        t_cp = self.t_cam + self.R_cam @ c
        planes, hs = [], []
        Kp_inv = np.linalg.inv(self.K_proj)
        for w in self._walls[:self._n_walls]:
            n_p = self.R_proj @ w.n
            d_p = float(w.d - w.n @ c)
            planes.append(np.concatenate([n_p, [d_p]]))
            H = self.K_cam @ (R_cp + np.outer(t_cp, n_p) / d_p) @ Kp_inv
            hs.append(H / H[2, 2])
        fold_proj, fold_cam, folds_proj, folds_cam, fold_planes = self._folds()
        shade = self._pad_shade[fr]
        alb = self._pad_albedo[fr]
        # The far wall seen through a gap is no plane of the set-up: -1 in both plane maps.
        plane_map = self._pad_plane[fr].copy()
        plane_map[plane_map >= self._n_walls] = -1
        cam_plane = self._cam_plane.copy()
        cam_plane[cam_plane >= self._n_walls] = -1
        self.truth = GroundTruth(
            radius_map=self._pad_radius[1][fr].copy(),
            radius_rgb=self._pad_radius[:, fr[0], fr[1]].copy(),
            plane_map=plane_map, cam_from_proj=self._cam_from_proj(),
            depth_map=self._pad_depth[fr].astype(np.float32),
            fold_proj=fold_proj, fold_cam=fold_cam,
            folds_proj=folds_proj, folds_cam=folds_cam, fold_planes=fold_planes,
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
            camera_response=self._cam_inverse.astype(np.float32),
            camera_response_kind=self.camera_response, distortion=self.distortion,
            exposure_drift=self.exposure_drift,
            extra={"margin": m, "camera_in_frame": self._cam_in_frame,
                   "proj_from_cam": projector_map(self._map_x, self._map_y, m, _OUTSIDE),
                   "camera_plane_map": cam_plane, "shaped": self._shaped},
        )

    def _cam_from_proj(self) -> np.ndarray:
        """(Hp, Wp, 2) float32: the ideal camera pixel (x, y) of the surface point each
        projector pixel centre lights (exact for bowed walls, where the homographies are not)."""
        wp, hp = self.projector_size
        gx, gy = np.meshgrid(np.arange(wp, dtype=np.float64), np.arange(hp, dtype=np.float64))
        _, _, pts, _ = self._cast_projector(np.stack([gx.ravel(), gy.ravel()]))
        xc = self.K_cam @ (self.R_cam @ pts + self.t_cam[:, None])
        return np.stack([xc[0] / xc[2], xc[1] / xc[2]], axis=-1).reshape(hp, wp, 2).astype(np.float32)

    def _folds(self):
        """fold_proj, fold_cam (the one fold of two planes, plane 0 negative; else None) and
        folds_proj, folds_cam (m, 3), fold_planes (m, 2): every fold inside the frame,
        canonically oriented, [plane on the negative side, plane on the positive side]."""
        def proj(X):
            x = self.K_proj @ (self.R_proj @ (X - self._proj_center))
            return x[:2] / x[2]

        def cam(X):
            x = self.K_cam @ (self.R_cam @ X + self.t_cam)
            return x[:2] / x[2]

        fold_proj = fold_cam = None
        folds = []                                    # (line_proj, line_cam, [neg, pos])
        if self._room:
            for f in self._room_folds():
                xa, xb = f.points[0], f.points[-1]
                xi = 0.5 * (xa + xb) + 0.01 * f.side_i    # 1 cm into wall i
                folds.append((line_through(proj(xa), proj(xb), proj(xi)),
                              line_through(cam(xa), cam(xb), cam(xi)), [f.i, f.j]))
            if self._n_walls == 2 and folds:
                fold_proj, fold_cam = folds[0][0], folds[0][1]
        elif self._n_walls == 2:
            f0 = self._fold_point
            p_hi, p_lo = f0 + [0.0, -1.0, 0.0], f0 + [0.0, 1.0, 0.0]
            inside0 = f0 + 0.3 * self._walls[0].e + [0.0, 0.0, 0.0]
            fold_proj = line_through(proj(p_hi), proj(p_lo), proj(inside0))
            fold_cam = line_through(cam(p_hi), cam(p_lo), cam(inside0))
            folds.append((fold_proj, fold_cam, [0, 1]))
        folds_proj, folds_cam, fold_planes = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2), np.int64)
        if folds:
            for k, (lp, lc, pair) in enumerate(folds):
                if not np.array_equal(canonical_line(lp), lp):
                    folds[k] = (-lp, -lc, pair[::-1])
            folds_proj = np.stack([f[0] for f in folds])
            folds_cam = np.stack([f[1] for f in folds])
            fold_planes = np.array([f[2] for f in folds], np.int64)
        return fold_proj, fold_cam, folds_proj, folds_cam, fold_planes

    # ----------------------------------------------------------------------- rendering
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
        return self._blur.apply(lin, m)[m:m + hp, m:m + wp]

    def capture(self, pattern: np.ndarray, sharp: bool = False, noise=None) -> np.ndarray:
        """Show ``pattern`` on the projector and return the camera frame.

        Parameters
        ----------
        pattern : (Hp, Wp, 3) uint8 RGB projector image (a (Hp, Wp) grey one is expanded).
        sharp : render the ideal in-focus display: no blur and no noise, all else equal.
        noise : a skipped capture's noise (:meth:`skip_capture`); default the camera's own.

        Returns
        -------
        (Hc, Wc, 3) uint8 RGB camera frame.
        """
        pattern = check_pattern(pattern, self.projector_size)
        # Averaged captures of one pattern differ only by their noise: render it once.
        last = self.__dict__.setdefault("_last_render", LastRender())
        cam = None if sharp else last.get(self, pattern)
        if cam is None:
            lin = self._proj_lut[pattern]
            m = self._margin
            if sharp:
                irr = np.zeros(self._pad_shade.shape + (3,), np.float32)
                irr[m:-m, m:-m] = lin
            else:
                irr = self._blur.apply(lin, m)
            irr *= self._pad_shade[..., None]
            cam = cv2.remap(irr, self._map_x, self._map_y, cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            cam += self.ambient
            cam *= self._cam_albedo                   # Lambertian walls, exposure folded in
            if not sharp:
                last.put(self, pattern, cam)
        if not sharp and noise is None:
            if self.exposure_drift != 0.0 and self._captures > 0:
                step = self.exposure_drift * (1.0 + 0.1 * float(self._drift_rng.standard_normal()))
                self._gain *= math.exp(step)
            self._captures += 1
            if self._gain != 1.0:
                cam *= np.float32(self._gain)
        if not sharp and self.noise > 0:
            rng = self._rng if noise is None else noise
            cam += rng.standard_normal(cam.shape, dtype=np.float32) * np.float32(self.noise)
        np.clip(cam, 0.0, 1.0, out=cam)
        if self.camera_response == "srgb":
            cam = linear_to_srgb(cam)
        elif self.camera_gamma != 1.0:
            cam = cam ** np.float32(1.0 / self.camera_gamma)
        return np.rint(cam * 255.0).astype(np.uint8)

    def __repr__(self) -> str:
        return (f"VirtualProCam({self.preset!r}, projector {self.projector_size[0]}x"
                f"{self.projector_size[1]}, camera {self.camera_size[0]}x{self.camera_size[1]})")

