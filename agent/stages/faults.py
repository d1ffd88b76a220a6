"""Stage "faults": the receiver-side fault layer and the range filter.

Every peer envelope that passes the trust stage is queued through this robot's own fault
streams (delay, jitter, loss, bursts, partitions, silences: :mod:`copath.wire.faults`,
docs/reference/faults.md, "Faults tried" and "Determinism"); at a control instant the
released ones reach the controller unless their sender is lost or was beyond the
communication range when it sent them (Def. 10: the sender's position travels in the
envelope, no oracle)."""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field

import numpy as np

from copath.control import PeerMessage
from copath.scenario import Scenario
from copath.wire.faults import FaultyInbox, LinkFaults
from copath.wire.messages import Event, PeerEnvelope

from .counters import Counters

__all__ = ["FaultStage", "Released"]

_ORDER = operator.attrgetter("stamp", "sender", "seq")
"""The order released envelopes reach the controller in, whatever their arrival order."""


@dataclass
class Released:
    """What the fault layer released at one control instant."""

    senders: list[str] = field(default_factory=list)
    """Sender of every released envelope, lost or beyond range included (they were heard)."""
    envelopes: list[PeerEnvelope] = field(default_factory=list)
    """The delivered ones, in delivery order."""
    messages: list[PeerMessage] = field(default_factory=list)
    """The same, as the controller's inbox."""


class FaultStage:
    """One robot's fault layer on its incoming robot-to-robot links.

    Reads: admitted peer envelopes (:meth:`push`); at a control instant the step's time, the
    robot's pose and the robots lost to it (:meth:`release`).
    Writes: the controller's inbox; :class:`Counters` ``received``, ``dropped_by_faults``,
    ``partitioned``, ``out_of_range``, ``delivered``; ``faults_injected`` events
    (:meth:`events`)."""

    name = "faults"

    def __init__(self, scenario: Scenario, name: str, counters: Counters) -> None:
        self.robot = name
        self.layer = LinkFaults(scenario.network, scenario.run.seed, name)
        self.inbox = FaultyInbox(self.layer)
        self.comm_range = scenario.network.range_m
        """Communication range r [m] (Def. 10); 0: a fixed graph, no range filter."""
        self._counters = counters
        self._injected: list[tuple[float, str, str]] = []  # (stamp, sender, "dropped" | "partitioned" | "silenced")

    def push(self, env: PeerEnvelope) -> None:
        """Queue an admitted envelope through the fault streams; a drop is remembered for
        the ``faults_injected`` event of the step after its stamp."""
        c = self._counters
        c.received += 1
        partitioned, silenced = self.layer.partitioned, self.layer.silenced
        if not self.inbox.push(env.sender, env.stamp, env):
            c.dropped_by_faults = self.layer.dropped
            c.partitioned = self.layer.partitioned
            what = ("partitioned" if self.layer.partitioned > partitioned
                    else "silenced" if self.layer.silenced > silenced else "dropped")
            self._injected.append((env.stamp, env.sender, what))

    def in_range(self, env: PeerEnvelope, pose: np.ndarray) -> bool:
        """Whether ``env`` was sent within the communication range of ``pose`` (always on a
        fixed graph)."""
        return self.comm_range == 0 or math.hypot(env.pos[0] - pose[0], env.pos[1] - pose[1]) <= self.comm_range

    def release(self, now: float, pose: np.ndarray, lost: frozenset[str]) -> Released:
        """The envelopes released at ``now``, in a deterministic order whatever the arrival
        order (sums over neighbours stay bitwise equal); those of ``lost`` senders and from
        beyond range are dropped."""
        out = Released()
        for env in sorted(self.inbox.pop_ready(now), key=_ORDER):
            out.senders.append(env.sender)  # heard: when it was last heard, not how old its news is
            if env.sender in lost:
                continue
            if self.comm_range > 0 and math.hypot(env.pos[0] - pose[0], env.pos[1] - pose[1]) > self.comm_range:
                self._counters.out_of_range += 1
                continue
            out.envelopes.append(env)
            out.messages.append(PeerMessage(env.sender, env.kind, env.stamp, now - env.stamp, env.payload,
                                            tuple(env.pos), None if env.cov is None else tuple(env.cov)))
        self._counters.delivered += len(out.messages)
        return out

    def events(self, now: float) -> list[Event]:
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
        return [Event(float(now), self.robot, "faults_injected",
                      {"dropped": sum(v["dropped"] for v in by.values()),
                       "partitioned": sum(v["partitioned"] for v in by.values()),
                       "silenced": sum(v["silenced"] for v in by.values()),
                       "from": dict(sorted(by.items()))})]

    def close(self) -> None:
        """Copy the fault layer's totals into the counters (the closing account)."""
        self._counters.dropped_by_faults = self.layer.dropped
        self._counters.partitioned = self.layer.partitioned
        self._counters.extra["silenced"] = self.layer.silenced
