"""Everything after the geometry stage with any number of planes: kernel sampling and the
kernel field (calib/psf), radiometry's and the Wiener path's per-plane steps, the near-folds
band of the scores and the diagnostics pictures."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy import ndimage

import rtdefocus as rd
from rtdefocus.calib.file import Calibration
from rtdefocus.calib.psf import RadiusModel, fold_code, fold_segments, pack_patterns, plan_samples
from rtdefocus.calib.psf.dots import dot_geometry, dot_sizes
from rtdefocus.calib.psf.kernel_field import interpolation_field
from rtdefocus.planar import apply_h, fold_segments_cam, projector_frame

SIZE = (320, 240)


def _synthetic(n_planes: int, folds, fold_planes) -> Calibration:
    """A geometry-only calibration: the camera sees the projector frame scaled by 1.5 on every
    plane (the sampling only reads the layout, the fold lines and the frame)."""
    S = np.diag([1.5, 1.5, 1.0])
    folds = np.asarray(folds, np.float64).reshape(-1, 3)
    folds = folds / np.hypot(folds[:, 0], folds[:, 1])[:, None]
    folds_cam = folds @ np.linalg.inv(S)
    folds_cam /= np.hypot(folds_cam[:, 0], folds_cam[:, 1])[:, None]
    wp, hp = SIZE
    return Calibration(
        projector_size=SIZE, camera_size=(int(1.5 * wp), int(1.5 * hp)),
        H_cam_from_proj=np.stack([S] * n_planes), H_proj_from_cam=np.stack([np.linalg.inv(S)] * n_planes),
        folds_proj=folds, folds_cam=folds_cam, fold_planes=np.asarray(fold_planes, np.int32),
        lit_polygon_cam=1.5 * projector_frame(SIZE))


@functools.cache
def case(name: str) -> Calibration:
    if name == "u":                   # three walls, folds at a quarter and three quarters
        return _synthetic(3, [[1, 0, -79.5], [1, 0, -239.5]], [[0, 1], [1, 2]])
    if name == "vertex":              # two walls and a ceiling meeting inside the frame
        v = np.array([160.0, 90.0])
        probes = {0: (40.0, 200.0), 1: (160.0, 20.0), 2: (280.0, 200.0)}   # left, ceiling, right
        lines, pairs = [], []
        for end, (p, q) in (((0.0, 20.0), (0, 1)), ((160.0, 240.0), (0, 2)), ((320.0, 10.0), (1, 2))):
            d = np.subtract(end, v)
            n = np.array([d[1], -d[0]]) / np.hypot(*d)
            line = np.array([n[0], n[1], -n @ v])
            lines.append(line)
            pairs.append([p, q] if line[:2] @ probes[p] + line[2] < 0 else [q, p])
        return _synthetic(3, lines, pairs)
    if name == "quadrants":           # four planes: a cross of two folds (two fold lines each)
        return _synthetic(4, [[1, 0, -159.5], [1, 0, -159.5], [0, 1, -119.5], [0, 1, -119.5]],
                          [[0, 1], [2, 3], [0, 2], [1, 3]])
    raise KeyError(name)


def _affine_model(calib: Calibration, coefs) -> RadiusModel:
    m = RadiusModel(points=np.zeros((0, 2)), radii=np.zeros(0))
    for p, c in enumerate(coefs):
        c = np.asarray(c, np.float64)
        m.regions[p] = lambda xy, c=c: xy @ c[:2] + c[2]
        m.kind[p], m.coef[p] = "affine", c
    m.folds = {fold_code(j): (int(a), int(b)) for j, (a, b) in enumerate(calib.layout.fold_planes)}
    return m


MODELS = {"u": [[-0.004, 0.0, 3.5], [0.0, 0.002, 3.0], [0.004, 0.0, 2.5]],
          "vertex": [[0.003, 0.004, 2.0], [0.0, -0.006, 3.5], [-0.004, 0.003, 3.0]],
          "quadrants": [[0.0, 0.0, 2.0], [0.004, 0.0, 2.0], [0.0, 0.004, 2.5], [0.003, 0.003, 2.0]]}
CASES = tuple(MODELS)


def _seg_dist(pts: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of points to a segment, and their position t (px) along it."""
    a, b = seg
    ab = b - a
    L = float(np.hypot(*ab))
    t = np.clip((pts - a) @ ab / L, 0, L)
    return np.hypot(*(pts - a - t[:, None] * ab / L).T), t


