"""The fault and trust suite (issue 10), the faults tier: ``python -m pytest -q -m 'faults
and not slow'`` runs it, ``-m slow`` the long ones (README "Test tiers"; every test here is
marked ``faults`` by tests/conftest.py). Every process a test starts is killed by pid."""

from __future__ import annotations

import pytest

from tests.integration.conftest import procs  # noqa: F401  (the fixture that kills by pid)

E55_LOG_S = 32.0
"""Simulated length of :func:`e55_log`."""
E55_LOG_RUN_ID = "e55-log"


@pytest.fixture(scope="session")
def e55_log(tmp_path_factory):
    """The run log of E5.5 in lockstep, in-process, 32 s (the files and replay tests read it)."""
    from copath.scenario import load_scenario  # noqa: PLC0415
    from orchestrator.run.inprocess import run_scenario  # noqa: PLC0415
    from orchestrator.log.writer import write_records  # noqa: PLC0415
    from tests.conftest import config  # noqa: PLC0415

    scen = load_scenario(config("e5.5-"))
    res = run_scenario(scen, duration_s=E55_LOG_S)
    return write_records(tmp_path_factory.mktemp("e55-log") / "run.mcap", res.records, scen, E55_LOG_RUN_ID)
