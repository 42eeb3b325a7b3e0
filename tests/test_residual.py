"""Planes plus a smooth residual: the B-spline field, its fit, the calibration file carrying
it, and the warp (GL and its cv2 reference) adding it to the homographies."""

from __future__ import annotations

import numpy as np
import pytest
from test_warp import FOLD, H2, IMAGES, PROJ, RECT, _assert_agree, _calibration, _compare_mask

from rtdefocus.calib.file import FORMAT_VERSION, Calibration
from rtdefocus.errors import InputError
from rtdefocus.reference.warp import warp_cv2
from rtdefocus.residual import basis, dense_displacement, displacement, fit_residual


def smooth_ctrl(n_planes=2, grid=(7, 5), amp=4.0, seed=3):
    """Control points of a smooth field of a few px (a bow, different per plane)."""
    gx, gy = grid
    u, v = np.meshgrid(np.linspace(0, 1, gx), np.linspace(0, 1, gy))
    out = np.zeros((n_planes, gy, gx, 2))
    for p in range(n_planes):
        out[p, ..., 0] = amp * np.sin(np.pi * u) * np.sin(np.pi * v) * (1 + p)
        out[p, ..., 1] = -0.5 * amp * np.sin(np.pi * u) * (p - 0.5)
    return out


def test_basis_is_a_partition_of_unity_and_smooth():
    x = np.linspace(-3, 402, 2000)
    b = basis(x, 400, 7)
    assert np.allclose(b.sum(axis=1), 1.0) and b.min() >= 0
    # C1 across knots: the field of random control values has no jump in slope
    f = b @ np.random.default_rng(1).normal(size=7)
    inner = (x > 1) & (x < 398)
    slope = np.diff(f[inner]) / np.diff(x[inner])
    assert np.abs(np.diff(slope)).max() < 1e-3
    with pytest.raises(InputError, match=">= 4"):
        basis(x, 400, 3)


