"""Defocus kernels: dot PSFs, sampling layouts and the kernel field F (calib/psf/)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from calib_presets import NEAR_FOLD, PRESETS, calibrated, eval_points, fold_distance, kernel_errors
from helpers import Blind

from rtdefocus.calib.capture import Capturer
from rtdefocus.calib.file import Calibration
from rtdefocus.calib.psf import (
    FOLD,
    RadiusModel,
    calibrate_psf,
    equivalent_radius,
    fold_segment,
    pack_patterns,
    plan_samples,
    psf_diagnostics,
    radius_map,
)
from rtdefocus.errors import InputError

DEFAULT, PAPER, BLIND = ("default", False), ("paper", False), ("default", True)
# Median kernel errors (inside the planes, within NEAR_FOLD px of the fold) per preset and
# layout: `tools/measure_gains.py --sections psf` (deterministic).
MEASURED_KERNELS = {
    ("cubicle", "default"): (0.0800, 0.1196), ("cubicle", "cross_fold"): (0.1969, 0.2008),
    ("tilted", "default"): (0.0823, 0.1124), ("tilted", "cross_fold"): (0.1917, 0.1894),
    ("pillar", "default"): (0.0818, 0.0312), ("pillar", "cross_fold"): (0.2764, 0.4624),
}
# Largest step of the blended kernel between neighbouring pixels (L1), 1.5x the measured
# (`tools/measure_gains.py --sections field`: default 0.075, paper <= 0.02; the same fields
# snapped to their nearest sample step by 0.59 and 1.73).
FIELD_JUMP = {"default": 0.112, "paper": 0.03}


def _errors(preset, key):
    res = calibrated(preset)
    interior, near = eval_points(preset)
    cal = res.variants[key]
    return kernel_errors(cal, res.procam.truth, interior), kernel_errors(cal, res.procam.truth, near)


# ----------------------------------------------------------------------------- accuracy
@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_kernel_accuracy(preset):
    """Relative L2 error of kernel_at against the true kernel (rd.calibrate, noise on), median
    inside the planes and near the fold, within 1.5x of the measured."""
    ei, en = _errors(preset, DEFAULT)
    m_in, m_near = MEASURED_KERNELS[preset, "default"]
    assert np.median(ei) <= 1.5 * m_in, f"inside the planes: median {np.median(ei):.4f} ({m_in})"
    assert np.median(en) <= 1.5 * m_near, \
        f"within {NEAR_FOLD} px of the fold: median {np.median(en):.4f} (measured {m_near})"


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_fold_claim(preset):
    """Near the fold the default layout beats the paper's where the fold is the blurriest
    (concave cubicle, tilted fold); the geometry-blind baseline that blends across the fold is
    clearly worse everywhere (at least 85 % of its measured ratio to the default's error:
    1.68 on the cubicle and the tilted fold, 14.8 on the pillar).

    On the convex pillar the fold is the sharpest place and both per-plane layouts sit at the
    noise floor there: since the dots are normalised by the white frame minus a smoothed
    background, the paper's fold-straddling dots are measured correctly too, and
    near the fold it measured 0.026 against the default's 0.028 (0.037 before). There the claim
    is only that the default is no worse than the paper's layout within that floor."""
    en = {key: np.median(_errors(preset, key)[1]) for key in (DEFAULT, PAPER, BLIND)}
    msg = ", ".join(f"{k[0]}{'+cross' if k[1] else ''} {v:.3f}" for k, v in en.items())
    if preset == "pillar":
        assert en[DEFAULT] <= en[PAPER] + 0.005, msg
    else:
        assert en[DEFAULT] < en[PAPER], msg
    measured = MEASURED_KERNELS[preset, "cross_fold"][1] / MEASURED_KERNELS[preset, "default"][1]
    assert en[BLIND] >= 0.85 * measured * en[DEFAULT], msg


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_capture_budget(preset):
    counts = calibrated(preset).calib.meta["captures"]
    assert counts["radiometry"] + counts["psf"] < 30, counts
    meta = calibrated(preset).calib.meta["psf"]
    # the pilot, the dot patterns, and one white frame at the end (the exposure check)
    assert counts["psf"] == meta["captures"] == 2 + meta["patterns"] * meta["averages"]
    assert np.abs(meta["white_drift"]).max() < 0.005, meta["white_drift"]


