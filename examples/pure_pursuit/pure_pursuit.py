"""Pure pursuit on the robot's path, with a speed correction from the neighbours' progress.

A user controller for copath, kept outside the package: the scenario next to this file
names it by import path (``controller.type = "pure_pursuit:build"``). It is the
coordination idea of Sec. 5.5 of the dissertation in its simplest form: each robot
follows its own path by pure pursuit and speeds up or slows down so that its path
coordinate, minus its desired offset ``s_d``, agrees with its neighbours'.

Besides its law it declares, on its factory, what the rest of copath would otherwise have
to be told: the schema of its ``progress`` message (receivers validate it) and its team
geometry (how the metrics grade the team from the simulator's truth: robots spaced along
their paths by their ``s_d``), so the offsets are typed once, in the robots' parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from copath.control import LatestMessages, Observation, Outgoing, PeerMessage, RobotContext, StepResult, controller
from copath.team import TeamGeometry, along_path_geometry, robot_params

PAYLOADS = {"progress": {"xi": "float", "v": "float"}}
"""The one message kind it sends: its coordination coordinate xi = s - s_d and its speed."""


@dataclass(frozen=True)
class PursuitConfig:
    speed: float = 0.2
    """Cruise speed along the path [m/s]."""
    lookahead: float = 0.3
    """Look-ahead distance along the path [m]."""
    k_coord: float = 0.5
    """Speed correction per metre of progress lag behind the neighbours [1/s]."""
    s_d: float = 0.0
    """Desired along-path offset of this robot [m]."""

    def __post_init__(self) -> None:
        for key in ("speed", "lookahead", "k_coord"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key} = {getattr(self, key)!r} is not allowed; must be > 0")


class PurePursuit:
    def __init__(self, ctx: RobotContext, cfg: PursuitConfig) -> None:
        self.path, self.cfg, self.model = ctx.own_path, cfg, ctx.model
        self.period = self.path.length if self.path.closed else 0.0
        self.s: float | None = None
        self.inbox = LatestMessages()

    def step(self, obs: Observation, messages: list[PeerMessage]) -> StepResult:
        x, y, theta = obs.pose
        self.s = self.path.project((x, y), self.s)
        xi = self.s - self.cfg.s_d
        self.inbox.update(messages, obs.t)
        lags = []
        for got in self.inbox.fresh("progress", obs.t, max_age=1.0).values():
            d = got.payload["xi"] + got.payload["v"] * got.age(obs.t) - xi  # neighbour's xi now
            if self.period:
                d = (d + self.period / 2) % self.period - self.period / 2
            lags.append(d)
        v = min(self.cfg.speed + self.cfg.k_coord * float(np.mean(lags) if lags else 0.0), self.model.v_max)
        gx, gy = self.path.pos(self.s + self.cfg.lookahead)
        alpha = math.atan2(gy - y, gx - x) - theta
        omega = 2.0 * max(v, 0.0) * math.sin(alpha) / self.cfg.lookahead
        px, py = self.path.pos(self.s)
        return StepResult(
            command=np.array([max(v, 0.0), omega]),
            messages=[Outgoing("progress", {"xi": xi, "v": v})],
            telemetry={"s": self.s, "sdot": v, "xi": xi, "xi_period": self.period,
                       "ref": [float(px), float(py), float(self.path.theta(self.s))]},
        )


def team_geometry(scenario) -> TeamGeometry:
    """xi_i = s_i - s_di; robot i's slot at xi_ref is its path point at xi_ref + s_di."""
    paths = {r.name: scenario.paths[r.path] for r in scenario.robots}
    s_d = {n: robot_params(scenario, PursuitConfig, n).s_d for n in paths}
    return along_path_geometry("pure_pursuit", paths, s_d)


@controller(config=PursuitConfig, needs_path=True, models=("unicycle",), payloads=PAYLOADS, geometry=team_geometry)
def build(ctx: RobotContext, cfg: PursuitConfig) -> PurePursuit:
    return PurePursuit(ctx, cfg)
