"""Evaluation helpers: image scores, the near-fold band, and an oracle calibration.

* :func:`psnr`, :func:`ssim` — scores of a camera view against a reference, optionally inside a
  mask (e.g. the display rectangle, or the band around the fold);
* :func:`near_fold_mask` — the pixels within a distance of a fold line;
* :func:`oracle_calibration` — a :class:`rtdefocus.Calibration` built from the simulator's
  ground truth (tests and benchmarks only): what a perfect calibration would measure, so that
  compensation can be judged apart from calibration errors;
* :func:`run_eval` — ``rtdefocus eval``: presets x images x methods x kernel layouts (and the
  oracle), scored with :func:`rtdefocus.demo.score_image`, with :func:`convergence_curves`
  plotted by :func:`plot_convergence`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .errors import InputError, RtDefocusError

log = logging.getLogger(__name__)

__all__ = ["psnr", "ssim", "near_fold_mask", "rect_mask", "oracle_calibration", "text_slide",
           "photographs"]


def text_slide(size: tuple[int, int] = (640, 480)) -> np.ndarray:
    """A slide of black text on white: (h, w, 3) uint8 for ``size = (w, h)``.

    Several lines of decreasing size (the smallest strokes are 1–2 px wide): the hardest case
    for compensation, with no room above white or below black to pre-sharpen into.
    """
    import cv2

    w, h = int(size[0]), int(size[1])
    img = np.full((h, w, 3), 255, np.uint8)
    # (text, stroke thickness at 640 px width); each line is scaled to span 88 % of the width,
    # so text crosses the middle of the frame (where a centred fold is).
    lines = [("Defocus compensation", 3), ("on a two-wall corner, sharp", 2),
             ("Projected text stays readable even", 2), ("where the two walls meet: edges, strokes,",
                                                          1),
             ("The quick brown fox jumps over the lazy dog 0123456789", 1),
             ("Pack my box with five dozen liquor jugs - 42", 1),
             ("Sphinx of black quartz, judge my vow! 1/2 3:4", 1)]
    font = cv2.FONT_HERSHEY_SIMPLEX
    y = 0.0
    for text, thick in lines:
        th = max(1, int(round(thick * w / 640.0)))
        (tw, tht), _ = cv2.getTextSize(text, font, 1.0, th)
        fs = 0.88 * w / tw
        y += 1.75 * tht * fs
        cv2.putText(img, text, (int(0.04 * w), int(y)), font, fs, (0, 0, 0), th, cv2.LINE_AA)
    return img


def photographs() -> dict[str, np.ndarray]:
    """The test photographs (scikit-image's chelsea, coffee, astronaut, rocket) as RGB uint8."""
    from skimage import data

    return {name: np.ascontiguousarray(getattr(data, name)())
            for name in ("chelsea", "coffee", "astronaut", "rocket")}


def _pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        raise InputError(f"images to compare must have the same shape; got {a.shape} and {b.shape}")
    return a, b


def _data_range(a: np.ndarray, data_range: float | None) -> float:
    if data_range is not None:
        return float(data_range)
    return 255.0 if a.dtype == np.uint8 else 1.0


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None,
         data_range: float | None = None) -> float:
    """Peak signal-to-noise ratio (dB) of ``a`` against ``b``.

    Parameters
    ----------
    a, b : (H, W) or (H, W, C) arrays of the same shape (uint8: range 255, float: range 1).
    mask : (H, W) bool, optional — only these pixels count.
    data_range : peak value, overriding the dtype's.

    Returns
    -------
    float (inf for identical images).
    """
    a, b = _pair(a, b)
    peak = _data_range(a, data_range)
    diff = a.astype(np.float64) - b.astype(np.float64)
    if mask is not None:
        diff = diff[np.asarray(mask, dtype=bool)]
    mse = float(np.mean(diff ** 2)) if diff.size else float("nan")
    return float("inf") if mse == 0 else 10.0 * np.log10(peak ** 2 / mse)


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None,
         data_range: float | None = None) -> float:
    """Mean structural similarity (``skimage.metrics.structural_similarity``, 7×7 windows,
    colour channels averaged) of ``a`` against ``b``, over ``mask`` when given.

    Parameters
    ----------
    a, b : (H, W) or (H, W, 3) arrays of the same shape.
    mask : (H, W) bool, optional — average the SSIM map over these pixels only.
    data_range : peak value, overriding the dtype's.
    """
    from skimage.metrics import structural_similarity

    a, b = _pair(a, b)
    channel_axis = 2 if a.ndim == 3 else None
    score, smap = structural_similarity(a, b, data_range=_data_range(a, data_range),
                                        channel_axis=channel_axis, full=True)
    if mask is None:
        return float(score)
    if smap.ndim == 3:
        smap = smap.mean(axis=2)
    return float(smap[np.asarray(mask, dtype=bool)].mean())


