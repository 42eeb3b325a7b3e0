"""The Eq. 4 distance, its gradient and the constrained solvers: NumPy reference properties and
the OpenCL kernels against it (metric.cl, solver.cl)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import TOLERANCES, assert_close

from rtdefocus.compensate.backends import make_solver
from rtdefocus.compensate.solvers import lipschitz_estimate
from rtdefocus.reference.blur import blur_adjoint, blur_forward
from rtdefocus.reference.lut import decode_lut, encode_lut, increasing_lut
from rtdefocus.reference.metric import (
    M_RGB_TO_YCBCR,
    Metric,
    distance,
    distance_and_gradient,
    exact_step,
    forward_differences,
    laplacian,
    metric_field,
    rgb_to_ycbcr,
    ycbcr_to_rgb,
)
from rtdefocus.reference.ops import NumpyOps

H, W = 238, 318          # odd sizes: W is not a multiple of the 16-pixel chunks, 3HW of 16
METRICS = {
    "ycbcr": Metric.ycbcr((1.0, 0.5, 0.3, 0.2)),
    "ycbcr-pixel": Metric.ycbcr((1.0, 0.5, 0.0, 0.0)),
    "rgb": Metric.rgb(),
}
VARIANTS = ["cpu", "gpu"]   # both kernel shapes run on any device (PoCL included)


def disc(radius: float, k: int) -> np.ndarray:
    """Area-sampled disc PSF of a radius, (k, k) unit sum."""
    ss = 8
    c = (np.arange(k * ss) + 0.5) / ss - k / 2
    u, v = np.meshgrid(c, c)
    ker = (u * u + v * v <= max(radius, 0.3) ** 2).reshape(k, ss, k, ss).sum(axis=(1, 3))
    return (ker / ker.sum()).astype(np.float32)


def make_field(h: int, w: int, k: int = 7, seed: int = 0):
    """Two 'planes' split by a slanted fold, each blending its own PSFs smoothly (as a
    calibrated field does), plus random jitter of the weights so every slot is exercised."""
    rng = np.random.default_rng(seed)
    radii = [0.4, 1.0, 1.6, 2.2, 2.8, 1.3, 0.7, 2.5]
    psfs = np.stack([disc(r, k) for r in radii])
    ys, xs = np.mgrid[0:h, 0:w]
    plane = (xs - 0.6 * w + 0.2 * (ys - h / 2) >= 0).astype(np.int64)
    fx, fy = xs / max(w - 1, 1), ys / max(h - 1, 1)
    bil = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], -1)
    wts = bil * rng.uniform(0.5, 1.5, bil.shape)
    wts /= wts.sum(-1, keepdims=True)
    idx = np.where(plane[..., None] == 0, np.array([0, 1, 2, 3]), np.array([4, 5, 6, 7]))
    return psfs, idx.astype(np.int32), wts.astype(np.float32)


@pytest.fixture(scope="module")
def field():
    return make_field(H, W)


@pytest.fixture(scope="module")
def images():
    rng = np.random.default_rng(7)
    # Smooth content plus edges, so both the pixel and the spatial terms matter.
    base = rng.random((3, H // 8 + 1, W // 8 + 1)).astype(np.float32)
    smooth = np.kron(base, np.ones((8, 8), np.float32))[:, :H, :W]
    target = np.clip(0.7 * smooth + 0.3 * rng.random((3, H, W)), 0, 1).astype(np.float32)
    P = rng.random((3, H, W)).astype(np.float32)
    return target, P


def rel_err(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30))


# --------------------------------------------------------------------------- NumPy reference
def test_ycbcr_is_bt601_and_invertible(rng):
    white = np.ones((3, 1, 1))
    assert np.allclose(rgb_to_ycbcr(white)[:, 0, 0], [1.0, 0.0, 0.0], atol=1e-6)
    grey = np.full((3, 1, 1), 0.25)
    assert np.allclose(rgb_to_ycbcr(grey)[:, 0, 0], [0.25, 0.0, 0.0], atol=1e-6)
    img = rng.random((3, 5, 7))
    assert np.allclose(ycbcr_to_rgb(rgb_to_ycbcr(img)), img, atol=1e-6)
    assert np.allclose(M_RGB_TO_YCBCR[0], [0.299, 0.587, 0.114])


def test_laplacian_is_grad_transpose_grad(rng):
    x, y = rng.standard_normal((2, 3, 13, 17))
    dx_x, dy_x = forward_differences(x)
    dx_y, dy_y = forward_differences(y)
    lhs = np.vdot(dx_x, dx_y) + np.vdot(dy_x, dy_y)          # ⟨∇x, ∇y⟩
    assert np.isclose(lhs, np.vdot(x, laplacian(y)), rtol=1e-12)
    # Neumann border: a constant has zero Laplacian everywhere, corners and edges included.
    assert np.abs(laplacian(np.full((1, 6, 9), 3.0))).max() == 0
    # Each neighbour pair once: the 4-connected degree of an interior / edge / corner pixel.
    delta = np.zeros((1, 5, 5))
    delta[0, 2, 2] = 1
    assert laplacian(delta)[0, 2, 2] == 4
    delta[...] = 0
    delta[0, 0, 0] = 1
    assert laplacian(delta)[0, 0, 0] == 2


@pytest.mark.parametrize("name", list(METRICS), ids=list(METRICS))
def test_distance_is_the_quadratic_form_of_the_field(name, rng):
    m = METRICS[name]
    e = rng.standard_normal((3, 11, 14))
    d = distance(e, m)
    assert d > 0
    assert np.isclose(np.vdot(e, metric_field(e, m)), d, rtol=1e-10)
    assert np.isclose(distance(2 * e, m), 4 * d, rtol=1e-12)


def test_spatial_term_penalises_the_difference_of_differences():
    """Eq. 4 as corrected in DESIGN.md §3: showing the input exactly costs nothing, and an
    offset of the whole luma (no change of any edge) costs only the pixel term."""
    m_spatial = Metric.ycbcr((0.0, 0.0, 1.0, 1.0))
    img = np.random.default_rng(1).random((3, 9, 12))
    assert distance(img - img, m_spatial) == 0.0
    assert distance(np.full((3, 9, 12), 0.2), m_spatial) == pytest.approx(0.0, abs=1e-20)
    # The paper's printed form [(Y_ip^i − Y_ip^j) + (Y_op^i − Y_op^j)]² would charge 4 |∇Y|² here.
    printed = sum(float(np.sum((2 * g) ** 2)) for g in forward_differences(rgb_to_ycbcr(img)[0]))
    assert printed > 0


def test_gradient_matches_finite_differences(rng):
    h, w = 19, 23
    psfs, idx, wts = make_field(h, w, k=5, seed=3)
    m = METRICS["ycbcr"]
    target = rng.random((3, h, w))
    P = rng.random((3, h, w))
    d0, g = distance_and_gradient(P, target, psfs, idx, wts, m, dtype=np.float64)
    eps = 1e-4
    for _ in range(3):       # directional derivatives along random directions
        v = rng.standard_normal(P.shape)
        dp, _ = distance_and_gradient(P + eps * v, target, psfs, idx, wts, m, dtype=np.float64)
        dm, _ = distance_and_gradient(P - eps * v, target, psfs, idx, wts, m, dtype=np.float64)
        assert (dp - dm) / (2 * eps) == pytest.approx(np.vdot(g, v), rel=1e-6)
    for c, y, x in [(0, 0, 0), (1, h - 1, w // 2), (2, h // 2, w - 1)]:   # single pixels, borders
        v = np.zeros_like(P)
        v[c, y, x] = 1.0
        dp, _ = distance_and_gradient(P + eps * v, target, psfs, idx, wts, m, dtype=np.float64)
        dm, _ = distance_and_gradient(P - eps * v, target, psfs, idx, wts, m, dtype=np.float64)
        assert (dp - dm) / (2 * eps) == pytest.approx(g[c, y, x], rel=1e-5, abs=1e-9)


def test_exact_step_is_the_minimum_of_the_parabola(rng):
    h, w = 17, 21
    psfs, idx, wts = make_field(h, w, k=5, seed=4)
    m = METRICS["ycbcr"]
    target, P = rng.random((2, 3, h, w))
    d0, g = distance_and_gradient(P, target, psfs, idx, wts, m, dtype=np.float64)
    s = -g
    t = exact_step(g, s, blur_forward(s, psfs, idx, wts, dtype=np.float64), m)
    assert t > 0

    def d_at(tt):
        return distance_and_gradient(P + tt * s, target, psfs, idx, wts, m, dtype=np.float64)[0]

    assert d_at(t) < d0
    assert d_at(t) < d_at(0.9 * t) and d_at(t) < d_at(1.1 * t)


def test_lipschitz_estimate_bounds_the_curvature(rng):
    # Delta PSF: the Hessian of ‖P − I‖² is 2·identity.
    delta = np.zeros((1, 3, 3), np.float32)
    delta[0, 1, 1] = 1
    assert lipschitz_estimate(delta, Metric.rgb()) == pytest.approx(2.0, rel=1e-9)
    # A blend field: power iteration on the true Hessian 2 Fᵀ Q F stays below the estimate.
    h, w = 24, 29
    psfs, idx, wts = make_field(h, w, k=7, seed=5)
    m = METRICS["ycbcr"]
    v = rng.standard_normal((3, h, w))
    lam = 0.0
    for _ in range(40):
        hv = 2 * blur_adjoint(metric_field(blur_forward(v, psfs, idx, wts, np.float64), m),
                              psfs, idx, wts, np.float64)
        lam = np.vdot(v, hv) / np.vdot(v, v)
        v = hv / np.linalg.norm(hv)
    est = lipschitz_estimate(psfs, m)
    assert 0.5 * est < lam <= 1.05 * est


def test_lut_encode_inverts_decode():
    gamma = np.tile((np.arange(256) / 255.0) ** 2.2, (3, 1)).astype(np.float32)
    for lut in (gamma, np.tile(np.linspace(0, 1, 256, dtype=np.float32), (3, 1))):
        inc = increasing_lut(lut)
        codes = np.random.default_rng(0).integers(0, 256, (31, 37, 3)).astype(np.uint8)
        codes[0, :3] = [[0, 0, 0], [255, 255, 255], [1, 2, 254]]
        assert np.array_equal(encode_lut(decode_lut(codes, inc), inc), codes)
    # Nearest code under linear interpolation: just below / above a midpoint.
    inc = increasing_lut(gamma)
    mid = (inc[:, 100] + inc[:, 101]) / 2
    P = np.stack([np.full((1, 2), 0.0, np.float32)] * 3)
    P[:, 0, 0], P[:, 0, 1] = mid * 0.999, mid * 1.001
    out = encode_lut(P, inc)
    assert (out[0, 0] == 100).all() and (out[0, 1] == 101).all()


# --------------------------------------------------------------------------- OpenCL vs NumPy
def cl_ops(cl_runtime, field, metric, variant):
    from rtdefocus.cl.solve import ClSolveOps

    psfs, idx, wts = field
    return ClSolveOps(cl_runtime, psfs, idx, wts, metric, blur_variant=variant)


@pytest.mark.slow
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", list(METRICS), ids=list(METRICS))
def test_cl_metric_kernels_match_numpy(cl_runtime, field, images, name, variant):
    m = METRICS[name]
    ops = cl_ops(cl_runtime, field, m, variant)
    target, P = images
    fs = (P - 0.5).astype(np.float32)
    fp, tg, fsd, q, fp_out, v = (ops.new() for _ in range(6))
    ops.upload(P, fp)
    ops.upload(target, tg)
    ops.upload(fs, fsd)
    tol = TOLERANCES["float32"]

    d = ops.metric_residual(fp, tg, q)
    q_ref = metric_field(P - target, m)
    assert_close(ops.download(q), q_ref, tol, f"{name}/{variant} metric_residual q")
    assert d == pytest.approx(distance(P - target, m), rel=tol)

    t = 0.37
    d = ops.metric_update(fp, fsd, t, tg, fp_out, q)
    moved = P + np.float32(t) * fs
    assert_close(ops.download(fp_out), moved, tol, "metric_update fp_out")
    assert_close(ops.download(q), metric_field(moved - target, m), tol, "metric_update q")
    assert d == pytest.approx(distance(moved - target, m), rel=tol)

    ops.upload(q_ref, v)
    c, dot = ops.metric_curvature(fsd, v)
    assert c == pytest.approx(distance(fs, m), rel=tol)
    assert dot == pytest.approx(np.vdot(fs.astype(np.float64), q_ref), rel=tol)


@pytest.mark.parametrize("variant", VARIANTS)
def test_cl_metric_gradient_matches_numpy(cl_runtime, field, images, variant):
    m = METRICS["ycbcr"]
    psfs, idx, wts = field
    target, P = images
    ops = cl_ops(cl_runtime, field, m, variant)
    Pd, tg, fp, q, g = (ops.new() for _ in range(5))
    ops.upload(P, Pd)
    ops.upload(target, tg)
    ops.forward(Pd, fp)
    d = ops.metric_residual(fp, tg, q)
    ops.adjoint(q, g)
    d_ref, g_ref = distance_and_gradient(P, target, psfs, idx, wts, m)
    assert d == pytest.approx(d_ref, rel=TOLERANCES["float32"])
    assert_close(2 * ops.download(g), g_ref, TOLERANCES["float32"], f"gradient ({variant})")


@pytest.mark.parametrize("variant", VARIANTS)
def test_cl_step_kernels_match_numpy(cl_runtime, field, images, variant):
    m = METRICS["ycbcr"]
    target, P = images
    rng = np.random.default_rng(3)
    g = rng.standard_normal(P.shape).astype(np.float32)
    Pb = P.copy()
    Pb[:, ::7, ::5] = 0.0                 # points at the bounds, so the mask matters
    Pb[:, 3::11, ::3] = 1.0
    ops = cl_ops(cl_runtime, field, m, variant)
    ref = NumpyOps(*field, m)
    dev = {k: ops.new() for k in ("P", "g", "s", "delta", "Pp", "Gp", "out")}
    host = {k: ref.new() for k in dev}
    for k, v in (("P", Pb), ("g", g), ("Pp", P), ("Gp", 0.5 * g)):
        ops.upload(v, dev[k])
        host[k][...] = v
    tol = TOLERANCES["float32"]
    assert ops.pg_direction(dev["P"], dev["g"], dev["s"]) == pytest.approx(
        ref.pg_direction(host["P"], host["g"], host["s"]), rel=tol)
    assert_close(ops.download(dev["s"]), host["s"], tol, "pg_direction")
    got = ops.pg_step(dev["P"], dev["s"], 0.3, dev["delta"])
    want = ref.pg_step(host["P"], host["s"], 0.3, host["delta"])
    assert got[:2] == pytest.approx(want[:2], rel=tol) and got[2] == want[2] > 0
    assert_close(ops.download(dev["P"]), host["P"], tol, "pg_step P")
    assert_close(ops.download(dev["delta"]), host["delta"], tol, "pg_step delta")
    for beta in (0.0, 0.6):
        got = ops.fista_step(dev["P"], dev["Pp"], dev["g"], dev["Gp"], beta, 0.2, dev["out"])
        want = ref.fista_step(host["P"], host["Pp"], host["g"], host["Gp"], beta, 0.2, host["out"])
        assert got == pytest.approx(want, rel=tol)
        assert_close(ops.download(dev["out"]), host["out"], tol, f"fista_step beta={beta}")
    ops.axpy(dev["P"], dev["g"], -0.25)
    ref.axpy(host["P"], host["g"], -0.25)
    assert_close(ops.download(dev["P"]), host["P"], tol, "axpy")


@pytest.mark.parametrize("variant", VARIANTS)
def test_cl_lut_decode_encode_match_numpy(cl_runtime, field, images, variant):
    ops = cl_ops(cl_runtime, field, METRICS["rgb"], variant)
    lut = increasing_lut(np.tile((np.arange(256) / 255.0) ** 2.2, (3, 1)))
    codes = np.random.default_rng(2).integers(0, 256, (H, W, 3)).astype(np.uint8)
    buf = ops.new()
    ops.decode(codes, lut, 0.1, 0.8, buf)
    assert_close(ops.download(buf), decode_lut(codes, lut, (0.1, 0.9)), 1e-6, "decode")
    _, P = images
    Pw = np.concatenate([P[:, :10] * 1.4 - 0.2, P[:, 10:]], axis=1).astype(np.float32)  # out of range too
    ops.upload(Pw, buf)
    assert np.array_equal(ops.encode(buf, lut), encode_lut(Pw, lut))


_NUMPY_SOLVES: dict = {}


@pytest.mark.slow
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("solver", ["pg", "fista"])
def test_cl_solver_steps_match_numpy(cl_runtime, field, images, solver, variant):
    psfs, idx, wts = field
    target, _ = images
    m = METRICS["ycbcr"]
    s_cl = make_solver(psfs, idx, wts, m, backend="opencl", solver=solver,
                       runtime=cl_runtime, blur_variant=variant)
    for n in (1, 3):
        if (solver, n) not in _NUMPY_SOLVES:    # the reference is the same for both variants
            s_np = make_solver(psfs, idx, wts, m, backend="numpy", solver=solver)
            _NUMPY_SOLVES[solver, n] = s_np.solve(target, iterations=n)
        P_np, i_np = _NUMPY_SOLVES[solver, n]
        P_cl, i_cl = s_cl.solve(target, iterations=n)
        assert_close(P_cl, P_np, TOLERANCES["float32"], f"{solver} after {n} iterations")
        assert i_cl.distances == pytest.approx(i_np.distances, rel=TOLERANCES["float32"])


# --------------------------------------------------------------------------- solver properties
SMALL = (61, 83)


@pytest.fixture(scope="module")
def small_problem():
    """A small field and a target with saturated parts (so the clamp is active)."""
    h, w = SMALL
    psfs, idx, wts = make_field(h, w, k=7, seed=11)
    rng = np.random.default_rng(5)
    t = np.kron(rng.random((3, h // 6 + 1, w // 6 + 1)), np.ones((6, 6)))[:, :h, :w]
    target = np.clip(1.6 * t - 0.3, 0, 1).astype(np.float32)   # ~35 % of values at 0 or 1
    return (psfs, idx, wts), target


@pytest.mark.slow
def test_fista_restart_on_the_device_matches_numpy_without_read_backs(cl_runtime, small_problem):
    """FISTA's restart test runs on the backend (solver.cl fista_decide / fista_undo): with L
    underestimated 16x, steps are rejected and L doubles on both backends alike, the distance
    never increases, and the OpenCL run reads back once (its end), not once per iteration."""
    (psfs, idx, wts), target = small_problem
    runs = {}
    for backend in ("numpy", "opencl"):
        s = make_solver(psfs, idx, wts, METRICS["ycbcr"], backend=backend, solver="fista",
                        runtime=cl_runtime if backend == "opencl" else None)
        L0 = s.L
        s.L = L0 / 16
        s.ops.upload(target, s.target)
        s.start_from_target()
        reads = []
        if backend == "opencl":
            for name in ("_reduce", "download", "fista_accepted", "fista_state_read"):
                f = getattr(s.ops, name)
                setattr(s.ops, name, lambda *a, _f=f, _n=name, _r=reads, **k:
                        (_r.append(_n), _f(*a, **k))[1])
        info = s.run(12)
        runs[backend] = (info, s.L / L0, s.ops.download(s.P), reads)
    (i_np, l_np, P_np, _), (i_cl, l_cl, P_cl, reads) = runs["numpy"], runs["opencl"]
    assert i_np.restarts >= 2 and i_cl.restarts == i_np.restarts
    assert l_np == l_cl > 1 / 16          # L doubled (from the 16x underestimate)
    assert i_cl.iterations == i_np.iterations == 12
    d = np.array(i_cl.distances)
    assert len(d) == 13 and (np.diff(d) <= 1e-6 * d[:-1]).all() and d[-1] < 0.9 * d[0]
    assert i_cl.distances == pytest.approx(i_np.distances, rel=TOLERANCES["float32"])
    assert_close(P_cl, P_np, TOLERANCES["float32"], "FISTA with restarts")
    assert reads == ["fista_state_read", "download"], reads


def check_monotone_in_range(problem, solver, backend, runtime=None):
    (psfs, idx, wts), target = problem
    s = make_solver(psfs, idx, wts, METRICS["ycbcr"], backend=backend, solver=solver,
                    runtime=runtime)
    P, info = s.solve(target, iterations=25)
    d = np.array(info.distances)
    # (part of the target is saturated, so d cannot approach 0; ~15 % is what 25 steps buy)
    assert len(d) == 26 and d[-1] < 0.9 * d[0], f"{backend}/{solver} made no progress: {d}"
    assert (np.diff(d) <= 1e-6 * d[:-1]).all(), f"{backend}/{solver}: distance increased: {d}"
    assert P.min() >= 0.0 and P.max() <= 1.0
    if solver == "pg":   # the clamp bent some steps: the chord search was exercised
        assert info.clipped_steps > 0


@pytest.mark.parametrize("solver", ["pg", "fista"])
def test_numpy_solvers_never_increase_the_distance_and_stay_in_range(small_problem, solver):
    check_monotone_in_range(small_problem, solver, "numpy")


@pytest.mark.parametrize("solver", ["pg", "fista"])
def test_cl_solvers_never_increase_the_distance_and_stay_in_range(cl_runtime, small_problem, solver):
    check_monotone_in_range(small_problem, solver, "opencl", cl_runtime)


@pytest.mark.parametrize("solver", ["pg", "fista"])
def test_warm_start_converges_in_fewer_iterations(cl_runtime, small_problem, solver):
    (psfs, idx, wts), target = small_problem
    s = make_solver(psfs, idx, wts, METRICS["ycbcr"], backend="opencl", solver=solver,
                    runtime=cl_runtime)
    tol = 2e-3
    P_cold, cold = s.solve(target, iterations=400, tol=tol)
    assert cold.converged
    # The next "frame": the same scene 2 % brighter, started from the last solution.
    nxt = np.clip(target * 1.02, 0, 1)
    _, warm = s.solve(nxt, P0=P_cold, iterations=400, tol=tol)
    _, cold2 = s.solve(nxt, iterations=400, tol=tol)
    assert warm.converged and cold2.converged
    assert warm.iterations < cold2.iterations, (warm.iterations, cold2.iterations)
    assert warm.distances[-1] <= cold2.distances[-1] * 1.05


@pytest.mark.parametrize("variant", VARIANTS)
def test_a_converged_solve_leaves_no_subnormal_floats(cl_runtime, variant):
    """Programs are built with -cl-denorms-are-zero (rtdefocus.cl.runtime.BUILD_OPTIONS): a
    solve near convergence fills its fields (momentum differences, residuals near black) with
    subnormal floats, which x86 handles in microcode; without the flag this very solve holds
    up to ~1700 of them after a call and, at 800x600 on PoCL, an iteration costs twice as much."""
    from rtdefocus import sim
    from rtdefocus.compensate import Compensator
    from rtdefocus.study.samples import photographs

    # (cl_runtime: skipped where no OpenCL device exists; the Compensator takes the default one)
    procam = sim.VirtualProCam("cubicle", projector_size=(160, 120), camera_size=(256, 192))
    comp = Compensator(sim.oracle_calibration(procam), backend="opencl", blur_variant=variant)
    s, tiny = comp._solver, np.finfo(np.float32).tiny
    photo = photographs()["astronaut"]
    for call in range(6):                       # a slide: the solve continues, 10 at a time
        comp.compensate(photo, iterations=10)
        for name in ("P", "_P_prev", "_q", "_G", "_G_prev", "_fp"):
            a = s.ops.download(getattr(s, name))
            n = int(np.count_nonzero((a != 0) & (np.abs(a) < tiny)))
            assert n == 0, f"{n} subnormal floats in the solver's {name} after call {call}"
    d = comp.last_info["distances"]
    assert d[-1] <= d[0]
