"""NMPC path following and trajectory tracking of the omnidirectional robot (Chapter 4, Sec. 4.2).

Two problems, each built once and solved every control period with :mod:`copath.mpc`:

- :class:`OmniPathFollowingNMPC`, (4.1)-(4.11): the error state in the path frame at
  the virtual vehicle Q, whose speed s-dot is a decision variable; stage cost (4.6),
  terminal penalty (4.7), terminal controller (4.8) with the gain conditions (4.10)
  checked at build time, and the terminal region (4.11) as a soft constraint.
- :class:`OmniTrackingNMPC`, (4.3), (4.12)-(4.13): tracking of a time-parameterised
  reference given as arrays over the horizon (x_r, y_r, theta_r, u_r, omega_r per step).

Decision variables are the three wheel rim speeds (plus s-dot for path following), so
the wheel limit |qdot_i| <= qdot_max of (3.2) is an exact box (docs/journal/measurements.md, what made the omni NMPC fast (W12)). The body
velocities are (u, v, omega) = M^-1 qdot. The dissertation's inputs (s-dot, alpha_e,
omega) with a fixed u_R are recovered as a special case: the path-frame velocity is
V = R(theta - theta_p) [u, v] = u_R [cos alpha_e, sin alpha_e]. Because |V| is now free,
a speed residual sqrt(w_speed) (|V|^2 - u_R^2) / (2 u_R) (~ |V| - u_R) keeps the speed at
u_R (docs/reference/controllers-notes.md, omni NMPC wheel speeds as inputs (N1)).

The builders ``build_path_following`` and ``build_trajectory_tracking`` wrap them as
controllers (contract: :mod:`copath.control`); the leader-following NMPC of
Sec. 5.3 imports the problem classes directly: a leader uses
:class:`OmniPathFollowingNMPC` (``solution.sdot`` is the predicted s-dot sequence), a
follower :class:`OmniTrackingNMPC` with its own reference arrays.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Callable, Sequence

import casadi as ca
import numpy as np

from copath.config import ConfigError, require
from copath.models import OmniModel
from copath.mpc import OCP, MPCSolver, SolveResult, SolverConfig, weighted
from copath.paths import Path, wrap_to_pi

from copath.control import VirtualVehicle, Observation, PeerMessage, RobotContext, StepResult

from .config import OmniNMPCFields, OmniPFConfig, OmniTTConfig, check_gain_conditions, gain_condition_margins

__all__ = [
    "OmniNMPCFields",
    "pf_errors",
    "pf_error_dynamics",
    "pf_virtual_inputs",
    "tt_errors",
    "tt_error_dynamics",
    "tt_virtual_inputs",
    "gain_condition_margins",
    "check_gain_conditions",
    "OmniPathFollowingNMPC",
    "OmniTrackingNMPC",
    "PFSolution",
    "TTSolution",
    "EightTrajectory",
    "PathTrajectory",
    "OmniPFConfig",
    "OmniTTConfig",
    "OmniPathFollower",
    "OmniPathFollowingController",
    "OmniTrackingController",
]

logger = logging.getLogger(__name__)


# -- error models (numpy or CasADi arguments) ----------------------------------------


def pf_errors(pose, ref) -> np.ndarray:
    """Path-frame errors (4.1) at the virtual vehicle: (x_e, y_e, psi).

    ``ref = (x_d, y_d, theta_p)`` is the path point and tangent at s; ``psi = theta -
    theta_p`` is the heading relative to the path tangent (it equals theta_e of (4.1)
    when the desired heading is the tangent).
    """
    x, y, th = (float(v) for v in pose)
    xd, yd, thp = (float(v) for v in ref[:3])
    c, sn = math.cos(thp), math.sin(thp)
    dx, dy = x - xd, y - yd
    return np.array([c * dx + sn * dy, -sn * dx + c * dy, wrap_to_pi(th - thp)])


def _path_frame_velocity(psi, u, v):
    """R(psi) [u, v]: body velocity expressed in the path frame."""
    c, s = ca.cos(psi), ca.sin(psi)
    return c * u - s * v, s * u + c * v


def pf_error_dynamics(xe, body, sdot, kappa):
    """Error dynamics (4.2)/(4.4) of (x_e, y_e, psi) under body velocities (u, v, omega).

    The translational part is R(psi)[u, v] = u_R [cos alpha_e, sin alpha_e].
    """
    Vx, Vy = _path_frame_velocity(xe[2], body[0], body[1])
    return ca.vertcat(
        kappa * sdot * xe[1] - sdot + Vx,
        -kappa * sdot * xe[0] + Vy,
        body[2] - kappa * sdot,
    )


def pf_virtual_inputs(xe, body, sdot, omega_d):
    """Virtual inputs u_e of (4.5) with u_3 = omega - omega_d (docs/reference/ambiguities.md, sign of the third virtual input (A1))."""
    Vx, Vy = _path_frame_velocity(xe[2], body[0], body[1])
    return ca.vertcat(-sdot + Vx, Vy, body[2] - omega_d)


def tt_errors(pose, ref) -> np.ndarray:
    """Robot-frame tracking errors of (4.3): R(-theta)(p_d - p), theta_d - theta (wrapped)."""
    x, y, th = (float(v) for v in pose)
    xr, yr, thr = (float(v) for v in ref[:3])
    c, s = math.cos(th), math.sin(th)
    dx, dy = xr - x, yr - y
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_to_pi(thr - th)])


def tt_error_dynamics(xe, body, u_d, omega_d):
    """Tracking error dynamics (4.3): the reference moves along its tangent (v_d = 0)."""
    return ca.vertcat(
        body[2] * xe[1] - body[0] + u_d * ca.cos(xe[2]),
        -body[2] * xe[0] - body[1] + u_d * ca.sin(xe[2]),
        omega_d - body[2],
    )


def tt_terminal_law(xe, u_d, omega_d, gains, cos=ca.cos, sin=ca.sin) -> tuple:
    """Body velocities (u, v, omega) the terminal law asks at tracking errors ``xe``
    (docs/reference/derivations.md, terminal-law commands of tracking (D15)): u_d cos(e_theta) + a e_x, u_d sin(e_theta) + b e_y,
    omega_d + g e_theta. Symbolic with CasADi's ``cos``/``sin``, numeric with ``math``'s."""
    a, b, g = gains
    return (u_d * cos(xe[2]) + a * xe[0], u_d * sin(xe[2]) + b * xe[1], omega_d + g * xe[2])


def tt_virtual_inputs(xe, body, u_d, omega_d):
    """Virtual inputs of (4.12)-(4.13), rows corrected per docs/reference/ambiguities.md, first rows of the tracking inputs (A3)."""
    return ca.vertcat(u_d * ca.cos(xe[2]) - body[0], u_d * ca.sin(xe[2]) - body[1], omega_d - body[2])


# -- path following ------------------------------------------------------------------


@dataclass
class PFSolution:
    """Result of one path-following solve."""

    ok: bool
    body: np.ndarray
    """(3,) body velocities (u, v, omega) to apply now."""
    wheels: np.ndarray
    """(3,) wheel rim speeds of ``body``."""
    sdot: np.ndarray
    """(N,) planned virtual-vehicle speeds (sdot[0] applies now)."""
    x: np.ndarray
    """(N+1, 4) predicted (x_e, y_e, psi, s)."""
    result: SolveResult


class OmniPathFollowingNMPC:
    """NMPC path following of one omni robot, Sec. 4.2 (build once, solve many).

    Parameters
    ----------
    path : Path
        Reference path (arc-length parameterised).
    model : OmniModel
        Wheel geometry and limit qdot_max.
    N : int
        Horizon steps N_p.
    dt : float
        Step delta [s].
    Q, R : (3,)
        Diagonals of the weights of (4.6) on (x_e, y_e, theta_e) and u_e.
    gains : (3,)
        Terminal-controller gains (alpha, beta, gamma) of (4.8).
    P : (3,)
        Terminal penalty diagonal; (4.7) is 1/2 x^T x, i.e. P = (1, 1, 1).
    speed_weight : float
        Weight of the speed residual (|V| - u_R)^2.
    sdot_max : float
        Upper bound of the virtual-vehicle speed [m/s].
    heading : str
        ``tangent`` (theta_d = theta_p, as in E4.2) or ``fixed`` (theta_d = heading_angle).
    heading_angle : float
        Desired heading for ``fixed`` [rad].
    terminal : bool
        Include the terminal penalty (4.7) and the soft terminal region (4.11).
    solver : SolverConfig
        Solver settings.
    """

    nx = 4
    nu = 4

    def __init__(
        self,
        path: Path,
        model: OmniModel,
        N: int,
        dt: float,
        Q: Sequence[float],
        R: Sequence[float],
        gains: Sequence[float],
        P: Sequence[float] = (1.0, 1.0, 1.0),
        speed_weight: float = 1.0,
        sdot_max: float = 2.0,
        heading: str = "tangent",
        heading_angle: float = 0.0,
        terminal: bool = True,
        solver: SolverConfig | None = None,
        name: str = "omni_pf",
    ) -> None:
        require(heading in ("tangent", "fixed"), "heading", heading, "allowed: tangent, fixed")
        self.path, self.model, self.N, self.dt = path, model, int(N), float(dt)
        self.table = path.table()
        self.Q, self.R = np.asarray(Q, float), np.asarray(R, float)
        self.gains = np.asarray(gains, float)
        self.P = np.asarray(P, float)
        self.heading, self.heading_angle = heading, float(heading_angle)
        self.M = model.M
        self.Minv = np.linalg.inv(self.M)
        if terminal:
            check_gain_conditions(self.Q, self.R, self.gains, self.P)
        Minv = ca.DM(self.Minv)
        M = ca.DM(self.M)
        tangent = heading == "tangent"
        qmax = model.qdot_max
        a, b, g = (float(k) for k in self.gains)
        sw = math.sqrt(speed_weight)

        # stage parameters p = (kappa_bar, dkappa_bar, s_bar, u_R, theta_off):
        # kappa(s) ~ kappa_bar + dkappa_bar (s - s_bar), the curvature linearised about
        # the warm-start prediction s_bar (docs/journal/measurements.md, what made the omni NMPC fast (W12));
        # theta_off = theta_p(s_bar) - theta_b for a fixed desired heading.
        def kappa(x, p):
            return p[0] + p[1] * (x[3] - p[2])

        def heading_error(x, p):
            if tangent:
                return x[2]
            return x[2] + p[4] + p[0] * (x[3] - p[2])

        def dynamics(x, u, p):
            body = ca.mtimes(Minv, u[:3])
            xe = pf_error_dynamics(x[:3], body, u[3], kappa(x, p))
            return ca.vertcat(xe, u[3])

        def stage(x, u, p):
            body = ca.mtimes(Minv, u[:3])
            k = kappa(x, p)
            omega_d = k * u[3] if tangent else 0.0
            ue = pf_virtual_inputs(x[:3], body, u[3], omega_d)
            Vx, Vy = _path_frame_velocity(x[2], body[0], body[1])
            speed = (Vx * Vx + Vy * Vy - p[3] * p[3]) / (2 * ca.fmax(p[3], 0.05))
            e = ca.vertcat(x[0], x[1], heading_error(x, p))
            return ca.vertcat(weighted(e, self.Q), weighted(ue, self.R), sw * speed)

        def terminal_cost(x, p):
            e = ca.vertcat(x[0], x[1], heading_error(x, p))
            return weighted(e, 0.5 * self.P)  # (4.7): V = 1/2 x^T P x

        def terminal_region(x, u, p):
            # (4.11) with J evaluated at the heading relative to the path frame
            # (docs/reference/ambiguities.md, angle in the terminal wheel map (A2)) and s-dot_T = the last planned s-dot.
            sdT = u[3]
            k = kappa(x, p)
            omega_dT = k * sdT if tangent else 0.0
            Vx, Vy = sdT - a * x[0], -b * x[1]
            om = omega_dT - g * heading_error(x, p)
            c, s = ca.cos(x[2]), ca.sin(x[2])
            body = ca.vertcat(c * Vx + s * Vy, -s * Vx + c * Vy, om)
            return ca.mtimes(M, body)

        ocp = OCP(
            nx=4, nu=4, N=self.N, dt=self.dt, dynamics=dynamics, stage_residual=stage,
            terminal_residual=terminal_cost if terminal else None,
            n_p=5, n_pt=5 if terminal else 0,
            u_lb=[-qmax, -qmax, -qmax, 0.0], u_ub=[qmax, qmax, qmax, float(sdot_max)],
            soft_terminal=terminal_region if terminal else None,
            hT_lb=[-qmax] * 3, hT_ub=[qmax] * 3, name=name,
        )
        self.terminal = terminal
        self.mpc = MPCSolver(ocp, solver or SolverConfig())

    def _params(self, s_bar: np.ndarray, u_R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stage parameters (N+1, 5) at s_bar and the path point (x, y, theta) at s_bar[0]."""
        geo = self.table(s_bar)
        prm = np.empty((len(s_bar), 5))
        prm[:, 0] = geo[3]
        prm[:, 1] = geo[4]
        prm[:, 2] = s_bar
        prm[:, 3] = u_R
        if self.heading == "fixed":
            d = geo[2] - self.heading_angle
            prm[:, 4] = np.arctan2(np.sin(d), np.cos(d))
        else:
            prm[:, 4] = 0.0
        return prm, geo[:3, 0]

    def reference(self, s: float) -> np.ndarray:
        """(x_d, y_d, theta_d) at s: path point and desired heading."""
        x, y, th, _ = self.table.pose(s)
        return np.array([x, y, th if self.heading == "tangent" else self.heading_angle])

    def solve(self, pose, s: float, u_R: float | Sequence[float]) -> PFSolution:
        """Solve from the robot pose with the virtual vehicle at ``s``.

        ``u_R`` is the desired translational speed [m/s], a scalar or (N,) per step.
        """
        N = self.N
        plan = self.mpc.shifted_plan()
        guess = None
        uR_arr = np.empty(N + 1)
        uR_arr[:N] = u_R
        uR_arr[N] = uR_arr[N - 1]
        if plan is None:
            s_bar = s + float(uR_arr[0]) * self.dt * np.arange(N + 1)
        else:
            s_bar = plan[0][:, 3] - plan[0][0, 3] + s  # linearisation points consistent with x0
        prm, geo0 = self._params(s_bar, uR_arr)
        x0 = np.empty(4)
        x0[:3] = pf_errors(pose, geo0)
        x0[3] = s
        if plan is None:
            guess = self._cold_guess(x0, float(uR_arr[0]))
        res = self.mpc.solve(x0, prm[:N], prm[N] if self.terminal else None, guess=guess)
        q = res.u0[:3]
        body = self.Minv @ q
        return PFSolution(res.ok, body, q, res.u[:, 3].copy(), res.x, res)

    def _cold_guess(self, x0: np.ndarray, u_R: float) -> tuple[np.ndarray, np.ndarray]:
        """Roll out 'move along the tangent at u_R' as the first warm start."""
        N, dt = self.N, self.dt
        X = np.tile(x0, (N + 1, 1))
        X[:, 3] = x0[3] + u_R * dt * np.arange(N + 1)
        k = self.table(X[:-1, 3])[3]
        psi = x0[2]
        U = np.zeros((N, 4))
        for i in range(N):
            body = np.array([u_R * math.cos(psi), -u_R * math.sin(psi), k[i] * u_R])
            U[i, :3] = self.model.saturate_wheels(self.M @ body)
            U[i, 3] = u_R
        return X, U


