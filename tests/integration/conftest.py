"""Multi-process tests: every process a test starts is tracked and killed by pid
(``orchestrator.testkit.processes``)."""

from __future__ import annotations

import pytest

from orchestrator.testkit.processes import Procs


@pytest.fixture
def procs():
    ps = Procs()
    yield ps
    ps.cleanup()
