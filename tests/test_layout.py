"""The package layout: one installed namespace, and layers whose imports only run downwards
and never in a circle.

The layers, bottom to top (README, *Layout*):

    base/ -> gridflow (shared base: volume container, sources, file formats)
    estimator/ (numerics)
    generators/, scenes/ (data sources)     pipeline/ (the grower's path: run, sinks, growth)
    bench/ (benchmark) and bench/cli/ (the CLI: its modules import each other, nothing
    else imports them)

The import rules are checked on the source (every ``import`` statement, also those inside
functions), so a violation fails here whether or not a test happens to execute it.  The
install test builds a wheel from a copy of the repository's files and installs it, without
its dependencies, into a fresh virtual environment outside the repository; the
dependencies are lent from the test environment by a ``.pth`` line, so the test needs no
network and installs nothing else.  The import graph of that installed package (a node
per module, an edge per import statement that names another of its modules) must have no
cycle and no edge upwards.
"""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# folder -> (installed name, project subpackages it may import)
LAYERS = {
    "base": ("gridflow", set()),
    "estimator": ("gridflow.estimator", set()),
    "generators": ("gridflow.generators", {"gridflow"}),
    "scenes": ("gridflow.scenes", {"gridflow"}),
    "pipeline": ("gridflow.pipeline", {"gridflow", "gridflow.estimator"}),
    "bench": ("gridflow.bench", {"gridflow", "gridflow.estimator", "gridflow.generators",
                                 "gridflow.scenes", "gridflow.pipeline"}),
    "bench/cli": ("gridflow.bench.cli", {"gridflow", "gridflow.estimator",
                                         "gridflow.generators", "gridflow.scenes",
                                         "gridflow.pipeline", "gridflow.bench"}),
}
# third-party libraries that belong to the edges: the numerics and data sources never need
# them (pictures and tables are the benchmark's business)
EDGE_LIBRARIES = {"matplotlib", "pandas", "dask", "distributed", "tqdm"}
NUMERICS = {"estimator", "generators"}


def _imports(path: Path, package: str) -> set[str]:
    """Absolute names of everything ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    pkg = package.split(".")            # the module's __package__ (its folder's name)
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[:len(pkg) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            names.add(mod)
            names |= {f"{mod}.{a.name}" for a in node.names}
    return names


def _layer_of(name: str) -> str | None:
    """The project layer an imported name belongs to, or None for other libraries."""
    parts = name.split(".")
    if parts[0] in ("estimator", "generators", "scenes", "bench", "base", "pipeline"):
        return "top-level name of a repository folder, " + parts[0]
    if parts[0] != "gridflow":
        return None
    if parts[1:3] == ["bench", "cli"]:
        return "gridflow.bench.cli"
    if len(parts) > 1 and parts[1] in ("estimator", "generators", "scenes", "pipeline",
                                       "bench"):
        return "gridflow." + parts[1]
    if len(parts) > 1 and parts[1] in ("cli",):
        return "gridflow.bench"
    return "gridflow"


def _project_modules():
    for folder, (package, _) in LAYERS.items():
        for path in sorted((ROOT / folder).glob("*.py")):
            yield folder, package, path


@pytest.mark.parametrize("folder", sorted(LAYERS))
def test_no_import_runs_upwards(folder):
    package, allowed = LAYERS[folder]
    bad = []
    for path in sorted((ROOT / folder).glob("*.py")):
        for name in _imports(path, package):
            layer = _layer_of(name)
            if layer is None or layer == package:
                continue
            if layer not in allowed:
                bad.append(f"{path.relative_to(ROOT)} imports {name} ({layer})")
            if folder in NUMERICS and name.split(".")[0] in EDGE_LIBRARIES:
                bad.append(f"{path.relative_to(ROOT)} imports {name}")
        if folder in NUMERICS:
            bad += [f"{path.relative_to(ROOT)} imports {n}" for n in _imports(path, package)
                    if n.split(".")[0] in EDGE_LIBRARIES | {"imageio", "tifffile", "vapory"}]
    assert not bad, "imports against the layering:\n" + "\n".join(sorted(set(bad)))


def test_the_cli_is_imported_by_nothing():
    """The CLI package is the top floor: its modules may import each other, no other
    module imports any of them."""
    users = [f"{path.relative_to(ROOT)}" for folder, package, path in _project_modules()
             if folder != "bench/cli"
             and any(_layer_of(n) == "gridflow.bench.cli" for n in _imports(path, package))]
    assert not users, f"the CLI is the top floor, yet imported by {users}"
    inside = {n for _, package, path in _project_modules() if package == "gridflow.bench.cli"
              for n in _imports(path, package) if _layer_of(n) == "gridflow.bench.cli"}
    assert "gridflow.bench.cli._common" in inside       # the check sees the package's own
    assert _layer_of("gridflow.bench.cli.sweeps") == "gridflow.bench.cli"
    assert _layer_of("gridflow.bench.sweep") == "gridflow.bench"


def test_the_checker_sees_a_violation(tmp_path):
    """The import check must be able to fail: a numerics module importing the benchmark."""
    bad = tmp_path / "bad.py"
    bad.write_text("from ..bench import sweep\nimport matplotlib.pyplot\n")
    names = _imports(bad, "gridflow.estimator")
    assert "gridflow.bench" in names and _layer_of("gridflow.bench.sweep") == "gridflow.bench"
    assert "matplotlib.pyplot" in names


# --- the installed wheel ---------------------------------------------------------------------

_TRACKED_IGNORE = shutil.ignore_patterns(".git", ".venv", "work", "build", "*.egg-info",
                                         "__pycache__", ".pytest_cache", ".hypothesis",
                                         "results", "tests", ".gl", ".whl")


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """A fresh virtual environment outside the repository with gridflow installed from a
    wheel (not editable) by the environment's own pip; returns (python, site-packages,
    working folder)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=_TRACKED_IGNORE)
    dist = tmp / "dist"
    # the wheel is built with the test environment's setuptools (no network needed)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                    "-q", "-w", str(dist), str(src)], check=True, capture_output=True)
    wheel = next(dist.glob("gridflow-*.whl"))
    env_dir = tmp / "venv"
    venv.EnvBuilder(with_pip=True, symlinks=True).create(env_dir)
    py = env_dir / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "--no-deps", "--no-index", "-q",
                    str(wheel)], check=True, capture_output=True)
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; "
                                "print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    # the dependencies (numpy, scipy, ...) come from this environment, after the new one's
    # own site-packages on sys.path
    (site / "zz_test_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp / "elsewhere"
    work.mkdir()
    return py, site, work


def _run_installed(installed, *args, **kw):
    """Run ``args`` (the environment's python when the first is an option or ``-c``)."""
    py, _, work = installed
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    cmd = [str(py), *args] if args[0].startswith("-") else list(args)
    return subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True,
                          timeout=300, **kw)


