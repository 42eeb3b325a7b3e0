"""Geometric calibration: structured light, kinks, fold, homographies, layout.

Every simulator preset is calibrated once (module fixture, default sizes, camera noise on)
through a wrapper that exposes only ``capture`` — calibration never sees the ground truth —
and is then held against ``sim.truth``. The property tests (lens distortion, projector
response, bad conditions, CLI) use a half-size set-up: what they check does not depend on size.
"""

from __future__ import annotations

import functools
import math
import time

import checkerboard
import cv2
import numpy as np
import pytest
from helpers import Blind, CountingProCam

import rtdefocus as rd
from rtdefocus import sim
from rtdefocus.calib.capture import Capturer
from rtdefocus.calib.geometry.fold import find_kink
from rtdefocus.calib.geometry.homography import line_crossings
from rtdefocus.calib.geometry.stage import calibrate_geometry
from rtdefocus.calib.geometry.structured_light import LinePatterns, find_ridge_points
from rtdefocus.errors import CalibrationError, InputError
from rtdefocus.graycode import decode_gray
from rtdefocus.planar import apply_h, largest_inscribed_rect

# The three-plane rooms are held against the truth at 320x240 in test_geometry_planes.py; walls
# that are planes only nearly (and a far wall through a gap) in test_geometry_walls.py; the
# clipping camera is the cubicle's geometry.
PRESETS = [p for p in sim.PRESETS if p not in ("u_cubicle", "corner_ceiling", "bowed", "sagging",
                                                "gap", "clipping")]
SMALL = {"projector_size": (400, 300), "camera_size": (640, 480)}


_RUNS: dict = {}


@pytest.fixture(scope="module")
def calibrated():
    """preset -> (VirtualProCam, Calibration, seconds); each preset calibrated once."""
    def get(preset):
        if preset not in _RUNS:
            pc = sim.VirtualProCam(preset)          # default sizes and camera noise
            t0 = time.perf_counter()
            calib = rd.calibrate(Blind(pc), stages=("geometry",))
            _RUNS[preset] = (pc, calib, time.perf_counter() - t0)
        return _RUNS[preset]
    return get


def _frame_segment(line, size):
    """Ends (2, 2) of a line's part inside the projector frame [-0.5, W-0.5] x [-0.5, H-0.5]."""
    w, h = size
    a, b, c = line
    pts = []
    for x in (-0.5, w - 0.5):
        if abs(b) > 1e-12:
            y = -(a * x + c) / b
            if -0.5 <= y <= h - 0.5:
                pts.append((x, y))
    for y in (-0.5, h - 0.5):
        if abs(a) > 1e-12:
            x = -(b * y + c) / a
            if -0.5 <= x <= w - 0.5:
                pts.append((x, y))
    pts = np.array(pts)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    i, j = np.unravel_index(np.argmax(d), d.shape)
    return pts[[i, j]]


# --------------------------------------------------------------------------- structured light
def test_patterns_cover_the_projector_and_stay_under_40_captures():
    pats = LinePatterns((800, 600))
    seq = pats.sequence()
    assert len(seq) == pats.count() <= 40
    assert len({name for name, _ in seq}) == len(seq)
    for axis, n in (("v", 800), ("h", 600)):
        centres = np.sort([c for p in range(pats.phases) for _, c in pats.lines(axis, p)])
        gaps = np.diff(np.concatenate([[-0.5], centres, [n - 0.5]]))
        # a line every spacing/phases px, none missing, none closer than that to an edge + 1
        assert gaps.max() <= pats.spacing / pats.phases + 1, (axis, gaps.max())
        assert np.allclose(np.diff(centres), pats.spacing / pats.phases)


