"""Shared test configuration: test tiers, hypothesis profile and scenario helpers.

Tiers (README "Test tiers"; the markers are registered in pyproject.toml):

- ``fleet``: the test starts real processes over Zenoh. Every test under tests/integration is
  marked so here, and so is any test marked with the older name ``integration``, or, under
  tests/faults, any test that takes the ``procs`` fixture (the one that kills by pid).
- ``faults``: a fault or trust case. Every test under tests/faults is marked so here.
- ``long``: a closed-loop run in one process that takes many seconds, marked by hand.
- ``slow``: a long run (minutes), marked by hand on the test; no tier but its own runs it.
- ``smoke``: the one fleet test kept in the fast tier (a short E5.5 lockstep fleet).

``python -m pytest -q`` (pyproject's ``addopts``) runs the fast tier: everything that is none
of fleet, faults, long or slow, plus the smoke test. A ``-m`` on the command line replaces that
selection (``-m 'faults and not slow'``). Naming test files or folders without a ``-m``
runs every test in them but the slow ones (``python -m pytest -q tests/faults/test_acl.py``)."""

from __future__ import annotations

import pathlib

import pytest
from hypothesis import HealthCheck, settings

from orchestrator.testkit.scenarios import CONFIGS, config  # noqa: F401  (the tests' scenario lookup)

REPO = pathlib.Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"

settings.register_profile("copath", deadline=None, max_examples=60,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("copath")


def pytest_configure(config: pytest.Config) -> None:
    """Named files or folders and no ``-m`` of one's own: every test in them but the slow ones."""
    own_m = any(a == "-m" or (a.startswith("-m") and not a.startswith("--")) for a in config.invocation_params.args)
    if config.args_source == pytest.Config.ArgsSource.ARGS and not own_m:
        config.option.markexpr = "not slow"


def _under(item: pytest.Item, folder: str) -> bool:
    return pathlib.Path(str(item.path)).resolve().is_relative_to(TESTS / folder)


@pytest.hookimpl(tryfirst=True)  # before ``-m`` deselects by marker
def pytest_collection_modifyitems(config, items) -> None:
    """Mark each test with its tier by the folder it lives in (module docstring)."""
    for item in items:
        fleet = item.get_closest_marker("fleet") is not None or item.get_closest_marker("integration") is not None
        if _under(item, "integration"):
            fleet = True
        if _under(item, "faults"):
            if item.get_closest_marker("faults") is None:
                item.add_marker(pytest.mark.faults)
            fleet = fleet or "procs" in getattr(item, "fixturenames", ())
        if fleet and item.get_closest_marker("fleet") is None:
            item.add_marker(pytest.mark.fleet)


@pytest.fixture(scope="session")
def configs_dir() -> pathlib.Path:
    return CONFIGS


def is_connected(A) -> bool:
    """Whether the undirected graph with boolean adjacency matrix ``A`` is connected."""
    import numpy as np

    seen, stack = {0}, [0]
    while stack:
        i = stack.pop()
        for j in np.nonzero(A[i])[0]:
            if j not in seen:
                seen.add(int(j))
                stack.append(int(j))
    return len(seen) == len(A)
