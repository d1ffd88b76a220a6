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

Each step is one state object (:class:`~.agreement.Agreement`, and of :mod:`.phases`
:class:`~.phases.Assignment`, :class:`~.phases.Motion`, :class:`~.phases.TaskSequence`),
made afresh for every task, beside the neighbour table (:class:`~.peers.PeerTable`); this
class only orders them.

Messages: one broadcast ``role_state`` per step (payload schema in
:mod:`.payloads`), tagged with the task index. The graph is range-limited
(Def. 10): neighbours are the robots heard within ``neighbour_timeout_s``. No robot
knows N. A robot that hears a neighbour already working on a later task follows it
(the switch "induces the team to abandon the current task", Sec. 6.2.2).

A robot in ``Observation.lost`` leaves the graph, the consensus and the relayed
assignment problem at once; the position it claimed is released (a tombstone that later
merges respect, lifted when it is heard claiming again) and a robot without a position
takes it (docs/reference/ambiguities.md, robot lost in role assignment (A38)). A robot that has lost every robot it knew cannot tell
its own silent radio from their loss and applies the same rule to itself: unless it was
within R_max of its position when it was last heard, its position has been released, so
it holds still, a stationary obstacle like a dead robot, until it hears one again.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Sequence

import numpy as np

from copath.config import from_table
from copath.control import Observation, Outgoing, PeerMessage, RobotContext, StepResult
from copath.models import UnicycleModel

from .config import RolesConfig
from .navigation import NavigationGains
from .agreement import Agreement
from .payloads import MESSAGE_KIND
from .peers import Peer, PeerTable
from .phases import ASSIGNED, CONSENSUS, UNASSIGNED, Assignment, Motion, TaskSequence
from .rotation import covariance_from_moments, principal_axis, template_frame, transform_targets

__all__ = ["RolesController", "MESSAGE_KIND", "CONSENSUS", "ASSIGNED", "UNASSIGNED"]

logger = logging.getLogger(__name__)


CLAIMS_EVERY = 10
"""The relayed claims table (docs/reference/ambiguities.md, robot lost in role assignment (A38)) goes in every 10th ``role_state``
(1 s at 10 Hz) while no robot is lost: a sender's own claim travels first-hand in every
message (``claim``, ``d``, its position), and the table, 0.5 kB for 16 robots, doubled the
cost of decoding and validating each message (36 -> 73 us) for news that is only used
after a loss."""