# -- trajectory tracking -------------------------------------------------------------


@dataclass
class TTSolution:
    """Result of one trajectory-tracking solve."""

    ok: bool
    body: np.ndarray
    """(3,) body velocities (u, v, omega) to apply now."""
    wheels: np.ndarray
    x: np.ndarray
    """(N+1, 3) predicted world poses."""
    result: SolveResult


class OmniTrackingNMPC:
    """NMPC trajectory tracking of one omni robot, (4.3), (4.12)-(4.13).

    The prediction runs on the world-frame kinematics (3.1) and evaluates the robot-frame
    errors of (4.3) against the reference *arrays* at every step, so any reference whose
    samples are given over the horizon can be tracked (the followers of Sec. 5.3 build
    theirs from the leader's broadcast). For a reference that moves with (u_r, omega_r)
    along its tangent this is the error model (4.3) exactly.

    ``solve(pose, ref)`` takes ``ref`` of shape (N+1, 5): rows (x_r, y_r, theta_r, u_r,
    omega_r) at t, t + delta, ..., t + N delta.

    ``contractive_terminal``: from a state outside the terminal region (the terminal law
    (4.8) of (4.12) would ask a wheel for more than qdot_max, the bound of (4.11); terminal-law commands of tracking (D15) of
    docs/reference/derivations.md), the terminal state may ask the terminal law for no more than
    the current state does, and for qdot_max once it is inside. A robot far from its
    reference cannot reach the region within the horizon (Sec. 2.2.2: the domain of
    attraction is limited to the states that can be steered into it in T_p; a
    contractive constraint in the sense of Kothare and Morari [128] is kept); with the fixed
    bound the soft terminal constraint's slack carries the slack weight as its
    multiplier, the Gauss-Newton Hessian leaves that constraint's curvature out, and the
    SQP cycles without converging (docs/reference/faults.md, "A restarted leader, in one process").
    Inside the region (every step of an undisturbed run) nothing changes.
    """

    nx = 3
    nu = 3

    def __init__(
        self,
        model: OmniModel,
        N: int,
        dt: float,
        Q: Sequence[float],
        R: Sequence[float],
        gains: Sequence[float],
        P: Sequence[float] = (1.0, 1.0, 1.0),
        terminal: bool = True,
        solver: SolverConfig | None = None,
        name: str = "omni_tt",
        contractive_terminal: bool = False,
    ) -> None:
        self.model, self.N, self.dt = model, int(N), float(dt)
        self.Q, self.R = np.asarray(Q, float), np.asarray(R, float)
        self.gains, self.P = np.asarray(gains, float), np.asarray(P, float)
        self.M = model.M
        self.Minv = np.linalg.inv(self.M)
        if terminal:
            check_gain_conditions(self.Q, self.R, self.gains, self.P)
        Minv, M = ca.DM(self.Minv), ca.DM(self.M)
        qmax = model.qdot_max
        a, b, g = (float(k) for k in self.gains)

        def errors(x, p):
            c, s = ca.cos(x[2]), ca.sin(x[2])
            dx, dy = p[0] - x[0], p[1] - x[1]
            return ca.vertcat(c * dx + s * dy, -s * dx + c * dy, p[2] - x[2])

        def dynamics(x, u, p):
            body = ca.mtimes(Minv, u)
            c, s = ca.cos(x[2]), ca.sin(x[2])
            return ca.vertcat(c * body[0] - s * body[1], s * body[0] + c * body[1], body[2])

        def stage(x, u, p):
            xe = errors(x, p)
            ue = tt_virtual_inputs(xe, ca.mtimes(Minv, u), p[3], p[4])
            return ca.vertcat(weighted(xe, self.Q), weighted(ue, self.R))

        def terminal_cost(x, p):
            return weighted(errors(x, p), 0.5 * self.P)

        def terminal_region(x, u, p):
            # terminal-law commands (docs/reference/derivations.md, terminal-law commands of tracking (D15)) must respect the wheel limit
            return ca.mtimes(M, ca.vertcat(*tt_terminal_law(errors(x, p), p[3], p[4], (a, b, g))))

        ocp = OCP(
            nx=3, nu=3, N=self.N, dt=self.dt, dynamics=dynamics, stage_residual=stage,
            terminal_residual=terminal_cost if terminal else None,
            n_p=5, n_pt=5 if terminal else 0,
            u_lb=[-qmax] * 3, u_ub=[qmax] * 3,
            soft_terminal=terminal_region if terminal else None,
            hT_lb=[-qmax] * 3, hT_ub=[qmax] * 3, name=name,
        )
        self.terminal = terminal
        self.mpc = MPCSolver(ocp, solver or SolverConfig())
        self.contractive = terminal and contractive_terminal

    def terminal_bound(self, pose, ref_row) -> float | None:
        """The bound of the terminal law's wheel speeds for a solve from ``pose`` against
        ``ref_row`` (x_r, y_r, theta_r, u_r, omega_r, heading next to the pose's): the
        largest wheel speed the terminal law (4.8) asks at the current state, or None when
        that is within qdot_max of (4.11) (or the bound is not contractive)."""
        if not self.contractive:
            return None
        body = tt_terminal_law(tt_errors(pose, ref_row), float(ref_row[3]), float(ref_row[4]), self.gains,
                               math.cos, math.sin)  # numpy, as the OCP's terminal_region (36 -> 9 us)
        need = float(np.max(np.abs(self.M @ body)))
        return need if need > self.model.qdot_max else None

    def solve(self, pose, ref) -> TTSolution:
        """Solve from ``pose`` (3,) against reference samples ``ref`` (N+1, 5)."""
        N = self.N
        ref = np.array(ref, dtype=float).reshape(N + 1, 5)
        pose = np.asarray(pose, float).reshape(3)
        # unwrap the reference headings next to the robot heading so theta_r - theta
        # is the wrapped error at k = 0 and stays continuous along the horizon
        th = ref[:, 2]
        if np.any(np.abs(np.diff(th)) > math.pi):
            th[:] = np.unwrap(th)
        th += 2 * math.pi * round((pose[2] - th[0]) / (2 * math.pi))
        plan = self.mpc.shifted_plan()
        x0 = pose.copy()
        if plan is not None:  # keep the robot heading continuous with the plan
            x0[2] += 2 * math.pi * round((plan[0][0, 2] - x0[2]) / (2 * math.pi))
            ref[:, 2] += x0[2] - pose[2]
        guess = None
        if plan is None:
            guess = self._cold_guess(x0, ref)
        bound = self.terminal_bound(x0, ref[0])
        hT = {} if bound is None else {"hT_lb": [-bound] * 3, "hT_ub": [bound] * 3}
        res = self.mpc.solve(x0, ref[:N], ref[N] if self.terminal else None, guess=guess, **hT)
        q = res.u0
        return TTSolution(res.ok, self.Minv @ q, q, res.x, res)

    def _cold_guess(self, x0: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        N = self.N
        X = np.vstack([x0, ref[1:, :3]])
        U = np.zeros((N, 3))
        for i in range(N):
            xe = tt_errors(X[i], ref[i])
            body = np.array([ref[i, 3] * math.cos(xe[2]), ref[i, 3] * math.sin(xe[2]), ref[i, 4]])
            U[i] = self.model.saturate_wheels(self.M @ body)
        return X, U


# -- references ---------------------------------------------------------------------


@dataclass(frozen=True)
class EightTrajectory:
    """Time-parameterised eight curve (4.14) with phi = t: x = ax sin(w t), y = ay sin(2 w t).

    ``sample(t)`` returns (n, 5) rows (x, y, theta, u, omega): theta = atan2(ydot, xdot),
    u = |pdot| (0.49-1.20 m/s for the published values), omega = (xdot yddot - ydot
    xddot) / |pdot|^2 (docs/reference/derivations.md, reference of the eight curve (D14)).
    """

    ax: float = 1.8
    ay: float = 1.2
    rate: float = 0.4
    t0: float = 0.0

    def sample(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float)) - self.t0
        w = self.rate
        x, y = self.ax * np.sin(w * t), self.ay * np.sin(2 * w * t)
        xd, yd = self.ax * w * np.cos(w * t), 2 * self.ay * w * np.cos(2 * w * t)
        xdd, ydd = -self.ax * w * w * np.sin(w * t), -4 * self.ay * w * w * np.sin(2 * w * t)
        sp2 = xd * xd + yd * yd
        th = np.arctan2(yd, xd)
        if th.size > 1 and np.any(np.abs(np.diff(th)) > math.pi):
            th = np.unwrap(th)
        return np.stack([x, y, th, np.sqrt(sp2), (xd * ydd - yd * xdd) / sp2], axis=1)


