"""``RunOptions.fork_server``: agents forked by a pre-imported launcher (``agent/zygote.py``)
run exactly as ``python -m agent`` processes: same lockstep metrics, direct children of the
orchestrator with their own command line, a killed one fails the run clearly."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from orchestrator.api import load
from orchestrator.run.fleet import RunOptions, run_fleet
from tests.conftest import config

from orchestrator.testkit.processes import child_pids, cmdline

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(300)]


def _run(tmp_path, name: str, fork: bool, duration: float = 6.0, clock: str = "lockstep"):
    sc = load(config("e5.5-"), [f"run.duration_s={duration}", "run.settle_s=3", f'run.clock="{clock}"'])
    return run_fleet(sc, RunOptions(out_dir=tmp_path / name, run_id=name, progress=False, fork_server=fork))


def test_forked_agents_give_the_same_lockstep_run(tmp_path):
    forked = _run(tmp_path, "forked", True)
    plain = _run(tmp_path, "plain", False)
    assert forked.ok and plain.ok, (forked.reason, plain.reason)
    assert (tmp_path / "forked" / "logs" / "zygote.log").is_file()
    f, p = forked.metrics["fleet"], plain.metrics["fleet"]
    assert f["messages_published"] == f["messages_recorded"] == p["messages_published"]
    for key in ("coordination_error_max_m", "coordination_error_rms_m"):
        assert f[key] == pytest.approx(p[key], abs=1e-9), key


def test_a_forked_agent_is_a_direct_child_and_killing_it_fails_the_run(tmp_path):
    result: dict = {}
    me = os.getpid()
    t = threading.Thread(target=lambda: result.update(out=_run(tmp_path, "kill", True, 30.0, "realtime")), daemon=True)
    t.start()
    deadline = time.monotonic() + 60
    victim: list[int] = []
    while not victim and time.monotonic() < deadline:
        victim = [q for q in child_pids(me) if "agent" in cmdline(q) and "r2" in cmdline(q)]
        time.sleep(0.1)
    assert len(victim) == 1, [cmdline(q)[:6] for q in child_pids(me)]
    time.sleep(2.0)  # running
    os.kill(victim[0], signal.SIGKILL)
    t.join(timeout=120)
    out = result["out"]
    assert not out.ok and "robot r2" in out.reason and "SIGKILL" in out.reason, out.reason
    assert not [q for q in child_pids(me) if "agent" in cmdline(q)]  # nothing left behind
