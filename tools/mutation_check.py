#!/usr/bin/env python
"""Deliberately break the product, one mutation at a time, and check that a test catches it.

Each mutation replaces one exact snippet of one file (Python, OpenCL or GLSL) and runs its own
small selection of tests (``-x``: the first failure is enough). Every stage has at least one:
geometry, the lens, radiometry, kernel extraction and blending, the metric, the solver,
flatten, motion and catch-up, the GLSL warp and the OpenCL kernels.

How it stays honest:

* the mutations are applied in a **copy** of the tree (a temporary folder, removed at the
  end): the working tree is never written, also when the run is interrupted or killed;
* the copy is imported ahead of the editable install (``PYTHONPATH``), and the run checks that
  ``rtdefocus`` and its kernels really load from the copy;
* the union of the selected tests runs **unmutated first**: a failing baseline is an error
  (exit 2), not a catch;
* ``tests/test_suite_rules.py`` asserts that every snippet still occurs exactly once in its file
  and that every selected test still exists, so a refactor that moves a snippet fails CI
  instead of leaving a mutation that silently tests nothing.

Example::

    .venv/bin/python tools/mutation_check.py                     # all, report on stdout
    .venv/bin/python tools/mutation_check.py --only flip-psf,snap-kernel-field
    .venv/bin/python tools/mutation_check.py --report docs/mutation-report.md

Exit status: 0 every mutation caught, 1 some not caught, 2 the baseline or the set-up failed.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutation:
    """``old`` (occurring exactly once in ``path``) becomes ``new``; ``tests`` should catch it."""

    name: str
    stage: str
    path: str          # relative to the repository root
    old: str
    new: str
    tests: tuple[str, ...]
    why: str = ""


WEBCAM_E2E = "tests/test_webcam.py::test_calibration_on_a_webcam_in_a_lit_room"

MUTATIONS = [
    # ---------------------------------------------------------------- geometry
    Mutation("line-centre-half-pixel", "geometry", "rtdefocus/calib/geometry/structured_light.py",
             "return stripe * self.spacing + self.first_pixel(phase) + (self.width - 1) / 2.0",
             "return stripe * self.spacing + self.first_pixel(phase) + self.width / 2.0",
             (WEBCAM_E2E,),
             "every projector line placed half a pixel off"),
    Mutation("gray-code-binary", "geometry", "rtdefocus/graycode.py",
             "    code = index ^ (index >> 1)\n", "    code = index\n",
             ("tests/test_independent.py::test_gray_patterns_carry_the_reflected_binary_code",),
             "plain binary stripes instead of the Gray code"),
    # ---------------------------------------------------------------- lens
    Mutation("lens-model-k2-power", "lens", "rtdefocus/planar.py",
             "    f = 1.0 + k1 * r2 + k2 * r2 * r2\n    return np.stack(",
             "    f = 1.0 + k1 * r2 + k2 * r2\n    return np.stack(",
             ("tests/test_independent.py::test_lens_model_is_opencvs_radial_distortion",),
             "k2 multiplies r^2 instead of r^4"),
    Mutation("radiometry-forgets-the-lens", "lens", "rtdefocus/calib/radiometry/stage.py",
             "    if lens_k(calib) is not None:\n        obs = observed_points(",
             "    if False:\n        obs = observed_points(",
             ("tests/test_radiometry.py::test_albedo_through_a_barrel_lens_on_a_woven_wall",),
             "the radiometry stage reads its frames as if the lens were ideal"),
    Mutation("psf-forgets-the-lens", "lens", "rtdefocus/calib/psf/dots.py",
             "    if lens_k(calib) is not None:\n        ideal = ideal_points(",
             "    if False:\n        ideal = ideal_points(",
             (WEBCAM_E2E,),
             "the dots are mapped to the projector without undistorting the camera"),
    # ---------------------------------------------------------------- radiometry
    Mutation("ramp-without-black", "radiometry", "rtdefocus/calib/radiometry/stage.py",
             "num = (frames[i][sl] - black_p[sl])[m].sum(axis=0)",
             "num = frames[i][sl][m].sum(axis=0)",
             ("tests/test_radiometry.py::test_albedo_through_a_barrel_lens_on_a_woven_wall",),
             "the room light is left in the grey ramp's ratios"),
    Mutation("drop-response-lut", "radiometry", "rtdefocus/compensate/compensator.py",
             "self._lut = np.asarray(calib.lut, dtype=np.float32)",
             "self._lut = np.tile(np.linspace(0, 1, 256, dtype=np.float32), (3, 1))",
             ("tests/test_heldout.py::test_held_out_setup_gains_most_of_the_measured_gain",),
             "the Compensator ignores the projector's response"),
    # ---------------------------------------------------------------- kernel extraction
    Mutation("flip-psf", "kernels", "rtdefocus/calib/psf/dots.py",
             "            raw[i] = k / energy\n", "            raw[i] = (k / energy)[::-1, ::-1]\n",
             ("tests/test_psf.py::test_measured_psf_is_the_dot_image_shifted_not_flipped",),
             "each measured kernel turned by 180 degrees"),
    Mutation("flip-psf-outcome", "kernels", "rtdefocus/calib/psf/dots.py",
             "            raw[i] = k / energy\n", "            raw[i] = (k / energy)[::-1, ::-1]\n",
             (WEBCAM_E2E,),
             "the same flip, against the webcam outcome test alone (triangle aperture)"),
    Mutation("transpose-psf", "kernels", "rtdefocus/calib/psf/dots.py",
             "            raw[i] = k / energy\n", "            raw[i] = (k / energy).T\n",
             (WEBCAM_E2E,),
             "each measured kernel transposed (x and y swapped)"),
    Mutation("shift-psf", "kernels", "rtdefocus/calib/psf/dots.py",
             "            raw[i] = k / energy\n",
             "            raw[i] = np.roll(k / energy, 1, axis=1)\n",
             (WEBCAM_E2E,),
             "each measured kernel shifted by one pixel"),
    # ---------------------------------------------------------------- kernel blending
    Mutation("blend-across-fold", "blending", "rtdefocus/calib/psf/kernel_field.py",
             'mode = mode or ("cross" if plan.cross_fold else "planes")', 'mode = "cross"',
             ("tests/test_psf.py::test_field_blends_within_planes",),
             "the kernel field blends samples of both walls"),
    Mutation("snap-kernel-field", "blending", "rtdefocus/calib/psf/kernel_field.py",
             "    wts /= np.maximum(wts.sum(axis=1, keepdims=True), 1e-12)\n",
             "    wts = (wts == wts.max(axis=1, keepdims=True)).astype(np.float32)\n"
             "    wts /= np.maximum(wts.sum(axis=1, keepdims=True), 1e-12)\n",
             ("tests/test_psf.py::test_kernel_field_has_no_seams",),
             "each pixel takes its nearest sample's kernel (weights still sum to one)"),
    # ---------------------------------------------------------------- the metric
    Mutation("ycbcr-coefficient", "metric", "rtdefocus/reference/metric.py",
             "    [0.5, -0.418688, -0.081312],", "    [0.5, -0.081312, -0.418688],",
             ("tests/test_metric.py::test_ycbcr_is_bt601_and_invertible",
              "tests/test_independent.py::test_ycbcr_matrix_is_bt601_full_range"),
             "Cr's green and blue coefficients swapped (white still has no chroma)"),
    Mutation("cl-metric-laplacian", "OpenCL", "kernels/metric.cl",
             "if (x < W - 1) lap += e - e_at(mode, a, b, t, c, sc, i + 1, hw);",
             "if (x < W - 1) lap += e - e_at(mode, a, b, t, c, sc, i - 1, hw);",
             ("tests/test_metric.py::test_cl_metric_kernels_match_numpy",),
             "the device Laplacian reads the left neighbour twice"),
    # ---------------------------------------------------------------- the solver
    Mutation("halve-iterations", "solver", "rtdefocus/compensate/compensator.py",
             "        iters = self.iterations if iterations is None else int(iterations)\n"
             "        lo, scale = headroom_params(self.headroom)\n",
             "        iters = max(1, (self.iterations if iterations is None else int(iterations)) // 2)\n"
             "        lo, scale = headroom_params(self.headroom)\n",
             ("tests/test_compensate.py::test_compensator_spends_its_whole_budget",),
             "the Compensator silently runs half its iteration budget"),
    Mutation("cl-fista-half-step", "OpenCL", "kernels/solver.cl",
             "const vecf pn = clamp(y - step * gy, 0.0f, 1.0f);",
             "const vecf pn = clamp(y - 0.5f * step * gy, 0.0f, 1.0f);",
             ("tests/test_metric.py::test_cl_solver_steps_match_numpy",),
             "the device's FISTA step is half the step it reports"),
    Mutation("cl-blur-flipped", "OpenCL", "kernels/blur.cl",
             "const int l = (ly + RADIUS - v) * TW + lx + RADIUS - u;     /* P(x - u) */",
             "const int l = (ly + RADIUS + v) * TW + lx + RADIUS + u;     /* P(x - u) */",
             ("tests/test_blur.py::test_forward_matches_reference",
              "tests/test_blur.py::test_direction_on_device"),
             "the device blur (GPU variant) convolves with the kernel turned by 180 degrees"),
    # ---------------------------------------------------------------- flatten
    Mutation("flatten-forgets-room-light", "flatten", "rtdefocus/compensate/surface.py",
             "        T = self.gain * I + self.offset\n        return np.clip(T",
             "        T = self.gain * I\n        return np.clip(T",
             ("tests/test_surface.py::test_flatten_makes_a_grey_field_uniform",
              "tests/test_surface.py::test_flatten_photograph_closer_to_a_white_wall"),
             "flatten's target leaves out the room light's offset"),
    # ---------------------------------------------------------------- motion and catch-up
    Mutation("motion-backwards", "motion", "rtdefocus/compensate/motion.py",
             "map_xy = cv2.scaleAdd(flow, float(scale), self._pixel_grid(h, w))",
             "map_xy = cv2.scaleAdd(flow, -float(scale), self._pixel_grid(h, w))",
             ("tests/test_motion.py::test_motion_recovers_a_pan_and_flags_the_new_edge",
              "tests/test_motion.py::test_warm_start_follows_the_motion"),
             "the correction is carried against the motion"),
    Mutation("cut-keeps-warm-start", "motion", "rtdefocus/compensate/compensator.py",
             "        if motion.cut:\n            s.start_from_target()\n",
             "        if False:\n            s.start_from_target()\n",
             ("tests/test_motion.py::test_a_cut_restarts_from_the_target",),
             "a cut is treated as motion: the previous shot's correction is carried"),
    Mutation("catch-up-never", "catch-up", "rtdefocus/stream/catch_up.py",
             "        if fit >= b.minimum:\n            return \"compensate\", min(iterations, fit)\n",
             "        if True:\n            return \"compensate\", min(iterations, max(fit, b.minimum))\n",
             ("tests/test_stream.py::test_a_slow_device_keeps_up_with_geometry_only_frames",),
             "a late frame is always compensated, never shown with geometry only"),
    Mutation("catch-up-fixed-margin", "catch-up", "rtdefocus/stream/catch_up.py",
             "        ratio = self.budget.cost_ratio(CATCH_UP_QUANTILE, repeat=repeat)\n",
             "        ratio = None\n",
             ("tests/test_catch_up.py::test_a_steady_device_near_its_deadline_compensates_moving_frames",),
             "the safety margin ignores the measured spread of the costs"),
    Mutation("catch-up-still-spread", "catch-up", "rtdefocus/stream/catch_up.py",
             "        ratio = self.budget.cost_ratio(CATCH_UP_QUANTILE, repeat=repeat)\n",
             "        ratio = (self.budget.cost_ratio(CATCH_UP_QUANTILE, repeat=True)\n"
             "                 or self.budget.cost_ratio(CATCH_UP_QUANTILE, repeat=repeat))\n",
             ("tests/test_catch_up.py::"
              "test_a_still_pictures_steady_costs_do_not_lower_a_moving_frames_margin",),
             "a still picture's steady costs set the moving frames' margin"),
    # ---------------------------------------------------------------- the GLSL warp
    Mutation("glsl-half-texel", "GLSL", "kernels/warp.glsl",
             "    vec2 st = q.xy / q.z;\n", "    vec2 st = q.xy / q.z + 0.5 / u_image_size;\n",
             ("tests/test_warp.py::test_gl_matches_cv2",),
             "the shader samples half a texel off"),
]


def _tree_files() -> list[str]:
    """Tracked files and untracked ones git does not ignore (what a clean checkout holds)."""
    out = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    return [p for p in out.split("\0") if p and (ROOT / p).is_file()]


def copy_tree(dest: Path) -> None:
    """The working tree's files into ``dest``, and ``rtdefocus/kernels`` pointing at the copy's
    ``kernels/`` (the package maps it there; without the link the editable install's mapping
    would serve the working tree's kernels)."""
    for rel in _tree_files():
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, target)
    (dest / "rtdefocus" / "kernels").symlink_to(dest / "kernels", target_is_directory=True)