@dataclass(frozen=True)
class PathTrajectory:
    """A path traversed at constant speed: s(t) = s0 + speed (t - t0)."""

    path: Path
    speed: float
    s0: float = 0.0
    t0: float = 0.0

    def sample(self, t) -> np.ndarray:
        s = self.s0 + self.speed * (np.atleast_1d(np.asarray(t, float)) - self.t0)
        x, y, th, k = self.path.frame(s)
        return np.stack([x, y, th, np.full_like(s, self.speed), k * self.speed], axis=1)


# -- controllers -------------------------------------------------------------------


class OmniPathFollower:
    """Path following of one omni robot, Sec. 4.2: the NMPC (4.1)-(4.11) and its virtual
    vehicle, advanced at the actual step times (:class:`copath.control.VirtualVehicle`).

    Shared by the Sec. 4.2 controller, the Sec. 5.3 leader (5.6)-(5.7) and the leader of
    the heterogeneous team (Sec. 5.5.5).

    Parameters
    ----------
    ctx : RobotContext
        The robot (an omni robot with a path).
    cfg : OmniPFConfig
        NMPC settings; ``cfg.s0`` places the virtual vehicle (None: at the first step).
    kind : str
        Controller type named in error messages.
    name : str, optional
        Suffix of the solver's name (default ``kind``).
    start : callable (path, p) -> s, optional
        Placement of the virtual vehicle at the first step when ``cfg.s0`` is None
        (default: :meth:`copath.paths.Path.project` of the robot's position).
    """

    def __init__(self, ctx: RobotContext, cfg: OmniPFConfig, kind: str, name: str | None = None,
                 start: Callable[[Path, np.ndarray], float] | None = None) -> None:
        if not isinstance(ctx.model, OmniModel):
            raise ConfigError(f"robots.{ctx.name}.model = {ctx.model.kind!r} is not allowed; {kind} needs omni")
        if cfg.terminal:
            check_gain_conditions(cfg.Q, cfg.R, cfg.gains, where=f"robots.{ctx.name}.controller")
        self.path = ctx.own_path
        self.nmpc = OmniPathFollowingNMPC(
            self.path, ctx.model, cfg.horizon, ctx.dt, cfg.Q, cfg.R, cfg.gains,
            speed_weight=cfg.speed_weight, sdot_max=cfg.sdot_max, heading=cfg.heading,
            heading_angle=cfg.heading_angle, terminal=cfg.terminal, solver=cfg.solver_config(),
            name=f"{ctx.name}_{name or kind}",
        )
        self.vehicle = VirtualVehicle(cfg.s0)
        self._start = start

    @property
    def s(self) -> float | None:
        """The virtual vehicle's path coordinate [m]."""
        return self.vehicle.s

    def solve(self, obs: Observation, u_R: float | Sequence[float]) -> PFSolution:
        """Advance the virtual vehicle to obs.t and solve for the desired speed u_R."""
        if not self.vehicle.started:
            p = obs.pose[:2]
            self.vehicle.start(self._start(self.path, p) if self._start else self.path.project(p))
        s = self.vehicle.advance(obs.t)
        sol = self.nmpc.solve(obs.pose, s, u_R)
        self.vehicle.hold(obs.t, float(sol.sdot[0]))
        return sol


