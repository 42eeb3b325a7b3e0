"""rd.Compensator end to end on the simulator: what the camera sees of `compensate` is closer to
the sharp reference than geometry correction alone (DESIGN.md §2-3)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from helpers import blind_calibrate

from rtdefocus import sim
from rtdefocus.compensate import Compensator, Metric
from rtdefocus.compensate import compensator as compensator_mod
from rtdefocus.errors import CalibrationFileError, InputError
from rtdefocus.reference.blur import blur_forward_filter2d
from rtdefocus.reference.lut import decode_lut
from rtdefocus.reference.metric import distance
from rtdefocus.sim import oracle_calibration
from rtdefocus.study.samples import photographs, text_slide
from rtdefocus.study.scores import near_folds_mask, psnr, rect_mask, ssim

# Smaller than the default 800x600 / 1280x960 to stay fast: the blur radii scale with the
# projector resolution (0.8-3 px here on the cubicle), which still needs compensation.
PROJECTOR, CAMERA = (400, 300), (640, 480)
PRESETS = ["cubicle", "tilted", "pillar"]
BAND = 16   # camera px either side of the fold: the "near-fold band"


def calibration_source(procam):
    """The calibration the outcome is judged with: learnt through capture() only, as a user
    gets it (the oracle, built from the ground truth, is the yardstick in the test below)."""
    return blind_calibrate(procam)


@pytest.fixture(scope="module")
def images():
    out = photographs()
    out["text"] = text_slide((640, 480))
    return out


_SETUPS: dict = {}


def setup_for(preset: str):
    """(procam, calib, compensators by method); built once per module run."""
    if preset not in _SETUPS:
        procam = sim.VirtualProCam(preset, projector_size=PROJECTOR, camera_size=CAMERA, seed=3)
        calib = calibration_source(procam)
        comps = {m: Compensator(calib, method=m) for m in ("ycbcr", "rgb", "none")}
        _SETUPS[preset] = (procam, calib, comps)
    return _SETUPS[preset]


_VIEWS: dict = {}


def camera_views(preset: str, name: str, image: np.ndarray) -> dict:
    """Camera frames of the sharp reference, geometry only and each compensation method, with
    the display-rect mask and the near-fold band inside it."""
    key = (preset, name)
    if key not in _VIEWS:
        procam, calib, comps = setup_for(preset)
        warped = comps["none"].warp(image)
        rect = comps["none"].display_rect((image.shape[1], image.shape[0]))
        shape = (CAMERA[1], CAMERA[0])
        mask = rect_mask(rect, shape)
        views = {"sharp": procam.capture(warped, sharp=True), "none": procam.capture(warped),
                 "mask": mask, "band": mask & near_folds_mask(calib, shape, BAND),
                 "rect": rect}
        for m in ("ycbcr", "rgb"):
            comps[m].reset()
            views[m] = procam.capture(comps[m].compensate(image))
            views[m + "_P"] = comps[m].last_info
        _VIEWS[key] = views
    return _VIEWS[key]


PHOTOS = ["chelsea", "coffee", "astronaut", "rocket"]

# Measured gains of ycbcr over geometry only (PSNR dB over the display, PSNR dB in the fold band,
# SSIM over the display), from `.venv/bin/python tools/measure_gains.py --sections compensate`
# (OpenCL on PoCL, deterministic). The tests ask for MARGIN of each: a change that loses a
# sixth of a gain fails. (pillar/rocket's fold band is mostly flat sky: little to sharpen there.)
MEASURED = {
    ("cubicle", "chelsea"): (4.06, 3.92, 0.0320), ("cubicle", "coffee"): (3.99, 3.46, 0.0314),
    ("cubicle", "astronaut"): (4.24, 3.89, 0.0387), ("cubicle", "rocket"): (3.45, 4.04, 0.0201),
    ("tilted", "chelsea"): (3.99, 3.86, 0.0312), ("tilted", "coffee"): (3.83, 3.07, 0.0327),
    ("tilted", "astronaut"): (4.15, 3.62, 0.0391), ("tilted", "rocket"): (3.32, 3.77, 0.0206),
    ("pillar", "chelsea"): (3.33, 3.19, 0.0191), ("pillar", "coffee"): (3.80, 2.77, 0.0293),
    ("pillar", "astronaut"): (4.32, 4.41, 0.0230), ("pillar", "rocket"): (3.08, 0.94, 0.0194),
}
MARGIN = 0.85


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("name", PHOTOS)
def test_compensation_beats_geometry_only(preset, name, images):
    v = camera_views(preset, name, images[name])
    for region in ("mask", "band"):
        m = v[region]
        assert m.sum() > 500, f"{region} is nearly empty"
        p0, p1 = psnr(v["none"], v["sharp"], m), psnr(v["ycbcr"], v["sharp"], m)
        s0, s1 = ssim(v["none"], v["sharp"], m), ssim(v["ycbcr"], v["sharp"], m)
        # At least MARGIN of the measured gain, over the display and in the fold band.
        need = MARGIN * MEASURED[preset, name][0 if region == "mask" else 1]
        assert p1 > p0 + need, (f"{preset}/{name} {region}: PSNR {p1:.2f} vs geometry {p0:.2f} "
                                f"(gain {p1 - p0:.2f} dB < {need:.2f} dB)")
        need_s = MARGIN * MEASURED[preset, name][2] if region == "mask" else 0.0
        assert s1 > s0 + need_s, f"{preset}/{name} {region}: SSIM {s1:.4f} vs geometry {s0:.4f}"


def oracle_gains(preset: str, images) -> tuple[list, list]:
    """Per photograph, the PSNR gain over geometry only with the calibrated kernels and with
    the simulator's true kernels (the oracle), each against the sharp view of its own warp (the
    oracle warps with the true geometry, whose display rectangle is not the calibrated one)."""
    procam, calib, comps = setup_for(preset)
    truth = oracle_calibration(procam)
    oracle, geometry = Compensator(truth, method="ycbcr"), Compensator(truth, method="none")
    gains_cal, gains_oracle = [], []
    for name in PHOTOS:
        img = images[name]
        v = camera_views(preset, name, img)
        gains_cal.append(psnr(v["ycbcr"], v["sharp"], v["mask"]) - psnr(v["none"], v["sharp"], v["mask"]))
        warped = geometry.warp(img)
        mask = rect_mask(geometry.display_rect((img.shape[1], img.shape[0])), (CAMERA[1], CAMERA[0]))
        sharp = procam.capture(warped, sharp=True)
        oracle.reset()
        view = procam.capture(oracle.compensate(img))
        gains_oracle.append(psnr(view, sharp, mask) - psnr(procam.capture(warped), sharp, mask))
    return gains_cal, gains_oracle


# Mean gains over the photographs (calibrated, oracle) in dB, from
# `tools/measure_gains.py --sections compensate`.
MEASURED_ORACLE = {"cubicle": (3.936, 4.030), "tilted": (3.820, 3.887), "pillar": (3.632, 3.717)}


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_calibrated_gain_is_most_of_the_oracle_gain(preset, images):
    """The PSNR gain over geometry only, mean over the photographs, with calibrated kernels and
    with the simulator's true kernels (the oracle), each at least MARGIN of its measured value,
    and the calibrated share of the oracle's gain at least MARGIN of its measured share."""
    gains_cal, gains_oracle = oracle_gains(preset, images)
    g_cal, g_or = float(np.mean(gains_cal)), float(np.mean(gains_oracle))
    m_cal, m_or = MEASURED_ORACLE[preset]
    msg = (f"{preset}: calibrated {g_cal:.2f} dB (measured {m_cal}), oracle {g_or:.2f} dB "
           f"(measured {m_or}); per photo {np.round(gains_cal, 2)} vs {np.round(gains_oracle, 2)}")
    assert g_or >= MARGIN * m_or and g_cal >= MARGIN * m_cal, msg
    assert g_cal / g_or >= MARGIN * m_cal / m_or, msg


