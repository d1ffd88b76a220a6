"""The scenario's ``[metrics]`` table: how a run is scored (the definitions are in
docs/metrics.md)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from .config import from_table, require

__all__ = ["MetricsConfig", "parse_metrics"]


@dataclass(frozen=True)
class MetricsConfig:
    """Scoring options of a scenario."""

    coordination_pairs: str = "all"
    """Robot pairs scored for coordination: ``"all"`` pairs or the graph's ``"edges"``."""
    formation_tolerance_m: float = 0.05
    """A formation change is over when every robot is this close to its new slot [m]."""
    task_tolerance_m: float | None = None
    """A Chapter 6 target counts as occupied within this distance [m]; default: the
    controllers' ``arrive_tol``."""

    def __post_init__(self) -> None:
        require(self.coordination_pairs in ("all", "edges"), "metrics.coordination_pairs", self.coordination_pairs,
                "allowed: 'all', 'edges'")
        require(self.formation_tolerance_m > 0, "metrics.formation_tolerance_m", self.formation_tolerance_m,
                "must be > 0")
        require(self.task_tolerance_m is None or self.task_tolerance_m > 0, "metrics.task_tolerance_m",
                self.task_tolerance_m, "must be > 0")


def parse_metrics(table: Mapping[str, Any] | None) -> dict[str, Any]:
    """The ``[metrics]`` table, validated (ConfigError naming the key), as given."""
    from_table(MetricsConfig, table, "metrics")
    return dict(table or {})
