"""The ``rtdefocus eval --video`` report: the markdown table and the per-frame plot."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .evalreport import new_figure

__all__ = ["video_markdown", "plot_video", "MODE_LABELS"]


def mode_label(mode: str) -> str:
    """Human words for a mode name (``warm-2``, ``cold-4``, ``fps-30``, ``offline``)."""
    kind, _, n = mode.partition("-")
    if kind == "warm":
        return f"{n} it/frame, warm start"
    if kind == "cold":
        return f"{n} it/frame, cold start"
    if kind == "fps":
        return f"{n} fps wall-clock budget (warm)"
    if kind == "window":
        n, _, k = n.partition("-s")
        return (f"the window at {n} fps (the player, live)" if not k else
                f"the window at {n} fps, a device {k}x slower")
    if kind == "geowindow":
        return f"the window at {n} fps, geometry only"
    return MODE_LABELS.get(mode, mode)


MODE_LABELS = {"offline": "offline (cold, full budget)"}


def _f(v, spec="+.1f", suffix="") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:{spec}}{suffix}"


def video_markdown(result: dict) -> str:
    """The report: settings, then one row per mode: the mean PSNR gain over geometry only per
    segment with its share of the offline gain, the still gain after 1 s, the frames to recover
    after the cut, and the median iterations and ms per frame (this machine)."""
    s, summ, segs = result["settings"], result["summary"], result["segments"]
    off = s["offline_iterations"]
    m = result.get("machine", {})
    lines = [
        "# Live video through the real-time path (`rtdefocus eval --video`)", "",
        f"Projector {s['projector_size'][0]}x{s['projector_size'][1]}, camera "
        f"{s['camera_size'][0]}x{s['camera_size'][1]}, preset `{s['preset']}`, kernels: "
        f"{s['kernels']}; clip {s['clip_size'][0]}x{s['clip_size'][1]}, "
        f"{len(result['frames'])} frames ("
        + ", ".join(f"{g['name']} {g['frames']}" for g in s["segments"]) + "); solver "
        f"{s['solver']} on {s['backend']} ({m.get('device', '?')}; {m.get('cpu', '?')}, "
        f"{m.get('cores', '?')} cores, load average {_load(m)}).", "",
        "Mean camera-view PSNR gain over geometry only per segment (dB), scored against the "
        "sharp capture of the same warp inside the display rectangle; in brackets the share of "
        f"the offline gain ({off} cold iterations per frame). *still @1 s*: gain on the still "
        f"segment's frame {_still_frame(summ)} (1 s at {s['clip_fps']} fps, or its last frame "
        "when shorter); *cut*: frames after the cut "
        "until the view is at least as good as a 1-iteration cold start and stays so; *it*, "
        "*ms*: median iterations and milliseconds of `compensate()` per frame (wall-clock modes "
        "pick their iterations from these times, on this loaded machine; every frame is "
        "compensated). *The window*: the clip played live through the player, as the projector "
        "window shows it: a dropped frame's time shows the last frame shown, a frame shown "
        "with geometry only to keep up counts 0 iterations, a frame shown late (more than two "
        "periods after it arrived) is scored as shown and counted.", "",
    ]
    head = "| mode | " + " | ".join(segs) + " | still @1 s | cut | it | ms |"
    lines += [head, "|" + "---|" * (len(segs) + 5)]
    for mode in result["modes"]:
        r = summ[mode]
        cells = []
        for seg in segs:
            share = r["share"].get(seg)
            cells.append(_f(r["gain"][seg]) + (f" ({_f(100 * share, '.0f', '%')})"
                                                 if share is not None and mode != "offline" else ""))
        st = r.get("still_after_1s") or {}
        still = _f(st.get("gain")) + (f" ({_f(100 * st['share'], '.0f', '%')})"
                                      if st and mode != "offline" else "")
        rec = r.get("cut_recovery_frames")
        cut = "never" if rec is None and "cut_recovery_frames" in r else _f(rec, "d")
        lines.append(f"| {mode_label(mode)} | " + " | ".join(cells) + f" | {still} | {cut} | "
                     f"{_f(r['iterations_median'], 'g')} | {_f(r['ms_median'], '.0f')} |")
    for mode, w in (result.get("window") or {}).items():
        start = (f", {w['start_only']} from the previous correction carried along the motion"
                 if w.get("start_only") else "")
        caught = (f" ({w['geometry_only']} with geometry only to keep up{start})"
                  if mode.startswith("window") else "")
        copies = w.get("dropped_copies", 0)
        copies = f" ({copies} of them copies of the picture on the screen)" if copies else ""
        late = f", {w['late']} of them late" if w.get("late") else ""
        lines += ["", f"{mode_label(mode)}: {w['shown']} frames shown{caught}{late}, "
                  f"{w['dropped']} dropped{copies}, {w['fps']:.1f} fps end to end."]
    lines += ["", f"Run time {result['seconds']:.0f} s.", ""]
    return "\n".join(lines)


def _still_frame(summ: dict):
    for r in summ.values():
        if r.get("still_after_1s"):
            return r["still_after_1s"]["frame"]
    return "–"


def _load(m: dict) -> str:
    la = m.get("loadavg")
    return "/".join(f"{v:.1f}" for v in la) if la else "?"


def plot_video(result: dict, path) -> Path:
    """Per-frame PSNR gain over geometry only for every mode, segments shaded; PNG."""
    path = Path(path)
    fig = new_figure("the video plot", (13, 6), path, ", or pass plot=False / --no-plot")
    frames = result["frames"]
    ax = fig.subplots()
    x = np.arange(len(frames))
    styles = {"warm": "-", "cold": ":", "fps": "--", "window": "-.", "geowindow": "-."}
    for mode in result["modes"]:
        y = [f["gain"][mode] for f in frames]
        kind = mode.split("-")[0]
        kw = {"color": "k", "linewidth": 2} if mode == "offline" else {}
        ax.plot(x, y, styles.get(kind, "-"), label=mode_label(mode), **kw)
    ax.axhline(0.0, color="grey", linewidth=1, label="geometry only")
    start = 0
    for i, g in enumerate(result["settings"]["segments"]):
        if i % 2:
            ax.axvspan(start - 0.5, start + g["frames"] - 0.5, color="0.92", zorder=0)
        ax.text(start + g["frames"] / 2 - 0.5, 1.0, g["name"], ha="center", va="bottom",
                transform=ax.get_xaxis_transform(), fontsize=9)
        start += g["frames"]
    ax.set(xlabel="frame", ylabel="PSNR gain over geometry only (dB)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, ncol=2, loc="lower left")
    fig.savefig(path, dpi=90)
    return path
