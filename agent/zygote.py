"""A pre-imported agent launcher: the imports once, then one forked process per robot.

An agent process spends most of its start-up importing numpy, the controllers, the wire
code and Zenoh (docs/journal/performance.md, realtime at 128 robots (P10)). The zygote does that once for a run: it imports
``agent.node``, reads the run's scenario and builds one controller of each type (which
imports what that controller imports lazily, e.g. CasADi), and then serves requests on its
standard input, one JSON line per robot::

    {"name": "r2", "argv": ["--robot", "r2", "--run-id", ...], "log": "DIR/logs/r2.log"}

For each it forks twice: the robot's process is started by a short-lived intermediate that
exits at once, so the robot is re-parented to the orchestrator (a child subreaper,
``PR_SET_CHILD_SUBREAPER``) and is its direct child, as with ``python -m agent``. The robot
then runs in its own session and process group, writes to its log, shows the command line
``python -m agent ARGV`` and runs exactly :func:`agent.node.main` with ``ARGV``. The zygote
answers each request with ``{"name": ..., "pid": ...}``.

No Zenoh session is ever opened in the zygote: a fork after ``zenoh.open`` hangs the child
(docs/journal/measurements.md); each robot opens its own after the fork.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import signal
import sys
import traceback

__all__ = ["main", "set_subreaper", "TITLE_ROOM"]

TITLE_ROOM = 4096
"""Bytes of command line the zygote reserves (a padding argument) so a robot can show its own."""


def set_subreaper() -> bool:
    """Make this process adopt its orphaned descendants (Linux ``PR_SET_CHILD_SUBREAPER``)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(36, 1, 0, 0, 0) == 0  # PR_SET_CHILD_SUBREAPER
    except (OSError, AttributeError):
        return False


def _set_cmdline(argv: list[str]) -> None:
    """Overwrite this process's command line (``/proc/self/cmdline``) in place, within the
    room the zygote's own arguments take."""
    try:
        with open("/proc/self/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        start, end = int(fields[45]), int(fields[46])  # arg_start, arg_end (fields 48, 49)
        room = end - start
        data = ("\0".join(argv) + "\0").encode()[: room - 1]
        ctypes.memmove(start, data + b"\0" * (room - len(data)), room)
    except (OSError, ValueError, IndexError):
        pass


def _become_agent(req: dict) -> None:
    """In the forked robot process: detach, redirect, retitle, run the agent. Never returns."""
    code = 1
    try:
        os.setsid()
        fd = os.open(req["log"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)
        os.close(null)
        for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGPIPE):
            signal.signal(sig, signal.SIG_DFL if sig != signal.SIGINT else signal.default_int_handler)
        sys.stdin = open(os.devnull)
        sys.stdout = os.fdopen(1, "w", buffering=1)
        sys.stderr = os.fdopen(2, "w", buffering=1)
        argv = list(req["argv"])
        _set_cmdline([sys.executable, "-m", "agent", *argv])
        sys.argv = ["agent", *argv]
        from . import node  # noqa: PLC0415  (imported in the zygote already)

        code = node.main(argv) or 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:
        traceback.print_exc()
        code = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def _spawn(req: dict) -> int:
    """Fork the robot through a short-lived intermediate; return the robot's pid."""
    r, w = os.pipe()
    mid = os.fork()
    if mid == 0:
        try:
            os.close(r)
            pid = os.fork()
            if pid == 0:
                os.close(w)
                _become_agent(req)
            os.write(w, str(pid).encode())
        finally:
            os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as fh:
        data = fh.read()
    os.waitpid(mid, 0)  # the robot is the subreaper's child from here on
    return int(data)


def _preload(config: str) -> None:
    """Import what the agents of this run import: the node, the scenario, one controller
    of each type (its lazy imports, and its solver into the cache)."""
    from copath.scenario import load_scenario  # noqa: PLC0415
    from copath.wire.keys import Keys  # noqa: PLC0415

    from . import node  # noqa: PLC0415
    from .runtime import RobotRuntime  # noqa: PLC0415

    scenario = load_scenario(config)
    node.PRELOADED[config] = scenario
    seen: set[str] = set()
    for robot in scenario.robots:
        if robot.controller not in seen:
            seen.add(robot.controller)
            try:
                RobotRuntime(scenario, robot.name, Keys("zygote"))
            except Exception:  # the robot's own process reports it
                pass


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m agent.zygote", description=__doc__.splitlines()[0])
    p.add_argument("--config", required=True, help="the run's scenario.json")
    p.add_argument("--title-room", default="", help="padding: room for the robots' command lines")
    args = p.parse_args(argv)
    _preload(args.config)
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        if not line.strip():
            continue
        req = json.loads(line)
        try:
            pid = _spawn(req)
            out = {"name": req["name"], "pid": pid}
        except OSError as exc:
            out = {"name": req["name"], "error": str(exc)}
        print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
