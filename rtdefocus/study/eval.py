"""``rtdefocus eval``: the ablation run on the virtual set-ups, and the solvers' convergence.

* :func:`run_eval` — presets x images x methods x kernel layouts (plus the oracle kernels,
  :func:`rtdefocus.sim.oracle_calibration`, as the upper bound), scored with
  :func:`rtdefocus.study.scores.score_image`;
* :func:`calibrate_layouts` — one geometry and radiometry, the kernel stage for several layouts
  from shared captures; :func:`mean_gains` — the summary over images;
* :func:`convergence_curves` — distance and camera-view PSNR against iterations and time.

The report (markdown tables, the convergence figure) is written by :mod:`rtdefocus.study.evalreport`.
"""

from __future__ import annotations

import copy
import json
import logging
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .. import sim
from ..calib import calibrate
from ..calib.capture import Capturer
from ..calib.file import json_default
from ..cl.runtime import opencl_available
from ..compensate import Compensator
from ..errors import InputError
from ..sim import oracle_calibration
from .eval_layouts import calibrate_psf_layouts
from .evalreport import eval_markdown, plot_convergence
from .samples import demo_images
from .scores import camera_view, psnr, rect_mask, score_image

log = logging.getLogger(__name__)

__all__ = ["run_eval", "calibrate_layouts", "convergence_curves", "plot_convergence",
           "mean_gains", "eval_markdown", "EVAL_LAYOUTS", "QUICK"]

#: Kernel layouts of the PSF stage (``rtdefocus.calib.psf``) by eval name -> (layout, cross_fold).
EVAL_LAYOUTS = {"default": ("default", False), "paper": ("paper", False),
                "dense": ("dense", False), "cross_fold": ("default", True)}
EVAL_PRESETS = ("cubicle", "tilted", "pillar")
#: Iteration counts at which the convergence run captures the camera view (PSNR).
CHECKPOINTS = (0, 1, 2, 5, 10, 20, 40, 80)
#: The NumPy reference is slow (~8 s per FISTA iteration at 800x600 with the default layout's
#: ~100 kernels, against ~0.03 s on OpenCL/PoCL): its curves stop here (``numpy_iterations``).
NUMPY_ITERATIONS = 2
#: ``rtdefocus eval --quick``: one preset, two images, small sizes, shorter curves.
QUICK = {"presets": ("cubicle",), "images": ("chelsea", "text"), "projector_size": (400, 300),
         "camera_size": (640, 480), "checkpoints": (0, 1, 2, 5, 10, 20, 40), "numpy_iterations": 2}
# Camera px per projector px of the simulator's default sizes (1280x960 for 800x600): the PSF
# stage's measurement relies on ~2.5 camera pixels per projector pixel, so keep the ratio.
_CAMERA_SCALE = 1.6


def _select_images(images) -> dict[str, np.ndarray]:
    """``images``: None (the demo's), a dict name -> RGB uint8, or names among the demo's."""
    if isinstance(images, dict):
        chosen = dict(images)
    else:
        available = demo_images()
        if images is None:
            chosen = available
        else:
            names = [str(n) for n in images]
            unknown = [n for n in names if n not in available]
            if unknown:
                raise InputError(f"unknown image(s) {unknown}; choose among {', '.join(available)} "
                                 "(or pass a dict name -> RGB uint8 array)")
            chosen = {n: available[n] for n in names}
    if not chosen:
        raise InputError("no images to evaluate; pass at least one")
    for name, img in chosen.items():
        img = np.asarray(img)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise InputError(f"image {name!r} must be (H, W, 3) uint8 RGB; got {img.dtype} {img.shape}")
    return chosen


def _check_names(what: str, given, allowed) -> tuple[str, ...]:
    given = tuple(str(g) for g in given)
    bad = [g for g in given if g not in allowed]
    if bad or not given:
        raise InputError(f"{what} must be a non-empty selection of {', '.join(allowed)}; got "
                         f"{', '.join(given) or 'nothing'}")
    return given


