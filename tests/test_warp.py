"""The warp + stitch: GL shader (gl/warp.py) against its cv2 reference (reference/warp.py),
known answers, degenerate geometry, object reuse, the CLI, and an end-to-end check on the
simulator's true geometry."""

from __future__ import annotations

import logging

import checkerboard
import cv2
import numpy as np
import pytest

from rtdefocus.calib.file import Calibration
from rtdefocus.errors import DeviceError, InputError
from rtdefocus.planar import PlaneLayout
from rtdefocus.reference.warp import warp_cv2, warp_lod, warp_maps

PROJ = (318, 238)                  # odd on purpose (width, height)
# GL vs cv2, outside a 1-px band at the fold and at the input's border
MEAN_LSB, MAX_LSB = 0.5, 2


def _two_planes(tilt_deg=80.0, kink=0.2):
    """A perspective plane 0 and a plane 1 that meets it along a tilted fold.

    ``H1 = H0 + k foldᵀ`` agrees with H0 exactly on the fold line (the walls touch) and bends
    away from it on plane 1's side, like a corner."""
    a = np.deg2rad(tilt_deg)
    fold = np.array([np.cos(a), np.sin(a), 0.0])
    fold[2] = -(fold[0] * 160.0 + fold[1] * 115.0)
    H0 = np.array([[1.10, 0.08, 20.0], [-0.03, 1.05, 15.0], [2e-4, -1e-4, 1.0]])
    H1 = H0 + np.outer([kink, -0.4 * kink, 5e-4 * kink], fold)
    return np.stack([H0, H1]), fold


H2, FOLD = _two_planes()
RECT = (40.3, 30.7, 260.0, 190.0)         # camera px, fractional on purpose


def _images():
    rng = np.random.default_rng(7)
    import skimage.data as data
    noise = lambda w, h: rng.integers(0, 256, (h, w, 3), dtype=np.uint8)  # noqa: E731
    return {
        "noise-97x73-magnified": noise(97, 73),
        "noise-251x190-about-1to1": noise(251, 190),
        "chelsea-451x300-mild-minify": data.chelsea(),
        "coffee-600x400-minify": data.coffee(),
    }


IMAGES = _images()


def _compare_mask(H, fold, rect, image_shape):
    """True where GL and cv2 must agree: not within 1 px of the fold, nor of the input's border."""
    _, _, valid = warp_maps(H, fold, rect, (image_shape[1], image_shape[0]), PROJ)
    k = np.ones((3, 3), np.uint8)
    border = cv2.dilate(valid.astype(np.uint8), k) != cv2.erode(valid.astype(np.uint8), k)
    ys, xs = np.mgrid[0:PROJ[1], 0:PROJ[0]]
    near_fold = (np.abs(fold[0] * xs + fold[1] * ys + fold[2]) < 1.0) if H.shape[0] == 2 else False
    return ~(border | near_fold)


def _assert_agree(gl_out, ref_out, mask, what):
    d = np.abs(gl_out.astype(np.int16) - ref_out.astype(np.int16)).max(axis=2)
    inner = d[mask]
    worst = np.unravel_index(int(np.argmax(np.where(mask, d, -1))), d.shape)
    assert inner.mean() <= MEAN_LSB and inner.max() <= MAX_LSB, (
        f"{what}: GL vs cv2 mean {inner.mean():.3f} max {inner.max()} LSB (limits {MEAN_LSB}, "
        f"{MAX_LSB}); worst at (row, col) {worst}; whole frame max {d.max()}")
    return float(inner.mean()), int(inner.max())


@pytest.fixture(scope="module")
def warper(gl_ctx):
    from rtdefocus.gl.warp import GLWarp
    w = GLWarp(gl_ctx, PROJ)
    yield w
    w.release()