def test_gray_code_round_trip_names_every_stripe():
    pats = LinePatterns((333, 217), spacing=32)          # odd sizes, partial last stripe
    for axis, n in (("v", 333), ("h", 217)):
        bits = []
        for b in range(pats.n_bits(axis)):
            img = pats.gray_pattern(axis, b)[..., 0]
            bits.append((img[0] if axis == "v" else img[:, 0]) > 127)
        got = decode_gray([bb[None, :] for bb in bits])[0]
        np.testing.assert_array_equal(got, np.arange(n) // 32)


@pytest.mark.parametrize("sigma", [1.5, 4.0, 8.0], ids=["sharp", "blurred", "very-blurred"])
def test_ridge_centres_are_sub_pixel_accurate(sigma):
    rng = np.random.default_rng(7)
    h, w = 40, 400
    centres = 40.0 + 64.0 * np.arange(5) + rng.uniform(0, 1, 5)     # known sub-pixel truth
    xs = np.arange(w)[None, :]
    prof = sum(0.6 * np.exp(-0.5 * ((xs - c) / sigma) ** 2) for c in centres)
    img = np.repeat(prof, h, axis=0) + rng.normal(0, 0.01, (h, w))
    rows, cols, _ = find_ridge_points(img.astype(np.float32), np.ones((h, w), bool), half=20)
    err = np.abs(cols[:, None] - centres[None, :]).min(axis=1)
    assert len(rows) >= 5 * (h - 4)
    assert np.sqrt(np.mean(err ** 2)) < 0.06 and err.max() < 0.3, (err.mean(), err.max())


def test_stage_options_and_pattern_limits():
    from rtdefocus.calib.geometry.stage import OPTIONS, GeometryOptions

    # every field is an option of the stage; an unknown one is refused before any capture
    pc = sim.VirtualProCam("flat", **SMALL)
    cap = Capturer(pc)
    with pytest.raises(InputError, match=r"unknown GeometryOptions options \['spacing'\]"):
        calibrate_geometry(None, cap, spacing=8)
    with pytest.raises(InputError, match="spacing"):
        calibrate_geometry(None, cap, GeometryOptions(line_spacing=8, line_phases=4))
    with pytest.raises(InputError, match="calib=None"):
        calibrate_geometry(sim.oracle_calibration(pc), cap)
    assert cap.total == 0 and "line_spacing" in OPTIONS
    with pytest.raises(InputError, match="spacing"):
        LinePatterns((800, 600), spacing=8, phases=4)
    with pytest.raises(InputError, match="too large"):
        LinePatterns((80, 60), spacing=48)


def test_every_stage_has_one_contract():
    """calibrate_X(calib, capture, options=None, **overrides): bad input refused before any
    capture, with the stage's valid options or what to pass instead."""
    import inspect

    from rtdefocus.calib import STAGE_TABLE
    from rtdefocus.errors import InputTypeError

    pc = sim.VirtualProCam("flat", **SMALL)
    cap, calib = Capturer(pc), sim.oracle_calibration(pc)
    for name, st in STAGE_TABLE.items():
        assert list(inspect.signature(st.run).parameters) == \
            ["calib", "capture", "options", "overrides"], name
        so_far = None if name == "geometry" else calib
        with pytest.raises(InputError, match=rf"unknown {st.options.__name__} options \['nope'\]"):
            st.run(so_far, cap, nope=1)
        with pytest.raises(InputTypeError, match="capture must be a Capturer"):
            st.run(so_far, pc)
    with pytest.raises(InputTypeError, match="run the geometry stage first"):
        STAGE_TABLE["psf"].run(None, cap)
    assert cap.total == 0


# --------------------------------------------------------------------------- kinks
def test_kink_found_at_a_sharp_bend_and_not_on_a_smooth_one():
    rng = np.random.default_rng(3)
    t = np.arange(100, 900)
    # two straight pieces meeting at t = 530 with a 3° change of direction
    s = 200 + 0.02 * t + np.tan(math.radians(3)) * np.maximum(0, t - 530)
    k = find_kink(t, s + rng.normal(0, 0.08, t.size))
    assert k is not None and abs(k.point_cam_xy[0] - 530) < 2 and abs(k.angle_deg - 3) < 0.2
    # a smooth bend with a larger sagitta (6 px over the line, as lens distortion makes)
    u = (t - 500) / 400
    bent = 200 + 0.02 * t + 6 * u ** 2 - 1.5 * u ** 3
    assert find_kink(t, bent + rng.normal(0, 0.08, t.size)) is None
    # a gentle bend below the angle threshold is not a kink either
    soft = 200 + np.tan(math.radians(0.4)) * np.maximum(0, t - 530)
    assert find_kink(t, soft + rng.normal(0, 0.05, t.size)) is None


# --------------------------------------------------------------------------- accuracy per preset
@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_checkerboard_through_the_calibrated_warp_is_where_the_rect_says(calibrated, preset):
    """The calibrated geometry end to end: a checkerboard through ``warp`` (the calibration's
    homographies, fold and display rect), seen by the camera with ``sharp=True``, has its inner
    corners within 1.5x their measured RMS distance of where ``display_rect`` puts them, and
    each row and column of corners straight across the fold (its line-fit residual within 1.5x
    the measured)."""
    rms, bend = checker_figures(*calibrated(preset)[:2])
    m_rms, m_bend = MEASURED_CHECKER[preset]
    assert rms <= 1.5 * m_rms, f"{preset}: corners {rms:.3f} px RMS from the rect (measured {m_rms})"
    assert bend <= 1.5 * m_bend, f"{preset}: a row/column of corners bends by {bend:.3f} px RMS " \
                                 f"(measured {m_bend})"


def checker_figures(pc, calib) -> tuple[float, float]:
    """(RMS of the checkerboard's inner corners from where the display rect puts them, the
    largest line-fit residual of a row or column of corners), camera px."""
    err, grid = checkerboard.through_warp(pc, calib)
    bends = [np.linalg.svd(line - line.mean(axis=0), compute_uv=False)[-1] / np.sqrt(len(line))
             for line in list(grid) + list(grid.transpose(1, 0, 2))]
    return float(np.sqrt(np.mean(err ** 2))), float(max(bends))


# Measured by `tools/measure_gains.py --sections geometry` (default sizes, noise on; camera px):
# checkerboard (RMS, largest bend); fold error (projector px) and held-out RMS (camera px).
MEASURED_CHECKER = {"cubicle": (0.0683, 0.0661), "pillar": (0.0628, 0.0485),
                    "flat": (0.0632, 0.0513), "tilted": (0.0807, 0.0639),
                    "offcenter": (0.0689, 0.0793), "fabric": (0.0697, 0.0602)}
MEASURED_GEOMETRY = {"cubicle": (0.0300, 0.0153), "pillar": (0.0210, 0.0151),
                     "flat": (None, 0.0146), "tilted": (0.0312, 0.0159),
                     "offcenter": (0.1890, 0.0181), "fabric": (0.0380, 0.0247)}


def truth_figures(pc, calib) -> tuple[float | None, float]:
    """(fold error: the largest distance, projector px, of the calibrated fold from the true
    one along its part inside the frame, None without a fold; held-out RMS: 4000 random
    projector points, 8 px or more from the fold, through the calibrated against the true
    homography of their plane, camera px)."""
    truth = pc.truth
    wp, hp = pc.projector_size
    rng = np.random.default_rng(11)
    pts = np.stack([rng.uniform(-0.5, wp - 0.5, 4000), rng.uniform(-0.5, hp - 0.5, 4000)], axis=1)
    fold_err = None
    if truth.fold_proj is not None:
        seg = _frame_segment(truth.fold_proj, pc.projector_size)
        fold_err = float(np.abs(seg @ calib.fold_proj[:2] + calib.fold_proj[2]).max())
        pts = pts[np.abs(pts @ truth.fold_proj[:2] + truth.fold_proj[2]) > 8]
    plane = truth.plane_map[np.clip(np.rint(pts[:, 1]), 0, hp - 1).astype(int),
                            np.clip(np.rint(pts[:, 0]), 0, wp - 1).astype(int)]
    err = np.empty(len(pts))
    for k in range(truth.n_planes):
        sel = plane == k
        err[sel] = np.linalg.norm(apply_h(calib.H_cam_from_proj[k], pts[sel])
                                  - apply_h(truth.H_cam_from_proj[k], pts[sel]), axis=1)
    return fold_err, float(np.sqrt(np.mean(err ** 2)))


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_geometry_matches_the_truth(calibrated, preset):
    pc, calib, seconds = calibrated(preset)
    truth = pc.truth
    g = calib.meta["geometry"]
    assert calib.n_planes == truth.n_planes, g
    assert g["captures"] == calib.meta["captures"]["geometry"] == LinePatterns(pc.projector_size).count()
    wp, hp = pc.projector_size
    rng = np.random.default_rng(11)
    pts = np.stack([rng.uniform(-0.5, wp - 0.5, 4000), rng.uniform(-0.5, hp - 0.5, 4000)], axis=1)
    if truth.fold_proj is not None:
        fold_err = truth_figures(pc, calib)[0]
        m_fold = MEASURED_GEOMETRY[preset][0]
        assert fold_err <= 1.5 * m_fold, f"{preset}: fold off by {fold_err:.3f} projector px " \
                                         f"(measured {m_fold})"
        assert abs(math.hypot(*calib.fold_proj[:2]) - 1) < 1e-9
        # held-out points away from the fold, on the plane the truth says
        far = np.abs(pts @ truth.fold_proj[:2] + truth.fold_proj[2]) > 8
        pts = pts[far]
    else:
        fold_err = None
        assert not calib.fold_proj.any() and not calib.fold_cam.any()
    true_plane = truth.plane_map[np.clip(np.rint(pts[:, 1]), 0, hp - 1).astype(int),
                                 np.clip(np.rint(pts[:, 0]), 0, wp - 1).astype(int)]
    est_plane = calib.plane_of(pts[:, 0], pts[:, 1])
    # same numbering as the truth (plane 0 on the negative side of both fold lines)
    assert np.mean(est_plane == true_plane) > 0.999
    err = np.empty(len(pts))
    for k in range(truth.n_planes):
        sel = true_plane == k
        err[sel] = np.linalg.norm(apply_h(calib.H_cam_from_proj[k], pts[sel])
                                  - apply_h(truth.H_cam_from_proj[k], pts[sel]), axis=1)
        # forward and inverse are inverses of each other
        back = apply_h(calib.H_proj_from_cam[k], apply_h(calib.H_cam_from_proj[k], pts[sel]))
        assert np.abs(back - pts[sel]).max() < 1e-6
        if truth.n_planes == 2:
            # plane 0 in the projector is plane 0 in the camera
            cam = apply_h(truth.H_cam_from_proj[k], pts[sel])
            side = cam @ calib.fold_cam[:2] + calib.fold_cam[2]
            assert np.all((side < 0) if k == 0 else (side > 0))
    rms = truth_figures(pc, calib)[1]
    assert abs(rms - float(np.sqrt(np.mean(err ** 2)))) <= 1e-9
    m_rms = MEASURED_GEOMETRY[preset][1]
    assert rms <= 1.5 * m_rms, f"{preset}: held-out reprojection RMS {rms:.3f} camera px " \
                               f"(measured {m_rms})"
    # the lit outline covers what the camera sees lit by the projector frame
    lit = np.zeros(pc.camera_size[::-1], np.uint8)
    cv2.fillPoly(lit, [np.round(calib.lit_polygon_cam * 16).astype(np.int32)], 1, shift=4)
    seen = truth.extra["camera_in_frame"]
    iou = np.logical_and(lit, seen).sum() / np.logical_or(lit, seen).sum()
    assert iou > 0.99, iou
    print(f"\n{preset}: planes {calib.n_planes}, fold error "
          f"{'-' if fold_err is None else f'{fold_err:.3f}'} projector px, held-out RMS "
          f"{rms:.3f} camera px (fit RMS {g['rms_px']}), fold disagreement "
          f"{g['fold_disagreement_px']}, captures {g['captures']}, {seconds:.1f} s")


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["cubicle", "pillar"])
def test_display_rect_lies_in_the_lit_area(calibrated, preset):
    pc, calib, _ = calibrated(preset)
    seen = pc.truth.extra["camera_in_frame"]
    for size in ((1600, 1200), (1920, 1080)):
        x, y, w, h = calib.display_rect(size)
        assert abs(w / h - size[0] / size[1]) <= 1.0 / h + 1e-9
        # inside what the projector really lights (1 px of blur-free tolerance at the edges)
        inner = seen[y + 1:y + h - 1, x + 1:x + w - 1]
        assert inner.all(), f"{size}: {inner.size - inner.sum()} rect pixels unlit"
        assert w * h > 0.4 * seen.sum(), "rectangle implausibly small"


