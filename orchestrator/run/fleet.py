"""Spawn a run: the router (in this process), the recorder, the simulator and one process per robot.

Lifecycle of ``copath run``:

1. validate the scenario with the CLI overrides and write it to ``DIR/scenario.json``
   (the exact scenario every process loads);
2. open the run's Zenoh router on a free loopback port (multicast scouting off) and
   subscribe the recorder to ``copath/<run_id>/**`` before anything is started;
3. start ``python -m sim`` and ``python -m agent`` per robot, each in its own process
   group, logs in ``DIR/logs/``;
4. watch: progress from the recorded truth; a child that dies before the end fails
   the run with a one-line reason; Ctrl-C and the wall-clock limit too;
5. tear down every child by process group (SIGTERM, then SIGKILL), finish the MCAP,
   read it back and compute ``metrics.json`` from it.
"""

from __future__ import annotations

import json
import logging
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

from agent.controllers import import_path_dirs
from copath.scenario import Scenario
from copath.wire.keys import Keys
from copath.wire.messages import Event
from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint

from orchestrator.run.failures import FailureReporter
from orchestrator.log.mcap import read_log
from orchestrator.log.writer import Recorder, fault_metadata, software_version
from orchestrator.analysis.metrics import log_metrics
from orchestrator.run.progress import Progress

logger = logging.getLogger(__name__)

__all__ = ["RunOptions", "RunOutcome", "run_fleet", "new_run_id"]

REPO_ROOT = pathlib.Path(__file__).resolve().parents[2]


REJOIN_TIMEOUT_S = 20.0
"""Default bound [s] from a restarted robot's process start to its first command (measured:
about 1-2 s when forked from the zygote on a loaded 2-core machine; docs/reference/faults.md)."""


def new_run_id(scenario_id: str) -> str:
    return f"{scenario_id}-{time.strftime('%Y%m%d-%H%M%S')}-{uuid.uuid4().hex[:6]}"


@dataclass
class RunOptions:
    out_dir: pathlib.Path
    run_id: str
    wall_timeout_s: float | None = None
    """Give up after this many wall-clock seconds (default: 120 s + 20x the duration)."""
    start_timeout_s: float = 120.0
    progress: bool = True
    connect: tuple[str, ...] = ()
    """Extra endpoints for the router to connect to (multi-host runs)."""
    listen: tuple[str, ...] = ()
    """Router listen endpoints (default: one free loopback port)."""
    live_port: int | None = None
    """Serve the run's Foxglove views on this WebSocket port while it runs (orchestrator/view/live.py)."""
    external: tuple[str, ...] = ()
    """Robots not started here: the run prints the ``copath agent`` command for each and
    waits for them to join before the first tick (another terminal or machine)."""
    secure: bool | None = None
    """Per-run credentials and access control on the router (orchestrator/run/security.py);
    None: the scenario's ``run.secure``."""
    ros2_view: bool = False
    """Mirror the run into ROS 2 live (``copath run --ros2``, orchestrator/view/ros2.py)."""
    max_restarts: int = 3
    """``run.on_robot_failure = "restart"``: restarts per robot before it is left lost."""
    rejoin_timeout_s: float = REJOIN_TIMEOUT_S
    """A restarted robot that has sent no command this long after its process started is
    lost: an event, a terminal line, the process stopped and the run failed (docs/reference/faults.md)."""
    fork_server: bool = field(default_factory=lambda: os.environ.get("COPATH_FORK_SERVER", "1") != "0")
    """Start the agents by forking a pre-imported launcher (``agent/zygote.py``) instead of
    one ``python -m agent`` each: the imports are paid once (docs/journal/performance.md, realtime at 128 robots (P10)).
    ``COPATH_FORK_SERVER=0`` in the environment turns it off."""


@dataclass
class RunOutcome:
    ok: bool
    reason: str
    out_dir: pathlib.Path
    metrics: dict[str, Any] | None = None
    pids: dict[str, int] = field(default_factory=dict)
    records: list = field(default_factory=list, repr=False)
    """Every record of the run, as read back from its log for the metrics (decoded once)."""


@dataclass
class _Child:
    name: str
    proc: subprocess.Popen
    log: Any


def _spawn(name: str, argv: list[str], log_path: pathlib.Path, cwd: pathlib.Path) -> _Child:
    env = dict(os.environ)
    # the scenario's directory and the start directory: import-path controllers resolve alike in every child
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), *import_path_dirs(), env.get("PYTHONPATH", "")) if p)
    env.setdefault("PYTHONUNBUFFERED", "1")
    log = log_path.open("wb")
    proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            start_new_session=True, env=env, cwd=str(cwd))
    return _Child(name, proc, log)


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