# ----------------------------------------------------------------------------- GL == cv2
@pytest.mark.parametrize("planes", [2, 1], ids=["two-planes", "one-plane"])
@pytest.mark.parametrize("name", list(IMAGES))
def test_gl_matches_cv2(gl, warper, name, planes):
    img = IMAGES[name]
    H, fold = (H2, FOLD) if planes == 2 else (H2[:1], None)
    out = warper.render(img, H, fold, RECT)
    ref = warp_cv2(img, H, fold, RECT, PROJ)
    assert out.shape == (PROJ[1], PROJ[0], 3) and out.dtype == np.uint8
    mask = _compare_mask(H, FOLD, RECT, img.shape)
    _assert_agree(out, ref, mask, f"{name}, {planes} plane(s)")
    # the case is what its name says (magnified / minified), so every sampling path is covered
    lod = warp_lod(H, fold, RECT, (img.shape[1], img.shape[0]), PROJ)
    if "magnified" in name:
        assert np.nanmax(lod) < 0
    if "minify" in name:
        assert np.nanmax(lod) > 0.5 and warper.n_levels > 1
    assert ref[mask].mean() > 20, "test image landed outside the frame: the comparison is empty"


def _many_planes(kind):
    """Three planes that really meet: a U (two parallel-ish folds) or a trihedral corner
    (three folds through one vertex). Each neighbour's homography is its neighbour's plus a
    rank-one term that vanishes on their common fold, as for walls that touch."""
    H0 = np.array([[1.10, 0.08, 20.0], [-0.03, 1.05, 15.0], [2e-4, -1e-4, 1.0]])

    def line(nx, ny, x, y):
        n = np.array([nx, ny]) / np.hypot(nx, ny)
        return np.array([n[0], n[1], -(n[0] * x + n[1] * y)])

    if kind == "u":
        f01, f12 = line(1, 0.05, 70, 115), line(1, -0.08, 180, 115)
        H1 = H0 + np.outer([0.2, -0.08, 1e-4], f01)
        H2_ = H1 + np.outer([0.15, 0.05, 5e-5], f12)
        layout = PlaneLayout(3, [f01, f12], [[0, 1], [1, 2]])
    else:      # left wall 0, ceiling 1, right wall 2, vertex at (160, 90)
        vx, vy = 160.0, 90.0
        f02 = line(1, 0.0, vx, vy)                 # wall | wall, below the vertex
        f10 = line(-1.0, 1.2, vx, vy)              # ceiling (negative) | left wall
        f12 = line(1.0, 1.2, vx, vy)               # ceiling (negative) | right wall
        k = np.array([0.15, 0.2, 1e-4])
        H1 = H0 + np.outer(k, f10)
        # H2 = H0 + k2 f02ᵀ meets H0 on f02; on f12 (through the vertex) f10 and f02 are both
        # proportional to the distance from the vertex, so k2 = k f10/f02 there makes H2 meet
        # H1 on f12 too.
        d = np.array([1.2, -1.0])
        k2 = k * (f10[:2] @ d) / (f02[:2] @ d)
        H2_ = H0 + np.outer(k2, f02)
        layout = PlaneLayout(3, [f02, f10, f12], [[0, 2], [1, 0], [1, 2]])
    return np.stack([H0, H1, H2_]), layout


@pytest.mark.parametrize("kind", ["u", "corner"])
@pytest.mark.parametrize("name", ["noise-251x190-about-1to1", "coffee-600x400-minify"])
def test_gl_matches_cv2_many_planes(gl, warper, kind, name):
    """Any number of planes: the shader picks each pixel's homography as the reference does."""
    img = IMAGES[name]
    H, layout = _many_planes(kind)
    out = warper.render(img, H, layout, RECT)
    ref = warp_cv2(img, H, layout, RECT, PROJ)
    _, _, valid = warp_maps(H, layout, RECT, (img.shape[1], img.shape[0]), PROJ)
    k = np.ones((3, 3), np.uint8)
    border = cv2.dilate(valid.astype(np.uint8), k) != cv2.erode(valid.astype(np.uint8), k)
    ys, xs = np.mgrid[0:PROJ[1], 0:PROJ[0]]
    near = np.zeros(xs.shape, bool)
    for a, b, c in layout.folds:
        near |= np.abs(a * xs + b * ys + c) < 1.0
    mask = ~(border | near)
    _assert_agree(out, ref, mask, f"{name}, {kind}")
    # every plane is really used and has its own homography
    labels = layout.label(xs, ys)
    one = warp_cv2(img, H[:1], None, RECT, PROJ).astype(int)
    for p in range(3):
        sel = (labels == p) & mask & (ref.max(axis=2) > 0)
        assert sel.sum() > 1000, f"plane {p} covers too little of the frame to test"
        if p:
            assert np.abs(ref[sel].astype(int) - one[sel]).mean() > 5, f"plane {p} not its own"


