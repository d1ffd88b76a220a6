"""Shared MPC scaffolding: RK4 multiple shooting, a fast SQP solver factory, warm starts
and the fallback policy (Sec. 2.2; docs/reference/conventions.md, NMPC transcription (C3)).

Every MPC controller of the project (Ch. 4 and Ch. 5) describes its optimal control
problem with an :class:`OCP` and solves it with an :class:`MPCSolver`. The solver is
built once (in the controller's ``__init__``); ``step()`` passes numbers only.

Transcription
-------------
Inputs are piecewise constant on a grid of period ``dt`` (2.17)-(2.19); the horizon has
``N`` steps (T_c = T_p). Multiple shooting with ``substeps`` RK4 steps per interval::

    w = [x_0, u_0, x_1, u_1, ..., x_{N-1}, u_{N-1}, x_N, sigma]
    g = [x_0 - x0,  x_{k+1} - F(x_k, u_k, p_k)  and  h(x_k, u_k, p_k)  for k < N,
         h_N(x_N, u_{N-1}, p_N)  (hard),  h_T - sigma, h_T + sigma  (soft)]

The objective is a sum of squares (Gauss-Newton friendly) plus a linear slack penalty::

    J = sum_k ||r(x_k, u_k, p_k)||^2 + ||r_N(x_N, p_N)||^2 + sum w_l sigma + w_q ||sigma||^2

Write a weighted stage cost x^T Q x + u^T R u as the residual ``sqrt(Q) x, sqrt(R) u``
(see :func:`weighted`). Exactly one of these is evaluated per stage; the time step is
*not* multiplied into the cost (docs/reference/ambiguities.md, stage cost and sampling time (A29): the QP cost (4.30) is an unscaled sum).

Solver (docs/journal/measurements.md, NMPC solver choice (W11-W12))
-----------------------------------------------
``sqpmethod`` with a structure-exploiting QP solver (``qrqp`` by default, ``osqp`` or
``qpoases`` on request), a Gauss-Newton Hessian ``2 J_r^T J_r`` (passed as ``hess_lag``),
JIT compilation with ``compiler="shell"`` when a C compiler works (silently falling back
to the virtual machine otherwise). ``ipopt`` is available as ``method="ipopt"``. Warm
start: primal and dual solutions of the previous solve shifted by one step. Every call
goes through the solver's ``FunctionBuffer`` with pre-allocated numpy arrays (constant
bounds written once), which saves the numpy->DM conversions of a normal call (about
0.1-0.2 ms per solve here). Measured with ``copath bench solve``: the omni path-following
NMPC at N = 10 solves in about 0.25-0.35 ms (p50) on this 2-core machine.

Fallback policy
---------------
A solve never raises. An unfinished solve (iteration limit, stalled line search) is
restarted once from its own iterate. If it still fails (solver error, non-finite
numbers, constraint violation above ``feas_tol``), :meth:`MPCSolver.solve` logs a
warning and returns a :class:`SolveResult`
with ``ok=False`` whose plan is the previous plan shifted by one step (``fallback =
"shifted"``) while one is left, else the ``stop`` input repeated (``fallback = "stop"``).

Time cap: with ``SolverConfig.max_solve_s`` a solve (its retry included) that runs longer
stops at its next iteration (an ``iteration_callback``; IPOPT also gets ``max_wall_time``),
is not retried and falls back as above; ``SolveResult.timed_out`` says so and
``MPCSolver.timeouts`` counts them. A JIT-compiled solver comes from the solver cache and
carries no callback (a Python callback cannot be saved): the cap applies to solvers built
without JIT (docs/reference/controllers.md, "Solve time cap").

Usage
-----
>>> import casadi as ca
>>> def f(x, u, p):            # continuous dynamics, SX in, SX out
...     return ca.vertcat(x[1], u[0])
>>> ocp = OCP(nx=2, nu=1, N=10, dt=0.1, dynamics=f,
...           stage_residual=lambda x, u, p: ca.vertcat(x[0], 0.1 * u[0]),
...           terminal_residual=lambda x, p: x, u_lb=[-1.0], u_ub=[1.0])
>>> mpc = MPCSolver(ocp, SolverConfig(jit=False))
>>> res = mpc.solve([1.0, 0.0])
>>> res.ok, res.u0.shape
(True, (1,))

Parameters reach the problem per stage (``p_stage``: (N, n_p), row k seen by stage k
and ``p_stage[N-1]`` also by the terminal terms unless ``n_pt`` terminal parameters
are declared) and per horizon end (``p_term``: (n_pt,)). ``res.x`` (N+1, nx) and
``res.u`` (N, nu) are the predicted plan; ``mpc.shifted_plan()`` gives the warm start
of the next solve, ``mpc.set_initial_guess(X, U)`` replaces it, and ``mpc.reset()``
forgets it. ``solve(..., guess=(X, U))`` overrides the warm start once and
``solve(..., u_lb=..., u_ub=...)`` replaces the input bounds for one solve,
``solve(..., hT_lb=..., hT_ub=...)`` the bounds of the soft terminal constraint.

Helpers for controllers: :class:`SolverFields` (inherit it in a controller config to
accept ``solver``, ``qp_solver``, ``hessian``, ``max_iter``, ``jit``, ``tol`` and the
slack weights in the scenario table), :class:`PathTable` (fast x, y, theta, kappa,
dkappa/ds look-ups along a horizon; defined in :mod:`copath.paths`, re-exported here),
:func:`rk4`, and the one table of solver options (:data:`QP_OPTIONS`, :func:`qp_options`,
:func:`jit_options`) that every solver built here or in a controller uses.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import casadi as ca
import numpy as np

from .config import require
from .paths import PathTable  # noqa: F401  (re-exported: the one path table lives in copath.paths)
from .solver_fields import HESSIANS, QP_SOLVERS, SOLVER_METHODS, SolverConfig, SolverFields  # noqa: F401  (re-exported: solver keys without CasADi)

__all__ = [
    "SolverConfig",
    "SolverFields",
    "PathTable",
    "OCP",
    "MPCSolver",
    "SolveResult",
    "rk4",
    "weighted",
    "jit_available",
    "jit_options",
    "qp_options",
    "QP_OPTIONS",
    "SOLVER_METHODS",
    "QP_SOLVERS",
]

logger = logging.getLogger(__name__)


QP_OPTIONS: dict[str, dict] = {
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False,
             "max_iter": 50},
    "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-8, "eps_rel": 1e-8, "polish": True},
             "error_on_fail": False},
    "qpoases": {"printLevel": "none", "error_on_fail": False},
    "daqp": {"error_on_fail": False},
}
"""The one table of QP-solver options (CasADi ``conic`` plug-ins): quiet, and a failed
solve is reported in the return status instead of raised (the fallback policy decides)."""

_JIT_OK: bool | None = None


def qp_options(qp_solver: str, **extra) -> dict:
    """A fresh copy of the :data:`QP_OPTIONS` of ``qp_solver`` updated with ``extra``
    (e.g. ``sparse=True`` for qpOASES inside the SQP, ``warm_start_primal=True`` for OSQP)."""
    if qp_solver not in QP_OPTIONS:
        raise ValueError(f"qp_solver = {qp_solver!r} is not allowed; choose one of {sorted(QP_OPTIONS)}")
    opts = {k: (dict(v) if isinstance(v, dict) else v) for k, v in QP_OPTIONS[qp_solver].items()}
    opts.update(extra)
    return opts


def jit_options(flags: Sequence[str] = ("-O2",)) -> dict:
    """CasADi options that JIT-compile a Function with the system C compiler (``shell``);
    a saved Function carries its binary (the solver cache, ``copath.solver_cache``)."""
    from .solver_cache import EMBED, jit_directory  # noqa: PLC0415

    # an empty list would reach CasADi typed as a vector of booleans and be refused
    extra = {"flags": [str(f) for f in flags]} if flags else {}
    where = jit_directory()  # the generated C source and the library, not the working directory
    return {"jit": True, "compiler": "shell", **EMBED,
            "jit_options": {**extra, "verbose": False, "directory": where}}

# statuses whose iterate is used when it is feasible (a warm-started SQP that stops on
# its iteration limit still returns a usable, constraint-satisfying plan)
_ACCEPTABLE = frozenset({"Maximum_Iterations_Exceeded", "Solved_To_Acceptable_Level",
                         "Search_Direction_Becomes_Too_Small", "Maximum_IterationsExceeded"})


def jit_available() -> bool:
    """True when CasADi can JIT-compile through the system C compiler (cached)."""
    global _JIT_OK
    if _JIT_OK is None:
        try:
            from . import solver_cache  # noqa: PLC0415

            x = ca.SX.sym("x")
            opts = jit_options(())
            f = solver_cache.cached_function("jit_probe", solver_cache.solver_key("jit_probe", opts), lambda: ca.Function(
                "jit_probe", [x], [x * x], opts))
            _JIT_OK = abs(float(f(3.0)) - 9.0) < 1e-12
        except Exception as exc:  # no compiler, no write access, ...
            logger.info("CasADi JIT unavailable, using the virtual machine: %s", exc)
            _JIT_OK = False
    return _JIT_OK


class _WallCap(ca.Callback):
    """The ``iteration_callback`` of a capped solver: asks the solver to stop (a nonzero
    return: ``User_Requested_Stop``) once the wall clock passes :attr:`deadline`."""

    def __init__(self, name: str, nx: int, ng: int, np_: int) -> None:
        ca.Callback.__init__(self)
        self._sizes = {"x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "lam_p": np_, "f": 1}
        self.deadline = math.inf
        self.fired = False
        self.construct(name, {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "stop"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        n = self._sizes[ca.nlpsol_out(i)]
        return ca.Sparsity.scalar() if ca.nlpsol_out(i) == "f" else ca.Sparsity.dense(n)

    def eval(self, arg):
        if time.perf_counter() > self.deadline:
            self.fired = True
            return [1]
        return [0]


SXFn = Callable[..., ca.SX]


@dataclass
class OCP:
    """Symbolic description of an optimal control problem (all callables take SX).

    Attributes
    ----------
    nx, nu, N : int
        State size, input size, horizon steps.
    dt : float
        Step length delta [s].
    dynamics : callable (x, u, p) -> xdot
        Continuous-time model, integrated with RK4 over each step.
    stage_residual : callable (x, u, p) -> r
        Stage cost ||r||^2 at k = 0..N-1.
    terminal_residual : callable (x_N, p_T) -> r, optional
        Terminal cost ||r||^2.
    n_p, n_pt : int
        Number of stage parameters (per step) and terminal parameters.
    u_lb, u_ub : (nu,) or (N, nu)
        Hard input bounds (actuator constraints are hard, Sec. 2.2.2).
    x_lb, x_ub : (nx,), optional
        Hard state bounds on x_1..x_N.
    stage_constraint : callable (x, u, p) -> h, optional
        Hard path constraint ``h_lb <= h <= h_ub`` on k = 0..N-1.
    terminal_constraint : callable (x_N, u_{N-1}, p_T) -> h, optional
        Hard terminal constraint ``hN_lb <= h <= hN_ub``.
    soft_terminal : callable (x_N, u_{N-1}, p_T) -> h, optional
        Soft terminal constraint ``hT_lb - sigma <= h <= hT_ub + sigma``, sigma >= 0 with
        the slack penalties of :class:`SolverConfig` (terminal regions, Sec. 2.2.2).
    substeps : int
        RK4 steps per interval.
    stop_u : (nu,), optional
        Input meaning "stop"; the last fallback (default zeros).
    """

    nx: int
    nu: int
    N: int
    dt: float
    dynamics: SXFn
    stage_residual: SXFn
    terminal_residual: SXFn | None = None
    n_p: int = 0
    n_pt: int = 0
    u_lb: Sequence[float] | np.ndarray | None = None
    u_ub: Sequence[float] | np.ndarray | None = None
    x_lb: Sequence[float] | np.ndarray | None = None
    x_ub: Sequence[float] | np.ndarray | None = None
    stage_constraint: SXFn | None = None
    h_lb: Sequence[float] | None = None
    h_ub: Sequence[float] | None = None
    terminal_constraint: SXFn | None = None
    hN_lb: Sequence[float] | None = None
    hN_ub: Sequence[float] | None = None
    soft_terminal: SXFn | None = None
    hT_lb: Sequence[float] | None = None
    hT_ub: Sequence[float] | None = None
    substeps: int = 1
    stop_u: Sequence[float] | np.ndarray | None = None
    name: str = "mpc"

    def __post_init__(self) -> None:
        require(self.nx >= 1, "ocp.nx", self.nx, "must be >= 1")
        require(self.nu >= 1, "ocp.nu", self.nu, "must be >= 1")
        require(self.N >= 1, "horizon", self.N, "must be >= 1")
        require(self.dt > 0, "dt", self.dt, "must be > 0")
        require(self.substeps >= 1, "substeps", self.substeps, "must be >= 1")


def rk4(f: SXFn, x, u, p, h: float, substeps: int = 1):
    """State after ``h`` seconds of the classic RK4 scheme with ``substeps`` steps."""
    hs = h / substeps
    for _ in range(substeps):
        k1 = f(x, u, p)
        k2 = f(x + hs / 2 * k1, u, p)
        k3 = f(x + hs / 2 * k2, u, p)
        k4 = f(x + hs * k3, u, p)
        x = x + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def weighted(vec, weights) -> ca.SX:
    """Residual ``sqrt(w) * vec`` so that ``||r||^2 = vec^T diag(w) vec``."""
    w = np.sqrt(np.asarray(weights, dtype=float).reshape(-1))
    return ca.vertcat(*[float(wi) * vec[i] for i, wi in enumerate(w)])


@dataclass
class SolveResult:
    """Outcome of one :meth:`MPCSolver.solve` (a value, never an exception)."""

    ok: bool
    """True when the returned plan is a solution of this solve."""
    status: str
    """Solver return status (e.g. ``Solve_Succeeded``) or the failure reason."""
    u: np.ndarray
    """(N, nu) planned inputs (the fallback plan when not ok)."""
    x: np.ndarray
    """(N+1, nx) predicted states (shifted previous prediction when not ok)."""
    iterations: int = 0
    cost: float = math.nan
    slack: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Soft-constraint slacks at the solution."""
    fallback: str | None = None
    """None, ``"shifted"`` (previous plan shifted) or ``"stop"``."""
    timed_out: bool = False
    """The solve was stopped by the time cap (``SolverConfig.max_solve_s``)."""

    @property
    def u0(self) -> np.ndarray:
        """First input of the plan, to apply now."""
        return self.u[0]


