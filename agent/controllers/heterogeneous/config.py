"""Parameters of the Sec. 5.5.5 heterogeneous team (an omni leader commanding unicycle
followers, E5.7): plain dataclasses, readable without CasADi."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from copath.config import require

from ..omni_nmpc.config import OmniPFConfig

__all__ = ["HeteroLeaderConfig", "HeteroFollowerConfig"]


@dataclass(frozen=True)
class HeteroLeaderConfig(OmniPFConfig):
    """The omni leader of E5.7 (leader NMPC values of E5.1 as defaults, chosen)."""

    horizon: int = 3
    """N_p (chosen as E5.1)."""
    Q: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Q (chosen as E5.1)."""
    R: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """R (chosen as E5.1)."""
    u_R: float = 0.2
    """Leader speed (E5.7: 0.2 m/s)."""
    sdot_max: float = 0.6
    """Upper bound of s-dot [m/s] (chosen)."""
    followers: Mapping[str, Any] | None = None
    """{follower = [s_d, q], ...}: distance behind the leader along its path and lateral
    offset, left positive [m] (E5.7: R2 at 0.8 m, +0.2 m; R3 at 0.8 + 0.5 m, -0.2 m)."""
    k1: float = 5.0
    """Gain k1 of (5.40) (chosen: E5.4 gains)."""
    k4: float = 0.25
    """Gain k4 of (5.39) (E5.4)."""
    k5: float = 1.0
    """Gain k5 of (5.40) (E5.4)."""
    theta_a: float = math.pi / 4
    """Transient heading amplitude of delta(y_e) (E5.4)."""
    report_stale_s: float = 1.0
    """No command is sent to a follower whose newest report is older than this [s] (chosen)."""
    latency_s: float | None = None
    """Expected command latency for the prediction [s]; default: the newest report's age."""
    avoidance: bool = True
    """Brake robots heading towards each other (beyond the text)."""
    stop_margin: float = 0.1
    """Stop when the footprints are this close [m] (chosen)."""
    slow_distance: float = 0.3
    """Start braking this far beyond the stop distance [m] (chosen)."""
    avoid_turn_rate: float = 1.0
    """Extra yaw rate turning a blocked follower away from the blocking robot [rad/s] (chosen)."""
    follower_radius: float = 0.06
    """Footprint radius of the followers [m] (c't-Bot: 12 cm diameter)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        ok = isinstance(self.followers, Mapping) and len(self.followers) > 0 and all(
            isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v)
            for v in self.followers.values())
        require(ok, "followers", self.followers, "expected {follower = [s_d, q], ...} in metres")
        for k in ("k1", "k4", "k5"):
            require(getattr(self, k) > 0, k, getattr(self, k), "gains of (5.39)-(5.40) must be > 0")
        require(0 < self.theta_a < math.pi / 2, "theta_a", self.theta_a, "must be in (0, pi/2)")
        require(self.report_stale_s > 0, "report_stale_s", self.report_stale_s, "must be > 0")
        require(self.latency_s is None or self.latency_s >= 0, "latency_s", self.latency_s, "must be >= 0")
        require(self.stop_margin >= 0, "stop_margin", self.stop_margin, "must be >= 0")
        require(self.slow_distance > 0, "slow_distance", self.slow_distance, "must be > 0")
        require(self.follower_radius > 0, "follower_radius", self.follower_radius, "must be > 0")


@dataclass(frozen=True)
class HeteroFollowerConfig:
    """A unicycle follower of E5.7: applies the leader's commands."""

    leader: str = ""
    """Name of the leader robot."""
    cmd_timeout_s: float = 0.5
    """Stop when the newest command is older than this [s] (chosen)."""

    def __post_init__(self) -> None:
        require(self.cmd_timeout_s > 0, "cmd_timeout_s", self.cmd_timeout_s, "must be > 0")
