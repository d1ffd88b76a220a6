"""Stage "safety": the decentralised safety filter between the controller and the wheels
(docs/reference/safety.md; :class:`copath.safety.SafetyGuard`).

With ``[safety] overhear`` (the default) the filter is fed with the sender position of every
peer envelope the robot overhears, through fault streams of its own (another seed), so the
controller's messages are the same with or without the filter; without it, with those of
the controller's inbox."""

from __future__ import annotations

import time
from typing import Iterable

import numpy as np

from copath.safety import GuardConfig, SafetyGuard
from copath.scenario import Scenario
from copath.wire.faults import FaultyInbox, LinkFaults
from copath.wire.keys import Keys
from copath.wire.messages import PeerEnvelope

from .counters import Counters
from .cut_off import CutOffRule
from .faults import FaultStage
from .liveness import LivenessStage
from .trust import TrustStage

__all__ = ["SafetyStage", "OVERHEAR_SEED", "command_lag_periods"]

OVERHEAR_SEED = 7919
"""Offset of the seed of the safety filter's own fault streams (independent of the controller's)."""


def command_lag_periods(scenario: Scenario) -> float:
    """``safety.command_lag_periods`` for the run's clock: as set, else 1 in lockstep (the
    command is applied at the tick it answers) and 2 in realtime (chosen: a command reaches the
    base up to a period late; docs/reference/safety.md, "Late commands")."""
    lag = scenario.safety.command_lag_periods
    if lag is not None:
        return float(lag)
    return 2.0 if scenario.run.clock == "realtime" else 1.0


class SafetyStage:
    """One robot's safety filter and what feeds it.

    Reads: overheard envelopes (:meth:`overhear`) or the inbox's (:meth:`hear`), the robot's
    pose, range ring and command, the robots lost or gone quiet (the liveness stage).
    Writes: the command (unless the robot is held still: the others keep out of its disc),
    telemetry ``safety_active``, ``safety_change``, ``safety_ms``, the liveness stage's
    overheard times, and the filter's counters in the closing account."""

    name = "safety"

    def __init__(self, scenario: Scenario, name: str, rule: CutOffRule, trust: TrustStage, faults: FaultStage,
                 counters: Counters, listened: frozenset[str]) -> None:
        self.robot = name
        self.guard = SafetyGuard(GuardConfig(
            safety=scenario.safety, name=name, models={r.name: r.model for r in scenario.robots}, dt=scenario.run.dt,
            sensor_count=scenario.sensors.count if scenario.sensors.enabled else 0,
            silent_hold_s=rule.silent_hold_s, handles_cut_off=rule.handled_by_controller,
            lag_periods=command_lag_periods(scenario),
            in_column=scenario.in_column(name)))
        self._overhear = (FaultyInbox(LinkFaults(scenario.network, scenario.run.seed + OVERHEAR_SEED, name))
                          if scenario.safety.overhear else None)
        self._trust = trust
        self._faults = faults
        self._counters = counters
        self._neighbours = listened
        self._listened = listened
        """Senders whose envelopes also reach the robot's inbox (whose trust stage counts their bad stamps)."""
        self._early: dict[str, PeerEnvelope] = {}
        """Before the first step: the newest overheard envelope of each sender (:meth:`overhear`)."""

    def listening(self, stand_ins: frozenset[str]) -> None:
        """The robot's inbox now also gets the envelopes of ``stand_ins`` (robots it listens to
        in place of lost neighbours, :func:`copath.graph.stand_ins`): their bad stamps are counted there."""
        self._listened = self._neighbours | stand_ins

    @property
    def overhearing(self) -> bool:
        """Whether the filter is fed by overhearing (``safety.overhear``)."""
        return self._overhear is not None

    def overhear_subscriptions(self, keys: Keys) -> list[str]:
        """Keys whose envelopes go to :meth:`overhear` (every robot's messages; none without overhearing)."""
        if self._overhear is None:
            return []
        return [keys.peer_broadcast("*"), keys.peer_direct("*", "*")]

    def overhear(self, env: PeerEnvelope) -> None:
        """Accept an overheard envelope: only its sender's position and stamp are used.

        Before the first step there is no clock to check a stamp against: the newest
        envelope of each sender is kept and checked at the first step's clock, as the trust
        stage keeps the inbox's (a robot restarted mid-run sees who is round it in its first
        period, not one period later; one from before the window is refused then). A
        neighbour's envelope also reaches the inbox, whose check counts a bad stamp; here
        only the others' are counted, so one bad message is one reject."""
        if self._overhear is None or env.sender == self.robot:
            return
        if not self._trust.started:
            kept = self._early.get(env.sender)
            if kept is None or env.stamp >= kept.stamp:
                self._early[env.sender] = env
            return
        self._admit(env)

    def _admit(self, env: PeerEnvelope, record: bool = True) -> None:
        if self._trust.admit(env, "overheard", record=record and env.sender not in self._listened):
            extra = self._counters.extra  # Counters.add, inline: once per robot and overheard envelope
            extra["overheard"] = extra.get("overheard", 0) + 1
            self._overhear.push(env.sender, env.stamp, env)

    def hear(self, envelopes: Iterable[PeerEnvelope]) -> None:
        """Without overhearing: the envelopes the controller's inbox got at this instant."""
        if self._overhear is None:
            for env in envelopes:
                self.guard.hear(env.sender, env.pos, env.stamp, env.vel, env.pos_t, env.acks)

    def apply(self, now: float, pose: np.ndarray, command: list[float], ranges, angles, held: bool,
              telemetry: dict, liveness: LivenessStage, pose_t: float | None = None,
              turning: bool = False) -> list[float]:
        """The filtered command at ``now`` (the command itself when ``held``: the others keep
        out of a held robot's disc); ``pose_t`` is when ``pose`` was true (None: ``now``);
        ``turning``: the detour stage turns the robot on the spot (:meth:`copath.safety.SafetyFilter.filter`)."""
        t0 = time.perf_counter()
        if self._early:  # the first step: what was overheard before it, at this clock
            early, self._early = self._early, {}
            for env in early.values():
                self._admit(env, record=False)  # stale by the wait, not bad: no reject
        if self._overhear is not None:
            ready = self._overhear.pop_ready(now)
            liveness.overheard_all([env.sender for env in ready], now)
            hear, ranged = self.guard.hear, self._faults.comm_range > 0
            for env in ready:
                if not ranged or self._faults.in_range(env, pose):
                    hear(env.sender, env.pos, env.stamp, env.vel, env.pos_t, env.acks)
        res = self.guard.apply(pose, command, now, ranges, angles, liveness.lost, liveness.quiet_for_filter(now),
                               pose_t, turning)
        if not held:
            command = res.command.tolist()
        telemetry.update(safety_active=res.active, safety_change=res.change, safety_ms=(time.perf_counter() - t0) * 1e3)
        return command

    def published(self, now: float, pose: np.ndarray, velocity: list[float]) -> None:
        """This robot published envelopes at ``now`` (committed plans: the filter keeps what it promised)."""
        self.guard.published(now, pose, velocity)

    def counters(self) -> dict:
        return self.guard.counters()
