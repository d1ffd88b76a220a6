"""Parameters of formation switching on a path (E6.6): the Sec. 5.5 gains, the robot's slots
and the switch schedule; a plain dataclass."""

from __future__ import annotations

from dataclasses import dataclass

from copath.config import require

from ..consensus.config import ConsensusConfig, ConsensusGains

__all__ = ["FormationSwitchingConfig"]


@dataclass(frozen=True)
class FormationSwitchingConfig(ConsensusGains):
    """Parameters of E6.6: the Sec. 5.5 gains, this robot's slots and the switch schedule."""

    slots: tuple[tuple[float, float], ...] = ()
    """(s_di, q_i) of this robot in each formation of the sequence [m]: along-track offset
    (positive ahead) and lateral offset (positive to the left of the path)."""
    switch_at: tuple[float, ...] = ()
    """Formation coordinate xi [m] at which the switch to formation k+1 begins (one entry
    per switch, increasing)."""
    transition_m: float = 2.0
    """Length of a transition in the robot's own path coordinate [m]."""
    k_r: float = 0.2
    """Repulsion gain of (6.12)."""
    R_max: float = 0.4
    """Influence distance of the repulsive field [m]."""
    F_max: float = 1.0
    """Clip of the reference displacement [m] (the reference must stay near the path)."""
    along: float = 2.0
    """Along-track share of the repulsion: the robot ahead on the path (ties: the higher
    index) has its reference pushed forward, the other one back, so robots whose slots
    cross sideways pass one behind the other instead of meeting head-on (the standstill
    of Sec. 6.2.2 when robot, obstacle and target are aligned)."""
    arrive_tol: float = 0.05
    """After a transition the robot counts as switching until it is this close to its
    new slot [m]."""
    repel_always: bool = False
    """Shape the reference outside transitions too (the text: during transitions)."""
    s0: float | None = None
    """Initial path coordinate [m]; default: projection of the first pose."""
    stale_after_s: float = 2.0
    """Neighbour information older than this is ignored [s]."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(len(self.slots) >= 1, "slots", self.slots, "need (s_d, q) for at least one formation")
        require(len(self.switch_at) == len(self.slots) - 1, "switch_at", self.switch_at,
                f"need one entry per switch ({len(self.slots) - 1} for {len(self.slots)} slots)")
        require(all(b > a for a, b in zip(self.switch_at, self.switch_at[1:])), "switch_at", self.switch_at,
                "must increase")
        require(self.transition_m > 0, "transition_m", self.transition_m, "must be > 0")
        for k in ("k_r", "R_max", "F_max", "stale_after_s", "arrive_tol"):
            require(getattr(self, k) > 0, k, getattr(self, k), "must be > 0")

    def consensus(self) -> ConsensusConfig:
        """The Sec. 5.5 gains as the consensus module's config."""
        return ConsensusConfig(**self.gains())
