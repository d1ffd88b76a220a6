"""The simulator node: owns time and the world, talks to the robots through a link.

The node runs over Zenoh in its own process (``main``) or on the in-memory bus of the
in-process loop (``orchestrator/run/inprocess.py``): the same lockstep protocol either way
(:class:`copath.wire.link.Link`).

``lockstep`` clock: tick k+1 starts when every live robot has answered tick k, or after
``run.tick_timeout_s``, in which case the late robot keeps its last command and the miss
is counted (and logged as an event). ``realtime`` clock: the world is integrated on the
wall clock every ``run.physics_dt``; observations and truth go out every ``run.dt``;
commands are applied when they arrive.

A robot whose liveliness token disappears (its process died) and does not come back within
``run.liveliness_grace_s`` ends the run with a failure record, so the orchestrator can report
it and the log stays readable (docs/reference/faults.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import queue
import sys
import threading
import time
from typing import Callable, Mapping

import numpy as np

from copath.occupancy import LastFormationWatch, TaskQueue, formations, queues_from_json, task_tolerance
from copath.scenario import ConfigError, Scenario, kill_tick, load_scenario
from copath.wire.cli import add_config_arguments, session_config_from_args
from copath.wire.faults import silence_outages, windows_between
from copath.wire.keys import Keys
from copath.wire.link import Link
from copath.wire.messages import Command, End, Event, Start, Stats, Telemetry

from .world import World

logger = logging.getLogger("copath.sim")

_WAKE = ("", None)
"""Put in the command queue when a robot's token goes or comes under ``continue``/``restart``:
the lockstep wait applies the change at once, not at its next 0.2 s poll. Without it a
restart from the zygote (0.2-0.3 s) could land in the same poll as the loss, and the
simulator recorded ``robot_lost`` and ``robot_rejoined`` at one instant: an outage the
team never saw (docs/reference/faults.md, "Restart")."""

__all__ = ["SimNode", "main"]


class TaskWatch:
    """``run.until = "tasks_done"``: when the truth completes the last formation of the
    task queue (Chapter 6: the robots whose controller family declares a task queue).

    A controller never grades itself: the rule is the metrics' own
    (:mod:`copath.occupancy`, docs/reference/metrics.md, tasks of Chapter 6 (M5)): the true positions occupy the targets
    the team announced for the last formation, one robot per target, within the task
    tolerance. Only the announced targets come from the robots' telemetry
    (``formation_targets``, data); the positions are the simulator's. Each robot publishes
    its telemetry before its command, so in lockstep the simulator has a tick's
    announcements when it has its commands, and the end tick is the same over Zenoh and in
    one process."""

    def __init__(self, scenario: Scenario, queues: Mapping[str, TaskQueue]) -> None:
        """``queues``: the robots' task queues as their controller families declare them
        (``ControllerFactory.tasks``). The simulator loads no controller code to ask a family:
        whoever starts it hands them over (the orchestrator; ``--tasks`` of :func:`main`)."""
        self.names = list(queues)
        self.watch = LastFormationWatch(self.names, formations(queues), task_tolerance(scenario, self.names, queues))
        self._lock = threading.Lock()  # telemetry arrives on the link's threads

    def update(self, name: str, rec: Telemetry) -> None:
        with self._lock:
            self.watch.update(name, rec.t, rec.data)

    def done(self, t: float, poses: Mapping[str, np.ndarray]) -> bool:
        """The true poses at time t complete the last formation."""
        if not self.names:
            return False
        P = np.array([poses[n][:2] for n in self.names], dtype=float)
        with self._lock:
            return self.watch.completed(t, P)


def sim_tasks(scenario: Scenario, text: str | None,
              tasks_of: Callable[[Scenario], Mapping[str, TaskQueue]] | None) -> dict[str, TaskQueue] | None:
    """The task queues a simulator process watches: from ``--tasks`` text, else from
    ``tasks_of``; a ``tasks_done`` run without either is refused (ValueError naming the key)."""
    if text is not None:
        return queues_from_json(text)
    if tasks_of is not None:
        return dict(tasks_of(scenario))
    if scenario.run.until == "tasks_done":
        raise ValueError("--tasks = None is not allowed; run.until = 'tasks_done' needs the robots' task queues "
                         "(JSON {robot: {formations, arrive_tol}}; copath run and copath sim pass them)")
    return None


class SimNode:
    def __init__(self, scenario: Scenario, keys: Keys, link: Link, start_timeout_s: float = 120.0,
                 duration_s: float | None = None, on_tick: Callable[[int], None] | None = None,
                 tasks: Mapping[str, TaskQueue] | None = None) -> None:
        """``tasks``: the robots' task queues for ``run.until = "tasks_done"`` (:class:`TaskWatch`)."""
        self.scenario = scenario
        self.keys = keys
        self.link = link
        self.duration_s = scenario.run.duration_s if duration_s is None else duration_s
        self.on_tick = on_tick
        """Called with k after each lockstep tick (progress display)."""
        self.synchronous = link.synchronous
        self._started_run = False
        self._started = False
        self.tasks = TaskWatch(scenario, tasks or {}) if scenario.run.until == "tasks_done" else None
        self.tasks_done_t: float | None = None
        """Simulated time at which the truth completed the last formation."""
        self.world = World(scenario)
        self.names = list(scenario.robot_names)
        self.start_timeout_s = start_timeout_s
        self.cmds: queue.SimpleQueue = queue.SimpleQueue()  # FIFO in C: a lock and a condition less per command
        self.alive: set[str] = set()
        self.lost: list[str] = []
        self._gone_at: dict[str, float] = {}
        self._closing = False
        """``fail``: robots whose token disappeared, when (monotonic); lost after the grace period."""
        self.policy = scenario.run.on_robot_failure
        self._wakes = scenario.run.clock == "lockstep"
        """A token's change wakes the lockstep wait (:data:`_WAKE`); the realtime loop polls."""
        self.down: set[str] = set()
        """Robots gone under ``continue`` or ``restart``: held still, not waited for."""
        self._transitions: queue.Queue = queue.Queue()
        self._declared = sorted((kill_tick(k.at_s, scenario.run.dt), k.robot) for k in scenario.run.kills
                                ) if self.policy != "fail" and scenario.run.clock == "lockstep" else []
        """Lockstep: the ticks at which the scenario's kills (``run.kills``) fall due, with their
        robot (:func:`copath.scenario.kill_tick`)."""
        self._alive_cv = threading.Condition()
        self.missed = {n: 0 for n in self.names}
        self.stale = 0
        self.overruns = 0
        self.sent: dict[str, dict[str, int]] = {}
        self._start_rec: Start | None = None
        """The run's start record, announced again to a robot that rejoins (its clock)."""
        self._cmd_at: dict[str, float] = {}
        """Realtime: simulated time of each robot's last command received."""
        self._timed_out: set[str] = set()
        """Realtime: robots stopped by the command timeout, until their next command."""
        self.command_timeouts = 0

    # -- callbacks (zenoh threads) ----------------------------------------------------
    def _on_cmd(self, key: str, rec) -> None:
        if isinstance(rec, Command):
            self.cmds.put((self.keys.relative(key).split("/")[1], rec))

    def _on_telemetry(self, key: str, rec) -> None:
        if isinstance(rec, Telemetry):
            self.tasks.update(self.keys.relative(key).split("/")[1], rec)

    def _until_reached(self) -> bool:
        """``run.until = "tasks_done"``: the margin after the tasks were done has passed."""
        if self.tasks is None:
            return False
        t = float(self.world.t)
        if self.tasks_done_t is None:
            if not self.tasks.done(t, self.world.poses):
                return False
            self.tasks_done_t = t
            self._event("tasks_done", t=t)
        return t >= self.tasks_done_t + self.scenario.run.until_margin_s - 1e-9

    def _on_alive(self, key: str, alive: bool) -> None:
        name = key.rsplit("/", 1)[-1]
        with self._alive_cv:
            if alive:
                self.alive.add(name)
                if self._gone_at.pop(name, None) is not None:
                    logger.warning("robot %s's liveliness token is back", name)
                if self._started_run and self.policy != "fail":
                    self._transitions.put((name, True))
                    if self._wakes:
                        self.cmds.put(_WAKE)
            elif name in self.alive:
                self.alive.discard(name)
                if self._started_run and not self._closing and name in self.names:
                    logger.warning("robot %s's liveliness token disappeared", name)
                if self._started_run and self.policy != "fail":
                    self._transitions.put((name, False))
                    if self._wakes:
                        self.cmds.put(_WAKE)
                elif self._started_run:  # "fail": lost unless it is back within the grace period
                    self._gone_at[name] = time.monotonic()
                # before the start a robot whose token went is simply waited for again
            self._alive_cv.notify_all()

    def _apply_transitions(self) -> None:
        """``continue``/``restart``: a robot lost is held still (zero command) and not waited
        for; one that comes back is waited for again. Both are events on the timeline."""
        while True:
            try:
                name, alive = self._transitions.get_nowait()
            except queue.Empty:
                return
            if name not in self.names:
                continue
            if alive and self._start_rec is not None:
                # a restarted process synchronises its clock on the start record, which it
                # missed: announce it again, unchanged (the others keep their first one)
                self.link.publish(self.keys.start, self._start_rec)
                logger.info("robot %s's token appeared after the start: start record announced again", name)
            if alive and name in self.down:
                self.down.discard(name)
                self._cmd_at[name] = float(self.world.t)  # the command timeout counts from its return
                self._event("robot_rejoined", robot=name)
            elif not alive and name not in self.down:
                self.down.add(name)
                self.world.command(name, [0.0] * self.scenario.robot(name).model.command_size)
                self._event("robot_lost", robot=name, policy=self.policy)

    def _declared_kills(self, k: int) -> None:
        """Lockstep: a robot whose kill falls due at tick ``k`` is down from this tick on, held
        still and named in this tick's observations (``Obs.down``), as in one process, where the
        loop closes its link between the ticks: its teammates learn of the loss at the same
        step over Zenoh as there. Without it they learned a tick later, when its token went
        after the process died on this tick's observation (docs/reference/faults.md, "When the
        others learn of a loss"). It is the token's going known ahead, queued as such for
        :meth:`_apply_transitions`: the token's own going afterwards changes nothing, a restart
        brings it back as its token comes back."""
        while self._declared and self._declared[0][0] <= k:
            self._transitions.put((self._declared.pop(0)[1], False))

    def _stop_stale(self, t: float) -> None:
        """Realtime: a robot whose base has had no command for ``run.command_timeout_s`` stops,
        as a real base's command timeout stops it (docs/reference/faults.md, "A base stops on
        stale commands"): a robot whose agent hangs keeps its liveliness, and would otherwise
        drive on its last command, blind. A robot lost is already held; one that never
        commanded has stood still since the start."""
        limit = self.scenario.run.command_timeout_s
        if limit <= 0:
            return
        for name, at in self._cmd_at.items():
            if t - at > limit and name not in self._timed_out and name not in self.down:
                self._timed_out.add(name)
                self.command_timeouts += 1
                self.world.command(name, [0.0] * self.scenario.robot(name).model.command_size)
                self._event("command_timeout", robot=name, last_command_s=round(at, 3), timeout_s=limit)
                logger.warning("robot %s: no command for %.2f s (run.command_timeout_s = %g): its base stops",
                               name, t - at, limit)

    def _event(self, what: str, **detail) -> None:
        self.link.publish(self.keys.event("sim"), Event(float(self.world.t), "sim", what, detail))

    def _fault_windows(self, t0: float, t1: float) -> str | None:
        """Partition and silence windows opening or closing in [t0, t1) go on the timeline as
        events. A radio silent for the run's lease (``run.lease_s``) is a lost
        robot under ``run.on_robot_failure``: ``fail`` returns the run's failure reason;
        ``continue`` and ``restart`` put ``robot_lost`` and, when its radio is back,
        ``robot_rejoined`` on the timeline (``cause = "silence"``). The robot is not held: its
        process is alive and its controller drives it, cut off; a restart cannot bring a
        radio back, so ``restart`` is ``continue`` here (docs/reference/faults.md)."""
        net = self.scenario.network
        for what, detail in windows_between(net, t0, t1):
            self._event(what, **detail)
        lease = self.scenario.run.lease_s
        for what, d in silence_outages(net, t0, t1, after_s=lease):
            if what == "silent" and self.policy == "fail":
                return (f"robot {d['robot']} silent since t={d['start_s']:.2f} s "
                        f"(no robot heard it for {lease:g} s)")
            self._event("robot_lost" if what == "silent" else "robot_rejoined", robot=d["robot"],
                        policy=self.policy, cause="silence", since=d["start_s"])
        return None

    def _reject_event(self, closing: bool = False) -> None:
        """At most one ``messages_rejected`` event a second (copath.wire.trust.RejectLog)."""
        log, t = self.link.reject_log, float(self.world.t)
        ev = log.flush("sim", t) if closing else log.event("sim", t, time.monotonic())
        if ev is not None:
            self.link.publish(self.keys.event("sim"), ev)

    # -- run ------------------------------------------------------------------------------
    def start(self) -> None:
        """Subscribe to the commands, watch the robots' tokens, declare the simulator's."""
        if self._started:
            return
        self._started = True
        self.link.subscribe(self.keys.all_cmds, self._on_cmd)
        if self.tasks is not None:
            for n in self.tasks.names:
                self.link.subscribe(self.keys.telemetry(n), self._on_telemetry)
        self.link.watch_liveliness(self.keys.all_alive, self._on_alive)
        self.link.declare_token(self.keys.alive("sim"))

    def run(self) -> bool:
        self.start()
        deadline = time.monotonic() + self.start_timeout_s
        told = time.monotonic()
        with self._alive_cv:
            while not set(self.names) <= self.alive:
                if time.monotonic() - told >= 5.0:  # say what it waits for, every few seconds
                    told = time.monotonic()
                    logger.info("waiting for the tokens of robots %s (%.0f s left; they build their controllers)",
                                sorted(set(self.names) - self.alive), deadline - told)
                left = deadline - time.monotonic()
                if left <= 0:
                    missing = sorted(set(self.names) - self.alive)
                    logger.error("robots %s did not come up within %.0f s", missing, self.start_timeout_s)
                    self._finish(0, f"robots {missing} did not start", False)
                    return False
                self._alive_cv.wait(timeout=min(left, 0.5))
        run = self.scenario.run
        self._started_run = True
        self._start_rec = Start(time.time(), run.dt, run.clock)
        self.link.publish(self.keys.start, self._start_rec)
        logger.info("every robot is up: run started (%s clock)", run.clock)
        if run.clock == "lockstep":
            k, ok, reason = self._lockstep()
        else:
            k, ok, reason = self._realtime()
        self._finish(k, reason, ok)
        if not ok:
            logger.error("run ended at tick %d: %s", k, reason)
        return ok

    def _lost_reason(self) -> str | None:
        """A robot whose token has been gone for ``run.liveliness_grace_s`` is lost."""
        with self._alive_cv:
            now = time.monotonic()
            for name, t in list(self._gone_at.items()):
                if now - t >= self.scenario.run.liveliness_grace_s:
                    del self._gone_at[name]
                    self.lost.append(name)
            if self.lost:
                return f"robot {self.lost[0]} lost (its process stopped)"
        return None

    def _lockstep(self) -> tuple[int, bool, str]:
        run = self.scenario.run
        n_ticks = int(round(self.duration_s / run.dt))
        for k in range(n_ticks):
            self.world.t = k * run.dt
            reason = self._fault_windows(k * run.dt, (k + 1) * run.dt)
            if reason:
                return k, False, reason
            # token changes before the observations, which say them (Obs.down): every robot
            # applies a loss at the tick the simulator applied it, in one process and over Zenoh
            self._declared_kills(k)
            self._apply_transitions()
            down = sorted(self.down)
            for n in self.names:
                self.link.publish(self.keys.obs(n), self.world.observe(n, k, self.sent, down))
            waiting = set(self.names) - self.down
            # a synchronous link has delivered every command by now: nothing to wait for
            deadline = time.monotonic() + (0.0 if self.synchronous else run.tick_timeout_s)
            while waiting:
                reason = self._lost_reason()
                if reason:
                    return k, False, reason
                self._apply_transitions()
                waiting -= self.down
                if not waiting:
                    break
                try:
                    name, cmd = self.cmds.get(timeout=min(0.2, max(0.0, deadline - time.monotonic())))
                except queue.Empty:
                    if time.monotonic() >= deadline:
                        for n in sorted(waiting):
                            self.missed[n] += 1
                            self._event("missed_tick", robot=n, k=k)
                        break
                    continue
                if cmd is None:  # woken by a robot's token going or coming (_WAKE): apply it, wait on
                    continue
                if cmd.k != k or name not in waiting or name in self.down:
                    self.stale += 1
                    continue
                self.world.command(name, cmd.cmd)
                self.sent[name] = cmd.sent
                waiting.discard(name)
            self.world.saturate_all()
            self.link.publish(self.keys.truth, self.world.truth(k))
            self._reject_event()
            done = self._until_reached()
            self.world.advance(run.dt)
            if self.on_tick is not None:
                self.on_tick(k)
            if done:
                return k + 1, True, "tasks done"
        return n_ticks, True, "duration reached"

    def _realtime(self) -> tuple[int, bool, str]:
        run = self.scenario.run
        # a starved agent loses old observations instead of stalling the router
        self.link.drop_when_congested(self.keys.obs("*"))
        t0 = time.monotonic()
        next_obs = 0.0
        k = 0
        t = 0.0
        while t < self.duration_s - 1e-9:
            reason = self._lost_reason()
            if reason:
                return k, False, reason
            self._apply_transitions()
            while True:
                try:
                    name, cmd = self.cmds.get_nowait()
                except queue.Empty:
                    break
                self.world.command(name, cmd.cmd)
                self._cmd_at[name] = t
                self._timed_out.discard(name)
            if t >= next_obs - 1e-9:
                self._stop_stale(t)
                reason = self._fault_windows(next_obs, next_obs + run.dt)
                if reason:
                    return k, False, reason
                for n in self.names:
                    self.link.publish(self.keys.obs(n), self.world.observe(n, k))
                self.world.saturate_all()
                self.link.publish(self.keys.truth, self.world.truth(k))
                self._reject_event()
                k += 1
                next_obs += run.dt
                if self._until_reached():
                    return k, True, "tasks done"
            self.world.advance(run.physics_dt)
            t = self.world.t
            sleep = t0 + t - time.monotonic()
            if sleep > 0:
                time.sleep(sleep)
            else:
                self.overruns += 1
        return k, True, "duration reached"

    def _finish(self, k: int, reason: str, ok: bool) -> None:
        self._closing = True
        self._reject_event(closing=True)
        self.link.publish(self.keys.end, End(k, float(self.world.t), reason, ok))
        counters = {"missed_ticks": self.missed, "stale_commands": self.stale, "physics_overruns": self.overruns, "rejects": self.link.rejects,
                    "command_timeouts": self.command_timeouts}
        cpu = os.times()
        counters["cpu_s"] = round(cpu.user + cpu.system, 3)  # this process (in-process runs: the whole run)
        self.link.publish(self.keys.stats("sim"), Stats("sim", self.link.published, counters))


