"""The world: true poses, obstacles, sensors and time (pure; ``sim/node.py`` puts it on Zenoh).

Each robot's commanded body velocities are saturated by its model's limits (a command
beyond them is counted as a limit violation) and integrated exactly over the tick
(``copath.models.integrate_body_velocity``). Observations carry the pose with optional
Gaussian noise (or, with a ``[sensing]`` profile, the raw readings and measurements of
the robot's sensor models, ``sim/sensing.py``) and, when enabled, a ring of range readings computed from the true
geometry of the obstacles (``sim/geometry.py``) and of the other robots' discs.
"""

from __future__ import annotations

import math

import numpy as np

from copath.scenario import Scenario
from copath.wire.messages import Obs, Truth

from .sensing import RobotSensors

__all__ = ["World"]


def _disc_polygon(center, radius: float, n: int = 12) -> np.ndarray:
    a = 2 * math.pi * np.arange(n) / n
    return np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], axis=-1)


class World:
    """Ground truth of one run."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.names = list(scenario.robot_names)
        self.models = {r.name: r.model for r in scenario.robots}
        self.poses = {r.name: np.array(r.pose, dtype=float) for r in scenario.robots}
        self.requested = {r.name: np.zeros(r.model.command_size) for r in scenario.robots}
        self.applied = {r.name: np.zeros(r.model.command_size) for r in scenario.robots}
        self.violated = {r.name: False for r in scenario.robots}
        self.t = 0.0
        self._noise_rng = np.random.default_rng(np.random.SeedSequence([scenario.run.seed, 101]))
        self.sensors = scenario.sensors
        self.sensing: dict[str, RobotSensors] = {}  # robots with a non-ideal sensor profile
        for i, r in enumerate(scenario.robots):
            profile = scenario.sensing.profile_for(r.name, r.model.kind)
            if not profile.ideal:
                self.sensing[r.name] = RobotSensors(profile, r.model, scenario.run.seed, i, r.pose)
        self._angles = 2 * math.pi * np.arange(self.sensors.count) / self.sensors.count
        self._obstacles = []
        if scenario.obstacles or self.sensors.enabled:
            from sim import geometry  # noqa: PLC0415  (only worlds with obstacles/sensors need it)

            self._geo = geometry
            self._obstacles = [geometry.PolygonObstacle(np.array(o.vertices), np.array(o.velocity))
                               for o in scenario.obstacles]

    # -- commands and integration ---------------------------------------------------
    def command(self, name: str, cmd) -> None:
        """Set the requested command of a robot (held until the next one)."""
        self.requested[name] = np.asarray(cmd, dtype=float).reshape(-1)

    def advance(self, dt: float) -> None:
        """Integrate every robot over dt with its saturated command."""
        for n in self.names:
            model = self.models[n]
            applied, violated = model.saturate(self.requested[n])
            self.applied[n] = applied
            self.violated[n] = violated
            if n in self.sensing:
                self.sensing[n].advance(self.t, self.poses[n], applied, dt)
            self.poses[n] = model.step(self.poses[n], applied, dt)
        self.t += dt

    def saturate_all(self) -> None:
        """Compute applied commands and violations without moving (for the truth record)."""
        for n in self.names:
            self.applied[n], self.violated[n] = self.models[n].saturate(self.requested[n])

    # -- observations -----------------------------------------------------------------
    def obstacle_polygons(self, t: float | None = None) -> list[np.ndarray]:
        t = self.t if t is None else t
        return [o.at(t) for o in self._obstacles]

    def observe(self, name: str, k: int, sent: dict[str, dict[str, int]] | None = None) -> Obs:
        """Observation of robot ``name`` at tick k; ``sent`` (each robot's latest
        ``Command.sent``) gives the lockstep barrier of peer messages to wait for."""
        meas = None
        if name in self.sensing:
            pose, meas = self.sensing[name].read(self.t)
        else:
            pose = self.poses[name].copy()
            std = np.asarray(self.scenario.noise.pose_std)
            if np.any(std > 0):
                pose = pose + self._noise_rng.normal(0.0, 1.0, 3) * std
        ranges = None
        if self.sensors.enabled:
            polys = self.obstacle_polygons()
            r_self = self.models[name].radius
            for other in self.names:  # other robots are seen as discs
                if other != name:
                    polys.append(_disc_polygon(self.poses[other][:2], self.models[other].radius))
            true_pose = self.poses[name]
            # rays start on the robot's rim so the robot does not see itself
            r = self._geo.ray_cast(true_pose[:2], float(true_pose[2]), self._angles,
                                   self.sensors.max_range_m + r_self, polys)
            r = np.asarray(r, dtype=float) - r_self
            if self.scenario.noise.range_std > 0:
                finite = np.isfinite(r)
                r[finite] += self._noise_rng.normal(0.0, self.scenario.noise.range_std, int(finite.sum()))
            r = np.where(np.isfinite(r), np.clip(r, 0.0, self.sensors.max_range_m), np.inf)
            ranges = [float(v) for v in r]
        expect = None
        if sent is not None:
            expect = {s: int(c.get("*", 0)) + int(c.get(name, 0)) for s, c in sent.items() if s != name}
        return Obs(k, float(self.t), [float(v) for v in pose], ranges, expect, meas)

    def truth(self, k: int) -> Truth:
        clearance = None
        polys = None
        if self._obstacles:
            polys_np = self.obstacle_polygons()
            clearance = [float(self._geo.clearance(self.poses[n][:2], self.models[n].radius, polys_np))
                         for n in self.names]
            polys = [p.tolist() for p in polys_np]
        wheel = []
        for n in self.names:
            ws = self.models[n].wheel_speeds(self.applied[n])
            wheel.append(float(np.max(np.abs(ws))))
        return Truth(
            k=k,
            t=float(self.t),
            names=list(self.names),
            poses=[[float(v) for v in self.poses[n]] for n in self.names],
            commands=[[float(v) for v in self.applied[n]] for n in self.names],
            violated=[bool(self.violated[n]) for n in self.names],
            wheel_max=wheel,
            clearance=clearance,
            obstacles=polys,
        )
