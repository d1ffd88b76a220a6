"""Parameters of the omni NMPC controllers (Sec. 4.2) and the gain condition (4.10) they are
checked against: plain dataclasses, readable without CasADi."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from copath.config import ConfigError, require
from copath.solver_fields import SolverFields

__all__ = ["OmniNMPCFields", "OmniPFConfig", "OmniTTConfig", "gain_condition_margins", "check_gain_conditions"]


def gain_condition_margins(Q, R, gains, P=None) -> np.ndarray:
    """Left sides of (4.10): p_ii k_i - q_ii - k_i^2 r_ii (P = I gives (4.10) exactly).

    The stability condition (4.9) holds for every terminal state when all are >= 0
    (the drift matrix of (4.4) is skew-symmetric, docs/reference/derivations.md, terminal gains (D7)).
    """
    Q, R, k = (np.asarray(a, float).reshape(3) for a in (Q, R, gains))
    P = np.ones(3) if P is None else np.asarray(P, float).reshape(3)
    return P * k - Q - k**2 * R


def check_gain_conditions(Q, R, gains, P=None, where: str = "controller") -> None:
    """Raise ConfigError unless the terminal gains satisfy (4.10)."""
    m = gain_condition_margins(Q, R, gains, P)
    for name, mi, q, r, k in zip(("alpha", "beta", "gamma"), m, Q, R, gains):
        if mi < -1e-12:
            raise ConfigError(
                f"{where}.{name} = {k!r} is not allowed; (4.10) needs {name} - q - {name}^2 r >= 0 "
                f"(q = {q}, r = {r}): margin {mi:.4g}"
            )


@dataclass(frozen=True)
class OmniNMPCFields(SolverFields):
    horizon: int = 3
    """Prediction horizon N_p = N_c (E4.1/E4.2: 3)."""
    Q: tuple[float, float, float] = (0.5, 0.5, 0.5)
    """Diagonal of Q in (4.6) (E4.1/E4.2)."""
    R: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """Diagonal of R in (4.6) (E4.1/E4.2)."""
    alpha: float = 2.0
    """Terminal gain on x_e, (4.8)."""
    beta: float = 2.0
    """Terminal gain on y_e, (4.8)."""
    gamma: float = 2.0
    """Terminal gain on theta_e, (4.8)."""
    terminal: bool = True
    """Use the terminal penalty (4.7) and the soft terminal region (4.11)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.horizon >= 1, "horizon", self.horizon, "must be >= 1")
        require(all(q >= 0 for q in self.Q), "Q", self.Q, "entries must be >= 0")
        require(all(r > 0 for r in self.R), "R", self.R, "entries must be > 0")
        for k in ("alpha", "beta", "gamma"):
            require(getattr(self, k) >= 0, k, getattr(self, k), "must be >= 0 (4.8)")

    @property
    def gains(self) -> tuple[float, float, float]:
        return (self.alpha, self.beta, self.gamma)


@dataclass(frozen=True)
class OmniPFConfig(OmniNMPCFields):
    """Path-following NMPC (Sec. 4.2; published values of E4.2)."""

    u_R: float = 1.0
    """Desired translational speed u_R [m/s] (E4.2: 1.0)."""
    speed_weight: float = 1.0
    """Weight of the speed residual (|V| - u_R)^2 (chosen: wheel-speed inputs free |V|)."""
    sdot_max: float = 2.0
    """Upper bound of s-dot [m/s] (not given in the text; chosen > u_R)."""
    heading: str = "tangent"
    """Desired heading: ``tangent`` (E4.2) or ``fixed``."""
    heading_angle: float = 0.0
    """Desired heading for ``fixed`` [rad]."""
    s0: float | None = None
    """Initial virtual-vehicle position [m]; default: the path point nearest the robot."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.u_R > 0, "u_R", self.u_R, "must be > 0")
        require(self.sdot_max >= self.u_R, "sdot_max", self.sdot_max, "must be >= u_R")
        require(self.speed_weight >= 0, "speed_weight", self.speed_weight, "must be >= 0")
        require(self.heading in ("tangent", "fixed"), "heading", self.heading, "allowed: tangent, fixed")


@dataclass(frozen=True)
class OmniTTConfig(OmniNMPCFields):
    """Trajectory-tracking NMPC (Sec. 4.2; published values of E4.1)."""

    trajectory: str = "eight"
    """``eight``: time-parameterised (4.14); ``path``: the robot's path at ``speed``."""
    ax: float = 1.8
    """Eight curve x amplitude [m] (4.14)."""
    ay: float = 1.2
    """Eight curve y amplitude [m] (4.14)."""
    rate: float = 0.4
    """Eight curve rate: x = ax sin(rate t) [rad/s] (4.14)."""
    t0: float = 0.0
    """Time at which the reference starts [s]."""
    speed: float = 0.5
    """Reference speed for ``trajectory = "path"`` [m/s]."""
    s0: float = 0.0
    """Reference start on the path for ``trajectory = "path"`` [m]."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.trajectory in ("eight", "path"), "trajectory", self.trajectory, "allowed: eight, path")
        require(self.rate > 0, "rate", self.rate, "must be > 0")
