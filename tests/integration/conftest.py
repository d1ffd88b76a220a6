"""Multi-process tests: every process a test starts is tracked and killed by pid."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from tests.conftest import REPO


class Procs:
    def __init__(self) -> None:
        self.started: list[subprocess.Popen] = []

    def start(self, argv: list[str], **kw) -> subprocess.Popen:
        env = dict(os.environ)
        env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
        p = subprocess.Popen([sys.executable, *argv], start_new_session=True, cwd=str(REPO), env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)
        self.started.append(p)
        return p

    def cleanup(self) -> None:
        """Stop every process started here and every process they started, by pid.

        SIGTERM first, so an orchestrator ends its run and stops its children itself; then
        SIGKILL for whatever is left, the children included (each robot and the simulator
        run in a session of their own, so killing the orchestrator's group misses them)."""
        running = [p for p in self.started if p.poll() is None]
        family = {pid: cmdline(pid) for p in running for pid in descendants(p.pid)}
        for p in running:
            _signal_group(p.pid, signal.SIGTERM)
        for p in running:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                _signal_group(p.pid, signal.SIGKILL)
                p.wait(timeout=10)
        for pid, argv in family.items():
            if cmdline(pid) == argv:  # still that process (a pid is not reused for another one)
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass


def _signal_group(pid: int, sig: int) -> None:
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (children, their children, ...), from /proc."""
    out, todo = [], [pid]
    while todo:
        kids = child_pids(todo.pop())
        out += kids
        todo += kids
    return out


@pytest.fixture
def procs():
    ps = Procs()
    yield ps
    ps.cleanup()


def child_pids(parent_pid: int) -> list[int]:
    """Direct children of a pid (from /proc), for fault injection by pid."""
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
                if int(fields[1]) == parent_pid:
                    out.append(int(d))
            except (OSError, IndexError, ValueError):
                continue
    return out


def cmdline(pid: int) -> list[str]:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().decode().split("\0")
    except OSError:
        return []