def test_layout_labels_tile_the_frame():
    """Labels: every pixel has exactly one plane; each plane's pixels lie on its side of its
    folds (up to the vertex slack); two planes reproduce the single fold's rule."""
    ys, xs = np.mgrid[0:PROJ[1], 0:PROJ[0]].astype(float)
    for kind in ("u", "corner"):
        _, layout = _many_planes(kind)
        lab = layout.label(xs, ys)
        assert set(np.unique(lab)) == {0, 1, 2}
        for (a, b, c), (neg, pos) in zip(layout.folds, layout.fold_planes, strict=True):
            v = a * xs + b * ys + c
            assert (v[lab == neg] <= 1e-9).all() and (v[lab == pos] >= -1e-9).all()
    two = PlaneLayout.from_fold(FOLD, 2).label(xs, ys)
    assert np.array_equal(two, (FOLD[0] * xs + FOLD[1] * ys + FOLD[2] >= 0).astype(np.int8))


def test_the_fold_matters(gl, warper):
    """Plane 1's own homography is used on its side (so the stitch is really tested)."""
    img = IMAGES["noise-251x190-about-1to1"]
    two = warper.render(img, H2, FOLD, RECT).astype(int)
    one = warper.render(img, H2[:1], None, RECT).astype(int)
    ys, xs = np.mgrid[0:PROJ[1], 0:PROJ[0]]
    side = FOLD[0] * xs + FOLD[1] * ys + FOLD[2]
    assert np.array_equal(two[side < -1], one[side < -1])
    far = (side > 20) & (one.max(axis=2) > 0)
    assert far.sum() > 2000
    assert np.abs(two[far] - one[far]).mean() > 20, "plane 1 rendered with plane 0's homography"


def test_strong_minification_and_horizon(gl, warper):
    """Deep mip levels (input far larger than its footprint), and a homography whose horizon
    crosses the frame (z <= 0 there: black in both)."""
    img = IMAGES["coffee-600x400-minify"]
    rect = (100.0, 80.0, 48.0, 32.0)
    out, ref = warper.render(img, H2, FOLD, rect), warp_cv2(img, H2, FOLD, rect, PROJ)
    assert np.nanmax(warp_lod(H2, FOLD, rect, (600, 400), PROJ)) > 3.0
    _assert_agree(out, ref, _compare_mask(H2, FOLD, rect, img.shape), "minified 12x")

    # z = (x - 60) / 258: behind the horizon left of x = 60, camera x = x / z grows without
    # bound towards it (so the input is squeezed ever smaller: every mip level is used)
    Hh = np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1 / 258, 0.0, -60 / 258]]])
    hrect = (300.0, -10.0, 400.0, 260.0)
    out, ref = warper.render(img, Hh, None, hrect), warp_cv2(img, Hh, None, hrect, PROJ)
    assert not out[:, :61].any() and not ref[:, :61].any(), "behind the horizon must be black"
    assert ref[:, 200:].mean() > 30, "the visible part is missing: the case tests nothing"
    _assert_agree(out, ref, _compare_mask(Hh, FOLD, hrect, img.shape), "horizon")


