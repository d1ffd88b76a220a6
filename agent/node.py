"""One robot: link in -> controller step -> link out.

The node talks through a :class:`copath.wire.link.Link`: over Zenoh in its own process
(``main``), or on an in-memory bus inside the in-process loop
(``orchestrator/run/inprocess.py``), where a synchronous link runs each lockstep step inside
the observation's delivery. The node subscribes only to its own observation key and its neighbours' message keys
(every robot's on a range-limited graph, where its runtime drops what comes from beyond
range), declares a liveliness token once it is ready, and then:

- ``lockstep``: steps once per observation, at the observation's time;
- ``realtime``: steps on its own timer at ``1/run.dt`` with the newest observation and
  the wall clock synchronised once at start (``sim/start``), like the dissertation's
  robots.

Peer messages are published before the command of the same step, so in lockstep they
reach the router before the simulator can start the next tick. The lockstep barrier is
event-driven: the step waits on a condition the peer callback signals, not a sleep loop.

Every received record goes through one callback per record type (``_on_obs``,
``_on_peer``, ``_on_overheard``, ``_on_sim``), the place for receiver-side checks.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import logging
import os
import queue
import signal
import sys
import threading
import time
from typing import Callable, NamedTuple

from copath.scenario import ConfigError, load_scenario
from copath.wire.cli import add_config_arguments, session_config_from_args
from copath.wire.keys import Keys
from copath.wire.link import Link, key_matches
from copath.wire.messages import Command, End, Event, Obs, PeerEnvelope, Start, Stats
from copath.wire.trust import relative_key

from .runtime import RobotRuntime

logger = logging.getLogger("copath.agent")


class _Refused(NamedTuple):
    """A refused record on ``sender``'s peer key, queued with the peer messages (the barrier)."""

    sender: str


__all__ = ["AgentNode", "main"]


