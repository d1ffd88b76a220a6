"""A user's failing controller in one process (issue 21, items 1 and 2; the fleet runs of
the same scenarios, compared with these, are in tests/faults/test_controller_errors.py).

- ``step()`` raises from t = 1 s on: one terminal line per robot (robot, time, exception),
  ``controller_errors`` counted from the log, the traceback once in the robot's log, every
  target missed and ``copath run --check`` exiting 3.
- A robot sends NaN in its payloads from t = 1 s on: its listeners refuse every one (the
  receiver validation of a Zenoh subscriber), the lockstep barrier does not wait for them
  and no NaN reaches a controller.

The controller is a small user controller (``tests/faults/user_controller.py``)."""

from __future__ import annotations

import io
import json
import math

import pytest

from copath.scenario import parse_scenario
from copath.grading import grade
from copath.wire.keys import Keys
from copath.wire.messages import Event, Stats
from orchestrator import api
from orchestrator.cli import main as copath
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.mcap import read_log
from tests.faults.test_controller_errors import FAIL_AT, _assert_one_failure_line, _closing, _failing_steps, _nan_heard, _write

def test_step_exception_in_one_process_one_line_counted_traceback_once_check_fails(tmp_path, capsys):
    config = _write(tmp_path, 3.0, fail_after_s=FAIL_AT)
    out = tmp_path / "run"
    rc = copath(["run", config, "--inprocess", "--out", str(out), "--check", "--no-plots", "-q"])
    assert rc == 3
    got = capsys.readouterr()
    _assert_one_failure_line(got.err, str(out / "logs" / "r2.log"))
    assert "the controller of r2 failed" in got.err
    assert "CONTROLLER FAILED: robot r2" in got.out
    m = json.loads((out / "metrics.json").read_text())
    log = read_log(out / "run.mcap")
    keys = Keys(m["run_id"])
    steps = _failing_steps(log.records, keys, "r2")
    assert steps > 0
    assert m["robots"]["r2"]["controller_errors"] == steps
    assert m["robots"]["r2"]["solver_failures"] == 0  # a raised step is not a solver failure
    assert [m["robots"][r]["controller_errors"] for r in ("r1", "r3", "r4")] == [0, 0, 0]
    assert m["fleet"]["controller_errors"] == steps
    events = [r for _, _, r in log.records if isinstance(r, Event) and r.what == "controller_error"]
    assert [(e.source, e.t, e.detail["error"]) for e in events] == [("r2", pytest.approx(FAIL_AT), "ZeroDivisionError")]
    assert "Traceback" in events[0].detail["traceback"]
    text = (out / "logs" / "r2.log").read_text()
    assert text.count("Traceback") == 1 and "ZeroDivisionError" in text
    # the run's own verdict stands (it completed), but no target passes and the API agrees
    assert m["ok"] is True
    run = api.open_run(out)
    results = run.grade()
    assert results and not any(r.passed for r in results)
    assert all("r2" in r.reason for r in results)
    stats = {r.proc: r.counters for _, _, r in log.records if isinstance(r, Stats)}
    assert stats["r2"]["controller_errors"] == steps


def test_a_failed_robot_or_a_null_figure_never_lets_a_target_pass():
    metrics = {"robots": {"a": {"path_error_max_m": 0.01, "controller_errors": 0},
                          "b": {"path_error_max_m": None, "controller_errors": 0}},
               "fleet": {"collisions": 0}}
    sc = parse_scenario({**json.loads(json.dumps(_MINIMAL)), "targets": {"path_error_max_m": 0.1, "collisions": 0}})
    r = grade(sc.targets, metrics)
    assert (r[0].passed, r[0].worst) == (False, "b") and "b" in r[0].reason
    assert r[1].passed
    metrics["robots"]["b"] = {"path_error_max_m": 0.02, "controller_errors": 3}
    r = grade(sc.targets, metrics)
    assert not r[0].passed and not r[1].passed
    assert all("controller failed: b (3 steps)" in x.reason for x in r)


_MINIMAL = {
    "id": "t-grade", "run": {"duration_s": 1.0, "dt": 0.1},
    "paths": {"c": {"type": "circle", "radius": 1.0}},
    "controller": {"type": "tests.faults.user_controller:build"},
    "robots": [{"name": "a", "path": "c", "pose": [1.0, 0.0, 1.57]}, {"name": "b", "path": "c", "pose": [-1.0, 0.0, -1.57]}],
}


def test_nan_payload_in_one_process_is_rejected_as_over_zenoh_and_the_barrier_does_not_wait(tmp_path):
    sc = api.load(_write(tmp_path, 3.0, nan_after_s=FAIL_AT))
    res = run_scenario(sc, failures=io.StringIO())
    keys = Keys(res.metrics["run_id"])
    m = res.metrics
    # r2's neighbours that listen to it (r1, r3) refuse each of its messages from FAIL_AT on
    sent = sum(1 for _, k, _ in res.records if k == keys.peer_broadcast("r2"))
    bad = sum(1 for _, k, r in res.records if k == keys.peer_broadcast("r2") and not math.isfinite(r.payload["xi"]))
    assert 0 < bad < sent
    assert m["robots"]["r1"]["messages_rejected"] == m["robots"]["r3"]["messages_rejected"] == bad
    assert m["robots"]["r2"]["messages_rejected"] == m["robots"]["r4"]["messages_rejected"] == 0
    assert m["fleet"]["messages_rejected"] == 2 * bad
    accounts = _closing(res.records)
    assert all(accounts[r].get("barrier_timeouts", 0) == 0 for r in sc.robot_names)
    assert _nan_heard(res.records, keys) == 0  # no NaN reached a controller
    assert m["fleet"]["controller_errors"] == 0
