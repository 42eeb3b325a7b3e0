#!/usr/bin/env python
"""Measure the compensation gains the quality tests guard, in the tests' own settings, so that
their thresholds can be set from measurement with a stated margin.

Sections (``--sections``, comma-separated):

``compensate``  tests/test_compensate.py: presets cubicle/tilted/pillar at 400x300 (camera
                640x480, seed 3), the four photographs; PSNR/SSIM gain of ``ycbcr`` over geometry
                only over the display rect and in the 16-px band either side of the fold.
``reference``   tests/test_compensate.py: the production solve against the independent reference.
``eval``        ``rtdefocus eval --quick`` (as tests/test_eval.py runs it): gains per row.
``demo``        the demo at 400x300 (as tests/test_demo.py runs it): the chelsea row.
``webcam``      tests/test_webcam.py's calibration on the webcam preset with a triangle
                aperture: lens, camera response, gamma, fold, checkerboard, kernels, gain.
``radiometry``  tests/test_radiometry.py: albedo and gamma through a barrel lens, fabric walls.
``geometry``    tests/test_geometry.py: fold, held-out points and checkerboard per preset.
``video``       tests/test_eval_video.py: the quick moving clip, fixed budgets and the ceiling.
``psf``         tests/test_psf.py: median kernel errors per preset and layout.
``rooms``       tests/test_rooms_e2e.py: the three-plane rooms' figures.
``surface``     tests/test_surface.py: flatten's grey field and photograph on the fabric walls.
``field``       tests/test_psf.py: the kernel field's largest step between neighbouring pixels.
``walls``       tests/test_geometry_walls.py: the nearly-flat walls' model, fold, checkerboard.
``watch``       tests/test_watch_residual.py: the residual report's errors per change.
``watcher``     tests/test_watcher.py: what each mend from the content leaves against the oracle.
``render``      tests/test_render.py: the chunked render off the serial one, the codec's loss.
``dots``        tests/test_psf_external.py: another rig's dots against the PSF stage's own.
``clipping``    tests/test_clipping.py: kernels and albedo of cameras that clip.
``correspondences``  tests/test_captureset.py: the geometry from a dense correspondence map.
``dense``       tests/test_geometry_dense.py: the dense decoder, the gap's mask, a given lens.
``lenscli``     tests/test_calibrate_walls_cli.py: ``--lens-from`` and the far-wall warning.

Example::

    .venv/bin/python tools/measure_gains.py --sections compensate,eval,demo

Prints one line per measurement; the tests quote these numbers next to their thresholds.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def section_compensate() -> None:
    import test_compensate as tc

    images = tc.photographs()
    for preset in tc.PRESETS:
        for name in tc.PHOTOS:
            v = tc.camera_views(preset, name, images[name])
            row = []
            for region in ("mask", "band"):
                m = v[region]
                dp = tc.psnr(v["ycbcr"], v["sharp"], m) - tc.psnr(v["none"], v["sharp"], m)
                ds = tc.ssim(v["ycbcr"], v["sharp"], m) - tc.ssim(v["none"], v["sharp"], m)
                row.append(f"{region}: {dp:+.2f} dB  SSIM {ds:+.4f}")
            print(f"compensate {preset:8s} {name:10s} " + "   ".join(row), flush=True)
        # test_calibrated_gain_is_most_of_the_oracle_gain and test_ycbcr_beats_rgb_in_luma
        cal, orc = tc.oracle_gains(preset, images)
        lead = []
        for name in tc.PHOTOS:
            v = tc.camera_views(preset, name, images[name])
            y = {k: tc.psnr(tc.luma(v[k]), tc.luma(v["sharp"]), v["mask"], data_range=255.0)
                 for k in ("ycbcr", "rgb")}
            lead.append(y["ycbcr"] - y["rgb"])
        print(f"compensate {preset:8s} oracle gain {np.mean(orc):.3f} dB  calibrated "
              f"{np.mean(cal):.3f} dB  share {np.mean(cal) / np.mean(orc):.4f}  luma lead of "
              f"ycbcr over rgb {np.mean(lead):.4f} dB (per photo {np.round(lead, 3)})", flush=True)


def section_reference() -> None:
    """tests/test_compensate.py's independent reference solve against the production one."""
    import test_compensate as tc

    g_ref, g_prod = tc.reference_gains(tc.photographs())
    print(f"reference {g_ref:.3f} dB  production {g_prod:.3f} dB  share {g_prod / g_ref:.4f}",
          flush=True)


