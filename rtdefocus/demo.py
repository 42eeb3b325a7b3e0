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
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .calib.file import json_default
from .imageio import write_image

log = logging.getLogger(__name__)

METHODS = ("ycbcr", "rgb", "wiener")
METHOD_LABELS = {"none": "geometry only", "ycbcr": "ours (YCbCr, Eq. 4)",
                 "rgb": "RGB least squares", "wiener": "Wiener pre-filter"}
# Canny thresholds for the edge-pixel counts (the paper's Table 1 gives none; OpenCV's usual pair).
CANNY_LO, CANNY_HI = 100, 200

StepFn = Callable[[str], None]


@dataclass
class ImageScores:
    """Scores of one input image on one set-up (camera views against the sharp reference)."""

    name: str
    psnr: dict[str, float] = field(default_factory=dict)        # method -> dB, display rect
    ssim: dict[str, float] = field(default_factory=dict)        # method -> SSIM, display rect
    psnr_fold: dict[str, float] = field(default_factory=dict)   # method -> dB, near-fold band
    edges_input: dict[str, int] = field(default_factory=dict)   # geometry / defocus corrected
    edges_output: dict[str, int] = field(default_factory=dict)  # camera views of the same
    clipped: dict[str, float] = field(default_factory=dict)     # method -> fraction of P at 0 or 1
    seconds: dict[str, float] = field(default_factory=dict)     # method -> compensate() time

    @property
    def edge_increase_input(self) -> float:
        return _percent(self.edges_input["geometry"], self.edges_input["defocus"])

    @property
    def edge_increase_output(self) -> float:
        return _percent(self.edges_output["geometry"], self.edges_output["defocus"])


def _percent(before: int, after: int) -> float:
    return 100.0 * (after - before) / max(before, 1)


def edge_pixels(rgb: np.ndarray, mask: np.ndarray | None = None) -> int:
    """Canny edge pixels of an RGB uint8 image (the paper's Table 1 measure), inside ``mask``."""
    import cv2

    edges = cv2.Canny(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), CANNY_LO, CANNY_HI) > 0
    if mask is not None:
        edges &= mask
    return int(edges.sum())


def demo_images(include_text: bool = True) -> dict[str, np.ndarray]:
    """The demo's inputs: scikit-image's chelsea (the paper's cat), coffee, astronaut, rocket,
    and a text slide."""
    from .eval import photographs, text_slide

    images = photographs()
    if include_text:
        images["text"] = text_slide((800, 600))
    return images


def _crop_box(calib, pad: int = 12) -> tuple[slice, slice]:
    """Camera rows/cols around the lit area (so the pictures show the projection, not the room)."""
    poly = np.asarray(calib.lit_polygon_cam)
    wc, hc = calib.camera_size
    x0, y0 = np.floor(poly.min(axis=0)).astype(int) - pad
    x1, y1 = np.ceil(poly.max(axis=0)).astype(int) + pad
    return slice(max(0, y0), min(hc, y1)), slice(max(0, x0), min(wc, x1))


def _label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    bar = np.full((28, img.shape[1], 3), 255, np.uint8)
    cv2.putText(bar, text, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([bar, img])


def _fit_height(img: np.ndarray, h: int) -> np.ndarray:
    import cv2

    w = max(1, round(img.shape[1] * h / img.shape[0]))
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA if img.shape[0] > h
                      else cv2.INTER_LINEAR)


def _fold_zoom_box(calib, rect, reference: np.ndarray, size: int = 96) -> tuple[slice, slice]:
    """A square of camera pixels on the fold (the middle of the rect for one plane), placed
    where the sharp reference has the most detail, so the zoom shows what compensation does."""
    x, y, w, h = rect
    best, best_score = None, -1.0
    for cy in np.linspace(y + size / 2, y + h - size / 2, 9):
        if calib.n_planes == 2 and abs(calib.fold_cam[0]) > 1e-9:
            a, b, c = calib.fold_cam
            cx = -(b * cy + c) / a
        else:
            cx = x + w / 2.0
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
    import cv2

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


def _hstack(panels: list[np.ndarray], gap: int = 6) -> np.ndarray:
    h = max(p.shape[0] for p in panels)
    out = []
    for i, p in enumerate(panels):
        if p.shape[0] < h:
            p = np.vstack([p, np.full((h - p.shape[0], p.shape[1], 3), 255, np.uint8)])
        out.append(p)
        if i < len(panels) - 1:
            out.append(np.full((h, gap, 3), 255, np.uint8))
    return np.hstack(out)


