"""The phases of one robot's Chapter 6 task, one small state object each.

:class:`~.controller.RolesController` ties them together; each object here holds the
state of one phase only, creates every attribute in ``__init__`` and builds no message:

- :class:`PeerTable`      the neighbours heard within ``neighbour_timeout_s`` (the
                          range-limited graph of Def. 10), from the newest ``role_state``
                          of each (:class:`copath.control.LatestMessages`);
- :class:`Agreement`      phase 1, Algorithm 6.1: average consensus on the moment vector
                          (6.8)-(6.9) and the local agreement test that ends it;
- :class:`Assignment`     phase 2, Sec. 6.2.2 and Algorithm 6.2: the target positions of
                          the task, the initial choice by a local Hungarian problem (6.7),
                          claims, rulings of the negotiation and the waiting place of a
                          robot without a position;
- :class:`Motion`         phase 3, (6.10)-(6.15): driving to the goal with the repulsive
                          target shift and the sideways escape from a standstill, and the
                          settling test of a robot without a position;
- :class:`TaskSequence`   phase 4, (6.16): the task index, the PI dynamic consensus on the
                          fraction of unfinished robots and what is kept across tasks.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from copath.control import LatestMessages, PeerMessage

from .assignment import Claim, RoleBook, Ruling, local_hungarian, nearest_position
from .config import RolesConfig
from .averaging import AverageConsensus, NeighbourContribution, PIConsensus
from .navigation import NavigationGains, parking_point, polar_control, repulsive_shift
from .rotation import moment_vector

__all__ = [
    "MESSAGE_KIND",
    "CONSENSUS",
    "ASSIGNED",
    "UNASSIGNED",
    "Peer",
    "PeerTable",
    "Agreement",
    "Assignment",
    "Motion",
    "TaskSequence",
]

logger = logging.getLogger(__name__)

MESSAGE_KIND = "role_state"
CONSENSUS, ASSIGNED, UNASSIGNED = 0, 1, 2
"""Phases of the assignment: agreeing on the transform; holding a position; without a position."""

N_MOMENTS = 5
"""Size of the moment vector (6.8)-(6.9): x, y, x^2, xy, y^2."""


# -- neighbours ------------------------------------------------------------------------


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
            vel = np.asarray(pl.get("vel") or (0.0, 0.0), dtype=float)
            self.peers[got.sender] = Peer(
                heard=got.received_at,
                age=max(got.message.age, 0.0),
                position=np.asarray(pos, dtype=float) + vel * max(got.message.age, 0.0),
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


# -- phase 1: agreement on the formation's placement ----------------------------------


class Agreement:
    """Average consensus on the moment vector (Algorithm 6.1) and its local stop test.

    The robot adopts the estimate once neighbours' estimates and its own change over
    ``consensus_hold_s`` stay within ``consensus_tol`` (or after ``consensus_timeout_s``).

    A same-task neighbour stays a consensus neighbour while it was heard within the
    longer of ``neighbour_timeout_s`` and ``consensus_hold_s``: under loss a neighbour
    that drops out of the range-limited graph for a few silent steps and comes back
    would change every degree, hence every Metropolis weight, and stop the iteration
    each time (docs/reference/envelope.md). Its edge flow is state, so its newest one is used.
    """

    def __init__(self, name: str, p: np.ndarray, cfg: RolesConfig) -> None:
        self.name = name
        self.cfg = cfg
        self.ac = AverageConsensus(moment_vector(p), gain=cfg.consensus_gain)
        self.history: list[tuple[float, np.ndarray, float]] = []
        """(t, estimate, largest neighbour disagreement) over the hold window."""
        self.neighbours: dict[str, NeighbourContribution] = {}
        self.memory_s = max(cfg.neighbour_timeout_s, cfg.consensus_hold_s)
        """A neighbour counts while heard within this [s]."""
        self.heard: dict[str, Peer] = {}
        """Newest same-task state of every consensus neighbour."""

    def step(self, same: dict[str, Peer], t: float | None = None, lost: frozenset[str] = frozenset()) -> np.ndarray:
        """One consensus iteration over the neighbours' latest contributions; the estimate.
        A robot in ``lost`` leaves at once instead of after the memory (robot lost in role assignment, A38)."""
        self.heard.update(same)
        if t is not None:
            self.heard = {n: q for n, q in self.heard.items()
                          if n in same or (t - q.heard <= self.memory_s and n not in lost)}
        nbrs = {}
        for n, q in (self.heard if t is not None else same).items():
            x = q.payload.get("ac_x")
            if not x or len(x) != N_MOMENTS:
                continue
            to = q.payload.get("ac_to") or []
            flows = q.payload.get("ac_a") or []
            echoes = q.payload.get("ac_e") or []
            a = np.zeros(N_MOMENTS)
            echo = np.zeros(N_MOMENTS)  # it has not heard us yet: nothing of ours applied
            if self.name in to:
                k = to.index(self.name)
                a = np.asarray(flows[k * N_MOMENTS:(k + 1) * N_MOMENTS], dtype=float)
                if len(echoes) == len(flows):
                    echo = np.asarray(echoes[k * N_MOMENTS:(k + 1) * N_MOMENTS], dtype=float)
            nbrs[n] = NeighbourContribution(np.asarray(x, dtype=float), int(q.payload.get("ac_deg", 0)), a, echo)
        self.neighbours = nbrs
        return self.ac.step(nbrs)

    def settled(self, est: np.ndarray, t: float, task_start: float) -> tuple[bool, bool]:
        """(agreed, timed out) after recording this step's estimate."""
        cfg = self.cfg
        spread = max((float(np.max(np.abs(c.estimate - est))) for c in self.neighbours.values()), default=math.inf)
        self.history.append((t, est.copy(), spread))
        hold = cfg.consensus_hold_s
        window = [h for h in self.history if h[0] >= t - hold - 1e-9]
        self.history = window
        timed_out = t - task_start >= cfg.consensus_timeout_s
        agreed = (
            t - task_start >= hold
            and all(h[2] <= cfg.consensus_tol for h in window)
            and float(np.max(np.abs(window[0][1] - est))) <= cfg.consensus_tol
        )
        return agreed, timed_out

    def payload(self) -> dict[str, Any]:
        """The consensus fields of ``role_state`` (edge-flow form, see :class:`AverageConsensus`)."""
        to = sorted(self.neighbours)
        return {
            "ac_x": [float(c) for c in self.ac.estimate],
            "ac_to": to,
            "ac_a": [float(c) for n in to for c in self.ac.flow_to(n)],
            "ac_e": [float(c) for n in to for c in self.ac.echo_to(n)],
            "ac_deg": len(to),
        }