# ----------------------------------------------------------------------------- known answers
@pytest.mark.parametrize("backend", ["gl", "cv2"])
def test_identity_returns_the_input(gl, warper, backend):
    img = IMAGES["noise-251x190-about-1to1"]
    img = np.ascontiguousarray(np.pad(img, ((0, PROJ[1] - 190), (0, PROJ[0] - 251), (0, 0)),
                                      mode="reflect"))
    rect = (0, 0, PROJ[0], PROJ[1])
    for H, fold in ((np.eye(3)[None], None), (np.stack([np.eye(3), 2.0 * np.eye(3)]), FOLD)):
        out = warper.render(img, H, fold, rect) if backend == "gl" else warp_cv2(img, H, fold, rect, PROJ)
        assert np.array_equal(out, img), f"identity changed {np.count_nonzero(out != img)} values"


@pytest.mark.parametrize("backend", ["gl", "cv2"])
def test_translation_shifts_and_black_outside(gl, warper, backend):
    rng = np.random.default_rng(3)
    img = rng.integers(1, 256, (PROJ[1], PROJ[0], 3), dtype=np.uint8)       # no zeros: black = outside
    dx, dy = 7, -5
    H = np.array([[[1.0, 0, dx], [0, 1.0, dy], [0, 0, 1.0]]])
    rect = (0, 0, PROJ[0], PROJ[1])
    run = (lambda H, r: warper.render(img, H, None, r)) if backend == "gl" else \
        (lambda H, r: warp_cv2(img, H, None, r, PROJ))
    out = run(H, rect)
    # output (x, y) shows input (x + dx, y + dy)
    assert np.array_equal(out[-dy:, :PROJ[0] - dx], img[:PROJ[1] + dy, dx:])
    assert not out[:, PROJ[0] - dx:].any() and not out[:-dy].any()
    # half a pixel: the mean of two neighbours (the +0.5 pixel-centre convention)
    out = run(np.array([[[1.0, 0, 0.5], [0, 1.0, 0], [0, 0, 1.0]]]), rect).astype(int)
    mean2 = (img[:, :-1].astype(int) + img[:, 1:]) / 2.0
    assert np.abs(out[:, :-1] - mean2).max() <= 0.5 + 1e-9


@pytest.mark.parametrize("backend", ["gl", "cv2"])
def test_homographies_are_scale_and_sign_free(gl, warper, backend):
    """H and c·H are the same homography for any c != 0 (negative too: z > 0 is not a property
    of the matrix); large pixel offsets (a 4K camera) are not mistaken for singularity."""
    img = IMAGES["chelsea-451x300-mild-minify"]
    shift = np.array([[1.0, 0, 3000], [0, 1, 1800], [0, 0, 1]])
    H = shift @ H2
    rect = (RECT[0] + 3000, RECT[1] + 1800, RECT[2], RECT[3])
    run = warper.render if backend == "gl" else (lambda *a: warp_cv2(*a, PROJ))
    base = run(img, H, FOLD, rect)
    assert base.max(axis=2).mean() > 20
    for scales in ([-1.0, -1.0], [1e-6, -3e5]):
        out = run(img, H * np.array(scales)[:, None, None], FOLD, rect)
        assert np.abs(out.astype(int) - base).max() <= 1, f"scales {scales} changed the warp"


@pytest.mark.parametrize("backend", ["gl", "cv2"])
def test_display_rect_scaling_is_cv2_resize(gl, warper, backend):
    """Identity homography, rect = the whole frame: the warp is a resize with the pixel-centre
    convention of cv2.resize (inside; at the border we fade to black, cv2 replicates)."""
    img = IMAGES["noise-97x73-magnified"]
    rect = (0, 0, PROJ[0], PROJ[1])
    out = warper.render(img, np.eye(3), None, rect) if backend == "gl" else \
        warp_cv2(img, np.eye(3), None, rect, PROJ)
    expect = cv2.resize(img, PROJ, interpolation=cv2.INTER_LINEAR)
    d = np.abs(out.astype(int) - expect)[3:-3, 3:-3]
    assert d.max() <= 1, f"max {d.max()} LSB from cv2.resize"


