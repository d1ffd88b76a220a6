"""A user's failing controller is seen, not hidden (issue 21, items 1 and 2).

- ``step()`` raises from t = 1 s on: one terminal line per robot (robot, time, exception),
  ``controller_errors`` counted from the log, the traceback once in the robot's log, every
  target missed and ``copath run --check`` exiting 3; in one process and as a fleet.
- A robot sends NaN in its payloads from t = 1 s on: every receiver rejects them, the same
  count in one process and over Zenoh, the lockstep barrier does not wait for them (no
  barrier timeout) and both runs give the same metrics; no NaN reaches a controller.

The controller is a small user controller (``tests/faults/user_controller.py``)."""

from __future__ import annotations

import io
import json
import math

import pytest

from copath.scenario import parse_scenario
from copath.targets import grade
from copath.wire.keys import Keys
from copath.wire.messages import Event, Stats
from orchestrator import api
from orchestrator.cli import main as copath
from orchestrator.inprocess import run_scenario
from orchestrator.mcaplog import read_log
from tests.faults.user_controller import scenario_text

FAIL_AT = 1.0
"""Controller time [s] from which the misbehaving robot misbehaves."""


def _write(tmp_path, duration: float, **r2) -> str:
    path = tmp_path / "scenario.toml"
    path.write_text(scenario_text(duration, **r2))
    return str(path)


def _failing_steps(records, keys: Keys, robot: str) -> int:
    """Steps of ``robot`` at or after FAIL_AT: the ones whose step() raised."""
    return sum(1 for _, k, r in records if k == keys.telemetry(robot) and r.t >= FAIL_AT - 1e-9)


def _assert_one_failure_line(err: str, log_hint: str) -> None:
    lines = [ln for ln in err.splitlines() if "controller step failed" in ln]
    assert len(lines) == 1, err[-3000:]
    line = lines[0]
    assert "robot r2" in line and f"t={FAIL_AT:.2f} s" in line and "ZeroDivisionError" in line
    assert log_hint in line
    assert "Traceback" not in err


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


def _closing(records) -> dict[str, dict]:
    return {r.proc: r.counters for _, _, r in records if isinstance(r, Stats)}


def _nan_heard(records, keys: Keys) -> int:
    return sum(int(r.data.get("heard_nan", 0)) for _, k, r in records
               if k.endswith("/telemetry") and k.startswith(keys.prefix))


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


@pytest.mark.fleet
@pytest.mark.integration
def test_step_exception_and_nan_payload_as_a_fleet_match_one_process(tmp_path, procs):
    """Both misbehaviours over Zenoh in lockstep, against the same scenario in one process."""
    for name, r2, rc_want in (("crash", {"fail_after_s": FAIL_AT}, 3), ("nan", {"nan_after_s": FAIL_AT}, 0)):
        config = tmp_path / f"{name}.toml"
        config.write_text(scenario_text(4.0, **r2))
        out = tmp_path / name
        p = procs.start(["-m", "orchestrator", "run", str(config), "--out", str(out), "--check", "--no-plots", "-q"])
        _, err = p.communicate(timeout=240)
        err = err.decode()
        assert p.returncode == rc_want, err[-3000:]
        m = json.loads((out / "metrics.json").read_text())
        assert m["ok"] is True
        log = read_log(out / "run.mcap")
        keys = Keys(m["run_id"])
        accounts = _closing(log.records)
        # the barrier never waited for a message it had dropped
        assert all(accounts[r].get("barrier_timeouts", 0) == 0 for r in ("r1", "r2", "r3", "r4")), accounts
        ref = run_scenario(api.load(str(config)), failures=io.StringIO()).metrics
        for r in ("r1", "r2", "r3", "r4"):
            for key in ("controller_errors", "messages_rejected", "path_error_max_m", "path_progress_m"):
                assert m["robots"][r][key] == pytest.approx(ref["robots"][r][key], rel=1e-9, abs=1e-12), (name, r, key)
        for key in ("controller_errors", "messages_rejected", "coordination_error_max_m", "min_separation_m"):
            assert m["fleet"][key] == pytest.approx(ref["fleet"][key], rel=1e-9, abs=1e-12), (name, key)
        if name == "crash":
            _assert_one_failure_line(err, str(out / "logs" / "r2.log"))
            assert m["robots"]["r2"]["controller_errors"] == _failing_steps(log.records, keys, "r2") > 0
            text = (out / "logs" / "r2.log").read_text()
            assert text.count("Traceback") == 1 and "controller step failed" in text
            assert f"failed {m['robots']['r2']['controller_errors']} times in all" in text
            assert len(text.splitlines()) < 40  # not one traceback per tick
        else:
            assert "controller step failed" not in err
            assert m["robots"]["r1"]["messages_rejected"] == m["robots"]["r3"]["messages_rejected"] > 0
            assert _nan_heard(log.records, keys) == 0
