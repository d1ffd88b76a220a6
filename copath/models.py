"""Kinematic models of the dissertation's robots (Chapter 3).

- Omnidirectional robot (3.1) with three Swedish wheels and the wheel map (3.2);
  body velocities (u, v, omega), wheel rim speeds limited by qdot_max.
- Unicycle (3.3) with (v, omega) limits and the curvature-preserving velocity
  scaling of Sec. 5.5.3.

Commands are body-frame velocities: omni ``(u, v, omega)``, unicycle ``(v, omega)``.
Poses are ``(x, y, theta)`` in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "OmniModel",
    "UnicycleModel",
    "integrate_body_velocity",
    "integrate_body_velocities",
    "body_velocity_between",
    "wheel_matrix",
    "rotation_speed_limit",
    "scale_velocities",
    "make_model",
    "limit_change",
    "world_velocity_list",
    "world_velocity",
]

DELTA_WHEEL = math.pi / 6
"""Wheel mounting angle delta of (3.2) [rad]."""


def wheel_matrix(delta: float = DELTA_WHEEL, L_w: float = 0.195) -> np.ndarray:
    """Body-frame wheel map M of (3.2): qdot = M @ [u, v, omega] (rim speeds, m/s)."""
    c, s = math.cos(delta), math.sin(delta)
    return np.array([[c, s, L_w], [-c, s, L_w], [0.0, -1.0, L_w]])


def rotation_speed_limit(omega, qdot_max: float = 1.9, L_w: float = 0.195):
    """Translational speed bound r(omega) of (4.17)-(4.18): qdot_max - L_w |omega|.

    (4.18) prints r = (9.7436 - |omega|) / 5.1283, which is the same line since
    9.7436 = qdot_max / L_w and 5.1283 = 1 / L_w (docs/reference/derivations.md, speed disc (D2)).
    """
    return np.maximum(0.0, qdot_max - L_w * np.abs(omega))


def integrate_body_velocity(pose, body_vel, dt: float) -> np.ndarray:
    """Exact pose after holding body velocities (u, v, omega) constant for dt.

    Integrates (3.1) in closed form (the unicycle is the case v = 0).
    """
    x, y, th = (float(p) for p in pose)
    u, v, w = (float(c) for c in body_vel)
    a = w * dt
    if abs(a) < 1e-9:
        dx_b, dy_b = u * dt, v * dt
    else:
        sa, ca = math.sin(a), math.cos(a)
        dx_b = (u * sa + v * (ca - 1.0)) / w
        dy_b = (u * (1.0 - ca) + v * sa) / w
    c, s = math.cos(th), math.sin(th)
    return np.array([x + c * dx_b - s * dy_b, y + s * dx_b + c * dy_b, th + a])


def body_velocity_between(pose0, pose1, dt: float) -> np.ndarray:
    """Body velocities (u, v, omega) held constant for ``dt`` that take ``pose0`` to ``pose1``:
    the exact inverse of :func:`integrate_body_velocity` (what a robot that sees two of its poses
    can tell of its base's twist; the heading change is taken the short way round)."""
    x0, y0, th0 = (float(p) for p in pose0)
    x1, y1, th1 = (float(p) for p in pose1)
    a = math.remainder(th1 - th0, 2.0 * math.pi)
    c, s = math.cos(th0), math.sin(th0)
    dx_b = c * (x1 - x0) + s * (y1 - y0)
    dy_b = -s * (x1 - x0) + c * (y1 - y0)
    w = a / dt
    if abs(a) < 1e-9:
        return np.array([dx_b / dt, dy_b / dt, w])
    sa, ca = math.sin(a), math.cos(a)
    k = w / (2.0 - 2.0 * ca)  # the 2x2 map of integrate_body_velocity, inverted
    return np.array([k * (sa * dx_b + (1.0 - ca) * dy_b), k * ((ca - 1.0) * dx_b + sa * dy_b), w])


def integrate_body_velocities(poses: np.ndarray, body_vels: np.ndarray, dt: float) -> np.ndarray:
    """:func:`integrate_body_velocity` for many robots at once: poses (n, 3), body
    velocities (n, 3) held for dt; returns the new poses (n, 3) (the simulator's physics)."""
    P = np.asarray(poses, dtype=float)
    B = np.asarray(body_vels, dtype=float)
    u, v, w = B[:, 0], B[:, 1], B[:, 2]
    a = w * dt
    small = np.abs(a) < 1e-9
    w_safe = np.where(small, 1.0, w)
    sa, ca = np.sin(a), np.cos(a)
    dx_b = np.where(small, u * dt, (u * sa + v * (ca - 1.0)) / w_safe)
    dy_b = np.where(small, v * dt, (u * (1.0 - ca) + v * sa) / w_safe)
    c, s = np.cos(P[:, 2]), np.sin(P[:, 2])
    return np.stack([P[:, 0] + c * dx_b - s * dy_b, P[:, 1] + s * dx_b + c * dy_b, P[:, 2] + a], axis=1)


def _check_accel(model) -> None:
    for name in ("a_max", "alpha_max"):
        val = getattr(model, name)
        if val is not None and not (math.isfinite(val) and val > 0):
            raise ValueError(f"{model.kind} model {name} = {val!r} is not allowed; must be > 0 (or left out: no limit)")


def limit_change(model, previous, command, dt: float) -> np.ndarray:
    """Command the robot can reach within dt from the ``previous`` applied one.

    Both are body commands within the model's limits (omni ``(u, v, omega)``, unicycle
    ``(v, omega)``). The applied command moves towards ``command`` along the straight line
    between them, by the largest fraction lam in [0, 1] with ``|Delta (u, v)| <= a_max dt``
    (unicycle ``|Delta v| <= a_max dt``) and ``|Delta omega| <= alpha_max dt``: a convex
    combination of two admissible commands, so the wheel limits (3.2) and the (v, omega) box
    still hold. Without limits it returns ``command`` (docs/reference/safety.md, "acceleration limits")."""
    cmd = np.asarray(command, dtype=float)
    if model.a_max is None and model.alpha_max is None:
        return cmd
    prev = np.asarray(previous, dtype=float)
    d = cmd - prev
    lam = 1.0
    trans = float(np.hypot(d[0], d[1])) if model.kind == "omni" else abs(float(d[0]))
    if model.a_max is not None and trans > model.a_max * dt:
        lam = min(lam, model.a_max * dt / trans)
    if model.alpha_max is not None and abs(float(d[-1])) > model.alpha_max * dt:
        lam = min(lam, model.alpha_max * dt / abs(float(d[-1])))
    return prev + lam * d


def world_velocity(model, theta: float, command) -> np.ndarray:
    """World-frame velocity ``(xdot, ydot, thetadot)`` of a robot at heading theta applying a
    body command, (3.1) / (3.3)."""
    return np.array(world_velocity_list(model, theta, command))


def world_velocity_list(model, theta: float, command) -> list[float]:
    """:func:`world_velocity` as a list of Python floats (the envelopes' ``vel``; no array
    for three numbers)."""
    c = np.asarray(command, dtype=float).tolist() if type(command) is not list else command
    u, v = (float(c[0]), float(c[1])) if model.kind == "omni" else (float(c[0]), 0.0)
    ct, st = math.cos(theta), math.sin(theta)
    return [ct * u - st * v, st * u + ct * v, float(c[-1])]


@dataclass(frozen=True)
class OmniModel:
    """Three-wheeled omnidirectional robot, (3.1)-(3.2)."""

    L_w: float = 0.195
    """Wheel distance from the centre [m]."""
    qdot_max: float = 1.9
    """Wheel rim-speed limit [m/s]."""
    delta: float = DELTA_WHEEL
    """Wheel mounting angle [rad]."""
    radius: float = 0.2
    """Footprint radius for collision checks [m] (chosen)."""
    a_max: float | None = None
    """Acceleration limit of the translational body velocity (u, v) [m/s^2], enforced by the
    simulator (:func:`limit_change`); None: no limit (velocities jump as in Chapter 3)."""
    alpha_max: float | None = None
    """Limit on the change of the yaw rate omega [rad/s^2]; None: no limit."""

    kind = "omni"
    command_size = 3

    def __post_init__(self) -> None:
        for name in ("L_w", "qdot_max", "radius"):
            if not getattr(self, name) > 0:
                raise ValueError(f"omni model {name} must be > 0, got {getattr(self, name)!r}")
        _check_accel(self)

    @property
    def M(self) -> np.ndarray:
        return wheel_matrix(self.delta, self.L_w)

    def wheel_speeds(self, cmd) -> np.ndarray:
        """Wheel rim speeds (3,) for body velocities (u, v, omega), (3.2)."""
        return self.M @ np.asarray(cmd, dtype=float).reshape(3)

    def world_wheel_matrix(self, theta: float) -> np.ndarray:
        """J(theta) with qdot = J(theta) [xdot, ydot, omega] (docs/reference/derivations.md, omni wheel map (D1); rows of (4.11))."""
        d = self.delta
        return np.array(
            [
                [math.cos(theta + d), math.sin(theta + d), self.L_w],
                [-math.cos(theta - d), -math.sin(theta - d), self.L_w],
                [math.sin(theta), -math.cos(theta), self.L_w],
            ]
        )

    def max_speed(self, omega):
        """Translational speed bound r(omega) = qdot_max - L_w |omega| of (4.17)-(4.18) [m/s]."""
        return rotation_speed_limit(omega, self.qdot_max, self.L_w)

    def max_rotation(self, u):
        """Yaw-rate bound omega_l(u) = (qdot_max - |u|) / L_w [rad/s]: the inverse of
        (4.18), printed in Sec. 4.3 as 9.7436 - 5.1283 u."""
        return np.maximum(0.0, (self.qdot_max - np.abs(u)) / self.L_w)

    def max_tangent_speed(self, kappa):
        """Largest speed along a curve of curvature kappa when the body turns with the
        tangent (omega = kappa u): the u solving u = r(kappa u), qdot_max / (1 + L_w |kappa|)."""
        return self.qdot_max / (1.0 + self.L_w * np.abs(kappa))

    def saturate_wheels(self, qdot) -> np.ndarray:
        """Wheel rim speeds (3,) scaled by a common factor so that none exceeds qdot_max
        (the direction of motion is kept, (3.2))."""
        qdot = np.asarray(qdot, dtype=float).reshape(3)
        peak = float(np.max(np.abs(qdot)))
        return qdot * (self.qdot_max / peak) if peak > self.qdot_max else qdot

    def saturate(self, cmd) -> tuple[np.ndarray, bool]:
        """Scale a command so every wheel speed is within qdot_max.

        Returns the applied command and whether the request violated the limit
        (beyond a 1e-6 relative tolerance).
        """
        cmd = np.asarray(cmd, dtype=float).reshape(3)
        peak = float(np.max(np.abs(self.wheel_speeds(cmd))))
        if peak <= self.qdot_max * (1 + 1e-6):
            return cmd, False
        return cmd * (self.qdot_max / peak), True

    def step(self, pose, cmd, dt: float) -> np.ndarray:
        return integrate_body_velocity(pose, cmd, dt)


def scale_velocities(v: float, omega: float, v_max: float, omega_max: float) -> tuple[float, float]:
    """Curvature-preserving scaling (Sec. 5.5.3): divide (v, omega) by
    sigma = max(1, |v|/v_max, |omega|/omega_max)."""
    sigma = max(1.0, abs(v) / v_max, abs(omega) / omega_max)
    return v / sigma, omega / sigma


@dataclass(frozen=True)
class UnicycleModel:
    """Differential-drive robot (3.3): xdot = v cos theta, ydot = v sin theta, thetadot = omega."""

    v_max: float = 0.5
    """Forward speed limit |v| [m/s]."""
    omega_max: float = 1.0
    """Yaw-rate limit |omega| [rad/s]."""
    b: float = 0.05
    """Half axle: centre to wheel distance [m] (chosen; the text gives only the 12 cm body)."""
    radius: float = 0.06
    """Footprint radius for collision checks [m] (c't-Bot, 12 cm diameter)."""
    a_max: float | None = None
    """Acceleration limit of the forward speed v [m/s^2], enforced by the simulator
    (:func:`limit_change`); None: no limit (velocities jump as in Chapter 3)."""
    alpha_max: float | None = None
    """Limit on the change of the yaw rate omega [rad/s^2]; None: no limit."""

    kind = "unicycle"
    command_size = 2

    def __post_init__(self) -> None:
        for name in ("v_max", "omega_max", "b", "radius"):
            if not getattr(self, name) > 0:
                raise ValueError(f"unicycle model {name} must be > 0, got {getattr(self, name)!r}")
        _check_accel(self)

    def wheel_speeds(self, cmd) -> np.ndarray:
        """(v_r, v_l) = (v + b omega, v - b omega) of (3.3)."""
        v, w = (float(c) for c in np.asarray(cmd).reshape(2))
        return np.array([v + self.b * w, v - self.b * w])

    def saturate(self, cmd) -> tuple[np.ndarray, bool]:
        """Clip (v, omega) to the limits with the curvature-preserving scaling."""
        if type(cmd) in (tuple, list) and len(cmd) == 2:  # the hot path: no array for two numbers
            v, w = float(cmd[0]), float(cmd[1])
        else:
            v, w = (float(c) for c in np.asarray(cmd, dtype=float).reshape(2))
        tol = 1e-6
        violated = abs(v) > self.v_max * (1 + tol) or abs(w) > self.omega_max * (1 + tol)
        return np.array(scale_velocities(v, w, self.v_max, self.omega_max)), violated

    def step(self, pose, cmd, dt: float) -> np.ndarray:
        v, w = (float(c) for c in np.asarray(cmd).reshape(2))
        return integrate_body_velocity(pose, (v, 0.0, w), dt)


MODEL_TYPES = {"omni": OmniModel, "unicycle": UnicycleModel}


def make_model(spec: dict | str) -> OmniModel | UnicycleModel:
    """Build a model from ``"omni"`` or a table ``{type = "unicycle", v_max = 0.5}``."""
    if isinstance(spec, str):
        spec = {"type": spec}
    kind = spec.get("type")
    if kind not in MODEL_TYPES:
        raise ValueError(f"model type = {kind!r} is not allowed; choose one of {sorted(MODEL_TYPES)}")
    cls = MODEL_TYPES[kind]
    allowed = set(cls.__dataclass_fields__)
    kwargs = {k: v for k, v in spec.items() if k != "type"}
    for k, v in kwargs.items():
        if k not in allowed:
            raise ValueError(f"model key {k!r} (= {v!r}) is not allowed for {kind!r}; allowed: {sorted(allowed)}")
    return cls(**{k: float(v) for k, v in kwargs.items()})