@pytest.mark.parametrize("backend", ["gl", "cv2"])
def test_minification_does_not_alias(gl, warper, backend):
    """A 1-px checkerboard shown 3.7x smaller averages to grey (mip levels), where plain
    bilinear sampling would pick a moiré of black and white."""
    ys, xs = np.mgrid[0:round(3.7 * PROJ[1]), 0:round(3.7 * PROJ[0])]
    img = np.repeat((((xs + ys) % 2) * 255).astype(np.uint8)[..., None], 3, axis=2)
    rect = (0, 0, PROJ[0], PROJ[1])
    H = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])   # a slight shear
    out = warper.render(img, H, None, rect) if backend == "gl" else warp_cv2(img, H, None, rect, PROJ)
    inner = out[4:-4, 4:-30].astype(float)            # the shear pushes the right edge out
    assert abs(inner.mean() - 127.5) < 3 and inner.std() < 4, \
        f"minified checkerboard: mean {inner.mean():.1f}, std {inner.std():.1f} (aliasing)"


def test_outside_the_rect_is_black(gl, warper):
    img = np.full((50, 60, 3), 200, np.uint8)
    rect = (100.0, 80.0, 90.0, 70.0)
    out = warper.render(img, H2, FOLD, rect)
    _, _, valid = warp_maps(H2, FOLD, rect, (60, 50), PROJ)
    far = cv2.dilate(valid.astype(np.uint8), np.ones((5, 5), np.uint8)) == 0
    assert far.mean() > 0.5 and not out[far].any()
    assert (out[cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0] == 200).all()


# ----------------------------------------------------------------------------- bad input
BAD = {
    "singular": (np.array([[[1.0, 2, 3], [2, 4, 6], [0, 0, 1]]]), None, RECT, "singular"),
    "nan": (np.array([[[1.0, 0, np.nan], [0, 1, 0], [0, 0, 1]]]), None, RECT, "NaN"),
    "zeros": (np.zeros((1, 3, 3)), None, RECT, "singular"),
    "three-planes-one-fold": (np.stack([H2[0]] * 3), FOLD, RECT, "PlaneLayout"),
    "nine-planes": (np.stack([np.eye(3)] * 9), None, RECT, r"n = 1 \.\. 8"),
    "no-fold": (H2, None, RECT, "planes"),
    "zero-fold": (H2, np.zeros(3), RECT, "planes"),
    "empty-rect": (H2, FOLD, (0, 0, 0, 10), "rect"),
    "nan-rect": (H2, FOLD, (0, np.nan, 10, 10), "rect"),
}


@pytest.mark.timeout(30)
@pytest.mark.parametrize("case", list(BAD))
@pytest.mark.parametrize("backend", ["gl", "cv2"])
def test_bad_geometry_is_a_clear_error(gl, warper, backend, case):
    H, fold, rect, words = BAD[case]
    img = IMAGES["noise-97x73-magnified"]
    with pytest.raises(InputError, match=words):
        if backend == "gl":
            warper.render(img, H, fold, rect)
        else:
            warp_cv2(img, H, fold, rect, PROJ)
    # the warper still works afterwards (a rejected geometry leaves no half-set state)
    ok = warper.render(img, H2, FOLD, RECT)
    assert np.array_equal(ok, warper.render(img, H2, FOLD, RECT))


@pytest.mark.parametrize("bad", [np.zeros((10, 10), np.uint8), np.zeros((10, 10, 3), np.float32),
                                 np.zeros((10, 10, 4), np.uint8)], ids=["gray", "float", "rgba"])
def test_bad_image_is_a_clear_error(gl, warper, bad):
    for run in (lambda: warper.render(bad, H2, FOLD, RECT), lambda: warp_cv2(bad, H2, FOLD, RECT, PROJ)):
        with pytest.raises(InputError, match=r"RGB uint8 of shape \(H, W, 3\)"):
            run()


