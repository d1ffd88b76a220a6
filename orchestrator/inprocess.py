"""A whole run in one process, with the lockstep semantics of the distributed runtime.

Used by tests and benchmarks. It drives the same pieces as the processes do — the
simulator's :class:`sim.world.World`, each robot's :class:`agent.runtime.RobotRuntime`
(controller, fault layer, range filter, envelopes) — and keeps every record that would
have been published, keyed exactly as on Zenoh, so metrics are computed from the same
stream as a real run's MCAP log (``orchestrator/metrics.py``).

Tick k at t_k = k dt: the simulator publishes each robot's observation; each robot
steps (peer messages sent at tick k are delivered at tick k+1 or later, after faults)
and publishes its command, messages and telemetry; the simulator publishes the truth
of tick k (pose at t_k, commands applied over [t_k, t_k+1)) and integrates.
"""

from __future__ import annotations

import fnmatch
import time
import uuid
from dataclasses import dataclass, field
from typing import Any, Callable

from agent.runtime import RobotRuntime
from copath.scenario import Scenario
from copath.wire.keys import Keys
from copath.wire.messages import End, Start, Stats
from sim.world import World

from .metrics import Trace, compute_metrics, trace_from_records

__all__ = ["run_scenario", "RunResult"]


@dataclass
class RunResult:
    metrics: dict[str, Any]
    trace: Trace
    records: list[tuple[int, str, Any]] = field(repr=False)
    """(log time [ns], key, record) of every message the run published."""


def _matches(key: str, patterns: list[str]) -> bool:
    return any(fnmatch.fnmatchcase(key, p.replace("**", "*")) for p in patterns)


def run_scenario(scenario: Scenario, duration_s: float | None = None, run_id: str | None = None,
                 on_tick: Callable[[float, int], None] | None = None) -> RunResult:
    """Run ``scenario`` in lockstep inside this process and return metrics and trace.

    ``on_tick(t, n)`` is called after each tick with the sim time reached [s] and the
    number of messages published so far (progress display)."""
    wall0 = time.perf_counter()
    run_id = run_id or f"inproc-{uuid.uuid4().hex[:8]}"
    keys = Keys(run_id)
    duration = scenario.run.duration_s if duration_s is None else duration_s
    dt = scenario.run.dt
    world = World(scenario)
    robots = {n: RobotRuntime(scenario, n, keys) for n in scenario.robot_names}
    subs = {n: r.subscriptions for n, r in robots.items()}
    receivers_of: dict[str, list[str]] = {}  # key -> subscribed robots, computed once per key
    overhear = {n: r.overhear_subscriptions for n, r in robots.items() if r.overhear_subscriptions}
    overhearers_of: dict[str, list[str]] = {}  # the same for the safety filter's subscriptions
    records: list[tuple[int, str, Any]] = []

    def publish(t: float, key: str, rec: Any) -> None:
        records.append((int(round(t * 1e9)), key, rec))

    publish(0.0, keys.start, Start(0.0, dt, "lockstep"))
    n_ticks = int(round(duration / dt))
    sent: dict[str, dict[str, int]] = {}
    for k in range(n_ticks):
        t = k * dt
        world.t = t
        outs = {}
        for n, rt in robots.items():
            obs = world.observe(n, k, sent)
            publish(t, keys.obs(n), obs)
            outs[n] = rt.step(obs, t)
        for n, out in outs.items():
            for key, env in out.peers:
                publish(t, key, env)
                if key not in receivers_of:
                    receivers_of[key] = [r for r, patterns in subs.items() if r != n and _matches(key, patterns)]
                for r in receivers_of[key]:
                    robots[r].receive(env)
                if overhear:
                    if key not in overhearers_of:
                        overhearers_of[key] = [r for r, p in overhear.items() if r != n and _matches(key, p)]
                    for r in overhearers_of[key]:
                        robots[r].overhear(env)
            publish(t, keys.cmd(n), out.command)
            publish(t, keys.telemetry(n), out.telemetry)
            if out.estimate is not None:
                publish(t, keys.estimate(n), out.estimate)
            world.command(n, out.command.cmd)
            sent[n] = out.command.sent
        world.saturate_all()
        publish(t, keys.truth, world.truth(k))
        world.advance(dt)
        if on_tick is not None:
            on_tick(t + dt, len(records))
    t_end = n_ticks * dt
    publish(t_end, keys.end, End(n_ticks, t_end, "duration reached", True))
    published = len(records)
    for n, rt in robots.items():
        records.append((int(round(t_end * 1e9)), keys.stats(n), Stats(n, 0, rt.closing_counters())))
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
    return RunResult(metrics, trace, records)
