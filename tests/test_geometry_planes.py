"""Geometry of any number of planes: how many, where their folds are, and that a
forced count or a moved set-up is not explained away as planes.

The rooms (``u_cubicle``: three walls; ``corner_ceiling``: two walls and the ceiling, the folds
meeting at a vertex) are calibrated once each at 320x240 through ``capture`` only and held
against ``sim.truth``; estimated planes are matched to the true ones by the overlap of the
plane maps, not by index.
"""

from __future__ import annotations

import functools
import math

import checkerboard
import cv2
import numpy as np
import pytest
from helpers import Blind, CountingProCam

import rtdefocus as rd
from rtdefocus import sim
from rtdefocus.calib.capture import Capturer
from rtdefocus.calib.geometry.fit import fit_geometry
from rtdefocus.calib.geometry.fold import find_kink, find_kinks
from rtdefocus.calib.geometry.stage import calibrate_geometry
from rtdefocus.calib.geometry.structured_light import LinePatterns
from rtdefocus.errors import CalibrationError, InputError
from rtdefocus.planar import PlaneLayout, apply_h, projector_frame

SIZE = {"projector_size": (320, 240), "camera_size": (480, 360)}
ROOMS = ["u_cubicle", "corner_ceiling"]


@functools.cache
def _calibrated(preset: str, planes="auto"):
    pc = sim.VirtualProCam(preset, **SIZE)
    return pc, calibrate_geometry(None, Capturer(Blind(pc)), planes=planes)


def _fit_again(calib, planes):
    """The fit alone, on the lines ``calib`` was made from (no new captures)."""
    g = calib.meta["geometry"]
    return fit_geometry(calib.geometry_detail.detection, calib.projector_size, calib.camera_size,
                        planes=planes, fold_band=g["options"]["fold_band"],
                        residual=g["options"]["residual"])


def _match(calib, truth):
    """est plane -> true plane by the largest overlap of the projector plane maps; and the
    share of projector pixels on matching planes."""
    wp, hp = calib.projector_size
    yy, xx = np.mgrid[0:hp, 0:wp]
    est = calib.layout.label(xx, yy)
    overlap = np.array([[np.sum((est == i) & (truth.plane_map == j)) for j in range(truth.n_planes)]
                        for i in range(calib.n_planes)])
    to_true = overlap.argmax(axis=1)
    return to_true, float(np.mean(to_true[est] == truth.plane_map))


# --------------------------------------------------------------------------- kinks
def test_every_bend_of_a_line_is_a_kink():
    rng = np.random.default_rng(5)
    t = np.arange(0, 900)
    s = (100 + 0.05 * t + math.tan(math.radians(4)) * np.maximum(0, t - 250)
         - math.tan(math.radians(3)) * np.maximum(0, t - 640))
    kinks = find_kinks(t, s + rng.normal(0, 0.08, t.size))
    assert [round(k.point_cam_xy[0] / 10) for k in kinks] == [25, 64]
    assert all(abs(k.point_cam_xy[0] - c) < 2 for k, c in zip(kinks, (250, 640), strict=True))
    # one bend: exactly what the single-kink finder gives; none: nothing
    one = 100 + math.tan(math.radians(3)) * np.maximum(0, t - 400) + rng.normal(0, 0.08, t.size)
    (k1,) = find_kinks(t, one)
    np.testing.assert_array_equal(k1.point_cam_xy, find_kink(t, one).point_cam_xy)
    assert find_kinks(t, 100 + 0.02 * t + rng.normal(0, 0.08, t.size)) == []


# --------------------------------------------------------------------------- rooms
# The U-shaped room (three planes, two folds) in the fast tier; the corner with a ceiling in
# the whole suite.
@pytest.mark.parametrize("preset", [pytest.param(p, marks=() if p == "u_cubicle" else pytest.mark.slow)
                                    for p in ROOMS])
