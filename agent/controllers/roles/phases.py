"""The phases of one robot's Chapter 6 task after the agreement, one small state object each.

:class:`~.controller.RolesController` ties them together with the neighbour table
(:mod:`.peers`) and the agreement on the transform (:mod:`.agreement`, phase 1); each
object here holds the state of one phase only, creates every attribute in ``__init__`` and
builds no message:

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
from typing import Any

import numpy as np


from .assignment import Claim, RoleBook, Ruling, local_hungarian, nearest_position
from .config import RolesConfig
from .averaging import PIConsensus
from .navigation import NavigationGains, parking_point, polar_control, repulsive_shift
from .payloads import ASSIGNED, CONSENSUS, UNASSIGNED
from .peers import Peer

__all__ = [
    "CONSENSUS",
    "ASSIGNED",
    "UNASSIGNED",
    "Assignment",
    "Motion",
    "TaskSequence",
]

logger = logging.getLogger(__name__)



# -- neighbours ------------------------------------------------------------------------


# -- phase 1: agreement on the formation's placement ----------------------------------


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
        for r in rulings:  # a ruling is final (RoleBook.negotiate): repeated, never reversed
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
