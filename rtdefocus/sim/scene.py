"""The virtual scene: presets of walls (one, two, or a room's three) and the projector-camera
rig, the walls they build and the ray casting that places them (world frame: x right, y down,
z ahead; the projector at the origin)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError


@dataclass(frozen=True)
class Scene:
    """One arrangement of walls, projector and camera (world frame: x right, y down, z ahead).

    Attributes
    ----------
    kind : "concave" (corner seen from inside, fold deepest), "convex" (pillar, fold nearest),
        "flat" (one plane, no fold), "u" (three walls, left, back and right, seen from inside a
        U-shaped cubicle: two folds) or "corner" (two walls and the ceiling of a room corner,
        seen from below: three folds meeting at a vertex). "u" and "corner" are rooms seen from
        inside (a convex region holding projector and camera), so every wall is a whole plane
        and the visible one along a ray is the nearest.
    fold_x_frac : where the fold crosses the projector's centre row, as a fraction of the width
        ("u": the left fold; "corner": the vertex's x).
    fold_depth : depth of the fold line along the projector axis (m) ("corner": of the vertex).
    wall_angles_deg : (left, right) angle of each wall to the plane square to the projector axis
        (degrees); for "flat" only the first is used (positive: the right side recedes); for "u"
        (left, back, right), the back wall's like "flat"'s; for "corner" (left, right), the walls'
        angles to the plane square to the room's horizontal view direction (90° in all for a
        rectangular room).
    fold2_x_frac : "u" only: where the right fold crosses the centre row (fraction of the width).
    vertex_y_frac : "corner" only: the vertex's y as a fraction of the height.
    pitch_deg : "corner" only: how far the projector (and the camera on it) is aimed up from the
        room's horizontal (degrees).
    roll_deg : roll of the projector (and the camera mounted on it) about the projector axis
        (degrees).
    focus_distance, aperture_radius : projector lens focus depth and aperture radius A (m);
        None (default) derives both from ``blur_range_px``.
    blur_range_px : (min, max) blur radius over the frame of an 800-px-wide projector, used when
        focus_distance / aperture_radius are None; the focus then lies in front of every wall
        point (no wall in focus). Radii scale with the projector width (f = 1.2 W).
    camera_position : camera centre (m) in the projector's frame, beside and a bit above it; the
        camera is mounted on the projector (rolls with it) and looks at the lit area.
    albedo : RGB albedo of each wall, in plane order (left, right; "u": left, back, right;
        "corner": left wall, ceiling, right wall).
    texture : printed texture of the walls when :class:`VirtualProCam` is not given one:
        "none", "faint" (about ±4 %, smooth) or "fabric" (a woven partition on the left wall, a
        coloured poster and wood-grain-like bands on the right one; see ``VirtualProCam``).
    ambient : ambient irradiance relative to a full-on projector when ``VirtualProCam`` is not
        given one (None: its default 0.02).
    bow : per wall (plane order), how far its middle stands off its plane (m, positive towards
        the projector): a wall that is a plane only nearly. The displacement is along the
        wall's normal, zero at the fold and at the wall's far edges and smooth in between
        (``bow_shape``); () or zeros: flat walls. Not for "u" and "corner".
    bow_shape : "cylinder" (a panel bent about a vertical axis: ``sin(pi s)`` across the wall,
        constant down it) or "pillow" (a sheet held at its edges that sags or puffs:
        ``sin(pi s) sin(pi y)``), with s and y the wall's extent over the frame scaled to 0..1.
    gap_x_frac : "concave" / "convex" only: the right wall ends where the projector's centre
        row at this fraction of the width meets it, and a far wall (``far_depth``, square to
        the projector axis) shows through the gap beside it; None: no gap.
    far_depth : depth (m) of that far wall along the projector axis.
    exposure_gain : factor on the camera's auto exposure (which puts a white frame's peak at
        95 % of full scale); above 1 the brightest captures clip.
    """

    kind: str
    fold_x_frac: float = 0.5
    fold_depth: float = 2.5
    wall_angles_deg: tuple[float, ...] = (35.0, 40.0)
    fold2_x_frac: float = 0.75
    vertex_y_frac: float = 0.5
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    focus_distance: float | None = None
    aperture_radius: float | None = None
    blur_range_px: tuple[float, float] = (1.5, 6.0)
    camera_position: tuple[float, float, float] = (0.4, -0.25, 0.0)
    albedo: tuple[tuple[float, float, float], ...] = (
        (0.86, 0.85, 0.81), (0.74, 0.76, 0.79))
    texture: str = "none"
    ambient: float | None = None
    bow: tuple[float, ...] = ()
    bow_shape: str = "cylinder"
    gap_x_frac: float | None = None
    far_depth: float = 4.5
    exposure_gain: float = 1.0
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
    "u_cubicle": Scene("u", fold_x_frac=0.25, fold2_x_frac=0.75, wall_angles_deg=(62.0, 8.0, 66.0),
                       albedo=((0.86, 0.85, 0.81), (0.78, 0.79, 0.80), (0.74, 0.76, 0.79)),
                       description="U-shaped cubicle seen from inside: left, back and right walls, "
                       "folds at about a quarter and three quarters of the width"),
    "corner_ceiling": Scene("corner", fold_x_frac=0.5, vertex_y_frac=0.35, pitch_deg=28.0,
                            wall_angles_deg=(40.0, 50.0),
                            albedo=((0.86, 0.85, 0.81), (0.90, 0.90, 0.88), (0.74, 0.76, 0.79)),
                            description="projector aimed up into a room corner: two walls and the "
                            "ceiling, the three folds meeting at a vertex inside the frame"),
    "bowed": Scene("concave", bow=(0.0, -0.012), bow_shape="cylinder",
                   description="cubicle whose right wall is a fabric panel bent back by 1.2 cm "
                   "(about 1 % of its width) in its middle"),
    "sagging": Scene("concave", bow=(0.02, 0.04), bow_shape="pillow",
                     description="cubicle of two sheets held at their edges, pillowed towards the "
                     "room by 2 cm (left) and 4 cm (right) in their middles"),
    "gap": Scene("concave", gap_x_frac=0.86, far_depth=4.5,
                 description="cubicle whose right wall ends short of the frame: a far wall 4.5 m "
                 "away shows through the gap beside it"),
    "clipping": Scene("concave", exposure_gain=1.6,
                      description="cubicle with the camera's exposure 1.6 times too long: white "
                      "frames and bright dots clip"),
}


#: Scene kinds that are rooms seen from inside: whole-plane walls, any number of folds.
ROOM_KINDS = ("u", "corner")


@dataclass(frozen=True)
class Bow:
    """A wall's smooth displacement off its plane along its normal n (m, + towards n).

    ``amplitude · f(u) · g(v)`` with u = (s - s0) / (s1 - s0), v = (y - y0) / (y1 - y0) clipped
    to [0, 1], s and y the point's coordinates along ``axes`` from ``origin``; f(u) = sin(pi u),
    g(v) = sin(pi v) for a "pillow" and 1 for a "cylinder"."""
    amplitude: float
    shape: str
    origin: np.ndarray     # (3,) world
    axes: np.ndarray       # (2, 3) in-plane unit axes (s, y), both square to the wall's normal
    s_range: tuple[float, float]
    y_range: tuple[float, float]

    def offset(self, pts: np.ndarray) -> np.ndarray:
        """Displacement (N,) at world points (3, N) (their in-plane coordinates are used)."""
        s, y = self.axes @ (pts - self.origin[:, None])
        u = np.clip((s - self.s_range[0]) / (self.s_range[1] - self.s_range[0]), 0.0, 1.0)
        out = self.amplitude * np.sin(math.pi * u)
        if self.shape == "pillow":
            v = np.clip((y - self.y_range[0]) / (self.y_range[1] - self.y_range[0]), 0.0, 1.0)
            out = out * np.sin(math.pi * v)
        return out


@dataclass(frozen=True)
class _Wall:
    n: np.ndarray        # unit normal (world), pointing towards the projector
    d: float             # n · X = d
    origin: np.ndarray   # a point on the fold (world)
    e: np.ndarray | None  # in-plane direction away from the fold; None = whole plane
    tex: np.ndarray | None = None  # (2, 3) in-plane texture axes (s, y); None: e (or n × up), world y
    extent: float = math.inf      # largest distance along e from the fold (a wall that ends)
    bow: Bow | None = None        # displacement off the plane; None: flat
    far: bool = False             # a far wall seen through a gap, no plane of the set-up


def rot_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def look_at(center: np.ndarray, target: np.ndarray, down: np.ndarray) -> np.ndarray:
    """World-to-camera rotation for a camera at ``center`` looking at ``target``, its image
    y axis as close to ``down`` as possible."""
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(down, z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def cast_rays(origin: np.ndarray, dirs: np.ndarray, walls: list[_Wall]) -> tuple[np.ndarray, np.ndarray]:
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
            if w.bow is not None:
                t = _bowed_hit(origin, dirs, w, t, denom)
        ok = np.isfinite(t) & (t > 1e-9)
        if w.e is not None:
            # Position along the wall away from the fold; a tiny tolerance so the fold itself
            # belongs to both walls.
            along = (origin - w.origin) @ w.e + t * (w.e @ dirs)
            ok &= (along >= -1e-9) & (along <= w.extent)
        better = ok & (t < best_t)
        best_t[better] = t[better]
        best_w[better] = i
    return best_t, best_w


def _bowed_hit(origin: np.ndarray, dirs: np.ndarray, w: _Wall, t: np.ndarray,
               denom: np.ndarray) -> np.ndarray:
    """Ray parameters (N,) where rays meet the bowed wall ``w``, from their hits ``t`` on its
    plane: fixed-point steps onto the plane shifted by the bow at the last hit. The bow's
    slope (a few cm over a metre) times the rays' obliquity is well below 1, so each step
    shrinks the error at least tenfold; the shadow test needs it to 1e-9 of the distance."""
    base = w.d - w.n @ origin
    fin = np.isfinite(t)
    tt = np.where(fin, t, 0.0)
    for _ in range(60):
        h = w.bow.offset(origin[:, None] + tt * dirs)
        new = np.where(fin, (base + h) / np.where(fin, denom, 1.0), 0.0)
        step = float(np.max(np.abs(new - tt))) if new.size else 0.0
        tt = new
        if step < 1e-13:
            break
    return np.where(fin, tt, t)


def line_through(p1: np.ndarray, p2: np.ndarray, neg_point: np.ndarray) -> np.ndarray:
    """Normalised line through two image points, negative at ``neg_point`` (all (x, y))."""
    line = np.cross([p1[0], p1[1], 1.0], [p2[0], p2[1], 1.0])
    line = line / math.hypot(line[0], line[1])
    if line @ [neg_point[0], neg_point[1], 1.0] > 0:
        line = -line
    return line



def _rot_x(deg: float) -> np.ndarray:
    """Room -> world rotation of a projector aimed ``deg`` up: the room's up (0, -1, 0) becomes
    (0, -cos, sin) (up and away), its forward (0, 0, 1) comes down in the image."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def _make_wall(origin, e, up, half: bool) -> _Wall:
    n = np.cross(e, up)
    n /= np.linalg.norm(n)
    if n @ (np.zeros(3) - origin) < 0:       # face the projector
        n = -n
    return _Wall(n=n, d=float(n @ origin), origin=origin.copy(), e=e.copy() if half else None)