class MPCSolver:
    """Build once, solve many: the NLP of an :class:`OCP` with warm starts and fallbacks.

    Parameters
    ----------
    ocp : OCP
        Problem description.
    config : SolverConfig
        Solver choice and tolerances.
    """

    def __init__(self, ocp: OCP, config: SolverConfig | None = None) -> None:
        self.ocp = ocp
        self.config = config or SolverConfig()
        self._cap: _WallCap | None = None
        self._build_symbolic()
        self._solver = self._make_solver()
        self._plan_w: np.ndarray | None = None
        self._lam_x: np.ndarray | None = None
        self._lam_g: np.ndarray | None = None
        self._fallback_plan: np.ndarray | None = None
        self._fallback_x: np.ndarray | None = None
        self.failures = 0
        self.timeouts = 0
        """Solves stopped by the time cap."""
        self._build_shift_indices()
        self._setup_buffer()

    # -- construction -----------------------------------------------------------------
    def _build_symbolic(self) -> None:
        o = self.ocp
        nx, nu, N = o.nx, o.nu, o.N
        X = [ca.SX.sym(f"x{k}", nx) for k in range(N + 1)]
        U = [ca.SX.sym(f"u{k}", nu) for k in range(N)]
        x0 = ca.SX.sym("x0", nx)
        P = [ca.SX.sym(f"p{k}", o.n_p) for k in range(N)]
        PT = ca.SX.sym("pT", o.n_pt) if o.n_pt else P[-1]
        residuals, g, lbg, ubg = [], [X[0] - x0], [np.zeros(nx)], [np.zeros(nx)]
        self._g_stage = []  # (start, size) of each stage block in g, for dual shifting
        row = nx
        for k in range(N):
            residuals.append(o.stage_residual(X[k], U[k], P[k]))
            xn = rk4(o.dynamics, X[k], U[k], P[k], o.dt, o.substeps)
            blk = [X[k + 1] - xn]
            lo, hi = [np.zeros(nx)], [np.zeros(nx)]
            if o.stage_constraint is not None:
                h = o.stage_constraint(X[k], U[k], P[k])
                blk.append(h)
                lo.append(np.broadcast_to(np.asarray(o.h_lb, float), (h.numel(),)))
                hi.append(np.broadcast_to(np.asarray(o.h_ub, float), (h.numel(),)))
            b = ca.vertcat(*blk)
            g.append(b)
            lbg += lo
            ubg += hi
            self._g_stage.append((row, b.numel()))
            row += b.numel()
        if o.terminal_residual is not None:
            residuals.append(o.terminal_residual(X[N], PT))
        if o.terminal_constraint is not None:
            h = o.terminal_constraint(X[N], U[N - 1], PT)
            g.append(h)
            lbg.append(np.broadcast_to(np.asarray(o.hN_lb, float), (h.numel(),)))
            ubg.append(np.broadcast_to(np.asarray(o.hN_ub, float), (h.numel(),)))
            row += h.numel()
        n_slack = 0
        sigma = ca.SX.sym("sigma", 0)
        if o.soft_terminal is not None:
            h = o.soft_terminal(X[N], U[N - 1], PT)
            n_slack = h.numel()
            sigma = ca.SX.sym("sigma", n_slack)
            hl = np.broadcast_to(np.asarray(o.hT_lb, float), (n_slack,))
            hu = np.broadcast_to(np.asarray(o.hT_ub, float), (n_slack,))
            g += [h - sigma, h + sigma]
            lbg += [np.full(n_slack, -np.inf), hl]
            ubg += [hu, np.full(n_slack, np.inf)]
            residuals.append(math.sqrt(self.config.slack_weight_quadratic) * sigma)
        r = ca.vertcat(*residuals)
        f = ca.sumsqr(r) + self.config.slack_weight * ca.sum1(sigma)
        # decision vector layout (see module docstring)
        parts = []
        for k in range(N):
            parts += [X[k], U[k]]
        parts += [X[N], sigma]
        w = ca.vertcat(*parts)
        p = ca.vertcat(x0, *P, PT) if o.n_pt else ca.vertcat(x0, *P)
        self._w, self._p, self._f, self._g, self._r = w, p, f, ca.vertcat(*g), r
        self._n_slack = n_slack
        self._stride = nx + nu
        self._nw = w.numel()
        # bounds
        u_lb = self._stage_bounds(o.u_lb, -np.inf, nu)
        u_ub = self._stage_bounds(o.u_ub, np.inf, nu)
        x_lb = np.broadcast_to(np.asarray(o.x_lb if o.x_lb is not None else -np.inf, float), (nx,))
        x_ub = np.broadcast_to(np.asarray(o.x_ub if o.x_ub is not None else np.inf, float), (nx,))
        lbw, ubw = [], []
        for k in range(N):
            lbw += [np.full(nx, -np.inf) if k == 0 else x_lb, u_lb[k]]
            ubw += [np.full(nx, np.inf) if k == 0 else x_ub, u_ub[k]]
        lbw += [x_lb, np.zeros(n_slack)]
        ubw += [x_ub, np.full(n_slack, np.inf)]
        self._lbw_np, self._ubw_np = np.concatenate(lbw), np.concatenate(ubw)
        self._lbg_np, self._ubg_np = np.concatenate(lbg), np.concatenate(ubg)
        self._stop_u = np.zeros(nu) if o.stop_u is None else np.asarray(o.stop_u, float).reshape(nu)
        self._u_lb, self._u_ub = u_lb, u_ub

    def _stage_bounds(self, b, default: float, nu: int) -> np.ndarray:
        if b is None:
            return np.full((self.ocp.N, nu), default)
        b = np.asarray(b, float)
        return np.broadcast_to(b, (self.ocp.N, nu)).copy()

    def _jit_opts(self) -> dict:
        return jit_options(self.config.jit_flags)

    def _make_solver(self) -> ca.Function:
        use_jit = self.config.jit and jit_available()
        try:
            if use_jit:  # compiled once per machine (copath.solver_cache), loaded by every other build
                from . import solver_cache  # noqa: PLC0415

                problem = ca.Function("nlp", [self._w, self._p], [self._f, self._g, self._r]).serialize()
                # keyed by structure and options, not by robot: robots with the same problem share it
                # and by the QP solver's options, which the saved Function carries but the config does not name
                key = solver_cache.solver_key(problem, repr(self.config),
                                              repr(QP_OPTIONS.get(self.config.qp_solver)))
                return solver_cache.cached_function("nlpsol", key, lambda: self._nlpsol(True))
            return self._nlpsol(use_jit)
        except Exception as exc:  # compiler failure: fall back silently (logged)
            if not use_jit:
                raise
            logger.info("JIT build of %s failed, using the virtual machine: %s", self.ocp.name, exc)
            return self._nlpsol(False)

    def _nlpsol(self, use_jit: bool) -> ca.Function:
        nlp = {"x": self._w, "p": self._p, "f": self._f, "g": self._g}
        # parameter multipliers are never used (and are NaN where a residual has a
        # sqrt/atan2 kink in a parameter direction)
        opts: dict = {"print_time": False, "error_on_fail": False, "calc_lam_p": False}
        if use_jit:
            opts.update(self._jit_opts())
            from .solver_cache import no_jit_sources_left  # noqa: PLC0415

            with no_jit_sources_left():
                return self._make_nlpsol(nlp, opts, use_jit)
        return self._make_nlpsol(nlp, opts, use_jit)

    def _make_nlpsol(self, nlp: dict, opts: dict, use_jit: bool) -> ca.Function:
        c = self.config
        if c.max_solve_s is not None and not use_jit:  # a cached (JIT) solver cannot carry a Python callback
            self._cap = _WallCap(f"{self.ocp.name}_cap", self._w.numel(), self._g.numel(), self._p.numel())
            opts["iteration_callback"] = self._cap
        if c.method == "ipopt":
            opts["ipopt"] = {"print_level": 0, "max_iter": c.max_iter, "tol": c.tol,
                             "sb": "yes", "warm_start_init_point": "yes",
                             "mu_init": 1e-3, "acceptable_tol": 1e-4}
            if c.max_solve_s is not None:
                opts["ipopt"]["max_wall_time"] = float(c.max_solve_s)
            if c.hessian == "gauss-newton":  # ipopt takes the upper triangle only
                opts["hess_lag"] = self._gn_hessian(use_jit, upper=True)
            return ca.nlpsol(f"{self.ocp.name}_ipopt", "ipopt", nlp, opts)
        extra = {"osqp": {"warm_start_primal": True}, "qpoases": {"sparse": True}}.get(c.qp_solver, {})
        qp_opts = qp_options(c.qp_solver, **extra)
        opts.update({
            "qpsol": c.qp_solver,
            "qpsol_options": qp_opts,
            "max_iter": c.max_iter,
            "tol_pr": c.tol,
            "tol_du": c.tol,
            "print_header": False,
            "print_iteration": False,
            "print_status": False,
            "min_step_size": 1e-12,
        })
        if c.hessian == "gauss-newton":
            opts["hess_lag"] = self._gn_hessian(use_jit)
        return ca.nlpsol(f"{self.ocp.name}_sqp", "sqpmethod", nlp, opts)

    def _gn_hessian(self, use_jit: bool, upper: bool = False) -> ca.Function:
        """Gauss-Newton Hessian of the Lagrangian: lam_f * 2 J_r^T J_r (+ tiny regulariser)."""
        lam_f = ca.SX.sym("lam_f")
        lam_g = ca.SX.sym("lam_g", self._g.numel())
        J = ca.jacobian(self._r, self._w)
        H = lam_f * 2 * ca.mtimes(J.T, J) + 1e-9 * ca.SX.eye(self._nw)
        if upper:
            H = ca.triu(H)
        opts = self._jit_opts() if use_jit else {}
        return ca.Function("nlp_hess_l", [self._w, self._p, lam_f, lam_g], [H],
                           ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"], opts)

    # -- plan bookkeeping ------------------------------------------------------------
    def _split(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X (N+1, nx), U (N, nu), slacks) of a decision vector (copies)."""
        return w[self._x_idx], w[self._u_idx2], w[self._s_idx]

    def _join(self, X: np.ndarray, U: np.ndarray, S: np.ndarray) -> np.ndarray:
        body = np.hstack([X[:-1], U]).reshape(-1)
        return np.concatenate([body, X[-1], S])

    def shifted_plan(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(X, U) of the last solution shifted by one step (last entries repeated)."""
        if self._plan_w is None:
            return None
        w = self._plan_w[self._w_shift]
        return w[self._x_idx], w[self._u_idx2]

    @property
    def u_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the OCP's input bounds, each (N, nu) (edit and pass to :meth:`solve`)."""
        return self._u_lb.copy(), self._u_ub.copy()

    def reset(self) -> None:
        """Forget the warm start and the fallback plan."""
        self._plan_w = self._lam_x = self._lam_g = None
        self._fallback_plan = self._fallback_x = None

    def take_warm_start(self, other: "MPCSolver") -> None:
        """Warm-start from ``other``'s last solve: a solver of the same decision variables and
        constraints whose parameters differ (the distributed MPC's coupling slots for a stand-in
        neighbour, agent/controllers/dmpc/controller.py)."""
        self._plan_w, self._lam_x, self._lam_g = other._plan_w, other._lam_x, other._lam_g
        self._fallback_plan, self._fallback_x = other._fallback_plan, other._fallback_x

    def set_initial_guess(self, X: np.ndarray, U: np.ndarray) -> None:
        """Warm-start the next solve from a given plan (e.g. a rollout of a simple law)."""
        o = self.ocp
        X = np.asarray(X, float).reshape(o.N + 1, o.nx)
        U = np.asarray(U, float).reshape(o.N, o.nu)
        self._plan_w = self._join(X, U, np.zeros(self._n_slack))
        self._lam_x = self._lam_g = None

    def _setup_buffer(self) -> None:
        """Pre-allocated numpy arrays bound to the solver's FunctionBuffer.

        A normal CasADi call converts every numpy argument to a DM (tens of
        microseconds each); the buffer reads and writes these arrays in place.
        """
        S = self._solver
        self._io = {S.name_in(i): np.zeros(S.nnz_in(i)) for i in range(S.n_in())}
        self._io.update({S.name_out(i): np.zeros(S.nnz_out(i)) for i in range(S.n_out())})
        self._io["lbg"][:] = self._lbg_np
        self._io["ubg"][:] = self._ubg_np
        self._buffer, self._trigger = S.buffer()
        for i in range(S.n_in()):
            self._buffer.set_arg(i, memoryview(self._io[S.name_in(i)]))
        for i in range(S.n_out()):
            self._buffer.set_res(i, memoryview(self._io[S.name_out(i)]))
        o = self.ocp
        self._u_idx = np.concatenate([np.arange(k * self._stride + o.nx, (k + 1) * self._stride)
                                      for k in range(o.N)])

    def _build_shift_indices(self) -> None:
        """Index arrays that shift w, lam_x and lam_g by one stage in one take."""
        o = self.ocp
        nx, st = o.nx, self._stride
        idx = np.arange(self._nw)
        w_shift = idx.copy()
        for k in range(o.N):
            src_x = (k + 1) * st if k + 1 < o.N else o.N * st  # X_{k+1}
            w_shift[k * st: k * st + nx] = idx[src_x: src_x + nx]
            src_u = min(k + 1, o.N - 1) * st + nx
            w_shift[k * st + nx: (k + 1) * st] = idx[src_u: src_u + o.nu]
        self._w_shift = w_shift
        g_shift = np.arange(self._g.numel())
        blocks = self._g_stage
        for k in range(len(blocks) - 1):
            (a0, n0), (a1, _) = blocks[k], blocks[k + 1]
            g_shift[a0:a0 + n0] = np.arange(a1, a1 + n0)
        self._g_shift = g_shift
        # index arrays of X (N+1, nx), U (N, nu) and the slacks inside w
        x_idx = [np.arange(k * st, k * st + nx) for k in range(o.N)] + [np.arange(o.N * st, o.N * st + nx)]
        self._x_idx = np.stack(x_idx)
        self._u_idx2 = np.stack([np.arange(k * st + nx, (k + 1) * st) for k in range(o.N)])
        self._s_idx = np.arange(o.N * st + nx, self._nw)

    # -- solving ------------------------------------------------------------------------
    def solve(
        self,
        x0,
        p_stage=None,
        p_term=None,
        guess: tuple[np.ndarray, np.ndarray] | None = None,
        u_lb=None,
        u_ub=None,
        hT_lb=None,
        hT_ub=None,
        _retry: bool = True,
    ) -> SolveResult:
        """Solve from state ``x0`` with parameters; never raises on solver failure.

        An unfinished solve (iteration limit, stalled line search) is restarted once from
        its own last iterate before the fallback policy applies.

        Parameters
        ----------
        x0 : (nx,)
            Current (error) state.
        p_stage : (N, n_p), optional
            Stage parameters (row k for step k).
        p_term : (n_pt,), optional
            Terminal parameters.
        guess : (X (N+1, nx), U (N, nu)), optional
            Initial guess overriding the shifted previous solution.
        u_lb, u_ub : (nu,) or (N, nu), optional
            Input bounds replacing the OCP's for this solve only.
        hT_lb, hT_ub : (n_T,), optional
            Bounds of the soft terminal constraint replacing the OCP's for this solve only
            (the plan is accepted against them).
        """
        o = self.ocp
        io = self._io
        x0 = np.asarray(x0, float).reshape(o.nx)
        p = io["p"]
        p[: o.nx] = x0
        try:
            if o.n_p:
                p[o.nx: o.nx + o.N * o.n_p] = np.asarray(p_stage, float).reshape(-1)
            if o.n_pt:
                p[o.nx + o.N * o.n_p:] = np.asarray(p_term, float).reshape(-1)
        except ValueError as exc:
            return self._fail(f"parameters do not fit: {exc}", x0)
        lo, hi = io["lbx"], io["ubx"]
        lo[:] = self._lbw_np
        hi[:] = self._ubw_np
        if u_lb is not None or u_ub is not None:
            for bound, arr in ((u_lb, lo), (u_ub, hi)):
                if bound is not None:
                    b = np.broadcast_to(np.asarray(bound, float), (o.N, o.nu))
                    arr[self._u_idx] = b.reshape(-1)
        lbg, ubg = self._lbg_np, self._ubg_np
        if hT_lb is not None or hT_ub is not None:
            lbg, ubg = lbg.copy(), ubg.copy()
            n, ns = len(lbg), self._n_slack  # the soft rows close g: h - sigma <= hT_ub, h + sigma >= hT_lb
            if hT_ub is not None:
                ubg[n - 2 * ns: n - ns] = np.broadcast_to(np.asarray(hT_ub, float), (ns,))
            if hT_lb is not None:
                lbg[n - ns:] = np.broadcast_to(np.asarray(hT_lb, float), (ns,))
        io["lbg"][:] = lbg
        io["ubg"][:] = ubg
        w0, lam_x, lam_g = io["x0"], io["lam_x0"], io["lam_g0"]
        if guess is not None:
            w0[:] = self._join(np.asarray(guess[0], float).reshape(o.N + 1, o.nx),
                               np.asarray(guess[1], float).reshape(o.N, o.nu), np.zeros(self._n_slack))
            lam_x[:] = 0.0
            lam_g[:] = 0.0
        elif self._plan_w is not None:
            np.take(self._plan_w, self._w_shift, out=w0)
            if self._lam_x is not None:
                np.take(self._lam_x, self._w_shift, out=lam_x)
                np.take(self._lam_g, self._g_shift, out=lam_g)
            else:
                lam_x[:] = 0.0
                lam_g[:] = 0.0
        else:
            w0[:] = self._join(np.tile(x0, (o.N + 1, 1)), np.tile(self._stop_u, (o.N, 1)),
                               np.zeros(self._n_slack))
            lam_x[:] = 0.0
            lam_g[:] = 0.0
        w0[: o.nx] = x0
        # keep the initial guess inside the box (active-set QP solvers prefer it)
        np.clip(w0, lo, hi, out=w0)
        cap = self._cap
        if cap is not None and _retry:  # one deadline for the solve and its retry
            cap.deadline = time.perf_counter() + self.config.max_solve_s
        try:
            self._trigger()  # zero-copy call through the FunctionBuffer (docs/journal/measurements.md, NMPC solver choice (W11): ~60 us saved)
            stats = self._buffer.stats()
        except Exception as exc:  # CasADi raises RuntimeError on evaluation errors
            return self._fail(f"exception: {exc}", x0)
        status = str(stats.get("return_status", "unknown"))
        if cap is not None and (cap.fired or status == "Maximum_WallTime_Exceeded"):
            cap.fired = False
            self.timeouts += 1
            return dataclasses.replace(self._fail(f"time cap of {self.config.max_solve_s:.3g} s reached ({status})", x0),
                                       timed_out=True)
        w = io["x"].copy()
        g = io["g"]
        viol = max(0.0, float(np.max(lbg - g, initial=0.0)), float(np.max(g - ubg, initial=0.0)))
        finite = bool(np.isfinite(w).all()) and math.isfinite(viol)
        accepted = finite and viol <= self.config.feas_tol and (
            bool(stats.get("success", False)) or status in _ACCEPTABLE
        )
        if not accepted and finite and _retry:
            return self.solve(x0, p_stage, p_term, guess=(w[self._x_idx], w[self._u_idx2]),
                              u_lb=u_lb, u_ub=u_ub, hT_lb=hT_lb, hT_ub=hT_ub, _retry=False)
        if not accepted:
            reason = status if finite else "non-finite solution"
            result = self._fail(f"{reason} (violation {viol:.2g})", x0)
            if finite:  # an unfinished iterate is still the best warm start we have
                self._plan_w = w
            return result
        self._plan_w = w
        self._lam_x = io["lam_x"].copy()
        self._lam_g = io["lam_g"].copy()
        X, U, S = self._split(w)
        self._fallback_plan, self._fallback_x = U, X
        return SolveResult(True, status, U, X, int(stats.get("iter_count", 0)), float(io["f"][0]), S, None)

    def _fail(self, reason: str, x0: np.ndarray) -> SolveResult:
        """Fallback policy: shifted previous plan while one is left, else stop."""
        o = self.ocp
        self.failures += 1
        logger.warning("%s: solve failed (%s), using fallback", o.name, reason)
        self._plan_w = None  # a failed iterate is no warm start
        self._lam_x = self._lam_g = None
        if self._fallback_plan is not None and len(self._fallback_plan) > 1:
            U = self._fallback_plan[1:]
            X = self._fallback_x[1:]
            self._fallback_plan, self._fallback_x = U, X
            U_full = np.vstack([U, np.tile(U[-1], (o.N - len(U), 1))])
            X_full = np.vstack([X, np.tile(X[-1], (o.N + 1 - len(X), 1))])
            return SolveResult(False, reason, U_full, X_full, fallback="shifted")
        self._fallback_plan = self._fallback_x = None
        U = np.tile(self._stop_u, (o.N, 1))
        X = np.tile(x0, (o.N + 1, 1))
        return SolveResult(False, reason, U, X, fallback="stop")
