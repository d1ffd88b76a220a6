"""The neighbours one robot of a Chapter 6 team has heard: the range-limited graph (Def. 10),
from the newest ``role_state`` of each (:class:`copath.control.LatestMessages`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from copath.control import LatestMessages, PeerMessage

from .payloads import CONSENSUS, MESSAGE_KIND

__all__ = ["Peer", "PeerTable"]


@dataclass
class Peer:
    """Newest ``role_state`` of one neighbour."""

    heard: float
    """Own clock when it was received [s]."""
    age: float
    """Age of the message when it was received [s] (its age at t is age + t - heard)."""
    position: np.ndarray
    """Sender position extrapolated to ``heard`` [m]."""
    velocity: np.ndarray
    task: int
    index: int
    phase: int
    payload: dict[str, Any] = field(repr=False)


def _has_position(m: PeerMessage) -> bool:
    return m.position is not None or m.payload.get("pos") is not None


class PeerTable:
    """Neighbours of a range-limited graph (Def. 10): robots heard within ``timeout`` [s]."""

    def __init__(self, timeout: float) -> None:
        self.timeout = float(timeout)
        self.inbox = LatestMessages(kinds=(MESSAGE_KIND,), accept=_has_position)
        self.peers: dict[str, Peer] = {}
        self.lost: frozenset[str] = frozenset()
        """Robots known to be gone (``Observation.lost``): out of the graph at once."""
        self._fresh: tuple[float, dict[str, Peer], dict[int, dict[str, Peer]]] | None = None
        """(t, neighbours at t, task -> those working on it), reset by :meth:`ingest`."""

    def ingest(self, inbox, t: float, lost: frozenset[str] = frozenset()) -> None:
        """Take in one step's messages (newest per neighbour by stamp); ``lost`` are the
        robots known to be gone (docs/reference/ambiguities.md, robot lost in role assignment (A38))."""
        self._fresh = None
        self.lost = frozenset(lost)
        for got in self.inbox.update(inbox, t):
            pl = dict(got.payload)
            pos = got.position if got.position is not None else pl.get("pos")
            v = pl.get("vel") or (0.0, 0.0)
            age = max(got.message.age, 0.0)
            if len(v) == 2 and len(pos) == 2:
                # floats, then one array: the same two products and sums numpy's
                # pos + vel * age does (docs/journal/performance.md, over Zenoh, third pass (P23))
                vx, vy = float(v[0]), float(v[1])
                vel = np.array((vx, vy))
                position = np.array((float(pos[0]) + vx * age, float(pos[1]) + vy * age))
            else:
                vel = np.asarray(v, dtype=float)
                position = np.asarray(pos, dtype=float) + vel * age
            self.peers[got.sender] = Peer(
                heard=got.received_at,
                age=age,
                position=position,
                velocity=vel,
                task=int(pl.get("task", -1)),
                index=int(pl.get("index", 0)),
                phase=int(pl.get("phase", CONSENSUS)),
                payload=pl,
            )

    def fresh(self, t: float) -> dict[str, Peer]:
        """Neighbours N_i at time t (computed once per step: callers must not modify it)."""
        if self._fresh is None or self._fresh[0] != t:
            lost = self.lost
            self._fresh = (t, {n: q for n, q in self.peers.items()
                               if t - q.heard <= self.timeout and n not in lost}, {})
        return self._fresh[1]

    def wrecks(self) -> list[np.ndarray]:
        """Last heard positions of the lost robots: a robot that went quiet or died is
        still somewhere, so it stays an obstacle where it was last heard (robot lost in role assignment, A38)."""
        return [self.peers[n].position for n in sorted(self.lost) if n in self.peers]

    def cut_off(self, team: frozenset[str]) -> bool:
        """Every other robot of the team is lost (robot lost in role assignment, A38): most likely this robot's own radio
        has gone quiet, not all of theirs, and the others have lost it in turn. (Its
        neighbours alone would not do: in a range-limited graph a robot may have heard only
        the one that was lost.)"""
        return bool(team) and team <= self.lost

    def last_stamp(self) -> float:
        """Send stamp of the newest message heard from any robot [s] (-inf: none): a radio
        that went quiet stopped both ways, so the others last heard this robot about then."""
        return max((q.heard - q.age for q in self.peers.values()), default=-math.inf)

    def same_task(self, t: float, task: int) -> dict[str, Peer]:
        """Neighbours working on ``task`` (once per step and task: callers must not modify it)."""
        fresh = self.fresh(t)
        by_task = self._fresh[2]
        if task not in by_task:
            by_task[task] = {n: q for n, q in fresh.items() if q.task == task}
        return by_task[task]
