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
reference point C moving from the leader progress it last knew (:class:`KeeperOfC`), so
every member keeps its offsets (p, q) from C and no reference jumps; C itself is left empty,
since the lost leader stops there. Each election raises a term carried in the plans, so a
returning leader, which starts at term 0, follows the leader of the higher term (tracking C)
instead of taking the lead back.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from copath.config import ConfigError, from_table, require
from copath.offsets import Quintic, offset_state
from copath.paths import Path, PathTable, wrap_to_pi

from copath.control import (controller, LatestMessages, Observation, Outgoing, PeerMessage, RobotContext, StepResult,
                            VirtualVehicle)
from agent.controllers.omni_nmpc.controller import OmniNMPCFields, OmniPathFollower, OmniPFConfig, OmniTrackingNMPC, check_gain_conditions

__all__ = [
    "PathLeader",
    "LeaderConfig",
    "FollowerConfig",
    "LeaderController",
    "FollowerController",
    "LeaderFollowing",
    "build_leader",
    "build_follower",
    "LeaderPlan",
    "FormationSchedule",
    "FollowerReference",
    "follower_reference",
    "planned_min_separation",
]

logger = logging.getLogger(__name__)

PLAN_KIND = "leader_plan"
"""The leader's plan (s_l, sdot_pred, delta_l) sent after each solve (Sec. 5.3.3)."""
STATUS_KIND = "follower_status"
"""A follower's tracking error for the formation feedback (beyond the text)."""


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


@dataclass(frozen=True)
class _Window:
    formation: str
    s_start: float
    s_end: float


@dataclass(frozen=True)
class FormationSchedule:
    """Curvilinear formation offsets (p_i, q_i) of every follower along the leader's s.

    ``formations`` maps a formation name to ``{robot: (p, q)}``; the leader is the
    reference point C with (0, 0). The team starts in ``initial`` and moves to the
    formation of each window over [s_start, s_end] of the leader's path coordinate,
    with p and q following the quintic (5.3). Windows must not overlap.
    """

    formations: Mapping[str, Mapping[str, tuple[float, float]]]
    initial: str
    windows: tuple[_Window, ...] = ()

    @classmethod
    def from_params(cls, formations: Any, initial: str, schedule: Any, where: str) -> "FormationSchedule":
        """Build from the scenario tables; raises ConfigError naming the key."""
        require(isinstance(formations, Mapping) and formations, f"{where}.formations", formations,
                "expected a table {name = {robot = [p, q], ...}, ...}")
        forms: dict[str, dict[str, tuple[float, float]]] = {}
        robots: set[str] | None = None
        for name, slots in formations.items():
            require(isinstance(slots, Mapping), f"{where}.formations.{name}", slots, "expected {robot = [p, q]}")
            forms[name] = {}
            for robot, pq in slots.items():
                ok = isinstance(pq, (list, tuple)) and len(pq) == 2 and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in pq)
                require(ok, f"{where}.formations.{name}.{robot}", pq, "expected [p, q] in metres")
                forms[name][robot] = (float(pq[0]), float(pq[1]))
            require(robots is None or set(forms[name]) == robots, f"{where}.formations.{name}", sorted(forms[name]),
                    f"every formation must place the same followers: {sorted(robots or [])}")
            robots = set(forms[name])
        require(initial in forms, f"{where}.initial_formation", initial, f"allowed: {', '.join(sorted(forms))}")
        wins = []
        for i, w in enumerate(schedule or []):
            key = f"{where}.schedule[{i}]"
            require(isinstance(w, Mapping) and set(w) == {"formation", "s_start", "s_end"}, key, w,
                    "expected {formation, s_start, s_end}")
            require(w["formation"] in forms, f"{key}.formation", w["formation"], f"allowed: {', '.join(sorted(forms))}")
            s0, s1 = float(w["s_start"]), float(w["s_end"])
            require(s1 > s0, f"{key}.s_end", s1, "must be greater than s_start")
            require(not wins or s0 >= wins[-1].s_end, f"{key}.s_start", s0,
                    "windows must be in order and must not overlap")
            wins.append(_Window(str(w["formation"]), s0, s1))
        return cls(forms, initial, tuple(wins))

    @property
    def followers(self) -> tuple[str, ...]:
        return tuple(self.formations[self.initial])

    def _segments(self, robot: str):
        """Quintics of p and q for each window: list of (window, Quintic_p, Quintic_q)."""
        out = []
        prev = self.formations[self.initial][robot]
        for w in self.windows:
            nxt = self.formations[w.formation][robot]
            out.append((w, Quintic(prev[0], nxt[0], w.s_start, w.s_end), Quintic(prev[1], nxt[1], w.s_start, w.s_end)))
            prev = nxt
        return out, prev

    def offsets(self, robot: str, s_c) -> tuple[np.ndarray, ...]:
        """(p, p', p'', q, q', q'') of ``robot`` at leader coordinate(s) s_c; ' = d/ds_c.
        A robot the formations do not place (the leader) is at C: all zero."""
        s_c = np.asarray(s_c, dtype=float)
        if robot not in self.formations[self.initial]:
            return tuple(np.zeros(s_c.shape) for _ in range(6))
        p0, q0 = self.formations[self.initial][robot]
        p = np.full(s_c.shape, p0)
        q = np.full(s_c.shape, q0)
        zeros = np.zeros(s_c.shape)
        dp, ddp, dq, ddq = zeros.copy(), zeros.copy(), zeros.copy(), zeros.copy()
        segs, _ = self._segments(robot)
        for w, qp, qq in segs:
            sel = s_c > w.s_start  # at and after the window's start the quintic holds (clipped)
            if not np.any(sel):
                continue
            pv, dpv, ddpv = qp(s_c)
            qv, dqv, ddqv = qq(s_c)
            p, dp, ddp = np.where(sel, pv, p), np.where(sel, dpv, dp), np.where(sel, ddpv, ddp)
            q, dq, ddq = np.where(sel, qv, q), np.where(sel, dqv, dq), np.where(sel, ddqv, ddq)
        return p, dp, ddp, q, dq, ddq

    def in_transition(self, s_c: float) -> bool:
        return any(w.s_start <= s_c <= w.s_end for w in self.windows)


