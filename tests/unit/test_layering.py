"""The architecture's import rules, checked on the source: the library (``copath/``) never
imports a program (``agent/``, ``sim/``, ``orchestrator/``), not even inside a function, and
the simulator never loads agent code (it owns the truth, not the controllers)."""

from __future__ import annotations

import ast
import pathlib

import pytest

from tests.conftest import REPO

RULES = {"copath": {"agent", "sim", "orchestrator"}, "sim": {"agent", "orchestrator"}}


def _imports(path: pathlib.Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


@pytest.mark.parametrize("package", sorted(RULES))
def test_package_does_not_import_the_programs(package):
    files = sorted((REPO / package).rglob("*.py"))
    assert files
    bad = {str(f.relative_to(REPO)): sorted(_imports(f) & RULES[package]) for f in files}
    assert not {f: m for f, m in bad.items() if m}


def _modules(path: pathlib.Path) -> set[str]:
    """Every module ``path`` imports, by its full dotted name (relative imports resolved
    against the file's package), wherever the import stands (a function body too)."""
    package = list(path.relative_to(REPO).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join([*base, *([node.module] if node.module else [])])
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)  # ``from pkg import module``
    return out


def _offending(files, banned: tuple[str, ...]) -> dict[str, list[str]]:
    """Per file, the imported modules that are, or lie under, one of ``banned``."""
    bad = {}
    for f in files:
        hits = sorted(m for m in _modules(f) if any(m == b or m.startswith(b + ".") for b in banned))
        if hits:
            bad[str(f.relative_to(REPO))] = hits
    return bad


def _tracked_python() -> list[pathlib.Path]:
    """The project's Python files (the checkout's, not a virtual environment's)."""
    skip = {".git", ".venv", "venv", "build", "dist", "node_modules"}
    return sorted(p for p in REPO.rglob("*.py")
                  if not skip & set(p.relative_to(REPO).parts) and not any(s.endswith(".egg-info") for s in p.parts))


def test_nothing_outside_tests_imports_tests():
    """The programs, the studies and the examples never import the test suite: what both
    need lives in ``orchestrator.testkit``."""
    files = [p for p in _tracked_python() if p.relative_to(REPO).parts[0] != "tests"]
    assert files
    assert not _offending(files, ("tests",))


def test_studies_never_import_tests():
    """The benchmarks and studies take their helpers from the test kit, not from ``tests/``."""
    files = sorted((REPO / "orchestrator" / "studies").rglob("*.py"))
    assert files
    assert not _offending(files, ("tests",))


def test_the_recorder_knows_nothing_of_views():
    """The log side (``orchestrator/log``: writing, reading, replay, export) never imports the
    views; the Foxglove views are a tap whoever wants them adds to the recorder."""
    files = sorted((REPO / "orchestrator" / "log").rglob("*.py"))
    assert files
    assert not _offending(files, ("orchestrator.view",))


def test_analysis_never_imports_the_agent_runtime_or_the_simulator():
    """Metrics come from the truth in the log: the analysis reads records, it never runs a
    robot's runtime or the simulator to get them."""
    files = sorted((REPO / "orchestrator" / "analysis").rglob("*.py"))
    assert files
    assert not _offending(files, ("agent.runtime", "sim"))


def test_the_views_take_the_sensor_ring_from_the_library():
    """The Foxglove views need no robot process: nothing under ``orchestrator/view`` imports
    the agent runtime (the sensor ring's bearings come from ``copath.scenario``)."""
    files = sorted((REPO / "orchestrator" / "view").rglob("*.py"))
    assert files
    assert not _offending(files, ("agent.runtime",))


# -- controller families (issue 23): a family is one unit, declared on its factory ----------

CONTROLLERS_DIR = REPO / "agent" / "controllers"


def _family_names() -> set[str]:
    """The registered controller names (the registry's name table, read from its source)."""
    tree = ast.parse((CONTROLLERS_DIR / "__init__.py").read_text())
    for node in tree.body:
        target = node.target if isinstance(node, ast.AnnAssign) else (node.targets[0] if isinstance(node, ast.Assign)
                                                                         else None)
        if getattr(target, "id", None) == "CONTROLLERS":
            return {k.value for k in node.value.keys}
    raise AssertionError("agent/controllers/__init__.py has no CONTROLLERS table")


def test_controllers_never_import_the_orchestrator():
    files = sorted(CONTROLLERS_DIR.rglob("*.py"))
    assert len(files) > 20
    assert not _offending(files, ("orchestrator",))


def _names_compared(path: pathlib.Path, names: set[str]) -> list[str]:
    """Registered controller names a file compares something with (==, !=, in, not in),
    as ``line: name``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if not isinstance(node, ast.Compare):
            continue
        for side in [node.left, *node.comparators]:
            consts = [side] if isinstance(side, ast.Constant) else (
                list(side.elts) if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [])
            found += [f"{node.lineno}: {c.value}" for c in consts
                      if isinstance(c, ast.Constant) and isinstance(c.value, str) and c.value in names]
    return found


# a benchmark of one family's own solver (orchestrator bench solve: the LTV QP) is about that family
FAMILY_IMPORT_EXCEPTIONS = {"orchestrator/studies/bench/solve.py"}


def test_nothing_outside_a_family_names_it():
    """No module of the programs or the library outside ``agent/controllers/`` compares a
    controller name or imports a family's modules: the metrics, the simulator's stop rule and
    validation ask the factory (geometry, payloads, tasks, handles_*). The registry's name
    table (``agent/controllers/__init__.py``) is the one place that names the families. (The
    families themselves share pieces of law, e.g. the heterogeneous team calls the consensus
    tracking law, and a family may name its own controller types.)"""
    names = _family_names()
    families = {d.name for d in CONTROLLERS_DIR.iterdir() if (d / "__init__.py").exists()}
    assert "consensus" in names and "roles" in families
    files = [f for pkg in ("agent", "sim", "orchestrator", "copath") for f in sorted((REPO / pkg).rglob("*.py"))
             if CONTROLLERS_DIR not in f.parents]
    assert len(files) > 50
    compared = {str(f.relative_to(REPO)): _names_compared(f, names) for f in files}
    assert not {f: c for f, c in compared.items() if c}
    internals = {str(f.relative_to(REPO)): sorted(m for m in _modules(f)
                                                  if m.split(".")[:2] == ["agent", "controllers"] and len(m.split(".")) > 2
                                                  and m.split(".")[2] in families)
                 for f in files}
    assert not {f: m for f, m in internals.items() if m and f not in FAMILY_IMPORT_EXCEPTIONS}