# ----------------------------------------------------------------------------- layout
@pytest.mark.parametrize("name", CASES)
def test_synthetic_layouts_are_valid(name):
    cal = case(name)
    lab = cal.plane_map()
    assert sorted(np.unique(lab).tolist()) == list(range(cal.n_planes))
    # each fold segment the sampling uses lies on its fold, inside the inset frame, and has
    # its two planes on either side of it
    segs = fold_segments(cal, 2.0)
    assert len(segs) == cal.layout.n_folds
    for j, seg in enumerate(segs):
        if seg is None:
            continue
        a, b, c = cal.layout.folds[j]
        np.testing.assert_allclose(seg @ [a, b] + c, 0.0, atol=1e-6)
        assert (seg >= 2.0 - 1e-6).all() and (seg <= np.array(SIZE) - 3.0 + 1e-6).all()
        mid = seg.mean(axis=0)
        neg, pos = cal.layout.fold_planes[j]
        off = 3.0 * np.array([a, b])
        ends = np.stack([mid - off, mid + off])
        assert cal.plane_of(ends[:, 0], ends[:, 1]).tolist() == [neg, pos]


@pytest.mark.parametrize("name", CASES)
def test_dots_on_both_sides_of_every_fold(name):
    """Default layout: every fold that separates two planes in the frame has samples on each
    of its sides, along its whole length, each farther from every fold than its blur (its light
    stays on its plane), and every sample lies on the plane it is filed under."""
    cal = case(name)
    model = _affine_model(cal, MODELS[name])
    plan = plan_samples(cal, model, "default", max_spacing=80.0)
    pts = plan.points.astype(np.float64)
    assert np.array_equal(plan.planes, cal.plane_of(pts[:, 0], pts[:, 1]))
    segs = fold_segments(cal, 2.0)
    assert sum(s is not None for s in segs) >= 2
    for j, seg in enumerate(segs):
        if seg is None:
            continue
        length = float(np.hypot(*(seg[1] - seg[0])))
        for p in cal.layout.fold_planes[j]:
            mine = plan.planes == p
            d, t = _seg_dist(pts[mine], seg)
            side = (plan.kinds[mine] == "fold-side") & (d < 15)
            assert side.sum() >= 2, f"fold {j}, plane {p}: {side.sum()} fold-side samples"
            # with the plane's corners, nothing along the fold is far from a sample of the plane
            near = d < 15
            ts = np.sort(np.concatenate([[0.0, length], t[near]]))
            assert np.diff(ts).max() <= 80.0 + 1, f"fold {j}, plane {p}: gap {np.diff(ts).max():.0f}"
    # fold-side samples: farther than the modelled blur from every fold of their plane
    for i in np.flatnonzero(plan.kinds == "fold-side"):
        p = int(plan.planes[i])
        r = model(pts[i][None], p)[0]
        for line, s in cal.layout.bounding(p):
            assert s * (line[:2] @ pts[i] + line[2]) > r, (name, pts[i], p, r)


@pytest.mark.slow
@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("layout", ["default", "paper", "dense"])
def test_blend_never_crosses_a_fold(name, layout):
    """Each pixel blends <= 4 kernels (weights sum to 1) of its own plane or of a fold of its
    plane (paper layout), never another plane's."""
    cal = case(name)
    plan = plan_samples(cal, _affine_model(cal, MODELS[name]), layout, dense_spacing=40)
    idx, wts = interpolation_field(cal, plan)
    np.testing.assert_allclose(wts.sum(axis=2), 1.0, atol=1e-5)
    pm = cal.plane_map()
    ok = np.zeros((cal.n_planes, len(plan)), bool)       # may plane p use sample i?
    for p in range(cal.n_planes):
        codes = [fold_code(j) for j in np.flatnonzero(cal.layout.signs[p])]
        ok[p] = (plan.planes == p) | np.isin(plan.planes, codes)
    bad = (wts > 0) & ~ok[pm[..., None], idx]
    assert not bad.any(), f"{bad.any(axis=2).sum()} pixels blend a kernel of another plane"
    if layout == "paper":       # the two ends of every fold, shared by its two planes
        n_seg = sum(s is not None for s in fold_segments(cal, 2.0))
        assert (plan.planes < 0).sum() == 2 * n_seg
        assert all((plan.planes == fold_code(j)).sum() in (0, 2) for j in range(len(cal.folds_proj)))