@pytest.mark.slow
def test_diagnostics_picture(calibrated):
    from rtdefocus.calib.geometry.diagnostics import geometry_diagnostics

    _, calib, _ = calibrated("cubicle")
    img = geometry_diagnostics(calib)
    wc, hc = calib.camera_size
    assert img.shape == (hc, wc, 3) and img.dtype == np.uint8
    # the fold is drawn in yellow along the camera fold line
    a, b, c = calib.fold_cam
    y = hc // 2
    x = int(round(-(b * y + c) / a))
    assert (img[y, x - 2:x + 3] == (255, 255, 0)).all(axis=1).any()
    # both planes tinted differently (blue-ish left, orange-ish right)
    left, right = img[y, x - 100].astype(int), img[y, x + 100].astype(int)
    assert left[2] > left[0] and right[0] > right[2]


# --------------------------------------------------------------------------- real-camera effects
def _barrel(k1, size):
    """Remap tables of a barrel-distorted camera (k1 relative to the half diagonal)."""
    wc, hc = size
    cx, cy, r = (wc - 1) / 2, (hc - 1) / 2, math.hypot((wc - 1) / 2, (hc - 1) / 2)
    y, x = np.mgrid[0:hc, 0:wc].astype(np.float32)
    dx, dy = (x - cx) / r, (y - cy) / r
    f = 1 + k1 * (dx * dx + dy * dy)
    return (cx + dx * f * r).astype(np.float32), (cy + dy * f * r).astype(np.float32)