def _pad_to_width(img: np.ndarray, width: int) -> np.ndarray:
    if img.shape[1] >= width:
        return img
    return np.hstack([img, np.full((img.shape[0], width - img.shape[1], 3), 255, np.uint8)])


def score_image(procam, calib, comps: dict, name: str, image: np.ndarray,
                fold_band_px: float = 24.0, headroom: tuple[float, float] | None = None
                ) -> tuple[ImageScores, dict[str, np.ndarray]]:
    """Project ``image`` every way on ``procam`` and score the camera views.

    With ``headroom`` (the compensators' own), geometry only and the sharp reference show the
    same reduced-contrast target the compensators solve for, so the scores say what
    compensation adds at that contrast.

    Returns the scores and the camera views ``{"no correction", "geometry only",
    "geometry + defocus", "sharp reference"}`` (the last three for the ``ycbcr`` method).
    """
    import cv2

    from .eval import near_fold_mask, psnr, rect_mask, ssim
    from .reference.lut import decode_lut, encode_lut, increasing_lut

    h, w = image.shape[:2]
    rect = calib.display_rect((w, h))
    wc, hc = calib.camera_size
    mask = rect_mask(rect, (hc, wc))
    band = mask & near_fold_mask(calib.fold_cam, (hc, wc), fold_band_px) \
        if calib.n_planes == 2 else None
    geometry = next(iter(comps.values()))
    warped = geometry.warp(image)
    if headroom is not None:
        warped = encode_lut(decode_lut(warped, calib.lut, headroom), increasing_lut(calib.lut))
    reference = procam.capture(warped, sharp=True)
    geometry_view = procam.capture(warped)
    raw_view = procam.capture(cv2.resize(image, calib.projector_size, interpolation=cv2.INTER_AREA))
    scores = ImageScores(name)
    views = {"none": geometry_view}
    frames = {"none": warped}
    for method, comp in comps.items():
        t0 = time.perf_counter()
        frame = comp.compensate(image, warm_start=False)
        scores.seconds[method] = time.perf_counter() - t0
        frames[method] = frame
        views[method] = procam.capture(frame)
    for method, view in views.items():
        scores.psnr[method] = psnr(view, reference, mask)
        scores.ssim[method] = ssim(view, reference, mask)
        if band is not None:
            scores.psnr_fold[method] = psnr(view, reference, band)
        scores.clipped[method] = float(np.mean((frames[method] == 0) | (frames[method] == 255)))
    ours = "ycbcr" if "ycbcr" in comps else next(iter(comps))
    pmask = np.ones(frames["none"].shape[:2], bool)
    scores.edges_input = {"geometry": edge_pixels(frames["none"], pmask),
                          "defocus": edge_pixels(frames[ours], pmask)}
    scores.edges_output = {"geometry": edge_pixels(views["none"], mask),
                           "defocus": edge_pixels(views[ours], mask)}
    shown = {"no correction": raw_view, "geometry only": geometry_view,
             "geometry + defocus": views[ours], "sharp reference": reference}
    return scores, shown


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
        lines += ["", "### PSNR within 24 camera px of the fold", "",
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
    for r in rows:
        lines.append(f"| {r.name} | {r.edges_input['geometry']} | {r.edges_input['defocus']} | "
                     f"{r.edge_increase_input:.2f} | {r.edges_output['geometry']} | "
                     f"{r.edges_output['defocus']} | {r.edge_increase_output:.2f} |")
    return "\n".join(lines) + "\n"


def run_demo(out_dir: str | Path = "demo_out", *, preset: str = "cubicle",
             methods: tuple[str, ...] = METHODS, images: dict[str, np.ndarray] | None = None,
             seed: int = 0, progress=None, step: StepFn | None = None,
             headroom: tuple[float, float] = (0.1, 0.9), **procam_options) -> dict:
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
    **procam_options : passed to :class:`rtdefocus.sim.VirtualProCam` (e.g. smaller sizes).

    Returns
    -------
    dict with ``rows`` (list of :class:`ImageScores` as dicts), ``files`` (what was written),
    ``calibration`` (captures, seconds, stats) and ``seconds`` (total).
    """
    from . import sim
    from .calib import calibrate
    from .calib.geometry import geometry_diagnostics
    from .calib.psf import psf_diagnostics
    from .compensate import Compensator

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
