"""The simulator's rooms of three planes (u_cubicle, corner_ceiling): exact ground truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rtdefocus import sim
from rtdefocus.errors import InputError
from rtdefocus.planar import canonical_line

ROOMS = ["u_cubicle", "corner_ceiling"]
SMALL = {"projector_size": (320, 240), "camera_size": (480, 360)}
_CACHE: dict = {}


def procam(preset: str) -> sim.VirtualProCam:
    if preset not in _CACHE:
        _CACHE[preset] = sim.VirtualProCam(preset, **SMALL)
    return _CACHE[preset]


def line_eval(line, x, y):
    return line[0] * x + line[1] * y + line[2]


def grid(t):
    hp, wp = t.plane_map.shape
    yy, xx = np.mgrid[0:hp, 0:wp]
    return xx.astype(np.float64), yy.astype(np.float64)


def wrong_side(labels, folds, fold_planes, xx, yy):
    """Per pixel, how far (px) it lies on the wrong side of the folds bounding its plane
    (0 where it is on its plane's side of all of them; labels < 0 are ignored)."""
    worst = np.zeros(labels.shape)
    for line, (neg, pos) in zip(folds, fold_planes, strict=True):
        d = line_eval(line, xx, yy)
        worst = np.maximum(worst, np.where(labels == neg, d, 0.0))     # neg side wanted
        worst = np.maximum(worst, np.where(labels == pos, -d, 0.0))    # pos side wanted
    return worst


@pytest.mark.parametrize("preset, n_folds", [("u_cubicle", 2), ("corner_ceiling", 3)])
def test_room_planes_and_fold_convention(preset, n_folds):
    t = procam(preset).truth
    wp, hp = procam(preset).projector_size
    assert t.n_planes == 3 and t.planes_proj.shape == (3, 4)
    assert t.fold_proj is None and t.fold_cam is None              # one fold line cannot say it
    assert sorted(np.unique(t.plane_map).tolist()) == [0, 1, 2]
    assert t.folds_proj.shape == t.folds_cam.shape == (n_folds, 3) and t.fold_planes.shape == (n_folds, 2)
    pairs = [tuple(sorted(p)) for p in t.fold_planes.tolist()]
    assert pairs == sorted(pairs) and len(set(pairs)) == n_folds   # one per pair, in pair order
    for lines in (t.folds_proj, t.folds_cam):
        assert np.allclose(np.hypot(lines[:, 0], lines[:, 1]), 1.0, atol=1e-12)
    for line in t.folds_proj:
        assert np.array_equal(canonical_line(line), line)
    # Planes numbered by their centroid x in the projector.
    xx, yy = grid(t)
    cx = [xx[t.plane_map == p].mean() for p in range(3)]
    assert cx == sorted(cx)
    if preset == "u_cubicle":
        assert t.fold_planes.tolist() == [[0, 1], [1, 2]]
        for line, frac in zip(t.folds_proj, (0.25, 0.75), strict=True):
            for y in (0.0, hp - 1.0):
                x = -(line[1] * y + line[2]) / line[0]
                assert abs(x / wp - frac) < 0.02, (x, frac)


@pytest.mark.parametrize("preset", ROOMS)
def test_folds_agree_with_the_plane_maps(preset):
    pc = procam(preset)
    t = pc.truth
    xx, yy = grid(t)
    bad = wrong_side(t.plane_map, t.folds_proj, t.fold_planes, xx, yy)
    assert bad.max() < 1.0, f"projector pixel {bad.max():.3f} px on the wrong side of its fold"
    # The same planes on the same sides in the (ideal) camera: the ray-cast camera plane map.
    cam = np.where(t.extra["camera_in_frame"], t.extra["camera_plane_map"], -1)
    hc, wc = cam.shape
    cy, cx = np.mgrid[0:hc, 0:wc].astype(np.float64)
    bad = wrong_side(cam, t.folds_cam, t.fold_planes, cx, cy)
    assert bad.max() < 1.0, f"camera pixel {bad.max():.3f} px on the wrong side of its fold"
    for p in range(3):
        assert (cam == p).sum() > 1000
    # Each fold maps through both of its planes' homographies onto the camera fold line.
    for lp, lc, (p0, p1) in zip(t.folds_proj, t.folds_cam, t.fold_planes, strict=True):
        foot = -lp[2] * lp[:2]
        for s in (-40.0, 0.0, 40.0):
            x = foot + s * np.array([-lp[1], lp[0]])
            q0, q1 = (t.H_cam_from_proj[p] @ [x[0], x[1], 1.0] for p in (p0, p1))
            q0, q1 = q0[:2] / q0[2], q1[:2] / q1[2]
            assert np.hypot(*(q0 - q1)) < 1e-6 and abs(line_eval(lc, *q0)) < 1e-6


@pytest.mark.parametrize("preset", ROOMS)
def test_homographies_match_the_ray_cast_camera(preset):
    """Camera pixels that see the frame, sent back to the projector by the renderer's own
    ray-cast maps, come back onto themselves through their plane's homography."""
    pc = procam(preset)
    t = pc.truth
    m = t.extra["margin"]
    # Private on purpose: the maps the renderer samples through are what is checked.
    u, v = pc._map_x.astype(np.float64) - m, pc._map_y.astype(np.float64) - m
    hc, wc = u.shape
    cy, cx = np.mgrid[0:hc, 0:wc]
    inside = t.extra["camera_in_frame"]
    plane = t.extra["camera_plane_map"]
    for p in range(t.n_planes):
        sel = inside & (plane == p)
        assert sel.sum() > 1000
        h = t.H_cam_from_proj[p] @ np.stack([u[sel], v[sel], np.ones(sel.sum())])
        err = np.hypot(h[0] / h[2] - cx[sel], h[1] / h[2] - cy[sel])
        assert err.max() < 0.01, f"plane {p}: {err.max():.4f} camera px"
        # ... and the projector pixel lies on that plane in the truth's plane map.
        ui, vi = np.rint(u[sel]).astype(int), np.rint(v[sel]).astype(int)
        ok = (ui >= 0) & (ui < t.plane_map.shape[1]) & (vi >= 0) & (vi < t.plane_map.shape[0])
        assert np.mean(t.plane_map[vi[ok], ui[ok]] == p) > 0.99


def test_corner_vertex_inside_the_frame():
    pc = procam("corner_ceiling")
    t = pc.truth
    wp, hp = pc.projector_size
    lines = t.folds_proj
    crossings = [np.cross(lines[i], lines[j]) for i, j in ((0, 1), (0, 2), (1, 2))]
    crossings = np.array([c[:2] / c[2] for c in crossings])
    assert np.abs(crossings - crossings[0]).max() < 1e-6, "the three folds do not meet in one point"
    vx, vy = crossings[0]
    assert abs(vx / wp - 0.5) < 0.02 and abs(vy / hp - 0.35) < 0.02
    yi, xi = int(round(vy)), int(round(vx))
    assert set(np.unique(t.plane_map[yi - 4:yi + 5, xi - 4:xi + 5]).tolist()) == {0, 1, 2}
    # The vertex is the deepest point (a room corner seen from inside).
    ym, xm = np.unravel_index(int(np.argmax(t.depth_map)), t.depth_map.shape)
    assert np.hypot(xm - vx, ym - vy) < 1.5


@pytest.mark.parametrize("preset", ROOMS)
def test_blur_continuous_across_folds_focus_in_front(preset):
    t = procam(preset).truth
    assert t.focus_distance < t.depth_map.min()
    assert 0.3 < t.radius_map.min()                               # nothing in focus
    # Piecewise affine and continuous: a step between neighbours across a fold is no bigger
    # than the steepest step between neighbours on one plane (a gap or overlap would be).
    n_across = 0
    for axis in (0, 1):
        step = np.abs(np.diff(t.radius_map.astype(np.float64), axis=axis))
        across = np.diff(t.plane_map, axis=axis) != 0
        n_across += across.sum()
        if not across.any():
            continue                                  # u_cubicle's folds are vertical
        assert step[across].max() <= step[~across].max() + 1e-4
        dstep = np.abs(np.diff(t.depth_map.astype(np.float64), axis=axis))
        assert dstep[across].max() <= dstep[~across].max() + 1e-5
    assert n_across > 200


@pytest.mark.parametrize("preset", ROOMS + ["webcam_" + p for p in ROOMS])
def test_room_captures_light_every_plane(preset):
    pc = procam(preset)
    t = pc.truth
    wp, hp = pc.projector_size
    if preset.startswith("webcam_"):
        assert pc.scene == sim.PRESETS[preset[len("webcam_"):]] and pc.distortion != (0.0, 0.0)
    white = pc.capture(np.full((hp, wp, 3), 255, np.uint8), sharp=True).astype(np.float64)
    black = pc.capture(np.zeros((hp, wp, 3), np.uint8), sharp=True).astype(np.float64)
    lit = (white - black)[..., 1]
    cam_plane = t.extra["camera_plane_map"]
    inside = t.extra["camera_in_frame"]
    for p in range(t.n_planes):
        # One plane alone lit: its camera pixels light up, the others' stay dark (beyond the
        # blur spill); observed pixels in distorted webcams shift, so away from the borders.
        mask = (t.plane_map == p).astype(np.uint8) * 255
        one = pc.capture(np.repeat(mask[..., None], 3, axis=2), sharp=True).astype(np.float64)
        own = inside & (cam_plane == p)
        assert np.median(lit[own]) > 60 and np.median((one - black)[..., 1][own]) > 60
        others = inside & (cam_plane >= 0) & (cam_plane != p)
        assert np.median((one - black)[..., 1][others]) < 2


def test_room_scene_checks():
    with pytest.raises(InputError, match="left, back, right"):
        sim.VirtualProCam(dataclasses.replace(sim.PRESETS["u_cubicle"], wall_angles_deg=(40.0, 40.0)),
                          **SMALL)
    with pytest.raises(InputError, match="three albedos"):
        sim.VirtualProCam(dataclasses.replace(sim.PRESETS["corner_ceiling"],
                                              albedo=((0.8, 0.8, 0.8), (0.7, 0.7, 0.7))), **SMALL)
    with pytest.raises(InputError, match="outside the room"):
        sim.VirtualProCam(dataclasses.replace(sim.PRESETS["u_cubicle"], camera_position=(3.0, 0.0, 0.0)),
                          **SMALL)
    with pytest.raises(InputError, match="outside the projector frame"):
        sim.VirtualProCam(dataclasses.replace(sim.PRESETS["u_cubicle"], fold2_x_frac=1.3), **SMALL)


@pytest.mark.parametrize("preset", ["cubicle", "pillar", "tilted", "flat"])
def test_two_and_one_plane_presets_list_their_fold(preset):
    t = procam(preset).truth
    if t.n_planes == 1:
        assert t.folds_proj.shape == (0, 3) and t.fold_planes.shape == (0, 2)
        return
    # The one fold, canonically oriented: the same line as fold_proj with its planes' sides.
    assert t.folds_proj.shape == (1, 3)
    s = 1.0 if t.fold_planes[0].tolist() == [0, 1] else -1.0
    assert sorted(t.fold_planes[0].tolist()) == [0, 1]
    assert np.array_equal(t.folds_proj[0], s * t.fold_proj) and np.array_equal(t.folds_cam[0], s * t.fold_cam)
    assert np.array_equal(canonical_line(t.folds_proj[0]), t.folds_proj[0])
    xx, yy = grid(t)
    assert wrong_side(t.plane_map, t.folds_proj, t.fold_planes, xx, yy).max() < 1.0


@pytest.mark.parametrize("preset", ROOMS)
def test_oracle_calibration_of_a_room(preset, tmp_path):
    from rtdefocus.calib.file import Calibration
    from rtdefocus.planar import points_in_polygon

    pc = procam(preset)
    t = pc.truth
    calib = sim.oracle_calibration(pc)
    assert calib.n_planes == 3 and calib.layout.n_folds == len(t.folds_proj)
    assert np.array_equal(calib.fold_planes, t.fold_planes) and np.array_equal(calib.folds_cam, t.folds_cam)
    # The calibration's plane of every projector pixel is the ray caster's, but at the folds.
    xx, yy = grid(t)
    near = np.min([np.abs(line_eval(f, xx, yy)) for f in t.folds_proj], axis=0) < 1.0
    same = calib.plane_map() == t.plane_map
    assert same[~near].all() and same.mean() > 0.99
    # The lit outline holds the camera pixels that see the frame (the three planes' pieces join).
    cam_y, cam_x = np.nonzero(t.extra["camera_in_frame"])
    inside = points_in_polygon(cam_x.astype(np.float64), cam_y.astype(np.float64), calib.lit_polygon_cam)
    assert inside.mean() > 0.995
    loaded = Calibration.load(calib.save(tmp_path / "room"))
    assert loaded.layout == calib.layout and loaded.layout_cam == calib.layout_cam