# -- follower reference trajectory (5.4)-(5.5) ----------------------------------------


@dataclass(frozen=True)
class FollowerReference:
    """Reference of one follower at a set of times (arrays of equal length)."""

    pose: np.ndarray
    """(n, 3) reference poses (x, y, theta) on the offset curve."""
    u: np.ndarray
    """(n,) reference translational speed u_{i,R} = H u_p (5.4) [m/s]."""
    omega: np.ndarray
    """(n,) reference yaw rate omega_{i,R} = k_i u_{i,R} (5.5) [rad/s]."""
    s_c: np.ndarray
    """(n,) estimated leader path coordinate [m]."""
    s_i: np.ndarray
    """(n,) own path coordinate s_i = s_c + p_i [m]."""
    p: np.ndarray
    """(n,) along-track offsets p_i [m]."""
    H: np.ndarray
    """(n,) dl/ds_i of the offset curve (A.4)."""

    def progress_of(self, xy) -> float:
        """First-order projection of a position onto the path coordinate at row 0:
        s_i + (p - o(s_i)) . t_i / H (the offset curve's tangent t_i, dl/ds = H)."""
        d = np.asarray(xy, dtype=float)[:2] - self.pose[0, :2]
        th = self.pose[0, 2]
        return float(self.s_i[0] + (d[0] * math.cos(th) + d[1] * math.sin(th)) / self.H[0])


