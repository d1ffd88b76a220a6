"""Heterogeneous team: an omni leader and unicycle followers (Sec. 5.5.5, docs/reference/ambiguities.md, heterogeneous team's follower law (A27)).

The formation control is centralised on the leader, as in the original: the leader
follows a waypoint path (a C2 spline through waypoints, standing in for the CARMEN
navigator's) with the omni path-following NMPC of the Sec. 5.3 leader, receives each
follower's pose estimate (``hetero_report``: the camera fix plus compass heading of the
original), computes the follower's velocities and sends them as ``hetero_cmd``. The
followers only apply the newest command (and stop when it is too old).

Follower law (the text says only "a nonlinear controller"; docs/reference/ambiguities.md, heterogeneous team's follower law (A27)): follower i
tracks the point of the leader's path at s_L - s_d,i with lateral offset q_i, i.e. the
offset-curve reference (5.10) with the velocities (5.11)-(5.12), using the unicycle
tracking law (5.39)-(5.40) of Sec. 5.5 (``consensus.tracking_law``); its reference
point moves with the leader's virtual vehicle, not by consensus.

Age of information: the leader predicts each follower's pose forward by the report's
age plus the expected link latency (the command will be applied one latency later)
with the last command it sent, and evaluates the reference at that time.

Beyond the dissertation (it had no collision avoidance; docs/reference/controllers-notes.md, heterogeneous braking near other robots (N6)): before
sending, the leader scales down each robot's forward speed when it is heading towards
another robot closer than ``slow_distance`` beyond the contact distance, down to a stop
at ``stop_distance`` (its own (u, v) too). Headings keep turning, so a robot can steer
away.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from copath.config import require
from copath.models import integrate_body_velocity
from copath.paths import PathTable, wrap_to_pi

from copath.control import LatestMessages, Observation, Outgoing, PeerMessage, RobotContext, StepResult
from agent.controllers.consensus.controller import tracking_errors, tracking_law
from agent.controllers.leader_following.controller import PathLeader

from .config import HeteroFollowerConfig, HeteroLeaderConfig
from .payloads import COMMAND_KIND, REPORT_KIND

__all__ = [
    "HeteroLeaderConfig",
    "HeteroFollowerConfig",
    "HeteroLeader",
    "HeteroFollower",
    "brake_factor",
    "offset_reference",
]

logger = logging.getLogger(__name__)


def brake_factor(p, direction, others, stop: Sequence[float], slow: float,
                 cone: float = math.pi / 2) -> tuple[float, float]:
    """Speed fraction in [0, 1] for a robot at ``p`` moving along ``direction``, and the side
    of the robot that limits it.

    Parameters
    ----------
    p : (2,) position.
    direction : (2,) direction of motion (need not be unit; zero means not moving).
    others : (m, 2) positions of the other robots.
    stop : (m,) centre distance at which to stop for each other robot [m].
    slow : float
        Braking starts ``slow`` metres beyond the stop distance [m].
    cone : float
        Only robots within this angle of ``direction`` count [rad] (pi/2: the half plane ahead).

    Returns
    -------
    fraction : float
        Falls linearly from 1 at stop + slow to 0 at stop for the closest robot ahead.
    side : float
        +1 when that robot is to the left of ``direction``, -1 to the right or dead
        ahead, 0 when nothing brakes.
    """
    d = np.asarray(direction, dtype=float)
    n = float(np.hypot(*d))
    others = np.atleast_2d(np.asarray(others, dtype=float))
    if n < 1e-12 or others.size == 0:
        return 1.0, 0.0
    d = d / n
    r = others - np.asarray(p, dtype=float)[None, :2]
    dist = np.hypot(r[:, 0], r[:, 1])
    ahead = (r @ d) > np.cos(cone) * dist
    frac = np.where(ahead, np.clip((dist - np.asarray(stop, dtype=float)) / slow, 0.0, 1.0), 1.0)
    k = int(np.argmin(frac))
    if frac[k] >= 1.0:
        return 1.0, 0.0
    cross = d[0] * r[k, 1] - d[1] * r[k, 0]
    return float(frac[k]), 1.0 if cross > 1e-9 else -1.0


def offset_reference(geometry: PathTable, s: float, q: float, sdot: float) -> tuple[np.ndarray, float, float]:
    """Reference pose, speed and curvature of the point at s with constant offset q.

    (5.10): (x_p - q sin theta_p, y_p + q cos theta_p, theta_p); (5.11)-(5.12):
    v_d = sdot (1 - kappa q), kappa_i = kappa / (1 - kappa q). Raises ValueError at a cusp.
    """
    g = geometry(s)[:, 0]
    x, y, th, k = (float(v) for v in g[:4])
    one = 1.0 - k * q
    if one <= 0.05:
        raise ValueError(f"offset q = {q} is beyond the leader path's radius of curvature at s = {s:.2f}")
    return np.array([x - q * math.sin(th), y + q * math.cos(th), th]), sdot * one, k / one


@dataclass
class _FollowerState:
    s_d: float
    q: float
    radius: float
    pose: np.ndarray | None = None
    stamp: float = -math.inf
    age: float = 0.0
    t_receipt: float = 0.0
    last_cmd: tuple[float, float] = (0.0, 0.0)


class HeteroLeader:
    """The omni leader: path following plus the followers' formation law (Sec. 5.5.5)."""

    def __init__(self, ctx: RobotContext, cfg: HeteroLeaderConfig) -> None:
        self.ctx, self.cfg = ctx, cfg
        self.leader = PathLeader(ctx, cfg, "hetero_leader")
        self.geometry = self.leader.path.table()
        self.radius = ctx.model.radius
        self.followers: dict[str, _FollowerState] = {}
        for name, (s_d, q) in cfg.followers.items():
            require(name in ctx.neighbours, f"robots.{ctx.name}.neighbours", list(ctx.neighbours),
                    f"the leader exchanges messages with its neighbours; add follower {name!r}")
            self.followers[name] = _FollowerState(float(s_d), float(q), cfg.follower_radius)
        self.inbox = LatestMessages(kinds=(REPORT_KIND,), senders=tuple(self.followers))

    def _receive(self, t: float, inbox: Sequence[PeerMessage]) -> None:
        for got in self.inbox.update(inbox, t):
            st, p = self.followers[got.sender], got.payload
            st.pose = np.array([float(p["x"]), float(p["y"]), float(p["heading"])])
            st.stamp, st.age, st.t_receipt = got.stamp, got.message.age, got.received_at

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        cfg = self.cfg
        self._receive(obs.t, inbox)
        sol = self.leader.solve(obs, cfg.u_R)
        s_L, sdot_L = float(self.leader.s), float(sol.sdot[0])
        body = np.array(sol.body, dtype=float)
        # predicted follower poses at the time their command will be applied
        plans: dict[str, tuple[np.ndarray, float]] = {}
        for name, st in self.followers.items():
            if st.pose is None or obs.t - st.stamp > cfg.report_stale_s:
                continue
            latency = st.age if cfg.latency_s is None else cfg.latency_s
            horizon = st.age + (obs.t - st.t_receipt) + latency
            v, w = st.last_cmd
            plans[name] = (integrate_body_velocity(st.pose, (v, 0.0, w), horizon), latency)
        messages, commands = [], {}
        for name, (pose, latency) in plans.items():
            st = self.followers[name]
            s_ref = s_L + sdot_L * latency - st.s_d
            try:
                ref, v_d, kap = offset_reference(self.geometry, s_ref, st.q, sdot_L)
            except ValueError as exc:
                logger.warning("%s: no reference for %s: %s", self.ctx.name, name, exc)
                continue
            errors = tracking_errors(pose, ref)
            v, w, _ = tracking_law(errors, v_d, kap, v_d, cfg.k1, cfg.k4, cfg.k5, cfg.theta_a)  # (5.39)-(5.40)
            # coordination coordinate: the follower's progress (first-order projection
            # onto the offset curve, dl/ds = 1 - kappa q) plus s_d; equals s_L in formation
            along = (pose[0] - ref[0]) * math.cos(ref[2]) + (pose[1] - ref[1]) * math.sin(ref[2])
            one = v_d / sdot_L if sdot_L > 1e-6 else 1.0
            commands[name] = [v, w, ref, s_ref + along / max(one, 0.05) + st.s_d, pose]
        if cfg.avoidance:
            self._avoid(obs, body, commands)
        for name, (v, w, ref, xi, _) in commands.items():
            self.followers[name].last_cmd = (v, w)
            messages.append(Outgoing(COMMAND_KIND, {"v": float(v), "omega": float(w),
                                                    "ref": [float(ref[0]), float(ref[1]), float(wrap_to_pi(ref[2]))],
                                                    "xi": float(xi)}, to=(name,)))
        tel = self.leader.telemetry(sol, cfg.u_R)
        tel["followers_commanded"] = len(commands)
        return StepResult(command=body, messages=messages, telemetry=tel)

    def _avoid(self, obs: Observation, body: np.ndarray, commands: dict[str, list]) -> None:
        """Brake every robot heading towards another one (in place)."""
        cfg = self.cfg
        names = [self.ctx.name, *commands]
        pos = np.array([obs.pose[:2]] + [c[4][:2] for c in commands.values()])
        radii = np.array([self.radius] + [self.followers[n].radius for n in commands])
        th = float(obs.pose[2])
        lead_dir = np.array([math.cos(th) * body[0] - math.sin(th) * body[1],
                             math.sin(th) * body[0] + math.cos(th) * body[1]])
        for i, name in enumerate(names):
            others = np.delete(pos, i, axis=0)
            stop = radii[i] + np.delete(radii, i) + cfg.stop_margin
            if i == 0:
                f, _ = brake_factor(pos[0], lead_dir, others, stop, cfg.slow_distance)
                body[:2] *= f
            else:
                c = commands[name]
                heading = c[4][2]
                sgn = 1.0 if c[0] >= 0 else -1.0
                f, side = brake_factor(pos[i], sgn * np.array([math.cos(heading), math.sin(heading)]),
                                       others, stop, cfg.slow_distance)
                c[0] *= f
                # steer away from the robot that blocks the way (a unicycle cannot sidestep)
                c[1] -= sgn * side * (1.0 - f) * cfg.avoid_turn_rate


