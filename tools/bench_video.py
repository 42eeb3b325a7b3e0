#!/usr/bin/env python
"""Per-frame cost of the real-time path, and ``rtdefocus eval --video``, in one run.

Sections (``--sections``, comma-separated; default ``cost``):

``cost``   ``Compensator.compensate()`` at the projector size (default 800x600) with the
           virtual cubicle's oracle kernels, *before* and *after* in this one run: the
           ``--baseline`` revision (default :data:`BASELINE_REV`, a tree without the
           warm-start cost work; extracted with ``git archive`` beside the results) and this tree, one process
           per tree, kind of frame and budget (one Compensator each, as in use), frames
           interleaved round by round. ``--baseline-cl-options`` adds the baseline built with
           extra OpenCL options (``before+opts``): the share of a build flag alone. Two kinds
           of frames: ``still`` (the same photograph again: a paused video, a slide) and ``moving`` (a pan of
           :data:`PAN_PX` input px per frame: every frame new). Per tree and kind: the time per
           iteration ``(t(8) - t(0)) / 8`` and the fixed part ``t(0)`` (the cost model's
           two terms; a moving frame's t(0) includes the first iteration's gradient, computed with
           the warm start), per stage, from the medians and from the minima of the wall time
           (the load of a shared machine only adds time) and from the median CPU time of the
           worker process (all its threads), and the ratios before / after.
``eval``   :func:`rtdefocus.study.eval_video.run_video_eval` (``--quick`` for the small clip).

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
import signal
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tools"))

from bench import git_commit, machine_info, parse_size  # noqa: E402

#: A tree without the warm start's cost work (the naive warm start, the blur over the whole k x k
#: window): the "before" of the cost section, run from a ``git archive`` of this revision.
BASELINE_REV = "834bc2e"
#: Pan of the moving frames, input pixels per frame (~9 projector px at 800x600).
PAN_PX = 6
KINDS = ("still", "moving")
BUDGETS = (0, 8)

#: One tree's side of the cost section, run in its own process (``python -c WORKER TREE W H``):
#: per request line "KIND N" it shows the next frame of that kind (a still photograph, or the
#: next step of a pan) to a Compensator kept for (KIND, N) and answers the seconds of
#: ``compensate(frame, iterations=N, warm_start=True)`` as one JSON line.
WORKER = r"""
import json, os, sys, time
tree, w, h, pan = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
sys.path.insert(0, tree)
extra = os.environ.get("RTDEFOCUS_BENCH_CL_OPTIONS", "").split()
if extra:   # --baseline-cl-options: that tree's programs built with these options too
    import pyopencl as cl
    _build = cl.Program.build
    def _build_with_extra(self, options=None, devices=None, cache_dir=None):
        opts = options.split() if isinstance(options, str) else list(options or [])
        return _build(self, opts + extra, devices, cache_dir)
    cl.Program.build = _build_with_extra
import cv2, numpy as np
import rtdefocus
from rtdefocus import sim
from rtdefocus.compensate import Compensator
from rtdefocus.study.samples import photographs
from rtdefocus.sim import oracle_calibration
procam = sim.VirtualProCam("cubicle", projector_size=(w, h), camera_size=(int(w * 1.6), int(h * 1.6)))
calib = oracle_calibration(procam)
photo = photographs()["astronaut"]
comps, count = {}, {}
def frame(kind, i):
    if kind == "still":
        return photo
    m = np.float32([[1, 0, -pan * i], [0, 1, 0]])
    return cv2.warpAffine(photo, m, photo.shape[1::-1], borderMode=cv2.BORDER_REFLECT)
print(json.dumps({"ready": rtdefocus.__file__}), flush=True)
for line in sys.stdin:
    kind, n = line.split()
    key = (kind, int(n))
    if key not in comps:
        comps[key], count[key] = Compensator(calib, backend="opencl"), 0
    img = frame(kind, count[key])
    count[key] += 1
    c0, t0 = time.process_time(), time.perf_counter()
    comps[key].compensate(img, iterations=key[1], warm_start=True)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    info = comps[key].last_info
    print(json.dumps({"s": dt, "cpu_s": cpu, "stages": info.get("seconds", {}),
                      "start": info.get("start")}), flush=True)
