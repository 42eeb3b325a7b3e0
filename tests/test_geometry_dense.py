"""Dense structured light (Gray code plus phase shift): every lit camera pixel's projector
coordinates to a fraction of a pixel with a validity mask; the geometry stage fitted to it; and
the region no plane fits (the gap preset's far wall) masked, drawn, and left out of the fit."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from helpers import Blind
from setup_figures import homography_rms

from rtdefocus import sim
from rtdefocus.calib import calibrate
from rtdefocus.calib.geometry.dense import (
    DenseDecoder,
    DenseMap,
    DensePatterns,
    decode_phase,
)
from rtdefocus.calib.geometry.diagnostics import caption, geometry_diagnostics
from rtdefocus.errors import InputError

# A camera that sees the projector through a homography, with a blur, a gamma and noise.
PROJ = (160, 120)
CAM = (200, 150)
H_CAM_FROM_PROJ = np.array([[1.1, 0.08, 8.0], [-0.04, 1.05, 6.0], [2e-4, 1e-4, 1.0]])


def _camera(pattern: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    lin = (pattern.astype(np.float32) / 255.0) ** 2.2           # the projector's response
    img = cv2.warpPerspective(lin, H_CAM_FROM_PROJ, CAM, flags=cv2.INTER_LINEAR)
    img = cv2.GaussianBlur(img, (0, 0), 1.5)                      # defocus
    img = 0.05 + 0.8 * img + rng.normal(0, 0.004, img.shape).astype(np.float32)
    return np.clip(255 * img ** (1 / 2.2), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def decoded() -> DenseMap:
    rng = np.random.default_rng(3)
    pats = DensePatterns(PROJ, period=16, steps=8)
    dec = DenseDecoder(pats)
    wp, hp = PROJ
    black = _camera(np.zeros((hp, wp, 3), np.uint8), rng).mean(axis=2)
    white = _camera(np.full((hp, wp, 3), 255, np.uint8), rng).mean(axis=2)
    dec.set_frames(black, white)
    for name, pattern in pats.sequence():
        dec.add(name, _camera(pattern, rng))
    return dec.result()


def _truth(cam_xy: np.ndarray) -> np.ndarray:
    h = np.linalg.inv(H_CAM_FROM_PROJ)
    p = np.c_[cam_xy, np.ones(len(cam_xy))] @ h.T
    return p[:, :2] / p[:, 2:]


def test_every_lit_pixel_gets_its_projector_coordinates(decoded):
    cam, proj = decoded.samples(1)
    err = np.linalg.norm(proj - _truth(cam), axis=1)
    # away from the lit edge, where the blur mixes in the dark
    wp, hp = PROJ
    t = _truth(cam)
    inner = (t[:, 0] > 4) & (t[:, 0] < wp - 5) & (t[:, 1] > 4) & (t[:, 1] < hp - 5)
    assert np.median(err[inner]) < 0.05 and np.percentile(err[inner], 99) < 0.3, \
        (np.median(err[inner]), np.percentile(err[inner], 99))
    # valid on nearly all of the lit inner area, never off the lit area
    ys, xs = np.mgrid[0:CAM[1], 0:CAM[0]]
    tt = _truth(np.c_[xs.ravel(), ys.ravel()]).reshape(CAM[1], CAM[0], 2)
    inside = (tt[..., 0] > 4) & (tt[..., 0] < wp - 5) & (tt[..., 1] > 4) & (tt[..., 1] < hp - 5)
    assert decoded.valid[inside].mean() > 0.97
    # (the blur carries light about 3 px past the frame's edge)
    outside = (tt[..., 0] < -5) | (tt[..., 0] > wp + 4) | (tt[..., 1] < -5) | (tt[..., 1] > hp + 4)
    assert not decoded.valid[outside].any()


def test_a_misread_gray_code_bit_is_invalid_not_a_wrong_coordinate():
    rng = np.random.default_rng(4)
    pats = DensePatterns(PROJ, period=16, steps=8)
    dec = DenseDecoder(pats)
    wp, hp = PROJ
    dec.set_frames(_camera(np.zeros((hp, wp, 3), np.uint8), rng).mean(axis=2),
                   _camera(np.full((hp, wp, 3), 255, np.uint8), rng).mean(axis=2))
    for name, pattern in pats.sequence():
        frame = _camera(pattern, rng)
        if name == "dgx0":              # the most significant bit flipped on a patch
            frame[60:80, 60:80] = 255 - frame[60:80, 60:80]
        dec.add(name, frame)
    out = dec.result()
    cam, proj = out.samples(1)
    err = np.linalg.norm(proj - _truth(cam), axis=1)
    t = _truth(cam)
    inner = (t[:, 0] > 4) & (t[:, 0] < wp - 5) & (t[:, 1] > 4) & (t[:, 1] < hp - 5)
    assert out.valid[62:78, 62:78].mean() < 0.05
    # the patch's rim, where the flipped bit and the true one mix, is invalid too or right
    assert err[inner].max() < 1.0, err[inner].max()


def test_phase_and_stripe_known_answer():
    period, steps = 16, 4
    x = np.array([0.0, 3.3, 7.9, 8.0, 15.5, 40.25])
    delta = 2 * np.pi * np.arange(steps) / steps
    i_k = 0.5 + 0.3 * np.cos(2 * np.pi * x[:, None] / period - delta[None, :])
    s = (i_k * np.sin(delta)).sum(axis=1)
    c = (i_k * np.cos(delta)).sum(axis=1)
    stripe = np.floor(x / (period / 2)).astype(int)
    stripe[3] -= 1                      # read on its stripe's edge: the neighbour's index
    coord, mod, agree = decode_phase(s, c, stripe, period, steps)
    np.testing.assert_allclose(coord, x, atol=1e-9)
    np.testing.assert_allclose(mod, 0.3, rtol=1e-6)
    assert agree.all()


def test_bad_dense_input_is_a_clear_error():
    with pytest.raises(InputError, match="even period"):
        DensePatterns(PROJ, period=15)
    dec = DenseDecoder(DensePatterns(PROJ, period=16))
    with pytest.raises(InputError, match="black and white"):
        dec.add("dpx0", np.zeros((CAM[1], CAM[0], 3), np.uint8))
    dec.set_frames(np.zeros(CAM[::-1]), np.full(CAM[::-1], 200.0))
    with pytest.raises(InputError, match="unknown dense pattern"):
        dec.add("zz", np.zeros((CAM[1], CAM[0], 3), np.uint8))
    with pytest.raises(InputError, match="expected 8 phase steps"):
        dec.result()


def test_resampling_the_map_moves_its_coordinates(decoded):
    ys, xs = np.mgrid[0:CAM[1], 0:CAM[0]].astype(np.float32)
    moved = decoded.resampled(xs + 3.0, ys)            # ideal pixel x sees observed x + 3
    ok = moved.valid[:, :-3] & decoded.valid[:, 3:]
    assert ok.sum() > 0.8 * decoded.valid.sum()
    np.testing.assert_allclose(moved.proj_xy[:, :-3][ok], decoded.proj_xy[:, 3:][ok], atol=1e-4)


# --------------------------------------------------------------------------- in the stage
SMALL = {"projector_size": (320, 240), "camera_size": (512, 384), "projector_gamma": 2.2}
_RUNS: dict = {}


def geometry(preset: str, dense: bool):
    if (preset, dense) not in _RUNS:
        pc = sim.VirtualProCam(preset, **SMALL)
        _RUNS[preset, dense] = pc, calibrate(Blind(pc), stages=["geometry"], dense=dense)
    return _RUNS[preset, dense]


@pytest.mark.slow
def test_the_far_wall_through_a_gap_is_masked_drawn_and_left_out():
    pc, calib = geometry("gap", dense=True)
    assert calib.n_planes == 2
    g = calib.meta["geometry"]
    assert g["options"]["dense"] and g["captures"] > 20
    mask = calib.geometry_detail.unfit_mask
    cam_plane = pc.truth.extra["camera_plane_map"]
    seen = pc.truth.extra["camera_in_frame"]
    far, walls = (cam_plane == -1) & seen, (cam_plane >= 0) & seen
    assert far.sum() > 1000
    assert mask[far].mean() > 0.8, mask[far].mean()
    assert mask[walls].mean() < 0.02, mask[walls].mean()
    assert g["unfit"]["pixels"] == int(mask.sum())
    # the walls themselves still fit: the far wall did not bend the right one
    assert homography_rms(calib, pc.truth) < 0.15
    # content goes only where a wall is lit: the display rectangle leaves out the projector
    # columns whose light goes through the gap
    x, y, w, h = calib.display_rect((4, 3))
    assert walls[y:y + h, x:x + w].mean() > 0.99, walls[y:y + h, x:x + w].mean()
    # the picture marks that region, and only it (its outline, label and the caption aside)
    detail = calib.geometry_detail
    img = geometry_diagnostics(calib, detail)
    plain = geometry_diagnostics(calib, replace(detail, unfit_mask=None))
    changed = (img != plain).any(axis=2)
    near = cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    near[-30:] = True                                   # the caption's line
    assert changed[mask].mean() > 0.9 and changed[walls & ~near].mean() < 0.01
    assert "masked (no plane fits)" in caption(calib)


@pytest.mark.slow
def test_dense_fit_of_a_sagging_wall_is_at_least_as_close_as_the_crossings():
    pc, dense = geometry("sagging", dense=True)
    _, lines = geometry("sagging", dense=False)
    assert dense.n_planes == lines.n_planes == 2
    assert homography_rms(dense, pc.truth) <= 1.1 * homography_rms(lines, pc.truth)


def test_a_bad_lens_option_is_a_clear_error():
    from rtdefocus.calib.capture import Capturer
    from rtdefocus.calib.geometry import calibrate_geometry

    cap = Capturer(sim.VirtualProCam("cubicle", **SMALL))
    for bad in ((0.1,), ("a", 0.0), (float("nan"), 0.0), (3.0, 0.0)):
        with pytest.raises(InputError, match=r"lens must be the camera's radial distortion"):
            calibrate_geometry(None, cap, lens=bad)
    assert cap.counts.get("geometry", 0) == 0           # refused before any capture


@pytest.mark.slow
def test_a_given_lens_tells_a_pillowed_sheet_from_barrel_distortion():
    pc = sim.VirtualProCam("webcam_sagging", **SMALL)
    given = calibrate(Blind(pc), stages=["geometry"], lens=tuple(pc.truth.distortion))
    guessed = calibrate(Blind(pc), stages=["geometry"])
    assert given.meta["geometry"]["distortion"]["given"]
    np.testing.assert_allclose(given.camera_distortion, pc.truth.distortion)
    assert homography_rms(given, pc.truth) < 0.5 * homography_rms(guessed, pc.truth)
