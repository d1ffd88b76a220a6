"""Linearised (LTV) MPC path following of the omnidirectional robot as a QP (Chapter 4, Sec. 4.3).

Per control period:

1. Velocity profile (4.25)-(4.27) along a look-ahead of N steps: the forward speed is
   ``min(u_max, min(u_R, r(omega_b)), sqrt(mu g / |kappa|))`` with r(omega) of
   (4.17)-(4.18) (docs/reference/ambiguities.md, min(u_R, (4.18)) (A7)); the look-ahead points s_j follow the profile in time.
2. Errors (4.19) in the path frame: (x_e, y_e, alpha_e, theta_e).
3. Time-varying linear model (4.23), Euler-discretised (4.28)-(4.29) at the look-ahead
   points, condensed into X = G x_e + S U (4.31) with the corrected products of
   docs/reference/ambiguities.md, transition products (A5), and the QP (4.32)-(4.33) with bounds (4.34)-(4.36) rewritten on the
   decision variables (docs/reference/ambiguities.md, bounds on omega and s-dot (A6)).
4. Physical commands from U*(0): s-dot, the motion-direction rate Phi u_R, omega, and
   (u, v) by (4.21).

Condensing is a CasADi SX Function (JIT-compiled when a compiler works) and the QP is
solved by the ``daqp`` conic inside one compiled call (docs/journal/measurements.md, daqp for the Sec. 4.3 QP (W13): 0.044 ms at N = 15).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Sequence

import casadi as ca
import numpy as np

from copath.config import ConfigError, require
from copath.models import OmniModel
from copath.mpc import jit_available, jit_options, qp_options
from copath.paths import Path, wrap_to_pi

from copath.control import VirtualVehicle, Observation, PeerMessage, RobotContext, StepResult

from .config import QP_CONICS, LTVConfig

__all__ = [
    "ltv_errors",
    "ltv_error_dynamics",
    "linear_model",
    "condense",
    "profile_speed",
    "VelocityProfile",
    "LTVPathFollowingQP",
    "LTVConfig",
    "LTVController",
]

logger = logging.getLogger(__name__)


# -- model -------------------------------------------------------------------------


def ltv_errors(pose, theta_t: float, ref, theta_b: float) -> np.ndarray:
    """Errors (4.19): R(-theta_r)(p - p_r), alpha_e = theta_t - theta_r, theta_e = theta - theta_b.

    ``ref = (x_r, y_r, theta_r)`` is the virtual vehicle; angles are wrapped.
    """
    x, y, th = (float(v) for v in pose)
    xr, yr, thr = (float(v) for v in ref[:3])
    c, s = math.cos(thr), math.sin(thr)
    dx, dy = x - xr, y - yr
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_to_pi(theta_t - thr), wrap_to_pi(th - theta_b)])


def ltv_error_dynamics(xe, u_R: float, Phi: float, omega: float, sdot: float, kappa: float,
                       omega_b: float) -> np.ndarray:
    """Nonlinear error dynamics (4.22) of (x_e, y_e, alpha_e, theta_e)."""
    x, y, a, _ = (float(v) for v in xe)
    return np.array([
        y * kappa * sdot - sdot + u_R * math.cos(a),
        -x * kappa * sdot + u_R * math.sin(a),
        Phi * u_R - kappa * sdot,
        omega - omega_b,
    ])


def linear_model(kappa, u_R, Ts: float):
    """Discrete LTV model (4.23), (4.28)-(4.29): A = I + A_c Ts, B = B_c Ts.

    Works for floats and CasADi symbols; returns (A (4, 4), B (4, 3)).
    """
    lib = ca if isinstance(kappa, (ca.SX, ca.MX)) or isinstance(u_R, (ca.SX, ca.MX)) else np
    if lib is np:
        Ac = np.array([[0.0, kappa * u_R, 0.0, 0.0], [-kappa * u_R, 0.0, u_R, 0.0],
                       [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
        A = np.eye(4) + Ac * Ts
    else:
        A = ca.SX.eye(4) if isinstance(kappa, ca.SX) or isinstance(u_R, ca.SX) else ca.MX.eye(4)
        A[0, 1] = kappa * u_R * Ts
        A[1, 0] = -kappa * u_R * Ts
        A[1, 2] = u_R * Ts
    B = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) * Ts
    return A, B


def condense(As: Sequence, B):
    """Condensed prediction (4.31): X = G x_e(k) + S U.

    ``alpha(k1, k0) = A(k1-1) ... A(k0)`` and ``G in R^{nN x n}`` (docs/reference/ambiguities.md, transition products (A5));
    ``S_ij = alpha(k+i, k+j) B(k+j-1)`` for j <= i. Works on numpy arrays or CasADi
    symbols (``As`` is the list A(k), ..., A(k+N-1)).
    """
    N = len(As)
    sym = isinstance(As[0], (ca.SX, ca.MX))
    n, m = 4, B.shape[1]
    Phi = ca.SX.eye(n) if sym else np.eye(n)
    G_rows = []
    S_rows: list[list] = []
    prev: list = []
    for i in range(N):
        A = As[i]
        Phi = (ca.mtimes(A, Phi) if sym else A @ Phi)
        G_rows.append(Phi)
        row = [(ca.mtimes(A, blk) if sym else A @ blk) for blk in prev] + [ca.DM(B) if sym else B]
        prev = row
        zeros = [ca.SX(n, m) if sym else np.zeros((n, m))] * (N - i - 1)
        S_rows.append(row + zeros)
    if sym:
        return ca.vertcat(*G_rows), ca.vertcat(*[ca.horzcat(*r) for r in S_rows])
    return np.vstack(G_rows), np.block(S_rows)


# -- velocity profile --------------------------------------------------------------


def profile_speed(kappa, u_R: float, u_max: float, mu: float, g: float, omega_b=0.0,
                  model: OmniModel | None = None, heading: str = "fixed"):
    """Forward-speed profile (4.25)-(4.27) at curvature kappa.

    u = min(u_max, u_d, sqrt(mu g / |kappa|)) with u_d = min(u_R, r(omega_b)) (4.25),
    docs/reference/ambiguities.md, min(u_R, (4.18)) (A7); r is the model's :meth:`~copath.models.OmniModel.max_speed` (default:
    the published robot). With ``heading = "tangent"`` the body turns with the path,
    omega_b = kappa u, and u_d = min(u_R, :meth:`~copath.models.OmniModel.max_tangent_speed`).
    """
    model = model or OmniModel()
    k = np.abs(np.asarray(kappa, float))
    friction = np.sqrt(mu * g / np.maximum(k, 1e-12))
    if heading == "tangent":
        u_d = np.minimum(u_R, model.max_tangent_speed(k))
    else:
        u_d = np.minimum(u_R, model.max_speed(omega_b))
    return np.minimum(np.minimum(u_max, u_d), friction)


class VelocityProfile:
    """The speed profile tabulated along a path with its travel time T(s) = int ds / u.

    ``lookahead(s0, N, Ts)`` returns the N+1 look-ahead points s_j reached after j Ts
    seconds when moving with the profile (the text's "velocity monitored within some
    look-ahead distance", at least N steps), and the profile speeds there.
    """

    def __init__(self, table, speed_fn, step: float = 2e-3) -> None:
        self.closed, self.length = table.closed, table.length
        L = self.length
        lo, hi = (0.0, 3 * L) if self.closed else (-L, 2 * L)
        n = int(math.ceil((hi - lo) / step)) + 1
        self.s = np.linspace(lo, hi, n)
        self.kappa = table(self.s)[3]
        self.u = np.maximum(speed_fn(self.kappa), 1e-3)
        inv = 1.0 / self.u
        self.T = np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(self.s))])

    def speed(self, s) -> np.ndarray:
        s = np.asarray(s, float)
        if self.closed:
            s = np.mod(s, self.length)
        return np.interp(s, self.s, self.u)

    def lookahead(self, s0: float, N: int, Ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s_j, u_j, kappa_j) for j = 0..N."""
        base = 0.0
        if self.closed:
            base = math.floor(s0 / self.length) * self.length
        t0 = np.interp(s0 - base, self.s, self.T)
        sj = np.interp(t0 + Ts * np.arange(N + 1), self.T, self.s)
        return sj + base, np.interp(sj, self.s, self.u), np.interp(sj, self.s, self.kappa)


# -- QP ------------------------------------------------------------------------------


@dataclass
class LTVSolution:
    ok: bool
    U: np.ndarray
    """(N, 3) optimal virtual inputs u_e."""
    status: str


class LTVPathFollowingQP:
    """Condensed LTV-MPC QP (4.30)-(4.36), compiled once for horizon N.

    ``solve(x_e, kappa (N,), u_R (N,), lb (N, 3), ub (N, 3))`` returns the optimal U.
    """

    def __init__(self, N: int, Ts: float, Q: Sequence[float], R: Sequence[float],
                 qp_solver: str = "daqp", jit: bool = True, name: str = "ltv") -> None:
        require(N >= 1, "horizon", N, "must be >= 1")
        require(qp_solver in QP_CONICS, "qp_solver", qp_solver, f"allowed: {', '.join(QP_CONICS)}")
        self.N, self.Ts = int(N), float(Ts)
        n, m = 4, 3
        xe = ca.SX.sym("xe", n)
        kap = ca.SX.sym("kappa", N)
        uR = ca.SX.sym("uR", N)
        As = []
        B = None
        for j in range(N):
            A, B = linear_model(kap[j], uR[j], Ts)
            As.append(A)
        G, S = condense(As, B)
        Qbar = np.kron(np.eye(N), np.diag(np.asarray(Q, float)))
        Rbar = np.kron(np.eye(N), np.diag(np.asarray(R, float)))
        H = 2 * (ca.mtimes([S.T, ca.DM(Qbar), S]) + ca.DM(Rbar))  # (4.33)
        f = 2 * ca.mtimes([S.T, ca.DM(Qbar), G, xe])
        H = ca.densify(0.5 * (H + H.T))
        opts = jit_options() if jit and jit_available() else {}
        try:
            if opts:  # compiled once per machine (copath.solver_cache), keyed by the condensing's expressions
                from copath import solver_cache  # noqa: PLC0415

                key = solver_cache.solver_key(ca.Function("condense", [xe, kap, uR], [H, f]).serialize(), repr(opts))
                self._condense = solver_cache.cached_function(
                    "condense", key, lambda: ca.Function(f"{name}_condense", [xe, kap, uR], [H, f], opts))
            else:
                self._condense = ca.Function(f"{name}_condense", [xe, kap, uR], [H, f], opts)
        except Exception as exc:  # compiler trouble: interpret instead
            logger.info("JIT of the LTV condensing failed, using the virtual machine: %s", exc)
            self._condense = ca.Function(f"{name}_condense", [xe, kap, uR], [H, f])
        nU = N * m
        self._qp = ca.conic(f"{name}_qp", qp_solver, {"h": ca.Sparsity.dense(nU, nU), "a": ca.Sparsity(0, nU)},
                            qp_options(qp_solver))
        x_in, k_in, u_in = ca.MX.sym("xe", n), ca.MX.sym("kappa", N), ca.MX.sym("uR", N)
        lb, ub = ca.MX.sym("lb", nU), ca.MX.sym("ub", nU)
        Hm, fm = self._condense(x_in, k_in, u_in)
        sol = self._qp(h=Hm, g=fm, lbx=lb, ubx=ub)
        self._solve = ca.Function(f"{name}_solve", [x_in, k_in, u_in, lb, ub], [sol["x"]])
        # zero-copy calls: numpy arrays bound once to the Function's buffer
        self._io = [np.zeros(n), np.zeros(N), np.zeros(N), np.zeros(nU), np.zeros(nU)]
        self._out = np.zeros(nU)
        self._buffer, self._trigger = self._solve.buffer()
        for i, a in enumerate(self._io):
            self._buffer.set_arg(i, memoryview(a))
        self._buffer.set_res(0, memoryview(self._out))
        self._last: np.ndarray | None = None

    def matrices(self, xe, kappa, u_R) -> tuple[np.ndarray, np.ndarray]:
        """(H, f) of (4.33) for inspection and tests."""
        H, f = self._condense(np.asarray(xe, float), np.asarray(kappa, float), np.asarray(u_R, float))
        return H.full(), f.full().ravel()

    def solve(self, xe, kappa, u_R, lb, ub) -> LTVSolution:
        """Solve the QP; on failure return the shifted previous plan, else zeros."""
        N = self.N
        io = self._io
        try:
            io[0][:] = xe
            io[1][:] = kappa
            io[2][:] = u_R
            io[3][:] = np.ravel(lb)
            io[4][:] = np.ravel(ub)
            self._trigger()
            U = self._out.copy()
            if np.isfinite(U).all() and (U >= io[3] - 1e-6).all() and (U <= io[4] + 1e-6).all():
                self._last = U.reshape(N, 3)
                return LTVSolution(True, self._last, "solved")
            status = "infeasible or non-finite"
        except Exception as exc:  # never raise out of a control step
            status = f"exception: {exc}"
        lb, ub = io[3].copy(), io[4].copy()
        logger.warning("LTV QP failed (%s), using fallback", status)
        if self._last is not None and len(self._last) > 1:
            self._last = np.vstack([self._last[1:], self._last[-1:]])
            return LTVSolution(False, np.clip(self._last, lb.reshape(N, 3), ub.reshape(N, 3)), status)
        self._last = None
        return LTVSolution(False, np.clip(np.zeros((N, 3)), lb.reshape(N, 3), ub.reshape(N, 3)), status)


# -- controller ----------------------------------------------------------------------


class LTVController:
    """Sec. 4.3 path following: profile, LTV QP and command recovery."""

    def __init__(self, ctx: RobotContext, cfg: LTVConfig) -> None:
        if not isinstance(ctx.model, OmniModel):
            raise ConfigError(f"robots.{ctx.name}.model = {ctx.model.kind!r} is not allowed; ltv_mpc needs omni")
        self.cfg, self.model, self.Ts = cfg, ctx.model, float(ctx.dt)
        self.path: Path = ctx.own_path
        self.table = self.path.table()

        def speed_fn(kappa):
            return profile_speed(kappa, cfg.u_R, cfg.u_max, cfg.mu, cfg.g, 0.0, ctx.model, cfg.heading)

        self.profile = VelocityProfile(self.table, speed_fn)
        self.qp = LTVPathFollowingQP(cfg.horizon, self.Ts, cfg.Q, cfg.R, cfg.qp_solver, cfg.jit,
                                     name=f"{ctx.name}_ltv")
        self.vehicle = VirtualVehicle(cfg.s0)
        """The virtual vehicle s on the path."""
        self.direction = VirtualVehicle()
        """The motion direction theta_t, turning at Phi u_R between samples."""

    @property
    def s(self) -> float | None:
        return self.vehicle.s

    @property
    def theta_t(self) -> float | None:
        return self.direction.s

    def _bounds(self, u: np.ndarray, kappa: np.ndarray, alpha_e: float, omega_b: np.ndarray):
        """Bounds (4.34)-(4.35) on U, rewritten on the decision variables (docs/reference/ambiguities.md, bounds on omega and s-dot (A6))."""
        cfg, N = self.cfg, self.cfg.horizon
        lb, ub = np.empty((N, 3)), np.empty((N, 3))
        ca_ = math.cos(alpha_e)
        # 0 <= sdot <= u_max with sdot = u_R cos(alpha_e) - u_1, alpha_e frozen
        lb[:, 0] = u * ca_ - cfg.u_max
        ub[:, 0] = u * ca_
        # |Phi| <= phi_max with u_2 = Phi u_R - kappa sdot, sdot ~ u_R (recommendation)
        lb[:, 1] = (-cfg.phi_max - kappa) * u
        ub[:, 1] = (cfg.phi_max - kappa) * u
        # |omega| <= omega_c = min(omega_l(u_R), omega_max); u_3 = omega - omega_b
        omega_c = np.minimum(self.model.max_rotation(u), cfg.omega_max)
        lb[:, 2] = -omega_c - omega_b
        ub[:, 2] = omega_c - omega_b
        return lb, ub

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        cfg, N, Ts = self.cfg, self.cfg.horizon, self.Ts
        pose = np.asarray(obs.pose, float)
        if not self.vehicle.started:
            self.vehicle.start(self.path.project(pose[:2]))
        if not self.direction.started:
            self.direction.start(self.table.pose(self.s)[2])
        self.vehicle.advance(obs.t)
        self.direction.advance(obs.t)
        s_j, u_j, k_j = self.profile.lookahead(self.s, N, Ts)
        geo = self.table(s_j)
        tangent = cfg.heading == "tangent"
        theta_b = float(geo[2, 0]) if tangent else cfg.theta_b
        omega_b = k_j[:N] * u_j[:N] if tangent else np.zeros(N)
        xr, yr, thr = float(geo[0, 0]), float(geo[1, 0]), float(geo[2, 0])
        xe = ltv_errors(pose, self.theta_t, (xr, yr, thr), theta_b)
        lb, ub = self._bounds(u_j[:N], geo[3, :N], xe[2], omega_b)
        sol = self.qp.solve(xe, geo[3, :N], u_j[:N], lb, ub)
        u1, u2, u3 = sol.U[0]
        uR = float(u_j[0])
        kr = float(geo[3, 0])
        # command recovery from U*(0) (docs/reference/controllers-notes.md, LTV-MPC commands (N2))
        sdot = min(max(uR * math.cos(xe[2]) - u1, 0.0), cfg.u_max)
        Phi = (u2 + kr * sdot) / uR
        omega = u3 + float(omega_b[0])
        # zero-order hold: aim the motion direction at its mid-step value relative to
        # the mid-step body heading so the applied (u, v) follows theta_t on average
        th_mid = self.theta_t + 0.5 * Phi * uR * Ts - (pose[2] + 0.5 * omega * Ts)
        cmd = np.array([uR * math.cos(th_mid), uR * math.sin(th_mid), omega])
        self.vehicle.hold(obs.t, sdot)
        self.direction.hold(obs.t, Phi * uR)
        tel = {
            "ref": [xr, yr, float(theta_b)],
            "s": float(self.s),
            "sdot": float(sdot),
            "speed_error": float(sdot - uR),
            "solver_ok": bool(sol.ok),
            "u_ref": uR,
        }
        return StepResult(command=cmd, telemetry=tel)