class _Zygote:
    """``python -m agent.zygote``: imports once, forks one process per robot (realtime at 128 robots, P10)."""

    def __init__(self, scen_path: pathlib.Path, cwd: pathlib.Path) -> None:
        from agent.zygote import TITLE_ROOM, set_subreaper  # noqa: PLC0415

        self.subreaper = set_subreaper()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), *import_path_dirs(), env.get("PYTHONPATH", "")) if p)
        env.setdefault("PYTHONUNBUFFERED", "1")
        self.log = (cwd / "zygote.log").open("wb")
        self.proc = subprocess.Popen([sys.executable, "-m", "agent.zygote", "--config", str(scen_path.resolve()),
                                      "--title-room=" + "x" * TITLE_ROOM], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.log, start_new_session=True, env=env, cwd=str(cwd))

    def spawn(self, name: str, argv: list[str], log_path: pathlib.Path) -> _Child | None:
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
        return _Child(name, _ForkedProc(int(reply["pid"])), open(os.devnull, "wb"))

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


def _stop(children: list[_Child], grace_s: float = 3.0) -> None:
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


class _Terminated(Exception):
    """SIGTERM arrived while a run was under way."""


def _raise_terminated(signum, frame) -> None:
    raise _Terminated()


def _describe_exit(rc: int) -> str:
    if rc < 0:
        try:
            return f"was killed by {signal.Signals(-rc).name}"
        except ValueError:
            return f"was killed by signal {-rc}"
    return f"exited with code {rc}"


