"""Parameters of the Sec. 5.3 leader and followers (E5.1 values as defaults): plain
dataclasses, readable without CasADi."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from copath.config import require

from ..omni_nmpc.config import OmniNMPCFields, OmniPFConfig
from .formation import FormationSchedule

__all__ = ["LeaderConfig", "FollowerConfig"]


@dataclass(frozen=True)
class _FormationFields:
    """Formation keys shared by the leader and the followers (one [controller] table)."""

    leader: str = ""
    """Name of the leader robot (required by followers)."""
    formations: Mapping[str, Any] | None = None
    """{name = {follower = [p, q], ...}, ...}: curvilinear offsets from C [m] (Fig. 5.2)."""
    initial_formation: str = ""
    """Formation at the start (default: the first one listed)."""
    schedule: tuple[Mapping[str, Any], ...] = ()
    """Formation changes [{formation, s_start, s_end}] on the leader's path coordinate [m]."""
    safety_distance: float = 0.5
    """Planned slots of two robots may not come closer than this [m] (checked at build)."""
    formation_feedback: bool = True
    """Followers report their tracking error and the leader slows down (beyond the text)."""

    def formation_schedule(self, where: str) -> FormationSchedule:
        require(bool(self.formations), f"{where}.formations", self.formations,
                "a leader-following team needs at least one formation")
        initial = self.initial_formation or next(iter(self.formations))
        return FormationSchedule.from_params(self.formations, initial, list(self.schedule), where)


@dataclass(frozen=True)
class LeaderConfig(_FormationFields, OmniPFConfig):
    """The leader of Sec. 5.3: path-following NMPC (5.6)-(5.7) with E5.1 values as defaults."""

    horizon: int = 3
    """N_p = 3 (E5.1)."""
    Q: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Q = I_3 (E5.1)."""
    R: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """R = 0.1 I_3 (E5.1)."""
    u_R: float = 0.4
    """Leader reference speed u_R (E5.1: 0.4 m/s); omega_R = kappa_R u_R."""
    sdot_max: float = 1.0
    """Upper bound of s-dot [m/s] (chosen: 2.5 u_R)."""
    feedback_error_low: float = 0.10
    """Formation feedback: full speed while every follower's error is below this [m] (chosen)."""
    feedback_error_high: float = 0.40
    """Formation feedback: slowest at this follower error [m] (chosen)."""
    feedback_min_factor: float = 0.25
    """Formation feedback: lowest fraction of u_R (chosen)."""
    feedback_rate: float = 1.0
    """Formation feedback: largest change of the speed fraction per second [1/s] (chosen)."""
    feedback_stale_s: float = 1.0
    """Follower reports older than this are ignored [s] (chosen)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(0 <= self.feedback_error_low < self.feedback_error_high, "feedback_error_high",
                self.feedback_error_high, "must exceed feedback_error_low >= 0")
        require(0 < self.feedback_min_factor <= 1, "feedback_min_factor", self.feedback_min_factor, "must be in (0, 1]")
        require(self.feedback_rate > 0, "feedback_rate", self.feedback_rate, "must be > 0")
        require(self.feedback_stale_s > 0, "feedback_stale_s", self.feedback_stale_s, "must be > 0")


@dataclass(frozen=True)
class FollowerConfig(_FormationFields, OmniNMPCFields):
    """A follower of Sec. 5.3: trajectory-tracking NMPC (5.8) with E5.1 values as defaults."""

    horizon: int = 3
    """N_p = 3 (E5.1)."""
    Q: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Q = I_3 (E5.1)."""
    R: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """R = 0.1 I_3 (E5.1)."""
    plan_timeout_s: float = 2.0
    """The leader's progress is extrapolated for at most this long without a new plan [s] (chosen)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.plan_timeout_s > 0, "plan_timeout_s", self.plan_timeout_s, "must be > 0")
