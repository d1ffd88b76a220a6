"""A remote host's router dies mid-run. The run's router (host A, in the orchestrator's
process) connects to host B's router (``copath run --connect``); r2 and r3 run on host B
behind it. When B's router is killed (SIGKILL), the robots behind it disappear: their
liveliness tokens go with the link. Under ``run.on_robot_failure = "fail"`` the run ends
with a reason naming both and a finalised, readable MCAP, once their tokens stayed away
for ``run.liveliness_grace_s``; under ``continue`` r1 goes on at once. Detection is
measured from the kill to the simulator's record of the loss."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

from copath.scenario import load_scenario
from orchestrator.log.mcap import read_log
from tests.conftest import config

from .hosts import ADDR_A, ADDR_B, endpoint, popen, start_router, stop_all, two_hosts, wait_for_file, why_not

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(300)]

REMOTE = ("r2", "r3")


def kill_remote_router(tmp_path, procs, hosts, policy: str, run_id: str = "router", duration_s: float = 60.0) -> dict:
    """E5.5 with r1 on host A and r2, r3 on host B; B's router is killed once the run is under
    way. Returns the orchestrator's exit code and stderr, metrics.json, the read-back log and
    the detection time (kill to the simulator's ``robot_lost`` event or, under ``fail``, its
    ``End``) in seconds."""
    router_b = start_router(hosts, hosts.b, endpoint(ADDR_B))
    procs.started.append(router_b)
    run = popen(hosts, hosts.a, ["-m", "orchestrator", "run", str(config("e5.5-")), "--out", str(tmp_path),
                                 "--run-id", run_id, "--duration", str(duration_s), "--listen", endpoint(ADDR_A),
                                 "--connect", endpoint(ADDR_B), *[a for n in REMOTE for a in ("--external", n)],
                                 "--on-robot-failure", policy, "-q", "--no-plots", "--no-secure"])  # a site router logs in as nobody (README)
    procs.started.append(run)
    wait_for_file(tmp_path / "scenario.json", run)
    for n in REMOTE:
        procs.started.append(popen(hosts, hosts.b, ["-m", "agent", "--run-id", run_id, "--robot", n, "--config",
                                                    str(tmp_path / "scenario.json"), "--connect", endpoint(ADDR_B)]))
    mcap = tmp_path / "run.mcap"
    deadline = time.monotonic() + 150
    while not (mcap.is_file() and mcap.stat().st_size > 200_000):  # the run is under way
        assert run.poll() is None and time.monotonic() < deadline, run.stderr.read().decode()[-2000:]
        time.sleep(0.05)
    t_kill = time.time_ns()
    os.kill(router_b.pid, signal.SIGKILL)
    rc = run.wait(timeout=240)
    stderr = run.stderr.read().decode()
    log = read_log(mcap)
    if policy == "fail":
        marks = [t for t, _, r in log.records if getattr(r, "TYPE", "") == "end"]
    else:
        marks = [t for t, _, r in log.records if getattr(r, "TYPE", "") == "event" and r.what == "robot_lost"]
    detection = [(t - t_kill) / 1e9 for t in marks]
    return {"rc": rc, "stderr": stderr, "metrics": json.loads((tmp_path / "metrics.json").read_text()), "log": log,
            "detection_s": max(detection) if detection else None}


@pytest.mark.parametrize("policy", ["fail", pytest.param("continue", marks=pytest.mark.slow)])
def test_a_remote_router_dies_and_its_robots_are_lost(tmp_path, procs, policy):
    why = why_not()
    if why:
        pytest.skip(why)
    with two_hosts(pytest.skip) as hosts:
        try:
            res = kill_remote_router(tmp_path, procs, hosts, policy)
        finally:
            stop_all(procs)  # before the namespaces go
    m, log = res["metrics"], res["log"]
    # continue: held still at once; fail: lost once the token stayed away for the grace
    grace = load_scenario(tmp_path / "scenario.json").run.liveliness_grace_s if policy == "fail" else 0.0
    assert res["detection_s"] is not None and grace <= res["detection_s"] < grace + 2.0, res["detection_s"]
    assert not log.cut_short and "outcome" in log.metadata  # the MCAP was finalised
    if policy == "fail":
        assert res["rc"] != 0 and not m["ok"]
        for n in REMOTE:  # the reason names every robot behind the dead router
            assert n in m["failure"], m["failure"]
            assert n in res["stderr"]
        assert log.metadata["outcome"]["ok"] == "False"
    else:
        assert res["rc"] == 0, res["stderr"][-3000:]
        assert m["ok"]
        lost = sorted(r.detail["robot"] for _, _, r in log.records
                      if getattr(r, "TYPE", "") == "event" and r.what == "robot_lost")
        assert lost == list(REMOTE)
        assert m["robots"]["r1"]["outage_s"] == 0 and m["robots"]["r1"]["path_error_max_m"] < 0.2
        for n in REMOTE:
            assert m["robots"][n]["outage_s"] > 5
