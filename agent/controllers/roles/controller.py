"""Distributed role assignment and formation switching of one robot (Chapter 6).

Per task (one formation of the queue) every robot:

1. agrees with its neighbours on the formation's translation (and rotation) by average
   consensus on its moment vector (Algorithm 6.1; :mod:`.rotation`), standing still. It
   adopts the estimate once it agrees locally (neighbours and its own last
   ``consensus_hold_s`` within ``consensus_tol``), or as soon as a neighbour announces an
   adopted transform: the first agreement floods the team, so every robot places the
   formation identically (a robot whose neighbours drove off can no longer agree);
2. picks a position by a local Hungarian problem and negotiates conflicts
   (Algorithm 6.2; :mod:`.assignment`); a robot left without a position waits next to
   the formation (:func:`.navigation.parking_point`). With ``relay_positions`` the
   start positions are relayed over several hops first, so the local problem covers the
   whole connected team (see :meth:`RolesController._choose`);
3. drives there with (6.11) and the repulsive target shift (6.12)-(6.15), with a
   sideways target change when it stands still away from its target;
4. feeds w_i (1 unfinished, 0 finished) to the PI dynamic consensus (6.16) and moves on
   to the next formation when its z_i reaches the threshold.

Messages: one broadcast ``role_state`` per step (payload schema in
``copath.wire.payloads``), tagged with the task index. The graph is range-limited
(Def. 10): neighbours are the robots heard within ``neighbour_timeout_s``. No robot
knows N. A robot that hears a neighbour already working on a later task follows it
(the switch "induces the team to abandon the current task", Sec. 6.2.2).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from copath.config import from_table
from copath.models import UnicycleModel

from copath.control import controller, Observation, Outgoing, PeerMessage, RobotContext, StepResult
from .assignment import Claim, RoleBook, Ruling, local_hungarian, nearest_position
from .config import RolesConfig
from .consensus import AverageConsensus, NeighbourContribution, PIConsensus
from .navigation import NavigationGains, parking_point, polar_control, repulsive_shift
from .rotation import covariance_from_moments, moment_vector, principal_axis, template_frame, transform_targets

__all__ = ["RolesController", "MESSAGE_KIND", "CONSENSUS", "ASSIGNED", "UNASSIGNED", "build"]

logger = logging.getLogger(__name__)

MESSAGE_KIND = "role_state"
CONSENSUS, ASSIGNED, UNASSIGNED = 0, 1, 2
"""Phases: agreeing on the transform; holding a position; without a position."""

_N_MOMENTS = 5


@dataclass
class _Peer:
    """Latest message of one neighbour."""

    heard: float
    """Own clock when it was received [s]."""
    position: np.ndarray
    """Sender position extrapolated to ``heard`` [m]."""
    velocity: np.ndarray
    task: int
    index: int
    phase: int
    payload: dict[str, Any] = field(repr=False)


class RolesController:
    """Ch. 6 controller of one unicycle: consensus, assignment, negotiation, navigation.

    Parameters
    ----------
    ctx : RobotContext
        Robot and scenario; ``ctx.params`` is parsed into :class:`RolesConfig`.
    """

    def __init__(self, ctx: RobotContext) -> None:
        self.cfg = from_table(RolesConfig, ctx.params, f"robots.{ctx.name}.controller")
        if not isinstance(ctx.model, UnicycleModel):
            raise ValueError(f"robots.{ctx.name}: the roles controller drives unicycles (model type 'unicycle')")
        self.name = ctx.name
        self.index = int(ctx.index)
        self.model = ctx.model
        self.dt = float(ctx.dt)
        self.rng = np.random.default_rng([int(ctx.seed), int(ctx.index)])
        self.gains = NavigationGains(self.cfg.k_c, self.cfg.gamma, self.cfg.k_r, self.cfg.R_max,
                                     self.cfg.F_max, self.cfg.side)
        self.templates = [np.asarray(f, dtype=float).reshape(-1, 2) for f in self.cfg.formations]
        self.frames = [template_frame(T, self.cfg.isotropy) for T in self.templates]
        self.peers: dict[str, _Peer] = {}
        self.pi = PIConsensus(self.cfg.k_z, self.cfg.k_p, self.cfg.k_i)
        self.conflicts_total = 0
        self.transform: tuple[np.ndarray, float] | None = None
        """Agreed (centroid, rotation) kept across tasks when ``transform_every_task`` is off."""
        self.task = -1
        self.book: RoleBook | None = None
        self._t_prev: float | None = None
        self._t = 0.0

    # ------------------------------------------------------------------ task state
    def _enter_task(self, k: int, p: np.ndarray, t: float) -> None:
        """Start formation k: reset (6.16) and the bookkeeping (ambiguity #26)."""
        if self.book is not None:
            self.conflicts_total += self.book.conflicts_initiated
        self.task = k
        self.task_start = t
        self.book = RoleBook(self.name, self.index, len(self.templates[k]))
        self.targets: np.ndarray | None = None
        self.park: np.ndarray | None = None
        self.done = False
        self.pi.reset(1.0)
        self.rulings_out: dict[tuple[int, str, str], float] = {}
        self.announce_targets = False
        self.announce_index = False
        self.settle_track: list[tuple[float, np.ndarray]] = []
        self.track: list[tuple[float, np.ndarray]] = []
        self.escape_until = -math.inf
        self.escape_vec = np.zeros(2)
        self.ac_nbrs: dict[str, NeighbourContribution] = {}
        self.snapshot = np.asarray(p, dtype=float).copy()
        self.known: dict[str, tuple[float, float, float, int]] = {self.name: (t, float(p[0]), float(p[1]), -1)}
        self.known_changed = t
        self.phase = CONSENSUS
        if self.transform is not None and not self.cfg.transform_every_task:
            self.ac = None
            self._adopt(*self.transform, p)
        else:
            self.ac = AverageConsensus(moment_vector(p), gain=self.cfg.consensus_gain)
            self.ac_hist: list[tuple[float, np.ndarray, float]] = []

    def _adopt(self, centroid: np.ndarray, rotation: float, p: np.ndarray) -> None:
        """Place the formation (ambiguity #22); the initial choice follows in :meth:`_choose`."""
        self.transform = (np.asarray(centroid, dtype=float), float(rotation))
        self.targets = transform_targets(self.templates[self.task], centroid, rotation)
        self.announce_targets = True
        if not self.cfg.relay_positions:
            self._choose(p)

    def _choose(self, p: np.ndarray) -> None:
        """Initial choice (Sec. 6.2.2): own row of a local Hungarian problem (6.7).

        One-hop exchange (the text): rows are this robot and its neighbours without a
        position, columns the positions it believes available; a robot left without a
        column takes the nearest position even though it is taken, and the negotiation
        sorts it out. With ``relay_positions`` every robot solves the same problem, all
        robots it has heard of (start positions of the task) x all positions, so the
        choices agree without negotiation whenever the tables agree; a robot left
        without a column then knows that the whole team's optimum has no role for it and
        goes without one instead of contesting a taken position.
        """
        same = self._same_task_peers()
        self._merge(same)
        if self.cfg.relay_positions:
            others = [(x, y) for n, (_, x, y, _c) in sorted(self.known.items()) if n != self.name]
            pos = local_hungarian(self.snapshot, others, self.targets, range(len(self.targets)))
            if pos is not None and pos in self.book.taken:
                # someone already holds it (a robot this one has not heard of): nearest free one
                pos = nearest_position(p, self.targets, self.book.available)
            self._take(pos, p)
            return
        others = [
            q.position
            for q in self._fresh_peers().values()
            if not (q.task == self.task and q.phase in (ASSIGNED, UNASSIGNED))
        ]
        pos = local_hungarian(p, others, self.targets, self.book.available)
        if pos is None:  # N > M: no column left -> the nearest position, even if taken
            pos = nearest_position(p, self.targets, range(len(self.targets)))
        self._take(pos, p)

    def _take(self, pos: int | None, p: np.ndarray) -> None:
        self.book.claim(pos)
        self.announce_index = True
        self.done = False
        if pos is None:
            self.phase = UNASSIGNED
            self.settle_track = []
            self._set_park(p)
        else:
            self.phase = ASSIGNED
            self.park = None

    def _priority_parks(self) -> list:
        """Waiting places announced by same-task robots without a role and a lower index."""
        return [
            q.payload.get("park")
            for q in self._same_task_peers().values()
            if q.phase == UNASSIGNED and q.index < self.index and len(q.payload.get("park") or []) == 2
        ]

    def _set_park(self, p: np.ndarray) -> None:
        avoid = self._priority_parks()
        self.park = parking_point(p, self.targets.mean(axis=0), self.targets, self.cfg.park_clearance, avoid)

    def _check_park(self, p: np.ndarray) -> None:
        """Move the waiting place when a robot with priority announced one too close to it."""
        avoid = self._priority_parks()
        if avoid and min(float(np.hypot(*(np.asarray(a) - self.park)))
                         for a in avoid) < self.cfg.park_clearance - 1e-6:
            self._set_park(p)

    def _transform_from_consensus(self, m: np.ndarray) -> tuple[np.ndarray, float]:
        centroid, C = covariance_from_moments(m)
        if self.cfg.orientation == "given":
            return centroid, self.cfg.rotation_rad
        theta_f = principal_axis(C, self.cfg.isotropy)
        theta_t = self.frames[self.task][1]
        if theta_f is None or theta_t is None:
            return centroid, 0.0  # nearly isotropic robots or template: keep the template's orientation
        return centroid, theta_f - theta_t

    # ------------------------------------------------------------------ messages in
    def _ingest(self, inbox: Sequence[PeerMessage], t: float) -> None:
        for msg in inbox:
            if msg.kind != MESSAGE_KIND:
                continue
            pl = dict(msg.payload)
            pos = msg.position if msg.position is not None else pl.get("pos")
            if pos is None:
                continue
            vel = np.asarray(pl.get("vel") or (0.0, 0.0), dtype=float)
            old = self.peers.get(msg.sender)
            if old is not None and old.payload.get("_stamp", -math.inf) > msg.stamp:
                continue  # an older message overtaken by a newer one
            pl["_stamp"] = msg.stamp
            self.peers[msg.sender] = _Peer(
                heard=t,
                position=np.asarray(pos, dtype=float) + vel * max(msg.age, 0.0),
                velocity=vel,
                task=int(pl.get("task", -1)),
                index=int(pl.get("index", 0)),
                phase=int(pl.get("phase", CONSENSUS)),
                payload=pl,
            )

    def _fresh_peers(self) -> dict[str, _Peer]:
        return {n: q for n, q in self.peers.items() if self._t - q.heard <= self.cfg.neighbour_timeout_s}

    def _same_task_peers(self) -> dict[str, _Peer]:
        return {n: q for n, q in self._fresh_peers().items() if q.task == self.task}

    def _relay(self, same: dict[str, _Peer]) -> None:
        """Merge the neighbours' tables of start positions and claims (freshest entry wins)."""
        self.known[self.name] = (self._t, float(self.snapshot[0]), float(self.snapshot[1]), int(self.book.position))
        for q in same.values():
            for e in q.payload.get("known") or []:
                if len(e) != 5 or e[0] == self.name:
                    continue
                name, stamp = str(e[0]), float(e[1])
                old = self.known.get(name)
                if old is None:
                    self.known_changed = self._t
                if old is None or stamp > old[0]:
                    self.known[name] = (stamp, float(e[2]), float(e[3]), int(e[4]))

    def _merge(self, same: dict[str, _Peer]) -> None:
        self.book.merge((q.payload.get("taken") or () for q in same.values()),
                        (int(q.payload.get("claim", -1)) for q in same.values()))

    # ------------------------------------------------------------------ phases
    def _consensus_step(self, same: dict[str, _Peer], p: np.ndarray) -> None:
        nbrs = {}
        for n, q in same.items():
            x = q.payload.get("ac_x")
            if not x or len(x) != _N_MOMENTS:
                continue
            to = q.payload.get("ac_to") or []
            flows = q.payload.get("ac_a") or []
            echoes = q.payload.get("ac_e") or []
            a = np.zeros(_N_MOMENTS)
            echo = np.zeros(_N_MOMENTS)  # it has not heard us yet: nothing of ours applied
            if self.name in to:
                k = to.index(self.name)
                a = np.asarray(flows[k * _N_MOMENTS:(k + 1) * _N_MOMENTS], dtype=float)
                if len(echoes) == len(flows):
                    echo = np.asarray(echoes[k * _N_MOMENTS:(k + 1) * _N_MOMENTS], dtype=float)
            nbrs[n] = NeighbourContribution(np.asarray(x, dtype=float), int(q.payload.get("ac_deg", 0)), a, echo)
        self.ac_nbrs = nbrs
        est = self.ac.step(nbrs)
        if self.phase != CONSENSUS or self.targets is not None:
            return
        # a neighbour has already agreed: take its transform (the first agreement floods
        # the team, so every robot places the formation identically)
        for n in sorted(same, key=lambda n: same[n].index):
            xf = same[n].payload.get("xf") or []
            if len(xf) == 3:
                self._adopt(np.array(xf[:2], dtype=float), float(xf[2]), p)
                return
        spread = max((float(np.max(np.abs(c.estimate - est))) for c in nbrs.values()), default=math.inf)
        self.ac_hist.append((self._t, est.copy(), spread))
        hold = self.cfg.consensus_hold_s
        window = [h for h in self.ac_hist if h[0] >= self._t - hold - 1e-9]
        self.ac_hist = window
        timed_out = self._t - self.task_start >= self.cfg.consensus_timeout_s
        agreed = (
            self._t - self.task_start >= hold
            and all(h[2] <= self.cfg.consensus_tol for h in window)
            and float(np.max(np.abs(window[0][1] - est))) <= self.cfg.consensus_tol
        )
        if agreed or timed_out:
            if timed_out and not agreed:
                logger.warning("%s: consensus of task %d timed out; adopting the current estimate", self.name, self.task)
            self._adopt(*self._transform_from_consensus(est), p)

    def _negotiate(self, same: dict[str, _Peer], p: np.ndarray) -> bool:
        """Algorithm 6.2 for this step; returns True when the robot must wait (stop)."""
        self._merge(same)
        incoming = []
        for q in same.values():
            for r in q.payload.get("rulings") or []:
                if len(r) == 3 and self.name in (r[1], r[2]):
                    incoming.append(Ruling(int(r[0]), str(r[1]), str(r[2])))
        if self.phase == ASSIGNED and self.book.lost(incoming):
            self._reassign(p)
        if self.phase != ASSIGNED:
            return False
        claims = [
            Claim(n, q.index, int(q.payload.get("claim", -1)), float(q.payload.get("d", math.inf)))
            for n, q in same.items()
            if q.phase == ASSIGNED
        ]
        conflicts = self.book.conflicts(claims)
        if not conflicts:
            return False
        d_i = self._distance(p)
        rulings, waiting = self.book.negotiate(d_i, conflicts)
        for r in rulings:
            self.rulings_out[(r.position, r.winner, r.loser)] = self._t
        if any(r.loser == self.name for r in rulings):
            self._reassign(p)
            return False
        return waiting

    def _reassign(self, p: np.ndarray) -> None:
        """The loser takes the nearest available position, or none (Algorithm 6.2)."""
        old = self.book.position
        cand = [k for k in self.book.available if k != old]
        self._take(nearest_position(p, self.targets, cand), p)

    def _distance(self, p: np.ndarray) -> float:
        if self.phase == ASSIGNED and self.targets is not None:
            return float(np.hypot(*(self.targets[self.book.position] - p)))
        return math.inf

    # ------------------------------------------------------------------ motion
    def _goal(self) -> np.ndarray | None:
        if self.phase == ASSIGNED:
            return self.targets[self.book.position]
        if self.phase == UNASSIGNED:
            return self.park
        return None

    def _drive(self, pose: np.ndarray, goal: np.ndarray) -> np.ndarray:
        p = pose[:2]
        obstacles = [q.position for q in self._fresh_peers().values()]
        e = float(np.hypot(*(goal - p)))
        # standstill away from the goal: change the target sideways for a while (Sec. 6.2.2)
        self.track.append((self._t, p.copy()))
        self.track = [h for h in self.track if h[0] >= self._t - self.cfg.stuck_s - 1e-9]
        if self._t >= self.escape_until and e > 2 * self.cfg.arrive_tol and self.cfg.escape_m > 0:
            t0, p0 = self.track[0]
            if self._t - t0 >= self.cfg.stuck_s - 1e-9 and np.hypot(*(p - p0)) < 0.03:
                u = (goal - p) / max(e, 1e-9)
                side = 1.0 if self.rng.random() < 0.5 else -1.0
                self.escape_vec = side * self.cfg.escape_m * np.array([-u[1], u[0]])
                self.escape_until = self._t + self.cfg.escape_s
                self.track = []
                logger.debug("%s: standstill at %.2f m from the target; escaping sideways", self.name, e)
        g = goal + (self.escape_vec if self._t < self.escape_until else 0.0)
        g_new = repulsive_shift(p, g, obstacles, self.gains)
        v, w = polar_control(pose, g_new, self.cfg.k_c, self.cfg.gamma, self.cfg.stop_radius)
        cmd, _ = self.model.saturate((v, w))
        return cmd

    def _finished(self, p: np.ndarray, cmd: np.ndarray, waiting: bool) -> bool:
        if self.phase == ASSIGNED:
            if waiting:
                return False
            e = float(np.hypot(*(self.targets[self.book.position] - p)))
            return e < (2.0 if self.done else 1.0) * self.cfg.arrive_tol
        if self.phase == UNASSIGNED:
            # settled: near the waiting place, or hardly moved for settle_s (repulsion from
            # a neighbour may hold it off the exact point)
            self.settle_track.append((self._t, p.copy()))
            self.settle_track = [h for h in self.settle_track if h[0] >= self._t - self.cfg.settle_s - 1e-9]
            t0, p0 = self.settle_track[0]
            still = self._t - t0 >= self.cfg.settle_s - 1e-9 and float(np.hypot(*(p - p0))) < self.cfg.arrive_tol
            near = float(np.hypot(*(self.park - p))) < 2 * self.cfg.arrive_tol
            return near or still
        return False

    # ------------------------------------------------------------------ step
    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        pose = np.asarray(obs.pose, dtype=float).reshape(3)
        p = pose[:2]
        self._t = float(obs.t)
        dt = self.dt if self._t_prev is None else min(max(self._t - self._t_prev, 0.0), 5 * self.dt)
        self._t_prev = self._t
        self._ingest(inbox, self._t)
        if self.book is None:
            self._enter_task(0, p, self._t)
        fresh = self._fresh_peers()
        later = max((q.task for q in fresh.values()), default=-1)
        if later > self.task and later < len(self.templates):
            self._enter_task(later, p, self._t)  # a neighbour has moved on: follow it
        same = self._same_task_peers()
        if self.cfg.relay_positions:
            self._relay(same)
        if self.ac is not None:
            self._consensus_step(same, p)
        if (self.phase == CONSENSUS and self.targets is not None
                and self._t - self.known_changed >= self.cfg.gather_s - 1e-9):
            self._choose(p)
        waiting = False
        if self.phase in (ASSIGNED, UNASSIGNED):
            waiting = self._negotiate(same, p)
        if self.phase == UNASSIGNED:
            self._check_park(p)
        goal = self._goal()
        if goal is None or waiting:
            cmd = np.zeros(2)
        else:
            cmd = self._drive(pose, goal)
        self.done = self._finished(p, cmd, waiting)
        # (6.16): w_i = 0 once this robot has finished its task
        self.pi.step(0.0 if self.done else 1.0,
                     ((float(q.payload.get("z", 1.0)), float(q.payload.get("eta", 0.0)), int(q.payload.get("deg", 0)))
                      for q in same.values()), dt)
        if (self.pi.z <= self.cfg.threshold and self.task + 1 < len(self.templates)
                and self._t - self.task_start >= self.cfg.min_task_s and self.phase != CONSENSUS):
            logger.info("%s: z = %.3f <= %.2f, moving to formation %d", self.name, self.pi.z, self.cfg.threshold, self.task + 1)
            self._enter_task(self.task + 1, p, self._t)
            same = {}
        return StepResult(command=cmd, messages=[self._message(pose, cmd, same)], telemetry=self._telemetry(pose))

    def _message(self, pose: np.ndarray, cmd: np.ndarray, same: dict[str, _Peer]) -> Outgoing:
        th = float(pose[2])
        v = float(cmd[0])
        payload: dict[str, Any] = {
            "task": int(self.task),
            "index": self.index,
            "phase": int(self.phase),
            "pos": [float(pose[0]), float(pose[1])],
            "vel": [v * math.cos(th), v * math.sin(th)],
            "deg": len(same),
            "z": float(self.pi.z),
            "eta": float(self.pi.eta),
            "claim": int(self.book.position),
            "d": float(self._distance(pose[:2])) if self.phase == ASSIGNED else 1e9,
            "taken": sorted(int(k) for k in self.book.taken),
            "park": [float(c) for c in self.park] if self.park is not None else [],
        }
        # rulings are repeated for a while so a lost message does not lose them
        self.rulings_out = {k: t0 for k, t0 in self.rulings_out.items() if self._t - t0 <= 1.0}
        payload["rulings"] = [[int(k[0]), k[1], k[2]] for k in self.rulings_out]
        if self.targets is not None and self.transform is not None:
            payload["xf"] = [float(self.transform[0][0]), float(self.transform[0][1]), float(self.transform[1])]
        if self.cfg.relay_positions:
            self.known[self.name] = (self._t, float(self.snapshot[0]), float(self.snapshot[1]), int(self.book.position))
            payload["known"] = [[n, st, x, y, c] for n, (st, x, y, c) in sorted(self.known.items())]
        if self.ac is not None:
            to = sorted(self.ac_nbrs)
            payload["ac_x"] = [float(c) for c in self.ac.estimate]
            payload["ac_to"] = to
            payload["ac_a"] = [float(c) for n in to for c in self.ac.flow_to(n)]
            payload["ac_e"] = [float(c) for n in to for c in self.ac.echo_to(n)]
            payload["ac_deg"] = len(to)
        return Outgoing(MESSAGE_KIND, payload)

    def _telemetry(self, pose: np.ndarray) -> dict[str, Any]:
        goal = self.targets[self.book.position] if self.phase == ASSIGNED else None
        tel: dict[str, Any] = {
            "task": int(self.task),
            "task_done": bool(self.done),
            "target": [float(goal[0]), float(goal[1])] if goal is not None else None,
            "ref": [float(goal[0]), float(goal[1]), float(pose[2])] if goal is not None else None,
            "conflicts_resolved": int(self.conflicts_total + self.book.conflicts_initiated),
            "in_transition": not self.done,
            "z": float(self.pi.z),
        }
        if self.announce_targets:
            tel["formation_targets"] = [[float(x), float(y)] for x, y in self.targets]
            self.announce_targets = False
        if self.announce_index:
            tel["assigned_index"] = int(self.book.position)
            self.announce_index = False
        return tel


@controller(config=RolesConfig, models=("unicycle",))
def build(ctx: RobotContext, cfg: RolesConfig) -> RolesController:
    """Registry builder ``roles`` (Chapter 6)."""
    return RolesController(ctx)
