"""One robot's runtime around its controller: inbox, faults, range filter, envelopes.

:class:`RobotRuntime` is transport-free: the agent process (``agent/node.py``) feeds it
records received over Zenoh, and the in-process loop (``orchestrator/run/inprocess.py``)
feeds it directly, so both run the exact same logic:

1. peer envelopes go through the receiver-side fault layer (``copath.wire.faults``);
2. at a control instant, released messages from beyond the communication range are
   dropped (Def. 10: the sender's position travels in the envelope, no oracle);
3. the controller steps; an exception inside it (or an invalid command) is counted and
   the robot stops for that step (it never kills the process); the first one per robot is
   logged with its traceback and published as a ``controller_error`` event; a robot that
   has lost every other robot (cut off: its own radio most likely went quiet) commands
   zero until it hears one again, unless its controller handles that itself
   (``handles_cut_off``; docs/reference/faults.md, "Gone quiet");
4. with ``[safety]`` on, the command passes the decentralised safety filter
   (``copath.safety``), fed with the sender positions of every peer envelope the robot
   overhears (:attr:`RobotRuntime.overhear_subscriptions`, its own fault streams and the
   range filter; the controller's inbox is not touched);
5. its outgoing messages become envelopes on the sender's keys.
"""

from __future__ import annotations

import logging
import math
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from agent.controllers import build_controller, resolve_controller
from copath.config import ConfigError
from copath.control import Observation, PeerMessage, RobotContext
from copath.detour import DetourPlanner
from copath.estimation import PoseEKF
from copath.paths import wrap_to_pi
from copath.models import limit_change, world_velocity
from copath.safety import SafetyGuard
from copath.scenario import Scenario
from copath.wire.faults import FaultyInbox, LinkFaults
from copath.wire.keys import Keys
from copath.wire.messages import Command, Estimate, Event, Obs, PeerEnvelope, Telemetry, WireError, to_plain
from copath.wire.trust import RejectLog, StampWindow

logger = logging.getLogger(__name__)

_OVERHEAR_SEED = 7919
"""Offset of the seed of the safety filter's own fault streams (independent of the controller's)."""

_ERROR_CHARS = 300
"""An exception's message is cut to this length in the ``controller_error`` event."""
_TRACEBACK_CHARS = 6000
"""The traceback in the ``controller_error`` event keeps its last this many characters."""

__all__ = ["RobotRuntime", "StepOutput", "handles_cut_off", "handles_obstacles", "sensor_angles", "silent_hold_s"]


def silent_hold_s(scenario: Scenario) -> float:
    """The latest a robot gone quiet holds itself still, after the stamp of its last message
    heard [s] (docs/reference/safety.md, "A lost robot"): its radio went quiet within one period after
    that stamp; the last message it received arrived within the network's largest delay
    (``delay_ms`` + ``jitter_ms``) after that and was read at its next step; it is cut off at
    the first step more than one lease (``run.lease_s``) later."""
    net, dt = scenario.network, scenario.run.dt
    return float(scenario.run.lease_s) + (net.delay_ms + net.jitter_ms) * 1e-3 + 3.0 * dt


def handles_cut_off(scenario: Scenario, name: str) -> bool:
    """Whether robot ``name``'s controller handles being cut off itself: its parameter
    dataclass says so (``handles_cut_off = True``, a class constant; the roles controller,
    docs/reference/ambiguities.md, robot lost in role assignment (A38)). Read from the scenario, so every robot knows it of every other;
    the class is enough (parsing every robot's parameters cost each runtime 0.46 ms per role
    robot, N^2 over a fleet)."""
    try:
        factory = resolve_controller(scenario.robot(name).controller)
    except ConfigError:  # reported where that robot's controller is built
        return False
    return bool(getattr(factory.config, "handles_cut_off", False))


def handles_obstacles(scenario: Scenario, name: str) -> bool:
    """Whether robot ``name``'s controller avoids obstacles itself (``handles_obstacles = True``
    on its parameter class: the unicycle NMPC's constraints, Sec. 4.4.3); the runtime's detour
    stage then leaves it alone (docs/reference/detours.md)."""
    try:
        factory = resolve_controller(scenario.robot(name).controller)
    except ConfigError:
        return False
    return bool(getattr(factory.config, "handles_obstacles", False))


