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
