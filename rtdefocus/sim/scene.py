"""The virtual scene: presets of two walls (or one) and the projector-camera rig, and the ray
casting that places them (world frame: x right, y down, z ahead; the projector at the origin)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


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
    texture : printed texture of the walls when :class:`VirtualProCam` is not given one:
        "none", "faint" (about ±4 %, smooth) or "fabric" (a woven partition on the left wall, a
        coloured poster and wood-grain-like bands on the right one; see ``VirtualProCam``).
    ambient : ambient irradiance relative to a full-on projector when ``VirtualProCam`` is not
        given one (None: its default 0.02).
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
    texture: str = "none"
    ambient: float | None = None
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
    "fabric": Scene("concave", albedo=((0.50, 0.56, 0.66), (0.84, 0.76, 0.58)), texture="fabric",
                    ambient=0.06,
                    description="cubicle with a blue-grey woven partition (left) and a beige wall "
                    "with a printed poster (right), room light on: a coloured, textured screen"),
}


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

