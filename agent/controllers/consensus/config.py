"""Parameters of the Sec. 5.5 consensus law ((5.39)-(5.42)): plain dataclasses."""

from __future__ import annotations

import math
from dataclasses import dataclass

from copath.config import require

__all__ = ["ConsensusGains", "ConsensusConfig"]


@dataclass(frozen=True)
class ConsensusGains:
    """Gains of the Sec. 5.5 law (published values of E5.4 as defaults); shared by every
    controller built on (5.39)-(5.42)."""

    v0: float = 0.2
    """Group speed v_0 = v_di for every robot [m/s] (5.35)."""
    k1: float = 5.0
    """Heading weight 1/k1 in V (5.36) and k1 in (5.40)."""
    k2: float = 0.5
    """Coordination (position) consensus gain of (5.42)."""
    k3: float = 0.2
    """Speed consensus gain of (5.42)."""
    k4: float = 0.25
    """Along-track gain of (5.39)."""
    k5: float = 1.0
    """Heading gain of (5.40)."""
    k6: float = 0.2
    """Speed-tracking gain of (5.42)."""
    theta_a: float = math.pi / 4
    """Transient heading amplitude theta_a of delta(y_e) [rad]."""
    sdot_max: float = 0.5
    """Upper bound of the virtual-vehicle speed [m/s] (chosen: the unicycle's v_max)."""
    predict_acceleration: bool = True
    """Predict a neighbour over its message age with its received rate and acceleration
    (else with its rate only) (delay-robust coupling, docs/reference/envelope.md)."""
    age_nominal_s: float = 0.6
    """Age of information up to which the coupling of (5.42) runs at full speed; beyond it
    k2 and k3 are scaled by g^2 and g, g = age_nominal_s / age (docs/reference/envelope.md) [s]."""

    def __post_init__(self) -> None:
        for k in ("k1", "k2", "k3", "k4", "k5", "k6"):
            require(getattr(self, k) > 0, k, getattr(self, k), "gains of (5.39)-(5.42) must be > 0")
        require(self.v0 >= 0, "v0", self.v0, "must be >= 0")
        require(self.sdot_max > 0, "sdot_max", self.sdot_max, "must be > 0")
        require(0 < self.theta_a < math.pi / 2, "theta_a", self.theta_a, "must be in (0, pi/2)")
        require(self.age_nominal_s > 0, "age_nominal_s", self.age_nominal_s, "must be > 0")

    def gains(self) -> dict:
        """The gain fields only (to build another gains-based config)."""
        return {f: getattr(self, f) for f in ConsensusGains.__dataclass_fields__}


@dataclass(frozen=True)
class ConsensusConfig(ConsensusGains):
    """Parameters of one robot of the Sec. 5.5 team."""

    s_d: float = 0.0
    """This robot's desired coordination offset s_di [m]; s_dij = s_di - s_dj."""
    s0: float | None = None
    """Initial path coordinate [m]; default: projection of the first pose onto the path."""
    extrapolate: bool = True
    """Compensate neighbour messages for their age: s_j + sdot_j * age (docs/journal/measurements.md, convergence times and delay tolerance (W15)),
    plus sddot_j * age^2 / 2 when the message carries the sender's acceleration (docs/reference/envelope.md)."""
    stale_after_s: float = 2.0
    """Neighbour information older than this is ignored [s]."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.stale_after_s > 0, "stale_after_s", self.stale_after_s, "must be > 0")