class RolesController:
    """Ch. 6 controller of one unicycle: agreement, assignment and negotiation, navigation,
    task sequencing, one state object per phase (:mod:`.phases`).

    Parameters
    ----------
    ctx : RobotContext
        Robot and scenario.
    cfg : RolesConfig, optional
        Parsed ``[controller]`` table (default: parsed from ``ctx.params``).
    """

    def __init__(self, ctx: RobotContext, cfg: RolesConfig | None = None) -> None:
        self.cfg = cfg if cfg is not None else from_table(RolesConfig, ctx.params, f"robots.{ctx.name}.controller")
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
        self.peers = PeerTable(self.cfg.neighbour_timeout_s)
        self.team = frozenset(ctx.robots) - {ctx.name}
        """The other robots of the scenario: used only to tell that this robot is cut off
        from all of them (robot lost in role assignment, A38), never by the algorithm, which does not know N."""
        self.tasks = TaskSequence(self.cfg)
        self.agreement: Agreement | None = None
        """Phase 1 of the current task (None when the placement is kept across tasks)."""
        self.roles: Assignment | None = None
        """Phase 2 of the current task (None before the first step)."""
        self.motion = Motion(self.cfg, self.gains, self.model, self.rng)
        """Phase 3 of the current task."""
        self._t_prev: float | None = None
        self._t = 0.0
        self._sent = 0
        """Messages sent so far (the relayed claims table goes in every CLAIMS_EVERY-th)."""

    # ------------------------------------------------------------------ tasks
    def _enter_task(self, k: int, p: np.ndarray, t: float) -> None:
        """Start formation k with fresh phase objects (docs/reference/ambiguities.md, reset at a task switch (A26): (6.16) is reset)."""
        if self.roles is not None:
            self.tasks.conflicts_total += self.roles.book.conflicts_initiated
        self.tasks.begin(k, t)
        self.roles = Assignment(self.name, self.index, len(self.templates[k]), p, t)
        self.motion = Motion(self.cfg, self.gains, self.model, self.rng)
        if self.tasks.transform is not None and not self.cfg.transform_every_task:
            self.agreement = None
            self._adopt(*self.tasks.transform, p)
        else:
            self.agreement = Agreement(self.name, p, self.cfg)

    def _same(self) -> dict[str, Peer]:
        """Neighbours working on the current task."""
        return self.peers.same_task(self._t, self.tasks.task)

    # ------------------------------------------------------------------ phase 1
    def _adopt(self, centroid: np.ndarray, rotation: float, p: np.ndarray) -> None:
        """Place the formation (docs/reference/ambiguities.md, rotation direction and order of translation (A22)); the initial choice follows in
        :meth:`_choose`."""
        self.tasks.transform = (np.asarray(centroid, dtype=float), float(rotation))
        self.roles.place(transform_targets(self.templates[self.tasks.task], centroid, rotation))
        if not self.cfg.relay_positions:
            self._choose(p)

    def _transform_from_consensus(self, m: np.ndarray) -> tuple[np.ndarray, float]:
        centroid, C = covariance_from_moments(m)
        if self.cfg.orientation == "given":
            return centroid, self.cfg.rotation_rad
        theta_f = principal_axis(C, self.cfg.isotropy)
        theta_t = self.frames[self.tasks.task][1]
        if theta_f is None or theta_t is None:
            return centroid, 0.0  # nearly isotropic robots or template: keep the template's orientation
        return centroid, theta_f - theta_t

    def _agree(self, same: dict[str, Peer], p: np.ndarray) -> None:
        """One step of Algorithm 6.1; adopts the placement once agreed."""
        est = self.agreement.step(same, self._t, self.peers.lost)
        if self.roles.phase != CONSENSUS or self.roles.targets is not None:
            return
        # a neighbour has already agreed: take its transform (the first agreement floods
        # the team, so every robot places the formation identically)
        for n in sorted(same, key=lambda n: same[n].index):
            xf = same[n].payload.get("xf") or []
            if len(xf) == 3:
                self._adopt(np.array(xf[:2], dtype=float), float(xf[2]), p)
                return
        agreed, timed_out = self.agreement.settled(est, self._t, self.tasks.task_start)
        if agreed or timed_out:
            if timed_out and not agreed:
                logger.warning("%s: consensus of task %d timed out; adopting the current estimate",
                               self.name, self.tasks.task)
            self._adopt(*self._transform_from_consensus(est), p)

    # ------------------------------------------------------------------ phase 2
    def _choose(self, p: np.ndarray) -> None:
        """Initial choice of a position (:meth:`.phases.Assignment.initial_choice`)."""
        pos = self.roles.initial_choice(p, self._same(), self.peers.fresh(self._t), self.tasks.task,
                                        self.cfg.relay_positions)
        self._take(pos, p)

    def _take(self, pos: int | None, p: np.ndarray) -> None:
        """Claim ``pos``; without one the robot heads for a waiting place next to the formation."""
        self.roles.take(pos)
        self.tasks.done = False
        if pos is None:
            self.motion.settle_track = []
            self.roles.set_park(p, self._same(), self.cfg.park_clearance)

    def _negotiate(self, same: dict[str, Peer], p: np.ndarray) -> bool:
        """Algorithm 6.2 for this step; returns True when the robot must wait (stop)."""
        roles = self.roles
        roles.merge(same)
        if roles.phase == ASSIGNED and roles.lost_a_ruling(same):
            self._take(roles.reassign_choice(p), p)
        if roles.phase != ASSIGNED:
            return False
        waiting, lost = roles.resolve_conflicts(same, p, self._t)
        if lost:
            self._take(roles.reassign_choice(p), p)
            return False
        return waiting

    # ------------------------------------------------------------------ phase 3
    def _finished(self, p: np.ndarray, waiting: bool) -> bool:
        """This robot has finished its task: at its position, or settled without one."""
        roles = self.roles
        if roles.phase == ASSIGNED:
            if waiting:
                return False
            e = float(np.hypot(*(roles.targets[roles.position] - p)))
            return e < (2.0 if self.tasks.done else 1.0) * self.cfg.arrive_tol
        if roles.phase == UNASSIGNED:
            return self.motion.settled(p, roles.park, self._t)
        return False

    # ------------------------------------------------------------------ step
    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        pose = np.asarray(obs.pose, dtype=float).reshape(3)
        p = pose[:2]
        self._t = float(obs.t)
        dt = self.dt if self._t_prev is None else min(max(self._t - self._t_prev, 0.0), 5 * self.dt)
        self._t_prev = self._t
        self.peers.ingest(inbox, self._t, obs.lost)
        if self.roles is None:
            self._enter_task(0, p, self._t)
        fresh = self.peers.fresh(self._t)
        later = max((q.task for q in fresh.values()), default=-1)
        if self.tasks.task < later < len(self.templates):
            self._enter_task(later, p, self._t)  # a neighbour has moved on: follow it
        same = self._same()
        roles = self.roles
        roles.track_claims(same, obs.lost, self._t, self.cfg.R_max)
        # phase 1: agreement on the placement
        if self.cfg.relay_positions:
            roles.relay(same, self._t)
        if self.agreement is not None:
            self._agree(same, p)
        # phase 2: initial choice and negotiation
        if (roles.phase == CONSENSUS and roles.targets is not None
                and self._t - roles.known_changed >= self.cfg.gather_s - 1e-9):
            self._choose(p)
        waiting = False
        if roles.phase in (ASSIGNED, UNASSIGNED):
            waiting = self._negotiate(same, p)
        # cut off from every robot it knew (robot lost in role assignment, A38): it cannot tell which positions are free,
        # and the others have released its own unless they last heard it within R_max of
        # it; then it holds still until it hears one again
        cut_off = self.peers.cut_off(self.team)
        hold = cut_off and not roles.kept_while_lost(self.peers.last_stamp() - self.dt)
        if roles.phase == UNASSIGNED and not cut_off:
            pos = roles.take_released(p, self._t, self.cfg.gather_s)
            if pos is not None:
                self._take(pos, p)
            else:
                roles.check_park(p, same, self.cfg.park_clearance)
        # phase 3: navigation
        goal = roles.goal()
        if goal is None or waiting or hold:
            cmd = np.zeros(2)
        else:
            obstacles = [q.position for q in self.peers.fresh(self._t).values()] + self.peers.wrecks()
            cmd = self.motion.drive(pose, goal, obstacles, self._t, self.name)
        # phase 4: task sequencing, (6.16)
        self.tasks.done = self._finished(p, waiting)
        self.tasks.step(same, dt, self._t)
        if self.tasks.switch_due(self._t, roles.phase):
            logger.info("%s: z = %.3f <= %.2f, moving to formation %d", self.name, self.tasks.pi.z,
                        self.cfg.threshold, self.tasks.task + 1)
            self._enter_task(self.tasks.task + 1, p, self._t)
            same = {}
        return StepResult(command=cmd, messages=[self._message(pose, cmd, same)], telemetry=self._telemetry(pose))

    # ------------------------------------------------------------------ out
    def _message(self, pose: np.ndarray, cmd: np.ndarray, same: dict[str, Peer]) -> Outgoing:
        roles, tasks = self.roles, self.tasks
        th = float(pose[2])
        v = float(cmd[0])
        d = roles.distance(pose[:2])  # inf without a position
        roles.track_near(d, self._t, self.cfg.R_max)
        payload: dict[str, Any] = {
            "task": int(tasks.task),
            "index": self.index,
            "phase": int(roles.phase),
            "pos": [float(pose[0]), float(pose[1])],
            "vel": [v * math.cos(th), v * math.sin(th)],
            "deg": len(same),
            **tasks.payload(),
            "claim": int(roles.position),
            "d": float(d) if roles.phase == ASSIGNED else 1e9,
            "taken": sorted(int(k) for k in roles.book.taken),
            "gone": {m: float(s) for m, s in sorted(roles.gone.items())},
            "park": [float(c) for c in roles.park] if roles.park is not None else [],
        }
        # the relayed claims table (robot lost in role assignment, A38) changes slowly and is only acted on after a loss: it
        # goes in every CLAIMS_EVERY-th message, and in every one while a robot is lost
        if roles.gone or self._sent % CLAIMS_EVERY == 0:
            payload["claims"] = roles.claims_payload(self._t, pose[:2], self.cfg.R_max)
        self._sent += 1
        # rulings are repeated for a while so a lost message does not lose them
        payload["rulings"] = roles.recent_rulings(self._t)
        if roles.targets is not None and tasks.transform is not None:
            centroid, rotation = tasks.transform
            payload["xf"] = [float(centroid[0]), float(centroid[1]), float(rotation)]
        if self.cfg.relay_positions:
            payload["known"] = roles.known_payload()
        if self.agreement is not None:
            payload.update(self.agreement.payload())
        return Outgoing(MESSAGE_KIND, payload)

    def _telemetry(self, pose: np.ndarray) -> dict[str, Any]:
        roles, tasks = self.roles, self.tasks
        goal = roles.targets[roles.position] if roles.phase == ASSIGNED else None
        tel: dict[str, Any] = {
            "task": int(tasks.task),
            "task_done": bool(tasks.done),
            "target": [float(goal[0]), float(goal[1])] if goal is not None else None,
            "ref": [float(goal[0]), float(goal[1]), float(pose[2])] if goal is not None else None,
            "conflicts_resolved": int(tasks.conflicts_total + roles.book.conflicts_initiated),
            "in_transition": not tasks.done,
            "z": float(tasks.pi.z),
        }
        if roles.announce_targets:
            tel["formation_targets"] = [[float(x), float(y)] for x, y in roles.targets]
            roles.announce_targets = False
        if roles.announce_index:
            tel["assigned_index"] = int(roles.position)
            roles.announce_index = False
        return tel