def section_eval() -> None:
    from rtdefocus import cli

    with tempfile.TemporaryDirectory() as out:
        cli.main(["-q", "eval", "--quick", "-o", out, "--methods", "ycbcr,wiener",
                  "--layouts", "default,cross_fold", "--numpy-iterations", "1"])
        result = json.loads((Path(out) / "eval.json").read_text())
    for r in result["presets"]["cubicle"]["rows"]:
        print(f"eval {r['name']:8s} PSNR gain {r['psnr']['ycbcr/default'] - r['psnr']['none']:+.2f}"
              f" dB  SSIM gain {r['ssim']['ycbcr/default'] - r['ssim']['none']:+.4f}")
    print("eval gains", json.dumps(result["presets"]["cubicle"]["gains"]))


def section_demo() -> None:
    from rtdefocus.study.demo import run_demo
    from rtdefocus.study.samples import demo_images

    images = demo_images()
    with tempfile.TemporaryDirectory() as out:
        result = run_demo(out, images={k: images[k] for k in ("chelsea", "text")},
                          methods=("ycbcr", "wiener"), projector_size=(400, 300),
                          camera_size=(640, 480), rooms=("corner_ceiling",))
    for r in result["rows"]:
        print(f"demo {r['name']:16s} PSNR gain {r['psnr']['ycbcr'] - r['psnr']['none']:+.2f} dB"
              f"  SSIM gain {r['ssim']['ycbcr'] - r['ssim']['none']:+.4f}  edges "
              f"{r['edges_output']}")
    for r in result["rooms"]["corner_ceiling"]["rows"]:
        print(f"demo corner_ceiling {r['name']:16s} PSNR gain "
              f"{r['psnr']['ycbcr'] - r['psnr']['none']:+.2f} dB, within 24 px of a fold "
              f"{r['psnr_fold']['ycbcr'] - r['psnr_fold']['none']:+.2f} dB", flush=True)


def section_webcam() -> None:
    """tests/test_webcam.py's end-to-end calibration (webcam preset, triangle aperture)."""
    import test_webcam as tw
    from setup_figures import figures

    from rtdefocus.study.samples import photographs

    pc, calib = tw._webcam_calibration()
    photos = photographs()
    f = figures(pc, calib, {k: photos[k] for k in ("chelsea", "coffee")})
    print("webcam " + "  ".join(f"{k} {v:.6g}" if isinstance(v, float) else f"{k} {v}"
                                for k, v in f.items()), flush=True)


def section_radiometry() -> None:
    """tests/test_radiometry.py's lens test: the radiometry stage on the webcam preset with the
    fabric walls, reading its frames through the lens (and, for contrast, as if it were ideal)."""
    from calib_presets import truth_geometry
    from helpers import Blind

    from rtdefocus import sim
    from rtdefocus.calib.capture import Capturer
    from rtdefocus.calib.radiometry import calibrate_radiometry

    for lens in (True, False):
        pc = sim.VirtualProCam("webcam", texture="fabric", projector_size=(320, 240),
                               camera_size=(480, 360))
        calib = truth_geometry(pc)
        if not lens:
            calib.camera_distortion = np.zeros(2)
        out = calibrate_radiometry(calib, Capturer(Blind(pc)))
        t = pc.truth
        r = int(np.ceil(t.radius_map.max())) + 2
        m = np.zeros(t.radius_map.shape, bool)
        m[r:-r, r:-r] = True
        rel = (np.abs(out.albedo_proj - t.albedo_proj) / t.albedo_proj)[m]
        print(f"radiometry {'lens' if lens else 'no lens':8s} albedo median {np.median(rel):.4f}"
              f"  p99 {np.percentile(rel, 99):.4f}  gamma {np.round(out.meta['radiometry']['gamma'], 4)}",
              flush=True)


