"""Faults are part of the record: fault settings in the MCAP metadata, every injected drop
(aggregated per step) and every partition window as an event on the timeline."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from copath.scenario import load_scenario
from copath.wire.faults import windows_between
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.mcap import read_log
from orchestrator.log.writer import write_records
from orchestrator.analysis.truth import truth_series
from tests.conftest import config


def _faulty(tmp_path):
    toml = config("e5.5-").read_text()
    path = tmp_path / "faulty.toml"
    extra = ('\n[network]\nloss = 0.2\ndelay_ms = 100\n'
             'partitions = [{links = [["r1", "r2"]], start_s = 5.0, end_s = 8.0}]\n')
    assert "[network]" not in toml
    path.write_text(toml + extra)
    return load_scenario(path)


def test_partition_windows_open_and_close_once():
    from copath.scenario import NetworkConfig, Partition

    net = NetworkConfig(partitions=(Partition((("r1", "r2"),), 5.0, 8.0),))
    got = [w for k in range(100) for w in windows_between(net, k * 0.1, (k + 1) * 0.1)]
    assert [w[0] for w in got] == ["partition_start", "partition_end"]
    assert got[0][1]["links"] == [["r1", "r2"]]


def test_drops_and_partitions_are_events_and_the_settings_are_metadata(tmp_path):
    scen = _faulty(tmp_path)
    res = run_scenario(scen, duration_s=45.0)
    log = read_log(write_records(tmp_path / "run.mcap", res.records, scen, "faults-record"))
    net = json.loads(log.metadata["faults"]["network"])
    assert net["loss"] == 0.2 and net["delay_ms"] == 100 and net["partitions"][0]["start_s"] == 5.0
    events = [r for _, _, r in log.records if getattr(r, "TYPE", "") == "event"]
    windows = [(e.what, e.t) for e in events if e.what.startswith("partition_")]
    assert windows == [("partition_start", 5.0), ("partition_end", 8.0)]
    injected = [e for e in events if e.what == "faults_injected"]
    dropped = sum(e.detail["dropped"] for e in injected)
    partitioned = sum(e.detail["partitioned"] for e in injected)
    assert dropped == res.metrics["fleet"]["messages_dropped_by_faults"] - partitioned > 0
    assert partitioned > 0
    part = [e for e in injected if e.detail["partitioned"]]
    assert all(5.0 <= e.t <= 8.0 + 0.3 for e in part)  # stamped in the window, reported a step later
    assert {e.source for e in part} == {"r1", "r2"}


def test_a_silent_radio_neither_sends_nor_receives_and_is_on_the_timeline(tmp_path):
    toml = config("e5.5-").read_text()
    path = tmp_path / "silent.toml"
    path.write_text(toml + '\n[network]\nsilence = [{robot = "r2", start_s = 5.0, end_s = 10.0}]\n')
    scen = load_scenario(path)
    # 5 s of silence is a lost robot (docs/reference/faults.md): go on without it, as the test measures recovery
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, on_robot_failure="continue"))
    res = run_scenario(scen, duration_s=45.0)
    log = read_log(write_records(tmp_path / "run.mcap", res.records, scen, "silence"))
    assert json.loads(log.metadata["faults"]["network"])["silence"] == [{"robot": "r2", "start_s": 5.0, "end_s": 10.0}]
    events = [r for _, _, r in log.records if getattr(r, "TYPE", "") == "event"]
    assert [(e.what, e.t) for e in events if e.what.startswith("silence_")] == [("silence_start", 5.0),
                                                                                ("silence_end", 10.0)]
    silenced = [e for e in events if e.what == "faults_injected" and e.detail["silenced"]]
    assert silenced and all(5.0 < e.t <= 10.0 + 0.15 for e in silenced)
    by_receiver = {e.source for e in silenced}
    assert by_receiver == {"r1", "r2", "r3"}  # r2 hears nothing, and nobody hears r2
    assert all(set(e.detail["from"]) == {"r2"} for e in silenced if e.source != "r2")
    assert res.metrics["fleet"]["messages_dropped_by_faults"] == sum(e.detail["silenced"] for e in silenced)
    # r2, cut off, held still from 6.1 s to the silence's end (run.cut_off = "hold",
    # docs/reference/faults.md "Gone quiet"), fell behind by about a metre, and the team closes up
    # again: 0.07 m at 30 s, under 0.05 m from 35 s (with "drive" r2 drives on blind: 0.009 m)
    assert [(e.t, e.what) for e in events if e.source == "r2" and e.what in ("cut_off", "reconnected")] == \
        [(pytest.approx(6.1), "cut_off"), (pytest.approx(10.1, abs=0.15), "reconnected")]
    ser = truth_series(res.trace, scen)
    assert np.nanmax(ser.coordination_error[ser.t >= 35.0]) < 0.05
    assert res.metrics["fleet"]["coordination_error_max_m"] < 0.1


def test_a_silence_must_name_a_robot(tmp_path):
    from copath.scenario import ConfigError

    path = tmp_path / "bad.toml"
    path.write_text(config("e5.5-").read_text() + '\n[network]\nsilence = [{robot = "r9", start_s = 1.0}]\n')
    with pytest.raises(ConfigError, match=r"network.silence\[0\].robot = 'r9' is not allowed"):
        load_scenario(path)
