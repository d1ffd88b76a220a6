"""The scenario's ``[metrics]`` table: how a run is scored (the definitions are in
docs/reference/metrics.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
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
    path_offsets: dict[str, float] | None = None
    """The team's desired geometry, declared for any controller (a user's own too):
    robot -> desired along-path offset s_d,i [m]. Coordination is scored on
    xi_i = s_i - s_d,i from the true poses, as for the law (5.39)-(5.42); given, it takes
    precedence over the geometry of a built-in controller family."""
    lateral_offsets: dict[str, float] | None = None
    """With ``path_offsets``: robot -> lateral offset q_i of its slot from its path [m]
    (positive to the left, (5.10)); default 0."""

    def __post_init__(self) -> None:
        require(self.coordination_pairs in ("all", "edges"), "metrics.coordination_pairs", self.coordination_pairs,
                "allowed: 'all', 'edges'")
        require(self.formation_tolerance_m > 0, "metrics.formation_tolerance_m", self.formation_tolerance_m,
                "must be > 0")
        require(self.task_tolerance_m is None or self.task_tolerance_m > 0, "metrics.task_tolerance_m",
                self.task_tolerance_m, "must be > 0")
        for key in ("path_offsets", "lateral_offsets"):
            table = getattr(self, key)
            require(table is None or (isinstance(table, dict) and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in table.values())),
                f"metrics.{key}", table, "expected a table robot = offset in metres, e.g. { r1 = 0.0, r2 = 0.5 }")
        require(self.lateral_offsets is None or self.path_offsets is not None, "metrics.lateral_offsets",
                self.lateral_offsets, "needs metrics.path_offsets")


def parse_metrics(table: Mapping[str, Any] | None, robots: tuple[str, ...] = ()) -> dict[str, Any]:
    """The ``[metrics]`` table, validated (ConfigError naming the key), with every option
    present (the defaults of :class:`MetricsConfig` fill what the table leaves out), so
    readers index it and no default is written twice.

    With ``robots``, the offset tables must name exactly those robots (each with a path)."""
    cfg = from_table(MetricsConfig, table, "metrics")
    if robots and cfg.path_offsets is not None:
        require(set(cfg.path_offsets) == set(robots), "metrics.path_offsets", cfg.path_offsets,
                f"must give an offset for each robot: {', '.join(robots)}")
    if robots and cfg.lateral_offsets is not None:
        require(set(cfg.lateral_offsets) <= set(robots), "metrics.lateral_offsets", cfg.lateral_offsets,
                f"must name robots of this scenario: {', '.join(robots)}")
    return {f.name: getattr(cfg, f.name) for f in fields(cfg)}