def _room_wall(origin, e, up) -> _Wall:
    """A whole-plane wall of a room through ``origin`` spanned by the unit vectors ``e`` and
    ``up``, textured along them."""
    w = _make_wall(origin, e, up, half=False)
    return _Wall(n=w.n, d=w.d, origin=w.origin, e=None, tex=np.stack([e, up]))


def scene_walls(sc: Scene, K_proj: np.ndarray, R_proj: np.ndarray,
                size: tuple[int, int]) -> tuple[list[_Wall], np.ndarray]:
    """The walls of ``sc`` for a projector of intrinsics ``K_proj``, world -> projector rotation
    ``R_proj`` and ``size`` (w, h); also the point where the (left) fold crosses the centre row
    (world; the vertex for "corner")."""
    wp, hp = size

    def ray(x, y):
        return R_proj.T @ np.linalg.solve(K_proj, [x, y, 1.0])

    # Fold: a vertical world line crossing the projector's centre row at fold_x_frac.
    r = ray(sc.fold_x_frac * wp - 0.5, (hp - 1) / 2.0)
    fold_pt = r * (sc.fold_depth / r[2])
    fold_pt[1] = 0.0
    up = np.array([0.0, 1.0, 0.0])
    walls = []
    if sc.kind == "flat":
        a = math.radians(sc.wall_angles_deg[0])
        e = np.array([math.cos(a), 0.0, math.sin(a)])
        walls.append(_make_wall(fold_pt, e, up, half=False))
    elif sc.kind in ("concave", "convex"):
        sgn = -1.0 if sc.kind == "concave" else 1.0   # concave: walls come towards us
        a0, a1 = (math.radians(v) for v in sc.wall_angles_deg)
        walls.append(_make_wall(fold_pt, np.array([-math.cos(a0), 0.0, sgn * math.sin(a0)]),
                                up, half=True))
        walls.append(_make_wall(fold_pt, np.array([math.cos(a1), 0.0, sgn * math.sin(a1)]),
                                up, half=True))
    elif sc.kind == "u":
        if len(sc.wall_angles_deg) != 3 or len(sc.albedo) < 3:
            raise InputError("a 'u' scene needs wall_angles_deg (left, back, right) and three "
                             f"albedos; got {sc.wall_angles_deg!r} and {len(sc.albedo)}")
        a0, b, a2 = (math.radians(v) for v in sc.wall_angles_deg)
        back = _make_wall(fold_pt, np.array([math.cos(b), 0.0, math.sin(b)]), up, half=False)
        # The right fold: where the back wall crosses the centre-row ray at fold2_x_frac.
        r2 = ray(sc.fold2_x_frac * wp - 0.5, (hp - 1) / 2.0)
        fold2 = r2 * (back.d / (back.n @ r2))
        fold2[1] = 0.0
        walls = [_make_wall(fold_pt, np.array([-math.cos(a0), 0.0, -math.sin(a0)]), up, half=False),
                 back,
                 _make_wall(fold2, np.array([math.cos(a2), 0.0, -math.sin(a2)]), up, half=False)]
    elif sc.kind == "corner":
        if len(sc.wall_angles_deg) != 2 or len(sc.albedo) < 3:
            raise InputError("a 'corner' scene needs wall_angles_deg (left, right) and three "
                             f"albedos; got {sc.wall_angles_deg!r} and {len(sc.albedo)}")
        r = ray(sc.fold_x_frac * wp - 0.5, sc.vertex_y_frac * hp - 0.5)
        fold_pt = r * (sc.fold_depth / r[2])
        room = _rot_x(sc.pitch_deg)
        a0, a1 = (math.radians(v) for v in sc.wall_angles_deg)
        left = room @ [-math.cos(a0), 0.0, -math.sin(a0)]
        right = room @ [math.cos(a1), 0.0, -math.sin(a1)]
        down = room @ up
        walls = [_room_wall(fold_pt, left, down),
                 _room_wall(fold_pt, room @ [1.0, 0.0, 0.0], room @ [0.0, 0.0, 1.0]),
                 _room_wall(fold_pt, right, down)]
    else:
        raise InputError("Scene.kind must be 'concave', 'convex', 'flat', 'u' or 'corner'; got "
                         f"{sc.kind!r}")
    if sc.gap_x_frac is not None:
        walls = _with_gap(sc, walls, ray((sc.gap_x_frac * wp) - 0.5, (hp - 1) / 2.0), up)
    if any(b != 0.0 for b in sc.bow):
        walls = _with_bows(sc, walls, ray, size)
    return walls, fold_pt