def test_planes_and_folds_match_the_truth(preset):
    pc, calib = _calibrated(preset)
    truth = pc.truth
    g = calib.meta["geometry"]
    assert calib.n_planes == g["n_planes"] == truth.n_planes == 3, g["candidates"]
    to_true, agree = _match(calib, truth)
    assert sorted(to_true) == list(range(truth.n_planes)) and agree > 0.995, (to_true, agree)
    # numbered by the convention (projector centroid x, then y), as the truth is
    assert to_true.tolist() == list(range(truth.n_planes))
    # every true fold: an estimated one between the same planes, within 1 px along the true
    # segment inside the frame; the same planes on the same sides
    segs = PlaneLayout(truth.n_planes, truth.folds_proj, truth.fold_planes).fold_segments(
        projector_frame(pc.projector_size))
    assert len(calib.folds_proj) == len(truth.folds_proj)
    for pair, seg in zip(truth.fold_planes, segs, strict=True):
        (j,) = [j for j, fp in enumerate(calib.fold_planes) if set(to_true[fp]) == set(pair)]
        est = calib.folds_proj[j]
        # oriented by canonical_line, [negative side, positive side] as the truth
        assert to_true[calib.fold_planes[j]].tolist() == pair.tolist()
        ts = np.linspace(0, 1, 50)[:, None]
        pts = seg[0] * (1 - ts) + seg[1] * ts
        err = float(np.abs(pts @ est[:2] + est[2]).max())
        assert err < 1.0, f"{preset}: fold {pair.tolist()} off by {err:.3f} projector px"
        assert abs(math.hypot(*est[:2]) - 1) < 1e-9
        f = g["folds"][j]
        assert f["kinks"] >= 8 and f["disagreement_px"] < 1.0, f
    # held-out projector points away from the folds map where the truth maps them
    wp, hp = pc.projector_size
    rng = np.random.default_rng(2)
    pts = np.stack([rng.uniform(0, wp - 1, 3000), rng.uniform(0, hp - 1, 3000)], axis=1)
    out = PlaneLayout(truth.n_planes, truth.folds_proj, truth.fold_planes).outside(*pts.T)
    pts = pts[out.min(axis=0) < -6]
    tp = truth.plane_map[np.rint(pts[:, 1]).astype(int), np.rint(pts[:, 0]).astype(int)]
    assert np.mean(calib.plane_of(pts[:, 0], pts[:, 1]) == tp) == 1.0
    for p in range(truth.n_planes):
        sel = tp == p
        err = np.linalg.norm(apply_h(calib.H_cam_from_proj[p], pts[sel])
                             - apply_h(truth.H_cam_from_proj[p], pts[sel]), axis=1)
        assert np.sqrt(np.mean(err ** 2)) < 0.5, f"{preset}: plane {p} RMS {err}"
    # camera folds: each plane's camera points are on its side of its folds
    cam_lab = calib.layout_cam.label(*apply_h(truth.H_cam_from_proj[0], pts[tp == 0]).T)
    assert np.all(cam_lab == 0)
    # the lit outline covers what the camera sees lit
    lit = np.zeros(pc.camera_size[::-1], np.uint8)
    cv2.fillPoly(lit, [np.round(calib.lit_polygon_cam * 16).astype(np.int32)], 1, shift=4)
    seen = truth.extra["camera_in_frame"]
    assert np.logical_and(lit, seen).sum() / np.logical_or(lit, seen).sum() > 0.98


@pytest.mark.parametrize("preset", ROOMS)
def test_checkerboard_is_in_place_on_every_plane_and_straight_across_every_fold(preset):
    pc, calib = _calibrated(preset)
    err, grid = checkerboard.through_warp(pc, calib)
    cam_plane = pc.truth.extra["camera_plane_map"]
    pts = grid.reshape(-1, 2)
    plane = cam_plane[np.rint(pts[:, 1]).astype(int), np.rint(pts[:, 0]).astype(int)]
    shown = [p for p in range(pc.truth.n_planes) if np.sum(plane == p) >= 4]
    assert len(shown) >= 2, f"{preset}: the board covers only planes {shown}"
    for p in shown:
        rms = float(np.sqrt(np.mean(err[plane == p] ** 2)))
        assert rms <= 0.5, f"{preset}: plane {p} corners {rms:.3f} px RMS from the rect"
    for line in list(grid) + list(grid.transpose(1, 0, 2)):
        centred = line - line.mean(axis=0)
        residual = np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(len(line))
        assert residual < 0.5, f"{preset}: a row/column of corners bends by {residual:.3f} px RMS"


