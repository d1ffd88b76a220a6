"""The fast tier's one fleet test (README "Test tiers"): E5.5 as real processes over Zenoh on
loopback, in lockstep, for 10 s of simulated time. Every tick of every robot is stepped and
recorded, and the figures from the log's truth equal those of the same run in one process;
the full-length runs, the faults and the other clocks are in tests/integration (``-m fleet``)."""

from __future__ import annotations

import json

import pytest

from copath.scenario import load_scenario
from copath.wire.keys import Keys
from orchestrator.cli import main as copath
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.mcap import read_log
from tests.conftest import config

pytestmark = [pytest.mark.smoke, pytest.mark.timeout(180)]

DURATION_S = 10.0
SETTLE_S = 5.0


def test_a_short_lockstep_fleet_over_zenoh_equals_the_same_run_in_one_process(tmp_path):
    rc = copath(["run", str(config("e5.5-")), "--out", str(tmp_path), "--run-id", "smoke", "--duration",
                 str(DURATION_S), "--set", f"run.settle_s={SETTLE_S}", "--no-plots", "-q"])
    assert rc == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["ok"] and m["clock"] == "lockstep" and m["run_id"] == "smoke"
    assert all(r["missed_ticks"] == 0 for r in m["robots"].values())
    assert m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"] > 0
    log = read_log(tmp_path / "run.mcap")
    assert log.rejected == 0
    keys = Keys("smoke")
    ticks = round(DURATION_S / 0.1)  # E5.5's dt
    assert log.counts[keys.truth] == ticks
    assert all(log.counts[keys.cmd(n)] == ticks for n in ("r1", "r2", "r3"))

    scen = load_scenario(config("e5.5-")).with_overrides(run={"duration_s": DURATION_S, "settle_s": SETTLE_S})
    ref = run_scenario(scen).metrics
    for key in ("coordination_error_max_m", "coordination_error_rms_m", "min_separation_m", "messages_published"):
        assert m["fleet"][key] == ref["fleet"][key], key
    for n in ref["robots"]:
        for key in ("path_error_max_m", "path_error_rms_m", "heading_error_max_rad", "speed_error_rms_mps"):
            assert m["robots"][n][key] == ref["robots"][n][key], (n, key)
