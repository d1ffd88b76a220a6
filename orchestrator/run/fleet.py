"""Spawn a run: the router (in this process), the recorder, the simulator and one process per robot.

Lifecycle of ``copath run`` (:func:`run_fleet` composes the parts):

1. validate the scenario with the CLI overrides and write it to ``DIR/scenario.json``
   (the exact scenario every process loads);
2. open the run's Zenoh router on a free loopback port (multicast scouting off;
   ``orchestrator/run/router.py``) and subscribe the recorder to ``copath/<run_id>/**``
   before anything is started (``orchestrator/run/recorder.py``);
3. start ``python -m sim`` and ``python -m agent`` per robot, each in its own process
   group, logs in ``DIR/logs/`` (``orchestrator/run/supervisor.py``);
4. watch: progress from the recorded truth; a child that dies before the end fails
   the run with a one-line reason (or is left or restarted, ``run.on_robot_failure``);
   Ctrl-C and the wall-clock limit too;
5. tear down every child by process group (SIGTERM, then SIGKILL), finish the MCAP,
   read it back and compute ``metrics.json`` from it.
"""

from __future__ import annotations

import json
import logging
import os
import pathlib
import signal
import threading
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

from copath.scenario import Scenario
from copath.wire.keys import Keys

from orchestrator.analysis.metrics import log_metrics
from orchestrator.log.mcap import read_log
from orchestrator.run.progress import Progress
from orchestrator.run.recorder import RunRecorder, run_metadata
from orchestrator.run.router import RunRouter
from orchestrator.run.supervisor import REJOIN_TIMEOUT_S, Supervisor

logger = logging.getLogger(__name__)

__all__ = ["RunOptions", "RunOutcome", "run_fleet", "new_run_id", "REJOIN_TIMEOUT_S"]


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


class _Terminated(Exception):
    """SIGTERM arrived while a run was under way."""


def _raise_terminated(signum, frame) -> None:
    raise _Terminated()


def run_fleet(scenario: Scenario, opts: RunOptions) -> RunOutcome:
    """Run ``scenario`` as separate processes over Zenoh; write run.mcap and metrics.json."""
    out = pathlib.Path(opts.out_dir)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    keys = Keys(opts.run_id)
    raw = dict(scenario.raw)
    raw["_source"] = scenario.source
    scen_path = out / "scenario.json"
    scen_path.write_text(json.dumps(raw, indent=1))
    wall0 = time.monotonic()
    secure = scenario.run.secure if opts.secure is None else bool(opts.secure)
    metadata = run_metadata(scenario, opts.run_id, secure)
    # live outlets before anything else opens: a busy port fails the run at once
    recording = RunRecorder(scenario, keys, out, live_port=opts.live_port, ros2_view=opts.ros2_view)
    router = RunRouter(scenario, keys, out / "secrets", secure, listen=opts.listen, connect=opts.connect)
    log = recording.start(router.link, metadata)
    common = ["--run-id", opts.run_id, "--config", str(scen_path.resolve())]  # children run in DIR/logs
    for e in router.children_connect:
        common += ["--connect", e]
    if logging.getLogger().isEnabledFor(logging.DEBUG):  # copath --log-level debug reaches every process
        common.append("--verbose")
    ok, reason = True, "completed"
    progress = Progress(scenario.run.duration_s, enabled=opts.progress,
                        starting=f"starting {len(scenario.robots) + 1} processes (solvers compile)").start()
    procs = Supervisor(scenario, keys, out, scen_path, common, router.auth, log, progress, run_id=opts.run_id,
                       listen=router.listen, external=opts.external, fork_server=opts.fork_server,
                       max_restarts=opts.max_restarts, rejoin_timeout_s=opts.rejoin_timeout_s,
                       start_timeout_s=opts.start_timeout_s)
    router.link.watch_liveliness(keys.all_alive, procs.on_alive)
    wall_limit = opts.wall_timeout_s or (120.0 + 20.0 * scenario.run.duration_s)
    # SIGTERM (a test's timeout, a process manager) ends the run like Ctrl-C: children stopped, log finished
    prev_term = (signal.signal(signal.SIGTERM, _raise_terminated)
                 if threading.current_thread() is threading.main_thread() else None)
    # and SIGINT always stops it, even when this process was started with SIGINT ignored (a
    # background job of a script: Python then leaves it ignored): robots must stop when told
    prev_int = (signal.signal(signal.SIGINT, signal.default_int_handler)
                if threading.current_thread() is threading.main_thread() else None)
    try:
        procs.start()
        ok, reason = procs.watch(wall0, wall_limit)
    except KeyboardInterrupt:
        ok, reason = False, f"interrupted (Ctrl-C) at sim t={log.sim_t:.2f} s"
    except _Terminated:
        ok, reason = False, f"terminated (SIGTERM) at sim t={log.sim_t:.2f} s"
    finally:
        if prev_term is not None:
            signal.signal(signal.SIGTERM, prev_term)
        if prev_int is not None:
            signal.signal(signal.SIGINT, prev_int)
        progress.done()
        if not ok:
            procs.stop_world()
        if ok:  # closing accounts may still be in flight through the router
            recording.await_accounts({"sim", *scenario.robot_names})
        else:
            time.sleep(0.3)
        pids = procs.stop()
        router.close()
        recording.finish(ok, reason)
    wall = time.monotonic() - wall0
    read = read_log(out / "run.mcap")
    accounts = {r.proc for _, _, r in read.records if getattr(r, "TYPE", "") == "stats"}
    if ok and accounts | procs.gone != {"sim", *scenario.robot_names}:
        missing = sorted({"sim", *scenario.robot_names} - accounts - procs.gone)
        ok, reason = False, f"no closing account from {missing}"
    if ok and procs.never_back:  # "restart" promises the robot back: one that never came is a failure
        ok, reason = False, f"robot {procs.never_back[0]} never came back after its restart"
    metrics = log_metrics(read, scenario, run_id=opts.run_id, clock=scenario.run.clock, wall_time_s=wall, ok=ok,
                          failure=reason)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return RunOutcome(ok, reason, out, metrics, pids, read.records)