def reference_gains(images) -> tuple[float, float]:
    """(reference gain, production gain) in dB over geometry only: the independent reference
    (tests/reference_solver.py: SciPy projected gradient with exact line search, 300
    iterations, to convergence) and the production solve at its default budget, both on the
    true kernels of a 200x150 cubicle whose blur radii (in projector px) match the 400x300
    set-up above."""
    import dataclasses

    from reference_solver import ReferenceSolve

    scene = dataclasses.replace(sim.PRESETS["cubicle"], blur_range_px=(3.0, 12.0))
    procam = sim.VirtualProCam(scene, projector_size=(200, 150), camera_size=(320, 240), seed=3)
    oracle = oracle_calibration(procam)
    image = images["chelsea"]
    geometry = Compensator(oracle, method="none")
    warped = geometry.warp(image)
    mask = rect_mask(geometry.display_rect((image.shape[1], image.shape[0])), (240, 320))
    sharp = procam.capture(warped, sharp=True)
    p0 = psnr(procam.capture(warped), sharp, mask)
    ref = ReferenceSolve(oracle.psfs, oracle.pix_idx, oracle.pix_wts)
    frame, d = ref.compensate(procam.truth.projector_gamma, warped, iterations=300)
    assert np.all(np.diff(d) <= 1e-9 * d[0]), "the reference's exact line search never rises"
    g_ref = psnr(procam.capture(frame), sharp, mask) - p0
    g_prod = psnr(procam.capture(Compensator(oracle).compensate(image)), sharp, mask) - p0
    return float(g_ref), float(g_prod)


