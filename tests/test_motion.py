"""The warm start of a video: the previous frame's correction moved along the motion,
never farther from the target than the cold start, a cut restarts, a still picture converges.

Frames are given in projector space (``compensate_warped``) on a small virtual cubicle with its
true kernels, so that the solver, not the warp or the calibration, is what is tested.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from helpers import skip_or_fail

import rtdefocus as rd
from rtdefocus.compensate.motion import MotionEstimator
from rtdefocus.study.samples import photographs

SIZE = (240, 180)                    # projector (w, h)


@pytest.fixture(scope="module")
def calib():
    procam = rd.sim.VirtualProCam("cubicle", projector_size=SIZE, camera_size=(384, 288))
    return rd.sim.oracle_calibration(procam)


@pytest.fixture(scope="module")
def pictures():
    ph = photographs()
    return (cv2.resize(ph["astronaut"], (480, 480), interpolation=cv2.INTER_AREA),
            cv2.resize(ph["coffee"], (400, 300), interpolation=cv2.INTER_AREA))


def _crop(img, x, y, s=1.0):
    """The SIZE window at (x, y) of ``img`` magnified by ``s`` (sub-pixel, bilinear)."""
    M = np.array([[s, 0, -x * s], [0, s, -y * s]], np.float32)
    return cv2.warpAffine(img, M, SIZE, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def clip(pictures):
    """(frames, segment names): pan, fast pan, zoom, a cut, a fade."""
    a, b = pictures
    frames, seg = [], []

    def add(name, frame):
        frames.append(frame)
        seg.append(name)

    for i in range(5):
        add("pan", _crop(a, 60 + 3 * i, 80))
    for i in range(4):
        add("fast pan", _crop(a, 75 + 11 * (i + 1), 80 + 4 * (i + 1)))
    for i in range(4):
        s = 1.03 ** (i + 1)
        add("zoom", _crop(a, 150 + 120 * (1 - 1 / s), 110 + 90 * (1 - 1 / s), s))
    for _ in range(3):
        add("cut", _crop(b, 80, 60))
    for i in range(4):
        t = (i + 1) / 5
        add("fade", (_crop(b, 80, 60) * (1 - t) + _crop(a, 100, 100) * t).astype(np.uint8))
    return frames, seg


def _run(calib, frames, iterations, warm, backend="numpy"):
    comp = rd.Compensator(calib, backend=backend)
    ds, starts, outs = [], [], []
    for f in frames:
        outs.append(comp.compensate_warped(f, iterations=iterations, warm_start=warm))
        ds.append(comp.last_info["distances"][-1])
        starts.append(comp.last_info["start"])
    return np.array(ds), starts, outs


# --------------------------------------------------------------------------- motion
def test_motion_recovers_a_pan_and_flags_the_new_edge(pictures):
    a, _ = pictures
    prev, cur = _crop(a, 100, 100), _crop(a, 106, 97)     # content moves 6 px left, 3 px down
    m = MotionEstimator().estimate(prev, cur)
    assert not m.cut and m.map_xy is not None
    h, w = cur.shape[:2]
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    core = m.valid[20:-20, 20:-20]
    dx = (m.map_xy[..., 0] - xs)[20:-20, 20:-20][core]
    dy = (m.map_xy[..., 1] - ys)[20:-20, 20:-20][core]
    assert abs(np.median(dx) - 6) < 0.3 and abs(np.median(dy) + 3) < 0.3, (np.median(dx),
                                                                             np.median(dy))
    assert m.valid_fraction > 0.85, m.valid_fraction
    # The strip that entered on the right was not in the previous frame: invalid there.
    assert m.valid[:, -3:].mean() < 0.2


def test_motion_of_a_still_and_of_a_cut(pictures):
    a, b = pictures
    est = MotionEstimator()
    same = est.estimate(_crop(a, 50, 50), _crop(a, 50, 50))
    assert same.map_xy is None and same.valid.all() and not same.cut
    cut = est.estimate(_crop(a, 50, 50), _crop(b, 0, 0))
    assert cut.cut, cut.valid_fraction


def test_carry_moves_a_field_with_the_picture(pictures):
    a, _ = pictures
    prev, cur = _crop(a, 100, 100), _crop(a, 104, 100)
    m = MotionEstimator().estimate(prev, cur)
    field = np.stack([cv2.cvtColor(prev, cv2.COLOR_RGB2GRAY).astype(np.float32)] * 3) / 255
    moved = m.carry(field)
    want = cv2.cvtColor(cur, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255
    err = np.abs(moved[0] - want)[m.valid]
    assert np.median(err) < 0.02, np.median(err)
    assert (moved[:, ~m.valid] == 0).all()


# --------------------------------------------------------------------------- the guarantee
@pytest.mark.slow
@pytest.mark.parametrize("iterations", [1, 2, 4])
def test_warm_start_is_never_farther_than_the_cold_start(calib, pictures, iterations):
    """On every frame of a moving clip (pans, zoom, cut, fade) the solver's own distance with the
    warm start is no larger than with the cold start at the same budget."""
    frames, seg = clip(pictures)
    d_warm, starts, _ = _run(calib, frames, iterations, True)
    d_cold, _, _ = _run(calib, frames, iterations, False)
    worse = [(i, seg[i], starts[i], float(d_warm[i] / d_cold[i]))
             for i in range(len(frames)) if d_warm[i] > d_cold[i] * (1 + 1e-5)]
    assert not worse, f"frames where the warm start ended farther than the cold one: {worse}"


@pytest.mark.slow
def test_warm_start_follows_the_motion(calib, pictures):
    """At 2 iterations per frame the warm start gets much closer than the cold one on moving
    content (measured here, mean warm/cold distance after each segment's first frame: pan 0.70,
    fast pan 0.61, zoom 0.65; asserted < 0.85) — a warm start that ignored the motion would be
    rejected frame after frame and be no better than cold."""
    frames, seg = clip(pictures)
    d_warm, starts, _ = _run(calib, frames, 2, True)
    d_cold, _, _ = _run(calib, frames, 2, False)
    seg = np.array(seg)
    for name in ("pan", "fast pan", "zoom"):
        idx = np.flatnonzero(seg == name)[1:]           # after the segment's first frame
        ratio = float(np.mean(d_warm[idx] / d_cold[idx]))
        assert ratio < 0.85, f"{name}: warm/cold distance {ratio:.2f}"
        assert all(starts[i] == "motion" for i in idx), [starts[i] for i in idx]


def test_a_cut_restarts_from_the_target(calib, pictures):
    frames, seg = clip(pictures)
    i_cut = seg.index("cut")
    comp = rd.Compensator(calib, backend="numpy")
    for f in frames[:i_cut]:
        comp.compensate_warped(f, iterations=2)
    out = comp.compensate_warped(frames[i_cut], iterations=2)
    assert comp.last_info["start"] == "cut"
    cold = rd.Compensator(calib, backend="numpy").compensate_warped(frames[i_cut], iterations=2)
    assert np.array_equal(out, cold), "the frame after a cut must be exactly the cold start's"


@pytest.mark.slow
def test_a_still_picture_converges_like_one_long_solve(calib, pictures):
    """A paused video or a slide: k frames of n iterations continue one solve (FISTA keeps its
    momentum), ending where one k·n-iteration solve ends."""
    frame = clip(pictures)[0][0]
    comp = rd.Compensator(calib, backend="numpy")
    for _ in range(10):
        out = comp.compensate_warped(frame, iterations=2)
    assert comp.last_info["start"] == "still"
    d_frames = comp.last_info["distances"][-1]
    one = rd.Compensator(calib, backend="numpy")
    out_one = one.compensate_warped(frame, iterations=20, warm_start=False)
    d_one = one.last_info["distances"][-1]
    assert d_frames <= d_one * (1 + 1e-4), (d_frames, d_one)
    assert np.abs(out.astype(int) - out_one).max() <= 1


def test_reset_and_warm_start_false_start_cold(calib, pictures):
    frames, _ = clip(pictures)
    comp = rd.Compensator(calib, backend="numpy")
    comp.compensate_warped(frames[0], iterations=1)
    comp.compensate_warped(frames[1], iterations=1, warm_start=False)
    assert comp.last_info["start"] == "cold"
    comp.compensate_warped(frames[2], iterations=1)
    assert comp.last_info["start"] == "motion"
    comp.reset()
    comp.compensate_warped(frames[3], iterations=1)
    assert comp.last_info["start"] == "cold"


def test_opencl_warm_start_matches_numpy(calib, pictures, cl_runtime):
    """The warm start's host-side steps are backend-independent: the OpenCL solve of a short
    pan follows the NumPy one (same starts, distances within float32 rounding)."""
    frames = clip(pictures)[0][:4]
    d_np, s_np, _ = _run(calib, frames, 2, True, backend="numpy")
    d_cl, s_cl, _ = _run(calib, frames, 2, True, backend="opencl")
    assert s_np == s_cl
    np.testing.assert_allclose(d_cl, d_np, rtol=2e-3)


def test_psf_energy_trims_the_kernels_and_keeps_the_result(calib, pictures):
    """``psf_energy`` cuts the kernels' faint halo: a smaller window, nearly the same frame."""
    frame = clip(pictures)[0][0]
    full = rd.Compensator(calib, backend="numpy")
    trimmed = rd.Compensator(calib, backend="numpy", psf_energy=0.99)
    assert trimmed._solver.ops.psfs.shape[-1] < full._solver.ops.psfs.shape[-1]
    a = full.compensate_warped(frame, iterations=10).astype(int)
    b = trimmed.compensate_warped(frame, iterations=10).astype(int)
    assert np.abs(a - b).mean() < 1.0, np.abs(a - b).mean()
    with pytest.raises(rd.InputError, match="psf_energy"):
        rd.Compensator(calib, psf_energy=0.5)