class AgentNode:
    def __init__(self, runtime: RobotRuntime, keys: Keys, link: Link, clock: str,
                 die: Callable[[], None] | None = None) -> None:
        """``die``: how this process dies at the scenario's kills of its robot (``run.kills``; a
        fleet's agent: SIGKILL of itself). In one process the loop closes the robot's link at
        the same tick instead (:func:`orchestrator.run.inprocess.run_scenario`)."""
        self.rt = runtime
        self.keys = keys
        self.link = link
        self.clock = clock
        self.inline = link.synchronous and clock == "lockstep"
        """Step inside the observation's delivery (a synchronous link, lockstep)."""
        self.obs_q: queue.Queue = queue.Queue()
        self.latest_obs: Obs | None = None
        self.peers: collections.deque = collections.deque()
        self.overheard: collections.deque = collections.deque()  # for the safety filter
        self._awaits_overheard = runtime.awaits_overheard  # the filter overhears: the barrier counts them too
        self.started = threading.Event()
        self.ended = threading.Event()
        self.wall_t0 = 0.0
        self.barrier_timeout_s = 5.0
        self._arrived = threading.Condition()  # signalled by every peer message (the barrier)
        self._finished = False
        self._ages: list[float] = []  # realtime: neighbour message age on arrival [s]
        # one count of rejects per process: the runtime's stamp checks count into the link's log
        runtime.count_rejects_in(link.reject_log)
        self.end_grace_s = 2.0
        """An ``End`` is honoured when the simulator's token goes (it exits after it) or
        when no newer observation follows within this time; an observation after it
        proves it forged (docs/reference/faults.md)."""
        self._end_at: float | None = None
        self.watchdog_s = runtime.scenario.run.watchdog_s
        """No observation for this long: command zero velocity and say so (0: off)."""
        self._heard = time.monotonic()
        self._tripped = False
        self.liveliness_grace_s = runtime.scenario.run.liveliness_grace_s
        self._sim_gone_at: float | None = None
        self._cpu_at_start = 0.0
        self._barrier = True
        self.process_start = time.time() if link.synchronous else process_start_time()
        """Wall time [s] this process started (a fork of the zygote: the fork; in one
        process, where a restart is a new node: the node's creation)."""
        self.joined_late = False
        """The run had started before this process: a restart (``run.on_robot_failure``)."""
        self._first_step_logged = False
        self._die = die
        run = runtime.scenario.run
        self._kills = sorted(k.due_s(run.dt) for k in run.kills if k.robot == runtime.name) if die else []
        """Observation times from which this robot's declared kills are due: the first
        observation after ``at_s`` (the one-process loop's tick, :func:`orchestrator.run.inprocess.run_scenario`)."""
        self._first_obs_t: float | None = None
        self._down_from_obs = False
        """Lockstep: the observations say who is down (``Obs.down``); the token watch is left alone."""

    # -- receive: one callback per record type (link threads, or inline) -------------
    def _kill_due(self, t: float) -> bool:
        """A declared kill falls due at an observation of time ``t``: this process was running
        before it (a process restarted after a kill is not killed by it again, only by a later one)."""
        if self._first_obs_t is None:
            self._first_obs_t = t
        return self._kill_by(t) is not None

    def _kill_by(self, t: float) -> float | None:
        """Realtime: the run time of a declared kill due by run time ``t`` (the earliest), for a
        process that was running before it; None if there is none."""
        if self._first_obs_t is None:
            return None
        due = [d for d in self._kills if self._first_obs_t < d <= t]
        return min(due) if due else None

    def _on_obs(self, key: str, rec) -> None:
        if isinstance(rec, Obs):
            if self._kills and self._kill_due(rec.t):
                logger.warning("robot %s: killed at sim t=%.2f s (run.kills)", self.rt.name, rec.t)
                self._die()  # a fleet's agent: SIGKILL, nothing after it runs
                return
            if self._end_at is not None:  # the simulator is still running: that End was forged
                self._end_at = None
                self.rt.reject_log.add(self.keys.end, "an end record followed by observations (not the simulator's)")
            self.latest_obs = rec
            self._heard, self._tripped = time.monotonic(), False
            if self.inline:
                self._lockstep_step(rec)
            else:
                self.obs_q.put(rec)

    def _on_peer(self, key: str, rec) -> None:
        if isinstance(rec, PeerEnvelope):
            self.peers.append(rec)
            if self.clock == "realtime" and self.started.is_set() and self.rt.listens_to(rec.sender):  # stamp to arrival
                self._ages.append(time.time() - self.wall_t0 - rec.stamp)
            if not self.inline:
                with self._arrived:
                    self._arrived.notify()

    def _on_peer_refused(self, key: str, error: str) -> None:
        """The link refused a record on a peer key this robot listens to (NaN in a payload,
        a record that does not decode): the barrier counts it as delivered-and-dropped for
        the sender its key names (``peer/<sender>/all``, ``peer/<sender>/to/<me>``), so it
        does not wait for it. Only the key can say who sent it; on an open bus a stranger
        can publish on any key, as it can publish well-formed messages (docs/reference/faults.md)."""
        rel = relative_key(key)
        if len(rel) >= 3 and rel[0] == "peer":
            self.peers.append(_Refused(rel[1]))
            if not self.inline:
                with self._arrived:
                    self._arrived.notify()

    def _on_overheard_refused(self, key: str, error: str) -> None:
        also_peer = self._also_peer_key(key)
        if also_peer:  # the peer copy first (:meth:`_on_overheard_or_peer`)
            self._on_peer_refused(key, error)
        if self._awaits_overheard:  # arrived, for a barrier that waits for every overheard message
            rel = relative_key(key)
            if len(rel) >= 3 and rel[0] == "peer":
                self.overheard.append(_Refused(rel[1]))
            if not also_peer and not self.inline:
                with self._arrived:
                    self._arrived.notify()

    def _also_peer_key(self, key: str) -> bool:
        """Whether an overheard ``key`` also goes the peer way (:meth:`_on_peer`): a key this robot
        subscribes to as a peer, or, on a fixed graph, any robot's broadcast or message to this
        one, which the runtime counts for the barrier and passes on while that robot stands in
        for a lost neighbour (:attr:`RobotRuntime.stand_ins`; docs/reference/faults.md,
        "Stand-ins for a lost neighbour")."""
        hit = self._also_peer.get(key)
        if hit is None:
            rel = relative_key(key)
            hit = self._also_peer[key] = (
                any(key_matches(key, e) for e in self._peer_exprs)
                or (self.rt.hears_stand_ins and len(rel) >= 3 and rel[0] == "peer"
                    and (rel[2:] == ["all"] or rel[2:] == ["to", self.rt.name])))
        return hit

    def _on_overheard(self, key: str, rec) -> None:
        if isinstance(rec, PeerEnvelope):
            self.overheard.append(rec)
            if self._awaits_overheard and not self.inline:  # the barrier waits for it too
                with self._arrived:
                    self._arrived.notify()

    def _on_overheard_or_peer(self, key: str, rec) -> None:
        """One message for both ways: the peer copy is queued before the overheard one, and
        :meth:`_drain_peers` takes the overheard queue before the peer queue, so a message the
        barrier has counted as overheard has its peer copy received in the same drain. In the
        other order a step could count the overheard copy, find nothing missing and step while
        the peer copy was still being queued: the controller got it a tick late (a lockstep E5.5
        run with 100 ms delay left the in-process run at t = 0.1 s, CI 2026-12-04;
        docs/reference/faults.md, "Overheard messages and the lockstep barrier")."""
        if self._also_peer_key(key):
            self._on_peer(key, rec)
        self._on_overheard(key, rec)

    def _on_sim(self, key: str, rec) -> None:
        if isinstance(rec, Start):
            if self.started.is_set():  # announced again for a robot that rejoined: the first one holds
                return
            cpu = os.times()
            self._cpu_at_start = cpu.user + cpu.system
            self.wall_t0 = rec.wall_t0
            self.joined_late = rec.wall_t0 < self.process_start - 0.5
            self.rt.joined = self.joined_late
            self.started.set()
            logger.info("synchronised on the start record: run time %.2f s%s, %.2f s after the process started",
                        time.time() - rec.wall_t0, " (joining a run in progress)" if self.joined_late else "",
                        time.time() - self.process_start)
        elif isinstance(rec, End):
            if not self.inline:
                self._end_at = time.monotonic()  # honoured by _end_due
                return
            self.ended.set()
            self.obs_q.put(None)
            self.finish()

    def _end_due(self) -> bool:
        """An End arrived and no observation followed within ``end_grace_s``, or the
        simulator's token has been gone for ``liveliness_grace_s``."""
        if self._end_at is not None and time.monotonic() - self._end_at > self.end_grace_s:
            self.ended.set()
        gone = self._sim_gone_at
        if gone is not None and not self.ended.is_set() and time.monotonic() - gone >= self.liveliness_grace_s:
            self._sim_went_away()
        return self.ended.is_set()

    def _on_robot_alive(self, key: str, alive: bool) -> None:
        name = key.rsplit("/", 1)[-1]
        # in lockstep the simulator's observations say who is down (Obs.down), at the tick it
        # applied the change; this watch, as it happens, would be a step early or late by chance
        if name in self.rt.scenario.robot_names and not self._down_from_obs:
            self.rt.peer_alive(name, alive)

    def _watchdog(self) -> None:
        """Heard nothing from the simulator for ``watchdog_s``: stop the robot (a zero
        command) and say so, once until the next observation (docs/reference/faults.md)."""
        obs = self.latest_obs
        if self.watchdog_s <= 0 or obs is None or self._tripped or self.ended.is_set():
            return
        silent = time.monotonic() - self._heard
        if silent < self.watchdog_s:
            return
        self._tripped = True
        name = self.rt.name
        logger.warning("heard nothing from the simulator for %.1f s; commanding zero velocity", silent)
        self.link.publish(self.keys.cmd(name), Command(obs.k, float(obs.t), [0.0] * self.rt.command_size, 0.0,
                                                       dict(self.rt.sent)))
        self.link.publish(self.keys.event(name), Event(float(obs.t), name, "watchdog",
                                                       {"silent_s": round(silent, 3), "k": obs.k,
                                                        "command": "zero velocity"}))
        self.rt.counters.extra["watchdog_stops"] = self.rt.counters.extra.get("watchdog_stops", 0) + 1

    def _on_sim_alive(self, key: str, alive: bool) -> None:
        """The simulator's token went: stop, unless it is back within ``run.liveliness_grace_s``
        (a transport reset under CPU starvation drops every token this process sees, and the
        session reconnects; docs/reference/faults.md). ``_end_due`` acts on it."""
        if alive:
            if self._sim_gone_at is not None:
                logger.warning("the simulator's liveliness token is back after %.2f s",
                               time.monotonic() - self._sim_gone_at)
            self._sim_gone_at = None
            return
        if self.ended.is_set():
            return
        self._sim_gone_at = time.monotonic()
        if self.liveliness_grace_s > 0:
            if self._end_at is None:  # after the end record its exit is expected
                logger.warning("the simulator's liveliness token disappeared; waiting %.1f s for it",
                               self.liveliness_grace_s)
            return
        self._sim_went_away()

    def _sim_went_away(self) -> None:
        logger.error("the simulator went away; stopping")
        self.ended.set()
        self.obs_q.put(None)
        with self._arrived:
            self._arrived.notify()

    def _await_peers(self, obs: Obs) -> None:
        """Lockstep barrier: wait until every message the neighbours sent by the end of
        the previous tick has arrived (``Obs.expect``), so runs are deterministic. The
        wait sleeps on a condition that each arriving peer message signals. A message the
        receiver refused has arrived too (delivered-and-dropped, :meth:`_on_peer_refused`):
        it is not waited for (docs/reference/faults.md, "Rejected messages and the lockstep barrier")."""
        self._drain_peers()
        if not self.rt.missing(obs.expect):
            return
        deadline = time.monotonic() + self.barrier_timeout_s
        while True:
            with self._arrived:
                if not self.peers and not (self._awaits_overheard and self.overheard):
                    left = deadline - time.monotonic()
                    if left <= 0 or self.ended.is_set() or self.inline:
                        late = self.rt.write_off(obs.expect, float(obs.t))
                        self.rt.counters.add("barrier_timeouts")
                        self.rt.counters.add("barrier_written_off", sum(late.values()))
                        logger.warning("tick %d: still missing peer messages %s; stepping without them "
                                       "(written off as lost)", obs.k, late)
                        return
                    self._arrived.wait(timeout=left)
            self._drain_peers()
            if not self.rt.missing(obs.expect):
                return

    def _newest_obs(self) -> Obs | None:
        """Realtime: the newest observation, carrying the sensor measurements of every
        observation since the previous step (``[sensing]``: none is lost; one seen twice
        is ignored by the estimator)."""
        got = []
        while True:
            try:
                o = self.obs_q.get_nowait()
            except queue.Empty:
                break
            if o is not None:
                got.append(o)
        if len(got) < 2 or got[-1].meas is None:
            return got[-1] if got else self.latest_obs
        merged = {k: [row for o in got if o.meas for row in o.meas.get(k, [])] for k in ("odom", "fixes", "headings")}
        return dataclasses.replace(got[-1], meas=merged)

    def _drain_peers(self) -> None:
        """Hand what arrived to the runtime: the overheard queue first, then the peer queue
        (the order :meth:`_on_overheard_or_peer` relies on; the link's threads append while this runs)."""
        while self.overheard:
            env = self.overheard.popleft()
            if type(env) is _Refused:
                self.rt.overheard_refused(env.sender)
            else:
                self.rt.overhear(env)
        while self.peers:
            env = self.peers.popleft()
            if type(env) is _Refused:
                self.rt.refused(env.sender)
            else:
                self.rt.receive(env)

    def _first_step(self, obs: Obs, now: float) -> None:
        """Say when this process first stepped; a robot that joined a run in progress also
        puts it on the timeline (``rejoined_stepping``: seconds from its process start to
        its first command, docs/reference/faults.md)."""
        self._first_step_logged = True
        since = time.time() - self.process_start
        # realtime: the start record is older than the process; lockstep: a first tick after 0
        late = self.joined_late if self.clock == "realtime" else obs.k > 0
        logger.info("first step at run time %.2f s (tick %d), %.2f s after the process started%s", now, obs.k, since,
                    "; rejoined a run in progress" if late else "")
        if late:
            self.link.publish(self.keys.event(self.rt.name), Event(
                float(now), self.rt.name, "rejoined_stepping",
                {"k": obs.k, "since_process_start_s": round(since, 3), "pid": os.getpid()}))

    def _emit(self, out) -> None:
        name = self.rt.name
        for key, env in out.peers:
            self.link.publish(key, env)
        # telemetry before the command: a simulator ending on reported tasks
        # (run.until = "tasks_done") has a tick's reports when it has its commands
        self.link.publish(self.keys.telemetry(name), out.telemetry)
        if out.estimate is not None:
            self.link.publish(self.keys.estimate(name), out.estimate)
        self.link.publish(self.keys.cmd(name), out.command)
        for ev in out.events:
            self.link.publish(self.keys.event(name), ev)
        ev = self.rt.reject_log.event(name, out.command.t, time.monotonic())
        if ev is not None:
            self.link.publish(self.keys.event(name), ev)

    def _lockstep_step(self, obs: Obs) -> None:
        if self.rt.counters.steps == 0 and obs.k > 0:
            # a robot restarted mid-run (run.on_robot_failure = "restart"): messages sent
            # while it was away or starting are gone, so the barrier's counts cannot be met;
            # it steps on what has arrived (the run is no longer deterministic anyway)
            self._barrier = False
            self.rt.joined = True
            logger.info("joined at tick %d: stepping without the lockstep barrier", obs.k)
        if not self._barrier:
            self._drain_peers()
        else:
            self._await_peers(obs)
        if obs.down is not None:
            self._down_from_obs = True
            self.rt.tokens_down(obs.down)
        self._emit(self.rt.step(obs, obs.t))
        if not self._first_step_logged:
            self._first_step(obs, obs.t)

    def start(self) -> None:
        """Subscribe, then declare the liveliness token (ready). With a synchronous link
        this is all: the node then steps inside each observation's delivery and sends its
        closing account when the run's end arrives."""
        name = self.rt.name
        self.link.subscribe(self.keys.obs(name), self._on_obs)
        peer, over = list(self.rt.subscriptions), list(self.rt.overhear_subscriptions)
        # one subscription (one decode) per message: a peer key the overheard keys cover is
        # received through them and handed to both callbacks (docs/reference/performance.md, the Link interface (P2))
        self._peer_exprs = peer
        self._also_peer: dict[str, bool] = {}
        for key in over:
            self.link.subscribe(key, self._on_overheard_or_peer, on_reject=self._on_overheard_refused)
        for key in peer:
            if not any(key_matches(key.replace("*", "_"), e) for e in over):
                self.link.subscribe(key, self._on_peer, on_reject=self._on_peer_refused)
        self.link.subscribe(self.keys.start, self._on_sim)
        self.link.subscribe(self.keys.end, self._on_sim)
        self.link.watch_liveliness(self.keys.alive("sim"), self._on_sim_alive)
        self.link.watch_liveliness(self.keys.all_alive, self._on_robot_alive)
        self.link.declare_token(self.keys.alive(name))  # ready: subscriptions are in place
        logger.info("ready (%s clock, pid %d, %.2f s after the process started): liveliness token declared, "
                    "waiting for the simulator", self.clock, os.getpid(), time.time() - self.process_start)

    def run(self) -> None:
        """Start and serve the run on this thread until it ends (threaded links)."""
        self.start()
        if self.clock == "lockstep":
            waited = told = time.monotonic()
            while True:
                try:
                    obs = self.obs_q.get(timeout=0.25)
                except queue.Empty:
                    if self._end_due():
                        break
                    self._watchdog()
                    if self.latest_obs is None and time.monotonic() - told >= WAIT_LOG_S:  # say what it waits for
                        told = time.monotonic()
                        logger.warning("no observation yet after %.0f s (waiting on %s; the simulator starts the "
                                       "run when every robot's token is up)", told - waited, self.keys.obs(self.rt.name))
                    continue
                if obs is None:
                    break
                self._lockstep_step(obs)
        else:
            # realtime: the newest broadcast matters, a starved receiver loses old ones
            self.link.drop_when_congested(self.keys.peer_broadcast(self.rt.name),
                                          self.keys.peer_direct(self.rt.name, "*"))
            _yield_to_simulator()
            waited, told = time.monotonic(), time.monotonic()
            while not self.started.wait(timeout=0.5):
                if self._end_due():
                    break
                if time.monotonic() - told >= WAIT_LOG_S:  # say what it waits for, every few seconds
                    told = time.monotonic()
                    logger.warning("still waiting for the simulator's start record (%s) after %.0f s%s",
                                   self.keys.start, told - waited,
                                   "" if self.latest_obs is None else
                                   f"; observations arrive (tick {self.latest_obs.k})")
            period = self.rt.dt
            next_t = time.time()
            extra = self.rt.counters.extra
            extra.setdefault("deadline_misses", 0)  # periods whose step ended after the next period began
            extra.setdefault("realtime_periods", 0)
            while not self._end_due():
                extra["realtime_periods"] += 1
                self._watchdog()
                obs = self._newest_obs()
                if obs is not None and self._end_at is None:  # no step while an End awaits confirmation
                    self._drain_peers()
                    now = time.time() - self.wall_t0
                    out = self.rt.step(obs, now)
                    # the timing account so far, on every step: a process killed before its
                    # closing account leaves it in the log all the same (docs/reference/faults.md)
                    out.telemetry.data["deadline_misses"] = extra["deadline_misses"]
                    out.telemetry.data["realtime_periods"] = extra["realtime_periods"]
                    self._emit(out)
                    if not self._first_step_logged:
                        self._first_step(obs, now)
                next_t += period
                due = self._kill_by(next_t - self.wall_t0) if self._kills else None
                if due is not None:
                    # a declared kill falls due before the next step: die at its time on the run's
                    # clock (at_s + dt/2), between the steps as in lockstep, not on the observation
                    # after it, a period late (docs/reference/faults.md, "A kill declared in the scenario")
                    if not self.ended.wait(timeout=max(0.0, self.wall_t0 + due - time.time())):
                        logger.warning("robot %s: killed at run time %.2f s (run.kills)", self.rt.name,
                                       time.time() - self.wall_t0)
                        self._die()  # SIGKILL: nothing after it runs
                sleep = next_t - time.time()
                if sleep > 0:
                    self.ended.wait(timeout=sleep)
                else:
                    extra["deadline_misses"] += 1
                    next_t = time.time()
        self.finish()

    def finish(self) -> None:
        """Publish the closing account (once)."""
        if self._finished:
            return
        self._finished = True
        ev = self.rt.reject_log.flush(self.rt.name, self.rt.now)
        if ev is not None:
            self.link.publish(self.keys.event(self.rt.name), ev)
        counters = self.rt.closing_counters()
        counters["rejects"] = self.link.rejects  # the runtime's stamp rejects are in the link's log
        counters["peak_rss_mb"] = _peak_rss_mb()
        cpu = os.times()
        counters["cpu_s"] = round(cpu.user + cpu.system, 3)  # the whole process: start-up, Zenoh's threads
        if self.started.is_set():
            counters["cpu_run_s"] = round(cpu.user + cpu.system - self._cpu_at_start, 3)  # from the start record
        if self._ages:
            ages = sorted(self._ages)
            for q in (50, 99):
                counters[f"peer_age_ms_p{q}"] = round(1e3 * ages[min(len(ages) - 1, int(q / 100 * len(ages)))], 4)
            counters["peer_age_ms_max"] = round(1e3 * ages[-1], 4)
        self.link.publish(self.keys.stats(self.rt.name), Stats(self.rt.name, self.link.published, counters))