# `tools/measure_gains.py --sections reference` (OpenCL on PoCL): reference, production (dB).
MEASURED_REFERENCE = (4.893, 5.021)


def test_solver_reaches_most_of_the_independent_reference_gain(images):
    """The production solve (default budget) on the true kernels keeps at least 85 % of its
    measured gain, and of its measured share of the independent reference's gain (1.03: the
    preconditioned solve ends nearer the optimum in the camera's PSNR); the oracle test above
    then ties the calibrated kernels to the production solve on the true ones."""
    g_ref, g_prod = reference_gains(images)
    m_ref, m_prod = MEASURED_REFERENCE
    assert g_ref >= 0.85 * m_ref, f"the reference itself gains only {g_ref:.2f} dB (measured {m_ref})"
    assert g_prod >= 0.85 * m_prod, f"production {g_prod:.2f} dB < 85 % of its measured {m_prod}"
    assert g_prod / g_ref >= 0.85 * m_prod / m_ref, \
        f"production {g_prod:.2f} dB is {g_prod / g_ref:.3f} of the reference {g_ref:.2f} dB"


def luminance_distance(a: np.ndarray, b: np.ndarray, rect) -> float:
    """Eq. 4 with the default weights between two camera frames inside rect (linear light:
    the simulator's camera gamma is 1)."""
    x, y, w, h = rect
    da = a[y:y + h, x:x + w].astype(np.float64) / 255.0
    db = b[y:y + h, x:x + w].astype(np.float64) / 255.0
    return distance((da - db).transpose(2, 0, 1), Metric.ycbcr(compensator_mod.DEFAULT_WEIGHTS))


def luma(a: np.ndarray) -> np.ndarray:
    """Rec. 601 luma of a camera frame, float in [0, 255]."""
    return a.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


