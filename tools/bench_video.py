#!/usr/bin/env python
"""Per-frame cost of the real-time path, and ``rtdefocus eval --video``, in one run.

Sections (``--sections``, comma-separated; default ``cost``):

``cost``   ``Compensator.compensate()`` on a photograph at the projector size (default 800x600)
           with the virtual cubicle's oracle kernels, per variant, all in this one run:
           ``full-window`` every tap of the k x k PSF window (the blur before issue 10),
           ``support`` only the taps inside each PSF group's exact support (the same operator;
           the default now), ``trim-999`` the PSFs cut to 99.9 % of their energy
           (:func:`rtdefocus.reference.blur.trim_psfs`). Per variant: the fixed part (median
           frame time at 0 iterations, per stage) and the time per iteration ((t(8) - t(0)) / 8,
           medians), the ratio to ``full-window``, and for trimming the camera-view PSNR change
           against the untrimmed kernels at the same budget.
``eval``   :func:`rtdefocus.eval_video.run_video_eval` (``--quick`` for the small clip).

Timings are medians of ``--repeats`` frames after ``--warmup`` (>= 3), every frame synchronised
(``compensate()`` returns host data). Writes ``bench_results/video-<commit>-<device>.json``.

Example::

    .venv/bin/python tools/bench_video.py --sections cost --repeats 7
    .venv/bin/python tools/bench_video.py --sections cost,eval --quick --out "$OUT"
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tools"))

from bench import git_commit, machine_info, parse_size  # noqa: E402

VARIANTS = ("full-window", "support", "trim-999")
ITERS = 8


def _time_frame(comp, image, iterations: int, stages: dict) -> float:
    t0 = time.perf_counter()
    comp.compensate(image, iterations=iterations, warm_start=True)
    dt = time.perf_counter() - t0
    for k, v in comp.last_info["seconds"].items():
        stages.setdefault(k, []).append(v)
    return dt


def section_cost(args, out: dict) -> None:
    from rtdefocus import sim
    from rtdefocus.cl.blur import ClBlur
    from rtdefocus.compensate import Compensator
    from rtdefocus.reference.blur import psf_support, trim_psfs
    from rtdefocus.samples import photographs
    from rtdefocus.scores import camera_view, psnr, rect_mask
    from rtdefocus.sim import oracle_calibration

    procam = sim.VirtualProCam("cubicle", projector_size=args.size,
                               camera_size=(int(args.size[0] * 1.6), int(args.size[1] * 1.6)))
    calib = oracle_calibration(procam)
    image = photographs()["astronaut"]
    psfs = calib.psfs
    print(f"oracle cubicle kernels: {len(psfs)} PSFs of {psfs.shape[1]}x{psfs.shape[2]}, "
          f"exact support half-widths {psf_support(psfs).tolist()}, at 99.9 % energy "
          f"{psf_support(psfs, 0.999).tolist()}")
    comps, frames = {}, {}
    for variant in VARIANTS:
        c = calib
        ClBlur.use_support = variant != "full-window"
        if variant == "trim-999":
            c = replace(calib, psfs=trim_psfs(calib.psfs, 0.999))
        comps[variant] = Compensator(c, backend="opencl")
        ClBlur.use_support = True
    # Interleaved: every round times each variant in turn, so that the load of a shared
    # machine falls on all of them alike; medians over the rounds.
    times = {(v, n): [] for v in VARIANTS for n in (0, ITERS)}
    stages = {(v, n): {} for v in VARIANTS for n in (0, ITERS)}
    for rnd in range(args.warmup + args.repeats):
        for v in VARIANTS:
            for n in (0, ITERS):
                dt = _time_frame(comps[v], image, n, stages[v, n] if rnd >= args.warmup else {})
                if rnd >= args.warmup:
                    times[v, n].append(dt)
    rows = []
    for v in VARIANTS:
        comp = comps[v]
        fixed = 1e3 * statistics.median(times[v, 0])
        per_it = 1e3 * (statistics.median(times[v, ITERS]) - statistics.median(times[v, 0])) / ITERS
        st0 = {k: 1e3 * statistics.median(x) for k, x in stages[v, 0].items()}
        stn = {k: 1e3 * statistics.median(x) for k, x in stages[v, ITERS].items()}
        comp.reset()
        frames[v] = comp.compensate(image, iterations=ITERS, warm_start=False)
        row = {"variant": v, "size": f"{args.size[0]}x{args.size[1]}", "fixed_ms": fixed,
               "per_iteration_ms": per_it, "stages_0it_ms": st0, "stages_8it_ms": stn,
               "frame_8it_ms": 1e3 * statistics.median(times[v, ITERS]),
               "repeats": args.repeats}
        rows.append(row)
        print(f"  {v:12s} fixed {fixed:7.1f} ms  per iteration {per_it:7.1f} ms  "
              f"(8 it: {row['frame_8it_ms']:.1f} ms)  stages at 0 it: "
              + ", ".join(f"{k} {x:.1f}" for k, x in st0.items()), flush=True)
    base = rows[0]
    for r in rows:
        r["fixed_ratio"] = base["fixed_ms"] / r["fixed_ms"]
        r["per_iteration_ratio"] = base["per_iteration_ms"] / max(r["per_iteration_ms"], 1e-9)
    # what trimming costs in quality: camera views at the same budget (8 cold iterations)
    rect = calib.display_rect((image.shape[1], image.shape[0]))
    wc, hc = procam.camera_size
    mask = rect_mask(rect, (hc, wc))
    warped = Compensator(calib, method="none").warp(image)
    ref = camera_view(procam, calib, warped, sharp=True)
    geo = psnr(camera_view(procam, calib, warped), ref, mask)
    for r in rows:
        p = psnr(camera_view(procam, calib, frames[r["variant"]]), ref, mask)
        r["psnr_8it_gain_db"] = p - geo
    print("\n| variant | fixed ms | per iteration ms | x fixed | x per iteration | "
          "gain at 8 it (dB) |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['variant']} | {r['fixed_ms']:.1f} | {r['per_iteration_ms']:.1f} | "
              f"{r['fixed_ratio']:.2f} | {r['per_iteration_ratio']:.2f} | "
              f"{r['psnr_8it_gain_db']:+.2f} |")
    out["cost"] = rows


def section_eval(args, out: dict) -> None:
    from rtdefocus.eval_video import run_video_eval

    result = run_video_eval(args.out / "eval_video", quick=args.quick, step=print,
                            plot=not args.no_plot)
    print(result["markdown"])
    out["eval"] = {"summary": result["summary"], "settings": result["settings"],
                   "seconds": result["seconds"], "files": result["files"]}


SECTIONS = {"cost": section_cost, "eval": section_eval}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="example:\n  .venv/bin/python tools/bench_video.py "
                                        "--sections cost,eval --quick")
    ap.add_argument("--sections", default="cost", help=f"comma-separated from {list(SECTIONS)}")
    ap.add_argument("--size", type=parse_size, default=(800, 600), help="projector WxH (800x600)")
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--quick", action="store_true", help="eval: the small clip")
    ap.add_argument("--no-plot", action="store_true", help="eval: no video.png")
    ap.add_argument("--out", type=Path, default=REPO / "bench_results")
    args = ap.parse_args(argv)
    names = [s.strip() for s in args.sections.split(",") if s.strip()]
    if any(n not in SECTIONS for n in names) or args.warmup < 3:
        ap.error(f"sections from {list(SECTIONS)}; --warmup >= 3")
    from rtdefocus.cl.runtime import get_runtime

    runtime = get_runtime()
    info = machine_info(runtime)
    print(f"machine: {info['cpu']}, {info['cores']} cores; device: {info.get('device')}; "
          f"load average {info.get('loadavg_start')}")
    args.out.mkdir(parents=True, exist_ok=True)
    out: dict = {"machine": info, "commit": git_commit(), "sections": names}
    t0 = time.perf_counter()
    for n in names:
        print(f"[{n}]", flush=True)
        SECTIONS[n](args, out)
    out["wall_s"] = time.perf_counter() - t0
    slug = re.sub(r"[^A-Za-z0-9]+", "-", runtime.device.name.strip()).strip("-").lower()
    path = args.out / f"video-{git_commit()}-{slug}.json"
    path.write_text(json.dumps(out, indent=1, default=_json))
    print(f"\nwrote {path}")
    return 0


def _json(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, (tuple, set)):
        return list(o)
    return str(o)


if __name__ == "__main__":
    sys.exit(main())
