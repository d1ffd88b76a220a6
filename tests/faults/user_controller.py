"""A small user controller for the controller-failure tests (docs/reference/controllers.md, the
plug-in contract): pure pursuit on the robot's own path with a speed correction from the
neighbours' progress, as ``examples/pure_pursuit``, plus two ways to misbehave on purpose.

- ``fail_after_s``: ``step()`` raises ``ZeroDivisionError`` from that controller time on
  (negative: never);
- ``nan_after_s``: from that time on every message carries a NaN in its payload, which
  every receiver must reject (docs/reference/faults.md, "Rejected messages").

Scenarios name it by import path, ``tests.faults.user_controller:build``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from copath.control import LatestMessages, Observation, Outgoing, PeerMessage, RobotContext, StepResult, controller


@dataclass(frozen=True)
class MisbehaveConfig:
    speed: float = 0.2
    """Cruise speed along the path [m/s]."""
    lookahead: float = 0.3
    """Look-ahead distance along the path [m]."""
    k_coord: float = 0.5
    """Speed correction per metre of progress lag behind the neighbours [1/s]."""
    s_d: float = 0.0
    """Desired along-path offset of this robot [m]."""
    fail_after_s: float = -1.0
    """step() raises from this controller time on [s] (negative: never)."""
    nan_after_s: float = -1.0
    """Messages carry a NaN from this controller time on [s] (negative: never)."""


class Misbehave:
    def __init__(self, ctx: RobotContext, cfg: MisbehaveConfig) -> None:
        self.path, self.cfg, self.model = ctx.own_path, cfg, ctx.model
        self.period = self.path.length if self.path.closed else 0.0
        self.s: float | None = None
        self.inbox = LatestMessages()
        self.heard_nan = 0
        """Messages with a non-finite payload that reached this controller (must stay 0)."""

    def step(self, obs: Observation, messages: list[PeerMessage]) -> StepResult:
        if 0 <= self.cfg.fail_after_s <= obs.t + 1e-9:
            raise ZeroDivisionError("division by zero in the user's step")
        self.heard_nan += sum(1 for m in messages if not all(math.isfinite(v) for v in m.payload.values()))
        x, y, theta = obs.pose
        self.s = self.path.project((x, y), self.s)
        xi = self.s - self.cfg.s_d
        self.inbox.update(messages, obs.t)
        lags = []
        for got in self.inbox.fresh("progress", obs.t, max_age=1.0).values():
            d = got.payload["xi"] + got.payload["v"] * got.age(obs.t) - xi
            if self.period:
                d = (d + self.period / 2) % self.period - self.period / 2
            lags.append(d)
        v = min(self.cfg.speed + self.cfg.k_coord * float(np.mean(lags) if lags else 0.0), self.model.v_max)
        gx, gy = self.path.pos(self.s + self.cfg.lookahead)
        alpha = math.atan2(gy - y, gx - x) - theta
        omega = 2.0 * max(v, 0.0) * math.sin(alpha) / self.cfg.lookahead
        px, py = self.path.pos(self.s)
        bad = 0 <= self.cfg.nan_after_s <= obs.t + 1e-9
        return StepResult(
            command=np.array([max(v, 0.0), omega]),
            messages=[Outgoing("progress", {"xi": float("nan") if bad else xi, "v": v})],
            telemetry={"s": self.s, "sdot": v, "xi": xi, "xi_period": self.period, "heard_nan": self.heard_nan,
                       "ref": [float(px), float(py), float(self.path.theta(self.s))]},
        )


@controller(config=MisbehaveConfig, needs_path=True, models=("unicycle",))
def build(ctx: RobotContext, cfg: MisbehaveConfig) -> Misbehave:
    return Misbehave(ctx, cfg)


SCENARIO = """
id = "user-misbehave"
title = "A user controller that fails on purpose"

[run]
duration_s = {duration}
dt = 0.1
settle_s = 0.0

[paths.oval]
type = "ellipse"
a = 1.5
b = 1.0

[controller]
type = "tests.faults.user_controller:build"

[[robots]]
name = "r1"
path = "oval"
pose = [0.70, 0.95, 2.8]
neighbours = ["r2", "r4"]
[robots.controller]
s_d = 1.2

[[robots]]
name = "r2"
path = "oval"
pose = [1.40, 0.45, 2.2]
neighbours = ["r1", "r3"]
[robots.controller]
s_d = 0.6
{r2}

[[robots]]
name = "r3"
path = "oval"
pose = [1.60, 0.0, 1.5708]
neighbours = ["r2", "r4"]

[[robots]]
name = "r4"
path = "oval"
pose = [1.0, -0.75, 0.6]
neighbours = ["r3", "r1"]
[robots.controller]
s_d = -0.8

[metrics]
path_offsets = {{ r1 = 1.2, r2 = 0.6, r3 = 0.0, r4 = -0.8 }}

[targets]
path_error_max_m = 10.0
collisions = 0
"""


def scenario_text(duration: float = 7.0, **r2: float) -> str:
    """The four-robot scenario with robot r2's misbehaviour (``fail_after_s``, ``nan_after_s``)."""
    return SCENARIO.format(duration=duration, r2="\n".join(f"{k} = {v}" for k, v in r2.items()))