def section_geometry() -> None:
    """tests/test_geometry.py: each preset calibrated as its fixture does, against the truth."""
    import test_geometry as tg
    from helpers import Blind

    import rtdefocus as rd
    from rtdefocus import sim

    for preset in tg.PRESETS:
        pc = sim.VirtualProCam(preset)
        calib = rd.calibrate(Blind(pc), stages=("geometry",))
        fold, held = tg.truth_figures(pc, calib)
        rms, bend = tg.checker_figures(pc, calib)
        print(f"geometry {preset:10s} fold {'-' if fold is None else f'{fold:.4f}'} px  held-out "
              f"{held:.4f} px  checkerboard {rms:.4f} px  bend {bend:.4f} px", flush=True)


def section_video() -> None:
    """tests/test_eval_video.py's quick run: per segment, the gain of the deterministic modes
    (fixed budgets and the offline ceiling) and the warm start's share of the offline gain."""
    from rtdefocus import cli

    with tempfile.TemporaryDirectory() as out:
        cli.main(["-q", "eval", "--video", "--quick", "-o", out, "--budgets", "1", "--fps", "30"])
        summ = json.loads((Path(out) / "video.json").read_text())["summary"]
    for mode in ("warm-1", "cold-1", "offline"):
        print(f"video {mode:8s} gain " + json.dumps({k: round(v, 3) for k, v in summ[mode]["gain"].items()})
              + ("" if mode == "offline" else "  share " + json.dumps(
                  {k: round(v, 3) for k, v in summ[mode]["share"].items()})), flush=True)


def section_psf() -> None:
    """tests/test_psf.py: median kernel errors inside the planes and near the fold per preset
    and layout (the calibrations of tests/calib_presets.py)."""
    import test_psf as tp

    for preset in tp.PRESETS:
        for key in (tp.DEFAULT, tp.PAPER, tp.BLIND):
            ei, en = tp._errors(preset, key)
            print(f"psf {preset:8s} {key[0]}{'+cross' if key[1] else '':6s} inside "
                  f"{np.median(ei):.4f}  near the fold {np.median(en):.4f}", flush=True)


def section_rooms() -> None:
    """tests/test_rooms_e2e.py: the three-plane rooms calibrated end to end, their figures."""
    import test_rooms_e2e as tr

    for preset in tr.ROOMS:
        _, _, f, seconds = tr._room(preset)
        print(f"rooms {preset:15s} " + "  ".join(
            f"{k} {v:.4g}" for k, v in f.items() if isinstance(v, float)), flush=True)


def section_surface() -> None:
    """tests/test_surface.py: flatten's grey-field CoV and its photograph against a white wall."""
    import cv2
    import test_surface as ts
    from skimage import data

    import rtdefocus as rd

    cam = rd.sim.VirtualProCam("fabric", projector_size=(240, 180), camera_size=(320, 240))
    calib = rd.sim.oracle_calibration(cam)
    grey = np.full((90, 120, 3), 128, np.uint8)
    mask = ts._inset(calib, (120, 90))
    cov = {s: ts.coefficient_of_variation(cam.capture(rd.Compensator(
        calib, backend="numpy", surface=s).compensate(grey)), mask) for s in ("keep", "flatten")}
    img = data.chelsea()
    x, y, w, h = calib.display_rect(img.shape[1::-1])
    wc, hc = calib.camera_size
    white = np.zeros((hc, wc, 3), np.uint8)
    white[y:y + h, x:x + w] = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    m = ts._inset(calib, img.shape[1::-1])
    p = {s: ts.psnr_affine(cam.capture(rd.Compensator(calib, backend="numpy", surface=s,
                                                      iterations=20).compensate(img)), white, m)
         for s in ("keep", "flatten")}
    print(f"surface grey CoV keep {cov['keep']:.4f} flatten {cov['flatten']:.4f} (factor "
          f"{cov['keep'] / cov['flatten']:.3f}); chelsea vs a white wall {p['keep']:.2f} -> "
          f"{p['flatten']:.2f} dB ({p['flatten'] - p['keep']:+.3f})", flush=True)