def test_fit_recovers_a_smooth_bow_from_scattered_points():
    rng = np.random.default_rng(5)
    wp, hp = 320, 240
    pts = rng.uniform([0, 0], [wp - 1, hp - 1], size=(1500, 2))
    # a sine bow (not in the spline space) of 3 px, plus 0.1 px noise
    true = np.stack([3.0 * np.sin(np.pi * pts[:, 0] / wp) * np.sin(np.pi * pts[:, 1] / hp),
                     1.0 * np.sin(np.pi * pts[:, 0] / wp)], axis=1)
    ctrl = fit_residual(pts, true + rng.normal(scale=0.1, size=true.shape), (wp, hp))
    test = rng.uniform([0, 0], [wp - 1, hp - 1], size=(500, 2))
    want = np.stack([3.0 * np.sin(np.pi * test[:, 0] / wp) * np.sin(np.pi * test[:, 1] / hp),
                     1.0 * np.sin(np.pi * test[:, 0] / wp)], axis=1)
    err = np.linalg.norm(displacement(ctrl, test[:, 0], test[:, 1], (wp, hp)) - want, axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.03
    # no data at all: the field is its prior, zero
    assert np.abs(fit_residual(pts[:0], true[:0], (wp, hp))).max() == 0


def test_dense_equals_pointwise_per_plane():
    ctrl = smooth_ctrl()
    wp, hp = PROJ
    yy, xx = np.mgrid[0:hp, 0:wp]
    labels = (xx > wp // 2).astype(int)
    dense = dense_displacement(ctrl, labels, PROJ)
    for p in (0, 1):
        sel = labels == p
        want = displacement(ctrl[p], xx[sel], yy[sel], PROJ)
        assert np.abs(dense[sel] - want).max() < 1e-4


def test_calibration_carries_the_residual_through_a_file(tmp_path):
    calib = _calibration(H2, FOLD)
    calib.residual_cam = smooth_ctrl()
    path = calib.save(tmp_path / "bent.npz")
    back = Calibration.load(path)
    assert np.array_equal(back.residual_cam, calib.residual_cam)
    assert "residual" in back.sections()
    import json

    with np.load(path) as npz:
        assert json.loads(str(npz["meta"]))["format_version"] == FORMAT_VERSION == 4
    # cam_from_proj = homography + the point's plane's field
    pts = np.array([[20.0, 30.0], [250.0, 100.0]])
    plane = back.plane_of(pts[:, 0], pts[:, 1]).astype(int)
    got = back.cam_from_proj(pts[:, 0], pts[:, 1])
    for i, p in enumerate(plane):
        h = H2[p] @ [*pts[i], 1.0]
        want = h[:2] / h[2] + displacement(back.residual_cam[p], pts[i:i + 1, 0], pts[i:i + 1, 1],
                                           PROJ)[0]
        assert np.allclose(got[i], want, atol=1e-9)
    # a flat calibration has none and writes none
    flat = _calibration(H2, FOLD)
    assert flat.residual_dense() is None
    assert "residual_cam" not in np.load(flat.save(tmp_path / "flat.npz")).files
    bad = _calibration(H2, FOLD)
    bad.residual_cam = np.zeros((3, 5, 7, 2))
    with pytest.raises(Exception, match="residual_cam"):
        bad.save(tmp_path / "bad.npz")


def test_constant_offset_is_a_shifted_rect():
    """The reference adds the offset to the camera point: a constant (dx, dy) is the rect moved
    by (-dx, -dy)."""
    img = IMAGES["chelsea-451x300-mild-minify"]
    off = np.zeros((PROJ[1], PROJ[0], 2), np.float32)
    off[..., 0], off[..., 1] = 2.5, -1.25
    a = warp_cv2(img, H2, FOLD, RECT, PROJ, offset=off)
    moved = (RECT[0] - 2.5, RECT[1] + 1.25, RECT[2], RECT[3])
    b = warp_cv2(img, H2, FOLD, moved, PROJ)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1
    assert np.abs(a.astype(int) - warp_cv2(img, H2, FOLD, RECT, PROJ).astype(int)).mean() > 5
    with pytest.raises(InputError, match="offset"):
        warp_cv2(img, H2, FOLD, RECT, PROJ, offset=off[:10])


@pytest.mark.parametrize("name", ["noise-251x190-about-1to1", "coffee-600x400-minify"])
def test_gl_matches_cv2_with_a_residual(gl, name):
    from rtdefocus.gl.warp import GLWarp, warp_image

    img = IMAGES[name]
    calib = _calibration(H2, FOLD)
    calib.residual_cam = smooth_ctrl()
    off = calib.residual_dense()
    # Not released: the program is shared (memoised per context) with warp_image's warp.
    warper = GLWarp(gl, PROJ)
    out = warper.render(img, H2, FOLD, RECT, off)
    ref = warp_cv2(img, H2, FOLD, RECT, PROJ, offset=off)
    mask = _compare_mask(H2, FOLD, RECT, img.shape)
    _assert_agree(out, ref, mask, f"{name} with a residual")
    # the residual moved the picture (so the comparison tests it), and a frame without it
    # after one with it is the plain warp again (the offset texture is replaced)
    plain = warp_cv2(img, H2, FOLD, RECT, PROJ)
    assert np.abs(out.astype(int) - plain.astype(int))[mask].mean() > 5
    _assert_agree(warper.render(img, H2, FOLD, RECT), plain, mask, f"{name} after")
    # warp_image takes the calibration's residual, on both backends
    g = warp_image(calib, img, rect=RECT, backend="gl")
    c = warp_image(calib, img, rect=RECT, backend="cv2")
    assert np.array_equal(c, warp_cv2(img, H2, FOLD, RECT, PROJ, offset=off))
    _assert_agree(g, c, _compare_mask(H2, FOLD, RECT, img.shape), "warp_image")