def _with_gap(sc: Scene, walls: list[_Wall], r: np.ndarray, up: np.ndarray) -> list[_Wall]:
    """The right wall cut where the ray ``r`` (world) meets it, and the far wall behind."""
    if sc.kind not in ("concave", "convex"):
        raise InputError(f"Scene.gap_x_frac needs a 'concave' or 'convex' scene; got {sc.kind!r}")
    right = walls[1]
    hit = r * ((right.d) / (right.n @ r))
    extent = float(right.e @ (hit - right.origin))
    if not extent > 0 or not sc.far_depth > 0:
        raise InputError(f"Scene.gap_x_frac={sc.gap_x_frac} puts the gap left of the fold (or "
                         f"far_depth={sc.far_depth} is not > 0); use a fraction right of "
                         f"fold_x_frac={sc.fold_x_frac}")
    cut = _Wall(n=right.n, d=right.d, origin=right.origin, e=right.e, extent=extent)
    far = _make_wall(np.array([0.0, 0.0, sc.far_depth]), np.array([1.0, 0.0, 0.0]), up, half=False)
    return [walls[0], cut, _Wall(n=far.n, d=far.d, origin=far.origin, e=None, far=True)]


def _with_bows(sc: Scene, walls: list[_Wall], ray, size: tuple[int, int]) -> list[_Wall]:
    """The walls with ``sc.bow``'s displacements, each spanning the wall's extent over the
    projector frame (from the fold for a half wall, so the fold stays straight)."""
    if sc.kind in ROOM_KINDS:
        raise InputError(f"Scene.bow is for 'concave', 'convex' and 'flat' scenes; got {sc.kind!r}")
    if sc.bow_shape not in ("cylinder", "pillow"):
        raise InputError(f"Scene.bow_shape must be 'cylinder' or 'pillow'; got {sc.bow_shape!r}")
    n_walls = sum(not w.far for w in walls)
    if len(sc.bow) != n_walls:
        raise InputError(f"Scene.bow needs one displacement per wall ({n_walls}); got {sc.bow!r}")
    wp, hp = size
    gx, gy = np.meshgrid(np.linspace(-0.5, wp - 0.5, 81), np.linspace(-0.5, hp - 0.5, 61))
    dirs = np.stack([ray(x, y) for x, y in zip(gx.ravel(), gy.ravel(), strict=True)], axis=1)
    t, which = cast_rays(np.zeros(3), dirs, walls)
    up = np.array([0.0, 1.0, 0.0])
    out = list(walls)
    for i, amp in enumerate(sc.bow):
        if amp == 0.0:
            continue
        w = walls[i]
        sel = which == i
        if sel.sum() < 4:
            raise InputError(f"Scene.bow: wall {i} is not seen by the projector; leave its bow 0")
        pts = t[sel] * dirs[:, sel]
        e = w.e if w.e is not None else np.cross(up, w.n)
        axes = np.stack([e, up])
        s, y = axes @ (pts - w.origin[:, None])
        s_range = (0.0, float(min(s.max(), w.extent))) if w.e is not None else (
            float(s.min()), float(s.max()))
        bow = Bow(float(amp), sc.bow_shape, w.origin.copy(), axes, s_range,
                  (float(y.min()), float(y.max())))
        out[i] = _Wall(n=w.n, d=w.d, origin=w.origin, e=w.e, tex=w.tex, extent=w.extent, bow=bow)
    return out