def calibrate_layouts(procam, layouts=tuple(EVAL_LAYOUTS), progress=None) -> tuple[dict, dict]:
    """Calibrate geometry and radiometry once, then the kernel stage for several layouts.

    The layouts share one pilot and one set of dot captures
    (:func:`rtdefocus.study.eval_layouts.calibrate_psf_layouts`), each pattern averaged as often as the
    first layout alone would average it, so the layouts are compared on equal noise.

    Parameters
    ----------
    procam : ProCam (e.g. :class:`rtdefocus.sim.VirtualProCam`)
    layouts : names among :data:`EVAL_LAYOUTS` (``"cross_fold"``: the default layout blended
        across the fold, the geometry-blind baseline).
    progress : callable(stage, done, total), optional (per capture).

    Returns
    -------
    calibs : dict layout name -> rtdefocus.Calibration (same geometry and radiometry)
    info : dict with ``captures`` (per stage; the psf captures are shared), ``seconds``,
        ``samples`` (per layout), ``window`` (kernel size per layout).
    """
    layouts = _check_names("layouts", layouts, tuple(EVAL_LAYOUTS))
    t0 = time.perf_counter()
    base = calibrate(procam, stages=("geometry", "radiometry"), progress=progress)
    t1 = time.perf_counter()
    cap = Capturer(procam, progress)
    keys = [EVAL_LAYOUTS[name] for name in layouts]
    measured = calibrate_psf_layouts(copy.deepcopy(base), cap, layouts=keys)
    t2 = time.perf_counter()
    calibs = {name: measured[key] for name, key in zip(layouts, keys, strict=True)}
    info = {
        "captures": dict(base.meta.get("captures", {}), psf=cap.counts.get("psf", 0)),
        "seconds": {"geometry+radiometry": round(t1 - t0, 2), "psf (all layouts)": round(t2 - t1, 2)},
        "samples": {n: int(c.meta["psf"]["samples"]) for n, c in calibs.items()},
        "window": {n: int(c.psfs.shape[1]) for n, c in calibs.items()},
        "averages": int(next(iter(calibs.values())).meta["psf"]["averages"]),
        "geometry": {k: base.meta.get("geometry", {}).get(k) for k in
                     ("n_planes", "rms_px", "fold_disagreement_px", "lines_found", "lines_expected")},
    }
    return calibs, info


def _merge_oracle(scores, oracle_scores) -> None:
    """Fold the oracle's scores into the row: its own geometry-only view is ``none/oracle``."""
    for table in ("psnr", "ssim", "psnr_fold", "clipped", "seconds"):
        dst = getattr(scores, table)
        for key, value in getattr(oracle_scores, table).items():
            dst["none/oracle" if key == "none" else key] = value


def _gain(row: dict, table: str, method: str, layout: str) -> float:
    base = row[table].get("none/oracle" if layout == "oracle" else "none", float("nan"))
    return float(row[table].get(f"{method}/{layout}", float("nan")) - base)


def mean_gains(rows: list[dict], methods, layouts) -> dict:
    """Mean over images of the gain over geometry only, per ``method/layout``.

    Parameters
    ----------
    rows : the ``rows`` of one preset in :func:`run_eval`'s result (``ImageScores`` as dicts,
        keys ``"none"``, ``"none/oracle"`` and ``"method/layout"``).

    Returns
    -------
    dict ``"method/layout"`` -> {``psnr``: dB, ``psnr_fold``: dB (NaN for one plane),
    ``ssim``: SSIM difference}. The oracle is compared with its own geometry-only view.
    """
    out = {}
    for m in methods:
        for lay in layouts:
            g = {}
            for table in ("psnr", "psnr_fold", "ssim"):
                vals = [_gain(r, table, m, lay) for r in rows if r[table]]
                g[table] = float(np.mean(vals)) if vals else float("nan")
            out[f"{m}/{lay}"] = g
    return out