# --------------------------------------------------------------------------- carry on the device
def _motion_case(seed=0, h=37, w=53, kind="noisy"):
    """A field, a map reaching past the frame's edges, a valid mask, bases and a fallback.
    The map: ``"noisy"`` (the device's gathers), ``"translation"`` or ``"zoom"`` (smooth: its
    vector loads, with source columns and rows that step unevenly for the zoom)."""
    rng = np.random.default_rng(seed)
    f = lambda: rng.random((3, h, w), np.float32) * 1.4 - 0.2      # noqa: E731 (outside [0, 1])
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    if kind == "zoom":
        map_xy = np.stack([gx * 0.97 + 3.3 + 0.02 * gy, gy * 1.03 - 2.6 + 0.05 * gx], -1)
    else:
        noise = 1.5 if kind == "noisy" else 0.0
        map_xy = np.stack([gx + 3.3 + rng.normal(0, noise, (h, w)),
                           gy - 2.6 + rng.normal(0, noise, (h, w))], -1)
    map_xy = map_xy.astype(np.float32)
    valid = rng.random((h, w)) > 0.2
    return f(), f(), f(), f(), map_xy, valid


def _carry_backends(cl_runtime, shape, variant):
    """NumPy and OpenCL solver ops for an (h, w) frame, for their carries (an identity blur)."""
    from rtdefocus.cl.solve import ClSolveOps
    from rtdefocus.reference.metric import Metric
    from rtdefocus.reference.ops import NumpyOps

    h, w = shape
    psfs = np.zeros((1, 3, 3), np.float32)
    psfs[0, 1, 1] = 1.0
    idx, wts = np.zeros((h, w, 4), np.int32), np.zeros((h, w, 4), np.float32)
    wts[..., 0] = 1.0
    metric = Metric.ycbcr((1.0, 0.1, 0.1, 0.0))
    return (NumpyOps(psfs, idx, wts, metric),
            ClSolveOps(cl_runtime, psfs, idx, wts, metric, blur_variant=variant))