def detour_planner(scenario: Scenario, name: str) -> DetourPlanner | None:
    """The detour stage of robot ``name`` (docs/reference/detours.md): one for every robot that follows a
    path (its own, or, for a robot without one such as a Sec. 5.5.5 follower, the one path
    its team's robots follow) with a controller that does not avoid obstacles itself; None
    otherwise (Chapter 6 roles, the unicycle NMPC)."""
    if not scenario.safety.detours:  # [safety] detours: off unless the scenario turns it on
        return None
    spec = scenario.robot(name)
    path = spec.path
    if not path:
        shared = {r.path for r in scenario.robots if r.path}
        path = next(iter(shared)) if len(shared) == 1 else None
    if not path or path not in scenario.paths or handles_obstacles(scenario, name):
        return None
    from copath.detour import DetourConfig  # noqa: PLC0415
    from copath.models import UnicycleModel  # noqa: PLC0415
    from copath.safety import UNICYCLE_TURN_RAD  # noqa: PLC0415

    unicycle = isinstance(spec.model, UnicycleModel)
    turn = scenario.safety.deadlock_turn_rad
    # the filter's deadlock rule (a right turn while a barrier slows the robot) already unwinds
    # head-on jams where it is on (unicycles by default): the stage's stall rule is for the rest
    ruled = scenario.safety.enabled and (UNICYCLE_TURN_RAD if turn is None and unicycle else (turn or 0.0)) > 0
    return DetourPlanner(scenario.paths[path], spec.model.radius, unicycle,
                         scenario.run.dt, [(o.vertices, o.velocity) for o in scenario.obstacles if o.known],
                         scenario.sensors.max_range_m if scenario.sensors.enabled else 0.0,
                         DetourConfig(margin_m=scenario.safety.margin_m, stall_detours=not ruled))


def sensor_angles(count: int) -> np.ndarray:
    """Bearings of a ring of ``count`` range sensors, from 0 rad counter-clockwise."""
    return 2 * math.pi * np.arange(count) / count


@dataclass
class StepOutput:
    command: Command
    peers: list[tuple[str, PeerEnvelope]]
    telemetry: Telemetry
    estimate: Estimate | None = None
    """The pose estimate the controller saw (robots with a ``[sensing]`` estimator)."""
    events: list[Event] = field(default_factory=list)
    """Timeline events of this step (``faults_injected``: the fault layer's drops, docs/reference/faults.md)."""


@dataclass
class Counters:
    received: int = 0
    dropped_by_faults: int = 0
    partitioned: int = 0
    out_of_range: int = 0
    delivered: int = 0
    rejected: int = 0
    controller_errors: int = 0
    steps: int = 0
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "extra"}
        d.update(self.extra)
        return d