# ----------------------------------------------------------------------------- the field
@pytest.mark.slow
@pytest.mark.parametrize("key", [DEFAULT, PAPER, BLIND], ids=["default", "paper", "cross_fold"])
def test_field_blends_within_planes(key):
    """Weights sum to 1 over <= 4 PSFs; per-plane layouts never blend across the fold, the
    cross-fold baseline does."""
    cal = calibrated("tilted").variants[key]
    wp, hp = cal.projector_size
    assert cal.pix_idx.shape == (hp, wp, 4) and cal.pix_wts.shape == (hp, wp, 4)
    np.testing.assert_allclose(cal.pix_wts.sum(axis=2), 1.0, atol=1e-5)
    assert cal.pix_wts.min() >= 0
    pts = cal.psf_points_proj.astype(np.float64)
    side = cal.plane_of(pts[:, 0], pts[:, 1]).astype(int)
    side[cal.psf_plane == FOLD] = -1                   # on the fold: belongs to both
    used = cal.pix_wts > 0
    s = side[cal.pix_idx]
    mixed = (used & (s >= 0) & (s != cal.plane_map()[..., None])).any(axis=2)
    if key[1]:
        assert mixed.sum() > 100, "the cross-fold baseline should blend across the fold"
    else:
        assert not mixed.any(), f"{mixed.sum()} pixels blend a PSF of the other plane"


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_kernel_at_is_a_centred_unit_sum_kernel(preset):
    cal = calibrated(preset).calib
    k_win = cal.psfs.shape[1]
    assert k_win % 2 == 1
    for x, y in eval_points(preset)[1][:20]:
        k = cal.kernel_at(x, y)
        assert k.shape == (k_win, k_win) and k.dtype == np.float32
        assert k.min() >= 0 and k.sum() == pytest.approx(1.0, abs=1e-5)
        vv, uu = np.mgrid[-(k_win // 2):k_win // 2 + 1, -(k_win // 2):k_win // 2 + 1]
        cx, cy = (k * uu).sum(), (k * vv).sum()
        assert np.hypot(cx, cy) < 0.3, f"kernel at ({x}, {y}) off-centre by ({cx:.2f}, {cy:.2f})"


@pytest.mark.slow
def test_save_load_roundtrip(tmp_path):
    cal = calibrated("cubicle").variants[PAPER]     # includes the shared fold samples (-1)
    path = cal.save(tmp_path / "paper.npz")
    back = Calibration.load(path)
    # "lens": the camera's radial distortion (zeros here), "camera": its recovered response
    # (calib.camera_distortion, calib.camera_lut, file format 2)
    assert back.sections() == ["geometry", "radiometry", "psf", "lens", "camera"]
    for x, y in [(0, 0), (399, 300), (401, 12), (799, 599)]:
        np.testing.assert_array_equal(back.kernel_at(x, y), cal.kernel_at(x, y))


# ----------------------------------------------------------------------------- layouts
@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_fold_samples_on_each_side_beyond_the_blur(preset):
    """Default layout: samples near the fold lie on both sides, each farther from the fold
    than the true blur radius there (its light stays on one wall), and cover the fold."""
    res = calibrated(preset)
    cal, truth = res.calib, res.procam.truth
    pts = cal.psf_points_proj.astype(np.float64)
    d = fold_distance(truth, pts)
    near = d < 25
    r_true = np.array([truth.radius_at(x, y) for x, y in pts[near]])
    assert np.all(d[near] > r_true), list(zip(d[near].round(1), r_true.round(2), strict=True))
    seg = fold_segment(cal)
    direction = (seg[1] - seg[0]) / np.linalg.norm(seg[1] - seg[0])
    length = float(np.linalg.norm(seg[1] - seg[0]))
    for p in (0, 1):
        on = near & (cal.psf_plane == p)
        assert on.sum() >= 3, f"plane {p}: only {on.sum()} samples along the fold"
        t = np.sort((pts[on] - seg[0]) @ direction)
        gaps = np.diff(np.concatenate([[0.0], t, [length]]))
        assert gaps.max() <= 160, f"plane {p}: a {gaps.max():.0f} px stretch of fold unsampled"


@pytest.mark.slow
def test_paper_layout_is_four_corners_per_plane_and_two_fold_points():
    res = calibrated("tilted")
    cal = res.variants[PAPER]
    assert (cal.psf_plane == 0).sum() == 4 and (cal.psf_plane == 1).sum() == 4
    fold = cal.psf_points_proj[cal.psf_plane == FOLD].astype(np.float64)
    assert len(fold) == 2
    assert np.all(fold_distance(res.procam.truth, fold) < 1.0)


def _affine_model(coef0, coef1):
    m = RadiusModel(points=np.zeros((0, 2)), radii=np.zeros(0))
    for p, c in enumerate((coef0, coef1)):
        c = np.asarray(c, np.float64)
        m.regions[p] = lambda xy, c=c: xy @ c[:2] + c[2]
        m.kind[p], m.coef[p] = "affine", c
    return m


@pytest.mark.slow
def test_default_layout_adapts_to_the_blur_gradient():
    """Every pixel blends PSFs whose (modelled) radii differ by <= radius_step, a steeper blur
    gradient gets more samples, and one pattern holds them all."""
    import copy

    from rtdefocus.calib.psf.dots import dot_geometry, dot_sizes
    from rtdefocus.calib.psf.kernel_field import interpolation_field

    cal = copy.deepcopy(calibrated("cubicle").calib)
    counts = []
    for slope in (0.004, 0.012):
        # Least blur at the fold (x = 399.5), growing linearly to both sides (a pillar).
        model = _affine_model([-slope, 0.0, 2 + slope * 399.5], [slope, 0.0, 2 - slope * 399.5])
        plan = plan_samples(cal, model, "default", radius_step=0.5)
        counts.append(len(plan))
        r = np.array([model(pt[None].astype(float), int(p))[0]
                      for pt, p in zip(plan.points, plan.planes, strict=True)])
        idx, wts = interpolation_field(cal, plan)
        rr = np.where(wts > 0, r[idx], np.nan)
        spread = np.nanmax(rr, axis=2) - np.nanmin(rr, axis=2)
        assert spread.max() <= 0.5 + 2 * slope, f"slope {slope}: spread {spread.max():.3f}"
        assert len(pack_patterns(plan.points, *dot_geometry(r, dot_sizes(r)))) == 1
    assert counts[1] > 1.5 * counts[0], counts


@pytest.mark.slow
def test_dense_layout_is_a_grid_per_plane():
    cal = calibrated("cubicle").calib
    model = _affine_model([0.0, 0.0, 3.0], [0.0, 0.0, 3.0])
    plan = plan_samples(cal, model, "dense", dense_spacing=50)
    grid = plan.points[plan.kinds == "grid"]
    assert len(grid) > 150
    wp, hp = cal.projector_size
    for axis, size in ((0, wp), (1, hp)):
        # one lattice of step 50 px (the grid is centred in the frame, so not on integers)
        ticks = np.unique(np.round(grid[:, axis], 6))
        np.testing.assert_allclose(np.diff(ticks), 50.0, atol=1e-6, err_msg=f"axis {axis}")
        assert ticks[0] <= 2.0 + 50 and ticks[-1] >= size - 3.0 - 50, (axis, ticks[[0, -1]])
    side = cal.plane_of(grid[:, 0], grid[:, 1])
    assert np.array_equal(side, plan.planes[plan.kinds == "grid"])


@pytest.mark.slow
def test_unknown_layout_raises():
    res = calibrated("cubicle")
    with pytest.raises(InputError, match="layout"):
        calibrate_psf(res.calib, Capturer(Blind(res.procam)), layout="sparse")


# ----------------------------------------------------------------------------- convention
class _AsymmetricProCam:
    """One plane seen through a known homography, blurred by a known *asymmetric* gather
    kernel K: O(x) = sum_u K(u) P(x - u), ``K[5 + v, 5 + u] = K(u, v)``. Light spills over
    the frame edge onto the wall (a margin), as on a real wall."""

    projector_size = (160, 120)
    camera_size = (290, 215)
    PAD = 8
    H = np.array([[1.5, 0.04, 18.0], [0.03, 1.45, 16.0], [0.0, 0.0, 1.0]])

    def __init__(self):
        vv, uu = np.mgrid[-5:6, -5:6]
        k = (uu ** 2 + vv ** 2 <= 2.5 ** 2).astype(float)          # a disc ...
        k += 2.0 * ((uu - 3) ** 2 + (vv + 2) ** 2 <= 1.5 ** 2)     # ... and a lobe at (+3, -2)
        self.K = k / k.sum()
        self.rng = np.random.default_rng(3)

    def capture(self, pattern):
        m = self.PAD
        P = np.pad(pattern.astype(np.float32) / 255.0, ((m, m), (m, m), (0, 0)))
        O = cv2.filter2D(P, -1, np.ascontiguousarray(self.K[::-1, ::-1], np.float32),
                         borderType=cv2.BORDER_CONSTANT)
        shift = np.array([[1.0, 0, -m], [0, 1.0, -m], [0, 0, 1.0]])   # padded -> projector px
        cam = cv2.warpPerspective(O, self.H @ shift, self.camera_size, flags=cv2.INTER_LINEAR)
        cam = 0.8 * cam + 0.03 + self.rng.normal(0, 0.002, cam.shape).astype(np.float32)
        return np.clip(np.rint(cam * 255), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("dot_size", [1, 2])
def test_measured_psf_is_the_dot_image_shifted_not_flipped(dot_size):
    procam = _AsymmetricProCam()
    H = procam.H
    calib = Calibration.with_fold(projector_size=procam.projector_size, camera_size=procam.camera_size,
                        H_cam_from_proj=H[None], H_proj_from_cam=np.linalg.inv(H)[None],
                        fold_proj=np.zeros(3), fold_cam=np.zeros(3),
                        lit_polygon_cam=np.array([[0, 0], [289, 0], [289, 214], [0, 214.0]]))
    calibrate_psf(calib, Capturer(procam), dot_size=dot_size, pilot_spacing=40)
    k = calib.psfs.shape[1]
    pad = (k - 11) // 2
    assert pad >= 0, f"window {k} smaller than the kernel"
    true = np.pad(procam.K, pad)
    tol = 0.10 if dot_size == 1 else 0.25     # a larger dot is deconvolved (ridge)
    for x, y in [(20, 20), (80, 60), (150, 110)]:
        got = calib.kernel_at(x, y)
        err = np.linalg.norm(got - true) / np.linalg.norm(true)
        flipped = np.linalg.norm(got - true[::-1, ::-1]) / np.linalg.norm(true)
        assert err < tol, f"({x}, {y}): error {err:.3f} against K"
        assert flipped > 2 * err and flipped > 0.5, f"flipped {flipped:.3f} vs {err:.3f}"


# ----------------------------------------------------------------------------- diagnostics
@pytest.mark.slow
def test_diagnostics_picture_and_radius_map():
    res = calibrated("pillar")
    cal, truth = res.calib, res.procam.truth
    wp, hp = cal.projector_size
    img = psf_diagnostics(cal, truth.radius_map)
    assert img.dtype == np.uint8 and img.shape == (hp, 4 * wp + 3 * 4, 3)
    assert psf_diagnostics(cal).shape == (hp, 2 * wp + 4, 3)
    # The measured blur size follows the truth: compare like with like, the equivalent
    # radius of the true kernels, at the evaluation points.
    est = radius_map(cal)
    pts = np.vstack(eval_points("pillar"))[::4]
    r_eq_true = np.array([equivalent_radius(truth.kernel_at(x, y)) for x, y in pts])
    err = np.abs(est[pts[:, 1], pts[:, 0]] - r_eq_true)
    assert np.median(err) < 0.3, f"median radius error {np.median(err):.3f} px"
    with pytest.raises(InputError):
        psf_diagnostics(cal, truth.radius_map[:10])


def _field_jump(cal, band: int = 32) -> float:
    """Largest L1 change of the blended kernel ``sum_i w_i psf_i`` between two neighbouring
    projector pixels of the same plane. A seam (one sample swapped for another) steps by the
    difference between two measured kernels; a continuous blend by a small fraction of it.
    The kernels have unit sum, so a pair's step is at most the L1 change of its weights: only
    pairs whose weights change by more than 0.02 need their kernels compared. The weights and
    the blended kernels are built a band of rows at a time (the whole field would not fit in
    memory)."""
    hp, wp, slots = cal.pix_idx.shape
    n = len(cal.psfs)
    psfs = cal.psfs.reshape(n, -1).astype(np.float32)
    plane = cal.plane_map()
    jump = 0.02
    for r0 in range(0, hp, band):
        rows = slice(r0, min(r0 + band + 1, hp))   # one row more: the pairs across the band's end
        idx, wts = cal.pix_idx[rows], cal.pix_wts[rows]
        h = idx.shape[0]
        flat = np.arange(h * wp)[:, None] * n + idx.reshape(-1, slots)
        dense = np.bincount(flat.ravel(), wts.astype(np.float64).ravel(),
                            minlength=h * wp * n).reshape(h, wp, n)
        pl = plane[rows]
        down = (pl[:-1] == pl[1:]) & (np.abs(dense[1:] - dense[:-1]).sum(axis=2) > jump)
        right = (pl[:, :-1] == pl[:, 1:]) & (np.abs(dense[:, 1:] - dense[:, :-1]).sum(axis=2) > jump)
        if rows.stop < hp:
            right = right[:-1]                    # the extra row's own pairs: the next band's
        if not (down.any() or right.any()):
            continue
        w = wts.astype(np.float32)
        kern = sum(w[..., j, None] * psfs[idx[..., j]] for j in range(slots))
        own = kern[:len(right)]
        for sel, step in ((down, kern[1:] - kern[:-1]), (right, own[:, 1:] - own[:, :-1])):
            if sel.any():
                jump = max(jump, float(np.abs(step[sel]).sum(axis=1).max()))
    return jump


@pytest.mark.slow
@pytest.mark.parametrize("key", [DEFAULT, PAPER], ids=["default", "paper"])
def test_kernel_field_has_no_seams(key):
    """Within a plane the kernel field is continuous: one pixel's step changes the blended
    kernel by a little, never swaps one measured kernel for another (no seams)."""
    jump = _field_jump(calibrated("tilted").variants[key])
    assert jump <= FIELD_JUMP[key[0]], f"largest step of the blend between neighbours {jump:.3f}"
