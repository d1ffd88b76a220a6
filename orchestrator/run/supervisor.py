"""The processes of a fleet run: spawning the simulator and one process per robot,
watching them, the policy on a robot's failure (``run.on_robot_failure``: fail, continue,
restart), restarts and their rejoin bound, and stopping them all.

Each child runs in a process group of its own, its output in ``DIR/logs/``. Robots are
forked from a pre-imported launcher (``agent/zygote.py``; docs/journal/performance.md,
realtime at 128 robots (P10)) unless that is turned off; a restart is a fresh process, as a robot rebooting would
be (docs/reference/faults.md)."""

from __future__ import annotations

import json
import logging
import os
import pathlib
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable

from agent.controllers import import_path_dirs, task_queues
from copath.occupancy import queues_to_json
from copath.scenario import Scenario
from copath.wire.keys import Keys
from copath.wire.messages import Event

from orchestrator.log.writer import Recorder
from orchestrator.run.progress import Progress

logger = logging.getLogger(__name__)

__all__ = ["Supervisor", "Child", "Zygote", "spawn", "stop_children", "describe_exit", "REPO_ROOT", "REJOIN_TIMEOUT_S"]

REPO_ROOT = pathlib.Path(__file__).resolve().parents[2]

REJOIN_TIMEOUT_S = 20.0
"""Default bound [s] from a restarted robot's process start to its first command (measured:
about 1-2 s when forked from the zygote on a loaded 2-core machine; docs/reference/faults.md)."""


@dataclass
class Child:
    """A process of the run: its name (``sim`` or a robot's), the process and its log file."""

    name: str
    proc: subprocess.Popen
    log: Any


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    # the scenario's directory and the start directory: import-path controllers resolve alike in every child
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), *import_path_dirs(), env.get("PYTHONPATH", "")) if p)
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def spawn(name: str, argv: list[str], log_path: pathlib.Path, cwd: pathlib.Path) -> Child:
    """Start ``argv`` in a session of its own, its output to ``log_path``."""
    log = log_path.open("wb")
    proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            start_new_session=True, env=_child_env(), cwd=str(cwd))
    return Child(name, proc, log)


class _ForkedProc:
    """The part of ``subprocess.Popen`` the orchestrator uses, for a robot forked by the
    zygote and re-parented to this process (a child subreaper)."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # not ours (no subreaper): gone when /proc forgets it
                if not os.path.exists(f"/proc/{self.pid}"):
                    self.returncode = -signal.SIGKILL
                return self.returncode
            if pid == self.pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(f"agent pid {self.pid}", timeout)
            time.sleep(0.01)
        return self.returncode


class Zygote:
    """``python -m agent.zygote``: imports once, forks one process per robot (realtime at 128 robots, P10)."""

    def __init__(self, scen_path: pathlib.Path, cwd: pathlib.Path) -> None:
        from agent.zygote import TITLE_ROOM, set_subreaper  # noqa: PLC0415

        self.subreaper = set_subreaper()
        self.log = (cwd / "zygote.log").open("wb")
        self.proc = subprocess.Popen([sys.executable, "-m", "agent.zygote", "--config", str(scen_path.resolve()),
                                      "--title-room=" + "x" * TITLE_ROOM], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.log, start_new_session=True, env=_child_env(), cwd=str(cwd))

    def spawn(self, name: str, argv: list[str], log_path: pathlib.Path) -> Child | None:
        """The robot's process, or None when the zygote cannot (the caller spawns it itself)."""
        if not self.subreaper or self.proc.poll() is not None:
            return None
        try:
            req = {"name": name, "argv": argv, "log": str(pathlib.Path(log_path).resolve())}  # it runs in DIR/logs
            self.proc.stdin.write((json.dumps(req) + "\n").encode())
            self.proc.stdin.flush()
            while True:
                line = self.proc.stdout.readline()
                if not line:
                    return None
                reply = json.loads(line)
                if reply.get("name") == name:
                    break
        except (OSError, ValueError):
            return None
        if "pid" not in reply:
            logger.warning("the zygote could not start robot %s: %s", name, reply.get("error"))
            return None
        return Child(name, _ForkedProc(int(reply["pid"])), open(os.devnull, "wb"))

    def close(self) -> None:
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=3)
        except (OSError, subprocess.TimeoutExpired):
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait(timeout=5)
        self.log.close()


