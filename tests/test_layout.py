"""The house rules of the package layout, checked on the source tree:

* no import cycles between rtdefocus modules — function-level (lazy) imports included, since a
  cycle through a lazy import is still a pair of modules that cannot be understood apart;
* no module over 600 lines, the size at which a module should become a package;
* every third-party module the package imports is a declared dependency (a plain
  ``pip install .`` must run every command).
"""

from __future__ import annotations

import ast
import functools
import sys
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:                          # the test extra installs tomli there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "rtdefocus"
MAX_LINES = 600


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PKG.rglob("*.py"))}


@functools.cache
def _tree(path: Path) -> ast.Module:
    """The parsed file, parsed once per run (several checks walk every module; none edits it)."""
    return ast.parse(path.read_text(), str(path))


def _is_package(name: str, modules: dict[str, Path]) -> bool:
    return modules[name].name == "__init__.py"


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The rtdefocus modules that ``name`` imports (at any level of the file)."""
    pkg = name if _is_package(name, modules) else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # `from pkg import sub` imports the submodule when there is one.
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in modules:          # `import rtdefocus.x.y` -> the nearest module
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the rtdefocus modules it imports. A package's ``__init__`` re-exporting its own
    submodules is a facade, not a dependency, so those edges are left out (otherwise every
    ``from .. import __version__`` in a submodule would close a loop through its package)."""
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        deps = _imports(name, path, modules)
        if _is_package(name, modules):
            deps = {d for d in deps if not d.startswith(name + ".")}
        graph[name] = deps
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected component with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_cycle_finder_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert find_cycles(graph) == [["a", "b", "c"]]
    assert find_cycles({"a": {"b"}, "b": set()}) == []


def test_the_graph_sees_relative_and_lazy_imports():
    graph = import_graph()
    # cli imports its stages inside functions (start-up time); those edges must be seen.
    assert "rtdefocus.errors" in graph["rtdefocus.cli"]
    assert any(d.startswith("rtdefocus.calib") for d in graph["rtdefocus.cli.setup"])


def test_no_import_cycles():
    cycles = find_cycles(import_graph())
    assert not cycles, "import cycles between modules:\n" + "\n".join(
        " <-> ".join(c) for c in cycles)


@pytest.mark.parametrize("path", sorted(PKG.rglob("*.py")), ids=lambda p: str(p.relative_to(ROOT)))
def test_module_size(path):
    n = len(path.read_text().splitlines())
    assert n <= MAX_LINES, (f"{path.relative_to(ROOT)} has {n} lines (> {MAX_LINES}): split it by "
                            "concept into a package of small modules")


# Import name -> distribution name, where they differ.
_DIST = {"cv2": "opencv-python-headless", "skimage": "scikit-image", "yaml": "pyyaml",
         "cv2_enumerate_cameras": "cv2-enumerate-cameras", "Xlib": "python-xlib"}


def _third_party_imports() -> dict[str, bool]:
    """Top-level third-party module -> whether some file imports it at module level (an
    import that runs on ``import rtdefocus.x``, not only when a function is called)."""
    std = set(sys.stdlib_module_names)
    found: dict[str, bool] = {}
    for path in PKG.rglob("*.py"):
        tree = _tree(path)
        top_level = {id(n) for n in tree.body}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module or ""]
            else:
                continue
            for n in names:
                top = n.split(".")[0]
                if top and top not in std and top != "rtdefocus":
                    found[top] = found.get(top, False) or id(node) in top_level
    return found


def _requirement_name(req: str) -> str:
    for sep in "<>=!~[; ":
        req = req.split(sep)[0]
    return req.strip().lower()


def test_every_third_party_import_is_declared():
    """A plain ``pip install .`` runs every command: each import is a dependency, or — only for
    an import inside a function (a demo/eval extra) — declared in an optional extra."""
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {_requirement_name(r) for r in meta["dependencies"]}
    extras = {_requirement_name(r) for reqs in meta.get("optional-dependencies", {}).values()
              for r in reqs}
    problems = []
    for mod, at_module_level in sorted(_third_party_imports().items()):
        dist = _DIST.get(mod, mod).lower()
        if dist in declared:
            continue
        if dist in extras and not at_module_level:
            continue
        problems.append(f"{mod} ({dist}: " + ("imported at module level, so it must be a "
                                               "dependency" if dist in extras else
                                               "declared nowhere") + ")")
    assert not problems, ("pyproject.toml does not declare what rtdefocus imports; a plain "
                          "`pip install .` would fail at run time: " + "; ".join(problems))


# The study wing measures and shows the product; only its command line, the tests and the
# tools reach into it, so the product runs (and installs) without it.
STUDY = "rtdefocus.study"
STUDY_USERS = {"rtdefocus.cli.study"}


def test_nothing_outside_the_study_wing_imports_it():
    graph = import_graph()
    assert any(d.startswith(STUDY + ".") for d in graph["rtdefocus.cli.study"]), \
        "the graph does not see cli.study's imports of the study wing"
    bad = sorted(f"{m} -> {d}" for m, deps in graph.items()
                 if not (m == STUDY or m.startswith(STUDY + ".")) and m not in STUDY_USERS
                 for d in deps if d == STUDY or d.startswith(STUDY + "."))
    assert not bad, "product modules import the study wing: " + "; ".join(bad)


def underscore_imports(modules: dict[str, Path]) -> list[str]:
    """``from x import _name`` lines (a private name taken from another module)."""
    out = []
    for path in modules.values():
        where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.ImportFrom):
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        out.append(f"{where}:{node.lineno} imports {a.name}")
    return out


def test_the_underscore_check_finds_a_planted_import(tmp_path):
    bad = tmp_path / "m.py"
    bad.write_text("from .other import _private, public\nfrom . import __version__\n")
    ok = tmp_path / "n.py"
    ok.write_text("from .other import public as _alias\n")
    found = underscore_imports({"m": bad, "n": ok})
    assert len(found) == 1 and found[0].endswith("m.py:1 imports _private")


def test_no_module_imports_a_private_name_of_another():
    bad = underscore_imports(_modules())
    assert not bad, ("a module imports another's private (underscore) name; make it public or "
                     "move it where it belongs: " + "; ".join(bad))


def test_plane_geometry_is_a_leaf():
    """Folds, segments, bounding folds and labels have one owner that calibration, the warps
    and the kernels import alike; it depends on nothing of the package but errors."""
    graph = import_graph()
    assert graph["rtdefocus.planar"] <= {"rtdefocus.errors"}, graph["rtdefocus.planar"]
    for user in ("rtdefocus.calib.file", "rtdefocus.gl.warp", "rtdefocus.reference.warp",
                 "rtdefocus.calib.psf.sampling"):
        assert "rtdefocus.planar" in graph[user], user
