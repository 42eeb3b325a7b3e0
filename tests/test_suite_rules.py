"""Rules of the test suite itself: one command for CI and the README, no silent skips, and a
mutation check whose table still points at real code and real tests."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _mutation_check():
    spec = importlib.util.spec_from_file_location("mutation_check", ROOT / "tools" / "mutation_check.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod            # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def test_every_mutation_snippet_exists_once_and_its_tests_exist():
    """A refactor that moves or rewrites a mutated snippet (or renames a selected test) fails
    here, so the mutation check cannot quietly test nothing."""
    mc = _mutation_check()
    assert mc.snippet_problems() == []


def test_the_mutations_cover_every_stage():
    stages = {m.stage for m in _mutation_check().MUTATIONS}
    assert stages >= {"geometry", "lens", "radiometry", "kernels", "blending", "metric", "solver",
                      "flatten", "motion", "catch-up", "GLSL", "OpenCL"}, stages


def test_ci_runs_make_test_and_make_test_requires_the_devices():
    run = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines()
           if ln.strip() and not ln.lstrip().startswith("#")]
    assert run[-1] == "exec make test", run
    assert not any("RTDEFOCUS" in ln for ln in run), "the environment belongs in the Makefile"
    make = (ROOT / "Makefile").read_text()
    target = re.search(r"^test: .*\n((?:\t.*\n)+)", make, re.M)
    assert target and "RTDEFOCUS_REQUIRE_DEVICES=1" in target.group(1), make


def test_no_plain_skips():
    """A missing device goes through helpers.skip_or_fail (a failure where devices are
    required); nothing else skips."""
    offenders = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        if path.name in ("helpers.py", Path(__file__).name):
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"pytest\.(skip|importorskip)\(|mark\.skip(if)?\b", line):
                offenders.append(f"{path.name}:{i}: {line.strip()}")
    assert offenders == []