class HeteroFollower:
    """A unicycle follower: reports its pose, applies the newest command of the leader."""

    def __init__(self, ctx: RobotContext, cfg: HeteroFollowerConfig) -> None:
        require(cfg.leader in ctx.neighbours, f"robots.{ctx.name}.controller.leader", cfg.leader,
                f"must name a neighbour of {ctx.name!r}: {', '.join(ctx.neighbours) or '(none)'}")
        self.ctx, self.cfg = ctx, cfg
        self.inbox = LatestMessages(kinds=(COMMAND_KIND,), senders=(cfg.leader,))

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        self.inbox.update(inbox, obs.t)
        got = self.inbox.get(self.cfg.leader, COMMAND_KIND)
        self.cmd = dict(got.payload) if got is not None else None
        report = Outgoing(REPORT_KIND, {"x": float(obs.pose[0]), "y": float(obs.pose[1]),
                                            "heading": float(obs.pose[2])},
                          to=(self.cfg.leader,))
        age = got.age(obs.t) if got is not None else 0.0
        tel: dict[str, Any] = {"command_age": float(age) if self.cmd is not None else None}
        if self.cmd is None or age > self.cfg.cmd_timeout_s:
            return StepResult(command=np.zeros(2), messages=[report], telemetry=tel)
        cmd, _ = self.ctx.model.saturate([float(self.cmd["v"]), float(self.cmd["omega"])])
        if "ref" in self.cmd:
            ref = [float(v) for v in self.cmd["ref"]]
            tel["ref"] = ref
            tel["formation_error"] = float(math.hypot(obs.pose[0] - ref[0], obs.pose[1] - ref[1]))
        if "xi" in self.cmd:
            tel["xi"] = float(self.cmd["xi"])
        return StepResult(command=cmd, messages=[report], telemetry=tel)