def test_corners_at_a_vertex_share_one_pattern():
    """Where three planes meet inside the frame their corners there are pushed apart into
    their planes, so the whole default layout fits in one dot pattern."""
    cal = case("vertex")
    model = _affine_model(cal, MODELS["vertex"])
    plan = plan_samples(cal, model, "default")
    sup, win = dot_geometry(plan.radius, dot_sizes(plan.radius))
    assert len(pack_patterns(plan.points, sup, win)) == 1
    corners = plan.points[plan.kinds == "corner"].astype(np.float64)
    v = np.array([160.0, 90.0])
    near_v = np.hypot(*(corners - v).T) < 60
    assert len(np.unique(plan.planes[plan.kinds == "corner"][near_v])) == 3, \
        "each plane keeps a corner near the vertex"


def test_fold_code_round_trip():
    assert fold_code(0) == rd.calib.psf.FOLD
    assert [fold_code(fold_code(j)) for j in range(5)] == list(range(5))


def _pilot_on(cal: Calibration, radius_at):
    """The pilot on a synthetic layout: each dot seen through the frame's 1.5x scale, blurred by
    a Gaussian of disc-equivalent radius ``radius_at(x)`` (E[u² + v²] = r² / 2 = 2 sigma²)."""
    import cv2

    from rtdefocus.calib.psf import pilot_radius

    S = cal.H_cam_from_proj[0]

    def capture(pattern):
        out = np.zeros(pattern.shape[:2], np.float32)
        lab, n = ndimage.label(pattern[..., 1] > 0)
        for k, sl in enumerate(ndimage.find_objects(lab)):
            x = (sl[1].start + sl[1].stop - 1) / 2
            one = (lab == k + 1).astype(np.float32)
            out += cv2.GaussianBlur(one, (0, 0), radius_at(x) / 2)
        cam = cv2.warpPerspective(out, S, cal.camera_size, flags=cv2.INTER_LINEAR)
        return np.repeat(np.clip(np.rint(255 * 0.9 * cam / out.max()), 0, 255)
                         .astype(np.uint8)[..., None], 3, axis=2)

    return pilot_radius(cal, capture)


def test_pilot_gives_every_plane_a_blur_gradient():
    """A side wall a quarter of the frame wide gets one column of the default pilot grid; the
    grid is made finer until every plane has MIN_PILOT_DOTS dots, so each plane's radius is fitted
    (not a constant guess) and follows the true gradient. Two half-frame walls keep the grid."""
    from rtdefocus.calib.psf.pilot import MIN_PILOT_DOTS

    def radius_at(x):              # blur grows towards the middle wall, 1.5 .. 3.5 px
        return 1.5 + 2.0 * min(x, 319 - x) / 160

    u = case("u")
    model = _pilot_on(u, radius_at)
    plane = u.plane_of(model.points[:, 0], model.points[:, 1]).astype(int)
    assert np.bincount(plane, minlength=3).min() >= MIN_PILOT_DOTS
    assert "constant" not in model.kind.values(), model.kind
    for p, x in ((0, 20.0), (0, 70.0), (2, 250.0), (2, 300.0)):
        got = float(model(np.array([[x, 120.0]]), p)[0])
        assert abs(got - radius_at(x)) < 0.3, f"plane {p} at x = {x}: {got:.2f} vs {radius_at(x):.2f}"
    two = _synthetic(2, [[1, 0, -159.5]], [[0, 1]])
    xs = np.unique(_pilot_on(two, radius_at).points[:, 0])
    assert np.all(np.diff(xs) == 80), xs      # the default 100 px, capped at a third of 240


def test_kernels_of_a_plane_without_a_gradient_are_not_averaged():
    """iso_average's premise (equal predicted radius, equal kernel) needs a fitted radius: on a
    plane whose pilot is a constant guess each kernel stays its own; elsewhere the planes (and
    fold codes) are the regions."""
    from rtdefocus.calib.psf import iso_regions

    m = RadiusModel(points=np.zeros((0, 2)), radii=np.zeros(0),
                    kind={0: "constant", 1: "affine", 2: "abs-affine"})
    planes = np.array([0, 0, 1, 1, 2, 2, fold_code(0), 0])
    reg = iso_regions(planes, m)
    np.testing.assert_array_equal(reg[2:7], planes[2:7])
    assert len({*reg[[0, 1, 7]].tolist(), *reg[2:7].tolist()}) == 3 + len(set(planes[2:7].tolist()))