def _max_bend(lines):
    dev = 0.0
    for ln in lines:
        A = np.stack([np.ones(ln.t.size), ln.t.astype(float)], axis=1)
        coef, *_ = np.linalg.lstsq(A, ln.s, rcond=None)
        dev = max(dev, float(np.abs(ln.s - A @ coef).max()))
    return dev


def test_lens_distortion_is_not_a_kink():
    mx, my = _barrel(0.05, SMALL["camera_size"])

    def distort(i, p, f):
        return cv2.remap(f, mx, my, cv2.INTER_LINEAR)

    # undistort=False: the kink finder itself must not take the lens's bend for a fold (with
    # the lens taken out, as by default, the lines it sees are straight again).
    flat = calibrate_geometry(None, Capturer(Blind(sim.VirtualProCam("flat", **SMALL), distort)),
                              undistort=False)
    bend = _max_bend(flat.geometry_detail.detection.lines)
    assert bend > 2.0, f"the distortion should bend the lines visibly; max bend {bend:.2f} px"
    assert flat.n_planes == 1 and flat.meta["geometry"]["kinks"] == 0
    # and the same camera still finds the real fold of a corner
    corner = calibrate_geometry(None, Capturer(Blind(sim.VirtualProCam("cubicle", **SMALL), distort)),
                                undistort=False)
    assert corner.n_planes == 2 and corner.meta["geometry"]["fold_kinks"] >= 10


