#!/usr/bin/env python
"""Deliberately break the product, one mutation at a time, and check that a test catches it
Each mutation replaces one exact snippet of one source file, runs a chosen subset
of the tests (``-x``: the first failure is enough), restores the file, and the table at the end
says which test caught it (or that none did).

Example::

    .venv/bin/python tools/mutation_check.py            # all mutations
    .venv/bin/python tools/mutation_check.py --only flip-psf,halve-iterations

The source is restored even when interrupted (``finally``); ``git diff rtdefocus`` after a
run should be empty.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutation:
    name: str
    path: str          # relative to the repository root
    old: str           # exact snippet, must occur once
    new: str
    tests: tuple[str, ...]


MUTATIONS = [
    Mutation("drop-response-lut", "rtdefocus/compensate/compensator.py",
             "self._lut = np.asarray(calib.lut, dtype=np.float32)",
             "self._lut = np.tile(np.linspace(0, 1, 256, dtype=np.float32), (3, 1))",
             ("tests/test_heldout.py", "tests/test_compensate.py", "tests/test_demo.py")),
    # The solver's kernels are made from the raw least-squares kernels (``Measurement.raw``,
    # averaged along lines of equal blur, then cleaned: calib/psf/stage.py), not from the
    # per-dot cleaned ``Measurement.psfs``: the flip goes where ``raw`` is filled.
    Mutation("flip-psf", "rtdefocus/calib/psf/dots.py",
             "            raw[i] = k / energy\n", "            raw[i] = (k / energy)[::-1, ::-1]\n",
             ("tests/test_psf.py::test_measured_psf_is_the_dot_image_shifted_not_flipped",
              "tests/test_psf.py")),
    Mutation("halve-iterations", "rtdefocus/compensate/compensator.py",
             'DEFAULT_ITERATIONS = {"fista": 40, "pg": 40}',
             'DEFAULT_ITERATIONS = {"fista": 20, "pg": 20}',
             ("tests/test_compensate.py::test_solver_reaches_most_of_the_independent_reference_gain",
              "tests/test_compensate.py", "tests/test_eval.py", "tests/test_demo.py")),
    Mutation("blend-across-fold", "rtdefocus/calib/psf/kernel_field.py",
             'mode = mode or ("cross" if plan.cross_fold else "planes")', 'mode = "cross"',
             ("tests/test_psf.py", "tests/test_eval.py")),
    # A cut treated as motion: the previous correction is carried into the new shot.
    Mutation("skip-warm-start-reset", "rtdefocus/compensate/compensator.py",
             "            if not motion.cut:\n", "            if True:\n",
             ("tests/test_motion.py::test_a_cut_restarts_from_the_target", "tests/test_motion.py")),
]


def run_tests(tests, timeout) -> tuple[str, float]:
    """'caught by <test id>' | 'not caught' | 'timeout', and seconds."""
    cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-rf", *tests]
    t0 = time.perf_counter()
    try:
        res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout", time.perf_counter() - t0
    seconds = time.perf_counter() - t0
    failed = re.findall(r"^(?:FAILED|ERROR) (\S+)", res.stdout, re.M)
    if res.returncode == 0:
        return "not caught", seconds
    return ("caught by " + failed[0]) if failed else f"pytest exit {res.returncode}", seconds


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", default="", help="comma-separated mutation names")
    p.add_argument("--timeout", type=float, default=1200.0, help="seconds per mutation")
    args = p.parse_args(argv)
    chosen = [m for m in MUTATIONS if not args.only or m.name in args.only.split(",")]
    rows = []
    for m in chosen:
        path = ROOT / m.path
        original = path.read_text()
        if original.count(m.old) != 1:
            rows.append((m.name, f"snippet not found once in {m.path}", 0.0))
            continue
        try:
            path.write_text(original.replace(m.old, m.new))
            verdict, seconds = run_tests(m.tests, args.timeout)
        finally:
            path.write_text(original)
        rows.append((m.name, verdict, seconds))
        print(f"{m.name}: {verdict} ({seconds:.0f} s)", flush=True)
    print("\n| mutation | result | seconds |\n|---|---|---|")
    for name, verdict, seconds in rows:
        print(f"| {name} | {verdict} | {seconds:.0f} |")
    return 0 if all(v.startswith("caught") for _, v, _ in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
