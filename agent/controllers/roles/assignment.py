"""Local role assignment and negotiation (Sec. 6.2.2, (6.5)-(6.7), Algorithm 6.2).

- :func:`local_hungarian`: the Hungarian method (6.7) on what one robot knows: itself
  and its unassigned neighbours x the positions it believes available; the robot adopts
  its own row. With more robots than positions it may get no column, and then takes
  the nearest position even though it is taken (Sec. 6.2.2).
- :func:`nearest_position`: the loser of a negotiation takes the nearest position of
  its available set (Algorithm 6.2, lines 6 and 11).
- :class:`RoleBook`: one robot's view J^a_i / J^t_i of the positions, merged with the
  neighbours' taken sets every step (docs/reference/ambiguities.md, sets united in Algorithm 6.2 (A24): line 2 unites the neighbours'
  *taken* sets), and the pairwise negotiation in which the robot with the higher index
  decides, ties going to it (line 5, d_i <= d_k).

All pure; the controller turns rulings into messages.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["assignment_cost", "local_hungarian", "nearest_position", "Ruling", "Claim", "RoleBook"]


def assignment_cost(robots, targets) -> np.ndarray:
    """Cost matrix c_ik = ||x_i - g_k||^2 of (6.5), shape (n_robots, n_targets)."""
    X = np.asarray(robots, dtype=float).reshape(-1, 2)
    G = np.asarray(targets, dtype=float).reshape(-1, 2)
    return np.sum((X[:, None, :] - G[None, :, :]) ** 2, axis=-1)


def local_hungarian(own, others, targets, available: Sequence[int]) -> int | None:
    """Own row of the local assignment problem (6.7) over {self} U neighbours x available.

    Parameters
    ----------
    own : (2,) array_like
        Own position.
    others : (n, 2) array_like
        Positions of the neighbours that have no position yet.
    targets : (M, 2) array_like
        All target positions g_k.
    available : sequence of int
        Indices of the positions this robot believes available (J^a_i).

    Returns
    -------
    int or None
        The position index assigned to this robot, or None when the local problem has
        more robots than available positions and this robot gets no column.
    """
    avail = list(available)
    if not avail:
        return None
    X = np.vstack([np.asarray(own, dtype=float).reshape(1, 2), np.asarray(others, dtype=float).reshape(-1, 2)])
    G = np.asarray(targets, dtype=float)[avail]
    rows, cols = linear_sum_assignment(assignment_cost(X, G))
    hit = np.nonzero(rows == 0)[0]
    return int(avail[cols[hit[0]]]) if len(hit) else None


def nearest_position(own, targets, candidates: Iterable[int]) -> int | None:
    """Index of the candidate target nearest to ``own`` (None if there is none)."""
    cand = list(candidates)
    if not cand:
        return None
    G = np.asarray(targets, dtype=float)[cand]
    d = np.hypot(*(G - np.asarray(own, dtype=float).reshape(2)).T)
    return int(cand[int(np.argmin(d))])


@dataclass(frozen=True)
class Ruling:
    """Outcome of one pairwise negotiation over a position (Algorithm 6.2)."""

    position: int
    winner: str
    loser: str


@dataclass(frozen=True)
class Claim:
    """A neighbour's claim as read from its latest message."""

    name: str
    index: int
    """Robot index: the higher index initiates the negotiation."""
    position: int
    """Claimed position, -1 for none."""
    distance: float
    """d_j = ||x_j - g_p(j)|| at sending [m]."""


