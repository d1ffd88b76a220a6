"""The world: true poses, obstacles, sensors and time (pure; ``sim/node.py`` puts it on a link).

Each robot's commanded body velocities are saturated by its model's limits (a command
beyond them is counted as a limit violation) and integrated exactly over the tick
(``copath.models.integrate_body_velocities``). The physics is vectorised over the robots:
poses, requested and applied commands live in arrays, one row per robot, and each model
kind saturates its rows at once (unicycles: the curvature-preserving scaling of
Sec. 5.5.3; omni robots: the common wheel-speed scaling of (3.2)), so a realtime
simulator steps hundreds of robots at 100 Hz (docs/reference/performance.md). Observations carry the pose with optional
Gaussian noise (or, with a ``[sensing]`` profile, the raw readings and measurements of
the robot's sensor models, ``sim/sensing.py``) and, when enabled, a ring of range readings computed from the true
geometry of the obstacles (``sim/geometry.py``) and of the other robots' discs.
"""

from __future__ import annotations

import math

import numpy as np

from copath.models import OmniModel, UnicycleModel, integrate_body_velocities, wheel_matrix
from copath.safety import awaits_overheard
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
        self._every_message = awaits_overheard(scenario.safety)
        """The lockstep barrier counts every message of each sender (the safety filter overhears)."""
        self._totals: tuple[int, dict[str, int]] = (-1, {})
        """(tick, every message each robot had sent by then): with :attr:`_every_message` the
        same for every robot's observation of the tick, so summed once a tick, not once a robot
        (N^2 sums: 9.7 ms a tick at 128 robots, 0.2 ms summed once)."""
        n = len(self.names)
        self._P = np.array([r.pose for r in scenario.robots], dtype=float).reshape(n, 3)
        self.poses = {name: self._P[i] for i, name in enumerate(self.names)}  # row views
        self._B = np.zeros((n, 3))  # applied body velocities (u, v, omega) of every robot
        self._viol = np.zeros(n, dtype=bool)
        self._groups = [_Group(kind, [i for i, r in enumerate(scenario.robots) if isinstance(r.model, cls)],
                               scenario.robots) for kind, cls in (("unicycle", UnicycleModel), ("omni", OmniModel))]
        self._groups = [g for g in self._groups if len(g.rows)]
        if sum(len(g.rows) for g in self._groups) != n:
            raise ValueError("every robot model must be a unicycle or an omni robot")
        self.requested: dict[str, np.ndarray] = {}
        self.applied: dict[str, np.ndarray] = {}
        for g in self._groups:
            for j, i in enumerate(g.rows):
                self.requested[self.names[i]] = g.req[j]  # row views
                self.applied[self.names[i]] = g.app[j]
        self.t = 0.0
        self._step_dt = scenario.run.dt
        self._saturated_dt: float | None = None
        """The dt of the latest :meth:`saturate_all`, until a command or a step changes what it
        computed (requested rows are written through :meth:`command` only)."""
        self._noise_rng = np.random.default_rng(np.random.SeedSequence([scenario.run.seed, 101]))
        std = np.asarray(scenario.noise.pose_std, dtype=float)
        self._pose_std = std if np.any(std > 0) else None
        """Standard deviations of the observed pose's noise (None: no noise)."""
        self.sensors = scenario.sensors
        self.sensing: dict[str, RobotSensors] = {}  # robots with a non-ideal sensor profile
        for i, r in enumerate(scenario.robots):
            profile = scenario.sensing.profile_for(r.name, r.model.kind)
            if not profile.ideal:
                self.sensing[r.name] = RobotSensors(profile, r.model, scenario.run.seed, i, r.pose)
        self._angles = self.sensors.angles()
        self._obstacles = []
        if scenario.obstacles or self.sensors.enabled:
            from sim import geometry  # noqa: PLC0415  (only worlds with obstacles/sensors need it)

            self._geo = geometry
            self._obstacles = [geometry.PolygonObstacle(np.array(o.vertices), np.array(o.velocity))
                               for o in scenario.obstacles]

    # -- commands and integration ---------------------------------------------------
    def command(self, name: str, cmd) -> None:
        """Set the requested command of a robot (held until the next one)."""
        row = self.requested[name]
        row[:] = np.asarray(cmd, dtype=float).reshape(row.shape)
        self._saturated_dt = None

    def advance(self, dt: float) -> None:
        """Integrate every robot over dt with its saturated (and, for models with an
        acceleration limit, rate-limited) command."""
        self.saturate_all(dt)
        for n, sensors in self.sensing.items():
            sensors.advance(self.t, self.poses[n], self.applied[n], dt)  # read only, nothing kept
        self._P[:] = integrate_body_velocities(self._P, self._B, dt)
        for g in self._groups:
            g.commit()
        self._saturated_dt = None
        self._step_dt = dt
        self.t += dt

    def saturate_all(self, dt: float | None = None) -> None:
        """Compute applied commands and violations without moving (for the truth record).

        Models with an acceleration limit move from the command applied over the last
        physics step towards the saturated request by at most a_max * dt
        (``copath.models.limit_change``); dt defaults to the last physics step's (run.dt
        before the first). Idempotent until :meth:`advance` commits the step."""
        dt = self._step_dt if dt is None else dt
        if dt == self._saturated_dt:  # nothing changed since (a lockstep tick's truth, then its step)
            return
        for g in self._groups:
            g.saturate(self._B, self._viol, dt)
        self._saturated_dt = dt

    # -- observations -----------------------------------------------------------------
    def obstacle_polygons(self, t: float | None = None) -> list[np.ndarray]:
        t = self.t if t is None else t
        return [o.at(t) for o in self._obstacles]

    def observe(self, name: str, k: int, sent: dict[str, dict[str, int]] | None = None,
                down: list[str] | None = None) -> Obs:
        """Observation of robot ``name`` at tick k; ``sent`` (each robot's latest
        ``Command.sent``) gives the lockstep barrier of peer messages to wait for, ``down`` the
        robots whose token the simulator holds gone (lockstep, ``Obs.down``)."""
        meas = None
        if name in self.sensing:
            pose, meas = self.sensing[name].read(self.t)
        elif self._pose_std is None:
            pose = self.poses[name].tolist()
        else:
            pose = self.poses[name] + self._noise_rng.normal(0.0, 1.0, 3) * self._pose_std
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
            if self._every_message:  # the filter overhears: every message each robot sent
                if self._totals[0] != k:  # ``sent`` changes between ticks, never within one
                    self._totals = (k, {s: sum(int(v) for v in c.values()) for s, c in sent.items()})
                expect = dict(self._totals[1])
                expect.pop(name, None)
            else:
                expect = {s: int(c.get("*", 0)) + int(c.get(name, 0)) for s, c in sent.items() if s != name}
        return Obs(k, float(self.t), pose if type(pose) is list else [float(v) for v in pose], ranges, expect, meas, down)

    def truth(self, k: int) -> Truth:
        clearance = None
        polys = None
        if self._obstacles:
            polys_np = self.obstacle_polygons()
            clearance = [float(self._geo.clearance(self.poses[n][:2], self.models[n].radius, polys_np))
                         for n in self.names]
            polys = [p.tolist() for p in polys_np]
        wheel = np.zeros(len(self.names))
        for g in self._groups:
            wheel[g.rows] = g.wheel_max()
        return Truth(
            k=k,
            t=float(self.t),
            names=list(self.names),
            poses=self._P.tolist(),
            commands=[self.applied[n].tolist() for n in self.names],
            violated=self._viol.tolist(),
            wheel_max=wheel.tolist(),
            clearance=clearance,
            obstacles=polys,
        )