def section_field() -> None:
    """tests/test_psf.py's kernel-field continuity: the largest blend step between neighbours."""
    import test_psf as tp
    from calib_presets import calibrated

    for key in (tp.DEFAULT, tp.PAPER):
        print(f"field {key[0]:8s} largest step {tp._field_jump(calibrated('tilted').variants[key]):.4f}",
              flush=True)


def section_walls() -> None:
    """tests/test_geometry_walls.py: the nearly-flat walls (bowed, sagging) and the flat
    cubicle through the geometry stage, against the simulator's exact map."""
    import test_geometry_walls as tw
    from setup_figures import fold_error, homography_rms

    for preset in ("bowed", "sagging"):
        calib, truth = tw.geometry(preset), tw.procam(preset).truth
        rms, bend = tw.checker(preset, calib)
        print(f"walls {preset:8s} model {homography_rms(calib, truth):.4f} px  fold "
              f"{fold_error(calib, truth):.4f} px  checkerboard {rms:.4f} px  bend {bend:.4f} px"
              f"  residual max {max(calib.meta['geometry']['residual']['max_px']):.3f} px",
              flush=True)
    flat, truth = tw.geometry("bowed", residual=False), tw.procam("bowed").truth
    print(f"walls bowed without the residual: model {homography_rms(flat, truth):.4f} px  "
          f"checkerboard {tw.checker('bowed', flat)[0]:.4f} px", flush=True)
    forced, calib = tw.geometry("sagging", planes=2), tw.geometry("sagging")
    print(f"walls sagging planes=2 vs found: {tw.map_difference(forced, calib):.4f} px", flush=True)
    calib, flat = tw.geometry("cubicle"), tw.geometry("cubicle", residual=False)
    res = calib.meta["geometry"]["residual"]
    print(f"walls cubicle flat-fit rms {max(res['rms_px_flat']):.4f} px  checkerboard with / "
          f"without the residual {tw.checker('cubicle', calib)[0]:.6f} / "
          f"{tw.checker('cubicle', flat)[0]:.6f} px", flush=True)
    import test_sim_walls as ts

    for preset in ("bowed", "sagging"):
        err, h_err, bent = ts.spots_against_the_maps(preset)
        print(f"walls sim {preset:8s} spots off the exact map: median {np.median(err):.4f} max "
              f"{err.max():.4f} px; off the homography where bent, less the exact map's: min "
              f"{(h_err[bent] - err[bent]).min():.4f} px", flush=True)
    seen, extended = ts.gap_spots()
    kernel = ts.gap_oracle_kernel_errors()
    print(f"walls sim gap: far-wall spots off the exact map max {seen.max():.4f} px, off the "
          f"extended plane min {extended.min():.3f} px ({extended.min() / seen.max():.1f}x); "
          f"oracle kernels off the truth max {kernel.max():.4f}", flush=True)


