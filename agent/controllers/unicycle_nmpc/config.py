"""Parameters of the Sec. 4.4 unicycle NMPC (defaults: the published values (4.55) of E4.4):
a plain dataclass, readable without CasADi."""

from __future__ import annotations

from dataclasses import dataclass

from copath.config import require
from copath.solver_fields import SolverFields

__all__ = ["UnicycleNMPCConfig", "MODES"]


MODES = ("path_following", "trajectory_tracking", "combined")


@dataclass(frozen=True)
class UnicycleNMPCConfig(SolverFields):
    """Sec. 4.4 NMPC; defaults are the published values (4.55) of E4.4."""

    mode: str = "combined"
    """``path_following`` (K_t = 0), ``trajectory_tracking`` or ``combined`` (E4.4)."""
    horizon: int = 3
    """N_p (4.55)."""
    Q: tuple[float, float, float, float] = (0.2, 2.0, 0.01, 0.01)
    """Stage weights on (x_e, y_e, theta_e, eta_e) (4.55)."""
    R: tuple[float, float, float] = (1e-4, 1e-4, 1e-4)
    """Weights on u_e (4.55)."""
    P: tuple[float, float, float, float] = (1.0, 1.0, 0.015, 0.015)
    """Terminal penalty diagonal (4.55)."""
    K_t: tuple[float, float, float, float] = (1.0, 2.0, 0.01, 0.01)
    """Time-penalty weights (4.55) on (longitudinal, lateral, heading, speed)."""
    K_obs: float = 1.5
    """Obstacle cost gain (4.55); 0 disables F_obs."""
    c1: float = 0.01
    """Bearing decay of (4.54) (4.55)."""
    c2: float = 10.0
    """Distance decay of (4.54) [1/m] (4.55)."""
    alpha: float = 2.5
    """Terminal gain on x_e (4.55)."""
    beta: float = 1.0
    """Terminal gain on theta_e (4.55)."""
    gamma: float = 1.0
    """Terminal gain on eta_e (4.55)."""
    v_d: float = 0.5
    """Desired speed [m/s] (E4.4: 0.5; E4.7: 0.2)."""
    v_max: float = 2.0
    """|v| bound [m/s] (E4.4)."""
    omega_max: float = 2.0
    """|omega| bound [rad/s] (E4.4)."""
    a_max: float = 2.0
    """|a| bound [m/s^2] (E4.4)."""
    sdot_max: float = 1.0
    """Upper bound of s-dot [m/s] (not given; chosen 2 v_d)."""
    s0: float = 0.0
    """s(0) [m] (4.55) and the time reference's start."""
    v0: float = 0.0
    """Initial speed [m/s] (chosen: starting at rest)."""
    terminal: bool = True
    """Terminal penalty and soft terminal region; false = real-robot variant (E4.7)."""
    predict_obstacles: bool = True
    """Predict detected points with a velocity estimated from consecutive scans."""
    slack_weight: float = 1.0
    """Linear penalty of the soft terminal region (4.49)/(4.52) (chosen: of the order of
    Q; the region is unreachable within T_p far from the path, docs/reference/ambiguities.md, missing sine in the terminal region (A8))."""
    slack_weight_quadratic: float = 1.0
    """Quadratic penalty of the soft terminal region (chosen)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.mode in MODES, "mode", self.mode, f"allowed: {', '.join(MODES)}")
        require(self.horizon >= 1, "horizon", self.horizon, "must be >= 1")
        require(all(q >= 0 for q in self.Q), "Q", self.Q, "entries must be >= 0")
        require(all(r > 0 for r in self.R), "R", self.R, "entries must be > 0")
        require(all(p >= 0 for p in self.P), "P", self.P, "entries must be >= 0")
        require(all(k >= 0 for k in self.K_t), "K_t", self.K_t, "entries must be >= 0")
        for k in ("K_obs", "c1", "c2"):
            require(getattr(self, k) >= 0, k, getattr(self, k), "must be >= 0")
        for k in ("alpha", "beta", "gamma", "v_d", "v_max", "omega_max", "a_max"):
            require(getattr(self, k) > 0, k, getattr(self, k), "must be > 0")
        require(self.sdot_max >= self.v_d, "sdot_max", self.sdot_max, "must be >= v_d")

    @property
    def gains(self) -> tuple[float, float, float]:
        return (self.alpha, self.beta, self.gamma)