# Luma PSNR of ycbcr minus rgb against the sharp reference, mean over PHOTOS, per preset: an
# independent measure (not Eq. 4, which the YCbCr solve minimises), from this test's own views
# (`tools/measure_gains.py --sections compensate`). Per photo the lead is -0.007 to +0.146 dB
# (astronaut about level).
MEASURED_LUMA_LEAD = {"cubicle": 0.0851, "tilted": 0.0712, "pillar": 0.0418}


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_ycbcr_beats_rgb_in_luma(preset, images):
    """At the same budget the YCbCr solve ends nearer the target under Eq. 4 than the RGB
    least-squares solve, for every photograph, where the solve measures it (projector space,
    F P against I), and in the camera under Eq. 4 over the set of photographs. Scored
    independently of Eq. 4, the camera's luma PSNR against the sharp reference is higher
    with YCbCr, by at least MARGIN of the measured lead over the photographs."""
    procam, calib, comps = setup_for(preset)
    m = Metric.ycbcr(compensator_mod.DEFAULT_WEIGHTS)
    cam = {"ycbcr": 0.0, "rgb": 0.0, "none": 0.0}
    lead = []
    for name in PHOTOS:
        target = decode_lut(comps["none"].warp(images[name]), calib.lut)
        d = {}
        for method in ("ycbcr", "rgb"):
            P, _ = comps[method].solve(target)
            d[method] = distance(blur_forward_filter2d(P, calib.psfs, calib.pix_idx, calib.pix_wts)
                                 - target, m)
        assert d["ycbcr"] < d["rgb"], f"{preset}/{name}: Eq. 4 distance {d}"
        v = camera_views(preset, name, images[name])
        for method in cam:
            cam[method] += luminance_distance(v[method], v["sharp"], v["rect"])
        y = {k: psnr(luma(v[k]), luma(v["sharp"]), v["mask"], data_range=255.0)
             for k in ("ycbcr", "rgb", "none")}
        assert y["rgb"] > y["none"], f"{preset}/{name}: luma PSNR {y}"
        lead.append(y["ycbcr"] - y["rgb"])
    assert cam["ycbcr"] < cam["rgb"] < cam["none"], cam
    need = MARGIN * MEASURED_LUMA_LEAD[preset]
    assert np.mean(lead) > need, (f"{preset}: ycbcr's luma PSNR lead over rgb {np.mean(lead):.3f} "
                                  f"dB < {need:.3f} (per photo {np.round(lead, 3)})")


@pytest.mark.slow
def test_text_slide_sharper_and_headroom_clips_less(images):
    procam, calib, comps = setup_for("cubicle")
    v = camera_views("cubicle", "text", images["text"])
    m = v["mask"]
    assert ssim(v["ycbcr"], v["sharp"], m) > ssim(v["none"], v["sharp"], m) + 0.005
    # Headroom: the target mapped into [0.15, 0.85] leaves the solve room to pre-sharpen, so
    # fewer of its output values sit at the 0 / 1 limits.
    warped = comps["none"].warp(images["text"])
    lit = comps["none"].warp(np.full_like(images["text"], 255)) > 0   # the content area
    clipped = {}
    for headroom in (None, (0.15, 0.85)):
        comp = Compensator(calib, method="ycbcr", headroom=headroom)
        out = comp.compensate_warped(warped)
        clipped[headroom] = float(np.mean((out[lit] == 0) | (out[lit] == 255)))
    assert clipped[(0.15, 0.85)] < 0.5 * clipped[None], clipped


# --------------------------------------------------------------------------- API behaviour
@pytest.fixture(scope="module")
def cubicle():
    procam, calib, _ = setup_for("cubicle")
    return procam, calib


@pytest.mark.slow
def test_warm_start_reuses_the_previous_frame(cubicle, images):
    _, calib = cubicle
    comp = Compensator(calib, iterations=8)
    img = images["coffee"]
    comp.compensate(img)
    cold = comp.last_info
    comp.compensate(img)
    warm = comp.last_info
    assert not cold["warm_start"] and warm["warm_start"]
    assert warm["distances"][0] < 0.8 * cold["distances"][0]
    d = np.array(warm["distances"])
    assert (np.diff(d) <= 1e-6 * d[:-1]).all()
    assert set(warm["seconds"]) >= {"warp", "decode", "solve", "encode", "total"}
    comp.reset()
    comp.compensate(img)
    assert not comp.last_info["warm_start"]