def test_a_forced_count_equal_to_what_is_found_changes_nothing():
    _, auto = _calibrated("cubicle")
    assert auto.n_planes == 2
    parts, stats, _ = _fit_again(auto, 2)
    for name in ("H_cam_from_proj", "folds_proj", "folds_cam", "fold_planes", "lit_polygon_cam"):
        np.testing.assert_array_equal(parts[name], getattr(auto, name), err_msg=name)
    assert stats["planes_option"] == 2 and auto.meta["geometry"]["planes_option"] == "auto"
    _, room = _calibrated("u_cubicle")
    parts, _, _ = _fit_again(room, "3")
    np.testing.assert_array_equal(parts["folds_proj"], room.folds_proj)


@pytest.mark.parametrize("preset, planes, match", [
    ("cubicle", 1, r"planes=1 was asked for, but the line crossings show 2 planes"),
    ("cubicle", 3, r"planes=3 was asked for, but the line crossings show only 2 plane"),
    ("u_cubicle", 2, r"planes=2 was asked for, but the line crossings show 3 planes"),
    ("flat", 2, r"planes=2 was asked for, but the line crossings show only 1 plane"),
], ids=["cubicle-1", "cubicle-3", "u-2", "flat-2"])
def test_a_forced_count_the_data_contradict_is_an_error(preset, planes, match):
    _, calib = _calibrated(preset)
    with pytest.raises(CalibrationError, match=match) as info:
        _fit_again(calib, planes)
    assert "planes='auto'" in str(info.value)


@pytest.mark.parametrize("planes", [0, 9, "two", 2.5, True, None])
def test_a_bad_planes_value_is_refused_before_any_capture(planes):
    pc = CountingProCam((320, 240), (480, 360))
    with pytest.raises(InputError, match="planes must be 'auto' or a whole number 1..8"):
        rd.calibrate(pc, stages=("geometry",), planes=planes)
    assert pc.n == 0


def _shift(frame, dx, dy):
    return cv2.warpAffine(frame, np.float32([[1, 0, dx], [0, 1, dy]]), frame.shape[1::-1])


@pytest.mark.slow
def test_a_room_knocked_and_back_is_not_explained_as_more_planes():
    # two phases of each line family 6 px off: four interleaved, equally good "homographies"
    # but no bend between them — the set-up moved, it did not grow planes
    blind = Blind(sim.VirtualProCam("u_cubicle", **SIZE),
                  lambda i, p, f: _shift(f, 6, 4) if 4 <= i < 8 else f)
    with pytest.raises(CalibrationError, match="inconsistent|moved"):
        calibrate_geometry(None, Capturer(blind))


@pytest.mark.slow
def test_cli_calibrate_takes_planes(tmp_path, monkeypatch, capsys):
    from rtdefocus import cli

    monkeypatch.setattr(sim, "VirtualProCam", functools.partial(sim.VirtualProCam, **SIZE))
    out = tmp_path / "p.npz"
    rc = cli.main(["-q", "calibrate", "--sim", "pillar", "-o", str(out), "--stages", "geometry",
                   "--planes", "2"])
    assert rc == 0, capsys.readouterr().out
    calib = rd.Calibration.load(out)
    assert calib.n_planes == 2 and calib.meta["geometry"]["options"]["planes"] == 2
    assert calib.meta["captures"]["geometry"] == LinePatterns(SIZE["projector_size"]).count()
    # a room: three planes found by default, file and picture written
    room = tmp_path / "room.npz"
    assert cli.main(["-q", "calibrate", "--sim", "u_cubicle", "-o", str(room), "--stages",
                     "geometry"]) == 0
    assert "3 plane(s)" in capsys.readouterr().out
    assert rd.Calibration.load(room).n_planes == 3 and (tmp_path / "room_geometry.png").exists()
    with pytest.raises(SystemExit) as info:
        cli.main(["calibrate", "--sim", "pillar", "-o", str(out), "--planes", "many"])
    assert info.value.code == 2
    assert "planes must be 'auto' or a whole number" in capsys.readouterr().err
