"""Scenario targets: the ``[targets]`` table and how a run's metrics are graded against it.

A target names a metric of ``metrics.json`` and a threshold, e.g.
``coordination_error_max_m = 0.1`` for the "coordination errors < 10 cm" of Sec. 5.5.4
(Fig. 5.25). Each targetable metric has a sense: an error, a count of violations or a
solve time must stay at or below its threshold; a separation, a clearance or a number of
completed tasks must reach it. A per-robot metric is graded on the worst robot. A metric
that is ``null`` in the run (not measured) misses its target, and so does a per-robot
metric that is ``null`` for any one robot (that robot is named): a robot without a figure
never lets the others' figures pass for the team.

A robot whose controller failed (``controller_errors`` > 0: ``step()`` raised or returned an
invalid command, and the robot stood still for that step) makes every target miss, naming
the robot: the figures of a run in which a controller failed do not show what the
controller can do (docs/reference/controllers.md, "When step() fails").

The grading reads only the metrics computed from the simulator's truth in the log; a
controller never grades itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

from .config import require

__all__ = ["TARGETS", "Target", "TargetResult", "parse_targets", "grade", "meets", "worst", "figure",
           "failed_robots"]

AT_MOST, AT_LEAST = "<=", ">="

TARGETS: dict[str, tuple[str, str]] = {
    # per robot (worst robot counts)
    "path_error_max_m": ("robots", AT_MOST),
    "path_error_rms_m": ("robots", AT_MOST),
    "heading_error_max_rad": ("robots", AT_MOST),
    "speed_error_rms_mps": ("robots", AT_MOST),
    "solve_ms_p50": ("robots", AT_MOST),
    "solve_ms_p99": ("robots", AT_MOST),
    "limit_violations": ("robots", AT_MOST),
    "missed_ticks": ("robots", AT_MOST),
    "wheel_speed_max_mps": ("robots", AT_MOST),
    "solver_failures": ("robots", AT_MOST),
    "path_progress_m": ("robots", AT_LEAST),
    "stalled_s": ("robots", AT_MOST),
    # fleet
    "coordination_error_max_m": ("fleet", AT_MOST),
    "coordination_error_rms_m": ("fleet", AT_MOST),
    "min_separation_m": ("fleet", AT_LEAST),
    "collisions": ("fleet", AT_MOST),
    "messages_dropped_by_faults": ("fleet", AT_MOST),
    "tasks_completed": ("fleet", AT_LEAST),
    "conflicts_resolved": ("fleet", AT_LEAST),
    "min_obstacle_clearance_m": ("fleet", AT_LEAST),
    "formation_error_max_m": ("fleet", AT_MOST),
}
"""Targetable metric keys of metrics.json: key -> (scope, sense)."""


@dataclass(frozen=True)
class Target:
    key: str
    """A key of :data:`TARGETS`."""
    threshold: float

    @property
    def scope(self) -> str:
        return TARGETS[self.key][0]

    @property
    def sense(self) -> str:
        return TARGETS[self.key][1]


@dataclass(frozen=True)
class TargetResult:
    target: Target
    value: float | None
    """The run's figure (worst robot for per-robot metrics), None if not measured."""
    worst: str | None
    """The robot that sets a per-robot figure, else None."""
    passed: bool
    reason: str | None = None
    """Why a target missed other than by its figure: a robot without the figure, or a robot
    whose controller failed."""


def parse_targets(table: Any) -> tuple[Target, ...]:
    """Validate a ``[targets]`` table: known metric keys, finite numeric thresholds."""
    if table is None:
        return ()
    require(isinstance(table, Mapping), "targets", table, "expected a table of metric key = threshold")
    out = []
    for key, value in table.items():
        require(key in TARGETS, f"targets.{key}", value, f"allowed metric keys: {', '.join(TARGETS)}")
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        require(ok, f"targets.{key}", value, "expected a finite number")
        out.append(Target(key, float(value)))
    return tuple(out)


def meets(key: str, value: float | None, threshold: float) -> bool:
    """Whether ``value`` of metric ``key`` meets ``threshold`` (at most / at least, by the
    key's sense); an unmeasured (None) value does not."""
    return value is not None and (value <= threshold if TARGETS[key][1] == AT_MOST else value >= threshold)


def worst(key: str, values: Iterable[float]) -> float:
    """The worst of some values of metric ``key`` (the largest of an at-most figure)."""
    return (max if TARGETS[key][1] == AT_MOST else min)(values)


def figure(metrics: Mapping[str, Any], key: str) -> tuple[float | None, str | None]:
    """A metrics.json figure: (value, None) for a fleet key, (worst robot's value, that
    robot) for a per-robot key; (None, None) when unmeasured."""
    if TARGETS[key][0] == "fleet":
        v = (metrics.get("fleet") or {}).get(key)
        return (None if v is None else float(v)), None
    vals = [(v[key], name) for name, v in (metrics.get("robots") or {}).items() if v.get(key) is not None]
    if not vals:
        return None, None
    value, name = (max if TARGETS[key][1] == AT_MOST else min)(vals, key=lambda p: p[0])
    return float(value), name


def failed_robots(metrics: Mapping[str, Any]) -> dict[str, int]:
    """Robots whose controller failed in the run, with their ``controller_errors`` (failed
    steps), in the order of metrics.json."""
    return {name: int(v["controller_errors"]) for name, v in (metrics.get("robots") or {}).items()
            if (v.get("controller_errors") or 0) > 0}


def grade(targets: tuple[Target, ...], metrics: Mapping[str, Any]) -> list[TargetResult]:
    """Each target against a metrics.json dict. A target misses when its figure misses the
    threshold or is unmeasured (null), when a per-robot figure is null for any robot (named
    in ``worst``), and whenever a robot's controller failed (:func:`failed_robots`)."""
    failed = failed_robots(metrics)
    because = (None if not failed else "controller failed: " + ", ".join(
        f"{name} ({n} step{'s' if n != 1 else ''})" for name, n in failed.items()))
    out = []
    for t in targets:
        value, who = figure(metrics, t.key)
        passed, reason = meets(t.key, value, t.threshold), None
        if t.scope == "robots" and value is not None:
            nulls = [name for name, v in (metrics.get("robots") or {}).items() if v.get(t.key) is None]
            if nulls:
                value, who, passed, reason = None, nulls[0], False, f"not measured for {', '.join(nulls)}"
        if because is not None:
            passed, reason = False, because if reason is None else f"{reason}; {because}"
        out.append(TargetResult(t, value, who, passed, reason))
    return out
