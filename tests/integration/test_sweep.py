"""``copath sweep`` over real fleets: two runs at once, each its own router, processes and log."""

from __future__ import annotations

import csv

import pytest

from orchestrator.cli import main as copath
from orchestrator.log.mcap import read_log

pytestmark = pytest.mark.fleet


def test_sweep_of_fleets_runs_each_setting_as_its_own_fleet(tmp_path, capsys):
    rc = copath(["sweep", "e5.5", "--seeds", "3", "--set", "network.loss=0,0.3", "--set", "run.duration_s=3",
                 "--set", "run.settle_s=1", "--jobs", "2", "--out", str(tmp_path), "--wall-timeout", "240", "-q"])
    assert rc == 0, capsys.readouterr().err
    rows = list(csv.DictReader((tmp_path / "sweep.csv").open()))
    assert [(r["network.loss"], r["run.seed"], r["ok"]) for r in rows] == [("0", "3", "True"), ("0.3", "3", "True")]
    for i, r in enumerate(rows):
        log = read_log(tmp_path / f"run{i:03d}" / "run.mcap")  # every run kept its own log
        assert log.run_id == r["run_id"]
        assert log.scenario_raw["network"]["loss"] == float(r["network.loss"])
        assert log.scenario_raw["run"]["seed"] == 3
    assert float(rows[0]["messages_dropped_by_faults"]) == 0 < float(rows[1]["messages_dropped_by_faults"])
    assert (tmp_path / "sweep-messages_dropped_by_faults.png").is_file()
