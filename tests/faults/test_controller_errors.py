"""A user's failing controller as a lockstep fleet over Zenoh, against the same scenario in
one process (issue 21, items 1 and 2; the in-process cases alone are in
tests/closed_loop/test_user_failures.py).

- ``step()`` raises from t = 1 s on: one terminal line from the orchestrator, the traceback
  once in the robot's log, ``controller_errors`` as in one process, ``--check`` exits 3.
- A robot sends NaN in its payloads from t = 1 s on: the same reject counts and metrics as
  in one process, no barrier timeout (the fleet runs at its normal speed), no NaN reaches
  a controller.

The controller is a small user controller (``tests/faults/user_controller.py``)."""

from __future__ import annotations

import io
import json

import pytest

from copath.wire.keys import Keys
from copath.wire.messages import Stats
from orchestrator import api
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.mcap import read_log
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


def _assert_one_failure_line(err: str, log_hint: str, late_s: float = 0.0) -> None:
    """One line naming r2, its first failing step's time (up to ``late_s`` after FAIL_AT: a
    realtime robot steps on its own timer) and the exception."""
    lines = [ln for ln in err.splitlines() if "controller step failed" in ln]
    assert len(lines) == 1, err[-3000:]
    line = lines[0]
    assert "robot r2" in line and "ZeroDivisionError" in line
    t = float(line.split("failed at t=", 1)[1].split(" s", 1)[0])
    assert FAIL_AT - 1e-9 <= t <= FAIL_AT + late_s + 0.005, line
    assert log_hint in line
    assert "Traceback" not in err


def _closing(records) -> dict[str, dict]:
    return {r.proc: r.counters for _, _, r in records if isinstance(r, Stats)}


def _nan_heard(records, keys: Keys) -> int:
    return sum(int(r.data.get("heard_nan", 0)) for _, k, r in records
               if k.endswith("/telemetry") and k.startswith(keys.prefix))


@pytest.mark.fleet
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


@pytest.mark.fleet
def test_step_exception_and_nan_payload_in_a_realtime_fleet(tmp_path, procs):
    """The same misbehaviours under the realtime clock over Zenoh: one failure line, the
    traceback once, ``controller_errors`` equal to the failing steps in the log, ``--check``
    exits 3; NaN payloads refused by every receiver and never seen by a controller."""
    for name, r2, rc_want in (("crash", {"fail_after_s": FAIL_AT}, 3), ("nan", {"nan_after_s": FAIL_AT}, 0)):
        config = tmp_path / f"{name}.toml"
        config.write_text(scenario_text(4.0, **r2))
        out = tmp_path / name
        p = procs.start(["-m", "orchestrator", "run", str(config), "--out", str(out), "--check", "--no-plots", "-q",
                         "--clock", "realtime"])
        _, err = p.communicate(timeout=240)
        err = err.decode()
        assert p.returncode == rc_want, err[-3000:]
        m = json.loads((out / "metrics.json").read_text())
        assert m["ok"] is True and m["clock"] == "realtime"
        log = read_log(out / "run.mcap")
        keys = Keys(m["run_id"])
        if name == "crash":
            _assert_one_failure_line(err, str(out / "logs" / "r2.log"), late_s=0.2)  # two periods
            assert m["robots"]["r2"]["controller_errors"] == _failing_steps(log.records, keys, "r2") > 0
            assert m["fleet"]["controller_errors"] == m["robots"]["r2"]["controller_errors"]
            text = (out / "logs" / "r2.log").read_text()
            assert text.count("Traceback") == 1 and "controller step failed" in text
        else:
            assert "controller step failed" not in err
            assert m["robots"]["r1"]["messages_rejected"] > 0 and m["robots"]["r3"]["messages_rejected"] > 0
            assert _nan_heard(log.records, keys) == 0
