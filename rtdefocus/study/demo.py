"""The demo: the whole story on the built-in virtual cubicle, in one output folder.

1. calibrate the virtual set-up through ``capture`` only (geometry, radiometry, kernels);
2. for real photographs and a text slide: show the input projected with no correction, with
   geometry correction only, and with geometry + defocus compensation, each as the camera
   (the audience) sees it, beside the input and a zoom near the fold;
3. score every camera view against the sharp reference (``capture(warp(img), sharp=True)``,
   what an in-focus projector would show) in PSNR and SSIM, for every compensation method,
   and count Canny edge pixels as the paper's Table 1 does.

:func:`run_demo` returns the rows of the table; the CLI prints where everything went.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from .. import sim
from ..calib import calibrate
from ..calib.camera_diagnostics import camera_diagnostics
from ..calib.file import json_default
from ..calib.geometry.diagnostics import geometry_diagnostics
from ..calib.psf import psf_diagnostics
from ..compensate import Compensator
from ..imageio import write_image
from .panels import crop_box as _crop_box
from .panels import fit_height as _fit_height
from .panels import hstack as _hstack
from .panels import label as _label
from .panels import pad_to_width as _pad_to_width
from .samples import demo_images
from .scores import ImageScores, score_image

log = logging.getLogger(__name__)

METHODS = ("ycbcr", "rgb", "wiener")
METHOD_LABELS = {"none": "geometry only", "ycbcr": "ours (YCbCr, Eq. 4)",
                 "rgb": "RGB least squares", "wiener": "Wiener pre-filter"}

StepFn = Callable[[str], None]


def _fold_zoom_box(calib, rect, reference: np.ndarray, size: int = 96) -> tuple[slice, slice]:
    """A square of camera pixels on a fold (the middle of the rect for one plane), placed
    where the sharp reference has the most detail, so the zoom shows what compensation does."""
    from ..planar import fold_segments_cam

    x, y, w, h = rect
    # Candidate centres: along every fold's camera segment, else down the rect's middle.
    centres = [np.asarray(seg[0]) + t * (np.asarray(seg[1]) - seg[0])
               for seg in fold_segments_cam(calib.projector_size, calib.H_cam_from_proj,
                                            calib.layout) if seg is not None
               for t in np.linspace(0.0, 1.0, 17)]
    centres = [c for c in centres if x <= c[0] < x + w and y <= c[1] < y + h]
    if not centres:
        centres = [(x + w / 2.0, cy) for cy in np.linspace(y + size / 2, y + h - size / 2, 9)]
    best, best_score = None, -1.0
    for cx, cy in centres:
        x0 = int(np.clip(cx - size / 2, x, x + w - size))
        y0 = int(np.clip(cy - size / 2, y, y + h - size))
        box = (slice(y0, y0 + size), slice(x0, x0 + size))
        patch = reference[box].astype(np.float32).mean(axis=2)
        score = float(np.abs(np.diff(patch, axis=0)).mean() + np.abs(np.diff(patch, axis=1)).mean())
        if score > best_score:
            best, best_score = box, score
    return best


def side_by_side(calib, rect, views: dict[str, np.ndarray], input_rgb: np.ndarray,
                 height: int = 300, zoom: int = 3) -> np.ndarray:
    """One picture: input | projected, no correction | geometry only | geometry + defocus,
    each camera view cropped to the lit area, then below the zooms near the fold."""
    rows, cols = _crop_box(calib)
    panels = [_label(_fit_height(input_rgb, height), "input")]
    for title, img in views.items():
        panels.append(_label(_fit_height(img[rows, cols], height), title))
    top = _hstack(panels)
    box = _fold_zoom_box(calib, rect, views["sharp reference"])
    zooms = []
    for title, img in views.items():
        patch = img[box]
        big = cv2.resize(patch, (patch.shape[1] * zoom, patch.shape[0] * zoom),
                         interpolation=cv2.INTER_NEAREST)
        zooms.append(_label(big, f"{title}, fold x{zoom}"))
    bottom = _hstack(zooms)
    width = max(top.shape[1], bottom.shape[1])
    return np.vstack([_pad_to_width(top, width), _pad_to_width(bottom, width)])


def table_markdown(rows: list[ImageScores], preset: str) -> str:
    """The demo table: PSNR/SSIM per method, and the paper's Table 1 edge counts."""
    methods = list(rows[0].psnr)
    lines = [f"### PSNR / SSIM against the sharp reference (virtual `{preset}`, display rect)", "",
             "| image | " + " | ".join(METHOD_LABELS.get(m, m) for m in methods) + " |",
             "|---|" + "---|" * len(methods)]
    for r in rows:
        cells = [f"{r.psnr[m]:.2f} dB / {r.ssim[m]:.3f}" if np.isfinite(r.psnr[m]) else "–"
                 for m in methods]
        lines.append(f"| {r.name} | " + " | ".join(cells) + " |")
    for r in rows:
        if "headroom" in r.name:
            base = next((b for b in rows if b.name == r.name.split(" (")[0]), None)
            clipped = (f"; clipped projector pixels {100 * base.clipped['ycbcr']:.1f} % without "
                       f"headroom, {100 * r.clipped['ycbcr']:.1f} % with it"
                       if base is not None and "ycbcr" in base.clipped else "")
            lines += ["", f"*{r.name}*: the target mapped into the headroom; geometry only and "
                      f"the sharp reference are shown at the same reduced contrast{clipped}."]
    if rows[0].psnr_fold:
        lines += ["", "### PSNR within 24 camera px of a fold", "",
                  "| image | " + " | ".join(METHOD_LABELS.get(m, m) for m in methods) + " |",
                  "|---|" + "---|" * len(methods)]
        for r in rows:
            lines.append(f"| {r.name} | " + " | ".join(
                f"{r.psnr_fold[m]:.2f} dB" if np.isfinite(r.psnr_fold[m]) else "–" for m in methods)
                + " |")
    lines += ["", "### Edge pixels (Canny), as the paper's Table 1", "",
              "| image | input: geometry corrected | input: defocus corrected | % increase "
              "| output: geometry corrected | output: defocus corrected | % increase |",
              "|---|---|---|---|---|---|---|"]
    def pct(v: float) -> str:
        return f"{v:.2f}" if np.isfinite(v) else "–"      # no edges to begin with

    for r in rows:
        lines.append(f"| {r.name} | {r.edges_input['geometry']} | {r.edges_input['defocus']} | "
                     f"{pct(r.edge_increase_input)} | {r.edges_output['geometry']} | "
                     f"{r.edges_output['defocus']} | {pct(r.edge_increase_output)} |")
    return "\n".join(lines) + "\n"


