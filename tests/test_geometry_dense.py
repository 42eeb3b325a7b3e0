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

#: Measured by ``.venv/bin/python tools/measure_gains.py --sections dense`` (2026-12-03).
#: Decoder (PROJ / CAM, away from the lit edge): coordinate error median and 99th percentile
#: (projector px), the valid share of the lit inner area; a flipped Gray-code bit: the valid
#: share on its patch and the largest error left. The gap (SMALL, dense): the far wall's share
#: masked, the walls' share masked, the walls' model RMS (camera px). webcam_sagging with the
#: lens given and guessed, sagging dense and from crossings: model RMS (camera px).
#: Error bounds 1.5x (none of the flipped patch or of the walls masked: none allowed); shares
#: >= 85 % (the valid share held to 0.97).
MEASURED = {
    "decode": {"median": 0.0130, "p99": 0.0338, "valid": 1.0},
    "misread": {"patch_valid": 0.0, "max": 0.0513},
    "gap": {"far_masked": 0.990, "walls_masked": 0.0, "rms": 0.00286},
    "sagging": {"dense": 0.0185, "lines": 0.0359},
    "lens": {"given": 0.0434, "guessed": 0.447},
}


def _camera(pattern: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    lin = (pattern.astype(np.float32) / 255.0) ** 2.2           # the projector's response
    img = cv2.warpPerspective(lin, H_CAM_FROM_PROJ, CAM, flags=cv2.INTER_LINEAR)
    img = cv2.GaussianBlur(img, (0, 0), 1.5)                      # defocus
    img = 0.05 + 0.8 * img + rng.normal(0, 0.004, img.shape).astype(np.float32)
    return np.clip(255 * img ** (1 / 2.2), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def decoded() -> DenseMap:
    return decode_map()


def decode_map() -> DenseMap:
    """The dense patterns through the homography camera (seed 3), decoded."""
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


def decode_figures(decoded: DenseMap) -> dict:
    """The decoded map against the true homography, away from the lit edge (where the blur
    mixes in the dark): error median and 99th percentile, the valid share of the lit inner
    area, and how many pixels off the lit area are valid."""
    cam, proj = decoded.samples(1)
    err = np.linalg.norm(proj - _truth(cam), axis=1)
    wp, hp = PROJ
    t = _truth(cam)
    inner = (t[:, 0] > 4) & (t[:, 0] < wp - 5) & (t[:, 1] > 4) & (t[:, 1] < hp - 5)
    ys, xs = np.mgrid[0:CAM[1], 0:CAM[0]]
    tt = _truth(np.c_[xs.ravel(), ys.ravel()]).reshape(CAM[1], CAM[0], 2)
    inside = (tt[..., 0] > 4) & (tt[..., 0] < wp - 5) & (tt[..., 1] > 4) & (tt[..., 1] < hp - 5)
    # (the blur carries light about 3 px past the frame's edge)
    outside = (tt[..., 0] < -5) | (tt[..., 0] > wp + 4) | (tt[..., 1] < -5) | (tt[..., 1] > hp + 4)
    return {"median": float(np.median(err[inner])), "p99": float(np.percentile(err[inner], 99)),
            "valid": float(decoded.valid[inside].mean()),
            "valid_outside": int(decoded.valid[outside].sum())}


def test_every_lit_pixel_gets_its_projector_coordinates(decoded):
    f, m = decode_figures(decoded), MEASURED["decode"]
    assert f["median"] <= 1.5 * m["median"] and f["p99"] <= 1.5 * m["p99"], f
    # valid on nearly all of the lit inner area, never off the lit area
    assert f["valid"] > 0.97 and f["valid_outside"] == 0, f


def misread_figures() -> dict:
    """The most significant Gray-code bit flipped on a patch: the valid share on the patch and
    the largest coordinate error left away from the lit edge."""
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
    return {"patch_valid": float(out.valid[62:78, 62:78].mean()), "max": float(err[inner].max())}


def test_a_misread_gray_code_bit_is_invalid_not_a_wrong_coordinate():
    f, m = misread_figures(), MEASURED["misread"]
    assert f["patch_valid"] <= 1.5 * m["patch_valid"], f
    # the patch's rim, where the flipped bit and the true one mix, is invalid too or right
    assert f["max"] <= 1.5 * m["max"], f


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


def gap_figures(pc, calib) -> dict:
    """The dense fit of the gap: the far wall's share masked, the walls' share masked, the
    walls' model RMS (the far wall did not bend the right one), the share of the display
    rectangle on a wall (content goes only where a wall is lit)."""
    mask = calib.geometry_detail.unfit_mask
    cam_plane = pc.truth.extra["camera_plane_map"]
    seen = pc.truth.extra["camera_in_frame"]
    far, walls = (cam_plane == -1) & seen, (cam_plane >= 0) & seen
    x, y, w, h = calib.display_rect((4, 3))
    return {"far": int(far.sum()), "far_masked": float(mask[far].mean()),
            "walls_masked": float(mask[walls].mean()), "rms": homography_rms(calib, pc.truth),
            "walls_shown": float(walls[y:y + h, x:x + w].mean())}


@pytest.mark.slow
def test_the_far_wall_through_a_gap_is_masked_drawn_and_left_out():
    pc, calib = geometry("gap", dense=True)
    assert calib.n_planes == 2
    g = calib.meta["geometry"]
    assert g["options"]["dense"] and g["captures"] > 20
    mask = calib.geometry_detail.unfit_mask
    f, m = gap_figures(pc, calib), MEASURED["gap"]
    assert f["far"] > 1000 and g["unfit"]["pixels"] == int(mask.sum())
    assert f["far_masked"] >= 0.85 * m["far_masked"], f
    assert f["walls_masked"] <= 1.5 * m["walls_masked"] and f["rms"] <= 1.5 * m["rms"], f
    assert f["walls_shown"] > 0.99, f
    cam_plane = pc.truth.extra["camera_plane_map"]
    walls = (cam_plane >= 0) & pc.truth.extra["camera_in_frame"]
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
    f = {"dense": homography_rms(dense, pc.truth), "lines": homography_rms(lines, pc.truth)}
    assert f["dense"] <= 1.1 * f["lines"], f
    assert all(f[k] <= 1.5 * v for k, v in MEASURED["sagging"].items()), f


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
    pc, given, guessed = given_lens_runs()
    assert given.meta["geometry"]["distortion"]["given"]
    np.testing.assert_allclose(given.camera_distortion, pc.truth.distortion)
    f = {"given": homography_rms(given, pc.truth), "guessed": homography_rms(guessed, pc.truth)}
    m = MEASURED["lens"]
    assert f["given"] <= 1.5 * m["given"], f
    # the lens, not the sheet's bow, is what the given lens takes out: >= 85 % of the MEASURED lead
    assert f["guessed"] / f["given"] >= 0.85 * m["guessed"] / m["given"], f


def given_lens_runs():
    """webcam_sagging's geometry with the true lens given, and with the lens estimated."""
    pc = sim.VirtualProCam("webcam_sagging", **SMALL)
    return (pc, calibrate(Blind(pc), stages=["geometry"], lens=tuple(pc.truth.distortion)),
            calibrate(Blind(pc), stages=["geometry"]))
