"""A whole run in one process: the same node code as a fleet, on an in-memory bus.

Used by tests, sweeps and benchmarks. The simulator's :class:`sim.node.SimNode` and one
:class:`agent.node.AgentNode` per robot run exactly as in their processes, but talk
through :class:`copath.wire.link.MemoryLink` instead of Zenoh: a publish runs the
subscribers' callbacks at once, so the lockstep protocol (observations with their
``expect`` barrier, peer envelopes through each robot's fault layer, commands, truth)
is the one the processes run and cannot drift from it. The bus keeps every published
record, keyed exactly as on Zenoh and stamped with the simulator's time, so metrics are
computed from the same stream as a real run's MCAP log (``orchestrator/analysis/metrics.py``).

Tick k at t_k = k dt: the simulator publishes each robot's observation; the robot steps
inside that delivery (peer messages sent at tick k are delivered at tick k+1 or later,
after faults: ``copath.wire.faults``) and publishes its messages, command and telemetry;
the simulator publishes the truth of tick k (pose at t_k, commands applied over
[t_k, t_k+1)) and integrates.
"""

from __future__ import annotations

import contextlib
import gc
import pathlib
import time
import uuid
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, TextIO

from agent.controllers import task_queues
from agent.node import AgentNode
from agent.runtime import RobotRuntime
from copath.scenario import Scenario, kill_tick
from copath.wire.acl import AccessPolicy
from copath.wire.keys import Keys
from copath.wire.link import MemoryBus
from copath.wire.messages import End, PeerEnvelope, Stats
from sim.node import SimNode

from orchestrator.run.failures import FailureReporter
from orchestrator.analysis.metrics import Trace, compute_metrics, trace_from_records

__all__ = ["run_scenario", "RunResult"]


@dataclass
class RunResult:
    metrics: dict[str, Any]
    trace: Trace
    records: list[tuple[int, str, Any]] = field(repr=False)
    """(log time [ns], key, record) of every message the run published."""
    ok: bool = True
    """The simulator's verdict (False: it ended the run, e.g. a lost robot under ``fail``)."""


RESTART_AFTER_S = 1.0
"""Under ``run.on_robot_failure = "restart"``, a robot killed by the scenario (``run.kills``) is
started again this long after the kill in one process [s] (chosen: a fleet's supervisor forks it
from the zygote and it rejoins within about a second, docs/reference/faults.md; the chaos soak's
in-process form uses the same)."""


