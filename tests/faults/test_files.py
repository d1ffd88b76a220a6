"""copath info / metrics / plot / replay on files that are not good run logs: one clear
line and exit code 2; a log cut short (recorder killed) is read up to its last complete chunk."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest
from mcap.writer import Writer

from orchestrator.cli import main as copath
from orchestrator.log.mcap import read_log
from orchestrator.log.replay import log_info
from tests.conftest import config
from tests.faults.conftest import E55_LOG_RUN_ID
from orchestrator.testkit.processes import child_pids

COMMANDS = ("info", "metrics", "plot", "replay")


@pytest.fixture
def good_log(e55_log):
    return e55_log


def _bad_files(tmp_path, good):
    data = good.read_bytes()
    files = {
        "empty": b"",
        "text": b"time,x,y\n0,1,2\n",
        "garbage": os.urandom(4096),
        "magic only": data[:8],
        "first bytes": data[:100],
    }
    out = {}
    for name, content in files.items():
        p = tmp_path / f"{name.replace(' ', '_')}.mcap"
        p.write_bytes(content)
        out[name] = p
    foreign = tmp_path / "foreign.mcap"
    with foreign.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="someone else")
        sid = w.register_schema("s", "jsonschema", b"{}")
        ch = w.register_channel("/chatter", "json", sid)
        w.add_message(ch, log_time=1, data=b'{"a": 1}', publish_time=1)
        w.finish()
    out["foreign"] = foreign
    return out


@pytest.mark.parametrize("command", COMMANDS)
def test_bad_files_give_one_line_and_exit_2(command, tmp_path, good_log, capsys):
    for what, path in _bad_files(tmp_path, good_log).items():
        capsys.readouterr()
        argv = [command, str(path)] + (["--out", str(tmp_path / "plots")] if command == "plot" else [])
        assert copath(argv) == 2, (command, what)
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"copath {command}: ") and str(path) in err[0], (what, err)
        assert "Traceback" not in err[0]


def test_a_truncated_log_is_read_up_to_its_last_complete_chunk(tmp_path, good_log):
    full = read_log(good_log)
    data = good_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    log = read_log(cut)
    assert log.cut_short and not full.cut_short
    assert 0 < len(log.records) < len(full.records)
    # what was read is the start of the full log, in the same order
    assert [(k, r) for _, k, r in log.records] == [(k, r) for _, k, r in full.records[: len(log.records)]]
    assert log.metadata["outcome"]["ok"] == "False" and "cut short" in log.metadata["outcome"]["reason"]
    info = log_info(cut)
    assert info["cut_short"] and info["messages"] == len(log.records) and info["run_id"] == E55_LOG_RUN_ID
    assert copath(["metrics", str(cut), "--out", str(tmp_path / "m.json")]) == 0
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["ok"] is False and "cut short" in m["failure"]


@pytest.mark.fleet
@pytest.mark.timeout(240)
def test_a_log_whose_orchestrator_was_killed_is_reported_as_cut_short(tmp_path, procs, capsys):
    p = procs.start(["-m", "orchestrator", "run", str(config("e5.5-")), "--out", str(tmp_path), "--run-id", "killed",
                     "--duration", "600", "-q", "--no-plots"])
    mcap = tmp_path / "run.mcap"
    deadline = time.monotonic() + 180
    while not (mcap.is_file() and mcap.stat().st_size > 600_000):
        assert p.poll() is None and time.monotonic() < deadline, p.stderr.read().decode()[-2000:]
        time.sleep(0.1)
    children = child_pids(p.pid)
    os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=10)
    for pid in children:  # the fleet runs in process groups of its own
        try:
            os.killpg(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    capsys.readouterr()
    assert copath(["info", str(mcap)]) == 0
    out = capsys.readouterr().out
    assert "cut short" in out and "killed" in out
    log = read_log(mcap)
    assert log.cut_short and len(log.records) > 1000
    assert log.metadata["copath"]["run_id"] == "killed"