class OmniPathFollowingController:
    """Sec. 4.2 path following as a controller (contract: ``copath.control``)."""

    def __init__(self, ctx: RobotContext, cfg: OmniPFConfig) -> None:
        self.cfg = cfg
        self.follower = OmniPathFollower(ctx, cfg, "omni_nmpc_pf", name="omni_pf")
        self.path = self.follower.path
        self.nmpc = self.follower.nmpc

    @property
    def s(self) -> float | None:
        return self.follower.s

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        sol = self.follower.solve(obs, self.cfg.u_R)
        sdot = float(sol.sdot[0])
        ref = self.nmpc.reference(self.s)
        tel = {
            "ref": [float(ref[0]), float(ref[1]), float(ref[2])],
            "s": float(self.s),
            "sdot": sdot,
            "speed_error": sdot - self.cfg.u_R,
            "solver_ok": bool(sol.ok),
        }
        return StepResult(command=sol.body, telemetry=tel)


class OmniTrackingController:
    """Sec. 4.2 trajectory tracking as a controller."""

    def __init__(self, ctx: RobotContext, cfg: OmniTTConfig) -> None:
        if not isinstance(ctx.model, OmniModel):
            raise ConfigError(f"robots.{ctx.name}.model = {ctx.model.kind!r} is not allowed; omni_nmpc_tt needs omni")
        self.cfg = cfg
        where = f"robots.{ctx.name}.controller"
        if cfg.terminal:
            check_gain_conditions(cfg.Q, cfg.R, cfg.gains, where=where)
        if cfg.trajectory == "eight":
            self.reference = EightTrajectory(cfg.ax, cfg.ay, cfg.rate, cfg.t0)
        else:
            self.reference = PathTrajectory(ctx.own_path, cfg.speed, cfg.s0, cfg.t0)
        self.dt = ctx.dt
        self.nmpc = OmniTrackingNMPC(ctx.model, cfg.horizon, ctx.dt, cfg.Q, cfg.R, cfg.gains,
                                     terminal=cfg.terminal, solver=cfg.solver_config(),
                                     name=f"{ctx.name}_omni_tt")

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        ref = self.reference.sample(obs.t + self.dt * np.arange(self.cfg.horizon + 1))
        sol = self.nmpc.solve(obs.pose, ref)
        tel = {
            "ref": [float(ref[0, 0]), float(ref[0, 1]), float(wrap_to_pi(ref[0, 2]))],
            "solver_ok": bool(sol.ok),
        }
        return StepResult(command=sol.body, telemetry=tel)