def follower_reference(path: Path | PathTable, schedule: FormationSchedule, robot: str, s_c,
                       sdot_c) -> FollowerReference:
    """Reference poses and velocities of follower ``robot`` for leader progress s_c, sdot_c.

    s_i = s_c + p_i(s_c); o(s_i) = r(s_i) + q_i n(s_i) with heading theta_p + atan2(q', 1 - k q)
    (App. A). With p and q functions of s_c (the schedule's coordinate), the derivatives
    along the follower's own coordinate are dq/ds_i = q_c' / (1 + p_c') and
    d2q/ds_i^2 = (q_c'' (1 + p_c') - q_c' p_c'') / (1 + p_c')^3. The speed at s_i is
    u_p = sdot_c (1 + p_c') = sdot_c + pdot_i (docs/reference/ambiguities.md, u_p when the along-track offset varies (A28)), so u_{i,R} = H u_p (5.4) and
    omega_{i,R} = k_i u_{i,R} (5.5).
    """
    s_c = np.atleast_1d(np.asarray(s_c, dtype=float))
    sdot_c = np.broadcast_to(np.asarray(sdot_c, dtype=float), s_c.shape)
    p, dp, ddp, q, dq_c, ddq_c = schedule.offsets(robot, s_c)
    j = 1.0 + dp
    if np.any(j <= 0.05):
        raise ValueError("along-track offset changes faster than the leader moves (1 + dp/ds <= 0.05)")
    dq = dq_c / j
    ddq = (ddq_c * j - dq_c * ddp) / j**3
    s_i = s_c + p
    geo = offset_state(path, s_i, q, dq, ddq)
    u_p = sdot_c * j
    u = geo.H * u_p
    pose = np.column_stack([geo.pos[..., 0], geo.pos[..., 1], geo.theta])
    return FollowerReference(pose=pose, u=u, omega=geo.kappa * u, s_c=s_c, s_i=s_i, p=p, H=geo.H)


def planned_min_separation(path: Path, schedule: FormationSchedule, s_from: float, s_to: float,
                           leader: str = "leader", step: float = 0.02) -> tuple[float, float, tuple[str, str]]:
    """Smallest distance between planned slots (leader at C included) over s_c in [s_from, s_to].

    Returns (distance [m], s_c where it occurs, the pair of robots).
    """
    s_c = np.arange(s_from, s_to + step, step)
    names = [leader, *schedule.followers]
    pos = [np.asarray(path.pos(s_c))]
    for r in schedule.followers:
        ref = follower_reference(path, schedule, r, s_c, np.ones_like(s_c))
        pos.append(ref.pose[:, :2])
    best = (math.inf, float(s_from), (names[0], names[0]))
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            d = np.hypot(*(pos[a] - pos[b]).T)
            k = int(np.argmin(d))
            if d[k] < best[0]:
                best = (float(d[k]), float(s_c[k]), (names[a], names[b]))
    return best


# -- configs -----------------------------------------------------------------------------


@dataclass(frozen=True)
class _FormationFields:
    """Formation keys shared by the leader and the followers (one [controller] table)."""

    leader: str = ""
    """Name of the leader robot (required by followers)."""
    formations: Mapping[str, Any] | None = None
    """{name = {follower = [p, q], ...}, ...}: curvilinear offsets from C [m] (Fig. 5.2)."""
    initial_formation: str = ""
    """Formation at the start (default: the first one listed)."""
    schedule: tuple[Mapping[str, Any], ...] = ()
    """Formation changes [{formation, s_start, s_end}] on the leader's path coordinate [m]."""
    safety_distance: float = 0.5
    """Planned slots of two robots may not come closer than this [m] (checked at build)."""
    formation_feedback: bool = True
    """Followers report their tracking error and the leader slows down (beyond the text)."""

    def formation_schedule(self, where: str) -> FormationSchedule:
        require(bool(self.formations), f"{where}.formations", self.formations,
                "a leader-following team needs at least one formation")
        initial = self.initial_formation or next(iter(self.formations))
        return FormationSchedule.from_params(self.formations, initial, list(self.schedule), where)