@pytest.mark.slow
@pytest.mark.parametrize("kw", [
    {"projector_gamma": 2.2, "ambient": 0.15, "exposure": 0.6},
    {"projector_gamma": 2.2, "ambient": 0.08, "exposure": 1.4, "camera_gamma": 2.2},
], ids=["gamma-ambient-darker", "gamma-ambient-brighter-camera-gamma"])
def test_response_ambient_and_exposure_do_not_move_the_lines(kw):
    def crossings(**k):
        c = calibrate_geometry(None, Capturer(Blind(sim.VirtualProCam("cubicle", **SMALL, **k))))
        proj, cam, _ = line_crossings(c.geometry_detail.detection.lines, SMALL["camera_size"])
        return {tuple(p): q for p, q in zip(proj, cam, strict=True)}

    ref = _RUNS.setdefault("small-linear", crossings())
    got = crossings(**kw)
    common = sorted(set(ref) & set(got))
    assert len(common) > 0.95 * len(ref)
    d = np.array([np.linalg.norm(ref[k] - got[k]) for k in common])
    assert d.max() < 0.2, f"crossings moved by up to {d.max():.3f} px (mean {d.mean():.3f})"


# --------------------------------------------------------------------------- bad conditions
def _shift(frame, dx, dy):
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(frame, m, frame.shape[1::-1])


