"""Parameters of the Sec. 5.4 distributed MPC (published E5.2 values as defaults): a plain
dataclass, readable without CasADi."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from copath.config import require
from copath.solver_fields import SolverFields

__all__ = ["DMPCConfig"]


@dataclass(frozen=True)
class DMPCConfig(SolverFields):
    """Parameters of the Sec. 5.4 controller (published E5.2 values as defaults)."""

    hessian: str = "exact"
    """Exact Lagrangian Hessian (chosen: with the hard wheel and compatibility constraints
    active, e.g. a neighbour far ahead, the Gauss-Newton SQP stalled; same solve time)."""
    jit: bool = False
    """JIT-compile the NLP (chosen off: it adds seconds to tens of seconds of build per
    robot and measured no faster at this size, solve p50 about 1 ms either way)."""

    base_speed: float = 0.4
    """Desired forward speed u_o on the base path, sigma_B of (5.28) [m/s]."""
    q: float = 0.0
    """Constant lateral offset q_i of the reference point, left positive [m] (5.10)."""
    formation: Mapping[str, float] | None = None
    """Desired progress offsets in base coordinates {robot: psi_d}; p_ij = psi_d_j - psi_d_i
    so that psi_i + p_ij = psi_j (Sec. 5.4.1). Default: all zero."""
    base_path: str | None = None
    """Name of the base path Gamma_B for morphing (5.28)-(5.29); default the own path."""
    horizon: int = 10
    """N_p = T_p / delta (chosen: the text's 3 steps at 0.12 s span 0.36 s; 10 x 0.05 s = 0.5 s)."""
    Q: tuple[float, float, float, float, float] = (0.05, 0.05, 1e-4, 1e-4, 0.05)
    """State weights on (x_e, y_e, phi, theta_e, eta), E5.2."""
    R: tuple[float, float, float, float] = (1e-5, 1e-5, 1e-5, 5e-6)
    """Input weights on (u1, u2, u3, u4), E5.2."""
    P: tuple[float, float, float, float, float] = (0.12, 0.12, 0.02, 0.02, 0.12)
    """Terminal penalty V = 1/2 x^T P x (5.19), E5.2."""
    k_terminal: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 0.5)
    """Terminal controller gains k1..k4 of (5.21), E5.2."""
    W: float = 0.05
    """Coupling weight W of (5.17), E5.2."""
    W_terminal: float = 0.05
    """Soft terminal coordination penalty (docs/reference/ambiguities.md, the DMPC terminal region (A14); chosen equal to W)."""
    mu: float = 10.0
    """Compatibility constant mu: |s^p - s_hat| <= delta^2 mu (5.18), E5.2."""
    sdot_max: float = 1.0
    """Upper bound of the virtual-vehicle speed [m/s] (chosen: 2.5 u_o)."""
    phi_rate_max: float = 8.0
    """|u2| = |d phi / dt| bound [rad/s] (chosen)."""
    theta_rate_max: float = 4.0
    """|u3| = |omega - omega_r| bound [rad/s] (chosen)."""
    accel_max: float = 2.0
    """|u4| = |d eta / dt| bound [m/s^2] (chosen)."""
    stale_after_s: float = 1.5
    """Neighbour trajectories older than this are not used [s] (chosen)."""
    s0: float | None = None
    """Initial path coordinate [m]; default: projection of the first pose onto the path."""
    substeps: int = 1
    """RK4 steps per interval."""
    max_solve_periods: float = 4.0
    """Cap of one solve's wall time in a realtime run, in control periods; 0: no cap (chosen: a
    runtime choice, not the law's; docs/reference/controllers.md, "Solve time cap"). Lockstep
    runs are never capped: their results must not depend on the machine's speed."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.max_solve_periods >= 0, "max_solve_periods", self.max_solve_periods, "must be >= 0 (0: no cap)")
        require(self.base_speed > 0, "base_speed", self.base_speed, "must be > 0")
        require(self.horizon >= 2, "horizon", self.horizon, "must be >= 2 (the lateral error needs two steps)")
        for name, n in (("Q", 5), ("R", 4), ("P", 5), ("k_terminal", 4)):
            v = getattr(self, name)
            require(len(v) == n and all(x >= 0 for x in v), name, v, f"expected {n} numbers >= 0")
        for name in ("W", "W_terminal", "mu"):
            require(getattr(self, name) >= 0, name, getattr(self, name), "must be >= 0")
        for name in ("sdot_max", "phi_rate_max", "theta_rate_max", "accel_max", "stale_after_s"):
            require(getattr(self, name) > 0, name, getattr(self, name), "must be > 0")
        require(self.sdot_max > self.base_speed, "sdot_max", self.sdot_max, "must exceed base_speed")
        if self.formation is not None:
            ok = isinstance(self.formation, Mapping) and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in self.formation.values())
            require(ok, "formation", self.formation, "expected {robot = psi_d [m], ...}")
        require(self.substeps >= 1, "substeps", self.substeps, "must be >= 1")

    def offset(self, robot: str) -> float:
        """psi_d of ``robot`` (0 when the formation does not list it)."""
        return float((self.formation or {}).get(robot, 0.0))
