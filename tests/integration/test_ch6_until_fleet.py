"""``run.until = "tasks_done"`` over Zenoh: the simulator process stops a Chapter 6 run on
the same tick as the in-process loop (the truth of the last formation, copath.occupancy),
because every robot's announcement of a tick arrives before its command of that tick."""

from __future__ import annotations

import json

import pytest

from copath.scenario import load_scenario
from copath.wire.messages import Event
from orchestrator.cli import main as copath
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.mcap import read_log
from tests.conftest import config

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(300)]


def _tasks_done(records) -> list[float]:
    return [r.detail["t"] for _, _, r in records if isinstance(r, Event) and r.what == "tasks_done"]


def test_fleet_ends_on_the_same_tick_as_the_in_process_loop(tmp_path):
    path = config("e6.5-")
    rc = copath(["run", str(path), "--out", str(tmp_path), "--run-id", "e65-until", "--no-plots", "-q"])
    assert rc == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    ref = run_scenario(load_scenario(path))
    fleet_done = _tasks_done(read_log(tmp_path / "run.mcap").records)
    assert len(fleet_done) == 1 and fleet_done == _tasks_done(ref.records)
    assert m["sim_time_s"] == ref.metrics["sim_time_s"] < load_scenario(path).run.duration_s
    assert m["fleet"]["task_times_s"] == ref.metrics["fleet"]["task_times_s"]
    assert m["fleet"]["tasks_completed"] == m["fleet"]["tasks_total"]