def test_carry_field_is_a_bilinear_remap():
    """The NumPy twin is cv2.remap (constant 0 border) up to cv2's 1/32 weight steps, and the
    cold fallback where the motion is invalid."""
    from rtdefocus.reference.ops import carry_field

    src, bp, bn, fb, map_xy, valid = _motion_case()
    out = carry_field(src, map_xy, valid, fb, bp, bn, clamp=False)
    want = np.stack([cv2.remap(c, map_xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=0.0) for c in src - bp]) + bn
    assert np.abs(out - want)[:, valid].max() < 0.05
    assert np.array_equal(out[:, ~valid], fb[:, ~valid])
    clamped = carry_field(src, map_xy, valid, fb, bp, bn, clamp=True)
    assert np.array_equal(clamped, np.clip(out, 0, 1))
    assert np.array_equal(carry_field(src, None, valid, fb)[:, valid], src[:, valid])


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("bases,clamp,still,kind", [(True, True, False, "noisy"),
                                                    (False, False, False, "noisy"),
                                                    (True, True, False, "translation"),
                                                    (True, False, False, "zoom"),
                                                    (True, True, True, "noisy")])
def test_opencl_carry_matches_numpy(cl_runtime, bases, clamp, still, kind, variant):
    """``kernels/solver.cl`` carry against its twin: the warm start's fields moved on the device
    (both kernel shapes; a noisy map takes the CPU shape's gathers, a translation and a zoom its
    vector loads, and 53 columns its scalar tail)."""
    src, bp, bn, fb, map_xy, valid = _motion_case(seed=1, kind=kind)
    outs = []
    for ops in _carry_backends(cl_runtime, valid.shape, variant):
        ops.set_motion(None if still else map_xy, valid)
        arrs = [ops.new() for _ in range(5)]
        for a, host in zip(arrs[:4], (src, bp, bn, fb), strict=True):
            ops.upload(host, a)
        s_, bp_, bn_, fb_, dst = arrs
        ops.carry(s_, fb_, dst, base_prev=bp_ if bases else None,
                  base_new=bn_ if bases else None, clamp=clamp)
        outs.append(ops.download(dst))
    np.testing.assert_allclose(outs[1], outs[0], atol=2e-6)
    assert np.array_equal(outs[1][:, ~valid], np.clip(fb, 0, 1)[:, ~valid] if clamp
                          else fb[:, ~valid])


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("kind,still", [("noisy", False), ("translation", False), ("zoom", True)])
def test_a_carry_of_two_fields_is_two_carries(cl_runtime, kind, still, variant):
    """``carry(..., src2=, dst2=)`` (the warm start's P and FISTA's P_prev in one pass) gives
    each field what a carry of its own gives, on both backends and both kernel shapes."""
    from rtdefocus.reference.ops import carry_field

    src, bp, bn, fb, map_xy, valid = _motion_case(seed=2, kind=kind)
    src2 = _motion_case(seed=3, kind=kind)[0]
    motion = None if still else map_xy
    want = [carry_field(f, motion, valid, fb, bp, bn, clamp=True) for f in (src, src2)]
    for ops in _carry_backends(cl_runtime, valid.shape, variant):
        ops.set_motion(motion, valid)
        bufs = [ops.new() for _ in range(7)]
        for b, host in zip(bufs, (src, src2, bp, bn, fb), strict=False):
            ops.upload(host, b)
        s1, s2, bp_, bn_, fb_, d1, d2 = bufs
        ops.carry(s1, fb_, d1, base_prev=bp_, base_new=bn_, clamp=True, src2=s2, dst2=d2)
        for got, exp in zip((d1, d2), want, strict=True):
            np.testing.assert_allclose(ops.download(got), exp, atol=2e-6)
        with pytest.raises(rd.InputError, match="src2 with dst2"):
            ops.carry(s1, fb_, d1, base_prev=bp_, base_new=bn_, src2=s2)
        with pytest.raises(rd.InputError, match="two destinations"):
            ops.carry(s1, fb_, d1, base_prev=bp_, base_new=bn_, src2=s2, dst2=fb_)
        with pytest.raises(rd.InputError, match="cannot write over"):
            ops.carry(s1, fb_, d1, base_prev=bp_, base_new=bn_, src2=s2, dst2=s1)