# what a fresh virtual environment holds before anything is installed (the installer itself)
_INSTALLER = {"pip", "setuptools", "pkg_resources", "_distutils_hack", "__pycache__"}


def test_site_packages_holds_gridflow_alone(installed):
    _, site, _ = installed
    top = sorted(p.name for p in site.iterdir()
                 if not p.name.endswith((".dist-info", ".pth")) and p.name not in _INSTALLER)
    assert top == ["gridflow"], top
    inner = {p.name for p in (site / "gridflow").iterdir()}
    assert {"estimator", "generators", "scenes", "pipeline", "bench"} <= inner
    assert (site / "gridflow" / "bench" / "sweeps" / "paper.toml").is_file()


def test_installed_imports(installed):
    _, site, _ = installed
    r = _run_installed(installed, "-c",
                       "import gridflow, gridflow.estimator, gridflow.generators, "
                       "gridflow.scenes, gridflow.bench; from gridflow.estimator import "
                       "estimate; from gridflow.generators import make_sinusoid; "
                       "print(gridflow.__file__)")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().startswith(str(site)), r.stdout
    for name in ("estimator", "generators", "scenes", "bench", "base"):
        r = _run_installed(installed, "-c", f"import {name}")
        assert r.returncode != 0 and "ModuleNotFoundError" in r.stderr, (name, r.stderr)


def test_installed_cli_runs_outside_the_repository(installed):
    py, _, work = installed
    gridflow = str(py.parent / "gridflow")      # the console script the wheel installed
    from gridflow import __version__

    r = _run_installed(installed, gridflow, "--version")
    assert r.returncode == 0 and r.stdout.strip() == f"gridflow {__version__}", r
    # a shipped spec found by name, run end to end
    r = _run_installed(installed, gridflow, "sweep", "smoke", "-o", "s.csv", "--no-progress",
                       "--processes", "1")
    assert r.returncode == 0, r.stderr
    assert (work / "s.csv").is_file() and len((work / "s.csv").read_text().splitlines()) > 1
    r = _run_installed(installed, gridflow, "claims", "s.csv")
    assert r.returncode == 0, r.stderr
    r = _run_installed(installed, gridflow, "figures", "--sweep", "s.csv", "--out", "figs")
    assert r.returncode == 0, r.stderr
    assert (work / "figs" / "fig3_gridflow_setup.png").is_file()
    r = _run_installed(installed, gridflow, "sweep", "nosuchspec", "-o", "x.csv")
    shipped = ", ".join(sorted(p.stem for p in (ROOT / "bench" / "sweeps").glob("*.toml")))
    assert r.returncode == 2 and f"shipped: {shipped}" in r.stderr, r.stderr


