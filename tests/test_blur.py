"""The spatially varying blur F and its adjoint: OpenCL (both kernel shapes) against NumPy."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import TOLERANCES, assert_close

from rtdefocus.errors import InputError
from rtdefocus.reference.blur import (
    blur_adjoint,
    blur_adjoint_filter2d,
    blur_forward,
    blur_forward_filter2d,
    synthetic_field,
)

VARIANTS = pytest.mark.parametrize("variant", ["cpu", "gpu"], ids=["cpu", "gpu"])


def random_field(h, w, k, n, seed, zero_slots=True):
    """Asymmetric random PSFs and random per-pixel indices/weights (some slots unused)."""
    rng = np.random.default_rng(seed)
    psfs = rng.random((n, k, k)).astype(np.float32) ** 3      # lopsided, not symmetric
    psfs /= psfs.sum(axis=(1, 2), keepdims=True)
    idx = rng.integers(0, n, (h, w, 4)).astype(np.int32)
    wts = rng.random((h, w, 4)).astype(np.float32)
    if zero_slots:   # unused slots: weight 0, index 0, as the contract has it
        unused = rng.random((h, w, 4)) < 0.3
        unused[..., 0] = False                            # every pixel keeps a kernel
        wts[unused], idx[unused] = 0.0, 0
    wts /= wts.sum(-1, keepdims=True)
    return psfs, idx, wts


# (name, H, W, k, N or None for the bilinear synthetic field, C)
CASES = [
    ("238x318-k7-random-C3", 238, 318, 7, 7, 3),        # many PSFs per chunk: several groups
    ("238x318-r5-bilinear-C3", 238, 318, 11, None, 3),  # the usual case: one group per chunk
    ("45x61-k11-random-C1", 45, 61, 11, 5, 1),          # not a multiple of chunk or rows
    ("37x50-k19-random-C3", 37, 50, 19, 4, 3),          # radius 9 > 8: wider row segments
    # supports 0 ... 6 of 7 (zero-padded, as the oracle's): the size is cut to the widest and
    # each group loops over its own support only
    ("61x83-k15-mixed-support-C3", 61, 83, 15, 9, 3),
]


def mixed_support(psfs, seed):
    """Each PSF zeroed outside a random centred window (half-widths 0 ... k // 2 - 1),
    renormalised: the zero padding of a field of different blur sizes."""
    rng = np.random.default_rng(seed)
    n, k = psfs.shape[:2]
    r = k // 2
    ring = np.maximum.outer(np.abs(np.arange(k) - r), np.abs(np.arange(k) - r))
    sup = rng.integers(0, r, n)
    sup[0], sup[-1] = 0, r - 1
    out = np.where(ring[None] <= sup[:, None, None], psfs, 0.0).astype(np.float32)
    return out / out.sum(axis=(1, 2), keepdims=True), sup


@pytest.fixture(scope="module", params=CASES, ids=[c[0] for c in CASES])
def case(request):
    name, h, w, k, n, c = request.param
    if n is None:
        psfs, idx, wts = synthetic_field(w, h, k // 2)
    else:
        psfs, idx, wts = random_field(h, w, k, n, seed=k * 1000 + h)
    if "mixed" in name:
        psfs, _ = mixed_support(psfs, seed=h)
    rng = np.random.default_rng(h + w)
    img = rng.random((c, h, w)).astype(np.float32)
    return {"psfs": psfs, "idx": idx, "wts": wts, "img": img,
            "fwd": blur_forward(img, psfs, idx, wts, np.float64),
            "adj": blur_adjoint(img, psfs, idx, wts, np.float64)}


_BLURS: dict = {}


def make_blur(runtime, psfs, idx, wts, channels, variant):
    from rtdefocus.cl.blur import ClBlur
    return ClBlur(runtime, psfs, idx, wts, channels=channels, variant=variant)


def cached_blur(runtime, case, variant):
    key = (id(case), variant)
    if key not in _BLURS:
        _BLURS[key] = make_blur(runtime, case["psfs"], case["idx"], case["wts"],
                                case["img"].shape[0], variant)
    return _BLURS[key]


@pytest.mark.slow
@VARIANTS
def test_forward_matches_reference(cl_runtime, case, variant):
    blur = cached_blur(cl_runtime, case, variant)
    assert blur.variant == variant
    assert_close(blur.forward_host(case["img"]), case["fwd"], TOLERANCES["float32"], "forward")


@pytest.mark.slow
@VARIANTS
def test_adjoint_matches_reference(cl_runtime, case, variant):
    blur = cached_blur(cl_runtime, case, variant)
    assert_close(blur.adjoint_host(case["img"]), case["adj"], TOLERANCES["float32"], "adjoint")


def _adjoint_gap(fx, y, x, fty):
    """|<F x, y> - <x, F^T y>| relative to the Cauchy-Schwarz scale ||F x|| ||y||."""
    lhs = float(np.sum(np.asarray(fx, np.float64) * y))
    rhs = float(np.sum(np.asarray(fty, np.float64) * x))
    return abs(lhs - rhs) / (np.linalg.norm(fx) * np.linalg.norm(y))


def _border_and_fold_masks(h, w, r):
    """Random data everywhere, and random data only within reach of the borders and the fold
    (the column w // 2 where the synthetic field's bands meet), where a wrong halo would show."""
    band = np.zeros((h, w), bool)
    band[:2 * r], band[-2 * r:], band[:, :2 * r], band[:, -2 * r:] = True, True, True, True
    band[:, w // 2 - 2 * r:w // 2 + 2 * r] = True
    return [np.ones((h, w), bool), band]


@pytest.mark.parametrize("field", ["random", "bilinear"])
def test_adjoint_identity_reference_float64(field):
    h, w, k = 41, 53, 7
    psfs, idx, wts = (random_field(h, w, k, 6, seed=3) if field == "random"
                      else synthetic_field(w, h, k // 2))
    rng = np.random.default_rng(7)
    for mask in _border_and_fold_masks(h, w, k // 2):
        x = rng.standard_normal((3, h, w)) * mask
        y = rng.standard_normal((3, h, w)) * mask
        gap = _adjoint_gap(blur_forward(x, psfs, idx, wts, np.float64), y,
                           x, blur_adjoint(y, psfs, idx, wts, np.float64))
        assert gap < 1e-12, f"float64 reference is not an exact adjoint pair: gap {gap:.3g}"


@VARIANTS
def test_adjoint_identity_on_device(cl_runtime, variant):
    h, w, k = 97, 131, 11
    psfs, idx, wts = synthetic_field(w, h, k // 2)
    blur = make_blur(cl_runtime, psfs, idx, wts, 3, variant)
    rng = np.random.default_rng(11)
    for mask in _border_and_fold_masks(h, w, k // 2):
        x = (rng.standard_normal((3, h, w)) * mask).astype(np.float32)
        y = (rng.standard_normal((3, h, w)) * mask).astype(np.float32)
        gap = _adjoint_gap(blur.forward_host(x), y, x, blur.adjoint_host(y))
        assert gap <= TOLERANCES["adjoint_identity"], f"<Fx,y> != <x,F^T y>: gap {gap:.3g}"


def test_filter2d_form_equals_gather_form():
    h, w, k = 47, 66, 9
    psfs, idx, wts = random_field(h, w, k, 5, seed=5)
    img = np.random.default_rng(5).random((3, h, w)).astype(np.float32)
    assert_close(blur_forward_filter2d(img, psfs, idx, wts),
                 blur_forward(img, psfs, idx, wts, np.float64), 1e-5, "filter2D forward")
    assert_close(blur_adjoint_filter2d(img, psfs, idx, wts),
                 blur_adjoint(img, psfs, idx, wts, np.float64), 1e-5, "filter2D adjoint")


def test_reference_orientation_is_image_of_a_dot():
    """psf[k//2 + v, k//2 + u] = k(u, v): a lit pixel z lights z + (u, v); the adjoint maps back."""
    h, w, k = 21, 23, 7
    psf = np.zeros((1, k, k), np.float32)
    psf[0, k // 2 + 1, k // 2 + 2] = 1.0                          # (u, v) = (2, 1)
    idx = np.zeros((h, w, 4), np.int32)
    wts = np.zeros((h, w, 4), np.float32)
    wts[..., 0] = 1.0
    dot = np.zeros((h, w), np.float32)
    dot[10, 8] = 1.0
    assert np.argwhere(blur_forward(dot, psf, idx, wts)).tolist() == [[11, 10]]
    assert np.argwhere(blur_adjoint(dot, psf, idx, wts)).tolist() == [[9, 6]]


@VARIANTS
def test_delta_psfs_give_identity(cl_runtime, variant):
    h, w, k = 39, 70, 7
    _, idx, wts = random_field(h, w, k, 3, seed=9)        # weights sum to 1 per pixel
    psfs = np.zeros((3, k, k), np.float32)
    psfs[:, k // 2, k // 2] = 1.0
    blur = make_blur(cl_runtime, psfs, idx, wts, 3, variant)
    img = np.random.default_rng(9).random((3, h, w)).astype(np.float32)
    assert_close(blur.forward_host(img), img, TOLERANCES["float32"], "forward, delta PSFs")
    assert_close(blur.adjoint_host(img), img, TOLERANCES["float32"], "adjoint, delta PSFs")


@VARIANTS
def test_direction_on_device(cl_runtime, variant):
    h, w, k = 21, 35, 7
    psf = np.zeros((1, k, k), np.float32)
    psf[0, k // 2 + 1, k // 2 + 2] = 1.0
    idx = np.zeros((h, w, 4), np.int32)
    wts = np.zeros((h, w, 4), np.float32)
    wts[..., 0] = 1.0
    blur = make_blur(cl_runtime, psf, idx, wts, 1, variant)
    dot = np.zeros((h, w), np.float32)
    dot[10, 17] = 1.0
    assert np.argwhere(blur.forward_host(dot)).tolist() == [[11, 19]]
    assert np.argwhere(blur.adjoint_host(dot)).tolist() == [[9, 15]]


@VARIANTS
@pytest.mark.timeout(60)
def test_nan_stays_local(cl_runtime, variant):
    h, w, k = 40, 57, 7
    r = k // 2
    psfs, idx, wts = synthetic_field(w, h, r)
    blur = make_blur(cl_runtime, psfs, idx, wts, 3, variant)
    img = np.random.default_rng(2).random((3, h, w)).astype(np.float32)
    img[1, 20, 30] = np.nan
    box = np.zeros((3, h, w), bool)
    box[1, 20 - r:20 + r + 1, 30 - r:30 + r + 1] = True   # every pixel the NaN can reach
    hit = np.isnan(img).astype(np.float64)
    for name, op, ref in (("forward", blur.forward_host, blur_forward),
                          ("adjoint", blur.adjoint_host, blur_adjoint)):
        out = op(img)
        expected = ref(img, psfs, idx, wts, np.float64)
        # NaN reaches every pixel whose kernel has a nonzero tap on it (PSFs and weights are
        # >= 0); through a zero tap (0 * NaN) only where the kernel does not skip it (the CPU
        # variant skips the zero corners of the disks; NumPy computes every tap)
        must = ref(hit, psfs, idx, wts, np.float64) > 0
        assert np.all(np.isnan(out)[must]), f"{name}: NaN lost"
        assert not np.isnan(out[~np.isnan(expected)]).any(), f"{name}: NaN where NumPy has none"
        assert not np.isnan(out[~box]).any(), f"{name}: NaN spread beyond the kernel radius"
        assert_close(out[~box], expected[~box], TOLERANCES["float32"], f"{name} outside the NaN")


@VARIANTS
@pytest.mark.timeout(60)
def test_zero_weights_give_zero(cl_runtime, variant):
    h, w, k = 36, 80, 7
    r = k // 2
    psfs, idx, wts = random_field(h, w, k, 4, seed=4)
    wts[:, :40] = 0.0                                      # left half: no kernel at all
    blur = make_blur(cl_runtime, psfs, idx, wts, 3, variant)
    img = np.random.default_rng(4).random((3, h, w)).astype(np.float32)
    fwd, adj = blur.forward_host(img), blur.adjoint_host(img)
    # F P at x depends on k_x only; F^T r at y on k_{y+u}, |u| <= r
    assert np.all(fwd[:, :, :40] == 0.0)
    assert np.all(adj[:, :, :40 - r] == 0.0)
    assert_close(fwd, blur_forward(img, psfs, idx, wts, np.float64), TOLERANCES["float32"])
    assert_close(adj, blur_adjoint(img, psfs, idx, wts, np.float64), TOLERANCES["float32"])
    wts[:] = 0.0
    none = make_blur(cl_runtime, psfs, idx, wts, 3, variant)
    assert np.all(none.forward_host(img) == 0.0) and np.all(none.adjoint_host(img) == 0.0)


def test_device_arrays_are_checked(cl_runtime):
    import pyopencl.array as cla
    psfs, idx, wts = synthetic_field(40, 30, 2)
    blur = make_blur(cl_runtime, psfs, idx, wts, 3, None)
    q = cl_runtime.queue
    good = cla.zeros(q, (3, 30, 40), np.float32)
    with pytest.raises(InputError, match=r"\(3, 30, 40\)"):
        blur.forward(cla.zeros(q, (1, 30, 40), np.float32), good)
    with pytest.raises(InputError, match="float32"):
        blur.adjoint(cla.zeros(q, (3, 30, 40), np.float64), good)
    with pytest.raises(InputError, match="in place"):
        blur.forward(good, good)
    with pytest.raises(InputError, match=r"\(C, H, W\)"):
        blur.forward_host(np.zeros((30, 40), np.float32))   # C = 3 needs planes
    event = blur.forward(cla.zeros(q, (3, 30, 40), np.float32) + 1, good)
    event.wait()
    assert np.allclose(good.get()[:, 5:-5, 5:-5], 1.0, atol=1e-5)  # unit-sum kernels keep 1


@pytest.mark.parametrize("bad, match", [
    ({"psfs": np.ones((2, 4, 4), np.float32)}, "k odd"),
    ({"idx": np.full((30, 40, 4), 99, np.int32)}, r"\[0, 18\)"),
    ({"wts": np.ones((30, 40, 3), np.float32)}, r"\(H, W, 4\)"),
    ({"idx": np.zeros((30, 40, 4), np.float32)}, "integer"),
], ids=["even-k", "index-range", "wts-shape", "idx-dtype"])
def test_bad_fields_are_rejected(bad, match):
    psfs, idx, wts = synthetic_field(40, 30, 2)
    args = {"psfs": psfs, "idx": idx, "wts": wts, **bad}
    img = np.zeros((3, 30, 40), np.float32)
    with pytest.raises(InputError, match=match):
        blur_forward(img, args["psfs"], args["idx"], args["wts"])


def test_field_must_cover_the_image():
    psfs, idx, wts = synthetic_field(40, 30, 2)
    with pytest.raises(InputError, match="40x30"):
        blur_adjoint(np.zeros((3, 31, 40), np.float32), psfs, idx, wts)


def test_support_and_trim():
    """psf_support: exact support at energy 1, smaller windows below; trim_psfs keeps unit sums,
    cuts to the widest support, and at energy 1 changes nothing but the padding."""
    from rtdefocus.reference.blur import psf_support, trim_psfs

    psfs, _, _ = random_field(4, 4, 15, 9, seed=3)
    psfs, sup = mixed_support(psfs, seed=5)
    assert np.array_equal(psf_support(psfs), sup)
    trimmed = trim_psfs(psfs, 1.0)
    r, r2 = 7, int(sup.max())
    assert trimmed.shape == (9, 2 * r2 + 1, 2 * r2 + 1)
    np.testing.assert_array_equal(trimmed, psfs[:, r - r2:r + r2 + 1, r - r2:r + r2 + 1])
    pill = np.stack([synthetic_field(32, 32, 6)[0][i] for i in (0, -1)])
    s999 = psf_support(pill, 0.999)
    assert np.all(s999 <= psf_support(pill)) and np.all(s999 >= 1)
    t = trim_psfs(pill, 0.9)
    np.testing.assert_allclose(t.sum((1, 2)), 1.0, atol=1e-6)
    assert t.shape[1] <= pill.shape[1]
    with pytest.raises(InputError):
        psf_support(pill, 0.0)


# ------------------------------------------------------------------ FISTA's fast adjoint
def _ops_pair(psfs, idx, wts, runtime, adjoint):
    from rtdefocus.cl.solve import ClSolveOps
    from rtdefocus.reference.metric import Metric
    from rtdefocus.reference.ops import NumpyOps

    metric = Metric.ycbcr((1.0, 0.1, 0.1, 0.0))
    return (NumpyOps(psfs, idx, wts, metric, adjoint=adjoint),
            ClSolveOps(runtime, psfs, idx, wts, metric, adjoint=adjoint))


def _gradient(ops, x):
    src, dst = ops.new(), ops.new()
    ops.upload(x, src)
    ops.gradient(src, dst)
    return ops.download(dst)


def test_fast_adjoint_device_matches_numpy_and_is_the_flipped_forward(cl_runtime):
    """``adjoint="fast"``: the forward blur with flipped PSFs, on the device as in NumPy."""
    psfs, idx, wts = random_field(41, 57, 7, 5, seed=3)
    x = np.random.default_rng(4).random((3, 41, 57), np.float32)
    g_np, g_cl = (_gradient(o, x) for o in _ops_pair(psfs, idx, wts, cl_runtime, "fast"))
    want = blur_forward(x, np.ascontiguousarray(psfs[:, ::-1, ::-1]), idx, wts)
    assert_close(g_np, want, TOLERANCES["float32"])
    assert_close(g_cl, want, TOLERANCES["float32"])
    exact = _gradient(_ops_pair(psfs, idx, wts, cl_runtime, "exact")[1], x)
    assert_close(exact, blur_adjoint(x, psfs, idx, wts), TOLERANCES["float32"])
    assert np.abs(exact - g_cl).max() > 1e-3     # random weights: the two differ


def test_fast_adjoint_is_the_transpose_where_the_blend_is_smooth():
    """Exactly the adjoint under one kernel; within a few percent on a bilinear field whose
    weights vary over ~60 px while the kernels span 11 (the calibrated fields' case)."""
    from rtdefocus.reference.metric import Metric
    from rtdefocus.reference.ops import NumpyOps

    x = np.random.default_rng(5).random((3, 120, 160), np.float32)
    psfs, idx, wts = random_field(120, 160, 7, 1, seed=6, zero_slots=False)
    ops = NumpyOps(psfs, idx, wts, Metric.rgb(), adjoint="fast")
    assert_close(_gradient(ops, x), blur_adjoint(x, psfs, idx, wts), TOLERANCES["float32"])
    psfs, idx, wts = synthetic_field(160, 120, 5.0)
    ops = NumpyOps(psfs, idx, wts, Metric.rgb(), adjoint="fast")
    exact = blur_adjoint(x, psfs, idx, wts)
    rel = np.abs(_gradient(ops, x) - exact)[:, 8:-8, 8:-8].mean() / exact.mean()
    assert rel < 0.03, rel


# ------------------------------------------------------------------ per-row tap extents (CPU)
def shaped_psfs(k=13):
    """Disks of different radii (zero corners), a delta, an off-centre disk (zero rows on one
    side, asymmetric extents) and two bars with zero rows between them."""
    from rtdefocus.reference.blur import pillbox_psf

    r = k // 2
    off = np.roll(pillbox_psf(2.0, k), (-3, 2), axis=(0, 1))     # centre at v = -3, u = +2
    bars = np.zeros((k, k), np.float32)
    bars[r - 3, r - 1:r + 2] = 1.0
    bars[r + 2, r - 4:r + 6] = 1.0
    delta = np.zeros((k, k), np.float32)
    delta[r, r] = 1.0
    psfs = np.stack([pillbox_psf(1.5, k), pillbox_psf(3.2, k), pillbox_psf(5.5, k), delta,
                     off, bars])
    return psfs / psfs.sum(axis=(1, 2), keepdims=True)


def test_row_extent_tables():
    """row_extents: per PSF row, the largest |u| of a nonzero tap (-1: zero row), as a loop over
    the taps finds it; group_row_extents: the widest over a group's ids, -1 slots ignored."""
    from rtdefocus.cl.blur import group_row_extents, row_extents

    psfs = shaped_psfs()
    n, k = psfs.shape[:2]
    r = k // 2
    ext = row_extents(psfs)
    assert ext.shape == (n, k) and ext.dtype == np.int32
    for i in range(n):
        for row in range(k):
            us = [abs(c - r) for c in range(k) if psfs[i, row, c] != 0]
            assert ext[i, row] == (max(us) if us else -1), (i, row)
    assert ext[3].tolist() == [-1] * r + [0] + [-1] * r                     # the delta
    assert ext[5, r - 3] == 1 and ext[5, r + 2] == 5 and ext[5, r] == -1   # the bars
    assert ext[4, r + 3:].max() == -1 and ext[4, r - 3] == 4               # off-centre
    assert np.all(ext[2] >= ext[1]) and np.all(ext[1] >= ext[0])           # nested disks
    gids = np.array([[0, 3, -1, -1], [4, 5, -1, -1], [-1, -1, -1, -1], [2, 1, 0, 3]], np.int32)
    gext = group_row_extents(ext, gids)
    assert gext.shape == (4, k) and gext.dtype == np.int32
    np.testing.assert_array_equal(gext[0], ext[0])
    np.testing.assert_array_equal(gext[1], np.maximum(ext[4], ext[5]))
    assert np.all(gext[2] == -1)
    np.testing.assert_array_equal(gext[3], ext[2])


@pytest.mark.slow
@VARIANTS
@pytest.mark.parametrize("h, w, c", [(48, 64, 3), (41, 53, 1)], ids=["64x48-C3", "53x41-C1"])
def test_shaped_psfs_match_reference(cl_runtime, variant, h, w, c):
    """PSFs with zero corners, zero rows and off-centre support, one per region with random
    blends elsewhere: the CPU forward and adjoint skip each row's zero taps and stay the same
    operator (bit for bit the result of every tap of the square support)."""
    from rtdefocus.cl.blur import ClBlur

    psfs = shaped_psfs()
    _, idx, wts = random_field(h, w, psfs.shape[1], len(psfs), seed=h + w)
    yy, xx = np.mgrid[0:h, 0:w]
    alone = xx < w // 2                                   # one PSF per 16 x 12 block there
    idx[alone] = 0
    wts[alone] = 0.0
    idx[alone, 0] = ((yy // 12 + xx // 16) % len(psfs))[alone]
    wts[alone, 0] = 1.0
    img = np.random.default_rng(h).random((c, h, w)).astype(np.float32)
    blur = make_blur(cl_runtime, psfs, idx, wts, c, variant)
    fwd = blur.forward_host(img)
    assert_close(fwd, blur_forward(img, psfs, idx, wts, np.float64), TOLERANCES["float32"],
                 "forward")
    adj = blur.adjoint_host(img)
    assert_close(adj, blur_adjoint(img, psfs, idx, wts, np.float64), TOLERANCES["float32"],
                 "adjoint")
    if variant == "cpu":
        try:
            ClBlur.use_row_extent = False
            square = make_blur(cl_runtime, psfs, idx, wts, c, variant)
        finally:
            ClBlur.use_row_extent = True
        assert np.array_equal(fwd, square.forward_host(img))
        assert np.array_equal(adj, square.adjoint_host(img))