def test_no_projector_light_is_reported():
    pc = sim.VirtualProCam("cubicle", **SMALL)
    dark = pc.capture(np.zeros((300, 400, 3), np.uint8))
    with pytest.raises(CalibrationError, match="sees no projector light") as info:
        calibrate_geometry(None, Capturer(Blind(pc, lambda i, p, f: dark)))
    assert "camera looks at the projected area" in str(info.value)


def test_lines_that_cannot_be_found_are_reported():
    # a badly out-of-focus camera: the white and black frames are fine, the lines are mush
    blind = Blind(sim.VirtualProCam("cubicle", **SMALL), lambda i, p, f: cv2.GaussianBlur(f, (0, 0), 25))
    with pytest.raises(CalibrationError, match=r"only \d+ of the \d+ projected .* lines") as info:
        calibrate_geometry(None, Capturer(blind))
    assert "focus" in str(info.value)


def test_setup_moved_half_way_is_reported():
    n = LinePatterns(SMALL["projector_size"]).count()
    blind = Blind(sim.VirtualProCam("cubicle", **SMALL),
                  lambda i, p, f: _shift(f, 5, 3) if i >= n // 2 else f)
    with pytest.raises(CalibrationError, match="moved during calibration"):
        calibrate_geometry(None, Capturer(blind))


@pytest.mark.slow
def test_setup_knocked_and_back_is_reported():
    # captures 4..7 (two phases of each line family) taken 6 px off: the white frames agree,
    # the correspondences do not
    blind = Blind(sim.VirtualProCam("cubicle", **SMALL),
                  lambda i, p, f: _shift(f, 6, 4) if 4 <= i < 8 else f)
    with pytest.raises(CalibrationError, match="inconsistent"):
        calibrate_geometry(None, Capturer(blind))


# --------------------------------------------------------------------------- layout
@pytest.mark.slow
@pytest.mark.parametrize("aspect", [4 / 3, 16 / 9, 1.0, 3.0], ids=["4:3", "16:9", "1:1", "3:1"])
@pytest.mark.parametrize("preset", ["cubicle", "pillar", "tilted"])
def test_largest_inscribed_rect_properties(calibrated, preset, aspect):
    _, calib, _ = calibrated(preset)
    poly = calib.lit_polygon_cam.astype(np.float32)
    wc, hc = calib.camera_size
    x, y, w, h = largest_inscribed_rect(calib.lit_polygon_cam, aspect, calib.camera_size)
    assert all(isinstance(v, int) for v in (x, y, w, h))
    assert abs(w / h - aspect) <= 1.0 / h + 1e-9

    def inside(x0, y0, x1, y1, n=200):
        t = np.linspace(0, 1, n)
        edge = np.concatenate([np.stack([x0 + (x1 - x0) * t, np.full(n, y0)], 1),
                               np.stack([x0 + (x1 - x0) * t, np.full(n, y1)], 1),
                               np.stack([np.full(n, x0), y0 + (y1 - y0) * t], 1),
                               np.stack([np.full(n, x1), y0 + (y1 - y0) * t], 1)])
        in_poly = all(cv2.pointPolygonTest(poly, (float(a), float(b)), False) >= 0 for a, b in edge)
        in_cam = x0 >= -0.5 and y0 >= -0.5 and x1 <= wc - 0.5 and y1 <= hc - 0.5
        return in_poly and in_cam

    # the continuous rectangle [x-0.5, x+w-0.5] x [y-0.5, y+h-0.5] is inside
    assert inside(x - 0.5, y - 0.5, x + w - 0.5, y + h - 0.5)
    # and maximal: grown by 1 % about its centre it is not
    cx, cy, gw, gh = x - 0.5 + w / 2, y - 0.5 + h / 2, 1.01 * w / 2, 1.01 * h / 2
    assert not inside(cx - gw, cy - gh, cx + gw, cy + gh)
    # a margin shrinks it about the same centre
    xm, ym, wm, hm = largest_inscribed_rect(calib.lit_polygon_cam, aspect, calib.camera_size, 0.1)
    assert abs(wm - 0.9 * w) <= 2 and abs((xm + wm / 2) - (x + w / 2)) <= 1


def test_largest_inscribed_rect_known_answer_and_errors():
    # the polygon is exactly the pixel area of columns 10..409 and rows 20..319 (400x300)
    poly = np.array([[9.5, 19.5], [409.5, 19.5], [409.5, 319.5], [9.5, 319.5]])
    assert largest_inscribed_rect(poly, 4 / 3, (640, 480)) == (10, 20, 400, 300)
    # a wide aspect is limited by the width, the camera frame clips the polygon
    x, y, w, h = largest_inscribed_rect(poly, 4.0, (640, 480))
    assert (x, w) == (10, 400) and h == 100
    big = np.array([[-100.0, -100.0], [1000, -100], [1000, 1000], [-100, 1000]])
    assert largest_inscribed_rect(big, 4 / 3, (640, 480)) == (0, 0, 640, 480)
    with pytest.raises(InputError, match="aspect"):
        largest_inscribed_rect(poly, 0.0, (640, 480))
    with pytest.raises(InputError, match="no camera pixel"):
        largest_inscribed_rect(poly + 5000, 1.0, (640, 480))


# --------------------------------------------------------------------------- CLI
def test_cli_calibrate_writes_file_and_picture(tmp_path, monkeypatch, capsys):
    from rtdefocus import cli

    monkeypatch.setattr(sim, "VirtualProCam", functools.partial(sim.VirtualProCam, **SMALL))
    out = tmp_path / "setup.npz"
    rc = cli.main(["-q", "calibrate", "--sim", "pillar", "-o", str(out), "--stages", "geometry",
                   "--seed", "2", "--noise", "0.01"])
    text = capsys.readouterr().out
    assert rc == 0, text
    calib = rd.Calibration.load(out)
    assert calib.n_planes == 2 and calib.meta["geometry"]["captures"] > 0
    pic = cv2.imread(str(tmp_path / "setup_geometry.png"))
    assert pic is not None and pic.shape[:2] == (480, 640)
    assert "2 plane(s)" in text and "reprojection RMS" in text and "setup_geometry.png" in text
    # a bad stage list is a usage error (argparse exits with 2)
    with pytest.raises(SystemExit) as info:
        cli.main(["calibrate", "--sim", "pillar", "-o", str(out), "--stages", "psf"])
    assert info.value.code == 2


def test_misspelt_option_is_reported_before_any_capture():
    pc = CountingProCam((400, 300), (640, 480))
    with pytest.raises(InputError, match="unknown calibration options \\['layuot'\\]"):
        rd.calibrate(pc, layuot="paper")
    assert pc.n == 0
