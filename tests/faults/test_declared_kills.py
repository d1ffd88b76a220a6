"""Kills declared in the scenario (``run.kills``, docs/reference/faults.md, "A kill declared in the
scenario"): the robot's process is killed at a simulated time, over Zenoh under both clocks and in
one process, the same tick; under ``restart`` it comes back and is killed again only by a later
kill. The bundled `e5.4-six-robots-lemniscate-r1-killed` is issue 20's case E5.4 with r1 killed
at 10 s."""

from __future__ import annotations

import json
import re

import pytest

from orchestrator import api
from orchestrator.log.mcap import read_log
from orchestrator.run.inprocess import run_scenario
from orchestrator.testkit.scenarios import config

SCENARIO = "e5.4-six-robots-lemniscate-r1-killed"
SHORT = ["run.duration_s=25", "run.settle_s=5"]


def _sim_events(records, what):
    return [r for _, _, r in records if getattr(r, "TYPE", "") == "event" and r.source == "sim" and r.what == what]


def _fleet(procs, out, clock, *sets):
    args = ["-m", "orchestrator", "run", str(config(SCENARIO)), "--out", str(out), "--run-id", "declared",
            "-q", "--no-plots", "--set", f'run.clock="{clock}"']
    for s in (*SHORT, *sets):
        args += ["--set", s]
    p = procs.start(args)
    assert p.wait(timeout=300) == 0, p.stderr.read().decode()[-3000:]
    return json.loads((out / "metrics.json").read_text()), read_log(out / "run.mcap").records


@pytest.mark.fleet
@pytest.mark.timeout(400)
@pytest.mark.parametrize("clock", ["lockstep", "realtime"])
def test_a_declared_kill_takes_the_robot_s_process_at_its_time_over_zenoh(tmp_path, procs, clock):
    m, records = _fleet(procs, tmp_path, clock)
    assert m["ok"] and m["fleet"]["collisions"] == 0
    lost = _sim_events(records, "robot_lost")
    assert [r.detail["robot"] for r in lost] == ["r1"]
    # the first observation after 10 s goes unanswered: lost at 10.1 s in lockstep; in realtime
    # the token goes with the process, within the liveliness watch's reach of it
    if clock == "lockstep":
        assert lost[0].t == pytest.approx(10.1, abs=1e-6), lost[0].t
    else:
        assert 10.0 <= lost[0].t <= 10.6, lost[0].t
    said = (tmp_path / "logs" / "r1.log").read_text()  # the robot's own last word
    if clock == "lockstep":  # on the first observation after 10 s
        assert "killed at sim t=10.10 s (run.kills)" in said
    else:  # between its steps, at 10.05 s on the run's clock (its own timer, not the observation after)
        when = float(re.search(r"killed at run time ([0-9.]+) s \(run.kills\)", said).group(1))
        assert 10.05 <= when < 10.3, when
    assert m["robots"]["r1"]["outage_s"] > 10 and m["robots"]["r1"]["restarts"] == 0
    assert m["fleet"]["accounts_reconstructed"] == 1  # a SIGKILLed process sends no closing account
    assert m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"]
    # the live robots went round the held r1 (the detour stage) and were graded without it
    assert all(m["robots"][n]["detours"] >= 1 for n in ("r2", "r3"))
    if clock == "lockstep":  # the same tick as in one process, and the others learn of it at the same step
        # (Obs.down; docs/reference/faults.md, "When the others learn of a loss"): the same run, robot by robot
        scen = api.load(config(SCENARIO), overrides=SHORT)
        inproc = run_scenario(scen).metrics
        for n, r in m["robots"].items():
            assert r["path_progress_m"] == inproc["robots"][n]["path_progress_m"], n
        assert m["fleet"]["min_separation_m"] == inproc["fleet"]["min_separation_m"]
        told = sorted((e.source, round(e.t, 2)) for _, _, e in records
                      if getattr(e, "TYPE", "") == "event" and e.what == "peer_lost" and e.detail.get("robot") == "r1")
        assert told == [(n, 10.1) for n in ("r2", "r3", "r4", "r5", "r6")]  # 10.2 s before Obs.down


@pytest.mark.fleet
@pytest.mark.timeout(400)
def test_a_restarted_robot_is_killed_again_only_by_a_later_kill_over_zenoh(tmp_path, procs):
    m, records = _fleet(procs, tmp_path, "lockstep", 'run.on_robot_failure="restart"',
                        'run.kills=[{robot="r1", at_s=8.0}, {robot="r1", at_s=16.0}]')
    assert m["ok"] and m["fleet"]["collisions"] == 0
    assert [(r.what, round(r.t, 1)) for r in _sim_events(records, "robot_lost")] == [("robot_lost", 8.1),
                                                                                    ("robot_lost", 16.1)]
    assert len(_sim_events(records, "robot_rejoined")) == 2
    assert m["robots"]["r1"]["restarts"] == 2
    logs = sorted((tmp_path / "logs").glob("r1*.log"))
    assert [p.name for p in logs] == ["r1.log", "r1.restart1.log", "r1.restart2.log"]
    killed = ["(run.kills)" in p.read_text() for p in logs]
    assert killed == [True, True, False]  # the last process runs to the end


def test_in_one_process_a_declared_kill_is_the_same_as_a_caller_s_and_restart_brings_it_back():
    scen = api.load(config(SCENARIO), overrides=SHORT)
    declared = run_scenario(scen)
    plain = api.load(config(SCENARIO), overrides=[*SHORT, "run.kills=[]"])
    called = run_scenario(plain, kills={"r1": 10.0})
    for n, r in declared.metrics["robots"].items():  # the same run, to the bit
        assert (r["path_progress_m"], r["detours"], r["outage_s"]) == (
            called.metrics["robots"][n]["path_progress_m"], called.metrics["robots"][n]["detours"],
            called.metrics["robots"][n]["outage_s"]), n
    assert [round(r.t, 1) for r in _sim_events(declared.records, "robot_lost")] == [10.1]
    again = api.load(config(SCENARIO), overrides=[*SHORT, 'run.on_robot_failure="restart"',
                                                  'run.kills=[{robot="r1", at_s=8.0}, {robot="r1", at_s=16.0}]'])
    res = run_scenario(again)
    assert res.ok and res.metrics["robots"]["r1"]["restarts"] == 2
    assert [(r.what, round(r.t, 1)) for r in _sim_events(res.records, "robot_lost") + _sim_events(
        res.records, "robot_rejoined")] == [("robot_lost", 8.1), ("robot_lost", 16.1),
                                            ("robot_rejoined", 9.1), ("robot_rejoined", 17.1)]