def _env(tree: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(tree)] + [p for p in [env.get("PYTHONPATH")] if p])
    env["RTDEFOCUS_REQUIRE_DEVICES"] = "1"      # a missing device fails, never skips
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def check_imports_from(tree: Path) -> None:
    """Fail unless ``rtdefocus`` and its kernels load from ``tree``."""
    code = ("import rtdefocus, rtdefocus.resources as r; "
            "print(rtdefocus.__file__); print(r.kernels_dir().resolve())")
    res = subprocess.run([sys.executable, "-c", code], cwd=tree, env=_env(tree),
                         capture_output=True, text=True)
    lines = res.stdout.split()
    real = tree.resolve()
    if res.returncode != 0 or len(lines) != 2 or not all(
            Path(p).resolve().is_relative_to(real) for p in lines):
        raise SystemExit(f"the copy in {tree} is not what gets imported: {res.stdout}{res.stderr}")


def run_tests(tree: Path, tests, timeout: float, first_failure: bool = True):
    """(returncode or None on timeout, failed test ids, seconds, output tail)."""
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfE",
           *(["-x"] if first_failure else []), *tests]
    t0 = time.perf_counter()
    try:
        res = subprocess.run(cmd, cwd=tree, env=_env(tree), capture_output=True, text=True,
                             timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, [], time.perf_counter() - t0, ""
    failed = re.findall(r"^(?:FAILED|ERROR) (\S+)", res.stdout, re.M)
    return res.returncode, failed, time.perf_counter() - t0, (res.stdout + res.stderr)[-3000:]


def snippet_problems(mutations=MUTATIONS, root: Path = ROOT) -> list[str]:
    """What is wrong with the mutation table against ``root``: a snippet not found exactly
    once, a replacement equal to the original, a selected test file or test function that no
    longer exists, a repeated name."""
    problems = []
    names = [m.name for m in mutations]
    problems += [f"{n}: the name is used twice" for n in sorted({n for n in names if names.count(n) > 1})]
    for m in mutations:
        path = root / m.path
        if not path.is_file():
            problems.append(f"{m.name}: {m.path} does not exist")
            continue
        n = path.read_text().count(m.old)
        if n != 1:
            problems.append(f"{m.name}: the snippet occurs {n} times in {m.path} (needs 1)")
        if m.old == m.new:
            problems.append(f"{m.name}: the replacement equals the snippet")
        for t in m.tests:
            file, _, rest = t.partition("::")
            if not (root / file).is_file():
                problems.append(f"{m.name}: {file} does not exist")
            elif rest:
                func = rest.split("[")[0].split("::")[-1]
                if not re.search(rf"^\s*def {re.escape(func)}\(", (root / file).read_text(), re.M):
                    problems.append(f"{m.name}: no test {func} in {file}")
    return problems


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", default="", help="comma-separated mutation names")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per pytest run")
    p.add_argument("--report", default="", help="also write the table to this markdown file")
    args = p.parse_args(argv)
    only = [s for s in args.only.split(",") if s]
    unknown = set(only) - {m.name for m in MUTATIONS}
    if unknown:
        p.error(f"unknown mutation(s): {', '.join(sorted(unknown))}")
    chosen = [m for m in MUTATIONS if not only or m.name in only]
    problems = snippet_problems(chosen)
    if problems:
        print("the mutation table is out of date:\n  " + "\n  ".join(problems), file=sys.stderr)
        return 2
    # A kill (SIGTERM) unwinds like Ctrl-C, so the temporary copy is removed too.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    rows = []
    with tempfile.TemporaryDirectory(prefix="rtdefocus-mutants-") as tmp:
        tree = Path(tmp) / "tree"
        copy_tree(tree)
        check_imports_from(tree)
        selected = list(dict.fromkeys(t for m in chosen for t in m.tests))
        rc, failed, seconds, tail = run_tests(tree, selected, args.timeout, first_failure=False)
        baseline_s = seconds
        print(f"baseline ({len(selected)} selections): exit {rc}, {seconds:.0f} s", flush=True)
        if rc != 0:
            print(f"the unmutated tree fails its own selection ({', '.join(failed) or 'timeout'}); "
                  f"fix that first:\n{tail}", file=sys.stderr)
            return 2
        for m in chosen:
            path = tree / m.path
            original = path.read_text()
            path.write_text(original.replace(m.old, m.new))
            try:
                rc, failed, seconds, _ = run_tests(tree, m.tests, args.timeout)
            finally:
                path.write_text(original)
            if rc is None:
                verdict = "timeout"
            elif rc == 0:
                verdict = "NOT CAUGHT"
            else:
                verdict = f"caught by `{failed[0]}`" if failed else f"caught (pytest exit {rc})"
            rows.append((m, verdict, seconds))
            print(f"{m.name}: {verdict} ({seconds:.0f} s)", flush=True)
    table = ["| stage | mutation | what it breaks | result | seconds |", "|---|---|---|---|---|"]
    table += [f"| {m.stage} | `{m.name}` ({m.path}) | {m.why} | {v} | {s:.0f} |"
              for m, v, s in rows]
    print("\n" + "\n".join(table))
    if args.report:
        caught = sum(v.startswith("caught") for _, v, _ in rows)
        Path(args.report).write_text(
            "# Mutation check\n\nEach row: one deliberate bug, applied in a copy of the tree, and "
            "the first test of its\nselection that failed. Made by `.venv/bin/python "
            "tools/mutation_check.py --report docs/mutation-report.md`\n(the unmutated selection "
            f"passed first: {len(selected)} tests, {baseline_s:.0f} s; then the {len(rows)} "
            f"mutations, {sum(s for _, _, s in rows):.0f} s;\n{caught} of {len(rows)} caught).\n\n"
            "The working tree is never written: the copy lives in a temporary folder, removed on\n"
            "exit, Ctrl-C or SIGTERM. `tests/test_suite_rules.py` fails when a snippet or a selected\n"
            "test no longer exists. The webcam outcome test's triangle aperture is not\n"
            "point-symmetric: a flipped, transposed or shifted kernel (`flip-psf-outcome`,\n"
            "`transpose-psf`, `shift-psf`) fails that outcome test alone.\n\n"
            + "\n".join(table) + "\n")
    return 0 if all(v.startswith("caught") for _, v, _ in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
