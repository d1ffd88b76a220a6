"""Real processes over Zenoh on loopback: runs, logs, replay, faults, isolation, failures."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import pytest

from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint
from orchestrator.cli import main as copath
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.mcap import read_log
from orchestrator.log.replay import log_info
from tests.conftest import config

from orchestrator.testkit.processes import child_pids, cmdline

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(180)]


@pytest.fixture(scope="module")
def e55_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("e55")
    rc = copath(["run", str(config("e5.5-")), "--out", str(out), "--run-id", "e55-test", "-q"])
    return rc, out


def test_lockstep_run_converges_and_logs_every_message(e55_run):
    rc, out = e55_run
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["ok"] and m["clock"] == "lockstep" and m["run_id"] == "e55-test"
    assert m["fleet"]["coordination_error_max_m"] < 0.02
    assert all(r["path_error_max_m"] < 0.05 for r in m["robots"].values())
    assert all(r["missed_ticks"] == 0 for r in m["robots"].values())
    assert m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"] == 7802
    log = read_log(out / "run.mcap")
    assert log.rejected == 0
    keys = Keys("e55-test")
    assert all(k.startswith(keys.prefix + "/") for _, k, _ in log.records)
    # 600 ticks x 3 robots of obs, cmd, telemetry and peer messages; 600 truths
    assert log.counts[keys.truth] == 600
    assert all(log.counts[keys.cmd(n)] == 600 for n in ("r1", "r2", "r3"))


def test_distributed_lockstep_equals_in_process_run(e55_run):
    _, out = e55_run
    m = json.loads((out / "metrics.json").read_text())
    ref = run_scenario(load_scenario(config("e5.5-"))).metrics
    for key in ("coordination_error_max_m", "coordination_error_rms_m", "min_separation_m", "messages_published"):
        assert m["fleet"][key] == ref["fleet"][key], key
    for n in ref["robots"]:
        for key in ("path_error_max_m", "path_error_rms_m", "heading_error_max_rad", "speed_error_rms_mps"):
            assert m["robots"][n][key] == ref["robots"][n][key], (n, key)


def test_info_lists_channels_counts_robots_and_scenario(e55_run, capsys):
    _, out = e55_run
    assert copath(["info", str(out / "run.mcap")]) == 0
    text = capsys.readouterr().out
    assert "e55-test" in text and "r1, r2, r3" in text and "sim/truth" in text and "600 msgs" in text
    info = log_info(out / "run.mcap")
    assert info["scenario"]["id"] == "e5.5-column-lemniscate" and info["outcome"]["ok"] == "True"
    assert info["messages"] == 7806  # 7802 + one closing account per process


def test_replay_republishes_the_log_under_a_new_run_id(e55_run):
    _, out = e55_run
    endpoint = loopback_endpoint(free_port())
    keys = Keys("replayed")
    got = []
    done = threading.Event()

    def replay():
        copath(["replay", str(out / "run.mcap"), "--speed", "20", "--run-id", "replayed", "--connect", endpoint])
        done.set()

    # a viewer hosts the network; replay joins it as a client
    with ZenohLink.open(SessionConfig(mode="router", listen=(endpoint,))) as link:
        link.subscribe_raw(keys.all, lambda k, d: got.append(k))
        t = threading.Thread(target=replay, daemon=True)
        t.start()
        assert done.wait(timeout=60)
        time.sleep(0.3)
    assert len(got) == 7806
    assert all(k.startswith("copath/replayed/") for k in got)
    assert sum(k.endswith("/sim/truth") for k in got) == 600


def test_delay_and_loss_are_survived(tmp_path):
    rc = copath(["run", str(config("e5.5-")), "--out", str(tmp_path), "--delay", "100", "--loss", "0.2", "-q"])
    assert rc == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["fleet"]["messages_dropped_by_faults"] > 300
    assert m["fleet"]["coordination_error_max_m"] < 0.1
    assert m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"]


def test_two_runs_with_the_same_id_at_once_do_not_hear_each_other(tmp_path, procs):
    """Isolation holds even for identical run ids: separate routers, no multicast scouting."""
    outs = [tmp_path / "a", tmp_path / "b"]
    ps = [procs.start(["-m", "orchestrator", "run", str(config("e5.5-")), "--out", str(o), "--run-id", "same",
                       "--duration", "20", "--set", "run.settle_s=10", "-q"]) for o in outs]
    for p in ps:
        assert p.wait(timeout=150) == 0, p.stderr.read().decode()[-2000:]
    for o in outs:
        m = json.loads((o / "metrics.json").read_text())
        assert m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"] == 2602


def test_killing_an_agent_fails_the_run_clearly_and_leaves_a_readable_log(tmp_path, procs):
    p = procs.start(["-m", "orchestrator", "run", str(config("e5.4-")), "--out", str(tmp_path),
                     "--run-id", "kill-test", "--clock", "realtime", "--duration", "60"])
    err_lines: list[str] = []
    reader = threading.Thread(target=lambda: err_lines.extend(l.decode() for l in p.stderr), daemon=True)
    reader.start()
    deadline = time.monotonic() + 90
    while not any("10%" in l for l in err_lines):  # progress: 6 s of the run have passed
        assert time.monotonic() < deadline and p.poll() is None, "".join(err_lines)
        time.sleep(0.1)
    victim = [pid for pid in child_pids(p.pid) if "agent" in cmdline(pid) and "r2" in cmdline(pid)]
    assert len(victim) == 1
    os.kill(victim[0], signal.SIGKILL)
    rc = p.wait(timeout=60)
    reader.join(timeout=10)
    err = "".join(err_lines)
    assert rc == 1
    assert "FAILED" in err and "robot r2" in err and str(victim[0]) in err and "SIGKILL" in err
    assert not child_pids(p.pid)  # nothing left behind
    info = log_info(tmp_path / "run.mcap")
    assert info["outcome"]["ok"] == "False" and info["messages"] > 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["ok"] is False and "r2" in m["failure"]


def test_realtime_run_steps_agents_on_their_own_clock(tmp_path):
    rc = copath(["run", str(config("e5.5-")), "--out", str(tmp_path), "--clock", "realtime", "--duration", "8", "--set", "run.settle_s=4", "-q"])
    assert rc == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["clock"] == "realtime" and m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"]
    log = read_log(tmp_path / "run.mcap")
    cmds = [r for _, k, r in log.records if k.endswith("/robot/r1/cmd")]
    assert 70 <= len(cmds) <= 82  # 10 Hz for 8 s, on its own timer
    # the robots make progress and stay near their paths
    tel = [r.data for _, k, r in log.records if k.endswith("/robot/r1/telemetry")]
    assert tel[-1]["s"] - tel[0]["s"] > 1.0


def test_bad_input_is_refused_with_a_clear_message(tmp_path, capsys):
    assert copath(["run", str(tmp_path / "missing.toml")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert copath(["run", str(config("e5.5-")), "--loss", "1.5", "--out", str(tmp_path)]) == 2
    assert "network.loss = 1.5 is not allowed" in capsys.readouterr().err
    assert copath(["agent", "--run-id", "x", "--robot", "r9", "--config", str(config("e5.5-")),
                   "--connect", "tcp/127.0.0.1:1"]) == 2
    assert "robot = 'r9' is not in the scenario" in capsys.readouterr().err
    assert copath(["info", str(tmp_path / "nope.mcap")]) == 2
