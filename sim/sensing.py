"""Sensor models of one robot (pure; the simulator's :class:`sim.world.World` drives them).

What a real robot of the dissertation would receive instead of its true pose
(Secs. 3.1-3.2, 5.5.4; profiles in ``copath.estimation``, values in docs/reference/sensing.md):

- **position fixes** taken at ``fix_rate_hz`` from the true position at that instant, with
  Gaussian noise, occasional outliers, and delivered ``fix_latency_s`` later, stamped
  with the time they were taken;
- **heading measurements** (compass) at ``heading_rate_hz`` with noise and a bias that
  follows a random walk, wrapped to [-pi, pi), also stamped and delayed;
- **wheel odometry**: the applied (saturated) body velocities of every integration step
  with multiplicative slip noise, as segments ``[t0, t1, u...]``.

Measurements are taken inside an integration step at the exact pose of that instant
(the command is constant over the step, so ``model.step`` over a fraction of it is exact).
Every random draw comes from a generator seeded by (run seed, robot index).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from copath.estimation import SensorProfile
from copath.paths import wrap_to_pi

__all__ = ["RobotSensors"]


class RobotSensors:
    """The sensors of one robot; :meth:`advance` while the world integrates, :meth:`read`
    at each observation."""

    def __init__(self, profile: SensorProfile, model, seed: int, index: int, pose0) -> None:
        self.p = profile
        self.model = model
        self.rng = np.random.default_rng(np.random.SeedSequence([int(seed), 303, int(index)]))
        self.bias = profile.heading_bias_rad
        self._pending: deque = deque()  # (t_deliver, kind, [t_taken, ...]) in delivery order per kind
        self._odom: list[list[float]] = []
        self._next_fix = 1.0 / profile.fix_rate_hz
        self._next_head = 1.0 / profile.heading_rate_hz
        self._t_bias = 0.0
        self.outliers = 0
        # the first reading (t = 0, delivered at once: the robot starts localised)
        self.held = [*self._fix(np.asarray(pose0, dtype=float)), self._heading(float(pose0[2]), 0.0)]

    # -- single measurements ---------------------------------------------------------
    def _fix(self, pose: np.ndarray) -> tuple[float, float]:
        p = self.p
        if p.outlier_prob > 0 and self.rng.random() < p.outlier_prob:
            self.outliers += 1
            e = self.rng.normal(0.0, p.outlier_std_m, 2)
        else:
            e = self.rng.normal(0.0, p.fix_std_m, 2) if p.fix_std_m > 0 else np.zeros(2)
        return float(pose[0] + e[0]), float(pose[1] + e[1])

    def _heading(self, theta: float, t: float) -> float:
        p = self.p
        if p.heading_bias_walk > 0 and t > self._t_bias:
            self.bias += p.heading_bias_walk * math.sqrt(t - self._t_bias) * float(self.rng.normal())
        self._t_bias = max(self._t_bias, t)
        n = float(self.rng.normal(0.0, p.heading_std_rad)) if p.heading_std_rad > 0 else 0.0
        return wrap_to_pi(theta + self.bias + n)

    # -- driven by the world ----------------------------------------------------------
    def advance(self, t0: float, pose0: np.ndarray, applied: np.ndarray, dt: float) -> None:
        """The robot moves from ``pose0`` at ``t0`` for ``dt`` with ``applied``: take the
        measurements due in (t0, t0 + dt] and one odometry segment."""
        t1 = t0 + dt
        p = self.p
        while self._next_fix <= t1 + 1e-9:
            tm = self._next_fix
            x, y = self._fix(self.model.step(pose0, applied, tm - t0))
            self._pending.append((tm + p.fix_latency_s, "fix", [tm, x, y]))
            self._next_fix = tm + 1.0 / p.fix_rate_hz
        while self._next_head <= t1 + 1e-9:
            tm = self._next_head
            th = float(self.model.step(pose0, applied, tm - t0)[2])
            self._pending.append((tm + p.heading_latency_s, "heading", [tm, self._heading(th, tm)]))
            self._next_head = tm + 1.0 / p.heading_rate_hz
        u = np.asarray(applied, dtype=float)
        noise = np.zeros_like(u)
        if p.odom_slip > 0:
            noise += p.odom_slip * np.abs(u) * self.rng.normal(size=u.shape)
        if p.odom_std > 0:
            noise += p.odom_std * self.rng.normal(size=u.shape)
        self._odom.append([float(t0), float(t1), *(float(v) for v in u + noise)])

    def read(self, t: float) -> tuple[list[float], dict]:
        """Raw pose reading held at ``t`` (latest fix and heading delivered) and the
        measurements delivered since the previous read: ``{"odom": [[t0, t1, u...]],
        "fixes": [[t, x, y]], "headings": [[t, theta]]}``."""
        fixes, heads, keep = [], [], deque()
        while self._pending:
            item = self._pending.popleft()
            if item[0] <= t + 1e-9:
                (fixes if item[1] == "fix" else heads).append(item[2])
            else:
                keep.append(item)
        self._pending = keep
        if fixes:
            self.held[0], self.held[1] = fixes[-1][1], fixes[-1][2]
        if heads:
            self.held[2] = heads[-1][1]
        odom, self._odom = self._odom, []
        return list(self.held), {"odom": odom, "fixes": fixes, "headings": heads}
