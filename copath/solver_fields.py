"""The solver keys of an MPC controller's parameters, without the solver.

:class:`SolverFields` (inherit it in a controller config) and :class:`SolverConfig` are
plain dataclasses: a controller's config, and so its team geometry and its scenario
checks, can be read without importing CasADi. :mod:`copath.mpc` re-exports both and does
the solving.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .config import require

__all__ = ["SolverConfig", "SolverFields", "SOLVER_METHODS", "QP_SOLVERS", "HESSIANS"]

SOLVER_METHODS = ("sqp", "ipopt")
QP_SOLVERS = ("qrqp", "osqp", "qpoases")
HESSIANS = ("gauss-newton", "exact")


@dataclass(frozen=True)
class SolverConfig:
    """How to solve an :class:`OCP` (defaults: the fastest prototype of docs/journal/measurements.md, NMPC solver choice (W11)-M12)."""

    method: str = "sqp"
    """``sqp`` (sqpmethod) or ``ipopt``."""
    qp_solver: str = "qrqp"
    """QP solver of ``sqp``: qrqp, osqp or qpoases."""
    hessian: str = "gauss-newton"
    """``gauss-newton`` (2 J_r^T J_r of the residuals) or ``exact``."""
    max_iter: int = 20
    """Maximum SQP (or interior point) iterations per solve."""
    tol: float = 1e-6
    """Primal and dual tolerance of the NLP solver."""
    feas_tol: float = 5e-3
    """A returned plan whose constraint violation exceeds this counts as failed."""
    jit: bool = True
    """JIT-compile the NLP functions with the C compiler when one works."""
    jit_flags: tuple[str, ...] = ("-O2",)
    """Compiler flags of the JIT build."""
    slack_weight: float = 1e3
    """Linear penalty per unit slack of soft constraints (exact penalty)."""
    slack_weight_quadratic: float = 1e2
    """Quadratic penalty per unit slack squared of soft constraints."""
    max_solve_s: float | None = field(default=None, repr=False)
    """Wall-time cap of one solve, its retry included [s]; None: no cap. A solve that
    reaches it stops at its next iteration and the fallback policy applies
    (docs/reference/controllers.md, "Solve time cap"). Left out of the repr, which keys the
    cache of JIT-compiled solvers: a cached solver carries no cap, so the cap is not part of
    its identity (and the keys of solvers built before the cap stay valid)."""

    def __post_init__(self) -> None:
        require(self.max_solve_s is None or self.max_solve_s > 0, "solver.max_solve_s", self.max_solve_s,
                "must be > 0 (or None: no cap)")
        require(self.method in SOLVER_METHODS, "solver.method", self.method, f"allowed: {', '.join(SOLVER_METHODS)}")
        require(self.qp_solver in QP_SOLVERS, "solver.qp_solver", self.qp_solver, f"allowed: {', '.join(QP_SOLVERS)}")
        require(self.hessian in HESSIANS, "solver.hessian", self.hessian, f"allowed: {', '.join(HESSIANS)}")
        require(self.max_iter >= 1, "solver.max_iter", self.max_iter, "must be >= 1")
        require(self.tol > 0, "solver.tol", self.tol, "must be > 0")
        require(self.feas_tol > 0, "solver.feas_tol", self.feas_tol, "must be > 0")
        require(self.slack_weight >= 0, "solver.slack_weight", self.slack_weight, "must be >= 0")
        require(self.slack_weight_quadratic >= 0, "solver.slack_weight_quadratic",
                self.slack_weight_quadratic, "must be >= 0")


@dataclass(frozen=True)
class SolverFields:
    """Solver keys shared by every MPC controller config (inherit from this).

    A controller config ``class MyConfig(SolverFields)`` accepts these keys in its
    ``[controller]`` table and gets its :class:`SolverConfig` from
    :meth:`solver_config`.
    """

    solver: str = "sqp"
    """NLP method: ``sqp`` or ``ipopt``."""
    qp_solver: str = "qrqp"
    """QP solver of ``sqp``: qrqp, osqp or qpoases."""
    hessian: str = "gauss-newton"
    """``gauss-newton`` or ``exact``."""
    max_iter: int = 20
    """NLP iterations per solve."""
    jit: bool = True
    """JIT-compile the NLP with the C compiler when available."""
    slack_weight: float = 1e3
    """Linear penalty per unit slack of soft (terminal) constraints."""
    slack_weight_quadratic: float = 1e2
    """Quadratic penalty per unit slack squared of soft (terminal) constraints."""
    tol: float = 1e-4
    """Primal and dual tolerance of the NLP solver."""

    def __post_init__(self) -> None:
        self.solver_config()  # validates

    def solver_config(self) -> SolverConfig:
        return SolverConfig(method=self.solver, qp_solver=self.qp_solver, hessian=self.hessian,
                            max_iter=self.max_iter, jit=self.jit, slack_weight=self.slack_weight,
                            slack_weight_quadratic=self.slack_weight_quadratic, tol=self.tol)