def main(argv: list[str] | None = None,
         tasks_of: Callable[[Scenario], Mapping[str, TaskQueue]] | None = None) -> int:
    """The simulator process. ``run.until = "tasks_done"`` needs the robots' task queues, which
    their controller families declare: ``--tasks`` gives them (``copath run`` passes it), else
    ``tasks_of(scenario)`` asks the families (``copath sim`` passes the registry's)."""
    p = argparse.ArgumentParser(prog="copath sim", description="Run the simulator process of a copath run.")
    p.add_argument("--run-id", required=True)
    p.add_argument("--config", required=True, help="scenario file (.toml, or the run's scenario.json)")
    p.add_argument("--tasks", default=None,
                   help="the robots' task queues for run.until = 'tasks_done', JSON {robot: {formations, arrive_tol}} "
                        "(copath run passes it)")
    p.add_argument("--start-timeout", type=float, default=120.0, help="seconds to wait for every robot [120]")
    p.add_argument("-v", "--verbose", action="store_true")
    add_config_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s sim %(levelname)s %(message)s")
    try:
        scenario = load_scenario(args.config)
        keys = Keys(args.run_id)
        conf = dataclasses.replace(session_config_from_args(args), lease_ms=round(1e3 * scenario.run.lease_s))
        tasks = sim_tasks(scenario, args.tasks, tasks_of)
    except (ConfigError, ValueError) as exc:
        print(f"copath sim: {exc}", file=sys.stderr)
        return 2
    from copath.wire.acl import AccessDenied, AccessPolicy  # noqa: PLC0415
    from copath.wire.session import ZenohLink  # noqa: PLC0415

    with ZenohLink.open(conf) as link:
        link.sender = "sim"  # in every record's attachment (the recorder's accounts)
        if conf.authenticated:  # behind a secure router: step outside the grants and fail at once
            link.guard(AccessPolicy.for_scenario(keys, scenario), "sim")
        try:
            ok = SimNode(scenario, keys, link, args.start_timeout, tasks=tasks).run()
        except AccessDenied as exc:
            print(f"copath sim: {exc}", file=sys.stderr)
            return 2
        time.sleep(0.2)  # let the router forward the closing records before the session closes
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