def run_scenario(scenario: Scenario, duration_s: float | None = None, run_id: str | None = None,
                 on_tick: Callable[[float, int], None] | None = None,
                 kills: Mapping[str, float] | None = None,
                 restarts: Mapping[str, float] | None = None,
                 failures: TextIO | None = None, log_dir: str | pathlib.Path | None = None) -> RunResult:
    """Run ``scenario`` in lockstep inside this process and return metrics and trace.

    ``on_tick(t, n)`` is called after each tick with the sim time reached [s] and the
    number of messages published so far (progress display). ``kills`` ({robot: t [s]},
    or {robot: [t, ...]} for several; added to the scenario's own ``run.kills``):
    the robot's process goes away at the first tick at or after t, as with SIGKILL (its
    link closes: its liveliness token disappears and it answers no more observations; the
    run's ``on_robot_failure`` applies). ``restarts`` ({robot: t}): a new process of that
    robot (a new controller) starts then (or at each of several times) and joins from the current world state, as
    ``restart`` does for a fleet (docs/reference/faults.md).

    Every peer message a node receives passes the receiver validation of a fleet's Zenoh
    link (:func:`copath.wire.link.validate_record`: schema and origin; the other records
    are copath's own); a rejected one counts as delivered-and-dropped for the lockstep
    barrier, as over Zenoh. The first controller failure of each robot is printed as one
    line on ``failures`` (default stderr; ``orchestrator/run/failures.py``), its traceback
    written to ``log_dir/<robot>.log`` when ``log_dir`` is given."""
    wall0 = time.perf_counter()
    run_id = run_id or f"inproc-{uuid.uuid4().hex[:8]}"
    keys = Keys(run_id)
    dt = scenario.run.dt
    sim: SimNode | None = None
    # secure mode's access policy, whatever run.secure says: a node that steps outside its
    # grants fails here at once, not as a stalled fleet behind a secure router; receiver
    # validation of what a controller decides (its peer messages), as over Zenoh
    bus = MemoryBus(clock=lambda: sim.world.t, policy=AccessPolicy.for_scenario(keys, scenario),
                    validate=(PeerEnvelope,))
    bus.link().subscribe(keys.event("*"), FailureReporter(failures, log_dir, write_logs=True))

    def runtime(name: str) -> RobotRuntime:
        rt = RobotRuntime(scenario, name, keys)
        rt.log_tracebacks = False  # the traceback goes to the event (and log_dir), one line to the terminal
        return rt

    agents = {n: AgentNode(runtime(n), keys, bus.link(n), "lockstep") for n in scenario.robot_names}
    started: list[AgentNode] = []
    def _times(v) -> list[float]:  # one time, or several (a robot killed and restarted again and again)
        return [float(x) for x in v] if isinstance(v, (list, tuple)) else [float(v)]

    # the scenario's own kills (run.kills) and the caller's, as one schedule; under "restart" a
    # declared kill's robot comes back RESTART_AFTER_S later, as the fleet's supervisor restarts it
    declared = [(k.robot, k.at_s) for k in scenario.run.kills]
    back = [(n, t + RESTART_AFTER_S) for n, t in declared] if scenario.run.on_robot_failure == "restart" else []
    declared += [(n, t) for n, ts in (kills or {}).items() for t in _times(ts)]
    # a kill's link closes after the tick before the one it falls due at (copath.scenario.kill_tick)
    faults = sorted([(kill_tick(t, dt) - 1, 0, n) for n, t in dict.fromkeys(declared)]
                    + [(round(t / dt), 1, n) for n, t in back]
                    + [(round(t / dt), 1, n) for n, ts in (restarts or {}).items() for t in _times(ts)])
    current = dict(agents)  # each robot's newest process
    for _, _, n in faults:
        scenario.robot(n)  # an unknown robot fails here, naming it

    def tick(k: int) -> None:
        while faults and faults[0][0] <= k:
            _, restart, n = faults.pop(0)
            if restart:
                started.append(AgentNode(runtime(n), keys, bus.link(n), "lockstep"))
                started[-1].start()
                current[n] = started[-1]
            else:
                current[n].link.close()
        if on_tick is not None:
            on_tick((k + 1) * dt, len(bus.records))

    sim = SimNode(scenario, keys, bus.link("sim"), duration_s=duration_s,
                  on_tick=tick if faults or on_tick is not None else None, tasks=task_queues(scenario))
    sim.world.t = 0.0
    for a in agents.values():
        a.start()
    with _long_lived():
        try:
            ok = sim.run()
        finally:
            for a in [*agents.values(), *started]:
                a.link.close()
            sim.link.close()
        return _result(scenario, bus, keys, run_id, wall0, ok)


@contextlib.contextmanager
def _long_lived():
    """What exists when the run starts (modules, the scenario, the nodes and their controllers)
    lives for the whole run: kept out of the collector's full passes, which the records piling up
    during the run trigger again and again (docs/journal/performance.md, "The robot step and the
    simulator, second pass"). A caller's own ``gc.freeze`` is left alone. During the run the
    youngest generation is collected after ``_YOUNG`` allocations instead of 700: the records
    the run keeps are then walked by one young pass each and no older pass comes (E5.4's
    collections 0.16 -> 0.07 s of CPU; docs/journal/performance.md, "In-process speed, third pass")."""
    frozen = gc.get_freeze_count() == 0
    if frozen:
        gc.freeze()
    threshold = gc.get_threshold()
    if threshold[0] and threshold[0] < _YOUNG:  # 0: the caller turned the collector off
        gc.set_threshold(_YOUNG, *threshold[1:])
    try:
        yield
    finally:
        if gc.get_threshold()[0] == _YOUNG:
            gc.set_threshold(*threshold)
        if frozen:
            gc.unfreeze()


_YOUNG = 50_000
"""Allocations between two collections of the youngest generation during an in-process run."""


def _result(scenario: Scenario, bus: MemoryBus, keys: Keys, run_id: str, wall0: float, ok: bool) -> RunResult:
    """Metrics and trace of a finished run from the records on the bus."""
    records = bus.records
    stats = [r for _, _, r in records if isinstance(r, Stats)]
    published = sum(s.published for s in stats)
    trace = trace_from_records(records, keys)
    metrics = compute_metrics(
        trace,
        scenario,
        run_id=run_id,
        clock="lockstep",
        wall_time_s=time.perf_counter() - wall0,
        messages_published=published,
        messages_recorded=published,
    )
    # ok and failure as a fleet run's metrics.json has them (orchestrator.analysis.metrics.log_metrics)
    end = next((r for _, _, r in reversed(records) if isinstance(r, End)), None)
    metrics["ok"] = bool(ok)
    metrics["failure"] = None if ok else (end.reason if end is not None else "the simulator ended the run")
    return RunResult(metrics, trace, records, bool(ok))