@dataclass
class RoleBook:
    """One robot's bookkeeping for one task: p(i), J^t_i, negotiations (Algorithm 6.2).

    Parameters
    ----------
    name, index : str, int
        This robot; ``index`` orders the negotiation (higher index initiates).
    n_positions : int
        M, the number of positions of the formation (J_0 = {0..M-1}).
    """

    name: str
    index: int
    n_positions: int
    position: int = -1
    """p(i), -1 while unassigned."""
    taken: set[int] = field(default_factory=set)
    """J^t_i."""
    resolved: dict[tuple[int, str], Ruling] = field(default_factory=dict)
    """(position, other) -> the ruling this robot made on that pair as initiator. A ruling
    is final (Algorithm 6.2, lines 6-14: the loser is dequeued and moves on): it is
    repeated, never made again from newer distances (ruling of the negotiation is final, N9)."""
    won: set[tuple[int, str]] = field(default_factory=set)
    """(position, initiator) pairs where a ruling said this robot won."""
    conflicts_initiated: int = 0
    released: set[int] = field(default_factory=set)
    """Positions released from J^t_i because the robot that claimed them is lost
    (docs/reference/ambiguities.md, robot lost in role assignment (A38)): merges of the neighbours' taken sets skip them."""

    @property
    def available(self) -> list[int]:
        """J^a_i = J_0 minus J^t_i, ascending."""
        return [k for k in range(self.n_positions) if k not in self.taken]

    def claim(self, position: int | None) -> None:
        """Adopt ``position`` (None: stay unassigned) and mark it taken."""
        self.position = -1 if position is None else int(position)
        if self.position >= 0:
            self.taken.add(self.position)

    def merge(self, taken_sets: Iterable[Iterable[int]], claims: Iterable[int] = ()) -> None:
        """Algorithm 6.2 lines 1-2 with docs/reference/ambiguities.md, sets united in Algorithm 6.2 (A24): J^t_i <- J^t_i U (U_j J^t_j)."""
        skip, n, taken = self.released, self.n_positions, self.taken
        for ts in taken_sets:
            for k in ts:
                k = int(k)
                if 0 <= k < n and k not in skip:
                    taken.add(k)
        for k in claims:
            k = int(k)
            if 0 <= k < n:
                taken.add(k)

    def release(self, positions: Iterable[int]) -> None:
        """Release the positions of lost robots (docs/reference/ambiguities.md, robot lost in role assignment (A38)): they leave
        J^t_i, and later merges of taken sets skip them until :meth:`release` is called
        again without them (a live robot's own claim always counts)."""
        self.released = {int(k) for k in positions if 0 <= int(k) < self.n_positions and int(k) != self.position}
        self.taken -= self.released

    def conflicts(self, claims: Iterable[Claim]) -> list[Claim]:
        """Neighbours claiming this robot's position, in descending index order (queue A_i)."""
        if self.position < 0:
            return []
        out = [
            c
            for c in claims
            if c.position == self.position and (self.position, c.name) not in self.won
        ]
        return sorted(out, key=lambda c: -c.index)

    def negotiate(self, own_distance: float, conflicts: Sequence[Claim]) -> tuple[list[Ruling], bool]:
        """Run Algorithm 6.2 lines 3-16 for the conflicts this robot initiates.

        The robot initiates against every conflicting neighbour with a lower index, in
        descending index order; d_i <= d_k means it wins (ties go to the initiator).
        It stops at the first loss (A_i is emptied). A pair it has already ruled on keeps
        that ruling: the loser acts on it when it arrives, so a ruling made again from
        the distances of a later step, which may go the other way once both robots have
        moved, would send both away and leave the position empty while every robot counts
        it taken (docs/reference/controllers-notes.md, ruling of the negotiation is final
        (N9)).

        Returns
        -------
        rulings : list of Ruling
            New rulings made here (to be sent).
        waiting : bool
            True when a higher-index neighbour claims the same position and has not
            ruled yet: the robot must stop and wait for its ruling.
        """
        rulings = []
        waiting = False
        for c in conflicts:
            if c.index > self.index:
                waiting = True
                continue
            key = (self.position, c.name)
            ruling = self.resolved.get(key)
            if ruling is None:
                if own_distance <= c.distance:
                    ruling = Ruling(self.position, self.name, c.name)
                else:
                    ruling = Ruling(self.position, c.name, self.name)
                self.resolved[key] = ruling
                self.conflicts_initiated += 1
            rulings.append(ruling)
            if ruling.loser == self.name:
                break
        return rulings, waiting

    def lost(self, rulings: Iterable[Ruling]) -> bool:
        """Apply rulings addressed to this robot; True if it lost its current position."""
        lost = False
        for r in rulings:
            if r.position != self.position or self.position < 0:
                continue
            if r.loser == self.name:
                lost = True
            elif r.winner == self.name:
                self.won.add((r.position, r.loser))
        return lost
