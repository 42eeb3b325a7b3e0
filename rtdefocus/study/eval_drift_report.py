"""The ``rtdefocus eval --drift`` report: the markdown tables and the PSNR-over-time plot."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .evalreport import new_figure

__all__ = ["drift_markdown", "plot_drift", "ROW_LABELS"]

ROW_LABELS = {"none": "no watching (original calibration)",
              "watch": "watching (the Watcher's updates)",
              "oracle": "oracle (re-calibrated with the truth at each event)",
              "geometry": "geometry only (the watch row's geometry)"}
_COLOURS = {"none": "tab:red", "watch": "tab:blue", "oracle": "k", "geometry": "0.55"}


def _f(v, spec=".2f", suffix="") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:{spec}}{suffix}"


def drift_markdown(result: dict) -> str:
    """Settings, the mean PSNR per row, the per-event figures and the false-alarm count."""
    s, m = result["settings"], result.get("machine", {})
    la = m.get("loadavg")
    load = "/".join(f"{v:.1f}" for v in la) if la else "?"
    w = s["within_db"]
    lines = [
        "# The show while the set-up changes (`rtdefocus eval --drift`)", "",
        f"Preset `{s['preset']}`, projector {s['size'][0]}x{s['size'][1]}, camera "
        f"{s['camera_size'][0]}x{s['camera_size'][1]}; {s['duration_s']:g} s of show at "
        f"{s['fps']:g} fps, frame-stepped on a simulated clock; every compensated row "
        f"{s['iterations']} warm-started iterations per frame ({s['backend']}; "
        f"{m.get('cpu', '?')}, {m.get('cores', '?')} cores, load average {load}). "
        "Camera-view PSNR against the sharp capture of the oracle's warp, inside the display "
        "rectangle of the original calibration (the picture stays where it was on the wall; "
        "after a camera knock, scored where the camera now sees it). "
        + ("Each event on a fresh set-up of its own (2 s of show, the event, "
           f"{s['duration_s'] / max(1, len(s['scheduled'])) - 2:g} s to recover), the plays laid "
           "end to end." if s.get("separate") else "One set-up, changed event after event.")
        + (f" Scored: every frame for {s['full_rate_s']:g} s after each event, every "
           f"{s['score_every']}-th frame elsewhere (means hold each scored frame until the "
           "next; *back* reads the scored frames)."
           if s.get("score_every", 1) > 1 else ""),
        "",
        "| row | mean PSNR (dB) |", "|---|---|",
    ]
    lines += [f"| {ROW_LABELS.get(r, r)} | {_f(v)} |" for r, v in result["rows"].items()]
    evs = result["events"]
    if evs:
        lines += ["", f"Per event (times in seconds of show after the event; *back*: from then "
                  f"on within {w:g} dB of the oracle until the next event; *worst vs geometry*: "
                  f"the watch row's worst frame against geometry only before its first update; "
                  "*seen*: the first look that distrusted the model (a geometry suspicion or a "
                  "detection); *after seen*: the worst frame against geometry only from then "
                  "to the first update; "
                  "*none / watch vs oracle*: mean over the event's span; *geometry left*: the "
                  "watch row's largest camera-px error against the truth at the span's end; "
                  "*geometry-only*: seconds of the span the watch row showed geometry only):", "",
                  "| event | at (s) | seen (s) | detected (s) | as | mended (s) | back (s) "
                  "| pattern frames | worst vs geometry (dB) | after seen (dB) "
                  "| none vs oracle (dB) | watch vs oracle (dB) "
                  "| geometry left (px) | detections | geometry-only (s) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for e in evs:
            back = e.get("recovered_s")
            back_txt = ("never" if back is None and "recovered_s" in e else _f(back))
            det = e.get("detected_s")
            det_txt = "not detected" if det is None and "detected_s" in e else _f(det)
            lines.append(
                f"| {e['label']} | {e['t']:g} | {_f(e.get('seen_s'))} | {det_txt} | "
                f"{e.get('detected_as') or '–'} | "
                f"{_f(e.get('mended_s'))} | {back_txt} | {e.get('pattern_frames', '–')} | "
                f"{_f(e.get('worst_vs_geometry_db'), '+.2f')} | "
                f"{_f(e.get('worst_after_seen_db'), '+.2f')} | "
                f"{_f(e.get('none_vs_oracle_db'), '+.2f')} | "
                f"{_f(e.get('watch_vs_oracle_db'), '+.2f')} | "
                f"{_f(e.get('geometry_error_px'))} | {e.get('detections', '–')} | "
                f"{_f(e.get('geometry_only_s'), '.1f')} |")
    fa = result.get("false_alarms")
    if fa:
        lines += ["", f"Unchanged set-up, {fa['seconds']:g} s of the clip (cuts included) at "
                  f"{fa['size'][0]}x{fa['size'][1]}, {fa['fps']:g} fps: **{fa['detections']} "
                  f"detection(s)**, {fa['retracted']} of them retracted by the watcher, {fa['updates']} "
                  f"update(s), {fa.get('suspicions', 0)} geometry suspicion(s), "
                  f"{fa['geometry_frames']} frame(s) shown with geometry only."]
    lines += ["", f"Run time {result['seconds']:.0f} s (this machine, loaded).", ""]
    return "\n".join(lines)


def plot_drift(result: dict, path) -> Path:
    """Every row's camera-view PSNR over show time, the events marked, the watch row's
    updates ticked; PNG."""
    path = Path(path)
    fig = new_figure("the drift plot", (13, 5.5), path, ", or pass plot=False / --no-plot")
    ax = fig.subplots()
    frames = [f for f in result["frames"] if f["psnr"]]     # the frames scored
    t = np.array([f["t"] for f in frames])
    for row in result["settings"]["rows"]:
        y = [f["psnr"][row] for f in frames]
        ax.plot(t, y, color=_COLOURS.get(row), label=ROW_LABELS.get(row, row),
                linewidth=1.6 if row in ("watch", "oracle") else 1.0,
                linestyle="--" if row == "geometry" else "-")
    for e in result["events"]:
        ax.axvline(e["t"], color="tab:orange", linewidth=1.2)
        ax.text(e["t"], 1.0, " " + e["label"], rotation=0, ha="left", va="bottom", fontsize=8,
                transform=ax.get_xaxis_transform())
    for u in result.get("updates") or ():
        ax.axvline(u["t"], color="tab:blue", linewidth=0.8, linestyle=":")
    ax.set(xlabel="show time (s)", ylabel="camera-view PSNR (dB)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    fig.savefig(path, dpi=90)
    return path