@pytest.mark.slow
@pytest.mark.parametrize("backend", ["opencl", "numpy"])
def test_compensator_spends_its_whole_budget(images, backend):
    """The solve runs the iterations it is given, the constructor's default (40, the budget
    the quality figures are measured at) or a frame's own, and each lowers the distance."""
    procam = sim.VirtualProCam("cubicle", projector_size=(160, 120), camera_size=(240, 180), seed=3)
    comp = Compensator(oracle_calibration(procam), backend=backend)
    assert comp.backend == backend
    for iterations in (None, 7):
        comp.reset()
        comp.compensate(images["chelsea"], iterations=iterations)
        info = comp.last_info
        n = 40 if iterations is None else iterations
        assert comp.iterations == 40 and info["iterations"] == n, (comp.iterations, info["iterations"])
        d = np.asarray(info["distances"])
        assert len(d) == n + 1 and d[-1] < d[n // 2] < d[0], d

@pytest.mark.slow
def test_numpy_and_opencl_backends_agree(cubicle, images, cl_runtime):
    _, calib = cubicle
    warped = Compensator(calib, method="none").warp(images["astronaut"])
    out = {}
    for backend in ("numpy", "opencl"):
        out[backend] = Compensator(calib, backend=backend, iterations=4).compensate_warped(warped)
    diff = np.abs(out["numpy"].astype(int) - out["opencl"].astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3


@pytest.mark.slow
def test_none_is_the_warp_and_solve_stays_in_range(cubicle, images):
    _, calib = cubicle
    img = images["rocket"]
    geo = Compensator(calib, method="none")
    assert np.array_equal(geo.compensate(img), geo.warp(img))
    wp, hp = calib.projector_size
    target = np.random.default_rng(0).random((3, hp, wp)).astype(np.float32)
    for method in ("ycbcr", "wiener"):
        P, info = Compensator(calib, method=method, iterations=3).solve(target)
        assert P.shape == target.shape and P.min() >= 0 and P.max() <= 1
    with pytest.raises(InputError, match=r"\(3, 300, 400\)"):
        Compensator(calib, iterations=1).solve(target[:, :10])


@pytest.mark.slow
def test_missing_psf_section_names_the_fix(cubicle):
    _, calib = cubicle
    from dataclasses import replace

    geometry_only = replace(calib, psf_points_proj=None, psf_plane=None, psfs=None, pix_idx=None,
                            pix_wts=None)
    with pytest.raises(CalibrationFileError, match="psf.*method='none'"):
        Compensator(geometry_only)
    Compensator(geometry_only, method="none")     # geometry only needs no kernels
    with pytest.raises(InputError, match="headroom"):
        Compensator(calib, headroom=(0.9, 0.1))


@pytest.mark.slow
def test_auto_falls_back_to_numpy_with_one_warning(cubicle, monkeypatch, caplog):
    _, calib = cubicle
    import rtdefocus.cl.runtime as clrt

    monkeypatch.setattr(clrt, "opencl_available", lambda: (False, "no platform (test)"))
    monkeypatch.setattr(clrt, "_fallback_warned", set())
    with caplog.at_level(logging.WARNING, logger="rtdefocus.compensate.compensator"):
        a = Compensator(calib, backend="auto", iterations=1)
        b = Compensator(calib, backend="auto", iterations=1)
    assert a.backend == b.backend == "numpy"
    warnings = [r for r in caplog.records if "NumPy" in r.getMessage()]
    assert len(warnings) == 1 and "no platform (test)" in warnings[0].getMessage()
