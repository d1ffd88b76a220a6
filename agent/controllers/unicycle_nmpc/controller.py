"""Unicycle NMPC blending path following and trajectory tracking, with an obstacle cost
from range sensors (Chapter 4, Sec. 4.4, (4.37)-(4.55)).

Prediction state (x_e, y_e, theta_e, eta_e, s): the path-frame errors (4.37) at the
virtual vehicle, the speed error eta_e = v - v_d (4.39) and the path coordinate.
Decision variables (s-dot, omega, a) per step, equivalent to u_e of (4.40); dynamics
(4.38)-(4.41). Objective: sum of F (4.42) + terminal penalty V (4.43) + time penalty
F_t (4.53) + obstacle cost F_obs (4.54). The terminal region (4.49) (with sin, docs/reference/ambiguities.md,
missing sine in the terminal region (A8)) and the bounds (4.52) on the terminal-law commands (inverted per docs/reference/ambiguities.md, terminal-law commands (A9)) are
soft constraints. Gain conditions (4.48) are checked at build time.

Modes (E4.4): ``path_following`` (K_t = 0, s-dot free), ``trajectory_tracking`` (the
virtual vehicle runs on the clock, s-dot = v_d, s = s_t(t); K_t unused) and
``combined`` (s-dot free plus F_t). ``terminal = false`` is the real-robot variant of
Sec. 4.4.4 / E4.7 (no terminal penalty or region; F_t kept).

Path geometry inside the NLP is a second-order expansion about the warm-start
prediction s_bar of each step (curvature, tangent angle and position), so the NLP holds
no interpolant; the expansion error is third order in s - s_bar.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Sequence

import casadi as ca
import numpy as np

from copath.config import ConfigError, require
from copath.models import UnicycleModel
from copath.mpc import OCP, MPCSolver, SolveResult, SolverConfig, weighted
from copath.paths import Path, wrap_to_pi

from copath.control import VirtualVehicle, Observation, PeerMessage, RobotContext, StepResult

from .config import MODES, UnicycleNMPCConfig

__all__ = [
    "uni_errors",
    "uni_error_dynamics",
    "uni_virtual_inputs",
    "uni_gain_condition_margins",
    "terminal_law",
    "obstacle_cost",
    "scan_points",
    "UnicycleNMPC",
    "UnicycleNMPCConfig",
    "UnicycleNMPCController",
    "MODES",
]

logger = logging.getLogger(__name__)


_SMOOTH_EPS = 1e-4
"""epsilon of |theta| ~ sqrt(theta^2 + eps) in (4.54) (docs/reference/ambiguities.md, ray-cast obstacle cost (A11))."""


# -- error model ---------------------------------------------------------------------


def uni_errors(pose, ref, v: float, v_d: float) -> np.ndarray:
    """Errors (4.37) and (4.39): (x_e, y_e, theta_e, eta_e) w.r.t. ``ref = (x_d, y_d, theta_d)``."""
    x, y, th = (float(c) for c in pose)
    xd, yd, thd = (float(c) for c in ref[:3])
    c, s = math.cos(thd), math.sin(thd)
    dx, dy = x - xd, y - yd
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_to_pi(th - thd), v - v_d])


def uni_error_dynamics(xe, sdot, omega, a, v_d, vdot_d, kappa):
    """(4.38)-(4.41): time derivative of (x_e, y_e, theta_e, eta_e), v = v_d + eta_e."""
    v = v_d + xe[3]
    return ca.vertcat(
        xe[1] * sdot * kappa - sdot + v * ca.cos(xe[2]),
        -xe[0] * sdot * kappa + v * ca.sin(xe[2]),
        omega - sdot * kappa,
        a - vdot_d,
    )


def uni_virtual_inputs(xe, sdot, omega, a, v_d, vdot_d, kappa):
    """u_e of (4.40): (-s-dot + v cos theta_e, omega - s-dot kappa, a - v-dot_d)."""
    v = v_d + xe[3]
    return ca.vertcat(-sdot + v * ca.cos(xe[2]), omega - sdot * kappa, a - vdot_d)


def uni_gain_condition_margins(Q, R, P, gains) -> np.ndarray:
    """Margins of (4.48): (p11 a - q11 - a^2 r11 - q22, p33 b - q33 - b^2 r22,
    p44 g - q44 - g^2 r33); all must be >= 0."""
    Q, R, P = (np.asarray(v, float) for v in (Q, R, P))
    a, b, g = (float(k) for k in gains)
    return np.array([
        P[0] * a - Q[0] - a * a * R[0] - Q[1],
        P[2] * b - Q[2] - b * b * R[1],
        P[3] * g - Q[3] - g * g * R[2],
    ])


def terminal_law(xe, v_d, vdot_d, kappa, gains):
    """Terminal-law commands, (4.50) inverted (docs/reference/ambiguities.md, terminal-law commands (A9)): (s-dot^L, omega^L, a^L)."""
    a_, b_, g_ = gains
    v = v_d + xe[3]
    sdot = a_ * xe[0] + v * ca.cos(xe[2])
    return sdot, -b_ * xe[2] + sdot * kappa, -g_ * xe[3] + vdot_d


def obstacle_cost(pose, points, weights, K_obs: float, c1: float, c2: float):
    """F_obs of (4.54) for one predicted pose: sum_j K e^{-c1 |theta_j|} e^{-c2 d_j}.

    ``points`` (n, 2) are detected obstacle points in the world frame; theta_j is their
    bearing in the robot frame and d_j their distance; |theta| is smoothed as
    sqrt(theta^2 + eps). Works for numpy or CasADi poses.
    """
    total = 0
    for j in range(len(weights)):
        dx, dy = points[j][0] - pose[0], points[j][1] - pose[1]
        c, s = ca.cos(pose[2]), ca.sin(pose[2])
        bearing = ca.atan2(-s * dx + c * dy, c * dx + s * dy)
        d = ca.sqrt(dx * dx + dy * dy + 1e-9)
        total = total + weights[j] * K_obs * ca.exp(-c1 * ca.sqrt(bearing**2 + _SMOOTH_EPS)) * ca.exp(-c2 * d)
    return total


def scan_points(pose, ranges, angles, radius: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """World points of the range hits and their weights (1 hit, 0 none), padded to n.

    Ranges are measured from the robot's rim (``sim/world.py``), so a hit at range r
    along bearing a lies at the centre + (r + radius) (cos(theta + a), sin(theta + a)).
    Unused slots hold a point 1 km away (weight 0) so no derivative meets atan2(0, 0).
    """
    far = np.array([float(pose[0]) + 1e3, float(pose[1])])
    pts = np.tile(far, (n, 1))
    w = np.zeros(n)
    if ranges is None or angles is None:
        return pts, w
    r = np.asarray(ranges, float).reshape(-1)[:n]
    a = np.asarray(angles, float).reshape(-1)[:n]
    hit = np.isfinite(r)
    th = float(pose[2]) + a
    dist = r + radius
    pts[: len(r), 0] = np.where(hit, float(pose[0]) + dist * np.cos(th), far[0])
    pts[: len(r), 1] = np.where(hit, float(pose[1]) + dist * np.sin(th), far[1])
    w[: len(r)] = hit.astype(float)
    return pts, w


# -- problem -------------------------------------------------------------------------


def _expand(s, p):
    """Second-order path expansion about s_bar: (x_d, y_d, theta_d, kappa) at s.

    p = (kappa_bar, dkappa_bar, s_bar, x_bar, y_bar, theta_bar, ...).
    """
    ds = s - p[2]
    k, dk = p[0], p[1]
    th0 = p[5]
    c, sn = ca.cos(th0), ca.sin(th0)
    x = p[3] + c * ds - 0.5 * k * sn * ds * ds
    y = p[4] + sn * ds + 0.5 * k * c * ds * ds
    return x, y, th0 + k * ds + 0.5 * dk * ds * ds, k + dk * ds


def _world_pose(xs, p):
    """World pose of the robot from the error state (x_e, y_e, theta_e, eta_e, s)."""
    x_d, y_d, th_d, _ = _expand(xs[4], p)
    c, s = ca.cos(th_d), ca.sin(th_d)
    return x_d + c * xs[0] - s * xs[1], y_d + s * xs[0] + c * xs[1], th_d + xs[2]


@dataclass
class UniSolution:
    ok: bool
    sdot: np.ndarray
    """(N,) planned s-dot."""
    omega: float
    a: float
    x: np.ndarray
    """(N+1, 5) predicted (x_e, y_e, theta_e, eta_e, s)."""
    result: SolveResult


class UnicycleNMPC:
    """The Sec. 4.4 optimal control problem (build once, solve many).

    Stage parameters (per step): kappa_bar, dkappa_bar, s_bar, x_bar, y_bar, theta_bar,
    v_d, vdot_d and n_points obstacle points (x, y, weight). Terminal parameters: the
    same for step N plus the time reference (x, y, theta, v) at t + T_p.
    """

    n_geo = 8

    def __init__(
        self,
        N: int,
        dt: float,
        Q: Sequence[float],
        R: Sequence[float],
        P: Sequence[float],
        K_t: Sequence[float],
        gains: Sequence[float],
        K_obs: float,
        c1: float,
        c2: float,
        v_bounds: tuple[float, float],
        omega_bounds: tuple[float, float],
        a_bounds: tuple[float, float],
        sdot_max: float,
        mode: str = "combined",
        terminal: bool = True,
        n_points: int = 12,
        v_d_nominal: float = 0.0,
        solver: SolverConfig | None = None,
        name: str = "unicycle",
    ) -> None:
        require(mode in MODES, "mode", mode, f"allowed: {', '.join(MODES)}")
        self.N, self.dt, self.mode, self.terminal = int(N), float(dt), mode, terminal
        self.n_points = int(n_points)
        self.sdot_max = float(sdot_max)
        self.gains = tuple(float(g) for g in gains)
        Q, R, P, K_t = (np.asarray(v, float) for v in (Q, R, P, K_t))
        if terminal:
            m = uni_gain_condition_margins(Q, R, P, gains)
            for name_, mi in zip(("alpha", "beta", "gamma"), m):
                if mi < -1e-12:
                    raise ConfigError(f"{name_} = {gains!r} is not allowed; the gain condition (4.48) "
                                      f"fails with margin {mi:.4g}")
        use_time = mode == "combined" and bool(np.any(K_t > 0))
        use_obs = K_obs > 0 and n_points > 0
        ng, npts = self.n_geo, self.n_points

        def dynamics(x, u, p):
            _, _, _, k = _expand(x[4], p)
            xe = uni_error_dynamics(x[:4], u[0], u[1], u[2], p[6], p[7], k)
            return ca.vertcat(xe, u[0])

        def obstacle_residuals(x, p):
            if not use_obs:
                return []
            pose = _world_pose(x, p)
            out = []
            c, s = ca.cos(pose[2]), ca.sin(pose[2])
            for j in range(npts):
                px, py, w = p[ng + 3 * j], p[ng + 3 * j + 1], p[ng + 3 * j + 2]
                dx, dy = px - pose[0], py - pose[1]
                bearing = ca.atan2(-s * dx + c * dy, c * dx + s * dy)
                d = ca.sqrt(dx * dx + dy * dy + 1e-9)
                # r^2 = w^2 K exp(-c1 |theta|) exp(-c2 d), (4.54); w in {0, 1}
                out.append(w * math.sqrt(K_obs) * ca.exp(-0.5 * c1 * ca.sqrt(bearing**2 + _SMOOTH_EPS) - 0.5 * c2 * d))
            return out

        def stage(x, u, p):
            _, _, _, k = _expand(x[4], p)
            ue = uni_virtual_inputs(x[:4], u[0], u[1], u[2], p[6], p[7], k)
            return ca.vertcat(weighted(x[:4], Q), weighted(ue, R), *obstacle_residuals(x, p))

        n_pt = ng + 3 * npts + 4

        def terminal_cost(x, p):
            parts = []
            if terminal:
                parts.append(weighted(x[:4], 0.5 * P))  # (4.43)
            if use_time:
                # (4.53) in the frame of the time reference (docs/reference/ambiguities.md, frame of the time penalty (A10)):
                # [longitudinal, lateral, heading, speed] differences
                xr, yr, thr, vr = (p[ng + 3 * npts + i] for i in range(4))
                px, py, th = _world_pose(x, p)
                c, s = ca.cos(thr), ca.sin(thr)
                dx, dy = px - xr, py - yr
                e = ca.vertcat(c * dx + s * dy, -s * dx + c * dy, th - thr, p[6] + x[3] - vr)
                parts.append(weighted(e, K_t))
            parts += obstacle_residuals(x, p)
            return ca.vertcat(*parts) if parts else ca.SX(0, 1)

        def terminal_region(x, u, p):
            _, _, _, k = _expand(x[4], p)
            v = p[6] + x[3]
            _, om_L, a_L = terminal_law(x[:4], p[6], p[7], k, self.gains)
            # (4.49) with sin (docs/reference/ambiguities.md, missing sine in the terminal region (A8)): x^2 - y^2 >= 0 and y v sin(theta) <= 0;
            # (4.52) on the terminal-law commands
            return ca.vertcat(x[0] ** 2 - x[1] ** 2, x[1] * v * ca.sin(x[2]), om_L, a_L)

        v_lo, v_hi = v_bounds
        self.v_bounds = (float(v_lo), float(v_hi))
        # |v| <= v_max on the predicted speed v = v_d + eta_e (hard state bound, v_d nominal)
        x_lb = [-np.inf, -np.inf, -np.inf, v_lo - v_d_nominal, -np.inf]
        x_ub = [np.inf, np.inf, np.inf, v_hi - v_d_nominal, np.inf]
        ocp = OCP(
            nx=5, nu=3, N=self.N, dt=self.dt, dynamics=dynamics, stage_residual=stage,
            terminal_residual=terminal_cost, n_p=ng + 3 * npts, n_pt=n_pt,
            u_lb=[0.0, omega_bounds[0], a_bounds[0]], u_ub=[self.sdot_max, omega_bounds[1], a_bounds[1]],
            soft_terminal=terminal_region if terminal else None,
            hT_lb=[0.0, -np.inf, omega_bounds[0], a_bounds[0]],
            hT_ub=[np.inf, 0.0, omega_bounds[1], a_bounds[1]],
            x_lb=x_lb, x_ub=x_ub, name=name,
        )
        self.mpc = MPCSolver(ocp, solver or SolverConfig())

    def solve(self, x0, geo: np.ndarray, points: np.ndarray, weights: np.ndarray,
              time_ref: np.ndarray | None, sdot_fixed: float | None = None) -> UniSolution:
        """Solve one step.

        Parameters
        ----------
        x0 : (5,)
            (x_e, y_e, theta_e, eta_e, s).
        geo : (N+1, 8)
            Per step: kappa, dkappa, s_bar, x_bar, y_bar, theta_bar, v_d, vdot_d.
        points, weights : (N+1, n_points, 2), (N+1, n_points)
            Predicted obstacle points and their weights.
        time_ref : (4,) or None
            Time reference (x, y, theta, v) at t + T_p.
        sdot_fixed : float, optional
            Pin s-dot (trajectory tracking: the virtual vehicle runs on the clock).
        """
        N, npts = self.N, self.n_points
        obs = np.concatenate([points.reshape(N + 1, npts, 2), weights.reshape(N + 1, npts, 1)], axis=2)
        stage_p = np.hstack([geo, obs.reshape(N + 1, 3 * npts)])
        tr = np.zeros(4) if time_ref is None else np.asarray(time_ref, float)
        p_term = np.concatenate([stage_p[N], tr])
        u_lb = u_ub = None
        if sdot_fixed is not None:
            lo, hi = self.mpc.u_bounds
            lo[:, 0] = hi[:, 0] = sdot_fixed
            u_lb, u_ub = lo, hi
        guess = None
        if self.mpc.shifted_plan() is None:
            guess = self._cold_guess(x0, geo)
        res = self.mpc.solve(x0, stage_p[:N], p_term, guess=guess, u_lb=u_lb, u_ub=u_ub)
        return UniSolution(res.ok, res.u[:, 0].copy(), float(res.u0[1]), float(res.u0[2]), res.x, res)

    def _cold_guess(self, x0, geo) -> tuple[np.ndarray, np.ndarray]:
        N = self.N
        X = np.tile(np.asarray(x0, float), (N + 1, 1))
        vd = geo[:, 6]
        X[:, 4] = x0[4] + np.concatenate([[0.0], np.cumsum(vd[:N] * self.dt)])
        U = np.zeros((N, 3))
        U[:, 0] = np.clip(vd[:N], 0.0, self.sdot_max)
        U[:, 1] = geo[:N, 0] * vd[:N]
        return X, U


# -- controller -------------------------------------------------------------------------


class UnicycleNMPCController:
    """Sec. 4.4 controller: error state, obstacle points, solve, command (v, omega)."""

    def __init__(self, ctx: RobotContext, cfg: UnicycleNMPCConfig) -> None:
        if not isinstance(ctx.model, UnicycleModel):
            raise ConfigError(f"robots.{ctx.name}.model = {ctx.model.kind!r} is not allowed; unicycle_nmpc needs unicycle")
        where = f"robots.{ctx.name}.controller"
        if cfg.terminal:
            m = uni_gain_condition_margins(cfg.Q, cfg.R, cfg.P, cfg.gains)
            names = ("alpha", "beta", "gamma")
            for i, mi in enumerate(m):
                if mi < -1e-12:
                    raise ConfigError(f"{where}.{names[i]} = {cfg.gains[i]!r} is not allowed; "
                                      f"(4.48) fails with margin {mi:.4g}")
        self.cfg, self.model, self.dt = cfg, ctx.model, float(ctx.dt)
        self.path: Path = ctx.own_path
        self.table = self.path.table()
        self.radius = ctx.model.radius
        v_max = min(cfg.v_max, ctx.model.v_max)
        om_max = min(cfg.omega_max, ctx.model.omega_max)
        self.v_max, self.omega_max = v_max, om_max
        self.nmpc = UnicycleNMPC(
            cfg.horizon, self.dt, cfg.Q, cfg.R, cfg.P, cfg.K_t, cfg.gains, cfg.K_obs, cfg.c1, cfg.c2,
            (-v_max, v_max), (-om_max, om_max), (-cfg.a_max, cfg.a_max), cfg.sdot_max,
            mode=cfg.mode, terminal=cfg.terminal, n_points=12 if cfg.K_obs > 0 else 0, v_d_nominal=cfg.v_d,
            solver=cfg.solver_config(), name=f"{ctx.name}_uni",
        )
        self.vehicle = VirtualVehicle(cfg.s0)
        self.v = float(cfg.v0)
        self._t0: float | None = None
        self._prev_scan: tuple[float, np.ndarray, np.ndarray] | None = None

    @property
    def s(self) -> float:
        """The virtual vehicle's path coordinate [m]."""
        return self.vehicle.s

    def time_reference(self, t: float) -> np.ndarray:
        """(x, y, theta, v) of the time-parameterised reference s_t = s0 + v_d (t - t0)."""
        st = self.cfg.s0 + self.cfg.v_d * (t - (self._t0 or 0.0))
        x, y, th, _ = self.table.pose(st)
        return np.array([x, y, th, self.cfg.v_d])

    def _obstacles(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        N, n = self.cfg.horizon, 12
        pts, w = scan_points(obs.pose, obs.ranges, obs.sensor_angles, self.radius, n)
        vel = np.zeros((n, 2))
        if self.cfg.predict_obstacles and self._prev_scan is not None:
            t_prev, p_prev, w_prev = self._prev_scan
            h = obs.t - t_prev
            if h > 1e-9:
                both = (w > 0) & (w_prev > 0)
                vel[both] = (pts[both] - p_prev[both]) / h
                # a ray sweeping along a surface fakes speed: cap it (chosen 1 m/s)
                sp = np.linalg.norm(vel, axis=1)
                vel *= np.minimum(1.0, 1.0 / np.maximum(sp, 1e-9))[:, None]
        self._prev_scan = (obs.t, pts.copy(), w.copy())
        steps = self.dt * np.arange(N + 1)
        P = pts[None, :, :] + steps[:, None, None] * vel[None, :, :]
        W = np.tile(w, (N + 1, 1))
        return P, W

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        cfg, N, dt = self.cfg, self.cfg.horizon, self.dt
        if self._t0 is None:
            self._t0 = obs.t
        tracking = cfg.mode == "trajectory_tracking"
        if tracking:  # the virtual vehicle runs on the clock
            self.vehicle.start(cfg.s0 + cfg.v_d * (obs.t - self._t0))
        else:
            self.vehicle.advance(obs.t)
        plan = self.nmpc.mpc.shifted_plan()
        if plan is not None and not tracking:
            s_bar = plan[0][:, 4] - plan[0][0, 4] + self.s
        else:
            s_bar = self.s + cfg.v_d * dt * np.arange(N + 1)
        geo_tab = self.table(s_bar)
        geo = np.stack([geo_tab[3], geo_tab[4], s_bar, geo_tab[0], geo_tab[1], geo_tab[2],
                        np.full(N + 1, cfg.v_d), np.zeros(N + 1)], axis=1)
        ref_now = geo_tab[:3, 0]
        xe = uni_errors(obs.pose, ref_now, self.v, cfg.v_d)
        # keep theta_e continuous with the prediction (the world heading is unwrapped)
        x0 = np.concatenate([xe, [self.s]])
        if plan is not None:
            x0[2] += 2 * math.pi * round((plan[0][0, 2] - x0[2]) / (2 * math.pi))
        if cfg.K_obs > 0:
            points, weights = self._obstacles(obs)
        else:
            points, weights = np.zeros((N + 1, 0, 2)), np.zeros((N + 1, 0))
        time_ref = None
        if cfg.mode == "combined":
            time_ref = self.time_reference(obs.t + N * dt)
            # unwrap the reference heading next to the predicted terminal heading
            if plan is not None:
                th_pred = plan[0][-1, 2] + self.table(plan[0][-1, 4] - plan[0][0, 4] + self.s)[2, 0]
            else:
                th_pred = geo_tab[2, -1] + x0[2]
            time_ref[2] += 2 * math.pi * round((th_pred - time_ref[2]) / (2 * math.pi))
        sol = self.nmpc.solve(x0, geo, points, weights, time_ref, cfg.v_d if tracking else None)
        a = sol.a
        # the prediction holds a over the step: apply the mean speed of the step
        v_cmd = float(np.clip(self.v + 0.5 * a * dt, -self.v_max, self.v_max))
        omega = float(np.clip(sol.omega, -self.omega_max, self.omega_max))
        self.v = float(np.clip(self.v + a * dt, -self.v_max, self.v_max))
        sdot = float(sol.sdot[0])
        self.vehicle.hold(obs.t, sdot)
        tref = self.time_reference(obs.t)
        tel = {
            "ref": [float(ref_now[0]), float(ref_now[1]), float(ref_now[2])],
            "ref_time": [float(tref[0]), float(tref[1]), float(tref[2])],
            "s": float(self.s),
            "sdot": sdot,
            "speed_error": sdot - cfg.v_d,
            "solver_ok": bool(sol.ok),
        }
        return StepResult(command=np.array([v_cmd, omega]), telemetry=tel)

