"""Leader-following coordinated path following with NMPC (Sec. 5.3, (5.1)-(5.8), App. A).

The leader runs the omni path-following NMPC of Sec. 4.2 on the team path and, after
each solve, sends its reference state s_l, its planned virtual-vehicle speeds
sdot_pred and its sampling time delta_l (``leader_plan``). Each follower i holds a
curvilinear offset (p_i(s), q_i(s)) from the leader's reference point C (after [18]),
estimates the leader's progress from the newest plan and the plan's age, builds its own
reference trajectory on the offset curve with the velocity profile (5.4)-(5.5), and
tracks it with the omni trajectory-tracking NMPC (5.8).

Formation changes move q with the quintic (5.3) and p with the same quintic
(docs/reference/ambiguities.md, changes of the along-track offset (A32)), both scheduled on the leader's path coordinate; the schedule
is checked at build time so that the planned slots of no two robots come closer than a safety
distance (the text leaves the collision-free timing to the designer).

Beyond the dissertation (docs/reference/controllers-notes.md, leader-following formation feedback (N4)): formation feedback. Followers report
their tracking error (``follower_status``) and the leader lowers its reference speed
while a follower lags; ``formation_feedback = false`` reproduces the original scheme.

Beyond the dissertation (docs/reference/faults.md, "A new leader"): with ``run.on_robot_failure``
``continue`` or ``restart``, a team whose leader is lost (``Observation.lost``) goes on under
a new one. Every member applies the same succession rule to what it already knows, so the
team agrees without exchanging a vote: the new leader is the first robot of the team, in the
scenario's robot order, that is not lost. It keeps its own slot and keeps the team's
reference point C moving from the leader progress it last knew (:class:`NewLeaderPlanner`), so
every member keeps its offsets (p, q) from C and no reference jumps; C itself is left empty,
since the lost leader stops there. Each election raises a term carried in the plans, so a
returning leader, which starts at term 0, follows the leader of the higher term (tracking C)
instead of taking the lead back.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from copath.config import ConfigError, from_table, require
from copath.paths import Path, wrap_to_pi

from copath.control import (LatestMessages, Observation, Outgoing, PeerMessage, RobotContext, StepResult,
                            VirtualVehicle)
from agent.controllers.omni_nmpc.config import OmniPFConfig, check_gain_conditions
from agent.controllers.omni_nmpc.controller import OmniPathFollower, OmniTrackingNMPC

from .config import FollowerConfig, LeaderConfig
from .formation import FollowerReference, FormationSchedule, follower_reference, planned_min_separation
from .payloads import PLAN_KIND, STATUS_KIND

__all__ = [
    "PathLeader",
    "LeaderConfig",
    "FollowerConfig",
    "LeaderController",
    "FollowerController",
    "LeaderFollowing",
    "NewLeaderPlanner",
    "LeaderPlan",
    "FormationSchedule",
    "FollowerReference",
    "follower_reference",
    "planned_min_separation",
]

logger = logging.getLogger(__name__)


def _usable_plan(m: PeerMessage) -> bool:
    """A ``leader_plan`` with at least one planned speed and a positive sampling time."""
    return len(m.payload["sdot_pred"]) > 0 and float(m.payload["delta_l"]) > 0


# -- leader information at the follower: age of information and fill-in ---------------


@dataclass(frozen=True)
class LeaderPlan:
    """The newest ``leader_plan`` a follower holds, with its age bookkeeping.

    The leader's progress is estimated as s_c(tau) = s_l + int_{t_k}^{tau} sdot(sigma)
    dsigma with sdot piecewise constant on steps of delta_l and held at its last value
    beyond the plan (Sec. 5.3.3; docs/reference/controllers-notes.md, follower's estimate of the leader (N5)). A lost packet
    is filled in by reusing this plan with its larger age (step 2).
    """

    s_l: float
    """Leader's reference state s_{l,k} at the stamp [m]."""
    sdot_pred: tuple[float, ...]
    """Planned virtual-vehicle speeds over the leader's horizon [m/s]."""
    delta_l: float
    """Leader's sampling time delta_{l,k} [s]."""
    stamp: float
    """Leader's clock at sending [s]."""
    age_at_receipt: float
    """Age of information when it was delivered [s] (``PeerMessage.age``)."""
    t_receipt: float
    """Follower's clock when it was delivered [s]."""

    def age(self, t: float):
        """Age of the plan at follower time(s) t: age at delivery plus time held since."""
        return self.age_at_receipt + (np.asarray(t, dtype=float) - self.t_receipt)

    def progress(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Estimated leader progress s_c and speed sdot_c at follower time(s) t.

        Returns arrays shaped like ``t``.
        """
        a = np.asarray(self.age(t), dtype=float)
        sd = np.asarray(self.sdot_pred, dtype=float)
        n = len(sd)
        cum = np.concatenate([[0.0], np.cumsum(sd * self.delta_l)])
        k = np.clip(np.floor(a / self.delta_l).astype(int), 0, n - 1)
        s = self.s_l + cum[k] + sd[k] * (a - k * self.delta_l)
        return s, sd[k]


# -- formation specification (curvilinear offsets) -------------------------------------


# -- follower reference trajectory (5.4)-(5.5) ----------------------------------------


# -- configs -----------------------------------------------------------------------------


# -- controllers ---------------------------------------------------------------------------


def _start_coordinate(path: Path, p) -> float:
    """Path coordinate of the point nearest p; on a closed path in [-L/2, L/2) so that a
    team starting near the path's origin has s near 0 (the schedule's coordinate)."""
    s = path.wrap(path.project(p))
    return s - path.length if path.closed and s >= 0.5 * path.length else s


class PathLeader(OmniPathFollower):
    """The leader's path following (5.6)-(5.7): the omni path following of Sec. 4.2
    (:class:`~.omni_nmpc.OmniPathFollower`) on the team path, starting near s = 0.
    Shared by the Sec. 5.3 leader and the heterogeneous team's leader (Sec. 5.5.5)."""

    def __init__(self, ctx: RobotContext, cfg: OmniPFConfig, role: str) -> None:
        super().__init__(ctx, cfg, role, start=_start_coordinate)

    def telemetry(self, sol, u_R: float) -> dict[str, Any]:
        """Telemetry of a path-following leader: ref, s, sdot, xi = s, speed error."""
        ref = self.nmpc.reference(self.s)
        sdot = float(sol.sdot[0])
        return {
            "ref": [float(ref[0]), float(ref[1]), float(wrap_to_pi(ref[2]))],
            "s": float(self.s),
            "sdot": sdot,
            "xi": float(self.s),
            "xi_period": float(self.path.length) if self.path.closed else 0.0,
            "speed_error": sdot - u_R,
            "solver_ok": bool(sol.ok),
        }


class FormationFeedback:
    """Formation feedback (beyond the text, docs/reference/controllers-notes.md, leader-following formation feedback (N4)): the fraction of
    u_R the team's reference point moves at, from the largest fresh follower error. Kept by
    the Sec. 5.3 leader and by a new leader that keeps C (docs/reference/faults.md)."""

    def __init__(self, cfg: LeaderConfig, followers: Sequence[str]) -> None:
        self.cfg = cfg
        self.factor = 1.0
        self.inbox = LatestMessages(kinds=(STATUS_KIND,), senders=followers)

    def __call__(self, inbox: Sequence[PeerMessage], t: float, dt: float) -> float:
        cfg = self.cfg
        self.inbox.update(inbox, t)
        if not cfg.formation_feedback:
            return 1.0
        errs = [float(got.payload["tracking_error"])
                for got in self.inbox.fresh(STATUS_KIND, t, cfg.feedback_stale_s).values()]
        e = max(errs, default=0.0)
        x = (e - cfg.feedback_error_low) / (cfg.feedback_error_high - cfg.feedback_error_low)
        target = 1.0 - (1.0 - cfg.feedback_min_factor) * min(max(x, 0.0), 1.0)
        step = cfg.feedback_rate * dt
        self.factor += min(max(target - self.factor, -step), step)
        return self.factor


def _plan(s_l: float, sdot_pred, delta_l: float, factor: float, u_R: float) -> dict[str, Any]:
    """The ``leader_plan`` payload (Sec. 5.3.3) with the slowdown and the nominal u_R."""
    return {"s_l": float(s_l), "sdot_pred": [float(v) for v in sdot_pred], "delta_l": float(delta_l),
            "slowdown": float(factor), "u_R": float(u_R)}


class LeaderController:
    """The Sec. 5.3 leader: NMPC path following and the ``leader_plan`` broadcast."""

    def __init__(self, ctx: RobotContext, cfg: LeaderConfig) -> None:
        where = f"robots.{ctx.name}.controller"
        self.cfg, self.ctx = cfg, ctx
        self.followers = cfg.formation_schedule(where).followers
        for f in self.followers:
            require(f in ctx.neighbours, f"robots.{ctx.name}.neighbours", list(ctx.neighbours),
                    f"the leader broadcasts to its neighbours; add follower {f!r}")
        self.leader = PathLeader(ctx, cfg, "leader_nmpc")
        self.feedback = FormationFeedback(cfg, self.followers)

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        factor = self.feedback(inbox, obs.t, obs.dt)
        u_R = self.cfg.u_R * factor
        sol = self.leader.solve(obs, u_R)
        plan = _plan(self.leader.s, sol.sdot, self.leader.nmpc.dt, factor, self.cfg.u_R)
        tel = self.leader.telemetry(sol, u_R)
        tel["slowdown"] = float(factor)
        return StepResult(command=sol.body, messages=[Outgoing(PLAN_KIND, plan, to=tuple(self.followers))],
                          telemetry=tel)


class NewLeaderPlanner:
    """A new leader's own part (docs/reference/faults.md, "A new leader"): it keeps the team's
    reference point C moving along the path as the Sec. 5.3 leader's virtual vehicle would,
    at u_R times the formation feedback, from the leader progress last known, and makes the
    plan (s_l, sdot_pred, delta_l) of (5.4)-(5.5) for the team and for itself. Its robot
    keeps tracking its own slot with the follower's NMPC (5.8); C is left empty, since
    the lost leader stops there."""

    def __init__(self, cfg: LeaderConfig, followers: Sequence[str], s0: float, horizon: int, dt: float) -> None:
        self.cfg, self.horizon, self.dt = cfg, horizon, dt
        self.feedback = FormationFeedback(cfg, followers)
        self.vehicle = VirtualVehicle(s0)

    def plan(self, obs: Observation, inbox: Sequence[PeerMessage]) -> dict[str, Any]:
        factor = self.feedback(inbox, obs.t, obs.dt)
        s = self.vehicle.advance(obs.t)
        sdot = self.cfg.u_R * factor
        self.vehicle.hold(obs.t, sdot)
        return _plan(s, [sdot] * self.horizon, self.dt, factor, self.cfg.u_R)


class FollowerController:
    """A Sec. 5.3 follower: reference from the leader's plan, NMPC trajectory tracking (5.8)."""

    def __init__(self, ctx: RobotContext, cfg: FollowerConfig, at_c: bool = False) -> None:
        """``at_c``: this robot has no slot of its own and tracks C itself (the team's first
        leader following a newer one, docs/reference/faults.md)."""
        where = f"robots.{ctx.name}.controller"
        if ctx.model.kind != "omni":
            raise ConfigError(f"robots.{ctx.name}.model = {ctx.model.kind!r} is not allowed; follower_nmpc needs omni")
        require(cfg.leader in ctx.neighbours, f"{where}.leader", cfg.leader,
                f"must name a neighbour of {ctx.name!r}: {', '.join(ctx.neighbours) or '(none)'}")
        self.cfg, self.ctx = cfg, ctx
        self.path = ctx.own_path
        self.schedule = cfg.formation_schedule(where)
        self.leader = cfg.leader
        require(at_c or ctx.name in self.schedule.followers, f"{where}.formations", sorted(self.schedule.followers),
                f"must place this follower {ctx.name!r}")
        s_end = max([w.s_end for w in self.schedule.windows], default=0.0)
        d, s_at, pair = planned_min_separation(self.path, self.schedule, -1.0, s_end + 1.0, leader=cfg.leader)
        require(d >= cfg.safety_distance, f"{where}.schedule", list(cfg.schedule),
                f"planned slots of {pair[0]} and {pair[1]} come {d:.3f} m close at s = {s_at:.2f} m "
                f"(safety_distance = {cfg.safety_distance} m)")
        if cfg.terminal:
            check_gain_conditions(cfg.Q, cfg.R, cfg.gains, where=where)
        # a member far from its slot (a restart, a rejoin) starts outside the terminal region of
        # (5.8) and cannot reach it within the horizon: the bound contracts from where it is
        # (docs/reference/faults.md, "A restarted leader, in one process")
        self.nmpc = OmniTrackingNMPC(ctx.model, cfg.horizon, ctx.dt, cfg.Q, cfg.R, cfg.gains,
                                     terminal=cfg.terminal, solver=cfg.solver_config(), name=f"{ctx.name}_follower",
                                     contractive_terminal=True)
        self.geometry = self.path.table()
        self.inbox = LatestMessages(kinds=(PLAN_KIND,), accept=_usable_plan)
        self.plan: LeaderPlan | None = None
        self.u_R: float | None = None
        """The leader's nominal speed from its newest plan (a new leader keeps it)."""

    def follow(self, leader: str) -> None:
        """Take plans from ``leader`` from now on; the newest plan held (the previous
        leader's) stays the fill-in until the new one's arrives."""
        self.leader = leader

    def progress(self, t: float) -> float | None:
        """The leader progress s_c this follower estimates at time t (None without a plan)."""
        if self.plan is None:
            return None
        t_cap = self.plan.t_receipt + self.cfg.plan_timeout_s - self.plan.age_at_receipt
        return float(self.plan.progress(min(t, t_cap))[0])

    def _receive(self, t: float, inbox: Sequence[PeerMessage]) -> None:
        for got in self.inbox.update((m for m in inbox if m.sender == self.leader), t):
            p = got.payload
            self.plan = LeaderPlan(float(p["s_l"]), tuple(float(v) for v in p["sdot_pred"]), float(p["delta_l"]),
                                   got.stamp, got.message.age, got.received_at)
            self.u_R = float(p["u_R"]) if "u_R" in p else self.u_R

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        cfg = self.cfg
        self._receive(obs.t, inbox)
        if self.plan is None:  # nothing heard from the leader yet: wait
            return StepResult(command=np.zeros(3), telemetry={"solver_ok": True, "in_transition": False})
        times = obs.t + self.nmpc.dt * np.arange(cfg.horizon + 1)
        # fill-in of lost packets: the newest plan with its growing age, capped
        t_cap = self.plan.t_receipt + cfg.plan_timeout_s - self.plan.age_at_receipt
        s_c, sdot_c = self.plan.progress(np.minimum(times, t_cap))
        sdot_c = np.where(times > t_cap, 0.0, sdot_c)
        ref = follower_reference(self.geometry, self.schedule, self.ctx.name, s_c, sdot_c)
        rows = np.column_stack([ref.pose, ref.u, ref.omega])
        sol = self.nmpc.solve(obs.pose, rows)
        err = float(np.hypot(*(np.asarray(obs.pose[:2]) - ref.pose[0, :2])))
        s_own = ref.progress_of(obs.pose)
        messages = [Outgoing(STATUS_KIND, {"tracking_error": err}, to=(self.leader,))] \
            if cfg.formation_feedback and self.leader != self.ctx.name else []
        tel = {
            "ref": [float(ref.pose[0, 0]), float(ref.pose[0, 1]), float(wrap_to_pi(ref.pose[0, 2]))],
            "s": float(ref.s_i[0]),
            "sdot": float(ref.u[0]),
            "xi": float(s_own - ref.p[0]),
            "xi_period": float(self.path.length) if self.path.closed else 0.0,
            "formation_error": err,
            "in_transition": bool(self.schedule.in_transition(float(s_c[0]))),
            "solver_ok": bool(sol.ok),
            "plan_age": float(self.plan.age(obs.t)),
        }
        return StepResult(command=sol.body, messages=messages, telemetry=tel)


def _role_config(cls: type, ctx: RobotContext, **overrides: Any):
    """``cls`` (LeaderConfig or FollowerConfig) from this robot's own ``[controller]`` table,
    keeping the keys ``cls`` knows (a follower's table has no leader-only keys and the
    other way round), with ``overrides``."""
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    cfg = from_table(cls, {k: v for k, v in ctx.params.items() if k in names}, f"robots.{ctx.name}.controller")
    return dataclasses.replace(cfg, **overrides)


class LeaderFollowing:
    """One member of a Sec. 5.3 team, leader or follower, under the succession rule.

    The rule (docs/reference/faults.md, "A new leader"): when the leader this member knows is in
    ``Observation.lost`` (and some other member is not), the new leader is the first robot
    of :attr:`succession` (the team in the scenario's robot order, the same list for every
    member) that is not lost, and the term rises by one. Members that see the same robots
    lost pick the same leader without a message; a member that elected another robot goes
    back to the old leader if it hears it again before a plan of the new leader arrives
    (it alone had lost it). The new leader keeps its slot and keeps C
    (:class:`NewLeaderPlanner`); everyone keeps its offsets from C. A ``leader_plan`` carries the
    term: a member that hears a plan of a higher term takes its sender as leader (a leader
    that comes back, or a member that learnt of a loss later); a plan of a lower term is
    ignored, so a returning leader follows, at C, instead of taking the lead back.
    """

    def __init__(self, ctx: RobotContext, cfg: LeaderConfig | FollowerConfig, lead: bool) -> None:
        self.ctx = ctx
        schedule = cfg.formation_schedule(f"robots.{ctx.name}.controller")
        first = ctx.name if lead else cfg.leader
        team = {first, *schedule.followers}
        self.succession = tuple(r for r in ctx.robots if r in team)
        """Who leads next: the team in the scenario's robot order."""
        self.term = 0
        self.leader = first
        self.role: LeaderController | FollowerController = (LeaderController(ctx, cfg) if lead
                                                             else FollowerController(ctx, cfg))
        self.planner: NewLeaderPlanner | None = None
        self._before: tuple[str, int] | None = None
        """(leader, term) before an election of another robot, until a plan of the new term
        comes from the new leader: if the old leader is heard again first, this member alone
        had lost it (a lossy link) and it goes back."""

    @property
    def leading(self) -> bool:
        return self.leader == self.ctx.name

    def _elect(self, lost: frozenset[str]) -> None:
        """The succession rule, applied until the leader known is not lost. A member that
        has lost every other member of the team cannot tell a dead team from its own radio
        gone quiet: it keeps what it knows and elects no one."""
        if self._before is not None and self._before[0] not in lost:  # heard again before the new one
            logger.info("%s: leader %s heard again; back to it (term %d)", self.ctx.name, *self._before)
            (self.leader, self.term), self._before = self._before, None
        while self.leader in lost and any(r not in lost for r in self.succession if r != self.ctx.name):
            old, self.leader = self.leader, next(r for r in self.succession if r not in lost)
            if self._before is None and self.leader != self.ctx.name:
                self._before = (old, self.term)
            self.term += 1
            logger.info("%s: leader %s lost; %s leads (term %d)", self.ctx.name, old, self.leader, self.term)

    def _adopt(self, inbox: Sequence[PeerMessage]) -> None:
        """A plan of a higher term: its sender leads. A plan of the leader elected, at its
        term, confirms the election."""
        for m in inbox:
            term = m.payload.get("term", 0) if m.kind == PLAN_KIND else -1
            if not isinstance(term, int) or term < self.term:
                continue
            if term > self.term:
                self.term, self.leader = term, m.sender
                logger.info("%s: %s leads (term %d, heard)", self.ctx.name, m.sender, term)
            if m.sender == self.leader:
                self._before = None

    def _take_role(self, t: float) -> None:
        me, role = self.ctx.name, self.role
        if self.leading and isinstance(role, FollowerController) and self.planner is None:
            # promoted: keep C from the leader progress last known, at the team's speed
            s0 = role.progress(t)
            if s0 is None:  # never heard a plan: C from the schedule's start
                s0 = 0.0
            extra = {} if role.u_R is None else {"u_R": role.u_R}
            cfg = _role_config(LeaderConfig, self.ctx, **extra)
            others = [r for r in self.succession if r != me]
            self.planner = NewLeaderPlanner(cfg, others, s0, role.cfg.horizon, role.nmpc.dt)
            role.follow(me)
        elif not self.leading:
            self.planner = None
            if isinstance(role, LeaderController):  # the first leader, back to a newer one: follow at C
                self.role = FollowerController(self.ctx, _role_config(FollowerConfig, self.ctx, leader=self.leader),
                                               at_c=True)
            else:
                role.follow(self.leader)

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        self._elect(obs.lost)
        self._adopt(inbox)
        self._take_role(obs.t)
        plan = None
        if self.planner is not None:
            plan = self.planner.plan(obs, inbox)
            inbox = [*inbox, PeerMessage(self.ctx.name, PLAN_KIND, obs.t, 0.0, plan)]
        res = self.role.step(obs, inbox)
        if plan is not None:
            res.messages.append(Outgoing(PLAN_KIND, plan, to=tuple(r for r in self.succession if r != self.ctx.name)))
            res.telemetry["slowdown"] = plan["slowdown"]
        if self.leading:
            res.messages = [Outgoing(m.kind, {**m.payload, "term": self.term}, m.to) if m.kind == PLAN_KIND else m
                            for m in res.messages]
        res.telemetry.update(leading=self.leading, term=self.term)
        return res