# ----------------------------------------------------------------------------- radiometry, Wiener
def test_per_plane_smoothing_and_wiener_are_label_generic():
    from rtdefocus.calib.radiometry.stage import _smooth_per_plane
    from rtdefocus.compensate.wiener import wiener_prefilter

    cal = case("quadrants")
    pm = cal.plane_map()
    img = (1.0 + pm.astype(np.float32))[..., None].repeat(3, axis=2)
    out = _smooth_per_plane(img, pm, np.ones(pm.shape, bool), 4.0)
    np.testing.assert_allclose(out, img, rtol=1e-5)        # nothing bleeds across any fold
    # Wiener: each plane filtered with the mean of its own kernels (a fold sample is ignored)
    k = 7
    psfs = np.zeros((cal.n_planes + 1, k, k), np.float32)
    for p in range(cal.n_planes):
        psfs[p] = 1.0 / k ** 2 if p % 2 else 0.0
        psfs[p, k // 2, k // 2] += 0.0 if p % 2 else 1.0
    psfs[-1] = 1.0 / k ** 2
    planes = np.append(np.arange(cal.n_planes), fold_code(0))
    rng = np.random.default_rng(0)
    target = rng.uniform(0.3, 0.7, (3,) + pm.shape).astype(np.float32)
    out = wiener_prefilter(target, psfs, planes, pm, nsr=0.01)
    delta = pm % 2 == 0                                    # identity kernel: unchanged
    np.testing.assert_allclose(out[:, delta], target[:, delta], atol=1e-4)
    assert np.abs(out[:, ~delta] - target[:, ~delta]).mean() > 0.05


# ----------------------------------------------------------------------------- scores
@functools.cache
def oracle(preset: str) -> Calibration:
    return rd.sim.oracle_calibration(rd.sim.VirtualProCam(preset, projector_size=SIZE,
                                                          camera_size=(480, 360)))


def test_near_folds_band_of_two_planes_is_the_fold_line_band():
    from rtdefocus.study.scores import near_fold_mask, near_folds_mask

    cal = oracle("tilted")
    shape = (360, 480)
    assert np.array_equal(near_folds_mask(cal, shape, 10.0), near_fold_mask(cal.fold_cam, shape, 10.0))
    assert not near_folds_mask(oracle("flat"), shape, 10.0).any()


def test_near_folds_band_follows_every_fold_segment():
    """corner_ceiling: the band covers each fold where it separates its planes and stops at the
    vertex (the line of the walls' fold, extended through the ceiling, is not in it)."""
    from rtdefocus.study.scores import near_folds_mask

    cal = oracle("corner_ceiling")
    shape = (360, 480)
    band = near_folds_mask(cal, shape, 6.0)
    segs = fold_segments_cam(cal.projector_size, cal.H_cam_from_proj, cal.layout)
    assert sum(s is not None for s in segs) == 3
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    pix = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    dmin = np.min([_seg_dist(pix, s)[0] for s in segs if s is not None], axis=0).reshape(shape)
    x, y, w, h = cal.display_rect((4, 3))             # what is scored (past the frame's edge
    shown = np.zeros(shape, bool)                      # the band goes on)
    shown[y:y + h, x:x + w] = True
    assert band[shown & (dmin <= 5.5)].all() and not band[shown & (dmin > 6.5)].any()
    # the walls' fold's line beyond the vertex, on the ceiling, is left out
    j = next(j for j, (a, b) in enumerate(cal.fold_planes) if 1 not in (a, b))
    seg = segs[j]
    up = seg[np.argmin(seg[:, 1])] + np.array([0.0, -30.0])
    up[0] = -(cal.folds_cam[j][1] * up[1] + cal.folds_cam[j][2]) / cal.folds_cam[j][0]
    assert not band[int(round(up[1])), int(round(up[0]))]


# ----------------------------------------------------------------------------- pictures
def test_geometry_picture_tints_each_plane_and_draws_every_fold():
    from rtdefocus.calib.geometry.diagnostics import geometry_diagnostics

    cal = oracle("corner_ceiling")
    img = geometry_diagnostics(cal).astype(int)
    pm = cal.plane_map()
    tints = []
    for p in range(cal.n_planes):
        ys, xs = np.nonzero(pm == p)
        c = np.array([xs.mean(), ys.mean()])
        cx, cy = np.rint(apply_h(cal.H_cam_from_proj[p], c[None])[0]).astype(int)
        tints.append(img[cy, cx])
    for a in range(3):
        for b in range(a + 1, 3):
            assert np.abs(tints[a] - tints[b]).max() > 30, (a, b, tints)
    for seg in fold_segments_cam(cal.projector_size, cal.H_cam_from_proj, cal.layout):
        x, y = np.rint(seg.mean(axis=0)).astype(int)
        assert (img[y - 2:y + 3, x - 2:x + 3] == (255, 255, 0)).all(axis=2).any(), seg


def test_psf_picture_shades_each_plane_and_draws_every_fold():
    from rtdefocus.calib.psf import psf_diagnostics

    cal = oracle("corner_ceiling")
    wp, hp = cal.projector_size
    panel = psf_diagnostics(cal)[:, :wp].astype(int)
    pm = cal.plane_map()
    shade = [np.median(panel[pm == p], axis=0) for p in range(cal.n_planes)]
    assert len({tuple(s) for s in shade}) == 3, shade
    for seg in fold_segments(cal):
        x, y = np.rint(seg.mean(axis=0)).astype(int)
        assert (panel[y - 1:y + 2, x - 1:x + 2] == (0, 160, 255)).all(axis=2).any(), seg


def test_demo_zoom_sits_on_a_fold():
    from rtdefocus.study.demo import _fold_zoom_box

    cal = oracle("u_cubicle")
    rect = cal.display_rect((4, 3))
    ref = np.random.default_rng(0).integers(0, 255, (360, 480, 3), np.uint8)
    rows, cols = _fold_zoom_box(cal, rect, ref, size=48)
    centre = np.array([[(cols.start + cols.stop) / 2, (rows.start + rows.stop) / 2]])
    segs = [s for s in fold_segments_cam(cal.projector_size, cal.H_cam_from_proj, cal.layout)
            if s is not None]
    assert len(segs) == 2
    assert min(_seg_dist(centre, s)[0][0] for s in segs) <= 2.0


# ----------------------------------------------------------------------------- the presets
@functools.cache
def measured(preset: str):
    """The real radiometry and PSF stages (default layout, noise on) on the simulator's true
    geometry of a three-plane room, at the presets' size (the kernels' radii, up to 6 px,
    are what the accuracy criteria are about): ~40 s each."""
    from calib_presets import GAMMA, truth_geometry
    from helpers import Blind

    from rtdefocus.calib.capture import Capturer
    from rtdefocus.calib.psf import calibrate_psf
    from rtdefocus.calib.radiometry.stage import calibrate_radiometry

    procam = rd.sim.VirtualProCam(preset, projector_gamma=GAMMA)
    calib = truth_geometry(procam)
    blind = Blind(procam)
    cap = Capturer(blind)
    calibrate_radiometry(calib, cap)
    calibrate_psf(calib, cap)
    return procam, calib


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["u_cubicle", "corner_ceiling"])
def test_three_plane_rooms_kernel_accuracy(preset):
    """Relative L2 error of kernel_at against the true kernel: median <= 0.20 inside the planes
    and <= 0.30 within NEAR_FOLD px of a fold (of the part that separates two planes); dots on
    both sides of every fold; no pixel blends a kernel of another plane."""
    from calib_presets import NEAR_FOLD, kernel_errors

    procam, cal = measured(preset)
    truth = procam.truth
    assert cal.n_planes == 3 and np.array_equal(cal.plane_map(), truth.plane_map)
    segs = [s for s in fold_segments(cal) if s is not None]
    wp, hp = cal.projector_size
    rng = np.random.default_rng(7)
    xy = np.column_stack([rng.integers(0, wp, 6000), rng.integers(0, hp, 6000)]).astype(np.float64)
    d = np.min([_seg_dist(xy, s)[0] for s in segs], axis=0)
    interior = xy[d > NEAR_FOLD][:300].astype(int)
    near = xy[d <= NEAR_FOLD][:300].astype(int)
    ei, en = kernel_errors(cal, truth, interior), kernel_errors(cal, truth, near)
    msg = f"{preset}: interior median {np.median(ei):.3f}, near folds median {np.median(en):.3f}"
    assert np.median(ei) <= 0.20 and np.median(en) <= 0.30, msg
    # dots on both sides of every fold
    pts = cal.psf_points_proj.astype(np.float64)
    for j, seg in enumerate(fold_segments(cal)):
        if seg is None:
            continue
        for p in cal.layout.fold_planes[j]:
            close = (_seg_dist(pts, seg)[0] < 25) & (cal.psf_plane == p)
            assert close.sum() >= 3, f"fold {j}, plane {p}: {close.sum()} dots along it"
    # the blend stays on each pixel's plane
    side = cal.plane_of(pts[:, 0], pts[:, 1]).astype(int)
    assert np.array_equal(side, cal.psf_plane)
    mixed = ((cal.pix_wts > 0) & (side[cal.pix_idx] != cal.plane_map()[..., None])).any(axis=2)
    assert not mixed.any(), f"{mixed.sum()} pixels blend a kernel of another plane"