# --- the import graph of the installed package -----------------------------------------------

# layer of each subpackage of the installed namespace (a module may import its own layer's
# modules and those of lower layers; base and estimator import nothing of the project)
_RANK = {"gridflow": 0, "gridflow.estimator": 0, "gridflow.generators": 1,
         "gridflow.scenes": 1, "gridflow.pipeline": 1, "gridflow.bench": 2,
         "gridflow.bench.cli": 3}
# within a layer, the parts that may not import each other
_APART = [{"gridflow", "gridflow.estimator"}, {"gridflow.generators", "gridflow.scenes"},
          {"gridflow.pipeline", "gridflow.generators"}, {"gridflow.pipeline", "gridflow.scenes"}]
# the grower's path: what `gridflow estimate`, `gridflow growth` and their library calls
# run; none of it may reach the benchmark, directly or through another module
GROWERS_PATH = ("gridflow.pipeline", "gridflow.sources", "gridflow.recording",
                "gridflow.loader", "gridflow.hci", "gridflow.io", "gridflow.estimator")


def import_graph(package_dir: Path, package: str = "gridflow") -> dict[str, set[str]]:
    """``{module: modules it imports}`` over the ``.py`` files of an installed package.

    Every import statement counts, also those inside functions.  ``from P import n`` is an
    edge to ``P.n`` where that is a module of the package, else to ``P``; ``import a.b.c``
    to the longest prefix that is one.  A submodule's implicit import of its parent
    package is not an edge (every module would otherwise import its own ``__init__``)."""
    files = {}
    for f in sorted(Path(package_dir).rglob("*.py")):
        rel = f.relative_to(package_dir).with_suffix("")
        parts = [package] + list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        files[".".join(parts)] = f
    graph = {}
    for mod, f in files.items():
        is_pkg = f.name == "__init__.py"
        pkg = mod if is_pkg else mod.rpartition(".")[0]
        edges = set()
        for node in ast.walk(ast.parse(f.read_text(), filename=str(f))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")[:len(pkg.split(".")) - node.level + 1]
                    src = ".".join(base + ([node.module] if node.module else []))
                else:
                    src = node.module
                targets = [f"{src}.{a.name}" if f"{src}.{a.name}" in files else src
                           for a in node.names]
            for t in targets:
                while t and t not in files:
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    edges.add(t)
        graph[mod] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: one per strongly connected component of more than
    one module (Tarjan's algorithm), as the component's modules in order."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
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

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _part(mod: str) -> str:
    """The subpackage (layer entry of _RANK) a module belongs to."""
    best = "gridflow"
    for name in _RANK:
        if (mod == name or mod.startswith(name + ".")) and len(name) > len(best):
            best = name
    return best


def upward_edges(graph: dict[str, set[str]]) -> list[str]:
    """Edges from a module to one of a higher layer, or between parts kept apart."""
    bad = []
    for a, targets in graph.items():
        pa = _part(a)
        for b in sorted(targets):
            pb = _part(b)
            if pa == pb:
                continue
            if _RANK[pb] > _RANK[pa] or any({pa, pb} <= g for g in _APART):
                bad.append(f"{a} -> {b}")
    return bad


def test_installed_import_graph_has_no_cycle_and_runs_downwards(installed):
    _, site, _ = installed
    graph = import_graph(site / "gridflow")
    assert {"gridflow.estimator.driver", "gridflow.estimator._solver", "gridflow.bench.cli",
            "gridflow.bench.sweep"} <= set(graph)
    assert "gridflow.estimator.backends" in graph["gridflow.estimator.driver"]
    assert not cycles(graph), f"import cycles: {cycles(graph)}"
    assert not upward_edges(graph), "imports against the layering:\n" + "\n".join(
        upward_edges(graph))


def reaches_benchmark(graph: dict[str, set[str]], roots=GROWERS_PATH) -> list[str]:
    """Import chains from a module of the grower's path to the benchmark (``gridflow.
    bench``), each as ``a -> b -> ... -> gridflow.bench.x``."""
    out = []
    starts = [m for m in graph if any(m == r or m.startswith(r + ".") for r in roots)]
    for start in sorted(starts):
        seen, todo = {start: [start]}, [start]
        while todo:
            a = todo.pop()
            for b in sorted(graph.get(a, ())):
                if b in seen:
                    continue
                seen[b] = seen[a] + [b]
                if b == "gridflow.bench" or b.startswith("gridflow.bench."):
                    out.append(" -> ".join(seen[b]))
                else:
                    todo.append(b)
    return out


def test_the_growers_path_imports_nothing_of_the_benchmark(installed):
    _, site, _ = installed
    graph = import_graph(site / "gridflow")
    assert {"gridflow.pipeline.run", "gridflow.pipeline.sinks", "gridflow.sources"} <= set(graph)
    chains = reaches_benchmark(graph)
    assert not chains, "the grower's path reaches the benchmark:\n" + "\n".join(chains)


def test_the_benchmark_check_can_fail(tmp_path):
    """A pipeline module that imports a base module that imports the benchmark (inside a
    function) is found, with its chain."""
    pkg = tmp_path / "gridflow"
    for sub in ("", "pipeline", "bench"):
        (pkg / sub).mkdir(parents=True, exist_ok=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "pipeline" / "run.py").write_text("from gridflow import io\n")
    (pkg / "io.py").write_text("def f():\n    from gridflow.bench.sweep import code\n")
    (pkg / "bench" / "sweep.py").write_text("code = 1\n")
    graph = import_graph(pkg)
    assert reaches_benchmark(graph) == [
        "gridflow.io -> gridflow.bench.sweep",
        "gridflow.pipeline.run -> gridflow.io -> gridflow.bench.sweep"]
    (pkg / "io.py").write_text("def f():\n    return 1\n")
    assert reaches_benchmark(import_graph(pkg)) == []


def test_the_graph_checker_finds_cycles_and_upward_imports(tmp_path):
    """The checker must be able to fail: a package whose driver and kernels import each
    other (lazily, inside a function: the form the earlier estimator/core.py and _fast.py
    had), and a numerics module importing the benchmark."""
    pkg = tmp_path / "gridflow"
    (pkg / "estimator").mkdir(parents=True)
    (pkg / "bench").mkdir()
    for init in (pkg, pkg / "estimator", pkg / "bench"):
        (init / "__init__.py").write_text("")
    (pkg / "estimator" / "core.py").write_text("from . import _fast\n")
    (pkg / "estimator" / "_fast.py").write_text(
        "def compile_kernels():\n    from .core import estimate\n")
    (pkg / "estimator" / "models.py").write_text("from gridflow.bench.sweep import run\n")
    (pkg / "bench" / "sweep.py").write_text("from gridflow.estimator import core\n")
    graph = import_graph(pkg)
    assert graph["gridflow.estimator.core"] == {"gridflow.estimator._fast"}
    assert graph["gridflow.bench.sweep"] == {"gridflow.estimator.core"}
    assert cycles(graph) == [["gridflow.estimator._fast", "gridflow.estimator.core"]]
    assert upward_edges(graph) == ["gridflow.estimator.models -> gridflow.bench.sweep"]


def test_every_mutant_still_applies(monkeypatch):
    """Each hand-written mutant of ``make mutants`` names text found exactly once in its
    file, so that a refactor cannot retire a mutant (and the bug it stands for) without a
    failing test here; ``tests/mutation.py`` refuses to run a stale list."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    name = "gridflow_mutation_list"
    spec = importlib.util.spec_from_file_location(name, root / "tests" / "mutation.py")
    mod = importlib.util.module_from_spec(spec)
    # dataclasses look their module up in sys.modules
    monkeypatch.setitem(__import__("sys").modules, name, mod)
    spec.loader.exec_module(mod)
    stale = [m.id for m in mod.MUTANTS if (root / m.file).read_text().count(m.old) != 1]
    assert not stale, f"mutants whose text is not found exactly once: {stale}"
    assert len({m.id for m in mod.MUTANTS}) == len(mod.MUTANTS)


def test_the_readme_counts_the_mutants(monkeypatch):
    """README's *Development* says how many mutants ``make mutants`` applies: the list's
    length (it said 58 while the list held 65)."""
    import importlib.util
    import re

    name = "gridflow_mutation_count"
    spec = importlib.util.spec_from_file_location(name, ROOT / "tests" / "mutation.py")
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, mod)
    spec.loader.exec_module(mod)
    said = re.findall(r"applies (\d+) hand-written", (ROOT / "README.md").read_text())
    assert said == [str(len(mod.MUTANTS))], (said, len(mod.MUTANTS))
