"""Detours over Zenoh (docs/reference/detours.md): the box-on-lane column as robot processes in lockstep
goes round the box as the in-process run does, and its log carries the detour events."""

from __future__ import annotations

import json

import pytest

from copath.scenario import load_scenario
from orchestrator.cli import main as copath
from orchestrator.run.inprocess import run_scenario
from tests.conftest import config

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(400)]


def test_box_on_lane_column_over_zenoh(tmp_path):
    rc = copath(["run", str(config("e5.5-column-box-on-lane")), "--out", str(tmp_path), "-q", "--duration", "40"])
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert rc == 0 and m["ok"], m.get("failure")
    assert m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"]
    f = m["fleet"]
    assert f["collisions"] == 0 and f["min_obstacle_clearance_m"] > 0.0
    assert all(r["detours"] == 1 and r["stalled_s"] == 0.0 for r in m["robots"].values())
    ref = run_scenario(load_scenario(config("e5.5-column-box-on-lane")), duration_s=40.0).metrics
    for n, r in m["robots"].items():  # lockstep: the processes run the in-process run
        assert r["path_progress_m"] == pytest.approx(ref["robots"][n]["path_progress_m"], abs=1e-6)
