"""Processes a test or a study starts: each in a session of its own, tracked and killed by
pid (never by name), with every process below it. Linux ``/proc`` only."""

from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

REPO = pathlib.Path(__file__).resolve().parents[2]
"""The checkout the programs are started from (their working directory and ``PYTHONPATH``)."""


def child_env() -> dict[str, str]:
    """The environment of a started program: this one, with the checkout first on ``PYTHONPATH``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


class Procs:
    """The Python programs started through :meth:`start` (or appended to ``started``);
    :meth:`cleanup` stops them all and everything they started."""

    def __init__(self) -> None:
        self.started: list[subprocess.Popen] = []

    def start(self, argv: list[str], **kw) -> subprocess.Popen:
        """``python argv...`` in its own session, from the checkout, output to pipes."""
        p = subprocess.Popen([sys.executable, *argv], start_new_session=True, cwd=str(REPO), env=child_env(),
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
            signal_group(p.pid, signal.SIGTERM)
        for p in running:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                signal_group(p.pid, signal.SIGKILL)
                p.wait(timeout=10)
        for pid, argv in family.items():
            if cmdline(pid) == argv:  # still that process (a pid is not reused for another one)
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass


def signal_group(pid: int, sig: int) -> None:
    """Send ``sig`` to the process group led by ``pid``; a group already gone is no error."""
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
    """The argv of ``pid`` (empty once it is gone)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().decode().split("\0")
    except OSError:
        return []


def victim(p: subprocess.Popen, out: pathlib.Path, name: str = "r3", under_way_bytes: int = 300_000) -> int:
    """The pid of robot ``name``'s process under the orchestrator ``p`` writing to ``out``,
    once the run is under way (its ``run.mcap`` holds ``under_way_bytes``)."""
    mcap = out / "run.mcap"
    deadline = time.monotonic() + 150
    while not (mcap.is_file() and mcap.stat().st_size > under_way_bytes):  # the run is under way
        assert p.poll() is None and time.monotonic() < deadline, p.stderr.read().decode()[-2000:]
        time.sleep(0.05)
    pids = [pid for pid in child_pids(p.pid) if "agent" in cmdline(pid) and name in cmdline(pid)]
    assert len(pids) == 1
    return pids[0]


def killed_mid_run(p: subprocess.Popen, out: pathlib.Path, name: str, under_way_bytes: int,
                   timeout: float = 300.0) -> tuple[dict, list, list[float]]:
    """Kill robot ``name``'s process (SIGKILL, :func:`victim`) once the run ``p`` writing to ``out``
    is under way, wait for the run to end (exit 0 asserted) and return its ``metrics.json``, its
    log's records and the times of the simulator's ``robot_lost`` events of ``name``."""
    from orchestrator.log.mcap import read_log  # noqa: PLC0415

    os.kill(victim(p, out, name, under_way_bytes), signal.SIGKILL)
    assert p.wait(timeout=timeout) == 0, p.stderr.read().decode()[-3000:]
    records = read_log(out / "run.mcap").records
    lost = [float(r.t) for _, _, r in records
            if getattr(r, "TYPE", "") == "event" and r.what == "robot_lost" and r.detail.get("robot") == name]
    return json.loads((out / "metrics.json").read_text()), records, lost


def unfreeze(pid: int, sig: int) -> None:
    """After a fault ``sig`` sent to ``pid``: a frozen (SIGSTOP) process is killed, so nothing
    of the test outlives it."""
    if sig == signal.SIGSTOP:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
