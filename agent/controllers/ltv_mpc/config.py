"""Parameters of the Sec. 4.3 LTV-MPC QP (published values of E4.3): a plain dataclass,
readable without CasADi."""

from __future__ import annotations

from dataclasses import dataclass

from copath.config import require

__all__ = ["LTVConfig", "QP_CONICS"]


QP_CONICS = ("daqp", "qrqp", "osqp", "qpoases")


@dataclass(frozen=True)
class LTVConfig:
    """LTV-MPC QP (Sec. 4.3; published values of E4.3)."""

    horizon: int = 3
    """Prediction horizon N (E4.3: 3; recommended 3-5). N >= 2: with N = 1 the input
    reaches y_e only one step later (docs/journal/measurements.md, closed-loop observations from the prototypes (W14))."""
    Q: tuple[float, float, float, float] = (300.0, 300.0, 7.0, 70.0)
    """Weights on (x_e, y_e, alpha_e, theta_e) (E4.3)."""
    R: tuple[float, float, float] = (1.0, 0.001, 3.0)
    """Weights on (u_1, u_2, u_3) (E4.3)."""
    u_R: float = 1.0
    """Desired forward speed [m/s] (E4.3)."""
    u_max: float = 1.315
    """Maximum forward speed [m/s] (E4.3; with omega_max = 3 rad/s on r(omega))."""
    omega_max: float = 3.0
    """Maximum rotation speed [rad/s] (E4.3)."""
    mu: float = 0.18
    """Friction coefficient of (4.26) (E4.3)."""
    g: float = 9.81
    """Gravity [m/s^2] (E4.3)."""
    heading: str = "fixed"
    """Desired body heading: ``fixed`` (theta_b, omega_b = 0 as in E4.3) or ``tangent``."""
    theta_b: float = 0.0
    """Fixed desired heading [rad] (E4.3: 0)."""
    phi_max: float = 10.0
    """Bound on the motion-direction curvature |Phi| [1/m] for u_2
    (docs/reference/ambiguities.md, no bound on the second virtual input (A31); not given in the text, chosen loose)."""
    qp_solver: str = "daqp"
    """QP solver (daqp, qrqp, osqp, qpoases)."""
    jit: bool = True
    """JIT-compile the condensing Function."""
    s0: float | None = None
    """Initial virtual-vehicle position [m]; default: nearest path point."""

    def __post_init__(self) -> None:
        require(self.horizon >= 2, "horizon", self.horizon, "must be >= 2 (N = 1 cannot act on y_e)")
        require(all(q >= 0 for q in self.Q), "Q", self.Q, "entries must be >= 0")
        require(all(r > 0 for r in self.R), "R", self.R, "entries must be > 0 (H positive definite)")
        require(self.u_R > 0, "u_R", self.u_R, "must be > 0")
        require(self.u_max > 0, "u_max", self.u_max, "must be > 0")
        require(self.omega_max > 0, "omega_max", self.omega_max, "must be > 0")
        require(self.mu > 0 and self.g > 0, "mu", self.mu, "mu and g must be > 0")
        require(self.heading in ("fixed", "tangent"), "heading", self.heading, "allowed: fixed, tangent")
        require(self.phi_max > 0, "phi_max", self.phi_max, "must be > 0")
        require(self.qp_solver in QP_CONICS, "qp_solver", self.qp_solver, f"allowed: {', '.join(QP_CONICS)}")