def section_watch() -> None:
    """tests/test_watch_residual.py: the residual report's errors against the virtual set-up's
    changes (its own settings: 320x240, the oracle calibration, smooth content)."""
    import math

    import test_watch_residual as tw

    from rtdefocus.watch import residual_report

    for preset in ("cubicle", "webcam_cubicle"):
        pc, calib, frame = tw.setup(preset)
        r = residual_report(calib, frame, pc.capture(frame))
        print(f"watch {preset:15s} unchanged: gain {abs(r.gain - 1):.4f} off, ambient "
              f"{abs(r.ambient_added):.5f}, shift {np.abs(r.shifts_proj).max():.4f} px, rms "
              f"{r.rms_before / pc.noise:.3f} x noise, watched {r.watched / (320 * 240):.3f}",
              flush=True)
        gamma0 = pc.truth.ambient_proj.copy()
        pc.set_light(ambient=pc.ambient + 0.1)
        r = residual_report(calib, frame, pc.capture(frame))
        added = float((pc.truth.ambient_proj - gamma0).mean())
        print(f"watch {preset:15s} light: ambient {abs(r.ambient_added / added - 1):.4f} rel off,"
              f" gain {abs(r.gain - 1):.4f} off, shift {np.abs(r.shifts_proj).max():.4f} px, "
              f"rms after / before {r.rms_after / r.rms_before:.4f}", flush=True)
    for preset in ("cubicle", "webcam_cubicle", "fabric"):
        pc, calib, frame = tw.setup(preset)
        pc.bump(projector_shift_px=3.0)
        r = residual_report(calib, frame, pc.capture(frame))
        nominal = max(np.abs(r.shifts_proj[p] - [3.0, 0.0]).max() for p in range(calib.n_planes))
        true = max(np.abs(r.shifts_proj[p] - tw.true_motion(calib, pc, p)).max()
                   for p in range(calib.n_planes))
        print(f"watch {preset:15s} projector shift: off nominal {nominal:.4f} px, off true "
              f"{true:.4f} px, ambient {abs(r.ambient_added):.5f}, gain {abs(r.gain - 1):.4f} off",
              flush=True)
    pc, calib, frame = tw.setup("cubicle")
    pc.bump(projector_yaw_deg=0.3)
    r = residual_report(calib, frame, pc.capture(frame))
    nom = pc.K_proj[0, 0] * math.tan(math.radians(0.3))
    nominal = max(np.abs(r.shifts_proj[p] - [nom, 0.0]).max() for p in range(calib.n_planes))
    true = max(np.abs(r.shifts_proj[p] - tw.true_motion(calib, pc, p)).max()
               for p in range(calib.n_planes))
    print(f"watch cubicle         projector turn: off nominal {nominal:.4f} px, off true "
          f"{true:.4f} px", flush=True)
    pc, calib, frame = tw.setup("webcam_cubicle", detail_px=1.5)
    base = residual_report(calib, frame, pc.capture(frame)).band_ratio
    pc.set_light(ambient=pc.ambient + 0.1)
    lit = residual_report(calib, frame, pc.capture(frame)).band_ratio
    pc.refocus(1.15)
    blurred = residual_report(calib, frame, pc.capture(frame)).band_ratio
    print(f"watch webcam_cubicle   band ratio: light {abs(lit / base - 1):.4f} rel off, blur "
          f"{1 - blurred / base:.4f} lower", flush=True)
    for preset in ("cubicle", "webcam_cubicle"):
        pc, calib, frame = tw.setup(preset)
        pc.bump(camera_shift_px=(4.0, 0.0))
        r = residual_report(calib, frame, pc.capture(frame))
        true = max(np.abs(r.shifts_proj[p] - tw.true_motion(calib, pc, p)).max()
                   for p in range(calib.n_planes))
        print(f"watch {preset:15s} camera shift: off true {true:.4f} px", flush=True)


def section_render() -> None:
    """tests/test_render.py: the chunked lossless render against the serial compensation, and
    the default quality's codec loss, in the camera's view."""
    import test_render as tr

    with tempfile.TemporaryDirectory() as root:
        film = tr.make_film(Path(root))
        _, frames = tr.render_archive(film)
        off, gain = tr.archive_figures(film, frames)
        print(f"render archive: worst {off.max():.4f} dB off serial, gain over geometry only "
              f"min {gain.min():.3f} dB", flush=True)
    with tempfile.TemporaryDirectory() as root:
        db, _, _ = tr.default_quality_views(Path(root))
        print("render default quality: codec loss " + " ".join(
            f"{d['exact'] - d['coded']:.4f}" for d in db) + " dB; coded over geometry only "
            + " ".join(f"{d['coded'] - d['geometry']:.3f}" for d in db) + " dB", flush=True)


def _print(section: str, name: str, figures: dict) -> None:
    print(f"{section} {name:14s} " + "  ".join(
        f"{k} {v:.4g}" for k, v in figures.items() if isinstance(v, (float, int))), flush=True)


def section_dots() -> None:
    """tests/test_psf_external.py: another rig's dots through calibrate_psf_from_dots against
    the PSF stage's own, on the small cubicle of the session fixture."""
    import test_psf_external as te
    from helpers import small_cubicle_run

    with tempfile.TemporaryDirectory() as root:
        procam, calib, _ = small_cubicle_run(Path(root) / "captures")
        _print("dots", "cubicle", te.dot_figures(procam, calib, Path(root)))