class RobotRuntime:
    """Controller + fault-layer inbox + envelope bookkeeping for one robot."""

    def __init__(self, scenario: Scenario, name: str, keys: Keys) -> None:
        spec = scenario.robot(name)
        self.name = name
        self.keys = keys
        self.scenario = scenario
        self.dt = scenario.run.dt
        self.comm_range = scenario.network.range_m
        self.neighbours = spec.neighbours if self.comm_range == 0 else None
        self.controller = build_controller(spec.controller, RobotContext.for_robot(scenario, name))
        self.faults = LinkFaults(scenario.network, scenario.run.seed, name)
        self.inbox = FaultyInbox(self.faults)
        self.counters = Counters()
        self.log_tracebacks = True
        """Log the first controller failure's traceback (an agent process's log); the
        in-process loop turns it off: the traceback travels in the event, the terminal gets
        one line (``orchestrator/run/failures.py``)."""
        self.seq = 0
        self.sent: dict[str, int] = {"*": 0}
        self.received_from: dict[str, int] = {}
        # stamps outside the window are rejected before the fault queue (copath.wire.trust);
        # the agent process shares its link's log, so every reject is counted once
        self.stamps = StampWindow.for_run(self.dt, scenario.network.delay_ms, scenario.network.jitter_ms)
        self.reject_log = RejectLog()
        self._now = 0.0
        self.lost: frozenset[str] = frozenset()
        """Robots whose liveliness token went away (the run goes on without them,
        ``run.on_robot_failure``): their messages are dropped and the controller is told."""
        self._heard: dict[str, float] = {}
        """When a robot-to-robot message of each sender was last delivered here (after faults).
        Arrival, not the message's stamp: a neighbour whose every message is 1 s old (a slow
        link) is still heard every period; it is silence, not age, that makes it lost."""
        self._told: frozenset[str] = frozenset()
        """:attr:`lost` as of the last step (its changes are events)."""
        self._silent_after = float(scenario.run.lease_s)
        """Silence threshold [s]: the run's transport lease, as for a frozen process."""
        self._silent: dict[str, float] = {}
        """Senders heard before and not for the lease (a radio gone quiet): lost here,
        in ``Observation.lost``, until one of their messages is delivered again; the value
        is when they were last heard."""
        self._early: list[PeerEnvelope] | None = []
        """Peer messages that came before the first step, checked against its clock."""
        self._injected: list[tuple[float, str, str]] = []  # (stamp, sender, "dropped" | "partitioned")
        self.sensors = scenario.sensors
        self._angles = sensor_angles(scenario.sensors.count) if scenario.sensors.enabled else None
        self._cmd_size = spec.model.command_size
        # [sensing]: the controller sees the EKF's estimate (or the raw reading without it)
        self._profile = scenario.sensing.profile_for(name, spec.model.kind)
        self._kind = spec.model.kind
        self.ekf: PoseEKF | None = None
        self._last_cmd = [0.0] * self._cmd_size
        self._model = spec.model
        self._applied = np.zeros(self._cmd_size)
        """The command the robot applies (saturated and, with an acceleration limit, rate-limited
        as the simulator does), for the velocity in its envelopes."""
        self._raw_pose: np.ndarray | None = None
        self.safety = (SafetyGuard(scenario.safety, name, {r.name: r.model for r in scenario.robots}, self.dt,
                                   scenario.sensors.count if scenario.sensors.enabled else 0,
                                   silent_hold_s(scenario) if scenario.run.cut_off == "hold" else None,
                                   frozenset(r for r in scenario.robot_names
                                             if r != name and handles_cut_off(scenario, r)))
                       if scenario.safety.enabled else None)
        # the filter reads the sender position of every envelope it overhears, through fault
        # streams of its own (another seed), so the controller's messages are the same with or
        # without the filter
        self._overhear = (FaultyInbox(LinkFaults(scenario.network, scenario.run.seed + _OVERHEAR_SEED, name))
                          if self.safety is not None and scenario.safety.overhear else None)
        self._listened = frozenset(scenario.robot_names if self.neighbours is None else self.neighbours)
        """Senders whose envelopes also reach :meth:`receive` (which counts their bad stamps)."""
        self._team = frozenset(scenario.robot_names) - {name}
        """Every other robot of the scenario. Having lost every one of them it has heard (in its
        inbox or overheard) is being cut off; one it never heard cannot be lost."""
        self._holds = (scenario.run.cut_off == "hold" and not handles_cut_off(scenario, name)
                       and silent_hold_s(scenario) <= scenario.safety.max_age_s)
        """Whether the runtime holds the robot still when it is cut off: its controller does not
        handle that itself, and the others' safety filters can keep the hold (they keep a robot
        gone quiet as held only while the hold is younger than ``safety.max_age_s``; with a
        slower network they forget it, and a hold would only cost coordination)."""
        self.cut_off = False
        """Every robot of :attr:`_team` it has heard is lost here, at least one by silence."""
        self._overheard_at: dict[str, float] = {}
        """When an overheard envelope of each sender was last delivered to the filter."""
        self.detour = detour_planner(scenario, name)
        """The detour stage (docs/reference/detours.md): the controller sees its pose moved back onto its
        lane while a detour round a blocked lane is under way."""
        self._radii = {r.name: r.model.radius for r in scenario.robots}
        self._positions: dict[str, tuple[float, float, float]] = {}
        """Without the safety filter: the last position each peer sent, and its stamp."""

    @property
    def now(self) -> float:
        """Controller time [s] of the latest step (0 before the first): the clock the stamp
        window checks against, and the time of the node's closing records."""
        return self._now

    @property
    def command_size(self) -> int:
        """Length of this robot's command vector (its model's ``command_size``): a node's
        zero command (the watchdog's stop) has this many zeros."""
        return self._cmd_size

    @property
    def last_command(self) -> tuple[float, ...]:
        """The command the latest step returned (zeros before the first)."""
        return tuple(self._last_cmd)

    def count_rejects_in(self, log: RejectLog) -> None:
        """Count this runtime's rejects (peer stamps outside the window) in ``log`` from now
        on: a node passes its link's log, so every reject of the process is counted once
        and reported in one ``messages_rejected`` stream (docs/reference/faults.md)."""
        self.reject_log = log

    @property
    def subscriptions(self) -> list[str]:
        return self.keys.peer_subscriptions(self.name, self.neighbours)

    @property
    def overhear_subscriptions(self) -> list[str]:
        """Keys whose envelopes go to :meth:`overhear` (every robot's messages; empty
        without the safety filter or with ``safety.overhear = false``)."""
        if self._overhear is None:
            return []
        return [self.keys.peer_broadcast("*"), self.keys.peer_direct("*", "*")]

    def overhear(self, env: PeerEnvelope) -> None:
        """Accept an overheard envelope: only its sender's position and stamp are used.

        Before the first step there is no clock to check a stamp against, so nothing is
        overheard (the filter needs current positions, not ones from before a restart). A
        neighbour's envelope also reaches :meth:`receive`, which counts a bad stamp; here
        only the others' are counted, so one bad message is one reject."""
        if self._overhear is None or env.sender == self.name or self._early is not None:
            return
        if self._stamp_ok(env, "overheard", record=env.sender not in self._listened):
            self.counters.extra["overheard"] = self.counters.extra.get("overheard", 0) + 1
            self._overhear.push(env.sender, env.stamp, env)

    def missing(self, expect: dict[str, int] | None) -> dict[str, int]:
        """Senders (among those this robot listens to) whose messages have not all
        arrived yet, with how many are missing (the lockstep barrier)."""
        if not expect:
            return {}
        out = {}
        for sender, n in expect.items():
            if sender == self.name or (self.neighbours is not None and sender not in self.neighbours):
                continue
            got = self.received_from.get(sender, 0)
            if got < n:
                out[sender] = n - got
        return out

    def refused(self, sender: str) -> None:
        """A message on ``sender``'s key arrived and was refused (schema, origin or stamp):
        delivered-and-dropped for the lockstep barrier (:meth:`missing`), so it is not
        awaited (docs/reference/faults.md, "Rejected messages and the lockstep barrier"). Attributed by
        the key, which names the sender: a refused message's own fields cannot be trusted."""
        if sender != self.name and sender in self._team:
            self.received_from[sender] = self.received_from.get(sender, 0) + 1
            self.counters.extra["refused_from_peers"] = self.counters.extra.get("refused_from_peers", 0) + 1

    def peer_alive(self, name: str, alive: bool) -> None:
        """A robot's liveliness changed (its process died or froze, or it came back)."""
        if name != self.name:
            self.lost = self.lost - {name} if alive else self.lost | {name}  # replaced whole: thread-safe read

    def _stamp_ok(self, env: PeerEnvelope, where: str, record: bool = True) -> bool:
        try:
            self.stamps.check(env.stamp, self._now)
        except WireError as exc:
            if record:
                self.reject_log.add(f"peer/{env.sender} ({where})", str(exc))
            return False
        return True

    def receive(self, env: PeerEnvelope) -> None:
        """Accept a peer envelope that arrived (before faults); one stamped outside the
        receiver's :class:`~copath.wire.trust.StampWindow` is rejected and counted."""
        if env.sender == self.name:
            return
        if self._early is not None:  # no clock yet (a robot restarted mid-run)
            self._early.append(env)
            return
        if not self._stamp_ok(env, "peer"):
            self.refused(env.sender)
            return
        self.counters.received += 1
        self.received_from[env.sender] = self.received_from.get(env.sender, 0) + 1
        partitioned, silenced = self.faults.partitioned, self.faults.silenced
        if not self.inbox.push(env.sender, env.stamp, env):
            self.counters.dropped_by_faults = self.faults.dropped
            self.counters.partitioned = self.faults.partitioned
            what = ("partitioned" if self.faults.partitioned > partitioned
                    else "silenced" if self.faults.silenced > silenced else "dropped")
            self._injected.append((env.stamp, env.sender, what))

    def step(self, obs: Obs, now: float) -> StepOutput:
        """Run one control instant at controller time ``now`` with the latest observation."""
        self._now = max(self._now, float(now))
        if self._early is not None:
            early, self._early = self._early, None
            for env in early:
                self.receive(env)
        pose = np.asarray(obs.pose, dtype=float)
        estimate = None
        if obs.meas is not None:
            pose, estimate = self._estimate(obs, now, pose)
        inbox = []
        lost = self.lost
        # a deterministic order whatever the arrival order (sums over neighbours stay bitwise equal)
        for env in sorted(self.inbox.pop_ready(now), key=lambda e: (e.stamp, e.sender, e.seq)):
            self._heard[env.sender] = now  # when it was last heard, not how old its news is
            if env.sender in lost:
                continue
            if self.comm_range > 0 and math.hypot(env.pos[0] - pose[0], env.pos[1] - pose[1]) > self.comm_range:
                self.counters.out_of_range += 1
                continue
            if self.safety is not None and self._overhear is None:
                self.safety.hear(env.sender, env.pos, env.stamp, env.vel)
            inbox.append(PeerMessage(env.sender, env.kind, env.stamp, now - env.stamp, env.payload, tuple(env.pos),
                                     None if env.cov is None else tuple(env.cov)))
        self.counters.delivered += len(inbox)
        silence_events = self._losses(now)
        lost = lost | frozenset(self._silent)
        cut = self._cut_off(now)
        if cut != self.cut_off:
            self.cut_off = cut
            silence_events.append(Event(float(now), self.name, "cut_off" if cut else "reconnected",
                                        {"held": self._holds}))
        ranges = None if obs.ranges is None else np.asarray(obs.ranges, dtype=float)
        seen, detour_offset = self._detour(now, pose, ranges, inbox, silence_events, cut and self._holds)
        observation = Observation(
            t=now,
            pose=seen,
            dt=self.dt,
            ranges=ranges,
            sensor_angles=self._angles,
            sensor_max_range=self.sensors.max_range_m if self._angles is not None else 0.0,
            lost=lost,
        )
        t0 = time.perf_counter()
        try:
            res = self.controller.step(observation, inbox)
            cmd = [float(c) for c in np.asarray(res.command, dtype=float).reshape(-1)]
            if len(cmd) != self._cmd_size or not all(math.isfinite(c) for c in cmd):
                raise ValueError(f"controller returned command {cmd!r}; expected {self._cmd_size} finite values")
            messages, telemetry = res.messages, dict(res.telemetry)
        except Exception as exc:  # the robot stops for this step instead of dying
            cmd, messages, telemetry = [0.0] * self._cmd_size, [], {"controller_error": True}
            failure = self._controller_failed(exc, obs.k, now)
        else:
            failure = None
        solve_ms = (time.perf_counter() - t0) * 1e3
        hold = cut and self._holds
        if hold:  # cut off: it cannot coordinate nor see the others; it stops where the others expect it
            cmd = [0.0] * self._cmd_size
            telemetry["cut_off"] = True
        if detour_offset:
            telemetry["detour_offset"] = detour_offset
        if self.safety is not None:
            t0 = time.perf_counter()
            for env in self._overhear.pop_ready(now) if self._overhear is not None else ():
                self._overheard_at[env.sender] = now
                if self.comm_range == 0 or math.hypot(env.pos[0] - pose[0], env.pos[1] - pose[1]) <= self.comm_range:
                    self.safety.hear(env.sender, env.pos, env.stamp, env.vel)
            res = self.safety.apply(pose, cmd, now, ranges, self._angles, self.lost, self._quiet_for_filter(now))
            if not hold:  # a held robot keeps still: the others keep out of its disc
                cmd = [float(c) for c in res.command]
            telemetry.update(safety_active=res.active, safety_change=res.change,
                             safety_ms=(time.perf_counter() - t0) * 1e3)
        self.counters.steps += 1
        self._applied = limit_change(self._model, self._applied, self._model.saturate(cmd)[0], self.dt)
        vel = [float(v) for v in world_velocity(self._model, float(pose[2]), self._applied)]
        peers = []
        for m in messages:
            self.seq += 1
            env = PeerEnvelope(self.name, self.seq, float(now), m.kind, [float(pose[0]), float(pose[1])],
                               to_plain(dict(m.payload)), None if self.ekf is None else self.ekf.position_cov,
                               vel)
            if m.to is None:
                peers.append((self.keys.peer_broadcast(self.name), env))
                self.sent["*"] += 1
            else:
                for r in m.to:
                    peers.append((self.keys.peer_direct(self.name, r), env))
                    self.sent[r] = self.sent.get(r, 0) + 1
        if self.safety is not None and peers:  # committed plans: the filter keeps what it published
            self.safety.published(now, pose, vel)
        self._last_cmd = cmd
        return StepOutput(
            Command(obs.k, float(now), cmd, solve_ms, dict(self.sent)),
            peers,
            Telemetry(obs.k, float(now), to_plain(telemetry)),
            estimate,
            self._fault_events(now) + silence_events + ([failure] if failure is not None else []),
        )

    def _controller_failed(self, exc: BaseException, k: int, now: float) -> Event | None:
        """Count a failed controller step (an exception in ``step()`` or an invalid command;
        docs/reference/controllers.md, "When step() fails"). The first failure of this robot is logged
        with its traceback (the process's log) and becomes a ``controller_error`` event
        (robot, time, exception, traceback) that the orchestrator prints as one line; later
        ones are only counted: each failed step's telemetry says ``controller_error`` (the
        count in metrics.json) and the closing account has the total."""
        self.counters.controller_errors += 1
        if self.counters.controller_errors > 1:
            return None
        what = f"{type(exc).__name__}: {exc}"[:_ERROR_CHARS]
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        if self.log_tracebacks:
            logger.error("robot %s: controller step failed at t=%.3f s (tick %d): %s\n%s"
                         "the robot stops at every failing step; further failures are counted "
                         "(controller_errors), not logged", self.name, now, k, what, tb)
        return Event(float(now), self.name, "controller_error",
                     {"k": int(k), "error": type(exc).__name__, "message": str(exc)[:_ERROR_CHARS],
                      "traceback": tb[-_TRACEBACK_CHARS:]})

    def _detour(self, now: float, pose: np.ndarray, ranges, inbox: list[PeerMessage], events: list[Event],
                held: bool = False) -> tuple[np.ndarray, float]:
        """The detour stage (docs/reference/detours.md): the pose the controller sees and the lane's shift,
        from the range ring, the known obstacles and the other robots' discs (the safety filter's
        when it runs: a lost robot is its held disc; else the positions heard); its
        ``detour_start`` / ``detour_end`` events are appended to ``events``. A robot the runtime
        holds still (cut off) plans nothing."""
        if self.detour is None or held:
            return pose, 0.0
        peers = []
        if self.safety is not None and (ranges is not None or self.lost or self._quiet_for_filter(now)
                                        or self.detour.plan is not None or self.detour.stalled(now)):
            for nb in self.safety.neighbours(now):  # held discs, and live ones to tell teammates in the ring
                held = nb.held
                spread = nb.spread if nb.spread is not None else nb.speed_max * nb.age
                peers.append((nb.position[0], nb.position[1], nb.radius + (0.0 if held else spread), held))
        else:
            for m in inbox:
                if m.position is not None:
                    self._positions[m.sender] = (m.position[0], m.position[1], m.stamp)
            for r, (x, y, stamp) in self._positions.items():
                held = r in self.lost
                peers.append((x, y, self._radii.get(r, 0.0) + min(0.5 * max(now - stamp, 0.0), 0.5), held))
        out = self.detour.step(now, pose, ranges, self._angles, peers)
        events += [Event(float(now), self.name, what, detail) for what, detail in out.events]
        return out.pose, out.offset

    def _cut_off(self, now: float) -> bool:
        """Every robot this robot has heard is lost, at least one by silence (docs/reference/faults.md,
        "Gone quiet"). Heard: in its inbox or, with the safety filter overhearing, in any
        envelope it overheard (a follower that hears only the leader is not cut off when the
        leader goes quiet: it still overhears the others). A robot whose every peer died is
        not cut off: its liveliness news came through, it hears the network."""
        silent = False
        for r in self._team:
            if r in self.lost:
                continue
            t = max(self._heard.get(r, -math.inf), self._overheard_at.get(r, -math.inf))
            if t == -math.inf:
                continue  # never heard: cannot be lost
            if now - t <= self._silent_after + 1e-9:
                return False  # heard within the lease
            silent = True
        return silent

    def _quiet_for_filter(self, now: float) -> frozenset[str]:
        """Robots gone quiet for the safety filter: with overhearing, those whose every
        envelope (to anyone) has been missing for the lease (a follower that only talks to the
        leader is heard by the others' filters, not by their controllers); else :attr:`_silent`."""
        if self._overhear is None:
            return frozenset(self._silent)
        return frozenset(s for s, t in self._overheard_at.items()
                         if s not in self.lost and now - t > self._silent_after + 1e-9)

    def _losses(self, now: float) -> list[Event]:
        """What this robot knows of lost robots, as events when it changes (docs/reference/faults.md):
        ``peer_lost`` / ``peer_rejoined`` when a token went or came back (:attr:`lost`), and
        ``peer_silent`` (robot, last_heard) / ``peer_heard`` (robot, silent_from) for senders
        heard before but not for the run's lease (``run.lease_s``): these are lost
        here until a message of theirs is delivered again. Only this robot's inbox decides
        silence; in lockstep every message stamped before ``now`` has arrived, so the
        decision is the same in every run with the seed."""
        lost, told = self.lost, self._told
        self._told = lost
        events = [Event(float(now), self.name, "peer_lost", {"robot": r}) for r in sorted(lost - told)]
        events += [Event(float(now), self.name, "peer_rejoined", {"robot": r}) for r in sorted(told - lost)]
        for s, t in sorted(self._heard.items()):
            if s in self.lost:  # its token went: lost already, whatever it says
                continue
            quiet = now - t > self._silent_after + 1e-9
            if quiet and s not in self._silent:
                self._silent[s] = t
                events.append(Event(float(now), self.name, "peer_silent", {"robot": s, "last_heard": float(t)}))
            elif not quiet and s in self._silent:
                events.append(Event(float(now), self.name, "peer_heard",
                                    {"robot": s, "silent_from": float(self._silent.pop(s))}))
        return events

    def _fault_events(self, now: float) -> list[Event]:
        """One ``faults_injected`` event for the fault layer's drops of messages stamped
        before ``now`` (in lockstep all of them have arrived by then, so the event is the
        same in every run with the seed), counted per sender and kind."""
        due = [x for x in self._injected if x[0] < now - 1e-9]
        if not due:
            return []
        self._injected = [x for x in self._injected if x[0] >= now - 1e-9]
        by: dict[str, dict[str, int]] = {}
        for _, sender, what in due:
            by.setdefault(sender, {"dropped": 0, "partitioned": 0, "silenced": 0})[what] += 1
        return [Event(float(now), self.name, "faults_injected",
                      {"dropped": sum(v["dropped"] for v in by.values()),
                       "partitioned": sum(v["partitioned"] for v in by.values()),
                       "silenced": sum(v["silenced"] for v in by.values()),
                       "from": dict(sorted(by.items()))})]

    def _estimate(self, obs: Obs, now: float, raw: np.ndarray) -> tuple[np.ndarray, Estimate | None]:
        """The pose the controller sees under ``[sensing]``: the EKF's estimate at the
        observation's time, predicted to ``now`` plus ``solve_time_s`` with the last
        command (solve-time compensation); without the estimator, the raw reading with
        its heading unwrapped."""
        cfg = self.scenario.sensing
        if not cfg.estimator:
            if self._raw_pose is not None:
                raw = raw.copy()
                raw[2] = self._raw_pose[2] + wrap_to_pi(raw[2] - self._raw_pose[2])
            self._raw_pose = raw
            return raw, None
        if self.ekf is None:
            self.ekf = PoseEKF(self._profile, self._kind, cfg.filter, obs.t, raw)
        m = obs.meas
        res = self.ekf.step(obs.t, m.get("odom", ()), m.get("fixes", ()), m.get("headings", ()))
        ahead = (now - obs.t) + cfg.solve_time_s
        pose = self.ekf.predict_ahead(ahead, self._last_cmd) if ahead > 0 else res.pose.copy()
        rec = Estimate(obs.k, float(obs.t), [float(v) for v in res.x], res.P.tolist(), [float(v) for v in res.nis],
                       [int(v) for v in res.nis_dof],
                       {"accepted": res.accepted, "rejected": res.rejected, "late": res.late})
        return pose, rec

    def closing_counters(self) -> dict:
        if self.counters.controller_errors > 1 and self.log_tracebacks:
            logger.error("robot %s: controller step failed %d times in all (traceback of the first above)",
                         self.name, self.counters.controller_errors)
        self.counters.dropped_by_faults = self.faults.dropped
        self.counters.partitioned = self.faults.partitioned
        self.counters.rejected = self.reject_log.total
        self.counters.extra["silenced"] = self.faults.silenced
        if self.safety is not None:
            self.counters.extra.update(self.safety.counters())
        return self.counters.as_dict()