"""


class _Worker:
    """A subprocess running :data:`WORKER` on one source tree, stopped (SIGSTOP) between its
    frames: an idle OpenCL runtime's worker threads would otherwise take CPU from the other
    tree's frames (measured: the per-iteration time doubled with both processes running)."""

    def __init__(self, tree: Path, size, cl_options: str = ""):
        import os
        import subprocess

        env = {**os.environ, "RTDEFOCUS_BENCH_CL_OPTIONS": cl_options}
        self.proc = subprocess.Popen(
            [sys.executable, "-c", WORKER, str(tree), str(size[0]), str(size[1]), str(PAN_PX)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=str(tree), env=env)
        ready = json.loads(self.proc.stdout.readline() or "{}")
        if "ready" not in ready:
            raise RuntimeError(f"the benchmark worker on {tree} did not start")
        self.module = ready["ready"]
        self.proc.send_signal(signal.SIGSTOP)

    def frame(self, kind: str, n: int) -> dict:
        self.proc.send_signal(signal.SIGCONT)
        self.proc.stdin.write(f"{kind} {n}\n")
        self.proc.stdin.flush()
        reply = json.loads(self.proc.stdout.readline())
        self.proc.send_signal(signal.SIGSTOP)
        return reply

    def close(self) -> None:
        self.proc.send_signal(signal.SIGCONT)
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


def _baseline_tree(rev: str, dest: Path) -> Path | None:
    """``git archive`` of ``rev`` under ``dest`` with its kernels inside the package (so that
    ``rtdefocus.kernels`` is that revision's, not this tree's editable install); None without
    git history (e.g. a copied tree)."""
    import shutil
    import subprocess

    tree = dest / f"baseline-{rev}"
    if (tree / "rtdefocus" / "kernels").is_dir():
        return tree
    tree.mkdir(parents=True, exist_ok=True)
    try:
        data = subprocess.run(["git", "archive", rev], cwd=REPO, capture_output=True,
                              check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=data, check=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        print(f"  no baseline: git archive {rev} failed ({exc})")
        return None
    shutil.copytree(tree / "kernels", tree / "rtdefocus" / "kernels")
    return tree


def section_cost(args, out: dict) -> None:
    """Before (``--baseline`` revision) and after (this tree), each in its own process, frames
    interleaved round by round so that a shared machine's load falls on both alike."""
    trees = {"after": REPO}
    options = {}
    if args.baseline:
        base = _baseline_tree(args.baseline, args.out)
        if base is not None:
            trees = {"before": base, **trees}
            if args.baseline_cl_options:
                # the baseline again with only these build options changed: what they alone give
                trees = {"before": base, "before+opts": base, "after": REPO}
                options["before+opts"] = args.baseline_cl_options
    keys = [(v, k, n) for v in trees for k in KINDS for n in BUDGETS]
    # One process per (tree, kind, budget), each with its one Compensator, as in use: four
    # Compensators in one process made a moving frame's start ~1.5x slower than a single one's
    # (their buffers compete for the caches), more so for the tree with more state.
    workers = {key: _Worker(trees[key[0]], args.size, options.get(key[0], "")) for key in keys}
    print("  trees: " + ", ".join(f"{v} {workers[v, KINDS[0], BUDGETS[0]].module}" for v in trees))
    times = {key: [] for key in keys}
    cpu = {key: [] for key in keys}
    stages = {key: {} for key in keys}
    for rnd in range(args.warmup + args.repeats):
        for v, k, n in keys:
            r = workers[v, k, n].frame(k, n)
            if rnd >= args.warmup:
                times[v, k, n].append(r["s"])
                cpu[v, k, n].append(r["cpu_s"])
                for st, x in r["stages"].items():
                    stages[v, k, n].setdefault(st, []).append(x)
    for w in workers.values():
        w.close()
    rows = []
    lo, hi = BUDGETS
    for v in trees:
        for k in KINDS:
            t_lo = statistics.median(times[v, k, lo])
            t_hi = statistics.median(times[v, k, hi])
            per_it = (t_hi - t_lo) / (hi - lo)
            row = {"variant": v, "tree": str(trees[v]), "frames": k,
                   "size": f"{args.size[0]}x{args.size[1]}", "fixed_ms": 1e3 * (t_lo - lo * per_it),
                   "per_iteration_ms": 1e3 * per_it, "frame_ms": {n: 1e3 * statistics.median(
                       times[v, k, n]) for n in BUDGETS},
                   "stages_ms": {n: {st: 1e3 * statistics.median(x)
                                     for st, x in stages[v, k, n].items()} for n in BUDGETS},
                   "repeats": args.repeats}
            # the same from the fastest frames: on a shared machine the load only adds time
            m_lo, m_hi = min(times[v, k, lo]), min(times[v, k, hi])
            row["per_iteration_min_ms"] = 1e3 * (m_hi - m_lo) / (hi - lo)
            row["fixed_min_ms"] = 1e3 * m_lo - lo * row["per_iteration_min_ms"]
            # and in CPU time (all the process's threads: host, OpenCL and GL workers): the
            # work a frame costs, whatever else runs on the machine
            c_lo, c_hi = statistics.median(cpu[v, k, lo]), statistics.median(cpu[v, k, hi])
            row["per_iteration_cpu_ms"] = 1e3 * (c_hi - c_lo) / (hi - lo)
            row["fixed_cpu_ms"] = 1e3 * c_lo - lo * row["per_iteration_cpu_ms"]
            rows.append(row)
            print(f"  {v:11s} {k:6s} fixed {row['fixed_ms']:7.1f} ms  per iteration "
                  f"{row['per_iteration_ms']:6.1f} ms  ({lo} it: {row['frame_ms'][lo]:.1f} ms: "
                  + ", ".join(f"{st} {x:.1f}" for st, x in row["stages_ms"][lo].items()) + ")",
                  flush=True)
    print(f"\n(fixed = t({lo}) - {lo} x per iteration, per iteration = (t({hi}) - t({lo})) / "
          f"{hi - lo}; {args.repeats} frames)\n")
    print("| frames | from | fixed before | fixed after | x | per iteration before | after | x |"
          "\n|---|---|---|---|---|---|---|---|")
    by = {(r["variant"], r["frames"]): r for r in rows}
    for k in KINDS:
        a, b = by[("after", k)], by.get(("before", k))
        for stat, sfx in (("medians", ""), ("minima", "_min"), ("CPU time", "_cpu")):
            fa, pa = a[f"fixed{sfx}_ms"], a[f"per_iteration{sfx}_ms"]
            if b is None:
                print(f"| {k} | {stat} | - | {fa:.1f} ms | - | - | {pa:.1f} ms | - |")
                continue
            fb, pb = b[f"fixed{sfx}_ms"], b[f"per_iteration{sfx}_ms"]
            a[f"fixed_ratio{sfx}"] = fb / fa if fa > 0 else float("inf")
            a[f"per_iteration_ratio{sfx}"] = pb / pa if pa > 0 else float("inf")
            print(f"| {k} | {stat} | {fb:.1f} ms | {fa:.1f} ms | {a[f'fixed_ratio{sfx}']:.2f} | "
                  f"{pb:.1f} ms | {pa:.1f} ms | {a[f'per_iteration_ratio{sfx}']:.2f} |")
    out["cost"] = rows


def section_eval(args, out: dict) -> None:
    from rtdefocus.study.eval_video import run_video_eval

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
    ap.add_argument("--baseline", default=BASELINE_REV,
                    help=f"cost: the revision measured as 'before' (default {BASELINE_REV}, "
                         "without the warm start's cost work; '' for none)")
    ap.add_argument("--baseline-cl-options", default="",
                    help="cost: also run the baseline with these OpenCL build options added "
                         "(e.g. '-cl-denorms-are-zero'), as the variant 'before+opts'")
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
