"""One robot's closing account: what its stages counted (the ``Stats`` record's counters)."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Counters"]


@dataclass
class Counters:
    """Counts of one robot's run; each stage adds to the fields of its own work."""

    received: int = 0
    """Peer envelopes admitted by the trust stage (before faults)."""
    dropped_by_faults: int = 0
    partitioned: int = 0
    out_of_range: int = 0
    """Released envelopes from beyond the communication range (Def. 10)."""
    delivered: int = 0
    """Peer messages handed to the controller."""
    rejected: int = 0
    controller_errors: int = 0
    steps: int = 0
    extra: dict = field(default_factory=dict)
    """Further counts by name (``overheard``, ``watchdog_stops``, the safety filter's ...)."""

    def add(self, name: str, n: int = 1) -> None:
        """Add ``n`` to the extra count ``name``."""
        self.extra[name] = self.extra.get(name, 0) + n

    def as_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "extra"}
        d.update(self.extra)
        return d