class _Group:
    """The robots of one model kind: their rows, limits, requested and applied commands."""

    def __init__(self, kind: str, rows: list[int], robots) -> None:
        self.kind = kind
        self.rows = np.array(rows, dtype=int)
        models = [robots[i].model for i in rows]
        size = 2 if kind == "unicycle" else 3
        self.req = np.zeros((len(rows), size))
        self.app = np.zeros((len(rows), size))
        # acceleration limits (inf: none) and the command applied over the last physics step
        self.a_max = np.array([np.inf if m.a_max is None else m.a_max for m in models])
        self.alpha_max = np.array([np.inf if m.alpha_max is None else m.alpha_max for m in models])
        self.limited = bool(np.any(np.isfinite(self.a_max)) or np.any(np.isfinite(self.alpha_max)))
        self.prev = np.zeros((len(rows), size))
        if kind == "unicycle":
            self.v_max = np.array([m.v_max for m in models])
            self.w_max = np.array([m.omega_max for m in models])
            self.b = np.array([m.b for m in models])
        else:
            self.M = np.stack([wheel_matrix(m.delta, m.L_w) for m in models]) if models else np.zeros((0, 3, 3))
            self.q_max = np.array([m.qdot_max for m in models])

    def saturate(self, B: np.ndarray, viol: np.ndarray, dt: float) -> None:
        """Applied commands (into ``self.app``), body velocities (rows of B) and violations."""
        R = self.req
        if self.kind == "unicycle":  # UnicycleModel.saturate, row-wise
            v, w = R[:, 0], R[:, 1]
            tol = 1e-6
            viol[self.rows] = (np.abs(v) > self.v_max * (1 + tol)) | (np.abs(w) > self.w_max * (1 + tol))
            sigma = np.maximum(1.0, np.maximum(np.abs(v) / self.v_max, np.abs(w) / self.w_max))
            self.app[:, 0] = v / sigma
            self.app[:, 1] = w / sigma
        else:  # OmniModel.saturate, row-wise
            peak = np.max(np.abs(np.einsum("kij,kj->ki", self.M, R)), axis=1)
            over = peak > self.q_max * (1 + 1e-6)
            viol[self.rows] = over
            scale = np.where(over, self.q_max / np.where(over, peak, 1.0), 1.0)
            self.app[:] = R * scale[:, None]
        if self.limited:  # copath.models.limit_change, row-wise
            d = self.app - self.prev
            trans = np.abs(d[:, 0]) if self.kind == "unicycle" else np.hypot(d[:, 0], d[:, 1])
            lam = np.ones(len(d))
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = np.minimum(lam, np.where(trans > self.a_max * dt, self.a_max * dt / trans, 1.0))
                rot = np.abs(d[:, -1])
                lam = np.minimum(lam, np.where(rot > self.alpha_max * dt, self.alpha_max * dt / rot, 1.0))
            self.app[:] = self.prev + lam[:, None] * d
        if self.kind == "unicycle":
            B[self.rows, 0] = self.app[:, 0]
            B[self.rows, 1] = 0.0
            B[self.rows, 2] = self.app[:, 1]
        else:
            B[self.rows] = self.app

    def commit(self) -> None:
        """The applied commands were held over a physics step: the next step starts from them."""
        if self.limited:
            self.prev[:] = self.app

    def wheel_max(self) -> np.ndarray:
        """Largest wheel rim speed of each robot for its applied command [m/s]."""
        if self.kind == "unicycle":
            return np.maximum(np.abs(self.app[:, 0] + self.b * self.app[:, 1]),
                              np.abs(self.app[:, 0] - self.b * self.app[:, 1]))
        return np.max(np.abs(np.einsum("kij,kj->ki", self.M, self.app)), axis=1)