# -- phase 2: assignment and negotiation ----------------------------------------------


EN_ROUTE, ON_IT, WAITING = 0, 1, 2
"""State of a robot in the claims table (robot lost in role assignment, A38): heading for its position (or still agreeing),
standing on it (within ``2 arrive_tol``), without a position."""


def _entries(table: Any, width: int):
    """(name, value) pairs of a relayed ``claims`` table (width 5: [position, stamp, state,
    x, y]) or ``gone`` table (width 0: a stamp); malformed entries are skipped, so a bad
    message cannot stop the controller."""
    if not isinstance(table, dict):
        return
    for m, e in table.items():
        try:
            if not isinstance(m, str):
                continue
            if width == 0:
                v = float(e)
                ok = math.isfinite(v)
            elif isinstance(e, list) and len(e) == width:
                v = (int(e[0]), float(e[1]), int(e[2]), float(e[3]), float(e[4]))
                ok = all(math.isfinite(c) for c in v[1:])
            else:
                continue
        except (TypeError, ValueError, OverflowError):
            continue
        if ok:
            yield m, v


class Assignment:
    """Positions of the task, this robot's claim and the negotiation (Algorithm 6.2)."""

    def __init__(self, name: str, index: int, n_positions: int, p: np.ndarray, t: float) -> None:
        self.name = name
        self.index = index
        self.book = RoleBook(name, index, n_positions)
        self.phase = CONSENSUS
        self.targets: np.ndarray | None = None
        """(M, 2) target positions once the placement is agreed."""
        self.park: np.ndarray | None = None
        """Waiting place of a robot without a position."""
        self.rulings_out: dict[tuple[int, str, str], float] = {}
        """Rulings this robot made -> when; repeated for a while so a lost message does not lose them."""
        self.snapshot = np.asarray(p, dtype=float).copy()
        """Own start position of the task."""
        self.known: dict[str, tuple[float, float]] = {name: (float(p[0]), float(p[1]))}
        """With ``relay_positions``: robot -> its start position of the task, relayed over
        hops. A robot's start position is fixed for the task, so an entry never changes
        once known and the table only grows; the message carries it as
        ``{name: [x, y]}`` (:meth:`relay`)."""
        self.known_changed = t
        self.claims: dict[str, tuple[int, float, int, float, float]] = {}
        """Who claims what (robot lost in role assignment, A38): robot -> (claimed position or -1, stamp of the message that
        said so, state :data:`EN_ROUTE` / :data:`ON_IT` / :data:`WAITING`, x, y), the newest
        per robot, heard directly or relayed by the neighbours (``claims``)."""
        self.gone: dict[str, float] = {}
        """Tombstones (robot lost in role assignment, A38): lost robot -> stamp of its newest claim known when it was lost;
        a claim of that robot stamped later lifts it (it was heard again)."""
        self._lost_seen: frozenset[str] = frozenset()
        self.near: tuple[int, float] | None = None
        """(claimed position, since when) while this robot has announced itself within
        ``R_max`` of it in every message (state :data:`ON_IT`), None otherwise."""
        self.avail_since = (tuple(), t)
        """(J^a_i, since when unchanged): a robot without a position waits ``gather_s``
        before it takes a released one."""
        self.announce_targets = False
        self.announce_index = False

    @property
    def position(self) -> int:
        """Claimed position index, -1 without one."""
        return self.book.position

    def place(self, targets: np.ndarray) -> None:
        """The agreed target positions (docs/reference/ambiguities.md, rotation direction and order of translation (A22), for the transform)."""
        self.targets = targets
        self.announce_targets = True

    def initial_choice(self, p: np.ndarray, same: dict[str, Peer], fresh: dict[str, Peer], task: int,
                       relay: bool) -> int | None:
        """Initial choice (Sec. 6.2.2): own row of a local Hungarian problem (6.7).

        One-hop exchange (the text): rows are this robot and its neighbours without a
        position, columns the positions it believes available; a robot left without a
        column takes the nearest position even though it is taken, and the negotiation
        sorts it out. With ``relay`` every robot solves the same problem, all robots it
        has heard of (start positions of the task) x all positions, so the choices agree
        without negotiation whenever the tables agree; a robot left without a column then
        knows that the whole team's optimum has no role for it and goes without one
        instead of contesting a taken position.
        """
        self.merge(same)
        if relay:
            others = [xy for n, xy in sorted(self.known.items()) if n != self.name and n not in self.gone]
            pos = local_hungarian(self.snapshot, others, self.targets, range(len(self.targets)))
            if pos is not None and pos in self.book.taken:
                # someone already holds it (a robot this one has not heard of): nearest free one
                pos = nearest_position(p, self.targets, self.book.available)
            return pos
        others = [q.position for q in fresh.values() if not (q.task == task and q.phase in (ASSIGNED, UNASSIGNED))]
        pos = local_hungarian(p, others, self.targets, self.book.available)
        if pos is None:  # N > M: no column left -> the nearest position, even if taken
            pos = nearest_position(p, self.targets, range(len(self.targets)))
        return pos

    def take(self, pos: int | None) -> None:
        """Claim ``pos`` (None: go without a position)."""
        self.book.claim(pos)
        self.announce_index = True
        if pos is None:
            self.phase = UNASSIGNED
        else:
            self.phase = ASSIGNED
            self.park = None

    def reassign_choice(self, p: np.ndarray) -> int | None:
        """The loser takes the nearest available position, or none (Algorithm 6.2)."""
        old = self.book.position
        return nearest_position(p, self.targets, [k for k in self.book.available if k != old])

    def priority_parks(self, same: dict[str, Peer]) -> list:
        """Waiting places announced by same-task robots without a role and a lower index."""
        return [
            q.payload.get("park")
            for q in same.values()
            if q.phase == UNASSIGNED and q.index < self.index and len(q.payload.get("park") or []) == 2
        ]

    def set_park(self, p: np.ndarray, same: dict[str, Peer], clearance: float) -> None:
        self.park = parking_point(p, self.targets.mean(axis=0), self.targets, clearance, self.priority_parks(same))

    def check_park(self, p: np.ndarray, same: dict[str, Peer], clearance: float) -> None:
        """Move the waiting place when a robot with priority announced one too close to it."""
        avoid = self.priority_parks(same)
        if avoid and min(float(np.hypot(*(np.asarray(a) - self.park))) for a in avoid) < clearance - 1e-6:
            self.set_park(p, same, clearance)

    def relay(self, same: dict[str, Peer], t: float) -> None:
        """Merge the neighbours' tables of start positions (``known``, ``{name: [x, y]}``);
        a name not heard of before grows the table (and restarts the ``gather_s`` wait)."""
        known = self.known
        for q in same.values():
            table = q.payload.get("known")
            if not isinstance(table, dict):
                continue
            for name, xy in table.items():
                if name in known or not (isinstance(xy, list) and len(xy) == 2):
                    continue
                known[name] = (float(xy[0]), float(xy[1]))
                self.known_changed = t

    def known_payload(self) -> dict[str, list[float]]:
        """The table for the message: ``{name: [x, y]}`` by name (one map of pairs: a
        third of the decoding and validation cost of a list of records per entry)."""
        return {n: [x, y] for n, (x, y) in sorted(self.known.items())}

    def track_claims(self, same: dict[str, Peer], lost: frozenset[str], t: float, at_tol: float) -> None:
        """Keep who claims which position and release the positions of lost robots (robot lost in role assignment, A38).

        Claims are merged newest-stamp-first from the neighbours' own claims and the
        tables they relay; tombstones from this robot's ``lost`` (when a robot enters it)
        and from the neighbours' ``gone``. A lost robot's position is released unless a
        live robot claims it too, or the lost robot was last heard standing on it (its
        body still fills it).
        """
        claims, gone = self.claims, self.gone
        for n, q in same.items():
            for m, e in _entries(q.payload.get("claims"), 5):
                if m != self.name and (m not in claims or e[1] > claims[m][1]):
                    claims[m] = e
            stamp = q.heard - q.age
            if n not in claims or stamp >= claims[n][1]:
                state = (WAITING if q.phase == UNASSIGNED
                         else ON_IT if float(q.payload.get("d", math.inf)) <= at_tol else EN_ROUTE)
                claims[n] = (int(q.payload.get("claim", -1)), stamp, state, float(q.position[0]), float(q.position[1]))
            for m, e in _entries(q.payload.get("gone"), 0):
                if m != self.name and e > gone.get(m, -math.inf):
                    gone[m] = e
        for m in lost - self._lost_seen:  # newly lost here
            gone[m] = max(gone.get(m, -1.0), claims[m][1] if m in claims else -1.0)  # stamps are >= 0
        self._lost_seen = frozenset(lost)
        for m in [m for m, s in gone.items() if m in claims and claims[m][1] > s]:
            del gone[m]  # heard claiming again: it has rejoined
        if not gone:
            if self.book.released:
                self.book.release(())
            return
        live = {c[0] for m, c in claims.items() if m not in gone}
        free = {claims[m][0] for m in gone if m in claims and claims[m][0] >= 0 and claims[m][2] != ON_IT}
        self.book.release(free - live)

    def track_near(self, d: float, t: float, at_tol: float) -> None:
        """Record whether this step's message, which says the robot is ``d`` from its
        position, announces it within ``at_tol`` (:data:`ON_IT`), as the others judge it
        when they lose it."""
        if self.phase == ASSIGNED and d <= at_tol:
            if self.near is None or self.near[0] != self.position:
                self.near = (self.position, t)
        else:
            self.near = None

    def kept_while_lost(self, last_heard: float) -> bool:
        """The others keep this robot's position after losing it (robot lost in role assignment, A38): it announced itself
        within ``R_max`` of it from before ``last_heard`` (the stamp of the newest message
        it heard, when its own last reached them) until now. The robot knows what it said,
        so it applies to itself the rule the others apply to it."""
        return self.near is not None and self.near[1] <= last_heard

    def claims_payload(self, t: float, p: np.ndarray, at_tol: float) -> dict[str, list]:
        """The claims table for the message, own entry first-hand (robot lost in role assignment, A38)."""
        out = {m: [c[0], c[1], c[2], c[3], c[4]] for m, c in sorted(self.claims.items())}
        state = (WAITING if self.phase == UNASSIGNED
                 else ON_IT if self.distance(p) <= at_tol else EN_ROUTE)
        out[self.name] = [int(self.book.position), float(t), state, float(p[0]), float(p[1])]
        return out

    def take_released(self, p: np.ndarray, t: float, wait_s: float) -> int | None:
        """A robot without a position takes a released one (robot lost in role assignment, A38): its own row of the
        Hungarian problem (6.7) over the live robots without a position in its claims
        table (relayed, so robots that do not hear each other solve the same problem) x
        J^a_i, once J^a_i has not changed for ``wait_s``. Only after a loss (no-loss runs
        are unchanged)."""
        avail = tuple(self.book.available)
        if avail != self.avail_since[0]:
            self.avail_since = (avail, t)
        if not self.gone or not avail or t - self.avail_since[1] < wait_s - 1e-9:
            return None
        others = [c[3:5] for m, c in sorted(self.claims.items())
                  if m != self.name and m not in self.gone and c[2] == WAITING]
        return local_hungarian(p, others, self.targets, avail)

    def merge(self, same: dict[str, Peer]) -> None:
        """Unite the taken sets and claims the neighbours announced (ambiguity sets united in Algorithm 6.2 (A24))."""
        self.book.merge((q.payload.get("taken") or () for q in same.values()),
                        (int(q.payload.get("claim", -1)) for q in same.values()))

    def lost_a_ruling(self, same: dict[str, Peer]) -> bool:
        """A neighbour ruled that this robot lost its claimed position."""
        incoming = []
        for q in same.values():
            for r in q.payload.get("rulings") or []:
                if len(r) == 3 and self.name in (r[1], r[2]):
                    ruling = Ruling(int(r[0]), str(r[1]), str(r[2]))
                    winner = same.get(ruling.winner)
                    if (ruling.loser == self.name and winner is not None
                            and int(winner.payload.get("claim", -1)) != ruling.position):
                        continue  # the winner has left the position since: an outdated ruling (delay)
                    incoming.append(ruling)
        return self.book.lost(incoming)

    def resolve_conflicts(self, same: dict[str, Peer], p: np.ndarray, t: float) -> tuple[bool, bool]:
        """Negotiate the claims that conflict with this robot's (Algorithm 6.2).

        Returns (wait, lost): stop for this step; this robot lost its position.
        """
        claims = [
            Claim(n, q.index, int(q.payload.get("claim", -1)), float(q.payload.get("d", math.inf)))
            for n, q in same.items()
            if q.phase == ASSIGNED
        ]
        conflicts = self.book.conflicts(claims)
        if not conflicts:
            return False, False
        rulings, waiting = self.book.negotiate(self.distance(p), conflicts)
        for r in rulings:
            self.rulings_out.pop((r.position, r.loser, r.winner), None)  # a reversed ruling withdraws the old one
            self.rulings_out[(r.position, r.winner, r.loser)] = t
        if any(r.loser == self.name for r in rulings):
            return False, True
        return waiting, False

    def distance(self, p: np.ndarray) -> float:
        """Distance to the claimed position (inf without one)."""
        if self.phase == ASSIGNED and self.targets is not None:
            return float(np.hypot(*(self.targets[self.book.position] - p)))
        return math.inf

    def goal(self) -> np.ndarray | None:
        if self.phase == ASSIGNED:
            return self.targets[self.book.position]
        if self.phase == UNASSIGNED:
            return self.park
        return None

    def recent_rulings(self, t: float) -> list[list]:
        """Rulings of the last second (forgetting older ones), for the message."""
        self.rulings_out = {k: t0 for k, t0 in self.rulings_out.items() if t - t0 <= 1.0}
        return [[int(k[0]), k[1], k[2]] for k in self.rulings_out]