def near_fold_mask(fold_line: np.ndarray, shape: tuple[int, int], half_width: float) -> np.ndarray:
    """Pixels within ``half_width`` px of the line ``a x + b y + c = 0`` (a² + b² = 1).

    Parameters
    ----------
    fold_line : (3,) float, e.g. ``calib.fold_cam`` or ``truth.fold_proj``.
    shape : (H, W) of the image the mask is for.
    half_width : px.

    Returns
    -------
    (H, W) bool
    """
    a, b, c = (float(v) for v in np.asarray(fold_line, dtype=np.float64))
    norm = np.hypot(a, b)
    if norm == 0:
        raise InputError("the fold line is all zeros (a one-plane set-up has no fold band)")
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    return np.abs(a * xs + b * ys + c) / norm <= half_width


def rect_mask(rect: tuple[int, int, int, int], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool mask of an OpenCV Rect ``(x, y, w, h)`` (clipped to the image)."""
    x, y, w, h = (int(v) for v in rect)
    m = np.zeros(shape, dtype=bool)
    m[max(0, y):max(0, y + h), max(0, x):max(0, x + w)] = True
    return m


def oracle_calibration(procam):
    """A calibration built from a simulator's ground truth, reproducing its blur exactly.

    Geometry: the true homographies and fold lines, and the lit outline from mapping the
    projector frame (cut at the fold) through them. Radiometry: the simulator's projector
    response ``(v/255)^gamma``, its albedo and ambient maps. Kernels: the simulator renders its
    blur on a grid of radii (``rtdefocus.sim.RADIUS_STEP``), each pixel blending the two grid
    kernels that bracket its radius with tent weights; those grid kernels are the PSFs here and
    each pixel's two brackets and weights its ``pix_idx`` / ``pix_wts``, so ``F`` equals the
    simulator's own (green-channel) blur to float precision.

    Parameters
    ----------
    procam : rtdefocus.sim.VirtualProCam

    Returns
    -------
    rtdefocus.calib.file.Calibration
        With ``meta["source"] = "oracle"``.
    """
    from . import sim
    from .calib.file import Calibration
    from .calib.planar import lit_polygon

    truth = procam.truth
    wp, hp = procam.projector_size
    H = np.asarray(truth.H_cam_from_proj, dtype=np.float64)
    H_inv = np.stack([np.linalg.inv(h) for h in H])
    H_inv /= H_inv[:, 2:3, 2:3]
    if truth.fold_proj is None:
        fold_proj = fold_cam = np.zeros(3)
    else:
        fold_proj = np.asarray(truth.fold_proj, dtype=np.float64)
        fold_cam = np.asarray(truth.fold_cam, dtype=np.float64)
    polygon = lit_polygon((wp, hp), H, fold_proj)

    # Radiometry: the simulator's projector response and its albedo/ambient maps.
    codes = np.arange(256, dtype=np.float64) / 255.0
    lut = np.tile(codes ** truth.projector_gamma, (3, 1)).astype(np.float32)

    # Kernels: the radius grid of the renderer.
    q = truth.radius_map.astype(np.float64) / sim.RADIUS_STEP
    j0 = np.floor(q).astype(np.int64)
    t = (q - j0).astype(np.float32)
    jmin, jmax = int(j0.min()), int(j0.max()) + 1
    levels = np.arange(jmin, jmax + 1)
    full = sim.blend_kernel(jmax * sim.RADIUS_STEP, truth.aperture)   # the largest support
    k = full.shape[0]
    psfs = np.stack([sim.blend_kernel(j * sim.RADIUS_STEP, truth.aperture, size=k)
                     for j in levels]).astype(np.float32)
    idx = np.zeros((hp, wp, 4), np.int32)
    wts = np.zeros((hp, wp, 4), np.float32)
    idx[..., 0] = j0 - jmin
    idx[..., 1] = np.minimum(j0 + 1 - jmin, len(levels) - 1)
    wts[..., 0] = 1.0 - t
    wts[..., 1] = t
    # A representative point and plane per PSF: the pixel whose radius is nearest the level
    # among the pixels of the plane that uses it most.
    plane_map = truth.plane_map.astype(np.int64)
    points = np.zeros((len(levels), 2), np.float32)
    planes = np.zeros(len(levels), np.int32)
    use = np.abs(q[None] - levels[:, None, None]) < 1.0              # (L, Hp, Wp)
    for i in range(len(levels)):
        counts = np.bincount(plane_map[use[i]], minlength=2)
        planes[i] = int(np.argmax(counts))
        dist = np.where(plane_map == planes[i], np.abs(q - levels[i]), np.inf)
        yy, xx = np.unravel_index(int(np.argmin(dist)), dist.shape)
        points[i] = (xx, yy)

    calib = Calibration(
        projector_size=(wp, hp), camera_size=tuple(procam.camera_size),
        H_cam_from_proj=H, H_proj_from_cam=H_inv, fold_proj=fold_proj, fold_cam=fold_cam,
        lit_polygon_cam=np.asarray(polygon, dtype=np.float64),
        response_lut=lut, ambient_proj=truth.ambient_proj.astype(np.float32),
        albedo_proj=truth.albedo_proj.astype(np.float32),
        psf_points_proj=points, psf_plane=planes, psfs=psfs, pix_idx=idx, pix_wts=wts,
        meta={"source": "oracle", "preset": getattr(procam, "preset", None)},
    )
    calib.validate()
    return calib


# =========================================================================== `rtdefocus eval`
# The ablation run: presets x images x methods x kernel layouts (plus the oracle kernels as the
# upper bound), and the solvers' convergence. Tables are built from rtdefocus.demo.score_image.

#: Kernel layouts of the PSF stage (``rtdefocus.calib.psf``) by eval name -> (layout, cross_fold).
EVAL_LAYOUTS = {"default": ("default", False), "paper": ("paper", False),
                "dense": ("dense", False), "cross_fold": ("default", True)}
LAYOUT_LABELS = {
    "default": "corners, both sides of the fold and the edges, refined where the blur changes",
    "paper": "4 corners + 2 fold points per plane, bilinear (the paper's §2.4)",
    "dense": "a regular grid per plane",
    "cross_fold": "the default samples of one region blended across the fold (geometry-blind)",
    "oracle": "the simulator's true geometry, response and kernels (the upper bound)"}
METHOD_SHORT = {"none": "geometry only", "ycbcr": "ours", "rgb": "RGB LS", "wiener": "Wiener"}
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
    from .demo import demo_images

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
    (:func:`rtdefocus.eval_layouts.calibrate_psf_layouts`), each pattern averaged as often as the
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
    import copy
    import time

    from .calib import calibrate
    from .calib.capture import Capturer
    from .eval_layouts import calibrate_psf_layouts

    layouts = _check_names("layouts", layouts, tuple(EVAL_LAYOUTS))
    t0 = time.perf_counter()
    base = calibrate(procam, stages=("geometry", "radiometry"), progress=progress)
    t1 = time.perf_counter()
    cap = Capturer(procam, progress)
    keys = [EVAL_LAYOUTS[name] for name in layouts]
    measured = calibrate_psf_layouts(procam, copy.deepcopy(base), capture=cap, layouts=keys)
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
    from .cl.runtime import opencl_available
    from .compensate import Compensator

    if method not in ("ycbcr", "rgb"):
        raise InputError(f"convergence needs an iterative method ('ycbcr' or 'rgb'); got {method!r}")
    cps = sorted({int(c) for c in checkpoints} | {0})
    if cps[0] < 0:
        raise InputError(f"checkpoints must be iteration counts >= 0; got {checkpoints}")
    h, w = image.shape[:2]
    wc, hc = calib.camera_size
    mask = rect_mask(calib.display_rect((w, h)), (hc, wc))
    warped = Compensator(calib, method="none").warp(image)
    reference = procam.capture(warped, sharp=True)

    def score(frame: np.ndarray) -> float:
        return psnr(procam.capture(frame), reference, mask)

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
        # Each run starts by re-evaluating d at its starting P: the previous run's last value.
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


def plot_convergence(curves: list[dict], path, title: str = "") -> Path:
    """Write the 4-panel convergence figure (distance and PSNR vs iteration and vs time) as PNG.

    Parameters
    ----------
    curves : from :func:`convergence_curves`.
    path : output file (``.png``); parent folders are created.
    title : figure title.

    Returns
    -------
    pathlib.Path of the file written.
    """
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise RtDefocusError("the convergence plot needs matplotlib: pip install "
                             "'rtdefocus[demo]' (or matplotlib)") from exc
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # A Figure without pyplot renders with Agg and leaves the process's backend alone.
    fig = Figure(figsize=(12, 8.5), layout="constrained")
    (ax_di, ax_dt), (ax_pi, ax_pt) = fig.subplots(2, 2)
    colours = {"fista": "tab:blue", "pg": "tab:orange"}
    # The backends compute the same iterates: NumPy gets open square markers so that its points
    # stay visible on top of the OpenCL lines in the per-iteration panels.
    styles = {"opencl": {"linestyle": "-", "marker": "o"},
              "numpy": {"linestyle": "--", "marker": "s", "mfc": "none", "ms": 7}}
    for c in curves:
        label = f"{c['solver'].upper()} · {c['backend']}"
        kw = {"color": colours.get(c["solver"], "k"), "label": label, "ms": 4,
              **styles.get(c["backend"], {"linestyle": ":", "marker": "."})}
        line_kw = {k: v for k, v in kw.items() if k not in ("marker", "mfc", "ms")}
        if c["backend"] == "numpy":                    # few points: show them
            line_kw = kw
        d = np.asarray(c["distances"], np.float64)
        rel = d / d[0]
        ax_di.semilogy(np.arange(len(d)), rel, **line_kw)
        t = np.asarray(c["seconds"])
        ax_dt.loglog(t[1:], rel[1:], **line_kw)              # log time: t = 0 cannot be drawn
        ax_pi.plot(c["checkpoints"], c["psnr"], **kw)
        ct = np.asarray(c["checkpoint_seconds"])
        ax_pt.semilogx(ct[1:], np.asarray(c["psnr"])[1:], **kw)
    if curves:
        base = curves[0]["psnr"][0]
        for ax in (ax_pi, ax_pt):
            ax.axhline(base, color="grey", linestyle=":", label="geometry only (0 iterations)")
    ax_di.set(xlabel="iteration", ylabel="distance d / d₀", title="distance vs iteration")
    ax_dt.set(xlabel="solve time (s)", ylabel="distance d / d₀", title="distance vs time")
    ax_pi.set(xlabel="iteration", ylabel="PSNR (dB)", title="camera-view PSNR vs iteration")
    ax_pt.set(xlabel="solve time (s)", ylabel="PSNR (dB)", title="camera-view PSNR vs time")
    for ax in (ax_di, ax_dt, ax_pi, ax_pt):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=100)
    return path


def _fmt(v: float, spec: str = ".2f") -> str:
    return "—" if v is None or not np.isfinite(v) else format(v, spec)


def eval_markdown(result: dict) -> str:
    """The eval report (markdown): summary of gains, then per preset its tables, then the
    convergence figure and its end points. ``result`` is :func:`run_eval`'s."""
    s = result["settings"]
    methods, layouts = s["methods"], s["layouts_scored"]
    cols = [(m, lay) for m in methods for lay in layouts]
    head = " | ".join(f"{METHOD_SHORT.get(m, m)} · {lay}" for m, lay in cols)
    lines = ["# rtdefocus eval", "",
             f"Virtual set-ups {', '.join(s['presets'])}; projector {s['projector_size']}, camera "
             f"{s['camera_size']}; compensation backend {s['backend']} (OpenCL device: "
             f"{s.get('opencl_device', 'none')}); "
             f"{result['seconds']:.0f} s on this machine.", "",
             "Every score compares the camera's view with the sharp reference "
             "(`capture(warp(image), sharp=True)`: what an in-focus projector would show through "
             "the same geometry correction). Layouts: "
             + "; ".join(f"`{lay}` = {LAYOUT_LABELS.get(lay, lay)}" for lay in layouts)
             + ". The oracle is scored against its own (true) geometry.", "",
             "## Summary: mean PSNR gain over geometry only (dB), display rect "
             f"(in brackets: within {s['fold_band_px']:.0f} camera px of the fold)", "",
             "| preset | method | " + " | ".join(layouts) + " |",
             "|---|---|" + "---|" * len(layouts)]
    for preset, pres in result["presets"].items():
        for m in methods:
            cells = []
            for lay in layouts:
                g = pres["gains"][f"{m}/{lay}"]
                fold = f" ({_fmt(g['psnr_fold'], '+.2f')})" if np.isfinite(g["psnr_fold"]) else ""
                cells.append(f"{_fmt(g['psnr'], '+.2f')}{fold}")
            lines.append(f"| {preset} | {METHOD_SHORT.get(m, m)} | " + " | ".join(cells) + " |")
    for preset, pres in result["presets"].items():
        cal = pres["calibration"]
        rows = pres["rows"]
        lines += ["", f"## {preset}", "",
                  f"Calibration: captures {cal['captures']} (the psf captures are shared by the "
                  f"layouts, {cal['averages']} averages per pattern); PSF samples "
                  + ", ".join(f"{k} {v}" for k, v in cal["samples"].items())
                  + "; kernel window " + ", ".join(f"{k} {v}" for k, v in cal["window"].items())
                  + f"; {sum(cal['seconds'].values()):.1f} s.", "",
                  "### PSNR (dB) / SSIM, display rect", "",
                  "| image | geometry only | " + head + " |", "|---|---|" + "---|" * len(cols)]
        for r in rows:
            cells = [f"{_fmt(r['psnr'].get(f'{m}/{lay}'))} / {_fmt(r['ssim'].get(f'{m}/{lay}'), '.3f')}"
                     for m, lay in cols]
            lines.append(f"| {r['name']} | {_fmt(r['psnr']['none'])} / {_fmt(r['ssim']['none'], '.3f')} | "
                         + " | ".join(cells) + " |")
        if rows and rows[0]["psnr_fold"]:
            lines += ["", f"### PSNR (dB) within {s['fold_band_px']:.0f} camera px of the fold", "",
                      "| image | geometry only | " + head + " |", "|---|---|" + "---|" * len(cols)]
            for r in rows:
                cells = [_fmt(r["psnr_fold"].get(f"{m}/{lay}")) for m, lay in cols]
                lines.append(f"| {r['name']} | {_fmt(r['psnr_fold']['none'])} | "
                             + " | ".join(cells) + " |")
        if "oracle" in layouts:
            lines += ["", "Geometry only through the oracle's (true) geometry: "
                      + ", ".join(f"{r['name']} {_fmt(r['psnr'].get('none/oracle'))} dB" for r in rows)
                      + "."]
    conv = result.get("convergence")
    if conv:
        lines += ["", f"## Convergence ({conv['preset']} / {conv['image']}, layout "
                  f"`{conv['layout']}`, method `{conv['method']}`)", "",
                  "![convergence](convergence.png)", "",
                  "| solver | backend | iterations | solve time (s) | d / d₀ | PSNR (dB) |",
                  "|---|---|---|---|---|---|"]
        for c in conv["curves"]:
            for i, n in enumerate(c["checkpoints"]):
                if n == 0:
                    continue
                d = c["distances"][min(n, len(c["distances"]) - 1)] / c["distances"][0]
                lines.append(f"| {c['solver']} | {c['backend']} | {n} | "
                             f"{c['checkpoint_seconds'][i]:.3f} | {d:.4f} | {c['psnr'][i]:.2f} |")
    return "\n".join(lines) + "\n"


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
    true calibration (:func:`oracle_calibration`) is added as the upper bound. Each image is
    projected every way and scored (:func:`rtdefocus.demo.score_image`): PSNR and SSIM of the
    camera view against the sharp reference over the display rect, PSNR over the band near the
    fold. Writes ``eval.md``, ``eval.json`` and (with ``convergence``) ``convergence.png`` into
    ``out_dir``.

    Parameters
    ----------
    out_dir : output folder (created).
    presets : simulator presets (:data:`rtdefocus.sim.PRESETS`).
    images : None (:func:`rtdefocus.demo.demo_images`: four photographs and a text slide),
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
    :class:`rtdefocus.demo.ImageScores` dict per image, score keys ``"none"``, ``"none/oracle"``
    and ``"method/layout"`` — and ``gains`` from :func:`mean_gains`), ``convergence`` (curves),
    ``seconds``, ``files`` and ``markdown``.
    """
    import json
    import time
    from dataclasses import asdict

    from . import sim
    from .calib.file import json_default
    from .compensate import Compensator
    from .demo import score_image

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

    from .cl.runtime import opencl_available

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


__all__ += ["run_eval", "calibrate_layouts", "convergence_curves", "plot_convergence",
            "mean_gains", "eval_markdown", "EVAL_LAYOUTS", "QUICK"]