@dataclass(frozen=True)
class RoomFold:
    """Where walls ``i`` and ``j`` of a room meet, as far as the projector frame shows it."""
    i: int
    j: int
    points: np.ndarray   # (k, 3) world points of the visible fold inside the frame, in order
    side_i: np.ndarray   # unit world vector in wall i, from the fold into wall i's visible part


def room_folds(walls: list[_Wall], K_proj: np.ndarray, R_proj: np.ndarray,
               size: tuple[int, int], n: int = 1001) -> list[RoomFold]:
    """The folds of a room seen from inside (whole-plane walls) that cross the projector frame.

    The room is the region in front of every wall (n · X >= d); the projector sees the
    intersection line of walls i and j where it lies in front of every other wall. Each pair
    (i < j) whose line does so somewhere inside the frame [-0.5, w - 0.5] x [-0.5, h - 0.5] is
    listed, in order of (i, j); ``points`` samples that part at ``n`` steps of the frame chord.
    """
    wp, hp = size
    P = K_proj @ R_proj
    out = []
    for i in range(len(walls)):
        for j in range(i + 1, len(walls)):
            a, b = walls[i], walls[j]
            u = np.cross(a.n, b.n)
            if np.linalg.norm(u) < 1e-9:
                continue                                  # parallel walls never meet
            u /= np.linalg.norm(u)
            x0 = np.linalg.solve(np.stack([a.n, b.n, u]), [a.d, b.d, 0.0])
            line = np.cross(P @ x0, P @ (x0 + u))         # the fold's image, homogeneous
            chord = _clip_line(line, (-0.5, -0.5, wp - 0.5, hp - 0.5))
            if chord is None:
                continue
            s = np.linspace(0.0, 1.0, n)[:, None]
            pix = chord[0] * (1 - s) + chord[1] * s
            dirs = R_proj.T @ np.linalg.solve(K_proj, np.vstack([pix.T, np.ones(n)]))
            t = a.d / (a.n @ dirs)
            pts = (t * dirs).T
            ok = t > 0
            for k, w in enumerate(walls):
                if k not in (i, j):
                    ok &= pts @ w.n >= w.d - 1e-9 * max(1.0, abs(w.d))
            if ok.sum() < 2:
                continue
            side = np.cross(a.n, u)
            if side @ b.n < 0:                            # into the part of wall i that j leaves visible
                side = -side
            out.append(RoomFold(i, j, pts[ok], side))
    return out


