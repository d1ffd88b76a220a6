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