# ----------------------------------------------------------------------------- reuse, targets
def test_objects_are_reused_across_frames(gl, warper):
    rng = np.random.default_rng(11)
    a, b = (rng.integers(0, 256, (73, 97, 3), dtype=np.uint8) for _ in range(2))
    out_a = warper.render(a, H2, FOLD, RECT)
    objs = (warper.texture, warper.fbo, warper.program, warper.vao, warper.sampler)
    glos = tuple(o.glo for o in objs[:4])
    out_b = warper.render(b, H2, FOLD, RECT)
    assert all(x is y for x, y in zip(objs, (warper.texture, warper.fbo, warper.program,
                                             warper.vao, warper.sampler), strict=True))
    assert glos == tuple(o.glo for o in objs[:4])
    assert not np.array_equal(out_a, out_b), "second frame shows the first frame's texture"
    _assert_agree(out_b, warp_cv2(b, H2, FOLD, RECT, PROJ), _compare_mask(H2, FOLD, RECT, b.shape),
                  "second frame")


def test_render_to_a_framebuffer(gl, warper):
    img = IMAGES["chelsea-451x300-mild-minify"]
    from rtdefocus.gl.runtime import read_rgb
    fbo = gl.framebuffer(color_attachments=[gl.renderbuffer(PROJ, components=4)])
    try:
        warper.render_to(fbo, img, H2, FOLD, RECT)
        assert np.array_equal(read_rgb(fbo, PROJ), warper.render(img, H2, FOLD, RECT))
    finally:
        fbo.release()
    small = gl.framebuffer(color_attachments=[gl.renderbuffer((100, 80), components=4)])
    try:
        with pytest.raises(InputError, match="projector's size"):
            warper.render_to(small, img, H2, FOLD, RECT)
    finally:
        small.release()


# ----------------------------------------------------------------------------- warp_image, CLI
def _calibration(H, fold):
    """A hand-made geometry-only Calibration (no geometric calibration needed)."""
    Hinv = np.linalg.inv(H)
    if H.shape[0] == 2:
        fold_cam = np.linalg.inv(H[0]).T @ fold
        fold_cam = fold_cam / np.hypot(fold_cam[0], fold_cam[1])
    else:
        fold, fold_cam = np.zeros(3), np.zeros(3)
    w, h = PROJ
    border = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], np.float64)
    pts = cv2.perspectiveTransform(border[None], H[0])[0]
    return Calibration.with_fold(projector_size=PROJ, camera_size=(400, 300), H_cam_from_proj=H,
                       H_proj_from_cam=Hinv, fold_proj=fold, fold_cam=fold_cam,
                       lit_polygon_cam=pts)


def test_warp_image_backends_and_fallback(gl, monkeypatch, caplog):
    import rtdefocus.gl.warp as glwarp
    calib = _calibration(H2, FOLD)
    img = IMAGES["chelsea-451x300-mild-minify"]
    seen = []
    monkeypatch.setattr(Calibration, "display_rect", lambda self, size, margin=0.0:
                        seen.append(size) or RECT)
    g = glwarp.warp_image(calib, img, backend="gl")
    c = glwarp.warp_image(calib, img, backend="cv2")
    assert seen == [(451, 300), (451, 300)], "rect=None must ask calib.display_rect((W, H))"
    _assert_agree(g, c, _compare_mask(H2, FOLD, RECT, img.shape), "warp_image")
    assert np.array_equal(glwarp.warp_image(calib, img, rect=RECT), g)      # auto -> GL here

    def no_egl(*a, **k):
        raise DeviceError("no EGL here")
    monkeypatch.setattr(glwarp, "create_context", no_egl)
    monkeypatch.setattr(glwarp, "_warned_no_gl", False)
    with caplog.at_level(logging.WARNING, logger="rtdefocus.gl.warp"):
        a1 = glwarp.warp_image(calib, img, rect=RECT)
        glwarp.warp_image(calib, img, rect=RECT)
    assert np.array_equal(a1, c)
    assert len([r for r in caplog.records if "cv2 reference" in r.message]) == 1
    with pytest.raises(DeviceError):
        glwarp.warp_image(calib, img, rect=RECT, backend="gl")
    with pytest.raises(InputError, match="backend"):
        glwarp.warp_image(calib, img, rect=RECT, backend="vulkan")