def _clip_line(line: np.ndarray, box: tuple[float, float, float, float]):
    """The chord (2, 2) of the homogeneous image line inside box (x0, y0, x1, y1), or None."""
    a, b, c = line
    x0, y0, x1, y1 = box
    pts = []
    if abs(b) > 1e-12:
        for x in (x0, x1):
            y = -(a * x + c) / b
            if y0 <= y <= y1:
                pts.append((x, y))
    if abs(a) > 1e-12:
        for y in (y0, y1):
            x = -(b * y + c) / a
            if x0 <= x <= x1:
                pts.append((x, y))
    if len(pts) < 2:
        return None
    pts = np.array(pts)
    # The two points farthest apart (a corner may appear twice).
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    k, m = np.unravel_index(int(np.argmax(d)), d.shape)
    if d[k, m] < 1e-9:
        return None
    return np.stack([pts[k], pts[m]])


def plane_order(plane_map: np.ndarray, n: int) -> list[int]:
    """Walls 0..n-1 of a projector-space label image in calibration order: by the centroid x
    of their pixels, ties (within 5 % of the width) by centroid y. Every wall must show."""
    h, w = plane_map.shape
    lab = plane_map.ravel().astype(np.int64)
    count = np.bincount(lab, minlength=n)[:n]
    if np.any(count == 0):
        raise InputError(f"walls {np.flatnonzero(count == 0).tolist()} of the scene are outside the "
                         "projector frame; move the folds inside the frame")
    yy, xx = np.divmod(np.arange(lab.size), w)
    cx = np.bincount(lab, weights=xx, minlength=n)[:n] / count
    cy = np.bincount(lab, weights=yy, minlength=n)[:n] / count

    def cmp(a, b):
        if abs(cx[a] - cx[b]) < 0.05 * w:
            return cy[a] - cy[b]
        return cx[a] - cx[b]

    return sorted(range(n), key=functools.cmp_to_key(cmp))
