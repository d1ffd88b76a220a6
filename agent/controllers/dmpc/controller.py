"""Distributed MPC for coordinated path following of omni robots (Sec. 5.4, Algorithm 5.1).

Each robot i solves its own problem (5.18) for the error model (5.16) in the Frenet
frame of its reference point (5.10) (its path at s_i, shifted by the constant lateral
offset q_i), with the reference velocities (5.11)-(5.13). The dynamics are decoupled;
the robots are coupled only through the stage cost (5.17)

    L_i = x_e^T Q x_e + u_e^T R u_e + sum_{j in N_i} W (psi_i - psi_hat_j + p_ij)^2,

where psi_hat_j is the *assumed* trajectory neighbour j sent after its last solve,
time-indexed by its stamp and interpolated onto robot i's grid (extrapolated linearly
past its end). Progress is compared in base-path coordinates psi = P_B / P_i s (5.29)
so robots on different paths coordinate by morphing (E5.3); on a shared path the scale
is one (E5.2). The compatibility constraint |s_i^p - s_hat_i| <= delta^2 mu keeps the
new plan near what the neighbours were told (applied from k >= 1); terminal
ingredients (5.19)-(5.22) are soft: the penalty V = 1/2 x^T P x plus a penalty on the
terminal coordination error (docs/reference/ambiguities.md, the DMPC terminal region (A14)).

After each solve the robot builds its next assumed trajectory (Algorithm 5.1 step 2:
the optimal s* shifted, followed by the terminal controller of (5.21) rolled out over
one period) and sends it to its graph neighbours as ``assumed_traj``.

Error state and inputs (5.14)-(5.16), with phi = theta_t - theta_r (docs/reference/ambiguities.md, the angle phi (A12))::

    x = [x_e, y_e, phi, theta_e, eta, s],   w = [sdot, u2, u3, u4]
    x_e' = y_e kappa sdot + u1,    u1 = -sdot (1 - kappa q) + (eta + u_r) cos(phi)
    y_e' = -x_e kappa sdot + (eta + u_r) sin(phi)
    phi' = u2,  theta_e' = u3 = omega - kappa sdot,  eta' = u4,  s' = sdot

(kappa l-dot = kappa_p sdot by (5.12)-(5.13)). The motion direction theta_t and speed
u_R = eta + u_r of the omni robot are states of the model, kept by the controller
between updates; the body command is u = u_R cos(theta_t - theta), v = u_R sin(theta_t - theta).
The path curvature along the horizon is a stage parameter evaluated on the previous
plan (linearised curvature, docs/journal/measurements.md, what made the omni NMPC fast (W12)).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import casadi as ca
import numpy as np

from copath.config import ConfigError
from copath.morphing import Morphing, morphing
from copath.mpc import OCP, MPCSolver, SolverConfig, weighted
from copath.paths import Path, wrap_to_pi

from copath.control import LatestMessages, Observation, Outgoing, PeerMessage, RobotContext, StepResult

from .config import DMPCConfig
from .payloads import MESSAGE_KIND

__all__ = [
    "DMPCConfig",
    "AssumedTrajectory",
    "assumed_trajectory",
    "terminal_rollout",
    "DMPCController",
]

logger = logging.getLogger(__name__)


NX, NU = 6, 4
IX, IY, IPHI, ITH, IETA, IS = range(NX)


# -- assumed trajectories ----------------------------------------------------------------


@dataclass(frozen=True)
class AssumedTrajectory:
    """An assumed trajectory s_hat on the grid t0 + k dt (Algorithm 5.1), in some coordinate.

    Evaluated by linear interpolation inside the grid and linear extrapolation with the
    end slopes outside it, so late or asynchronous trajectories still give a value on
    any receiver's grid.
    """

    t0: float
    dt: float
    values: np.ndarray

    def __post_init__(self) -> None:
        if self.dt <= 0 or len(self.values) < 2:
            raise ValueError(f"assumed trajectory needs dt > 0 and >= 2 points, got dt={self.dt}, n={len(self.values)}")

    @property
    def t_end(self) -> float:
        return self.t0 + self.dt * (len(self.values) - 1)

    def at(self, t) -> np.ndarray:
        """Values at time(s) t (arrays welcome)."""
        t = np.asarray(t, dtype=float)
        v = np.asarray(self.values, dtype=float)
        x = (t - self.t0) / self.dt
        n = len(v) - 1
        k = np.clip(np.floor(x).astype(int), 0, n - 1)
        return v[k] + (v[k + 1] - v[k]) * (x - k)

    def scaled(self, factor: float) -> "AssumedTrajectory":
        return AssumedTrajectory(self.t0, self.dt, np.asarray(self.values, dtype=float) * factor)


def _assumed_from(payload: Mapping[str, Any]) -> AssumedTrajectory:
    """The assumed trajectory of an ``assumed_traj`` payload in base-path coordinates
    psi (5.29) (raises KeyError, TypeError or ValueError on a bad payload)."""
    traj = AssumedTrajectory(float(payload["t0"]), float(payload["dt"]), np.asarray(payload["s_hat"], dtype=float))
    return traj.scaled(float(payload.get("psi_scale", 1.0)))


def terminal_rollout(x_N, kappa: float, q: float, u_o: float, k_terminal, duration: float,
                     substeps: int = 4) -> np.ndarray:
    """s under the decoupled terminal controllers of (5.21), rolled out from x_N for ``duration``.

    The path curvature is held at its value at x_N (the tail lasts one update period).

    u1 = -k1 x_e, u2 = -k2 phi, u3 = -k3 theta_e, u4 = -k4 eta; u1 gives the virtual
    vehicle's speed sdot = ((eta + u_r) cos phi + k1 x_e) / (1 - kappa q). Forward Euler
    with ``substeps`` steps; returns the s values at the end of each substep.
    """
    x = np.asarray(x_N, dtype=float).copy()
    k1, k2, k3, k4 = k_terminal
    h = duration / substeps
    out = []
    kap = float(kappa)
    for _ in range(substeps):
        one = 1.0 - kap * q
        u_r = u_o * one
        speed = x[IETA] + u_r
        sdot = max(0.0, (speed * math.cos(x[IPHI]) + k1 * x[IX]) / one)
        dx = np.array([
            x[IY] * kap * sdot - k1 * x[IX],
            -x[IX] * kap * sdot + speed * math.sin(x[IPHI]),
            -k2 * x[IPHI],
            -k3 * x[ITH],
            -k4 * x[IETA],
            sdot,
        ])
        x = x + h * dx
        out.append(x[IS])
    return np.asarray(out)


def assumed_trajectory(t_k: float, dt: float, s_plan, tail) -> AssumedTrajectory:
    """Assumed trajectory s_hat(.; t_{k+1}) of Algorithm 5.1 step 2, stamped on the grid of t_k.

    ``s_plan`` is the optimal s*(t_k + j dt; t_k), j = 0..N, and ``tail`` the terminal
    controller's value at t_k + (N+1) dt. The grid keeps s*(t_k) so that receivers that
    solve slightly before t_{k+1} still interpolate.
    """
    return AssumedTrajectory(float(t_k), float(dt), np.concatenate([np.asarray(s_plan, dtype=float), [float(tail)]]))


# -- the optimal control problem ---------------------------------------------------------


def _ocp(cfg: DMPCConfig, n_nbr: int, dt: float, q: float, scale: float, M: np.ndarray, qdot_max: float) -> OCP:
    """OCP (5.18) for one robot with ``n_nbr`` neighbours.

    Stage parameters p_k: [kappa, u_o, s_hat_i, compat_on, wheel_on, (target_j, on_j) * n_nbr]
    with target_j = psi_hat_j - p_ij, the psi_i the neighbour j asks for.
    """
    Q, R, P = cfg.Q, cfg.R, cfg.P
    sqW, sqWT = math.sqrt(cfg.W), math.sqrt(cfg.W_terminal)

    def _speeds(x, u, p):
        kap, u_o = p[0], p[1]
        u_r = u_o * (1 - kap * q)
        return kap, u_r, x[IETA] + u_r

    def f(x, u, p):
        kap, u_r, speed = _speeds(x, u, p)
        sdot = u[0]
        u1 = -sdot * (1 - kap * q) + speed * ca.cos(x[IPHI])
        return ca.vertcat(
            x[IY] * kap * sdot + u1,
            -x[IX] * kap * sdot + speed * ca.sin(x[IPHI]),
            u[1],
            u[2],
            u[3],
            sdot,
        )

    def stage(x, u, p):
        kap, u_r, speed = _speeds(x, u, p)
        u1 = -u[0] * (1 - kap * q) + speed * ca.cos(x[IPHI])
        ue = ca.vertcat(u1, u[1], u[2], u[3])
        res = [weighted(x[:5], Q), weighted(ue, R)]
        psi = scale * x[IS]
        for j in range(n_nbr):
            target, on = p[5 + 2 * j], p[6 + 2 * j]
            res.append(sqW * on * (psi - target))  # (5.17) coupling
        return ca.vertcat(*res)

    def terminal(x, p):
        res = [weighted(x[:5], [0.5 * v for v in P])]  # (5.19)
        psi = scale * x[IS]
        for j in range(n_nbr):
            target, on = p[5 + 2 * j], p[6 + 2 * j]
            res.append(sqWT * on * (psi - target))  # soft terminal coordination (docs/reference/ambiguities.md, the DMPC terminal region (A14))
        return ca.vertcat(*res)

    def constraints(x, u, p):
        kap, u_r, speed = _speeds(x, u, p)
        s_hat, compat_on, wheel_on = p[2], p[3], p[4]
        rel = x[IPHI] - x[ITH]  # theta_t - theta = phi - theta_e
        omega = u[2] + kap * u[0]
        body = ca.vertcat(speed * ca.cos(rel), speed * ca.sin(rel), omega)
        wheels = ca.mtimes(ca.DM(M), body)
        return ca.vertcat(compat_on * (x[IS] - s_hat), wheel_on * wheels)

    bound = dt**2 * cfg.mu
    return OCP(
        nx=NX,
        nu=NU,
        N=cfg.horizon,
        dt=dt,
        dynamics=f,
        stage_residual=stage,
        terminal_residual=terminal,
        n_p=5 + 2 * n_nbr,
        u_lb=[0.0, -cfg.phi_rate_max, -cfg.theta_rate_max, -cfg.accel_max],
        u_ub=[cfg.sdot_max, cfg.phi_rate_max, cfg.theta_rate_max, cfg.accel_max],
        stage_constraint=constraints,
        h_lb=[-bound] + [-qdot_max] * 3,
        h_ub=[bound] + [qdot_max] * 3,
        substeps=cfg.substeps,
        stop_u=[0.0, 0.0, 0.0, 0.0],
        name="dmpc",
    )


# -- the controller ----------------------------------------------------------------------


def _capped(solver: SolverConfig, cap_s: float) -> SolverConfig:
    """``solver`` with its solves capped at ``cap_s`` of wall time (0: none), in a realtime run
    only (docs/reference/controllers.md, "Solve time cap")."""
    return dataclasses.replace(solver, max_solve_s=cap_s) if cap_s > 0 else solver


class DMPCController:
    """One robot of the Sec. 5.4 team (Algorithm 5.1)."""

    def __init__(self, ctx: RobotContext, cfg: DMPCConfig) -> None:
        if ctx.model.kind != "omni":
            raise ConfigError(f"robots.{ctx.name}.model = {ctx.model.kind!r} is not allowed; dmpc needs an omni robot")
        self.ctx = ctx
        self.cfg = cfg
        self.path: Path = ctx.own_path
        if cfg.base_path is not None and cfg.base_path not in ctx.paths:
            raise ConfigError(f"robots.{ctx.name}.controller.base_path = {cfg.base_path!r} is not allowed; "
                              f"choose one of {sorted(ctx.paths)}")
        base = ctx.paths[cfg.base_path] if cfg.base_path else self.path
        self.morph: Morphing = morphing(self.path, base)
        self.u_o = self.morph.desired_speed(cfg.base_speed)  # (5.28)
        self.psi_period = base.length if base.closed else 0.0
        self.q = cfg.q
        s = np.linspace(0.0, self.path.length, 2000)
        k_max = float(np.max(np.abs(self.path.kappa(s))))
        if k_max * abs(self.q) >= 0.95:
            raise ConfigError(f"robots.{ctx.name}.controller.q = {self.q!r} is not allowed; the offset curve has a "
                              f"cusp (|q| must stay below 1/kappa_max = {1 / k_max:.3f} m)")
        self.nbrs = tuple(ctx.neighbours)
        self.psi_d = cfg.offset(ctx.name)
        self.dt = ctx.dt
        self.table = self.path.table()
        self.mpc = self._solver(len(self.nbrs))
        self._mpcs = {len(self.nbrs): self.mpc}
        """The solver for each number of coupling slots built so far (:meth:`_slots`)."""
        self.slots = self.nbrs
        """The robots of this step's coupling terms: the neighbours, then any stand-ins."""
        self.s: float | None = cfg.s0
        self.theta_t: float | None = None
        self.u_R = 0.0
        # every sender the runtime passes on: the neighbours, and the stand-ins for a lost one
        self.inbox = LatestMessages(kinds=(MESSAGE_KIND,), decode=self._decode)
        self.own_assumed: AssumedTrajectory | None = None
        self._last: tuple[float, np.ndarray] | None = None  # (t_k, predicted X) of the last solve
        self.k = 0

    # -- helpers ---------------------------------------------------------------------
    def _solver(self, n_nbr: int) -> MPCSolver:
        cfg, ctx = self.cfg, self.ctx
        return MPCSolver(_ocp(cfg, n_nbr, self.dt, self.q, self.morph.scale, ctx.model.M, ctx.model.qdot_max),
                         _capped(cfg.solver_config(), cfg.max_solve_periods * ctx.dt if ctx.realtime else 0.0))

    def _slots(self, t: float) -> tuple[str, ...]:
        """The robots coupled at this step: the neighbours, and every other robot with a fresh
        assumed trajectory in the inbox, which the runtime passes on only from a stand-in for a
        lost neighbour (docs/reference/faults.md, "Stand-ins for a lost neighbour"). (5.18) is
        built for a number of coupling terms: the problem for more is built when first needed
        (0.2 s for E5.2's robots) and warm-started from the last solve."""
        extra = sorted(g.sender for g in self.inbox.of_kind(MESSAGE_KIND).values()
                       if g.sender not in self.nbrs and t - g.stamp <= self.cfg.stale_after_s)
        slots = self.nbrs + tuple(extra)
        if len(slots) != len(self.slots):
            mpc = self._mpcs.get(len(slots))
            if mpc is None:
                mpc = self._mpcs[len(slots)] = self._solver(len(slots))
            mpc.take_warm_start(self.mpc)
            self.mpc = mpc
        self.slots = slots
        return slots

    def _u_r(self, kap) -> Any:
        return self.u_o * (1.0 - kap * self.q)  # (5.11)

    def _decode(self, m: PeerMessage) -> AssumedTrajectory:
        """A neighbour's assumed trajectory, decoded once when it arrives (a bad one is
        logged and ignored by the inbox)."""
        try:
            return _assumed_from(m.payload)
        except (KeyError, TypeError, ValueError) as exc:
            logger.warning("%s: bad %s from %s: %s", self.ctx.name, MESSAGE_KIND, m.sender, exc)
            raise

    def _receive(self, inbox: Sequence[PeerMessage], t: float, lost: frozenset[str] = frozenset()) -> None:
        # a lost neighbour's kept trajectory is forgotten at once, so its coupling term drops (docs/reference/faults.md)
        self.inbox.update(inbox, t, lost)

    @property
    def neighbour_traj(self) -> dict[str, tuple[float, AssumedTrajectory]]:
        """Neighbour -> (stamp, assumed trajectory) of its newest usable message."""
        return {g.sender: (g.stamp, g.value) for g in self.inbox.of_kind(MESSAGE_KIND).values()}

    def _wrap_near(self, value: np.ndarray, ref: np.ndarray) -> np.ndarray:
        if self.psi_period <= 0:
            return value
        return value + self.psi_period * np.round((ref - value) / self.psi_period)

    def _advance(self, elapsed: float, X: np.ndarray) -> None:
        """Move the model states to the actual time of the next update (asynchronous
        updates, Sec. 5.3.3/5.4.3): s along the plan's piecewise-constant s-dot for the
        elapsed time (extrapolated with the last s-dot), so s stays on the assumed
        trajectory the neighbours were told; the motion direction and speed to their
        planned values after min(elapsed, delta) (the command is held after that)."""
        a = max(0.0, elapsed) / self.dt
        grid = np.arange(len(X), dtype=float)
        s_plan = X[:, IS]
        last_rate = s_plan[-1] - s_plan[-2]
        self.s = float(np.interp(a, grid, s_plan) if a <= grid[-1] else s_plan[-1] + last_rate * (a - grid[-1]))
        b = min(a, 1.0)
        x_b = X[0] + (X[1] - X[0]) * b
        geo = self.table(x_b[IS])
        self.theta_t = float(geo[2, 0] + x_b[IPHI])
        self.u_R = float(x_b[IETA] + self._u_r(float(geo[3, 0])))

    # -- step ------------------------------------------------------------------------
    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        cfg, N, dt = self.cfg, self.cfg.horizon, self.dt
        self._receive(inbox, obs.t, obs.lost)
        pose = np.asarray(obs.pose, dtype=float)
        if self.s is None:
            self.s = self.path.project(pose[:2])
        if self.theta_t is None:
            self.theta_t = float(self.table(self.s)[2, 0])
        if self._last is not None:
            self._advance(obs.t - self._last[0], self._last[1])
        s = self.s
        # guess of s along the horizon: previous plan shifted, else nominal progress
        prev = self.mpc.shifted_plan()
        s_guess = prev[0][:, IS] - prev[0][0, IS] + s if prev is not None else s + self.u_o * dt * np.arange(N + 1)
        # one vectorised path evaluation: the reference now and the curvature along the horizon
        px, py, pth, pk, _ = self.table(np.concatenate([[s], s_guess[:N]]))
        th_r, kap0, kap = float(pth[0]), float(pk[0]), pk[1:]
        x_r, y_r = float(px[0]) - self.q * math.sin(th_r), float(py[0]) + self.q * math.cos(th_r)  # (5.10)
        c, sn = math.cos(th_r), math.sin(th_r)
        dx, dy = pose[0] - x_r, pose[1] - y_r
        x0 = np.array([
            c * dx + sn * dy,
            -sn * dx + c * dy,
            wrap_to_pi(self.theta_t - th_r),
            wrap_to_pi(pose[2] - th_r),
            self.u_R - self._u_r(kap0),
            s,
        ])
        times = obs.t + dt * np.arange(N)
        slots = self._slots(obs.t)
        P = np.zeros((N, 5 + 2 * len(slots)))
        P[:, 0] = kap
        P[:, 1] = self.u_o
        if self.own_assumed is not None:  # compatibility constraint from k >= 1
            P[:, 2] = self.own_assumed.at(times)
            P[1:, 3] = 1.0
        P[1:, 4] = 1.0  # wheel limits from k >= 1 (x_0 and its speed are given)
        psi_guess = self.morph.psi(s_guess[:N])
        used = 0
        for j, name in enumerate(slots):
            got = self.inbox.get(name, MESSAGE_KIND)
            if got is None or obs.t - got.stamp > cfg.stale_after_s:
                continue
            p_ij = cfg.offset(name) - self.psi_d
            target = self._wrap_near(got.value.at(times) - p_ij, psi_guess)
            P[:, 5 + 2 * j] = target
            P[:, 6 + 2 * j] = 1.0
            used += 1
        res = self.mpc.solve(x0, P)
        X, U = res.x, res.u
        if res.fallback == "stop":
            cmd = np.zeros(3)
            self.u_R = 0.0
            self.theta_t = pose[2]
            self._last = None
            s_plan = np.full(N + 1, s)
            sdot = 0.0
        else:
            sdot = float(U[0, 0])
            # apply the mean of the model's velocity over [t_k, t_k+1): midpoint of phi and eta
            x1 = X[1]
            geo = self.table(np.array([x1[IS], X[-1, IS]]))
            th_r1, kap1, kap_N = float(geo[2, 0]), float(geo[3, 0]), float(geo[3, 1])
            theta_t1 = th_r1 + x1[IPHI]
            u_R1 = x1[IETA] + self._u_r(kap1)
            omega = float(U[0, 2] + kap[0] * sdot)
            theta_mid = pose[2] + 0.5 * omega * dt
            tt_mid = self.theta_t + 0.5 * wrap_to_pi(theta_t1 - self.theta_t)
            uR_mid = 0.5 * (self.u_R + u_R1)
            rel = tt_mid - theta_mid
            cmd, _ = self.ctx.model.saturate([uR_mid * math.cos(rel), uR_mid * math.sin(rel), omega])
            s_plan = X[:, IS]
        tail = terminal_rollout(X[-1], kap_N, self.q, self.u_o, cfg.k_terminal, dt)[-1] \
            if res.fallback != "stop" else s
        assumed = assumed_trajectory(obs.t, dt, s_plan, tail)
        self.own_assumed = assumed
        if res.fallback != "stop":
            self._last = (obs.t, X)
        self.k += 1
        psi = self.morph.psi(s)
        msg = Outgoing(MESSAGE_KIND, {"t0": float(obs.t), "dt": float(dt),
                                        "s_hat": [float(v) for v in assumed.values],
                                        "psi_scale": float(self.morph.scale)})
        telemetry = {
            "ref": [x_r, y_r, th_r],
            "s": float(s),
            "sdot": sdot,
            "xi": float(psi - self.psi_d),
            "xi_period": float(self.psi_period),
            "speed_error": sdot - self.u_o,
            "solver_ok": bool(res.ok),
            "neighbours_used": used,
        }
        if res.timed_out:  # the control stage puts it on the timeline (docs/reference/controllers.md)
            telemetry["solve_timeout"] = {"cap_s": float(self.mpc.config.max_solve_s), "fallback": res.fallback}
        return StepResult(np.asarray(cmd, dtype=float), [msg], telemetry)