def convergence_curves(procam, calib, image: np.ndarray, *, method: str = "ycbcr",
                       solvers=("fista", "pg"), backends=("opencl", "numpy"),
                       checkpoints=CHECKPOINTS, numpy_iterations: int = NUMPY_ITERATIONS) -> list[dict]:
    """Distance and camera-view PSNR against iterations and solver time, per solver and backend.

    The distance ``d`` comes from the solver's own history (every iteration). The PSNR of the
    camera view (display rect, against the sharp reference) is measured at ``checkpoints``:
    projected gradient is memoryless, so its checkpoints are one warm-started chain of runs;
    FISTA carries momentum that a new run would reset, so each of its checkpoints is a run of
    its own from the cold start (the longest one gives the distance history). Time is the
    solve's own (device-synchronised) time, excluding warp, LUTs and captures; within a run the
    iterations share its time evenly. A first short run per compensator is not timed (program
    build, first-call costs).

    Parameters
    ----------
    procam : the virtual set-up (its ``capture``)
    calib : its calibration (with the PSF section)
    image : (H, W, 3) uint8 RGB
    method : ``"ycbcr"`` | ``"rgb"``
    solvers : among ``"fista"``, ``"pg"``
    backends : among ``"opencl"``, ``"numpy"`` (OpenCL is skipped, logged, without a device)
    checkpoints : iteration counts (0 = geometry only)
    numpy_iterations : the NumPy backend's curves stop at this many iterations (it is slow);
        0 leaves NumPy out.

    Returns
    -------
    list of dict, one per (solver, backend): ``solver``, ``backend``, ``distances`` (d per
    iteration, from 0), ``seconds`` (cumulative solve time at each of them), ``checkpoints``
    (iterations actually run), ``checkpoint_seconds``, ``psnr`` (dB at each checkpoint).
    """
    if method not in ("ycbcr", "rgb"):
        raise InputError(f"convergence needs an iterative method ('ycbcr' or 'rgb'); got {method!r}")
    cps = sorted({int(c) for c in checkpoints} | {0})
    if cps[0] < 0:
        raise InputError(f"checkpoints must be iteration counts >= 0; got {checkpoints}")
    h, w = image.shape[:2]
    wc, hc = calib.camera_size
    mask = rect_mask(calib.display_rect((w, h)), (hc, wc))
    warped = Compensator(calib, method="none").warp(image)
    reference = camera_view(procam, calib, warped, sharp=True)

    def score(frame: np.ndarray) -> float:
        return psnr(camera_view(procam, calib, frame), reference, mask)

    curves = []
    for backend in backends:
        if backend == "opencl" and not opencl_available()[0]:
            log.warning("convergence: no OpenCL device, the OpenCL curves are left out (%s)",
                        opencl_available()[1])
            continue
        limit = numpy_iterations if backend == "numpy" else cps[-1]
        if limit <= 0:
            continue
        these = [c for c in cps if c <= limit]
        for solver in solvers:
            comp = Compensator(calib, backend=backend, method=method, solver=solver)
            if backend == "opencl":       # untimed warm-up: program build, first-call costs
                comp.compensate_warped(warped, iterations=2, warm_start=False)
            curve = {"solver": solver, "backend": backend, "method": method, "distances": [],
                     "seconds": [], "checkpoints": [], "checkpoint_seconds": [], "psnr": []}
            if solver == "pg":
                _chained_curve(comp, warped, these, score, curve)
            else:
                _restarted_curve(comp, warped, these, score, curve)
            log.info("convergence %s/%s: %d iterations in %.2f s, d %.4g -> %.4g, PSNR %.2f -> "
                     "%.2f dB", solver, backend, curve["checkpoints"][-1], curve["seconds"][-1],
                     curve["distances"][0], curve["distances"][-1], curve["psnr"][0],
                     curve["psnr"][-1])
            curves.append(curve)
    return curves


def _spread(t_start: float, seconds: float, n: int) -> list[float]:
    """Cumulative times of ``n`` iterations sharing ``seconds`` evenly after ``t_start``."""
    return [t_start + seconds * (i + 1) / n for i in range(n)] if n else []


def _chained_curve(comp, warped, checkpoints, score, curve) -> None:
    """Warm-started runs from checkpoint to checkpoint (exact for a memoryless solver)."""
    done, t = 0, 0.0
    for n in checkpoints:
        first = not curve["checkpoints"]
        asked = n - done
        frame = comp.compensate_warped(warped, iterations=asked, warm_start=not first)
        info = comp.last_info
        d = info["distances"]
        run = int(info["iterations"])
        secs = info["seconds"]["solve"] if run else 0.0
        # Each run starts by re-evaluating d at its starting P: the last value of the run before it.
        curve["distances"] += d if first else d[1:]
        curve["seconds"] += ([0.0] if first else []) + _spread(t, secs, len(d) - 1)
        done += run
        t += secs
        curve["checkpoints"].append(done)
        curve["checkpoint_seconds"].append(t)
        curve["psnr"].append(score(frame))
        if run < asked:                       # stopped early (a KKT point): nothing more to gain
            break