# -- phase 3: navigation ------------------------------------------------------------------


class Motion:
    """Driving to the goal with (6.11) and the repulsive shift (6.12)-(6.15), plus the
    sideways target change that breaks a standstill away from the target (Sec. 6.2.2)."""

    def __init__(self, cfg: RolesConfig, gains: NavigationGains, model, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.gains = gains
        self.model = model
        self.rng = rng
        self.track: list[tuple[float, np.ndarray]] = []
        """Own positions over the last ``stuck_s`` (standstill detection)."""
        self.escape_until = -math.inf
        self.escape_vec = np.zeros(2)
        self.settle_track: list[tuple[float, np.ndarray]] = []
        """Own positions over the last ``settle_s`` (settling of a robot without a role)."""

    def drive(self, pose: np.ndarray, goal: np.ndarray, obstacles: list, t: float, name: str = "") -> np.ndarray:
        """Unicycle command (v, omega) towards ``goal`` avoiding ``obstacles`` (positions)."""
        cfg = self.cfg
        p = pose[:2]
        e = float(np.hypot(*(goal - p)))
        self.track.append((t, p.copy()))
        self.track = [h for h in self.track if h[0] >= t - cfg.stuck_s - 1e-9]
        if t >= self.escape_until and e > 2 * cfg.arrive_tol and cfg.escape_m > 0:
            t0, p0 = self.track[0]
            if t - t0 >= cfg.stuck_s - 1e-9 and np.hypot(*(p - p0)) < 0.03:
                u = (goal - p) / max(e, 1e-9)
                side = 1.0 if self.rng.random() < 0.5 else -1.0
                self.escape_vec = side * cfg.escape_m * np.array([-u[1], u[0]])
                self.escape_until = t + cfg.escape_s
                self.track = []
                logger.debug("%s: standstill at %.2f m from the target; escaping sideways", name, e)
        g = goal + (self.escape_vec if t < self.escape_until else 0.0)
        g_new = repulsive_shift(p, g, obstacles, self.gains)
        v, w = polar_control(pose, g_new, cfg.k_c, cfg.gamma, cfg.stop_radius)
        cmd, _ = self.model.saturate((v, w))
        return cmd

    def settled(self, p: np.ndarray, park: np.ndarray, t: float) -> bool:
        """A robot without a role has finished: near its waiting place, or hardly moved for
        ``settle_s`` (repulsion from a neighbour may hold it off the exact point)."""
        cfg = self.cfg
        self.settle_track.append((t, p.copy()))
        self.settle_track = [h for h in self.settle_track if h[0] >= t - cfg.settle_s - 1e-9]
        t0, p0 = self.settle_track[0]
        still = t - t0 >= cfg.settle_s - 1e-9 and float(np.hypot(*(p - p0))) < cfg.arrive_tol
        near = float(np.hypot(*(park - p))) < 2 * cfg.arrive_tol
        return near or still


# -- phase 4: task sequencing ---------------------------------------------------------


class TaskSequence:
    """The queue of formations: task index, the PI dynamic consensus (6.16) on
    w_i (1 unfinished, 0 finished) and what is kept across tasks."""

    def __init__(self, cfg: RolesConfig) -> None:
        self.cfg = cfg
        self.n_tasks = len(cfg.formations)
        self.pi = PIConsensus(cfg.k_z, cfg.k_p, cfg.k_i)
        self.task = -1
        self.task_start = 0.0
        self.done = False
        """This robot has finished the current task."""
        self.conflicts_total = 0
        """Negotiations initiated in the finished tasks."""
        self.transform: tuple[np.ndarray, float] | None = None
        """Agreed (centroid, rotation), kept across tasks when ``transform_every_task`` is off."""

    @property
    def started(self) -> bool:
        return self.task >= 0

    def begin(self, k: int, t: float) -> None:
        """Start formation k: reset (6.16) (ambiguity reset at a task switch (A26))."""
        self.task = k
        self.task_start = t
        self.done = False
        self.pi.reset(1.0)

    def step(self, same: dict[str, Peer], dt: float, t: float | None = None) -> float:
        """(6.16) with w_i = 0 once this robot has finished its task; returns z_i. With the
        time t, the neighbours' z_j, eta_j are predicted over their message age with the
        rates they sent (:class:`.consensus.PIConsensus`)."""
        def entry(q: Peer) -> tuple:
            pl = q.payload
            z, eta, deg = float(pl.get("z", 1.0)), float(pl.get("eta", 0.0)), int(pl.get("deg", 0))
            if t is None or "zdot" not in pl:
                return z, eta, deg
            return z, eta, deg, float(pl["zdot"]), float(pl.get("etadot", 0.0)), q.age + t - q.heard

        return self.pi.step(0.0 if self.done else 1.0, (entry(q) for q in same.values()), dt)

    def payload(self) -> dict[str, Any]:
        """The (6.16) fields of ``role_state``: z, eta and their rates."""
        pi = self.pi
        return {"z": float(pi.z), "eta": float(pi.eta), "zdot": float(pi.zdot), "etadot": float(pi.etadot)}

    def switch_due(self, t: float, phase: int) -> bool:
        """z_i has reached the threshold and there is a next formation."""
        cfg = self.cfg
        return (self.pi.z <= cfg.threshold and self.task + 1 < self.n_tasks
                and t - self.task_start >= cfg.min_task_s and phase != CONSENSUS)
