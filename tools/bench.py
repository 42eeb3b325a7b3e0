#!/usr/bin/env python
"""Benchmarks of the device compensation against the NumPy reference and the cv2.filter2D form.

Per section, every row is one operation at one size and kernel radius, timed as the median
(and minimum) of ``--repeats`` runs after ``--warmup`` (>= 3) warm-up runs, each run bracketed
by ``queue.finish()``. The kernel field is a realistic one: per half of the frame (the two walls
of a corner) a 3x3 lattice of pillbox PSFs with radii 0.6..1.0 r, blended bilinearly
(:func:`rtdefocus.reference.blur.synthetic_field`).

Sections (``--sections``, comma-separated; all by default):

``blur``        OpenCL forward F P and adjoint F^T r, both kernel shapes ("cpu", "gpu").
``reference``   the same two operations in the NumPy reference (fewer repeats at 1080p).
``filter2d``    the same two operations as a Python user would write them with cv2.filter2D.

More sections (e.g. "iteration", "compensate") plug in through :data:`SECTIONS`: a function
``f(bench: Bench) -> None`` that calls ``bench.record(...)`` per row.

Example::

    .venv/bin/python tools/bench.py --quick
    .venv/bin/python tools/bench.py --sections blur --sizes 800x600 --radii 5

Writes ``bench_results/bench-<git commit>-<device>.json`` and prints the machine, the device
and a table with the speed-up of OpenCL over the NumPy reference and the filter2D form.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rtdefocus.cli.common import parse_size  # noqa: E402
from rtdefocus.reference.blur import (  # noqa: E402
    blur_adjoint,
    blur_adjoint_filter2d,
    blur_forward,
    blur_forward_filter2d,
    synthetic_field,
)
from rtdefocus.study.machine import machine_info  # noqa: E402

# The paper's own figure for one iteration at 800x600 on one core (for the "iteration" section).
PAPER_ITERATION_S = (10.0, 12.0)


# ---------------------------------------------------------------------------------- machinery
@dataclass
class Bench:
    """What every section gets: options, the OpenCL runtime, cached fields, and ``record``."""

    sizes: list[tuple[int, int]]
    radii: list[float]
    warmup: int
    repeats: int
    quick: bool
    runtime: object = None
    rows: list[dict] = field(default_factory=list)
    _fields: dict = field(default_factory=dict)

    def field(self, size: tuple[int, int], radius: float):
        """``(psfs, idx, wts)`` of the synthetic field for ``size`` = (w, h) (cached)."""
        key = (size, radius)
        if key not in self._fields:
            self._fields[key] = synthetic_field(size[0], size[1], radius)
        return self._fields[key]

    def image(self, size: tuple[int, int], channels: int = 3, seed: int = 0) -> np.ndarray:
        """A random planar (C, H, W) float32 image in [0, 1]."""
        return np.random.default_rng(seed).random((channels, size[1], size[0]), np.float32)

    def time(self, fn, sync=None, warmup: int | None = None, repeats: int | None = None):
        """Times of ``repeats`` calls of ``fn`` after ``warmup`` calls; ``sync`` after each."""
        warmup = self.warmup if warmup is None else warmup
        repeats = self.repeats if repeats is None else repeats
        sync = sync or (lambda: None)
        sync()
        for _ in range(warmup):
            fn()
            sync()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            sync()
            times.append(time.perf_counter() - t0)
        return times

    def record(self, section: str, op: str, impl: str, size, radius, times, **extra):
        """Add one row (times in seconds) and print it as it comes."""
        row = {"section": section, "op": op, "impl": impl, "size": f"{size[0]}x{size[1]}",
               "radius": radius, "median_ms": 1e3 * statistics.median(times),
               "min_ms": 1e3 * min(times), "repeats": len(times), **extra}
        self.rows.append(row)
        print(f"  {section:10s} {op:10s} {impl:14s} {row['size']:>10s} r={radius:<4g} "
              f"median {row['median_ms']:9.2f} ms   min {row['min_ms']:9.2f} ms  "
              f"(n={len(times)})", flush=True)
        return row


def _large(size) -> bool:
    return size[0] * size[1] > 1_000_000


# ------------------------------------------------------------------------------------ sections
def section_blur(bench: Bench) -> None:
    """OpenCL forward and adjoint, both kernel shapes, on (3, H, W) device arrays."""
    import pyopencl.array as cla

    from rtdefocus.cl.blur import ClBlur

    q = bench.runtime.queue
    for size in bench.sizes:
        for radius in bench.radii:
            psfs, idx, wts = bench.field(size, radius)
            src = cla.to_device(q, bench.image(size))
            dst = cla.empty_like(src)
            native = "gpu" if bench.runtime.is_gpu else "cpu"
            for variant in ("cpu", "gpu"):
                # the other shape is there to be checked, not raced: it can be 100x slower
                repeats = bench.repeats if variant == native else min(bench.repeats, 3)
                if variant != native and bench.quick and (_large(size) or radius > 6):
                    continue
                t0 = time.perf_counter()
                blur = ClBlur(bench.runtime, psfs, idx, wts, channels=3, variant=variant)
                setup_s = time.perf_counter() - t0
                for op, fn in (("forward", blur.forward), ("adjoint", blur.adjoint)):
                    times = bench.time(partial(fn, src, dst), q.finish, repeats=repeats)
                    bench.record("blur", op, f"opencl-{variant}", size, radius, times,
                                 setup_s=setup_s)
                del blur


def section_reference(bench: Bench) -> None:
    """The NumPy reference (gather form, float32): the baseline of every ratio."""
    for size in bench.sizes:
        for radius in bench.radii:
            if bench.quick and (_large(size) or radius > 6):
                continue
            psfs, idx, wts = bench.field(size, radius)
            img = bench.image(size)
            n = 1 if _large(size) or radius > 6 else 3
            for op, fn in (("forward", blur_forward), ("adjoint", blur_adjoint)):
                times = bench.time(partial(fn, img, psfs, idx, wts), warmup=0, repeats=n)
                bench.record("reference", op, "numpy", size, radius, times)


def section_filter2d(bench: Bench) -> None:
    """The form a Python user writes: cv2.filter2D with every PSF, blended per pixel."""
    import cv2

    for size in bench.sizes:
        for radius in bench.radii:
            psfs, idx, wts = bench.field(size, radius)
            img = bench.image(size)
            n = min(bench.repeats, 3 if _large(size) else 5)
            for op, fn in (("forward", blur_forward_filter2d),
                           ("adjoint", blur_adjoint_filter2d)):
                times = bench.time(partial(fn, img, psfs, idx, wts), warmup=1, repeats=n)
                bench.record("filter2d", op, "cv2.filter2D", size, radius, times,
                             cv2_threads=cv2.getNumThreads())


def _iteration_times(bench: Bench, solver, n: int, warmup: int | None = None,
                     repeats: int | None = None) -> list[float]:
    """Seconds per iteration: (run(1 + n) - run(1)) / n, so the start-up forward blur and
    metric pass of each run are not counted (medians of both)."""
    short = bench.time(lambda: solver.run(1), solver.ops.finish, warmup, repeats)
    long = bench.time(lambda: solver.run(1 + n), solver.ops.finish, warmup, repeats)
    base = statistics.median(short)
    return [max(t - base, 0.0) / n for t in long]


def section_iteration(bench: Bench) -> None:
    """One full solver iteration (gradient, step, line search/momentum, reductions): OpenCL
    (FISTA and PG, the device's own kernel shape) vs the NumPy reference and the cv2.filter2D
    form of the same NumPy solver; the paper needed 10-12 s at 800x600 on one core."""
    from rtdefocus.compensate.backends import make_solver
    from rtdefocus.reference.metric import DEFAULT_WEIGHTS, Metric

    metric = Metric.ycbcr(DEFAULT_WEIGHTS)
    for size in bench.sizes:
        for radius in bench.radii:
            psfs, idx, wts = bench.field(size, radius)
            target = bench.image(size, seed=1)
            for name in ("fista", "pg"):
                s = make_solver(psfs, idx, wts, metric, backend="opencl", solver=name,
                                runtime=bench.runtime)
                s.ops.upload(target, s.target)
                s.start_from_target()
                times = _iteration_times(bench, s, 10, warmup=3, repeats=max(3, bench.repeats // 3))
                paper = 1e3 * PAPER_ITERATION_S[0] / (1e3 * statistics.median(times))
                bench.record("iteration", name, "opencl", size, radius, times,
                             x_paper_low=paper if size == (800, 600) else None)
                del s
            for form, impl in (("filter2d", "cv2.filter2D"), ("gather", "numpy")):
                if form == "gather" and (bench.quick and (_large(size) or radius > 6)):
                    continue
                s = make_solver(psfs, idx, wts, metric, backend="numpy", solver="fista",
                                blur=form)
                s.ops.upload(target, s.target)
                s.start_from_target()
                n = 1 if (_large(size) or radius > 6 or form == "gather") else 2
                times = _iteration_times(bench, s, n, warmup=0, repeats=1 if form == "gather" else 2)
                bench.record("iteration", "fista", impl, size, radius, times)
    _iteration_summary(bench.rows)


def _fmt_ms(v, w: int = 9) -> str:
    return f"{v:{w}.1f}" if v is not None else f"{'-':>{w}s}"


def _ratio(v, base, w: int = 8) -> str:
    return f"{v / base:{w}.0f}" if v is not None and base else f"{'-':>{w}s}"


def _iteration_summary(rows: list[dict]) -> None:
    it = [r for r in rows if r["section"] == "iteration"]
    keys = sorted({(r["size"], r["radius"]) for r in it})
    print(f"\n  {'size':>10s} {'r':>4s} {'fista cl':>9s} {'pg cl':>9s} {'filter2D':>9s} "
          f"{'numpy':>9s} {'x filter2D':>10s} {'x numpy':>8s} {'x paper':>8s}   (ms per iteration)")
    for size, radius in keys:
        med = {}
        for r in it:
            if (r["size"], r["radius"]) == (size, radius):
                med[r["op"], r["impl"]] = r["median_ms"]
        f, p = med.get(("fista", "opencl")), med.get(("pg", "opencl"))
        f2, n = med.get(("fista", "cv2.filter2D")), med.get(("fista", "numpy"))
        paper = _ratio(1e3 * PAPER_ITERATION_S[0], f) if size == "800x600" else f"{'-':>8s}"
        print(f"  {size:>10s} {radius:4g} {_fmt_ms(f)} {_fmt_ms(p)} {_fmt_ms(f2)} {_fmt_ms(n)} "
              f"{_ratio(f2, f, 10)} {_ratio(n, f)} {paper}")


def section_compensate(bench: Bench) -> None:
    """``Compensator.compensate`` end to end (GL warp, decode, solve with the default budget,
    encode, read-back) on the virtual cubicle at each size, with the synthetic kernel field of
    each radius; a video's steady state (warm start) and a cold first frame."""
    from dataclasses import replace

    from rtdefocus import sim
    from rtdefocus.compensate import Compensator
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.study.samples import photographs

    photo = photographs()["astronaut"]
    for size in bench.sizes:
        procam = sim.VirtualProCam("cubicle", projector_size=size, camera_size=(1280, 960))
        base = oracle_calibration(procam)
        for radius in bench.radii:
            psfs, idx, wts = bench.field(size, radius)
            calib = replace(base, psfs=psfs, pix_idx=idx, pix_wts=wts,
                            psf_points_proj=np.zeros((len(psfs), 2), np.float32),
                            psf_plane=np.zeros(len(psfs), np.int32))
            comp = Compensator(calib, backend="opencl")
            stages: dict[str, list[float]] = {}

            def frame(comp=comp, stages=stages):
                comp.compensate(photo)
                for k, v in comp.last_info["seconds"].items():
                    stages.setdefault(k, []).append(v)

            times = bench.time(frame, warmup=3, repeats=max(3, bench.repeats // 2))
            per_stage = {k: 1e3 * statistics.median(v) for k, v in stages.items()}
            bench.record("compensate", "warm", f"opencl-{comp.iterations}it", size, radius, times,
                         stages_ms=per_stage)
            cold = bench.time(lambda comp=comp: (comp.reset(), comp.compensate(photo)), warmup=1,
                              repeats=3)
            bench.record("compensate", "cold", f"opencl-{comp.iterations}it", size, radius, cold)
            print("    stages (median ms): " + ", ".join(f"{k} {v:.1f}" for k, v in per_stage.items()))


#: name -> function(bench); the solver's "iteration" and "compensate" sections register here.
SECTIONS = {
    "blur": section_blur,
    "reference": section_reference,
    "filter2d": section_filter2d,
    "iteration": section_iteration,
    "compensate": section_compensate,
}


# ------------------------------------------------------------------------------ report, files
def git_commit() -> str:
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO,
                             capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=REPO, capture_output=True, text=True).stdout.strip()
        return rev + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "nogit"


def summary_table(rows: list[dict]) -> str:
    """Per (op, size, radius): OpenCL medians and their speed-up over NumPy and filter2D."""
    def median(section, impl, op, size, radius):
        for r in rows:
            if (r["section"], r["impl"], r["op"], r["size"], r["radius"]) == (
                    section, impl, op, size, radius):
                return r["median_ms"]
        return None

    keys = sorted({(r["op"], r["size"], r["radius"]) for r in rows if r["section"] == "blur"},
                  key=lambda k: (k[1], k[2], k[0]))
    lines = [f"{'op':8s} {'size':>10s} {'r':>4s} {'cl-cpu ms':>10s} {'cl-gpu ms':>10s} "
             f"{'numpy ms':>10s} {'filter2D ms':>12s} {'x numpy':>8s} {'x filter2D':>10s}"]
    for op, size, radius in keys:
        cpu = median("blur", "opencl-cpu", op, size, radius)
        gpu = median("blur", "opencl-gpu", op, size, radius)
        ref = median("reference", "numpy", op, size, radius)
        f2d = median("filter2d", "cv2.filter2D", op, size, radius)
        best = min(v for v in (cpu, gpu) if v is not None)

        def fmt(v, w=10):
            return f"{v:{w}.2f}" if v is not None else f"{'-':>{w}s}"

        def ratio(v, best=best):
            return f"{v / best:8.0f}" if v is not None else f"{'-':>8s}"

        lines.append(f"{op:8s} {size:>10s} {radius:4g} {fmt(cpu)} {fmt(gpu)} {fmt(ref)} "
                     f"{fmt(f2d, 12)} {ratio(ref)} {ratio(f2d):>10s}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example:\n  .venv/bin/python tools/bench.py --quick --sections blur,filter2d")
    ap.add_argument("--sections", default=",".join(SECTIONS),
                    help=f"comma-separated, from: {', '.join(SECTIONS)} (default: all)")
    ap.add_argument("--sizes", default="800x600,1920x1080",
                    help="comma-separated WIDTHxHEIGHT (default: 800x600,1920x1080)")
    ap.add_argument("--radii", default="5,10", help="kernel radii in px (default: 5,10)")
    ap.add_argument("--warmup", type=int, default=3, help="warm-up runs (>= 3; default 3)")
    ap.add_argument("--repeats", type=int, default=15, help="timed runs (default 15)")
    ap.add_argument("--quick", action="store_true",
                    help="fewer repeats; NumPy reference only at the small size and radius")
    ap.add_argument("--out", type=Path, default=REPO / "bench_results",
                    help="folder of the JSON results (default: bench_results/)")
    args = ap.parse_args(argv)

    names = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = [s for s in names if s not in SECTIONS]
    if unknown:
        ap.error(f"unknown section(s) {unknown}; choose from {list(SECTIONS)}")
    if args.warmup < 3:
        ap.error("--warmup must be at least 3 (the first runs include compilation and caches)")
    try:
        sizes = [parse_size(s) for s in args.sizes.split(",")]
        radii = [float(r) for r in args.radii.split(",")]
    except (argparse.ArgumentTypeError, ValueError) as exc:
        ap.error(str(exc))
    repeats = min(args.repeats, 7) if args.quick else args.repeats

    from rtdefocus.cl.runtime import get_runtime
    from rtdefocus.errors import DeviceError
    try:
        runtime = get_runtime()
    except DeviceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    bench = Bench(sizes=sizes, radii=radii, warmup=args.warmup, repeats=repeats,
                  quick=args.quick, runtime=runtime)
    info = machine_info(runtime)
    print(f"machine: {info['cpu']}, {info['cores']} cores; device: {info.get('device')} "
          f"[{info.get('opencl')}]; load average {info.get('loadavg')}")
    t0 = time.perf_counter()
    for name in names:
        print(f"[{name}]", flush=True)
        SECTIONS[name](bench)
    try:
        info["loadavg_end"] = os.getloadavg()
    except OSError:
        pass
    print("\n" + summary_table(bench.rows))

    args.out.mkdir(parents=True, exist_ok=True)
    slug = re.sub(r"[^A-Za-z0-9]+", "-", runtime.device.name.strip()).strip("-").lower()
    path = args.out / f"bench-{git_commit()}-{slug}.json"
    path.write_text(json.dumps({
        "machine": info, "commit": git_commit(), "sections": names,
        "options": {"sizes": args.sizes, "radii": args.radii, "warmup": args.warmup,
                    "repeats": repeats, "quick": args.quick},
        "paper_iteration_s": PAPER_ITERATION_S, "wall_s": time.perf_counter() - t0,
        "rows": bench.rows}, indent=1))
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