WAIT_LOG_S = 5.0
"""A node waiting for something it has not got says so this often [s]."""


def process_start_time() -> float:
    """Wall time [s] this process started, from ``/proc`` (Linux; elsewhere: now)."""
    try:
        with open("/proc/self/stat") as fh:  # field 22: start time after boot, in clock ticks
            ticks = int(fh.read().rsplit(")", 1)[1].split()[19])
        return time.time() - (time.clock_gettime(time.CLOCK_BOOTTIME) - ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError, AttributeError):
        return time.time()


REALTIME_NICE = 15
"""Realtime: agents lower their scheduling priority by this much (``os.nice``) so that on a
busy machine the simulator's 100 Hz physics and the router and recorder are served first
(docs/journal/performance.md, goals measured and realtime at 128 robots (P9-P10): at 128 robots 5 was not enough); 0 leaves it."""


def _yield_to_simulator() -> None:
    if REALTIME_NICE > 0 and hasattr(os, "nice"):
        try:
            os.nice(REALTIME_NICE)
        except OSError:  # not allowed here: run at the default priority
            pass


def _peak_rss_mb() -> float | None:
    """Peak resident memory of this process [MB] (in-process runs share one process).

    Linux's ``VmHWM``: ``getrusage``'s ``ru_maxrss`` survives ``exec`` and so would report
    the spawning orchestrator's memory for a small agent."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024.0, 1)
    except (OSError, ValueError, IndexError):
        pass
    return None


PRELOADED: dict[str, object] = {}
"""Scenarios already parsed by the process that forked this one (``agent/zygote.py``), by path."""


def _sigkill_self() -> None:
    """The scenario's kill of this robot (``run.kills``): SIGKILL, as an operator's ``kill -9``
    or a power cut: no closing account, no goodbye; the transport closes with the process and
    the robot's liveliness token goes (docs/reference/faults.md, "A kill declared in the scenario")."""
    for h in logging.getLogger().handlers:  # the warning above reaches the robot's log first
        h.flush()
    os.kill(os.getpid(), signal.SIGKILL)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="copath agent", description="Run one robot of a copath run.")
    p.add_argument("--run-id", required=True)
    p.add_argument("--robot", required=True, help="robot name in the scenario")
    p.add_argument("--config", required=True, help="scenario file (.toml, or the run's scenario.json)")
    p.add_argument("--io", choices=("zenoh", "ros2"), default="zenoh",
                   help="ros2: the robot's own odometry and cmd_vel on this computer, no bridge hop (docs/reference/ros2.md)")
    p.add_argument("-v", "--verbose", action="store_true")
    add_config_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format=f"%(asctime)s {args.robot} %(levelname)s %(message)s")
    logger.info("started: robot %s of run %s, pid %d", args.robot, args.run_id, os.getpid())
    try:
        scenario = PRELOADED.get(args.config) or load_scenario(args.config)
        keys = Keys(args.run_id)
        scenario.robot(args.robot)
        if args.io == "ros2":  # one line when ROS 2 or the scenario does not allow it (agent/io_ros2.py)
            from .io_ros2 import problem

            if (why := problem(scenario, args.robot)) is not None:
                raise ConfigError(why)
            if any(k.robot == args.robot for k in scenario.run.kills):
                raise ConfigError(f"run.kills names robot {args.robot!r}, whose agent drives it over ROS 2 itself "
                                  "(--io ros2): a declared kill applies to agents over Zenoh only; kill the process "
                                  "yourself, or leave the robot out of run.kills")
        conf = dataclasses.replace(session_config_from_args(args), lease_ms=round(1e3 * scenario.run.lease_s))
        runtime = RobotRuntime(scenario, args.robot, keys)  # builds the controller (and solvers) once
    except (ConfigError, ValueError) as exc:
        print(f"copath agent: {exc}", file=sys.stderr)
        return 2
    from copath.wire.acl import AccessDenied, AccessPolicy  # noqa: PLC0415
    from copath.wire.session import ZenohLink  # noqa: PLC0415  (the in-process loop opens no session)

    with ZenohLink.open(conf) as link:
        link.sender = args.robot  # in every record's attachment (the recorder's accounts)
        link.local_delivery = False  # its own broadcast is not decoded by its own peer/*/all subscriber
        if conf.authenticated:  # behind a secure router: step outside the grants and fail at once
            link.guard(AccessPolicy.for_scenario(keys, scenario), args.robot)
        try:
            if args.io == "ros2":
                from .io_ros2 import run as run_with_ros2

                run_with_ros2(runtime, keys, link, scenario.run.clock)
            else:
                AgentNode(runtime, keys, link, scenario.run.clock, die=_sigkill_self).run()
        except AccessDenied as exc:
            print(f"copath agent: {exc}", file=sys.stderr)
            return 2
        time.sleep(0.2)  # let the router forward the closing record before the session closes
    return 0


if __name__ == "__main__":
    sys.exit(main())
