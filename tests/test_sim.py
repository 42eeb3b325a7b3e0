"""The virtual projector-camera set-up: geometry, thin-lens blur, radiometry, ground truth."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from rtdefocus import cli, sim
from rtdefocus.errors import InputError
from rtdefocus.procam import ProCam

_CACHE: dict = {}

# Presets whose walls are planes (the bowed ones and the gap's far wall: tests/test_sim_walls.py).
PLANAR = [p for p, sc in sim.PRESETS.items() if not any(sc.bow) and sc.gap_x_frac is None]
#: The presets the fast tier builds (each full-size build costs about a second); the others
#: run in the whole suite.
FAST_PRESETS = ("cubicle", "tilted", "offcenter")


def fast_only(presets, fast=FAST_PRESETS):
    """``presets`` as parameters, those outside ``fast`` marked slow."""
    return [pytest.param(p, marks=() if p in fast else pytest.mark.slow) for p in presets]


def procam(preset: str, **kw) -> sim.VirtualProCam:
    """One instance per (preset, options) for the whole module (construction costs ~0.5 s)."""
    key = (preset, tuple(sorted(kw.items())))
    if key not in _CACHE:
        _CACHE[key] = sim.VirtualProCam(preset, **kw)
    return _CACHE[key]


def fold_dist(line, x, y):
    return line[0] * x + line[1] * y + line[2]


def lit_difference(pc, pattern, sharp):
    """Camera image of ``pattern`` minus that of a black frame (float, noise-free procam)."""
    black = np.zeros_like(pattern)
    return (pc.capture(pattern, sharp=sharp).astype(np.float64)
            - pc.capture(black, sharp=sharp).astype(np.float64))


# --------------------------------------------------------------------------- basics
def test_protocol_sizes_and_dtype():
    pc = procam("cubicle")
    assert isinstance(pc, ProCam)
    assert pc.projector_size == (800, 600) and pc.camera_size == (1280, 960)
    img = pc.capture(sim.test_pattern("checker", pc.projector_size))
    assert img.shape == (960, 1280, 3) and img.dtype == np.uint8
    # A black frame shows only the ambient light on the walls: dark but not all zero.
    black = pc.capture(np.zeros((600, 800, 3), np.uint8), sharp=True)
    assert 0 < black.max() < 20


@pytest.mark.parametrize("name", sim.PATTERNS)
def test_patterns(name):
    p = sim.test_pattern(name, (320, 240))
    assert p.shape == (240, 320, 3) and p.dtype == np.uint8
    assert set(np.unique(p)) == {0, 255}
    with pytest.raises(InputError, match="unknown test pattern"):
        sim.test_pattern("stripes", (320, 240))


def test_bad_arguments():
    with pytest.raises(InputError, match="unknown simulator preset"):
        sim.VirtualProCam("kitchen")
    with pytest.raises(InputError, match="aperture"):
        sim.VirtualProCam("cubicle", aperture="square")
    pc = procam("cubicle")
    with pytest.raises(InputError, match="pattern must be"):
        pc.capture(np.zeros((100, 100, 3), np.uint8))
    with pytest.raises(InputError, match="outside"):
        pc.truth.kernel_at(800, 10)


@pytest.mark.slow
@pytest.mark.parametrize("preset", PLANAR)
def test_frame_fully_on_walls_and_in_view(preset):
    pc = procam(preset)
    t = pc.truth
    wp, hp = pc.projector_size
    assert np.all(np.isfinite(t.depth_map)) and t.depth_map.min() > 0.5
    # Every projector frame corner lands inside the camera frame, with a margin of >= 40 px.
    corners = np.array([[-0.5, -0.5], [wp - 0.5, -0.5], [-0.5, hp - 0.5], [wp - 0.5, hp - 0.5]])
    for x, y in corners:
        p = t.plane_map[min(int(y + 0.5), hp - 1), min(int(x + 0.5), wp - 1)]   # corner pixel's plane
        c = t.H_cam_from_proj[p] @ [x, y, 1.0]
        cx, cy = c[:2] / c[2]
        assert 40 < cx < pc.camera_size[0] - 40 and 40 < cy < pc.camera_size[1] - 40, (preset, cx, cy)
    # ... and the camera sees every lit point: projector points mapped through their plane's
    # homography land on camera pixels that the ray caster found lit, on the same wall.
    rng = np.random.default_rng(2)
    pts = rng.uniform([1, 1], [wp - 2, hp - 2], size=(2000, 2))
    plane = t.plane_map[np.rint(pts[:, 1]).astype(int), np.rint(pts[:, 0]).astype(int)]
    h = np.einsum("nij,nj->ni", t.H_cam_from_proj[plane], np.c_[pts, np.ones(len(pts))])
    cx, cy = np.rint(h[:, 0] / h[:, 2]).astype(int), np.rint(h[:, 1] / h[:, 2]).astype(int)
    assert np.all(t.extra["camera_in_frame"][cy, cx])
    assert np.mean(t.extra["camera_plane_map"][cy, cx] == plane) > 0.995   # rounding at the fold


# --------------------------------------------------------------------------- blur radius
# The cubicle in the fast tier; every other preset in the whole suite.
@pytest.mark.parametrize("preset", [pytest.param(p, marks=() if p == "cubicle" else pytest.mark.slow)
                                    for p in PLANAR])
def test_radius_affine_per_wall_and_thin_lens(preset):
    pc = procam(preset)
    t = pc.truth
    hp, wp = t.radius_map.shape
    yy, xx = np.mgrid[0:hp, 0:wp]
    # Thin lens from the depth map (float32 depth: ~1e-6 relative).
    expected = t.blur_scale * np.abs(1.0 / t.focus_distance - 1.0 / t.depth_map.astype(np.float64))
    assert np.abs(t.radius_map - expected).max() < 0.05
    # Radii in the documented range at 800x600, nobody in focus.
    assert 1.3 < t.radius_map.min() and t.radius_map.max() < 6.3
    fits = []
    for p in range(t.n_planes):
        sel = t.plane_map == p
        A = np.stack([xx[sel], yy[sel], np.ones(sel.sum())], 1).astype(np.float64)
        coef, *_ = np.linalg.lstsq(A, t.radius_map[sel].astype(np.float64), rcond=None)
        assert np.abs(A @ coef - t.radius_map[sel]).max() < 1e-3, f"radius not affine on wall {p}"
        # 1/D is affine in projector pixels on a plane (independent of the radius formula).
        cinv, *_ = np.linalg.lstsq(A, 1.0 / t.depth_map[sel].astype(np.float64), rcond=None)
        assert np.abs(A @ cinv - 1.0 / t.depth_map[sel]).max() < 1e-5
        fits.append(coef)
    if t.n_planes == 1:
        assert np.all(t.plane_map == 0) and t.fold_proj is None and len(t.folds_proj) == 0
        return
    # Continuous at every fold, with a slope change.
    for (a, b, c), (p0, p1) in zip(t.folds_proj, t.fold_planes, strict=True):
        s = np.linspace(-300, 300, 7)                  # along the fold from its foot
        xs, ys = -c * a - s * b, -c * b + s * a
        r0 = fits[p0][0] * xs + fits[p0][1] * ys + fits[p0][2]
        r1 = fits[p1][0] * xs + fits[p1][1] * ys + fits[p1][2]
        assert np.abs(r0 - r1).max() < 1e-3
        assert np.hypot(*(fits[p0][:2] - fits[p1][:2])) > 1e-3
    if t.fold_proj is None:
        return
    # Where the extreme radius is: at the fold (cubicle max, pillar min).
    d = np.abs(fold_dist(t.fold_proj, xx, yy))
    near = d < 1.0
    if preset in ("cubicle", "tilted"):
        assert t.radius_map[near].max() >= t.radius_map.max() - 1e-4
        assert t.radius_map[d > 50].max() < t.radius_map.max() - 0.2
    if preset == "pillar":
        assert t.radius_map[near].min() <= t.radius_map.min() + 1e-4
        assert t.radius_map[d > 50].min() > t.radius_map.min() + 0.2


def test_chromatic_radius_and_kernel():
    pc = procam("cubicle", chromatic=(1.2, 1.0, 0.8), projector_size=(400, 300), camera_size=(640, 480))
    t = pc.truth
    np.testing.assert_allclose(t.radius_rgb[0], 1.2 * t.radius_map, rtol=1e-6)
    np.testing.assert_allclose(t.radius_rgb[2], 0.8 * t.radius_map, rtol=1e-6)
    kr, kb = t.kernel_at(200, 150, size=15, channel=0), t.kernel_at(200, 150, size=15, channel=2)
    uu, vv = np.meshgrid(np.arange(15) - 7, np.arange(15) - 7)
    m2 = [float((k * (uu ** 2 + vv ** 2)).sum()) for k in (kr, kb)]
    assert m2[0] > 1.3 * m2[1]          # red spreads more than blue


# --------------------------------------------------------------------------- the kernel field
def _assert_gather_matches(pc, P, points):
    """pc.defocus(P) at ``points`` equals sum_u k_x(u) P(x - u) with truth.kernel_at."""
    out = pc.defocus(P)
    pad = 20
    Ppad = np.pad(P, ((pad, pad), (pad, pad), (0, 0)))    # no light outside the frame
    for x, y in points:
        for ch in range(3):
            k = pc.truth.kernel_at(x, y, channel=ch)
            assert k.dtype == np.float32 and k.shape[0] % 2 == 1
            assert abs(float(k.sum()) - 1.0) < 1e-5
            h = k.shape[0] // 2
            # psf[h + v, h + u] = k(u, v) pairs with P(x - u, y - v): the window, reversed.
            win = Ppad[pad + y - h:pad + y + h + 1, pad + x - h:pad + x + h + 1, ch]
            expect = float((k * win[::-1, ::-1]).sum())
            assert abs(out[y, x, ch] - expect) < 2e-5, (x, y, ch, out[y, x, ch], expect)


_POINTS = [(0, 0), (5, 230), (160, 120), (317, 3), (100, 200), (250, 60), (161, 50)]


@pytest.mark.parametrize("aperture, chromatic", [("disc", (1.1, 1.0, 0.9)), ("hex", (1.1, 1.0, 0.9)),
                                                  ("disc", (1.15, 1.0, 1.15))],
                         ids=["disc", "hex", "disc-R=B"])
def test_rendering_equals_truth_kernels(aperture, chromatic):
    """defocus() (the renderer's F) equals the explicit gather with truth.kernel_at."""
    pc = procam("tilted", aperture=aperture, chromatic=chromatic,
                projector_size=(320, 240), camera_size=(480, 360))
    P = np.random.default_rng(1).random((240, 320, 3)).astype(np.float32)
    _assert_gather_matches(pc, P, _POINTS)


def test_gather_convention_with_asymmetric_kernel(monkeypatch):
    """Disc and hexagon are centrally symmetric, so they cannot expose a flipped kernel; an
    asymmetric aperture (brighter on the +u side) can: the renderer must convolve
    (O(x) = sum_u k(u) P(x - u)), not correlate."""
    original = sim.optics._level_kernel

    def lopsided(j, aperture):
        ker = np.array(original(j, aperture))
        h = ker.shape[0] // 2
        u, v = np.meshgrid(np.arange(-h, h + 1), np.arange(-h, h + 1))
        ker = ker * (1.0 + 0.8 * (u > 0) + 0.3 * (v > 0))
        return ker / ker.sum()

    monkeypatch.setattr(sim.optics, "_level_kernel", lopsided)
    pc = sim.VirtualProCam("cubicle", projector_size=(320, 240), camera_size=(320, 240))
    k = pc.truth.kernel_at(160, 120)
    assert np.abs(k - k[::-1, ::-1]).max() > 1e-3          # really asymmetric
    # A single lit pixel spreads as the kernel itself, not flipped (DESIGN.md §3: a dot
    # at y measures m(x) = k_x(x - y)): mostly to its right.
    P = np.zeros((240, 320, 3), np.float32)
    P[120, 100] = 1.0
    out = pc.defocus(P)[..., 1]
    assert out[120, 101:110].sum() > 1.5 * out[120, 91:100].sum()
    P = np.random.default_rng(4).random((240, 320, 3)).astype(np.float32)
    _assert_gather_matches(pc, P, _POINTS)


def test_hex_kernel_shape():
    k = sim.blend_kernel(5.0, "hex")
    d = sim.blend_kernel(5.0, "disc")
    assert k.shape == d.shape and abs(k.sum() - 1) < 1e-6
    h = k.shape[0] // 2
    # Circumradius 5 with vertices on the x axis: reaches (±5, 0) but only ±4.33 along y.
    assert k[h, h + 5] > 0 and k[h + 5, h] == 0 and d[h + 5, h] > 0
    np.testing.assert_allclose(k, k[::-1, ::-1], atol=1e-7)     # centrally symmetric


def test_kernel_size_argument():
    t = procam("cubicle").truth
    full = t.kernel_at(400, 300)
    big = t.kernel_at(400, 300, size=full.shape[0] + 4)
    np.testing.assert_allclose(big[2:-2, 2:-2], full, atol=1e-7)
    small = t.kernel_at(400, 300, size=5)
    assert small.shape == (5, 5) and abs(small.sum() - 1) < 1e-6
    with pytest.raises(InputError, match="odd"):
        t.kernel_at(400, 300, size=8)


def test_blur_keeps_constant_and_energy_in_interior():
    pc = procam("cubicle")
    hp, wp = 600, 800
    # Unit-sum kernels: a uniform image stays uniform away from the border (exact).
    out = pc.defocus(np.ones((hp, wp, 3), np.float32))
    np.testing.assert_allclose(out[10:-10, 10:-10], 1.0, atol=1e-5)
    assert out[0, 0, 1] < 0.5                          # the corner loses light to the outside
    # Energy: an interior pattern (checker, zero within 20 px of the border) keeps its sum.
    # Kernels vary in space, so the gather form conserves energy only to second order in the
    # radius gradient (~0.01 px/px here); the asymmetric first-order term cancels.
    P = (sim.test_pattern("checker", (wp, hp)) / 255.0).astype(np.float32)
    P[:20], P[-20:], P[:, :20], P[:, -20:] = 0, 0, 0, 0
    blurred = pc.defocus(P)
    rel = abs(float(blurred.sum()) - float(P.sum())) / float(P.sum())
    assert rel < 2e-4, rel
    assert np.abs(blurred - P).max() > 0.3             # and it did blur


@pytest.mark.slow
def test_dot_radius_through_camera_matches_truth():
    """A dot, captured and mapped back through the true homography, has the true radius."""
    pc = procam("cubicle", noise=0.0)
    t = pc.truth
    wp, hp = pc.projector_size
    H_inv = np.linalg.inv(t.H_cam_from_proj[0])
    for x0, y0 in [(120, 150), (200, 420)]:        # left wall, far from the fold
        assert fold_dist(t.fold_proj, x0, y0) < -60
        pat = np.zeros((hp, wp, 3), np.uint8)
        pat[y0 - 2:y0 + 3, x0 - 2:x0 + 3] = 255       # 5x5 dot: bright enough for uint8
        m2 = {}
        for sharp in (True, False):
            diff = lit_difference(pc, pat, sharp)[..., 1]
            back = cv2.warpPerspective(diff, H_inv, (wp, hp), flags=cv2.INTER_LINEAR)
            win = back[y0 - 15:y0 + 16, x0 - 15:x0 + 16]
            win = np.where(win > 0, win, 0.0)
            vv, uu = np.mgrid[-15:16, -15:16]
            s = win.sum()
            cx, cy = (win * uu).sum() / s, (win * vv).sum() / s
            assert abs(cx) < 0.3 and abs(cy) < 0.3       # the dot lands where the homography says
            m2[sharp] = float((win * ((uu - cx) ** 2 + (vv - cy) ** 2)).sum() / s)
        # Second moments add under convolution; the sharp capture carries the dot's own size
        # and the resampling blur. For a uniform disc E[rho^2] = r^2 / 2.
        r_est = math.sqrt(2.0 * (m2[False] - m2[True]))
        r_true = t.radius_map[y0, x0]
        assert abs(r_est - r_true) < 0.25, (x0, y0, r_est, r_true)


# --------------------------------------------------------------------------- geometry
@pytest.mark.parametrize("preset", fast_only(["cubicle", "pillar", "tilted", "offcenter"]))
def test_fold_lines_consistent(preset):
    t = procam(preset).truth
    hp, wp = t.plane_map.shape
    for line in (t.fold_proj, t.fold_cam):
        assert line.shape == (3,) and abs(math.hypot(line[0], line[1]) - 1) < 1e-12
    yy, xx = np.mgrid[0:hp, 0:wp]
    d = fold_dist(t.fold_proj, xx, yy)
    clear = np.abs(d) > 1e-6
    assert np.array_equal(t.plane_map[clear], (d[clear] > 0).astype(np.int8))
    # Fold points map through both homographies to the same point on the camera fold line.
    a, b, c = t.fold_proj
    for y in np.linspace(0, hp - 1, 5):
        x = -(b * y + c) / a
        pts = []
        for H in t.H_cam_from_proj:
            q = H @ [x, y, 1.0]
            pts.append(q[:2] / q[2])
            assert abs(fold_dist(t.fold_cam, *pts[-1])) < 1e-6
        assert np.hypot(*(pts[0] - pts[1])) < 1e-6
    # Plane 0 is on the negative side in the camera too.
    q = t.H_cam_from_proj[0] @ [x - 50 * a, y - 50 * b, 1.0]
    assert fold_dist(t.fold_cam, *(q[:2] / q[2])) < 0


def test_tilted_fold_not_vertical_offcenter_position():
    t = procam("tilted").truth
    for line in (t.fold_proj, t.fold_cam):
        assert abs(math.degrees(math.atan2(abs(line[1]), abs(line[0])))) > 3   # not vertical
    t = procam("offcenter").truth
    x_mid = -(t.fold_proj[1] * 299.5 + t.fold_proj[2]) / t.fold_proj[0]
    assert abs(x_mid / 800 - 0.3) < 0.01
    assert procam("cubicle").truth.fold_proj[1] == pytest.approx(0.0, abs=1e-9)


def test_flat_has_one_plane():
    t = procam("flat").truth
    assert t.fold_proj is None and t.fold_cam is None
    assert t.H_cam_from_proj.shape == (1, 3, 3) and np.all(t.plane_map == 0)


@pytest.mark.parametrize("preset", fast_only(PLANAR))
def test_homographies_match_depth_and_pinholes(preset):
    """Back-project with the depth map, move to the camera, project: equals H @ x."""
    t = procam(preset).truth
    rng = np.random.default_rng(3)
    hp, wp = t.plane_map.shape
    for _ in range(50):
        x, y = int(rng.integers(0, wp)), int(rng.integers(0, hp))
        X = t.depth_map[y, x] * (np.linalg.inv(t.K_proj) @ [x, y, 1.0])
        n, dist = t.planes_proj[t.plane_map[y, x], :3], t.planes_proj[t.plane_map[y, x], 3]
        assert abs(n @ X - dist) < 1e-5 * abs(dist)
        c = t.K_cam @ (t.R_cam_from_proj @ X + t.t_cam_from_proj)
        q = t.H_cam_from_proj[t.plane_map[y, x]] @ [x, y, 1.0]
        assert np.hypot(*(c[:2] / c[2] - q[:2] / q[2])) < 1e-3


def _line_centres(diff, fold_cam, min_fold_px=12):
    """Per camera column, the intensity-weighted row of a bright near-horizontal line."""
    img = diff[..., 1]
    cols = np.flatnonzero(img.max(axis=0) > 30)
    pts = []
    for x in cols:
        col = img[:, x]
        y0 = int(np.argmax(col))
        lo, hi = max(0, y0 - 8), y0 + 9
        w = np.clip(col[lo:hi], 0, None)
        w = np.where(w > 0.1 * w.max(), w, 0)
        pts.append((x, float((w * np.arange(lo, lo + len(w))).sum() / w.sum())))
    pts = np.array(pts)
    d = fold_dist(fold_cam, pts[:, 0], pts[:, 1])
    return pts[d < -min_fold_px], pts[d > min_fold_px]


def _fit(pts):
    A = np.stack([pts[:, 0], np.ones(len(pts))], 1)
    coef, *_ = np.linalg.lstsq(A, pts[:, 1], rcond=None)
    return coef, np.sqrt(np.mean((A @ coef - pts[:, 1]) ** 2))


@pytest.mark.parametrize("preset", fast_only(["cubicle", "tilted"], fast=("cubicle",)))
@pytest.mark.parametrize("row", [60, 540])
def test_projected_line_straight_per_wall_bent_at_fold(preset, row):
    pc = procam(preset, noise=0.0)
    t = pc.truth
    pat = np.zeros((600, 800, 3), np.uint8)
    pat[row - 1:row + 2, 30:770] = 255
    left, right = _line_centres(lit_difference(pc, pat, sharp=True), t.fold_cam)
    assert len(left) > 100 and len(right) > 100
    (c0, res0), (c1, res1) = _fit(left[5:-5]), _fit(right[5:-5])
    assert res0 < 0.3 and res1 < 0.3, (res0, res1)
    bend = abs(math.degrees(math.atan(c0[0]) - math.atan(c1[0])))
    assert bend > 1.0, bend


def _checker_fn(xc, yc, x0, y0, s):
    return ((np.floor((xc - x0) / s) + np.floor((yc - y0) / s)) % 2 == 0)


@pytest.mark.parametrize("preset", ["cubicle", "tilted"])
def test_prewarped_checker_is_rectangular(preset):
    """A checker pre-warped with the true homographies (stitched at the fold) looks upright."""
    pc = procam(preset)
    t = pc.truth
    wp, hp = pc.projector_size
    x0, y0, s, nx, ny = 380.0, 270.0, 44.0, 10, 8          # camera rect: squares of 44 px
    ss = 4                                                  # supersampling: antialiased edges
    off = (np.arange(ss) + 0.5) / ss - 0.5
    acc = np.zeros((hp, wp))
    yy, xx = np.mgrid[0:hp, 0:wp].astype(np.float64)
    for dy in off:
        for dx in off:
            X, Y = xx + dx, yy + dy
            plane = (fold_dist(t.fold_proj, X, Y) > 0).astype(int)
            Hs = t.H_cam_from_proj[plane]                   # (hp, wp, 3, 3)
            v = np.stack([X, Y, np.ones_like(X)], -1)
            c = np.einsum("hwij,hwj->hwi", Hs, v)
            xc, yc = c[..., 0] / c[..., 2], c[..., 1] / c[..., 2]
            # (nx+1) x (ny+1) squares from (x0, y0): inner corners at x0 + i s, y0 + j s,
            # i = 1..nx, j = 1..ny; a white quiet zone of one square around the board.
            board = (xc >= x0) & (xc < x0 + (nx + 1) * s) & (yc >= y0) & (yc < y0 + (ny + 1) * s)
            zone = (xc >= x0 - s) & (xc < x0 + (nx + 2) * s) & (yc >= y0 - s) & (yc < y0 + (ny + 2) * s)
            acc += np.where(board, _checker_fn(xc, yc, x0, y0, s), zone.astype(float))
    pat = np.repeat(np.rint(255 * acc / ss ** 2).astype(np.uint8)[..., None], 3, axis=2)
    # The rect straddles the fold, so the test covers the stitch.
    assert fold_dist(t.fold_cam, x0, y0) < 0 < fold_dist(t.fold_cam, x0 + nx * s, y0)
    grey = cv2.cvtColor(pc.capture(pat, sharp=True), cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCorners(grey, (nx, ny))
    assert found, "chessboard not found in the sharp capture"
    corners = cv2.cornerSubPix(grey, corners, (9, 9), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)).reshape(-1, 2)
    expect = np.array([(x0 + i * s, y0 + j * s) for j in range(1, ny + 1) for i in range(1, nx + 1)])
    # Corner order may start at either end: match each found corner to the nearest expected one.
    d = np.hypot(*(corners[:, None, :] - expect[None]).transpose(2, 0, 1))
    err = d.min(axis=1)
    assert len(set(d.argmin(axis=1))) == nx * ny
    print(f"{pc.preset}: pre-warped checker corner error max {err.max():.3f} px, "
          f"mean {err.mean():.3f} px")
    assert err.max() < 0.5, err.max()


# --------------------------------------------------------------------------- radiometry
def test_radiometry_model():
    """Sharp captures follow code = 255 (exposure albedo (shade g(v) + ambient))^(1/gamma_c)."""
    pc = procam("cubicle", projector_gamma=2.2, camera_gamma=2.0, noise=0.0,
                projector_size=(400, 300), camera_size=(640, 480))
    t = pc.truth
    ys, xs = np.nonzero(t.extra["camera_in_frame"])
    rng = np.random.default_rng(0)
    pick = rng.choice(len(xs), 200, replace=False)
    for v in (64, 128, 255):
        img = pc.capture(np.full((300, 400, 3), v, np.uint8), sharp=True).astype(np.float64)
        g = (v / 255.0) ** 2.2
        for i in pick:
            xc, yc = xs[i], ys[i]
            # The projector pixel this camera pixel sees, through the true homography.
            plane = t.extra["camera_plane_map"][yc, xc]
            q = np.linalg.inv(t.H_cam_from_proj[plane]) @ [xc, yc, 1.0]
            xp, yp = int(round(q[0] / q[2])), int(round(q[1] / q[2]))
            if not (2 <= xp < 398 and 2 <= yp < 298):
                continue
            lin = t.albedo_proj[yp, xp, 1] * g + t.ambient_proj[yp, xp, 1]
            expect = 255.0 * lin ** 0.5
            assert abs(img[yc, xc, 1] - expect) < 0.02 * expect + 1.5, (v, xc, yc, img[yc, xc, 1], expect)
    # Auto-exposure: white peaks below full scale, and the walls differ in albedo.
    assert t.albedo_proj.max() + t.ambient_proj.max() <= 0.96


def test_noise_seeded_and_sharp_is_noise_free():
    pat = sim.test_pattern("checker", (320, 240))
    a = sim.VirtualProCam("cubicle", projector_size=(320, 240), camera_size=(480, 360), seed=5)
    b = sim.VirtualProCam("cubicle", projector_size=(320, 240), camera_size=(480, 360), seed=5)
    ia, ib = a.capture(pat), b.capture(pat)
    assert np.array_equal(ia, ib)                         # same seed, same frame
    ia2 = a.capture(pat)
    diff = ia2.astype(float) - ia.astype(float)
    sd = diff[60:300, 100:380].std() / math.sqrt(2)
    assert 0.5 < sd < 3.0                                 # ~0.6 % of full scale = 1.5 codes
    assert np.array_equal(a.capture(pat, sharp=True), a.capture(pat, sharp=True))


def test_texture_changes_albedo_faintly():
    plain = procam("cubicle", projector_size=(320, 240), camera_size=(480, 360))
    tex = sim.VirtualProCam("cubicle", projector_size=(320, 240), camera_size=(480, 360), texture=True)
    ratio = tex.truth.albedo_proj / plain.truth.albedo_proj * plain.exposure / tex.exposure
    assert 0.005 < ratio.std() < 0.05 and 0.9 < ratio.min() and ratio.max() < 1.1


# --------------------------------------------------------------------------- CLI
@pytest.mark.slow
def test_cli_simulate_writes_png(tmp_path):
    out = tmp_path / "cubicle.png"
    assert cli.main(["-q", "simulate", "--scene", "cubicle", "--pattern", "checker", "-o", str(out)]) == 0
    img = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert img is not None and img.shape == (960, 1280, 3)
    assert img.max() > 150 and np.median(img) < 60   # a bright checker on a dark surround
    assert cli.main(["-q", "simulate", "--scene", "nowhere", "-o", str(out)]) == 1


def test_skip_capture_keeps_the_noise_of_every_capture():
    """A capture skipped and rendered later with its noise is bit for bit the capture at its
    turn, and the captures after it are unchanged."""
    import copy

    pc = sim.VirtualProCam("cubicle", projector_size=(160, 120), camera_size=(256, 192))
    twin = copy.deepcopy(pc)
    a, b = (sim.test_pattern(n, pc.projector_size) for n in ("checker", "dots"))
    skipped = pc.skip_capture()
    after = pc.capture(b)
    assert np.array_equal(pc.capture(a, noise=skipped), twin.capture(a))
    assert np.array_equal(after, twin.capture(b))