def run_demo(out_dir: str | Path = "demo_out", *, preset: str = "cubicle",
             methods: tuple[str, ...] = METHODS, images: dict[str, np.ndarray] | None = None,
             seed: int = 0, progress=None, step: StepFn | None = None,
             headroom: tuple[float, float] = (0.1, 0.9), surfaces: bool = False,
             rooms: tuple[str, ...] = ("corner_ceiling",), **procam_options) -> dict:
    """Run the demo and write its pictures and table into ``out_dir``.

    Parameters
    ----------
    out_dir : folder to write into (created).
    preset : simulator preset (default ``"cubicle"``).
    methods : compensation methods to compare with geometry only.
    images : name -> RGB uint8; default :func:`demo_images`.
    progress : calibration progress callback ``(stage, done, total)``.
    step : called with a short message before each long step (the CLI prints them).
    headroom : the text slide is also shown with this headroom (what it buys on clipped text).
    surfaces : also the ``fabric`` preset: geometry only | defocus only | defocus + flatten |
        sharp on a white wall, per photograph, and the uniformity figures
        (:mod:`rtdefocus.study.demo_surfaces`; ``table.json`` gains ``surfaces``).
    rooms : presets of more than two planes also calibrated through ``capture`` and shown
        with the photographs (:mod:`rtdefocus.study.demo_rooms`; default ``corner_ceiling``, two
        walls and the ceiling; ``()`` for none); ``table.json`` gains ``rooms``.
    **procam_options : passed to :class:`rtdefocus.sim.VirtualProCam` (e.g. smaller sizes).

    Returns
    -------
    dict with ``rows`` (list of :class:`ImageScores` as dicts), ``files`` (what was written),
    ``calibration`` (captures, seconds, stats) and ``seconds`` (total).
    """
    say = step or (lambda msg: log.info(msg))
    t_start = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []

    say(f"calibrating the virtual {preset!r} through capture() only")
    procam = sim.VirtualProCam(preset, seed=seed, **procam_options)
    calib = calibrate(procam, progress=progress)
    files.append(calib.save(out / "setup.npz"))
    files.append(write_image(out / "calibration_geometry.png", geometry_diagnostics(calib)))
    files.append(write_image(out / "calibration_camera.png", camera_diagnostics(calib)))
    files.append(write_image(out / "calibration_kernels.png",
                             psf_diagnostics(calib, truth_radius=procam.truth.radius_map)))

    comps = {m: Compensator(calib, method=m) for m in methods}
    images = images if images is not None else demo_images()
    rows: list[ImageScores] = []
    for i, (name, image) in enumerate(images.items(), 1):
        say(f"[{i}/{len(images)}] {name}: projecting uncorrected, geometry only, "
            f"and compensated ({', '.join(methods)})")
        scores, shown = score_image(procam, calib, comps, name, image)
        rows.append(scores)
        rect = calib.display_rect(image.shape[1::-1])
        files.append(write_image(out / f"{name}_side_by_side.png",
                                 side_by_side(calib, rect, shown, image)))
    if "text" in images and "ycbcr" in comps:
        say(f"text slide with headroom {headroom}")
        comps_h = {"ycbcr": Compensator(calib, method="ycbcr", headroom=headroom)}
        scores, shown = score_image(procam, calib, comps_h, "text (headroom)", images["text"],
                                    headroom=headroom)
        rows.append(_fill_missing(scores, methods))
        rect = calib.display_rect(images["text"].shape[1::-1])
        files.append(write_image(out / "text_headroom_side_by_side.png",
                                 side_by_side(calib, rect, shown, images["text"])))
    md = table_markdown(rows, preset)
    surface_figures = None
    if surfaces:
        from .demo_surfaces import run_surfaces

        photos = {n: im for n, im in images.items() if n != "text"} or images
        say(f"fabric preset: keep vs flatten on {', '.join(photos)}")
        more, md_s, surface_figures = run_surfaces(out, photos, seed=seed, **procam_options)
        files += more
        md += "\n" + md_s
    room_summary = None
    if rooms:
        from .demo_rooms import run_rooms

        photos = {n: im for n, im in images.items() if n != "text"} or images
        more, room_rows, room_summary = run_rooms(
            out, tuple(rooms), photos, methods=methods, seed=seed, progress=progress, step=say,
            side_by_side=side_by_side, **procam_options)
        files += more
        for preset, r in room_rows.items():
            s = room_summary[preset]
            md += (f"\n{table_markdown(r, preset)}\n*{preset}*: {s['planes']} planes found "
                   f"({s['planes_true']} true), {s['folds']} folds, {s['captures']} captures.\n")
            s["rows"] = [dict(asdict(x), edge_increase_input=x.edge_increase_input,
                              edge_increase_output=x.edge_increase_output) for x in r]
    (out / "table.md").write_text(md)
    files.append(out / "table.md")
    result = {
        "preset": preset,
        "rows": [dict(asdict(r), edge_increase_input=r.edge_increase_input,
                      edge_increase_output=r.edge_increase_output) for r in rows],
        "calibration": {k: calib.meta.get(k) for k in ("captures", "seconds", "geometry")},
        "backend": next(iter(comps.values())).backend,
        "seconds": round(time.perf_counter() - t_start, 1),
    }
    if surface_figures is not None:
        result["surfaces"] = surface_figures
    if room_summary is not None:
        result["rooms"] = room_summary
    (out / "table.json").write_text(json.dumps(result, indent=2, default=json_default))
    files.append(out / "table.json")
    result["files"] = [str(f) for f in files]
    result["markdown"] = md
    return result


def _fill_missing(scores: ImageScores, methods) -> ImageScores:
    """Rows of the table share columns: methods not run on this row are NaN."""
    for table in (scores.psnr, scores.ssim, scores.psnr_fold, scores.clipped):
        if table:
            for m in methods:
                table.setdefault(m, float("nan"))
    return scores