@dataclass(frozen=True)
class LeaderConfig(_FormationFields, OmniPFConfig):
    """The leader of Sec. 5.3: path-following NMPC (5.6)-(5.7) with E5.1 values as defaults."""

    horizon: int = 3
    """N_p = 3 (E5.1)."""
    Q: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Q = I_3 (E5.1)."""
    R: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """R = 0.1 I_3 (E5.1)."""
    u_R: float = 0.4
    """Leader reference speed u_R (E5.1: 0.4 m/s); omega_R = kappa_R u_R."""
    sdot_max: float = 1.0
    """Upper bound of s-dot [m/s] (chosen: 2.5 u_R)."""
    feedback_error_low: float = 0.10
    """Formation feedback: full speed while every follower's error is below this [m] (chosen)."""
    feedback_error_high: float = 0.40
    """Formation feedback: slowest at this follower error [m] (chosen)."""
    feedback_min_factor: float = 0.25
    """Formation feedback: lowest fraction of u_R (chosen)."""
    feedback_rate: float = 1.0
    """Formation feedback: largest change of the speed fraction per second [1/s] (chosen)."""
    feedback_stale_s: float = 1.0
    """Follower reports older than this are ignored [s] (chosen)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(0 <= self.feedback_error_low < self.feedback_error_high, "feedback_error_high",
                self.feedback_error_high, "must exceed feedback_error_low >= 0")
        require(0 < self.feedback_min_factor <= 1, "feedback_min_factor", self.feedback_min_factor, "must be in (0, 1]")
        require(self.feedback_rate > 0, "feedback_rate", self.feedback_rate, "must be > 0")
        require(self.feedback_stale_s > 0, "feedback_stale_s", self.feedback_stale_s, "must be > 0")


@dataclass(frozen=True)
class FollowerConfig(_FormationFields, OmniNMPCFields):
    """A follower of Sec. 5.3: trajectory-tracking NMPC (5.8) with E5.1 values as defaults."""

    horizon: int = 3
    """N_p = 3 (E5.1)."""
    Q: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Q = I_3 (E5.1)."""
    R: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """R = 0.1 I_3 (E5.1)."""
    plan_timeout_s: float = 2.0
    """The leader's progress is extrapolated for at most this long without a new plan [s] (chosen)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.plan_timeout_s > 0, "plan_timeout_s", self.plan_timeout_s, "must be > 0")


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


class KeeperOfC:
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
    (:class:`KeeperOfC`); everyone keeps its offsets from C. A ``leader_plan`` carries the
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
        self.keeper: KeeperOfC | None = None
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
        if self.leading and isinstance(role, FollowerController) and self.keeper is None:
            # promoted: keep C from the leader progress last known, at the team's speed
            s0 = role.progress(t)
            if s0 is None:  # never heard a plan: C from the schedule's start
                s0 = 0.0
            extra = {} if role.u_R is None else {"u_R": role.u_R}
            cfg = _role_config(LeaderConfig, self.ctx, **extra)
            others = [r for r in self.succession if r != me]
            self.keeper = KeeperOfC(cfg, others, s0, role.cfg.horizon, role.nmpc.dt)
            role.follow(me)
        elif not self.leading:
            self.keeper = None
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
        if self.keeper is not None:
            plan = self.keeper.plan(obs, inbox)
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


@controller(config=LeaderConfig, needs_path=True, models=("omni",))
def build_leader(ctx: RobotContext, cfg: LeaderConfig) -> LeaderFollowing:
    """Builder of ``leader_nmpc`` (Sec. 5.3)."""
    return LeaderFollowing(ctx, cfg, lead=True)


@controller(config=FollowerConfig, needs_path=True, models=("omni",))
def build_follower(ctx: RobotContext, cfg: FollowerConfig) -> LeaderFollowing:
    """Builder of ``follower_nmpc`` (Sec. 5.3)."""
    return LeaderFollowing(ctx, cfg, lead=False)