def test_a_repeated_input_reuses_its_warp_and_an_edited_one_does_not(calib, pictures):
    """A paused video skips the warp; the cache holds a copy, so an input edited in place is
    warped again."""
    a, b = pictures
    comp = rd.Compensator(calib, backend="numpy", method="none")
    img = cv2.resize(a, (320, 240))
    first = comp.compensate(img)
    again = comp.compensate(img.copy())
    assert np.array_equal(first, again)
    img[...] = cv2.resize(b, (320, 240))
    edited = comp.compensate(img)
    assert np.array_equal(edited, rd.Compensator(calib, backend="numpy", method="none").warp(img))
    assert not np.array_equal(edited, first)


def test_fast_adjoint_ends_where_the_exact_one_does(calib, pictures):
    """FISTA's gradient through the flipped-PSF forward (the default) reaches the exact
    adjoint's distance within 1 % after 10 iterations; a bad name is refused."""
    frame = clip(pictures)[0][0]
    d = {}
    for adjoint in ("fast", "exact"):
        comp = rd.Compensator(calib, backend="numpy", adjoint=adjoint)
        comp.compensate_warped(frame, iterations=10, warm_start=False)
        d[adjoint] = comp.last_info["distances"]
    assert d["fast"][-1] < d["fast"][0] * 0.9                     # it converges
    assert abs(d["fast"][-1] - d["exact"][-1]) < 0.01 * d["exact"][-1], d
    with pytest.raises(rd.InputError, match="adjoint"):
        rd.Compensator(calib, adjoint="approximate")


