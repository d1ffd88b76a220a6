"""One robot's runtime around its controller: the stages of a control instant, as a pipeline.

:class:`RobotRuntime` is transport-free: the agent process (``agent/node.py``) feeds it
records received over Zenoh, and the in-process loop (``orchestrator/run/inprocess.py``)
feeds it directly, so both run the exact same logic. Each stage is an object of
:mod:`agent.stages` with its own state; one control instant (:meth:`RobotRuntime.step`) runs
them in the order of :data:`agent.stages.STAGE_ORDER`:

1. **trust**: the step clock advances; envelopes that came before the first step are
   checked against it (docs/reference/faults.md, "Every receiver validates");
2. **estimate**: with ``[sensing]``, the pose the robot believes (docs/reference/sensing.md);
3. **faults**: the receiver-side fault layer releases peer envelopes (``copath.wire.faults``);
   those of lost senders and from beyond the communication range are dropped (Def. 10:
   the sender's position travels in the envelope, no oracle);
4. **liveness**: robots lost (token gone) or gone quiet, and whether this robot is cut off
   (docs/reference/faults.md, "When a robot dies, freezes or goes quiet");
5. **detour**: the pose the controller sees while a detour round a blocked lane is under
   way (docs/reference/detours.md);
6. **control**: the controller steps; an exception inside it (or an invalid command) is
   counted and the robot stops for that step (docs/reference/controllers.md, "When step() fails");
7. **hold**: a robot cut off commands zero until it hears one again, unless its controller
   handles that itself (the cut-off rule, :mod:`agent.stages.cut_off`);
8. **safety**: with ``[safety]`` on, the command passes the decentralised safety filter
   (docs/reference/safety.md), fed with the sender positions of every peer envelope the robot
   overhears (its own fault streams and range filter; the controller's inbox is not touched);
9. **envelopes**: its outgoing messages become envelopes on the sender's keys, with the
   velocity of the command it applies.

Between instants, :meth:`RobotRuntime.receive` passes each arriving envelope through trust
and faults, and :meth:`RobotRuntime.overhear` each overheard one through trust to safety.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agent.controllers import build_controller, resolve_controller
from copath.config import ConfigError
from copath.control import Observation, RobotContext
from copath.detour import DetourPlanner
from copath.graph import stand_ins
from copath.safety import awaits_overheard
from copath.scenario import Scenario
from copath.wire.keys import Keys
from copath.wire.messages import Command, Estimate, Event, Obs, PeerEnvelope, Telemetry, to_plain
from copath.wire.trust import RejectLog

from .stages import (STAGE_ORDER, ControlStage, Counters, CutOffRule, DetourStage, EnvelopeStage, EstimateStage,
                     FaultStage, HoldStage, LivenessStage, SafetyStage, TrustStage)
from .stages.cut_off import silent_hold_s

__all__ = ["RobotRuntime", "StepOutput", "Counters", "STAGE_ORDER", "handles_cut_off", "handles_obstacles",
           "silent_hold_s"]


def handles_cut_off(scenario: Scenario, name: str) -> bool:
    """Whether robot ``name``'s controller handles being cut off itself: its family's factory
    declares it (``handles_cut_off``; the roles family, docs/reference/ambiguities.md, robot lost
    in role assignment (A38)). Read from the scenario, so every robot knows it of every other; the
    declaration is enough (parsing every robot's parameters cost each runtime 0.46 ms per role
    robot, N^2 over a fleet)."""
    try:
        factory = resolve_controller(scenario.robot(name).controller)
    except ConfigError:  # reported where that robot's controller is built
        return False
    return factory.handles_cut_off


def handles_obstacles(scenario: Scenario, name: str) -> bool:
    """Whether robot ``name``'s controller avoids obstacles itself (its family's factory declares
    ``handles_obstacles``: the unicycle NMPC's constraints, Sec. 4.4.3); the runtime's detour
    stage then leaves it alone (docs/reference/detours.md)."""
    try:
        factory = resolve_controller(scenario.robot(name).controller)
    except ConfigError:
        return False
    return factory.handles_obstacles


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
                         DetourConfig(margin_m=scenario.safety.margin_m, stall_detours=not ruled,
                                      # its filter takes no deadlock turn beside a held robot there
                                      turn_first=unicycle and scenario.in_column(name)))


@dataclass
class StepOutput:
    command: Command
    peers: list[tuple[str, PeerEnvelope]]
    telemetry: Telemetry
    estimate: Estimate | None = None
    """The pose estimate the controller saw (robots with a ``[sensing]`` estimator)."""
    events: list[Event] = field(default_factory=list)
    """Timeline events of this step (``faults_injected``: the fault layer's drops, docs/reference/faults.md)."""


class RobotRuntime:
    """One robot's pipeline of stages around its controller (:mod:`agent.stages`).

    The stages are public attributes, in their order: :attr:`trust`, :attr:`estimator`,
    :attr:`faults`, :attr:`liveness`, :attr:`detour`, :attr:`control`, :attr:`hold`,
    :attr:`safety` (None without ``[safety]``), :attr:`envelopes`."""

    def __init__(self, scenario: Scenario, name: str, keys: Keys) -> None:
        spec = scenario.robot(name)
        self.name = name
        self.keys = keys
        self.scenario = scenario
        self.dt = scenario.run.dt
        self.neighbours = spec.neighbours if scenario.network.range_m == 0 else None
        """The robots it listens to (None: every robot, a range-limited graph)."""
        self.counters = Counters()
        self._joined = False
        self.received_from: dict[str, int] = {}
        """Peer envelopes that arrived from each sender, refused ones included (the lockstep barrier)."""
        self.awaits_overheard = awaits_overheard(scenario.safety)
        """Whether the lockstep barrier waits for every message overheard (the safety filter
        overhears: what it does depends on them, so a deterministic run must have them all; the
        simulator's ``Obs.expect`` then counts every message of each sender;
        :func:`copath.safety.awaits_overheard`)."""
        self.overheard_from: dict[str, int] = {}
        """Overheard envelopes that arrived from each sender (every key), refused ones included,
        counted while :attr:`awaits_overheard` (:meth:`missing`)."""
        self.stand_ins: frozenset[str] = frozenset()
        """Live robots this one listens to in place of its lost neighbours (:func:`copath.graph.stand_ins`;
        docs/reference/faults.md, "Stand-ins for a lost neighbour"): their messages reach the
        controller and the lockstep barrier waits for them, as for a neighbour's."""
        self._stand_ins_for: frozenset[str] = frozenset()
        """The lost robots :attr:`stand_ins` were found for."""
        self._stand_in_since: dict[str, float] = {}
        """When each stand-in began [s]: its messages stamped before are not passed on."""
        self._overheard_last: dict[str, PeerEnvelope] = {}
        """On a fixed graph, the newest envelope of each robot it does not listen to (:meth:`receive`)."""
        self._written_off: dict[str, tuple[int, float]] = {}
        """Per sender, the messages the lockstep barrier gave up on and the tick time they were
        stamped before (:meth:`write_off`): one of them arriving after all is not counted twice."""
        self.cut_off_rule = CutOffRule.for_robot(scenario, name, handles_cut_off)
        controller = build_controller(spec.controller, RobotContext.for_robot(scenario, name))
        self._angles = scenario.sensors.angles() if scenario.sensors.enabled else None
        self._max_range = scenario.sensors.max_range_m if self._angles is not None else 0.0
        self._team = frozenset(scenario.robot_names) - {name}
        self._last_cmd = [0.0] * spec.model.command_size

        self.trust = TrustStage(scenario)
        self.estimator = EstimateStage(scenario, name)
        self.faults = FaultStage(scenario, name, self.counters)
        self.safety = (SafetyStage(scenario, name, self.cut_off_rule, self.trust, self.faults, self.counters,
                                   frozenset(scenario.robot_names if self.neighbours is None else self.neighbours))
                       if scenario.safety.enabled else None)
        self.liveness = LivenessStage(scenario, name, self.cut_off_rule,
                                      overhearing=self.safety is not None and self.safety.overhearing)
        self._graph = ({r.name: tuple(r.neighbours) for r in scenario.robots}
                       if self.neighbours is not None and self.safety is not None and self.safety.overhearing else None)
        """The fixed graph, every robot's neighbours, where stand-ins can be heard: their messages
        are the ones overheard for the safety filter (None: range-limited, or nothing overheard)."""
        self.detour = DetourStage(scenario, name, detour_planner(scenario, name))
        self.control = ControlStage(controller, name, spec.model.command_size, self.counters)
        self.hold = HoldStage(self.cut_off_rule, spec.model.command_size)
        self.envelopes = EnvelopeStage(scenario, name, keys)

    @property
    def joined(self) -> bool:
        """This process joined a run in progress (a restart; set by the node): the controllers'
        ``Observation.joined``. Set, it tells the envelope stage that what the base applies is not
        known yet (:meth:`EnvelopeStage.rejoined`)."""
        return self._joined

    @joined.setter
    def joined(self, value: bool) -> None:
        if value and not self._joined:
            self.envelopes.rejoined()
        self._joined = bool(value)

    # -- what nodes read ------------------------------------------------------------------
    @property
    def stages(self) -> tuple:
        """The stages of a control instant, in the order they run (:data:`agent.stages.STAGE_ORDER`;
        safety is left out without ``[safety]``)."""
        return tuple(s for s in (self.trust, self.estimator, self.faults, self.liveness, self.detour, self.control,
                                 self.hold, self.safety, self.envelopes) if s is not None)

    @property
    def controller(self):
        """This robot's controller (the control stage's)."""
        return self.control.controller

    @property
    def log_tracebacks(self) -> bool:
        """Log the first controller failure's traceback (an agent process's log); the
        in-process loop turns it off: the traceback travels in the event, the terminal gets
        one line (``orchestrator/run/failures.py``)."""
        return self.control.log_tracebacks

    @log_tracebacks.setter
    def log_tracebacks(self, on: bool) -> None:
        self.control.log_tracebacks = bool(on)

    @property
    def now(self) -> float:
        """Controller time [s] of the latest step (0 before the first): the clock the stamp
        window checks against, and the time of the node's closing records."""
        return self.trust.now

    @property
    def command_size(self) -> int:
        """Length of this robot's command vector (its model's ``command_size``): a node's
        zero command (the watchdog's stop) has this many zeros."""
        return self.control.command_size

    @property
    def last_command(self) -> tuple[float, ...]:
        """The command the latest step returned (zeros before the first)."""
        return tuple(self._last_cmd)

    @property
    def reject_log(self) -> RejectLog:
        """Where this runtime's rejects (peer stamps outside the window) are counted."""
        return self.trust.reject_log

    def count_rejects_in(self, log: RejectLog) -> None:
        """Count this runtime's rejects in ``log`` from now on: a node passes its link's log,
        so every reject of the process is counted once and reported in one
        ``messages_rejected`` stream (docs/reference/faults.md)."""
        self.trust.count_rejects_in(log)

    @property
    def sent(self) -> dict[str, int]:
        """Envelopes sent so far, per recipient (``*``: broadcasts): a command's ``sent``."""
        return self.envelopes.sent

    @property
    def lost(self) -> frozenset[str]:
        """Robots whose liveliness token went away (:meth:`peer_alive`)."""
        return self.liveness.lost

    @property
    def cut_off(self) -> bool:
        """Every robot it has heard is lost here, at least one by silence (the cut-off rule)."""
        return self.liveness.cut_off

    @property
    def ekf(self):
        """The pose estimator (``[sensing]`` with ``estimator``; None until its first measurement)."""
        return self.estimator.ekf

    @property
    def subscriptions(self) -> list[str]:
        return self.keys.peer_subscriptions(self.name, self.neighbours)

    @property
    def overhear_subscriptions(self) -> list[str]:
        """Keys whose envelopes go to :meth:`overhear` (every robot's messages; empty
        without the safety filter or with ``safety.overhear = false``)."""
        return [] if self.safety is None else self.safety.overhear_subscriptions(self.keys)

    # -- between instants -----------------------------------------------------------------
    def overhear(self, env: PeerEnvelope) -> None:
        """Accept an overheard envelope for the safety filter (:meth:`agent.stages.SafetyStage.overhear`)."""
        if self.awaits_overheard and not self._arrived_late(env):
            self.overheard_from[env.sender] = self.overheard_from.get(env.sender, 0) + 1
        if self.safety is not None:
            self.safety.overhear(env)

    def overheard_refused(self, sender: str) -> None:
        """An overheard message on ``sender``'s key was refused: arrived, for the barrier."""
        if self.awaits_overheard and sender != self.name and sender in self._team:
            self.overheard_from[sender] = self.overheard_from.get(sender, 0) + 1

    def missing(self, expect: dict[str, int] | None) -> dict[str, int]:
        """Senders (among those this robot listens to) whose messages have not all
        arrived yet, with how many are missing (the lockstep barrier)."""
        if not expect:
            return {}
        out = {}
        if self.awaits_overheard:
            for sender, n in expect.items():
                got = self.overheard_from.get(sender, 0)
                if sender != self.name and got < n:
                    out[sender] = n - got
            return out
        for sender, n in expect.items():
            if sender == self.name or not self.listens_to(sender):
                continue
            got = self.received_from.get(sender, 0)
            if got < n:
                out[sender] = n - got
        return out

    def write_off(self, expect: dict[str, int] | None, t: float) -> dict[str, int]:
        """The lockstep barrier of the tick at run time ``t`` gave up waiting: the messages
        still missing (returned, as :meth:`missing` gives them) are written off as lost, so
        the next ticks wait only for their own. Without this, one message lost on the wire
        (a router link reset drops what was in flight) kept every later barrier one message
        short, and each tick waited the full timeout: the run crawled at 5 s a tick
        (docs/reference/faults.md, "Lost messages and the lockstep barrier"). One of them
        arriving after all (stamped before ``t``) is then not counted again."""
        late = self.missing(expect)
        book = self.overheard_from if self.awaits_overheard else self.received_from
        for sender, n in late.items():
            book[sender] = book.get(sender, 0) + n
            self._written_off[sender] = (self._written_off.get(sender, (0, t))[0] + n, t)
        return late

    def _arrived_late(self, env: PeerEnvelope) -> bool:
        """``env`` is one of the messages :meth:`write_off` gave up on: already counted."""
        off = self._written_off.get(env.sender)
        if off is None or not env.stamp < off[1] - 0.5 * self.dt:
            return False
        if off[0] > 1:
            self._written_off[env.sender] = (off[0] - 1, off[1])
        else:
            del self._written_off[env.sender]
        return True

    @property
    def hears_stand_ins(self) -> bool:
        """Whether robots can stand in for a lost neighbour here (a fixed graph, overheard)."""
        return self._graph is not None

    def listens_to(self, sender: str) -> bool:
        """Whether ``sender``'s messages reach this robot's controller: a neighbour, a stand-in
        for a lost one, or anyone on a range-limited graph."""
        return self.neighbours is None or sender in self.neighbours or sender in self.stand_ins

    def refused(self, sender: str) -> None:
        """A message on ``sender``'s key arrived and was refused (schema, origin or stamp):
        delivered-and-dropped for the lockstep barrier (:meth:`missing`), so it is not
        awaited (docs/reference/faults.md, "Rejected messages and the lockstep barrier"). Attributed by
        the key, which names the sender: a refused message's own fields cannot be trusted."""
        if sender != self.name and sender in self._team:
            self.received_from[sender] = self.received_from.get(sender, 0) + 1
            if self.listens_to(sender):  # else overheard, counted by the safety stage's trust
                self.counters.add("refused_from_peers")

    def peer_alive(self, name: str, alive: bool) -> None:
        """A robot's liveliness changed (its process died or froze, or it came back)."""
        self.liveness.peer_alive(name, alive)

    def tokens_down(self, names) -> None:
        """Lockstep: the robots lost at this tick as the simulator applied their tokens'
        going (``Obs.down``), in place of this robot's own watch (:meth:`peer_alive`), so every
        robot learns of a loss at the same step in one process and over Zenoh
        (docs/reference/faults.md, "When the others learn of a loss"). Names outside the team
        are left out, as the token watch leaves them."""
        self.liveness.tokens_down(n for n in names if n in self._team)

    def receive(self, env: PeerEnvelope) -> None:
        """Accept a peer envelope that arrived (before faults); one stamped outside the
        receiver's :class:`~copath.wire.trust.StampWindow` is rejected and counted."""
        if env.sender == self.name:
            return
        if not self.listens_to(env.sender):
            # overheard on a key it would listen to were the sender its neighbour: counted, so
            # that the barrier knows what arrived should the sender become a stand-in, and the
            # newest kept for that step (:meth:`_stand_in`)
            if self.awaits_overheard or not self._arrived_late(env):
                self.received_from[env.sender] = self.received_from.get(env.sender, 0) + 1
            kept = self._overheard_last.get(env.sender)
            if kept is None or env.stamp >= kept.stamp:
                self._overheard_last[env.sender] = env
            return
        if self.trust.keep_early(env):  # no clock yet (a robot restarted mid-run)
            return
        if not self.trust.admit(env, "peer"):
            self.refused(env.sender)
            return
        if self.awaits_overheard or not self._arrived_late(env):  # else the barrier counts in overhear()
            self.received_from[env.sender] = self.received_from.get(env.sender, 0) + 1
        since = self._stand_in_since.get(env.sender)
        if since is not None and env.stamp < since - 1e-9:
            return  # sent before it stood in: in one process it came and went before (lockstep runs agree)
        self.faults.push(env)

    # -- one control instant: the pipeline ------------------------------------------------
    def step(self, obs: Obs, now: float) -> StepOutput:
        """Run one control instant at controller time ``now`` with the latest observation."""
        for env in self.trust.advance(now):  # trust
            self.receive(env)
        pose = np.asarray(obs.pose, dtype=float)
        if not self.envelopes.known:  # a restart: what the base applies is not known yet
            self.envelopes.observe(float(obs.t), pose, (obs.meas or {}).get("odom", ()))
        estimate = None
        if obs.meas is not None:  # estimate
            pose, estimate = self.estimator.pose(obs, now, pose, self._last_cmd)
        lost = self.liveness.lost
        released = self.faults.release(now, pose, lost)  # faults
        self.liveness.heard(released.senders, now)
        if self.safety is not None:
            self.safety.hear(released.envelopes)
        alive = self.liveness.update(now, lost)  # liveness
        events = alive.events
        # a robot cut off (it has lost every robot it heard) has nobody to stand in: they are quiet too
        gone = frozenset() if alive.cut_off else alive.lost
        if self._graph is not None and gone != self._stand_ins_for:
            self._stand_in(gone, now, events)
        if self.stand_ins:  # the closing account says how much of the inbox they made
            self.counters.add("stand_in_messages", sum(m.sender in self.stand_ins for m in released.messages))
        held = self.hold.held(alive.cut_off)
        ranges = None if obs.ranges is None else np.asarray(obs.ranges, dtype=float)
        seen, detour_offset = self.detour.step(now, pose, ranges, self._angles, released.messages, events,  # detour
                                               held, self.liveness, self.safety)
        observation = Observation(t=now, pose=seen, dt=self.dt, ranges=ranges, sensor_angles=self._angles,
                                  sensor_max_range=self._max_range, lost=alive.lost, joined=self.joined)
        res = self.control.step(observation, released.messages, obs.k, now)  # control
        telemetry = res.telemetry
        cmd = self.hold.apply(alive.cut_off, self.detour.command(res.command, self.envelopes.applied), telemetry)  # hold
        if detour_offset:
            telemetry["detour_offset"] = detour_offset
        # the pose is the observation's, true at obs.t: a realtime robot steps on its own timer,
        # up to a period later; the filter and the envelopes (pos_t) say so (docs/reference/safety.md,
        # "Late commands"); in lockstep the two are the same; the estimator's pose is predicted to now
        pose_t = now if estimate is not None else min(float(obs.t), now)
        if self.safety is not None:  # safety
            cmd = self.safety.apply(now, pose, cmd, ranges, self._angles, held, telemetry, self.liveness, pose_t,
                                    self.detour.turning)
        self.counters.steps += 1
        peers, vel = self.envelopes.send(now, pose, cmd, res.messages, self.estimator.position_cov,  # envelopes
                                         pose_t if pose_t < now else None,
                                         self.safety.guard.acks() if self.safety is not None else None)
        if self.safety is not None and peers:  # committed plans: the filter keeps what it published
            self.safety.published(pose_t, pose, vel)
        self._last_cmd = cmd
        return StepOutput(
            Command(obs.k, float(now), cmd, res.solve_ms, dict(self.sent)),
            peers,
            Telemetry(obs.k, float(now), to_plain(telemetry)),
            estimate,
            self.faults.events(now) + events + ([res.failure] if res.failure is not None else []),
        )

    def _stand_in(self, lost: frozenset[str], now: float, events: list[Event]) -> None:
        """Listen to the stand-ins for the robots lost now (:func:`copath.graph.stand_ins`); an
        event says who stands in for whom when they change."""
        self._stand_ins_for = lost
        found = frozenset(stand_ins(self._graph, self.name, lost))
        if found != self.stand_ins:
            for s in sorted(found - self.stand_ins):
                # its message of this very instant may have come already (in one process, from
                # the robots that step earlier; over Zenoh, as it happens): passed on at the next
                # step either way, and none from before (:meth:`receive`), so lockstep runs agree
                self._stand_in_since[s] = now
                kept = self._overheard_last.pop(s, None)
                if kept is not None and kept.stamp >= now - 1e-9 and self.trust.admit(kept, "peer", record=False):
                    self.faults.push(kept)
            for s in self.stand_ins - found:
                self._stand_in_since.pop(s, None)
            self.stand_ins = found
            if self.safety is not None:
                self.safety.listening(found)
            events.append(Event(float(now), self.name, "stand_ins",
                                {"robots": sorted(found), "lost": sorted(n for n in lost if n in self.neighbours)}))

    def closing_counters(self) -> dict:
        self.control.close()
        self.faults.close()
        self.counters.rejected = self.reject_log.total
        if self.safety is not None:
            self.counters.extra.update(self.safety.counters())
        return self.counters.as_dict()
