"""Stage "liveness": which robots are lost to this one, and whether it is cut off
(docs/reference/faults.md, "When a robot dies, freezes or goes quiet").

A robot is lost when its liveliness token goes (its process died or froze: the run's
``on_robot_failure``), or, here, when it was heard before and not for the run's lease
(``run.lease_s``: a radio gone quiet). Having lost every robot it has heard, at least one
by silence, this robot is cut off (:mod:`agent.stages.cut_off`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable

from copath.scenario import Scenario
from copath.wire.messages import Event

from .cut_off import CutOffRule

__all__ = ["Liveness", "LivenessStage"]


@dataclass
class Liveness:
    """The liveness stage's output at one control instant."""

    lost: frozenset[str]
    """Robots lost to this one (token gone or silent): the controller's ``Observation.lost``."""
    cut_off: bool
    events: list[Event] = field(default_factory=list)
    """``peer_lost`` / ``peer_rejoined`` / ``peer_silent`` / ``peer_heard`` / ``cut_off`` /
    ``reconnected`` events of this instant."""


class LivenessStage:
    """What one robot knows of the others' liveness.

    Reads: liveliness tokens (:meth:`peer_alive`, from the link's threads), the senders the
    fault layer released (:meth:`heard`) and those the safety filter overheard
    (:meth:`overheard`).
    Writes: :attr:`lost`, :attr:`cut_off`, and the events of their changes (:meth:`update`)."""

    name = "liveness"

    def __init__(self, scenario: Scenario, name: str, rule: CutOffRule, overhearing: bool) -> None:
        self.robot = name
        self.rule = rule
        self.overhearing = overhearing
        """Whether the safety filter overhears every robot's envelopes (then silence for the
        filter and for the cut-off is any envelope's, not only the inbox's)."""
        self.lost: frozenset[str] = frozenset()
        """Robots whose liveliness token went away (the run goes on without them,
        ``run.on_robot_failure``): their messages are dropped and the controller is told."""
        self.cut_off = False
        """Every robot of the team it has heard is lost here, at least one by silence."""
        self.silent_after_s = float(scenario.run.lease_s)
        """Silence threshold [s]: the run's transport lease, as for a frozen process."""
        self._team = frozenset(scenario.robot_names) - {name}
        """Every other robot of the scenario. Having lost every one of them it has heard (in its
        inbox or overheard) is being cut off; one it never heard cannot be lost."""
        self._watched = frozenset(scenario.robot(name).neighbours) if scenario.network.range_m == 0 else None
        """The robots whose silence it watches: its neighbours on a fixed graph (not a robot that
        stands in for a lost one, docs/reference/faults.md, "Stand-ins for a lost neighbour": it
        would be found silent once it stopped standing in), every robot on a range-limited one."""
        self._heard: dict[str, float] = {}
        """When a robot-to-robot message of each sender was last delivered here (after faults).
        Arrival, not the message's stamp: a neighbour whose every message is 1 s old (a slow
        link) is still heard every period; it is silence, not age, that makes it lost."""
        self._told: frozenset[str] = frozenset()
        """:attr:`lost` as of the last step (its changes are events)."""
        self._silent: dict[str, float] = {}
        """Senders heard before and not for the lease (a radio gone quiet): lost here,
        in ``Observation.lost``, until one of their messages is delivered again; the value
        is when they were last heard."""
        self._overheard_at: dict[str, float] = {}
        """When an overheard envelope of each sender was last delivered to the filter."""
        self.lost_at: dict[str, float] = {}
        """Each robot of :attr:`lost` and the step at which this robot first knew it [s]."""
        self._returned: dict[str, float] = {}
        """When each robot's liveliness token came back (a restarted or resumed process): until
        it is heard again, for a lease at most, it is not quiet for the filter
        (:meth:`quiet_for_filter`)."""

    def peer_alive(self, name: str, alive: bool) -> None:
        """A robot's liveliness changed (its process died or froze, or it came back)."""
        if name != self.robot:
            self.lost = self.lost - {name} if alive else self.lost | {name}  # replaced whole: thread-safe read

    def tokens_down(self, names: Iterable[str]) -> None:
        """Lockstep: the robots whose token is gone at this tick, as the simulator's observation
        says it (``Obs.down``): the lost set is replaced by it."""
        self.lost = frozenset(n for n in names if n != self.robot)

    def heard(self, senders: Iterable[str], now: float) -> None:
        """Senders whose envelopes the fault layer released at ``now`` (the watched ones count)."""
        watched = self._watched
        for s in senders:
            if watched is None or s in watched:
                self._heard[s] = now

    def overheard_all(self, senders: Iterable[str], now: float) -> None:
        """Overheard envelopes of ``senders`` reached the safety filter at ``now``."""
        self._overheard_at.update(dict.fromkeys(senders, now))

    def update(self, now: float, lost: frozenset[str]) -> Liveness:
        """The instant's liveness: ``lost`` (the token-lost robots as the step began) with the
        silent ones, cut off or not, and the events of what changed."""
        events = self._losses(now)
        lost = lost | frozenset(self._silent)
        cut = self._is_cut_off(now)
        if cut != self.cut_off:
            self.cut_off = cut
            events.append(Event(float(now), self.robot, "cut_off" if cut else "reconnected", {"held": self.rule.holds}))
        return Liveness(lost, cut, events)

    def quiet_for_filter(self, now: float) -> frozenset[str]:
        """Robots gone quiet for the safety filter: with overhearing, those whose every
        envelope (to anyone) has been missing for the lease (a follower that only talks to the
        leader is heard by the others' filters, not by their controllers); else the silent ones."""
        if not self.overhearing:
            quiet = frozenset(self._silent)
        else:
            # an envelope in its own inbox counts as well: a restarted robot's first one can be
            # delivered in the very step its token is seen back, before the filter overhears it
            # (an E5.4 soak: r6 began a 0.80 m detour round r5 in that step, docs/journal/faults.md,
            # "Heard, so not quiet")
            heard = self._heard
            quiet = frozenset(s for s, t in self._overheard_at.items()
                              if s not in self.lost and now - max(t, heard.get(s, -math.inf)) > self.silent_after_s + 1e-9)
        if not self._returned or not quiet:
            return quiet
        # a robot whose token came back after it was last heard is a process that drives
        # again (restarted, or resumed), not a radio gone quiet that holds itself still: the
        # filter keeps it as a robot back from a hold (docs/reference/safety.md, "A lost
        # robot"), and the detour stage does not go round it (in an E5.4 soak, r5 and r6 began
        # 0.79 m detours round r4 in the tick its restarted process rejoined, and the column
        # fell 0.55 m out of coordination; docs/journal/faults.md, "First instant or for good")
        # (for a lease: one that has not spoken by then is quiet again, and holds itself by
        # the cut-off rule)
        lease = self.silent_after_s + 1e-9
        return frozenset(s for s in quiet if not (
            now - self._returned.get(s, -math.inf) <= lease
            and self._returned[s] > max(self._heard.get(s, -math.inf), self._overheard_at.get(s, -math.inf))))

    def _is_cut_off(self, now: float) -> bool:
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
            if now - t <= self.silent_after_s + 1e-9:
                return False  # heard within the lease
            silent = True
        return silent

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
        if (lost == told and not self._silent
                and (not self._heard or now - min(self._heard.values()) <= self.silent_after_s + 1e-9)):
            return []  # no token changed, nobody silent, and nobody is yet (the common step)
        events = [Event(float(now), self.robot, "peer_lost", {"robot": r}) for r in sorted(lost - told)]
        events += [Event(float(now), self.robot, "peer_rejoined", {"robot": r}) for r in sorted(told - lost)]
        self._returned.update(dict.fromkeys(told - lost, float(now)))
        if lost != told:
            self.lost_at = {r: self.lost_at.get(r, float(now)) for r in lost}
        for s, t in sorted(self._heard.items()):
            if s in self.lost:  # its token went: lost already, whatever it says
                continue
            quiet = now - t > self.silent_after_s + 1e-9
            if quiet and s not in self._silent:
                self._silent[s] = t
                events.append(Event(float(now), self.robot, "peer_silent", {"robot": s, "last_heard": float(t)}))
            elif not quiet and s in self._silent:
                events.append(Event(float(now), self.robot, "peer_heard",
                                    {"robot": s, "silent_from": float(self._silent.pop(s))}))
        return events
