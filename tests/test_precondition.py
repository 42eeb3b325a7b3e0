"""FISTA's preconditioners (Solver(precondition=...)): the colour one (Metric.colour_preconditioner:
chroma errors falling as fast as luma ones) and the spatial one (boost_gammas, boost_field: the
fine pattern of blurry regions converging faster); the same distance, OpenCL equal to NumPy."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import TOLERANCES, assert_close
from test_metric import METRICS, SMALL, VARIANTS, make_field

import rtdefocus as rd
from rtdefocus import sim
from rtdefocus.compensate.backends import make_solver
from rtdefocus.compensate.solvers import BOOST_CAP, _spectra, boost_gammas, lipschitz_estimate
from rtdefocus.errors import InputError
from rtdefocus.reference.metric import DEFAULT_WEIGHTS, Metric
from rtdefocus.reference.ops import boost_edges, boost_field


def test_the_preconditioner_equalises_the_colour_directions_of_the_pixel_term():
    m = Metric.ycbcr(DEFAULT_WEIGHTS)
    a0 = m.qmatrices[0]
    c = m.colour_preconditioner
    assert np.allclose(c, c.T) and np.linalg.eigvalsh(c).min() > 0
    lam = np.linalg.eigvalsh(a0)
    assert lam[-1] / lam[0] > 3            # the problem it solves: chroma is far softer
    # C A0 = λ_max I: every colour direction of the pixel term as stiff as the stiffest
    assert np.allclose(c @ a0, lam[-1] * np.eye(3), atol=1e-9)
    assert Metric.rgb().colour_preconditioner is None              # already equal
    assert Metric.ycbcr((1.0, 0.0, 0.3, 0.0)).colour_preconditioner is None   # singular A0
    # the step-size estimate: C = I changes nothing, the real C a little
    psfs = make_field(16, 16, k=7)[0]
    plain = lipschitz_estimate(psfs, m)
    assert lipschitz_estimate(psfs, m, colour=np.eye(3)) == pytest.approx(plain, rel=1e-12)
    assert lipschitz_estimate(psfs, m, colour=c) == pytest.approx(plain, rel=0.2)


def _colourful_problem():
    h, w = SMALL
    psfs, idx, wts = make_field(h, w, k=7, seed=11)
    rng = np.random.default_rng(8)
    # saturated colours in blocks: most of the error is chroma, and the clamp is active
    t = np.kron(rng.random((3, h // 5 + 1, w // 5 + 1)), np.ones((5, 5)))[:, :h, :w]
    return (psfs, idx, wts), np.clip(1.4 * t - 0.2, 0, 1).astype(np.float32)


def _photo_like_problem():
    """Colour texture inside (0, 1), as most of a photograph is: the clamp is rarely active."""
    h, w = SMALL
    psfs, idx, wts = make_field(h, w, k=7, seed=11)
    rng = np.random.default_rng(9)
    t = np.kron(rng.random((3, h // 3 + 1, w // 3 + 1)), np.ones((3, 3)))[:, :h, :w]
    return (psfs, idx, wts), (0.15 + 0.7 * t).astype(np.float32)


def test_colour_preconditioned_fista_is_closer_at_every_budget_and_stays_monotone():
    (psfs, idx, wts), target = _photo_like_problem()
    m = Metric.ycbcr(DEFAULT_WEIGHTS)
    runs = {}
    for pc in (None, "colour", "colour+spatial"):
        s = make_solver(psfs, idx, wts, m, backend="numpy", solver="fista", precondition=pc)
        assert s.precondition == pc
        P, info = s.solve(target, iterations=12)
        d = np.array(info.distances)
        assert (np.diff(d) <= 1e-6 * d[:-1]).all(), f"{pc}: the distance increased: {d}"
        assert P.min() >= 0.0 and P.max() <= 1.0
        runs[pc] = d
    plain, colour, both = runs[None], runs["colour"], runs["colour+spatial"]
    assert plain[0] == colour[0] == both[0]            # the same start and the same distance
    assert (colour[1:] < plain[1:]).all(), (plain, colour)
    assert (both[1:] < colour[1:]).all(), (colour, both)
    # what the plain solver reaches in 12 iterations, the preconditioned ones do sooner
    assert colour[10] < plain[12], (plain, colour)
    assert both[6] < plain[12], (plain, both)


@pytest.mark.slow
def test_colour_preconditioned_fista_converges_close_to_the_plain_optimum():
    """The clamp is not the exact projection in C's metric, so the limit may sit a little
    above the plain solver's: measured 0.15-0.4 % on photographs and 1.2 % on saturated colour
    blocks (400x300 cubicle, 150 iterations); bounded here at 2 % on saturated blocks."""
    (psfs, idx, wts), target = _colourful_problem()
    m = Metric.ycbcr(DEFAULT_WEIGHTS)
    end = {}
    for pc in (None, "colour", "colour+spatial"):
        s = make_solver(psfs, idx, wts, m, backend="numpy", solver="fista", precondition=pc,
                        blur="filter2d")
        end[pc] = s.solve(target, iterations=250)[1].distances[-1]
    assert end["colour"] <= 1.02 * end[None], end
    assert end["colour+spatial"] <= 1.02 * end[None], end


@pytest.mark.parametrize("variant", VARIANTS)
def test_cl_colour_field_matches_numpy(cl_runtime, variant):
    """metric.cl COLOUR_PC (both kernel shapes) against NumpyOps.metric_residual(colour=True),
    and a preconditioned FISTA solve on both backends."""
    (psfs, idx, wts), target = _colourful_problem()
    m = METRICS["ycbcr"]
    s_np = make_solver(psfs, idx, wts, m, backend="numpy", solver="fista", precondition="colour")
    s_cl = make_solver(psfs, idx, wts, m, backend="opencl", solver="fista", runtime=cl_runtime,
                       blur_variant=variant, precondition="colour")
    assert s_np.precondition == s_cl.precondition == "colour"
    P0 = np.random.default_rng(3).random(target.shape, dtype=np.float32)
    fields = {}
    for s in (s_np, s_cl):
        ops = s.ops
        fp, q = ops.new(), ops.new()
        ops.upload(P0, fp)
        ops.upload(target, s.target)
        d = ops.metric_residual(fp, s.target, q, colour=True)
        d_plain = ops.metric_residual(fp, s.target, ops.new())
        assert d == pytest.approx(d_plain, rel=TOLERANCES["float32"])   # d is not changed
        fields[s.backend] = ops.download(q)
    assert_close(fields["opencl"], fields["numpy"], TOLERANCES["float32"], "C Q e")
    P_np, i_np = s_np.solve(target, iterations=4)
    P_cl, i_cl = s_cl.solve(target, iterations=4)
    assert_close(P_cl, P_np, TOLERANCES["float32"], "preconditioned FISTA")
    assert i_cl.distances == pytest.approx(i_np.distances, rel=TOLERANCES["float32"])


def test_where_the_preconditioner_does_not_apply_and_bad_values():
    (psfs, idx, wts), _ = _colourful_problem()
    assert make_solver(psfs, idx, wts, METRICS["ycbcr"], solver="pg").precondition is None
    assert make_solver(psfs, idx, wts, Metric.rgb(), solver="fista").precondition == "spatial"
    assert make_solver(psfs, idx, wts, Metric.rgb(), solver="fista",
                       precondition="colour").precondition is None
    ops = make_solver(psfs, idx, wts, Metric.rgb()).ops
    with pytest.raises(InputError, match="colour preconditioner"):
        ops.metric_residual(ops.new(), ops.new(), ops.new(), colour=True)
    with pytest.raises(InputError, match="precondition must be"):
        make_solver(psfs, idx, wts, solver="fista", precondition="luma")
    calib = sim.oracle_calibration(sim.VirtualProCam("cubicle", projector_size=(64, 48),
                                                     camera_size=(96, 72)))
    with pytest.raises(InputError, match="precondition must be"):
        rd.Compensator(calib, backend="numpy", precondition="yes")
    assert rd.Compensator(calib, backend="numpy", precondition=None)._solver.precondition is None
    assert rd.Compensator(calib, backend="numpy", precondition="colour")._solver.precondition \
        == "colour"
    # (these kernels are too sharp to leave room for the spatial one: it stays off)
    assert rd.Compensator(calib, backend="numpy")._solver.precondition == "colour"
    calib = sim.oracle_calibration(sim.VirtualProCam("cubicle", projector_size=(240, 180),
                                                     camera_size=(320, 240)))
    assert rd.Compensator(calib, backend="numpy")._solver.precondition == "colour+spatial"
    flat = rd.Compensator(calib, backend="numpy", surface="flatten")
    assert flat._solver.precondition is None      # a residual scale keeps plain steps


# --------------------------------------------------------------------------- the spatial one
def test_boost_weights_grow_with_the_blur_and_keep_the_step_bound():
    m = Metric.ycbcr(DEFAULT_WEIGHTS)
    c = m.colour_preconditioner
    from test_metric import disc
    psfs = np.stack([disc(r, 13) for r in (0.4, 1.0, 2.0, 3.0, 5.0)])
    L = lipschitz_estimate(psfs, m, colour=c) * 1.05
    g = boost_gammas(psfs, m, L, c)
    assert g[0] < 0.05 and (np.diff(g) >= 0).all() and g[-1] == BOOST_CAP, g
    # each PSF's preconditioned curvature stays within the step's bound at every frequency
    spec, lam, top = _spectra(psfs, m, 64, c)
    worst = (2 * spec * top[None] * (1 + g[:, None, None] * lam[None])).max()
    assert worst <= L / 1.05 * (1 + 1e-9), (worst, L)
    assert boost_gammas(psfs, m, L, c, cap=0.5).max() == 0.5


def test_boost_field_is_symmetric_on_the_free_set_and_keeps_active_elements():
    rng = np.random.default_rng(4)
    h, w = 9, 13
    idx = rng.integers(0, 3, (h, w, 4)).astype(np.int32)
    wts = rng.random((h, w, 4)).astype(np.float32)
    gx, gy = boost_edges(np.array([0.0, 1.0, 2.0]), idx, wts)
    assert (gx[:, -1] == 0).all() and (gy[-1] == 0).all() and gx.min() >= 0
    P = rng.random((3, h, w)).astype(np.float32)            # all free
    a, b = rng.standard_normal((2, 3, h, w)).astype(np.float32)
    Ma, Mb = boost_field(a, P, gx, gy), boost_field(b, P, gx, gy)
    assert np.vdot(Ma, b) == pytest.approx(np.vdot(a, Mb), rel=1e-5)      # M symmetric
    assert np.vdot(Ma, a) >= np.vdot(a, a) * (1 - 1e-6)                  # M >= I
    # active elements (at a bound, pushed out) keep their plain value, and count as 0
    P2 = P.copy()
    P2[0, 4, 6], a2 = 0.0, a.copy()
    a2[0, 4, 6] = abs(a2[0, 4, 6]) + 1.0
    out = boost_field(a2, P2, gx, gy)
    assert out[0, 4, 6] == a2[0, 4, 6]
    zeroed = a2.copy()
    zeroed[0, 4, 6] = 0.0
    ref = boost_field(zeroed, P2, gx, gy)
    ref[0, 4, 6] = a2[0, 4, 6]
    assert_close(out, ref, 1e-6, "active element")


@pytest.mark.parametrize("variant", VARIANTS)
def test_cl_boost_gradient_matches_numpy(cl_runtime, variant):
    (psfs, idx, wts), target = _colourful_problem()    # saturated: many active elements
    m = METRICS["ycbcr"]
    s_np = make_solver(psfs, idx, wts, m, backend="numpy", solver="fista")
    s_cl = make_solver(psfs, idx, wts, m, backend="opencl", solver="fista", runtime=cl_runtime,
                       blur_variant=variant)
    assert s_np.precondition == s_cl.precondition == "colour+spatial"
    rng = np.random.default_rng(6)
    P = np.clip(rng.random(target.shape) * 1.4 - 0.2, 0, 1).astype(np.float32)
    g = rng.standard_normal(target.shape).astype(np.float32)
    outs = {}
    for s in (s_np, s_cl):
        ops = s.ops
        bp, bg, bo = ops.new(), ops.new(), ops.new()
        ops.upload(P, bp)
        ops.upload(g, bg)
        ops.boost_gradient(bp, bg, bo)
        outs[s.backend] = ops.download(bo)
    assert_close(outs["opencl"], outs["numpy"], TOLERANCES["float32"], "M_F g")
    assert not np.allclose(outs["numpy"], g)             # it does something
    P_np, i_np = s_np.solve(target, iterations=5)
    P_cl, i_cl = s_cl.solve(target, iterations=5)
    assert_close(P_cl, P_np, TOLERANCES["float32"], "FISTA with both preconditioners")
    assert i_cl.distances == pytest.approx(i_np.distances, rel=TOLERANCES["float32"])
