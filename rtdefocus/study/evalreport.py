"""The ``rtdefocus eval`` report: the markdown tables and the convergence figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..calib.file import json_default
from .extras import need

__all__ = ["eval_markdown", "plot_convergence", "LAYOUT_LABELS", "METHOD_SHORT"]

LAYOUT_LABELS = {
    "default": "corners, both sides of the fold and the edges, refined where the blur changes",
    "paper": "4 corners + 2 fold points per plane, bilinear (the paper's §2.4)",
    "dense": "a regular grid per plane",
    "cross_fold": "the default samples of one region blended across the fold (geometry-blind)",
    "oracle": "the simulator's true geometry, response and kernels (the upper bound)"}
METHOD_SHORT = {"none": "geometry only", "ycbcr": "ours", "rgb": "RGB LS", "wiener": "Wiener"}


def write_report(result: dict, out: Path, stem: str, markdown, plot=None) -> dict:
    """Write ``result`` as ``STEM.md`` (``markdown(result)``, also kept in ``result["markdown"]``),
    ``STEM.json`` and, when ``plot`` is given, ``plot(result, STEM.png)``; ``result["files"]``
    lists them. Returns ``result``."""
    import json

    result["markdown"] = markdown(result)
    files = [out / f"{stem}.md", out / f"{stem}.json"]
    files[0].write_text(result["markdown"])
    files[1].write_text(json.dumps({k: v for k, v in result.items() if k != "markdown"},
                                   indent=1, default=json_default))
    if plot is not None:
        files.append(plot(result, out / f"{stem}.png"))
    result["files"] = [str(f) for f in files]
    return result


def new_figure(what: str, figsize: tuple[float, float], path: Path, hint: str = ""):
    """A matplotlib Figure for a plot written to ``path`` (its folder is created), or an error
    naming the extra to install: matplotlib is optional (rtdefocus[demo]) and slow to import,
    so it loads here, on use. A Figure without pyplot renders with Agg and leaves the process's
    backend alone."""
    Figure = need("matplotlib.figure", what, hint).Figure
    path.parent.mkdir(parents=True, exist_ok=True)
    return Figure(figsize=figsize, layout="constrained")


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
    path = Path(path)
    fig = new_figure("the convergence plot", (12, 8.5), path)
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