def stop_children(children: list[Child], grace_s: float = 3.0) -> None:
    """Terminate every child's process group; escalate to SIGKILL after ``grace_s``."""
    for c in children:
        if c.proc.poll() is None:
            try:
                os.killpg(c.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + grace_s
    for c in children:
        try:
            c.proc.wait(timeout=max(0.05, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            try:
                os.killpg(c.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            c.proc.wait(timeout=5)
    for c in children:
        try:
            os.killpg(c.proc.pid, signal.SIGKILL)  # stragglers in the group
        except (ProcessLookupError, PermissionError):
            pass
        c.log.close()


def describe_exit(rc: int) -> str:
    """``rc`` of a child as words: its exit code, or the signal that killed it."""
    if rc < 0:
        try:
            return f"was killed by {signal.Signals(-rc).name}"
        except ValueError:
            return f"was killed by signal {-rc}"
    return f"exited with code {rc}"


class Supervisor:
    """Starts, watches, restarts and stops the run's processes; ``children[0]`` is the simulator.

    It reads the run's progress from the log (``log``: the simulator's time and end record,
    each robot's latest command) and its robots' liveliness (:meth:`on_alive`, fed by the
    router's liveliness watch)."""

    def __init__(self, scenario: Scenario, keys: Keys, out: pathlib.Path, scen_path: pathlib.Path,
                 common: list[str], auth: Callable[[str], list[str]], log: Recorder, progress: Progress, *,
                 run_id: str, listen: tuple[str, ...], external: tuple[str, ...] = (), fork_server: bool = True,
                 max_restarts: int = 3, rejoin_timeout_s: float = REJOIN_TIMEOUT_S,
                 start_timeout_s: float = 120.0) -> None:
        self.scenario, self.keys, self.out, self.scen_path = scenario, keys, pathlib.Path(out), scen_path
        self.common, self.auth, self.log, self.progress = common, auth, log, progress
        self.run_id, self.listen, self.external = run_id, listen, tuple(external)
        self.policy = scenario.run.on_robot_failure
        self.max_restarts, self.rejoin_timeout_s, self.start_timeout_s = max_restarts, rejoin_timeout_s, start_timeout_s
        self.children: list[Child] = []
        self.ready: set[str] = set()
        """Robots whose controller is built: their liveliness token is up."""
        self.token_at: dict[str, float] = {}
        """When each robot's token last appeared (monotonic [s])."""
        self.spawned_at: dict[str, float] = {}
        self.restarts = {n: 0 for n in scenario.robot_names}
        self.gone: set[str] = set()
        """Robots lost under ``continue`` (or never back after a restart)."""
        self.rejoining: dict[str, int] = {}
        """Restarted robots not commanding yet: their spawn time [ns]."""
        self.never_back: list[str] = []
        """Restarted robots that missed the rejoin bound, or ran out of restarts."""
        self.fork_server = fork_server
        self._zygote: Zygote | None = None

    # -- liveliness -------------------------------------------------------------------------
    def on_alive(self, key: str, alive: bool) -> None:
        """A robot's liveliness token appeared (``alive``) or went."""
        name = key.rsplit("/", 1)[-1]
        if name in self.scenario.robot_names:
            (self.ready.add if alive else self.ready.discard)(name)
            if alive:
                self.token_at[name] = time.monotonic()
            self.progress.starting = (f"starting: {len(self.ready)}/{len(self.scenario.robots)} robots ready "
                                      "(the others build their controllers; solvers compile)")

    # -- spawning ---------------------------------------------------------------------------
    def _io(self, name: str) -> list[str]:  # a robot whose agent drives it over ROS 2 itself (docs/reference/ros2.md)
        world = self.scenario.world
        return ["--io", "ros2"] if world.ros2 and world.robots[name].commands == "agent" else []

    def _agent(self, name: str) -> Child:
        self.spawned_at[name] = time.monotonic()
        restarts = self.restarts[name]
        log = self.out / "logs" / (f"{name}.log" if not restarts else f"{name}.restart{restarts}.log")
        argv = ["--robot", name, *self.common, *self.auth(name), *self._io(name)]
        # a restart (run.on_robot_failure = "restart") is a fresh process, as a robot rebooting
        # would be: forked from the zygote it is one too (new session, new controller), without
        # paying the imports again, which took 1.4-1.7 s of a restart under load (docs/reference/faults.md)
        child = self._zygote.spawn(name, argv, log) if self._zygote is not None else None
        child = child or spawn(name, [sys.executable, "-m", "agent", *argv], log, self.out / "logs")
        if restarts:  # the bound's start first: a command noted after it can only be later
            self.rejoining[name] = time.time_ns()
            self.log.expect_commands(name)
        return child

    def start(self) -> None:
        """Start the simulator (the ROS 2 bridge for a ROS 2 world) and every robot not
        ``external``; print the command that starts each external one."""
        if self.fork_server:
            self._zygote = Zygote(self.scen_path, self.out / "logs")
        world = "sim.ros2_bridge" if self.scenario.world.ros2 else "sim"  # ROS 2 robots: the bridge (docs/reference/ros2.md)
        # the robots' task queues, as their families declare them: the simulator loads no
        # controller code to ask (run.until = "tasks_done")
        tasks = ["--tasks", queues_to_json(task_queues(self.scenario))]
        self.children.append(spawn("sim", [sys.executable, "-m", world, *self.common, *self.auth("sim"),
                                           "--start-timeout", str(self.start_timeout_s), *tasks],
                                   self.out / "logs" / "sim.log", self.out / "logs"))
        for name in self.scenario.robot_names:
            if name in self.external:
                continue
            self.children.append(self._agent(name))
        for name in self.external:  # the user starts these: the exact command, then the wait
            cmd = ["copath", "agent", "--run-id", self.run_id, "--robot", name, "--config",
                   str(self.scen_path.resolve()), *[a for e in self.listen for a in ("--connect", e)],
                   *self.auth(name), *self._io(name)]
            print(f"copath run: start robot {name} yourself (the run waits for it):\n  {' '.join(cmd)}",
                  file=sys.stderr, flush=True)

    # -- restarts ---------------------------------------------------------------------------
    def _check_rejoins(self) -> None:
        """A restarted robot commands again within ``rejoin_timeout_s`` of its process
        start, or it is lost: event, terminal line, process stopped (docs/reference/faults.md)."""
        for name, t_ns in list(self.rejoining.items()):
            # the first command's receive time, not the time of this look: a restart that
            # commands after the bound is late however soon the supervisor looks
            first = self.log.first_cmd_ns.get(name, 0)  # noted from t_ns on (_agent), 0 until one came
            came = first > 0
            waited = ((first if came else time.time_ns()) - t_ns) / 1e9
            if came and waited <= self.rejoin_timeout_s:
                del self.rejoining[name]
                logger.info("robot %s commands again %.2f s after its restart", name, waited)
                continue
            if not came and waited < self.rejoin_timeout_s:
                continue
            del self.rejoining[name]
            self.never_back.append(name)
            self.gone.add(name)
            log_file = self.out / "logs" / f"{name}.restart{self.restarts[name]}.log"
            late = f"; its first came {waited:.2f} s after" if came else ""
            msg = (f"robot {name} sent no command within {self.rejoin_timeout_s:g} s of its restart "
                   f"(the bound{late}); it is lost, see {log_file}")
            print(f"copath run: {msg}", file=sys.stderr, flush=True)
            logger.error(msg)
            self.log.write(self.keys.event("orchestrator"), Event(float(self.log.sim_t), "orchestrator", "rejoin_timeout", {
                "robot": name, "waited_s": round(waited, 3), "bound_s": self.rejoin_timeout_s}).pack())
            for c in list(self.children[1:]):
                if c.name == name:
                    self.children.remove(c)
                    stop_children([c])

    def _kill_frozen(self) -> None:
        """Frozen robots (token expired, process still there) are killed, to be restarted."""
        for c in self.children[1:]:
            if (c.proc.poll() is None and c.name not in self.ready
                    and self.token_at.get(c.name, 0.0) > self.spawned_at.get(c.name, float("inf"))):
                logger.warning("robot %s (pid %d) lost its liveliness; killing it to restart it", c.name, c.proc.pid)
                try:
                    os.killpg(c.proc.pid, signal.SIGKILL)
                    c.proc.wait(timeout=5)
                except (ProcessLookupError, subprocess.TimeoutExpired):
                    pass

    def _apply_policy(self, failed: list[Child]) -> None:
        """``run.on_robot_failure`` continue or restart: the simulator holds the robot still and goes on."""
        for c in failed:
            logger.warning("robot %s (pid %d) %s at sim t=%.2f s; policy %s", c.name, c.proc.pid,
                           describe_exit(c.proc.returncode), self.log.sim_t, self.policy)
            self.children.remove(c)
            c.log.close()
            if self.policy == "restart" and self.restarts[c.name] < self.max_restarts:
                self.restarts[c.name] += 1
                self.children.append(self._agent(c.name))
            else:
                if self.policy == "restart":
                    self.never_back.append(c.name)
                    print(f"copath run: robot {c.name} is lost: {self.max_restarts} restarts used",
                          file=sys.stderr, flush=True)
                self.gone.add(c.name)
                self.rejoining.pop(c.name, None)

    # -- watching ---------------------------------------------------------------------------
    def watch(self, wall0: float, wall_limit: float) -> tuple[bool, str]:
        """Watch the run until it ends: (ok, reason). A robot that dies fails the run under
        ``fail``; the simulator's end (or death) ends it; so does the wall-clock limit."""
        rec, out = self.log, self.out
        while True:
            self.progress.update(rec.sim_t, rec.count)
            rc_sim = self.children[0].proc.poll()
            failed = [c for c in self.children[1:] if c.proc.poll() is not None
                      and (c.proc.returncode != 0 or rc_sim is None and rec.end is None)]
            if self.policy == "restart" and rc_sim is None and rec.end is None:
                self._check_rejoins()
                self._kill_frozen()
                failed = [c for c in self.children[1:] if c.proc.poll() is not None
                          and (c.proc.returncode != 0 or rec.end is None)]
            if failed and rc_sim is None and rec.end is None and self.policy != "fail":
                self._apply_policy(failed)
                failed = []
            if failed:
                c = failed[0]
                return False, (f"robot {c.name} (pid {c.proc.pid}) {describe_exit(c.proc.returncode)} "
                               f"at sim t={rec.sim_t:.2f} s; see {out / 'logs' / (c.name + '.log')}")
            if rc_sim is not None:
                return self._at_end(rc_sim)
            if time.monotonic() - wall0 > wall_limit:
                return False, f"wall-clock limit of {wall_limit:.0f} s reached at sim t={rec.sim_t:.2f} s"
            time.sleep(0.05)

    def _at_end(self, rc_sim: int) -> tuple[bool, str]:
        """The simulator exited: its end record says how the run went; then the robots send
        their closing accounts and exit."""
        rec, out, scenario = self.log, self.out, self.scenario
        deadline = time.monotonic() + 10.0
        while rc_sim == 0 and rec.end is None and time.monotonic() < deadline:
            time.sleep(0.05)  # its end record is still on its way through a busy router
        end = rec.end
        if rc_sim != 0 or end is None or not end.ok:
            why = end.reason if end is not None else f"the simulator {describe_exit(rc_sim)}"
            silent = [n for n in scenario.robot_names if n in self.token_at and n not in self.ready and n not in self.gone]
            if silent and end is not None:  # every robot whose token is gone, not only the first
                why += (f"; no liveliness token from {', '.join(silent)} (a process stopped, or its "
                        "host or router lost the link to this run's router)")
            return False, f"{why} at sim t={rec.sim_t:.2f} s; see {out / 'logs' / 'sim.log'}"
        # normal end: wait for the robots to send their closing accounts and exit
        ended = time.monotonic()
        deadline = ended + 30.0
        # a restarted robot that came up after the simulator ended waits for a start that
        # will not come: it gets 5 s, like the others, to show it had rejoined by exiting
        late = ended + 5.0
        while time.monotonic() < deadline and any(
                c.proc.poll() is None and (self.policy == "fail" or c.name not in scenario.robot_names
                                           or c.name in self.ready)  # a frozen robot will not exit
                and not (self.restarts.get(c.name) and time.monotonic() > late)
                for c in self.children):
            time.sleep(0.05)
        too_late = [c for c in self.children if self.restarts.get(c.name) and c.proc.poll() is None]
        for c in too_late:
            logger.warning("robot %s was restarted too late to rejoin before the end; stopping it", c.name)
        stop_children(too_late)
        self.gone.update(c.name for c in too_late)  # never rejoined: no closing account to wait for
        stuck = [c.name for c in self.children if c.proc.poll() is None]
        if self.policy != "fail":  # frozen robots the run went on without
            self.gone.update(n for n in stuck if n in scenario.robot_names and n not in self.ready)
            self.gone.update(n for n in self.external if n not in self.ready)  # cut off, or stopped by hand
            stuck = [n for n in stuck if n not in self.gone]
        bad = [c for c in self.children[1:] if c.proc.poll() is not None and c.proc.returncode != 0
               and c not in too_late]
        if stuck:
            return False, f"processes {stuck} did not exit after the end of the run"
        if bad:
            return False, f"robot {bad[0].name} {describe_exit(bad[0].proc.returncode)} at the end of the run"
        return True, "completed"

    # -- stopping ---------------------------------------------------------------------------
    def stop_world(self) -> None:
        """A failed ROS 2 run: the bridge stops every robot now (docs/reference/ros2.md)."""
        if self.scenario.world.ros2 and self.children and self.children[0].proc.poll() is None:
            os.killpg(self.children[0].proc.pid, signal.SIGTERM)

    def stop(self) -> dict[str, int]:
        """Stop every process of the run (and the zygote); returns their pids by name."""
        pids = {c.name: c.proc.pid for c in self.children}
        stop_children(self.children)
        if self._zygote is not None:
            self._zygote.close()
        return pids