def run_fleet(scenario: Scenario, opts: RunOptions) -> RunOutcome:
    """Run ``scenario`` as separate processes over Zenoh; write run.mcap and metrics.json."""
    out = pathlib.Path(opts.out_dir)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    keys = Keys(opts.run_id)
    raw = dict(scenario.raw)
    raw["_source"] = scenario.source
    scen_path = out / "scenario.json"
    scen_path.write_text(json.dumps(raw, indent=1))
    endpoint = loopback_endpoint(free_port())
    listen = opts.listen or (endpoint,)
    connect_for_children = [e.replace("0.0.0.0", "127.0.0.1") for e in listen]
    wall0 = time.monotonic()
    metadata = {
        "scenario": {"json": json.dumps(raw), "id": scenario.id, "source": scenario.source},
        "copath": {"version": software_version(), "run_id": opts.run_id, "clock": scenario.run.clock,
                   "seed": str(scenario.run.seed), "robots": ",".join(scenario.robot_names),
                   "python": sys.version.split()[0]},
        "faults": fault_metadata(scenario),
    }
    if scenario.world.ros2:  # the world records are what the robots reported (docs/reference/ros2.md)
        metadata["world"] = {"backend": "ros2", "truth": "poses reported by the robots, not ground truth",
                             "ros_domain_id": os.environ.get("ROS_DOMAIN_ID", "0")}
    live = tail = None
    if opts.live_port is not None:  # before anything else opens: a busy port fails the run at once
        from orchestrator.view.live import LiveViz, LogTail
        from orchestrator.view.foxglove import TOPICS

        live = LiveViz(opts.live_port)
        live.advertise(TOPICS)
        tail = LogTail(out / "logs", live).start()  # process log lines, live
        logger.info("live views on %s (Foxglove: Open connection -> Foxglove WebSocket)", live.url)
    mirror = None
    if opts.ros2_view:  # RViz2 and ros2 topic echo see the run (docs/reference/ros2.md); before the router opens
        from orchestrator.view.ros2 import Ros2Mirror

        mirror = Ros2Mirror(scenario, keys)
    secure = scenario.run.secure if opts.secure is None else bool(opts.secure)
    metadata["copath"]["secure"] = str(secure)
    creds, router_extra = None, ()
    if secure:
        from copath.wire.acl import overhears

        from orchestrator.run.security import make_credentials, router_extra as _router_extra

        creds = make_credentials(out / "secrets", ["sim", *scenario.robot_names])
        router_extra = _router_extra(creds, keys, list(scenario.robot_names), overhear=overhears(scenario))
        if opts.connect:
            logger.warning("secure mode: robots that join through the routers of --connect are refused "
                           "(a router in between logs in as nobody); use --no-secure for such a fleet "
                           "(README, 'Running robots on several machines')")
    router = ZenohLink.open(SessionConfig(mode="router", listen=tuple(listen), connect=tuple(opts.connect),
                                          lease_ms=round(1e3 * scenario.run.lease_s),
                                          extra=router_extra))
    recorder = Recorder(out / "run.mcap", keys, metadata)
    from orchestrator.view.foxglove import RecordedViews  # noqa: PLC0415

    views = RecordedViews(recorder, scenario, live=live)
    router.subscribe_raw(keys.all, recorder.write, attachment=True)  # with each sender's sequence numbers
    if mirror is not None:
        router.subscribe_raw(keys.all, mirror.write)
    # the first controller failure of each robot, one line here (its traceback is in its log)
    router.subscribe(keys.event("*"), FailureReporter(log_dir=out / "logs"))
    common = ["--run-id", opts.run_id, "--config", str(scen_path.resolve())]  # children run in DIR/logs
    for e in connect_for_children:
        common += ["--connect", e]
    if logging.getLogger().isEnabledFor(logging.DEBUG):  # copath --log-level debug reaches every process
        common.append("--verbose")
    children: list[_Child] = []
    ok, reason = True, "completed"
    progress = Progress(scenario.run.duration_s, enabled=opts.progress,
                        starting=f"starting {len(scenario.robots) + 1} processes (solvers compile)").start()
    ready: set[str] = set()  # robots whose controller is built: their liveliness token is up
    token_at: dict[str, float] = {}  # when each robot's token last appeared
    spawned_at: dict[str, float] = {}

    def _on_alive(key: str, alive: bool) -> None:
        name = key.rsplit("/", 1)[-1]
        if name in scenario.robot_names:
            (ready.add if alive else ready.discard)(name)
            if alive:
                token_at[name] = time.monotonic()
            progress.starting = (f"starting: {len(ready)}/{len(scenario.robots)} robots ready "
                                 "(the others build their controllers; solvers compile)")

    router.watch_liveliness(keys.all_alive, _on_alive)
    wall_limit = opts.wall_timeout_s or (120.0 + 20.0 * scenario.run.duration_s)
    # SIGTERM (a test's timeout, a process manager) ends the run like Ctrl-C: children stopped, log finished
    prev_term = (signal.signal(signal.SIGTERM, _raise_terminated)
                 if threading.current_thread() is threading.main_thread() else None)
    def _auth(proc: str) -> list[str]:  # a process's credentials, in a file only its owner reads
        return ["--zenoh-config", str(creds.process_file(proc).resolve())] if creds is not None else []

    def _io(name: str) -> list[str]:  # a robot whose agent drives it over ROS 2 itself (docs/reference/ros2.md)
        return ["--io", "ros2"] if scenario.world.ros2 and scenario.world.robots[name].commands == "agent" else []

    policy = scenario.run.on_robot_failure
    restarts = {n: 0 for n in scenario.robot_names}
    gone: set[str] = set()  # robots lost under "continue"
    max_restarts = opts.max_restarts
    rejoining: dict[str, int] = {}  # restarted robots not commanding yet: their spawn time [ns]
    never_back: list[str] = []  # restarted robots that missed the rejoin bound, or ran out of restarts

    zygote = _Zygote(scen_path, out / "logs") if opts.fork_server else None

    def _agent(name: str) -> _Child:
        spawned_at[name] = time.monotonic()
        log = out / "logs" / (f"{name}.log" if not restarts[name] else f"{name}.restart{restarts[name]}.log")
        argv = ["--robot", name, *common, *_auth(name), *_io(name)]
        # a restart (run.on_robot_failure = "restart") is a fresh process, as a robot rebooting
        # would be: forked from the zygote it is one too (new session, new controller), without
        # paying the imports again, which took 1.4-1.7 s of a restart under load (docs/reference/faults.md)
        child = zygote.spawn(name, argv, log) if zygote is not None else None
        child = child or _spawn(name, [sys.executable, "-m", "agent", *argv], log, out / "logs")
        if restarts[name]:
            rejoining[name] = time.time_ns()
        return child

    def _check_rejoins() -> None:
        """A restarted robot commands again within ``opts.rejoin_timeout_s`` of its process
        start, or it is lost: event, terminal line, process stopped (docs/reference/faults.md)."""
        for name, t_ns in list(rejoining.items()):
            last = recorder.last_cmd_ns.get(name, 0)
            if last > t_ns:
                del rejoining[name]
                logger.info("robot %s commands again %.2f s after its restart", name, (last - t_ns) / 1e9)
                continue
            waited = (time.time_ns() - t_ns) / 1e9
            if waited < opts.rejoin_timeout_s:
                continue
            del rejoining[name]
            never_back.append(name)
            gone.add(name)
            msg = (f"robot {name} sent no command {waited:.1f} s after its restart (bound "
                   f"{opts.rejoin_timeout_s:g} s); it is lost, see {out / 'logs' / f'{name}.restart{restarts[name]}.log'}")
            print(f"copath run: {msg}", file=sys.stderr, flush=True)
            logger.error(msg)
            recorder.write(keys.event("orchestrator"), Event(float(recorder.sim_t), "orchestrator", "rejoin_timeout", {
                "robot": name, "waited_s": round(waited, 3), "bound_s": opts.rejoin_timeout_s}).pack())
            for c in list(children[1:]):
                if c.name == name:
                    children.remove(c)
                    _stop([c])

    try:
        world = "sim.ros2_bridge" if scenario.world.ros2 else "sim"  # ROS 2 robots: the bridge (docs/reference/ros2.md)
        children.append(_spawn("sim", [sys.executable, "-m", world, *common, *_auth("sim"), "--start-timeout",
                                       str(opts.start_timeout_s)], out / "logs" / "sim.log", out / "logs"))
        for name in scenario.robot_names:
            if name in opts.external:
                continue
            children.append(_agent(name))
        for name in opts.external:  # the user starts these: the exact command, then the wait
            cmd = ["copath", "agent", "--run-id", opts.run_id, "--robot", name, "--config", str(scen_path.resolve()),
                   *[a for e in listen for a in ("--connect", e)], *_auth(name), *_io(name)]
            print(f"copath run: start robot {name} yourself (the run waits for it):\n  {' '.join(cmd)}",
                  file=sys.stderr, flush=True)
        while True:
            progress.update(recorder.sim_t, recorder.count)
            sim = children[0]
            rc_sim = sim.proc.poll()
            failed = [c for c in children[1:] if c.proc.poll() is not None and (c.proc.returncode != 0 or rc_sim is None and recorder.end is None)]
            if policy == "restart" and rc_sim is None and recorder.end is None:
                _check_rejoins()
                for c in children[1:]:  # frozen (its token expired, the process is still there): kill, restart
                    if (c.proc.poll() is None and c.name not in ready
                            and token_at.get(c.name, 0.0) > spawned_at.get(c.name, float("inf"))):
                        logger.warning("robot %s (pid %d) lost its liveliness; killing it to restart it",
                                       c.name, c.proc.pid)
                        try:
                            os.killpg(c.proc.pid, signal.SIGKILL)
                            c.proc.wait(timeout=5)
                        except (ProcessLookupError, subprocess.TimeoutExpired):
                            pass
                failed = [c for c in children[1:] if c.proc.poll() is not None
                          and (c.proc.returncode != 0 or recorder.end is None)]
            if failed and rc_sim is None and recorder.end is None and policy != "fail":
                # run.on_robot_failure: the simulator holds the robot still and goes on
                for c in failed:
                    logger.warning("robot %s (pid %d) %s at sim t=%.2f s; policy %s", c.name, c.proc.pid,
                                   _describe_exit(c.proc.returncode), recorder.sim_t, policy)
                    children.remove(c)
                    c.log.close()
                    if policy == "restart" and restarts[c.name] < max_restarts:
                        restarts[c.name] += 1
                        children.append(_agent(c.name))
                    else:
                        if policy == "restart":
                            never_back.append(c.name)
                            print(f"copath run: robot {c.name} is lost: {max_restarts} restarts used",
                                  file=sys.stderr, flush=True)
                        gone.add(c.name)
                        rejoining.pop(c.name, None)
                failed = []
            if failed:
                c = failed[0]
                ok, reason = False, (f"robot {c.name} (pid {c.proc.pid}) {_describe_exit(c.proc.returncode)} "
                                     f"at sim t={recorder.sim_t:.2f} s; see {out / 'logs' / (c.name + '.log')}")
                break
            if rc_sim is not None:
                deadline = time.monotonic() + 10.0
                while rc_sim == 0 and recorder.end is None and time.monotonic() < deadline:
                    time.sleep(0.05)  # its end record is still on its way through a busy router
                end = recorder.end
                if rc_sim != 0 or end is None or not end.ok:
                    why = end.reason if end is not None else f"the simulator {_describe_exit(rc_sim)}"
                    silent = [n for n in scenario.robot_names if n in token_at and n not in ready and n not in gone]
                    if silent and end is not None:  # every robot whose token is gone, not only the first
                        why += (f"; no liveliness token from {', '.join(silent)} (a process stopped, or its "
                                "host or router lost the link to this run's router)")
                    ok, reason = False, f"{why} at sim t={recorder.sim_t:.2f} s; see {out / 'logs' / 'sim.log'}"
                    break
                # normal end: wait for the robots to send their closing accounts and exit
                ended = time.monotonic()
                deadline = ended + 30.0
                # a restarted robot that came up after the simulator ended waits for a start that
                # will not come: it gets 5 s, like the others, to show it had rejoined by exiting
                late = ended + 5.0
                while time.monotonic() < deadline and any(
                        c.proc.poll() is None and (policy == "fail" or c.name not in scenario.robot_names
                                                   or c.name in ready)  # a frozen robot will not exit
                        and not (restarts.get(c.name) and time.monotonic() > late)
                        for c in children):
                    time.sleep(0.05)
                too_late = [c for c in children if restarts.get(c.name) and c.proc.poll() is None]
                for c in too_late:
                    logger.warning("robot %s was restarted too late to rejoin before the end; stopping it", c.name)
                _stop(too_late)
                gone.update(c.name for c in too_late)  # never rejoined: no closing account to wait for
                stuck = [c.name for c in children if c.proc.poll() is None]
                if policy != "fail":  # frozen robots the run went on without
                    gone.update(n for n in stuck if n in scenario.robot_names and n not in ready)
                    gone.update(n for n in opts.external if n not in ready)  # cut off, or stopped by hand
                    stuck = [n for n in stuck if n not in gone]
                bad = [c for c in children[1:] if c.proc.poll() is not None and c.proc.returncode != 0
                       and c not in too_late]
                if stuck:
                    ok, reason = False, f"processes {stuck} did not exit after the end of the run"
                elif bad:
                    ok, reason = False, f"robot {bad[0].name} {_describe_exit(bad[0].proc.returncode)} at the end of the run"
                break
            if time.monotonic() - wall0 > wall_limit:
                ok, reason = False, f"wall-clock limit of {wall_limit:.0f} s reached at sim t={recorder.sim_t:.2f} s"
                break
            time.sleep(0.05)
    except KeyboardInterrupt:
        ok, reason = False, f"interrupted (Ctrl-C) at sim t={recorder.sim_t:.2f} s"
    except _Terminated:
        ok, reason = False, f"terminated (SIGTERM) at sim t={recorder.sim_t:.2f} s"
    finally:
        if prev_term is not None:
            signal.signal(signal.SIGTERM, prev_term)
        progress.done()
        if not ok and scenario.world.ros2 and children and children[0].proc.poll() is None:
            os.killpg(children[0].proc.pid, signal.SIGTERM)  # the bridge stops every robot now (docs/reference/ros2.md)
        if ok:  # closing accounts may still be in flight through the router
            expected = {"sim", *scenario.robot_names}
            deadline, hard, seen = time.monotonic() + 3.0, time.monotonic() + 15.0, recorder.count
            while time.monotonic() < deadline and not expected <= set(recorder.stats):
                time.sleep(0.02)
                if recorder.count != seen:  # a busy router is still forwarding: keep waiting a while
                    seen, deadline = recorder.count, min(hard, max(deadline, time.monotonic() + 1.0))
        else:
            time.sleep(0.3)
        pids = {c.name: c.proc.pid for c in children}
        _stop(children)
        if zygote is not None:
            zygote.close()
        router.close()
        if mirror is not None:
            mirror.close()
        views.add_process_logs(out / "logs")
        recorder.finish({"outcome": {"ok": str(ok), "reason": reason}})
        if live is not None:
            tail.stop()
            live.close()
    wall = time.monotonic() - wall0
    log = read_log(out / "run.mcap")
    accounts = {r.proc for _, _, r in log.records if getattr(r, "TYPE", "") == "stats"}
    if ok and accounts | gone != {"sim", *scenario.robot_names}:
        missing = sorted({"sim", *scenario.robot_names} - accounts - gone)
        ok, reason = False, f"no closing account from {missing}"
    if ok and never_back:  # "restart" promises the robot back: one that never came is a failure
        ok, reason = False, f"robot {never_back[0]} never came back after its restart"
    metrics = log_metrics(log, scenario, run_id=opts.run_id, clock=scenario.run.clock, wall_time_s=wall, ok=ok,
                          failure=reason)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return RunOutcome(ok, reason, out, metrics, pids, log.records)