def section_clipping() -> None:
    """tests/test_clipping.py: kernels of the clipping run and the plain cubicle, the albedo
    filled where white clips, the PSF stage on a camera whose red channel clips."""
    import test_clipping as tc
    from helpers import small_cubicle_run
    from setup_figures import kernel_medians

    with tempfile.TemporaryDirectory() as root:
        procam, calib, _ = tc.clipping_run(Path(root) / "clip")
        plain, pcal, _ = small_cubicle_run(Path(root) / "plain")
        _print("clipping", "kernels", {"clipped": kernel_medians(calib, procam.truth)[0],
                                       "unclipped": kernel_medians(pcal, plain.truth)[0],
                                       "lowered": calib.meta["radiometry"]["exposure_lowered"]})
    err, _ = tc.albedo_fill_errors()
    _print("clipping", "albedo", {"albedo_median": float(np.median(err)),
                                  "albedo_max": float(err.max()), "pixels": len(err)})
    red, ref = tc.red_hot_errors()
    _print("clipping", "red hot", {"red_hot": red, "red_hot_plain": ref})


def section_correspondences() -> None:
    """tests/test_captureset.py: calibrate_from_correspondences on the simulator's own map."""
    import test_captureset as tc

    err, _ = tc.correspondence_errors(*tc.true_cubicle_map())
    _print("correspondences", "cubicle", {"rms": float(np.sqrt(np.mean(err ** 2))),
                                          "max": float(err.max())})


def section_dense() -> None:
    """tests/test_geometry_dense.py: the dense decoder, a misread bit, the gap's far wall,
    sagging dense against crossings, a given lens against a guessed one."""
    import test_geometry_dense as td
    from setup_figures import homography_rms

    _print("dense", "decode", td.decode_figures(td.decode_map()))
    _print("dense", "misread", td.misread_figures())
    _print("dense", "gap", td.gap_figures(*td.geometry("gap", dense=True)))
    pc, dense = td.geometry("sagging", dense=True)
    _print("dense", "sagging", {"dense": homography_rms(dense, pc.truth),
                                "lines": homography_rms(td.geometry("sagging", False)[1], pc.truth)})
    pc, given, guessed = td.given_lens_runs()
    _print("dense", "lens", {"given": homography_rms(given, pc.truth),
                             "guessed": homography_rms(guessed, pc.truth)})


def section_watcher() -> None:
    """tests/test_watcher.py: each change mended from the content, against the oracle."""
    import test_watcher as tw

    for preset, name in tw.MEASURED:
        print(f"watcher {preset} {name}: {tw.mend_figure(preset, name):.4f}", flush=True)


def section_lenscli() -> None:
    """tests/test_calibrate_walls_cli.py: webcam_sagging's checkerboard with the lens of a
    flat-wall calibration and with its own guess; the far-wall warning's box on gap."""
    import test_calibrate_walls_cli as tw

    _print("lenscli", "lens_from", tw.measure_lens_from())
    _print("lenscli", "far wall", tw.measure_far_wall())


SECTIONS = {"compensate": section_compensate, "eval": section_eval, "demo": section_demo,
            "webcam": section_webcam, "reference": section_reference, "field": section_field,
            "radiometry": section_radiometry, "geometry": section_geometry,
            "video": section_video, "psf": section_psf, "rooms": section_rooms,
            "surface": section_surface, "walls": section_walls, "watch": section_watch,
            "render": section_render, "dots": section_dots, "clipping": section_clipping,
            "correspondences": section_correspondences, "dense": section_dense,
            "lenscli": section_lenscli, "watcher": section_watcher}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sections", default="compensate,eval,demo")
    args = p.parse_args(argv)
    for name in args.sections.split(","):
        t0 = time.perf_counter()
        SECTIONS[name]()
        print(f"[{name}: {time.perf_counter() - t0:.0f} s]", flush=True)
    return 0


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    raise SystemExit(main())