@pytest.mark.parametrize("backend", ["gl", "cv2"])
def test_cli_warp(gl, tmp_path, capsys, backend):
    from rtdefocus import cli
    from rtdefocus.imageio import read_image
    calib = _calibration(H2[:1], None)
    path = calib.save(tmp_path / "setup.npz")
    img = IMAGES["chelsea-451x300-mild-minify"]
    cli.write_image(tmp_path / "in.png", img)
    out = tmp_path / "out.png"
    assert cli.main(["warp", str(path), str(tmp_path / "in.png"), "-o", str(out),
                     "--margin", "0.1", "--backend", backend]) == 0
    text = capsys.readouterr().out
    rect = Calibration.load(path).display_rect((451, 300), margin=0.1)
    assert f"x={rect[0]} y={rect[1]} w={rect[2]} h={rect[3]}" in text
    got = read_image(out)
    ref = warp_cv2(img, calib.H_cam_from_proj, None, rect, PROJ)
    _assert_agree(got, ref, _compare_mask(calib.H_cam_from_proj, FOLD, rect, img.shape), "cli")
    assert got.any()
    with pytest.raises(SystemExit) as info:
        cli.main(["warp", str(path), str(tmp_path / "in.png"), "-o", str(out), "--margin", "2"])
    assert info.value.code == 2
    assert cli.main(["warp", str(tmp_path / "missing.npz"), str(tmp_path / "in.png"),
                     "-o", str(out)]) == 1


# ----------------------------------------------------------------------------- end to end
def _rect_inside(mask: np.ndarray, aspect: float, pad: int = 6):
    """Largest upright rect of ``aspect`` centred on the mask's centroid, inside the mask."""
    ys, xs = np.nonzero(mask)
    cx, cy = xs.mean(), ys.mean()
    lo, hi = 1.0, float(mask.shape[1])
    for _ in range(40):
        w = (lo + hi) / 2
        h = w / aspect
        x0, y0 = int(round(cx - w / 2)) - pad, int(round(cy - h / 2)) - pad
        x1, y1 = int(round(cx + w / 2)) + pad, int(round(cy + h / 2)) + pad
        inside = x0 >= 0 and y0 >= 0 and x1 < mask.shape[1] and y1 < mask.shape[0] and \
            mask[y0:y1 + 1, x0:x1 + 1].all()
        lo, hi = (w, hi) if inside else (lo, w)
    w = int(lo)
    h = int(round(w / aspect))
    return (int(round(cx - w / 2)), int(round(cy - h / 2)), w, h)


@pytest.mark.parametrize("preset", ["cubicle", "pillar", "flat", "tilted", "offcenter"])
def test_checkerboard_through_true_geometry_lands_on_the_rect(gl_ctx, preset):
    from rtdefocus import sim
    from rtdefocus.gl.warp import GLWarp
    procam = sim.VirtualProCam(preset)
    truth = procam.truth
    img = checkerboard.board()
    H, W = img.shape[:2]
    rect = _rect_inside(truth.extra["camera_in_frame"], W / H)
    fold = truth.fold_proj if truth.fold_proj is not None else np.zeros(3)
    frame = GLWarp(gl_ctx, procam.projector_size).render(img, truth.H_cam_from_proj, fold, rect)
    err, _ = checkerboard.corner_errors(procam.capture(frame, sharp=True), rect, img.shape)
    rms = float(np.sqrt(np.mean(err ** 2)))
    assert rms <= 0.5, f"{preset}: corners {rms:.3f} camera px RMS from the rect (max {err.max():.3f})"