def _restarted_curve(comp, warped, checkpoints, score, curve) -> None:
    """One cold-started run per checkpoint (FISTA's momentum makes a chain a different method)."""
    for n in checkpoints:
        frame = comp.compensate_warped(warped, iterations=n, warm_start=False)
        info = comp.last_info
        secs = info["seconds"]["solve"] if n else 0.0
        curve["checkpoints"].append(int(info["iterations"]))
        curve["checkpoint_seconds"].append(secs)
        curve["psnr"].append(score(frame))
        if n == checkpoints[-1]:
            d = info["distances"]
            curve["distances"] = list(d)
            curve["seconds"] = [0.0] + _spread(0.0, secs, len(d) - 1)


def run_eval(out_dir: str | Path = "eval_out", *, presets=EVAL_PRESETS, images=None,
             methods=("ycbcr", "rgb", "wiener"), layouts=tuple(EVAL_LAYOUTS), oracle: bool = True,
             projector_size: tuple[int, int] | None = None,
             camera_size: tuple[int, int] | None = None, seed: int = 0,
             convergence: tuple[str, str] | None = ("cubicle", "chelsea"),
             checkpoints=CHECKPOINTS, numpy_iterations: int = NUMPY_ITERATIONS,
             fold_band_px: float = 24.0, progress=None, step=None) -> dict:
    """Evaluate compensation over presets x images x methods x kernel layouts.

    Per preset: geometry and radiometry are calibrated once, the kernel stage once for all
    ``layouts`` (:func:`calibrate_layouts`: shared captures); with ``oracle`` the simulator's
    true calibration (:func:`rtdefocus.sim.oracle_calibration`) is added as the upper bound.
    Each image is projected every way and scored (:func:`rtdefocus.study.scores.score_image`): PSNR
    and SSIM of the camera view against the sharp reference over the display rect, PSNR over
    the band near the fold. Writes ``eval.md``, ``eval.json`` and (with ``convergence``)
    ``convergence.png`` into ``out_dir``.

    Parameters
    ----------
    out_dir : output folder (created).
    presets : simulator presets (:data:`rtdefocus.sim.PRESETS`).
    images : None (:func:`rtdefocus.study.samples.demo_images`: four photographs and a text slide),
        names among those, or a dict name -> (H, W, 3) uint8 RGB.
    methods : among ``"ycbcr"``, ``"rgb"``, ``"wiener"`` (geometry only is always scored).
    layouts : among :data:`EVAL_LAYOUTS`.
    oracle : also score the oracle calibration.
    projector_size, camera_size : (width, height); None: the simulator's defaults (with only
        ``projector_size`` given, the camera gets 1.6x it, the simulator's default ratio).
    seed : simulator noise seed.
    convergence : (preset, image) of the convergence plot, or None for none. The preset's
        calibrated default layout (else its first layout) is used; a preset or image not in the
        run falls back to the first one evaluated.
    checkpoints, numpy_iterations : see :func:`convergence_curves`.
    fold_band_px : half-width of the near-fold band (camera px).
    progress : callable(stage, done, total), per calibration capture.
    step : callable(message), before each long step (the CLI prints them).

    Returns
    -------
    dict with ``settings``, ``presets`` (per preset: ``calibration`` info, ``rows`` — one
    :class:`rtdefocus.study.scores.ImageScores` dict per image, score keys ``"none"``, ``"none/oracle"``
    and ``"method/layout"`` — and ``gains`` from :func:`mean_gains`), ``convergence`` (curves),
    ``seconds``, ``files`` and ``markdown``.
    """
    say = step or (lambda msg: log.info(msg))
    t_start = time.perf_counter()
    presets = _check_names("presets", presets, tuple(sim.PRESETS))
    methods = _check_names("methods", methods, ("ycbcr", "rgb", "wiener"))
    layouts = _check_names("layouts", layouts, tuple(EVAL_LAYOUTS))
    imgs = _select_images(images)
    procam_options: dict = {"seed": seed}
    if projector_size is not None:
        procam_options["projector_size"] = tuple(int(v) for v in projector_size)
        if camera_size is None:
            camera_size = tuple(round(_CAMERA_SCALE * int(v)) for v in projector_size)
    if camera_size is not None:
        procam_options["camera_size"] = tuple(int(v) for v in camera_size)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scored = list(layouts) + (["oracle"] if oracle else [])
    conv_preset = conv_image = None
    if convergence is not None:
        conv_preset = convergence[0] if convergence[0] in presets else presets[0]
        conv_image = convergence[1] if convergence[1] in imgs else next(iter(imgs))

    result: dict = {"presets": {}, "convergence": None}
    backend = None
    for pi, preset in enumerate(presets, 1):
        say(f"[{preset} {pi}/{len(presets)}] calibrating geometry and radiometry once, then the "
            f"kernels for {', '.join(layouts)} from one set of captures")
        procam = sim.VirtualProCam(preset, **procam_options)
        calibs, cal_info = calibrate_layouts(procam, layouts, progress=progress)
        comps = {f"{m}/{lay}": Compensator(calib, method=m)
                 for lay, calib in calibs.items() for m in methods}
        # Ours first: score_image counts edge pixels for its first compensator without "ycbcr".
        comps = dict(sorted(comps.items(), key=lambda kv: kv[0].split("/")[0] != "ycbcr"))
        backend = next(iter(comps.values())).backend
        oracle_comps = {}
        if oracle:
            o_calib = oracle_calibration(procam)
            oracle_comps = {f"{m}/oracle": Compensator(o_calib, method=m) for m in methods}
        rows = []
        for ii, (name, image) in enumerate(imgs.items(), 1):
            say(f"[{preset} {pi}/{len(presets)}] image {ii}/{len(imgs)} {name}: "
                f"{len(comps) + len(oracle_comps)} compensations")
            # The layouts share one geometry, so one sharp reference and one geometry-only view
            # serve them all: one score_image call with a column per method/layout.
            scores, _ = score_image(procam, next(iter(calibs.values())), comps, name, image,
                                    fold_band_px=fold_band_px)
            if oracle:
                o_scores, _ = score_image(procam, o_calib, oracle_comps, name, image,
                                          fold_band_px=fold_band_px)
                _merge_oracle(scores, o_scores)
            rows.append(asdict(scores))
        result["presets"][preset] = {"calibration": cal_info, "rows": rows,
                                     "gains": mean_gains(rows, methods, scored)}
        if preset == conv_preset:
            lay = "default" if "default" in calibs else next(iter(calibs))
            say(f"[{preset}] convergence on {conv_image} (layout {lay}): FISTA and PG, "
                "OpenCL and NumPy")
            curves = convergence_curves(procam, calibs[lay], imgs[conv_image],
                                        checkpoints=checkpoints, numpy_iterations=numpy_iterations)
            result["convergence"] = {"preset": preset, "image": conv_image, "layout": lay,
                                     "method": "ycbcr", "curves": curves}
        del comps, oracle_comps                       # free the device buffers before the next preset

    ok, device = opencl_available()
    device = device if ok else "none"
    files = []
    if result["convergence"] is not None:
        c = result["convergence"]
        files.append(plot_convergence(
            c["curves"], out / "convergence.png",
            title=f"convergence on {c['preset']} / {c['image']}, method {c['method']}, projector "
                  f"{procam.projector_size[0]}x{procam.projector_size[1]}\nOpenCL device: {device}"))
    result["settings"] = {
        "presets": list(presets), "images": list(imgs), "methods": list(methods),
        "layouts": list(layouts), "layouts_scored": scored, "oracle": bool(oracle),
        "projector_size": "x".join(map(str, procam.projector_size)),
        "camera_size": "x".join(map(str, procam.camera_size)), "seed": seed, "backend": backend,
        "opencl_device": device,
        "fold_band_px": fold_band_px, "checkpoints": list(checkpoints),
        "numpy_iterations": numpy_iterations,
    }
    result["seconds"] = round(time.perf_counter() - t_start, 1)
    md = eval_markdown(result)
    (out / "eval.md").write_text(md)
    (out / "eval.json").write_text(json.dumps(result, indent=1, default=json_default))
    result["files"] = [str(out / "eval.md"), str(out / "eval.json")] + [str(f) for f in files]
    result["markdown"] = md
    return result
