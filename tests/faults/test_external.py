"""``copath run CONFIG --external r2``: the run prints the exact command for r2 and waits
for it; r2 started by hand gives the same messages as a normal lockstep run."""

from __future__ import annotations

import shlex
import threading
import time

import pytest

from orchestrator.cli import main as copath
from tests.conftest import config

from .test_determinism import _payloads

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(300)]


def test_an_external_robot_joins_and_the_run_is_the_same(tmp_path, procs, capsys):
    args = [str(config("e5.5-")), "--run-id", "ext", "--duration", "40", "-q", "--no-plots"]
    p = procs.start(["-m", "orchestrator", "run", *args, "--out", str(tmp_path / "ext"), "--external", "r2"])
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(l.decode() for l in p.stderr), daemon=True)
    reader.start()
    deadline = time.monotonic() + 120
    while not any(l.strip().startswith("copath agent") for l in lines):
        assert p.poll() is None and time.monotonic() < deadline, "".join(lines)
        time.sleep(0.05)
    cmd = shlex.split(next(l for l in lines if l.strip().startswith("copath agent")))
    assert cmd[:2] == ["copath", "agent"] and "--robot" in cmd and cmd[cmd.index("--robot") + 1] == "r2"
    assert "--connect" in cmd and cmd[cmd.index("--run-id") + 1] == "ext"
    time.sleep(1.0)  # the run really waits: nothing has ticked without r2
    assert p.poll() is None
    r2 = procs.start(["-m", "orchestrator", *cmd[1:]])
    assert r2.wait(timeout=200) == 0, r2.stderr.read().decode()[-2000:]
    assert p.wait(timeout=60) == 0, "".join(lines)[-3000:]
    reader.join(timeout=5)
    assert copath(["run", *args, "--out", str(tmp_path / "normal")]) == 0
    a, b = (_payloads(tmp_path / d / "run.mcap", "ext") for d in ("ext", "normal"))
    assert set(a) == set(b)
    for key in a:
        assert a[key] == b[key], key