def test_warm_up_runs_the_moving_path_and_leaves_no_video_state(calib, pictures):
    """``Compensator.warm_up`` compensates a moving synthetic clip (its last frame starts from
    the motion, as a video's would) and forgets it: the next frame starts cold, as after
    ``reset()``, and gives what a fresh Compensator gives. It reports every moving frame it
    timed (``frames``: a live player measures the spread of their costs)."""
    a, _ = pictures
    comp = rd.Compensator(calib)
    info = comp.warm_up(iterations=1, frames=3)
    assert info["start"] == "motion" and info["iterations"] == 1
    assert {"warp", "solve", "total"} <= set(info["seconds"])
    assert len(info["moving"]) == 3 and info["moving"][-1] == info["seconds"]
    assert all(sec["total"] >= sec["solve"] > 0 for sec in info["moving"])
    with pytest.raises(rd.InputError, match="frames"):
        comp.warm_up(frames=0)
    frame = _crop(a, 50, 50)
    out = comp.compensate(frame, iterations=2)
    assert comp.last_info["start"] == "cold"
    fresh = rd.Compensator(calib, backend=comp.backend).compensate(frame, iterations=2)
    assert np.abs(out.astype(int) - fresh).max() <= 1
    assert rd.Compensator(calib, method="none").warm_up() is None


def test_the_motion_thread_of_a_gpu_device_gives_the_inline_result(calib, pictures):
    """On a GPU device the motion estimate runs on a helper thread beside the cold start's blur;
    on a CPU device in turn with it. Both orders give the same frames, bit for bit."""
    if not rd.Compensator(calib).backend == "opencl":
        skip_or_fail("needs an OpenCL device")
    a, _ = pictures
    frames = [_crop(a, 60 + 5 * i, 80 + 2 * i) for i in range(4)]
    outs = {}
    for gpu in (False, True):
        comp = rd.Compensator(calib, backend="opencl")
        ops = comp._solver.ops

        class Runtime:                 # the device's runtime, told to say GPU or not
            def __getattr__(self, name, rt=ops.runtime):
                return getattr(rt, name)
            is_gpu = gpu

        ops.runtime = Runtime()
        outs[gpu] = [comp.compensate(f, iterations=1) for f in frames]
        assert comp.last_info["start"] == "motion"
        assert (comp._pool is not None) == gpu
    for x, y in zip(outs[False], outs[True], strict=True):
        assert np.array_equal(x, y)
