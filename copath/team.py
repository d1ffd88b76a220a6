"""A team's desired geometry, as pure functions of path coordinates: what truth grading
needs from a controller family (Chapters 5-6).

A family declares how to build one on its factory
(:attr:`copath.control.ControllerFactory.geometry`); the metrics project each robot's true
position onto its path and hand the path coordinates to it. Nothing here knows a family:
the helpers below are the pieces the families' declarations share, and
:func:`declared_geometry` is the geometry a scenario types in ``[metrics] path_offsets``.
See docs/reference/metrics.md and docs/reference/controllers.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterable

import numpy as np

from .config import from_table
from .paths import Path
from .slots import offset_points

if TYPE_CHECKING:
    from .scenario import Scenario

__all__ = ["TeamGeometry", "no_transition", "robot_params", "closed_period", "along_path_geometry",
           "declared_geometry"]


@dataclass
class TeamGeometry:
    """The desired geometry of one team, as pure functions of path coordinates."""

    family: str
    paths: dict[str, Path]
    """Path each robot's true position is projected onto."""
    xi: Callable[..., dict[str, np.ndarray]]
    """{robot: s (T,)} -> {robot: xi (T,)}. A team with a :attr:`succession` also takes
    ``ref``, the team's reference coordinate C (T,) (default: the first leader's s)."""
    slots: Callable[[np.ndarray], dict[str, np.ndarray]]
    """xi_ref (T,) -> {robot: slot position (T, 2)} (robots that hold a slot)."""
    in_transition: Callable[[np.ndarray], np.ndarray]
    """xi_ref (T,) -> (T,) True while a formation change is under way."""
    period: float = 0.0
    """Period of xi (a shared closed path's length) or 0."""
    leader: str | None = None
    """The robot whose xi is the team's reference, or None for the mean."""
    lateral: Callable[..., dict[str, np.ndarray]] | None = None
    """{robot: s (T,)} -> {robot: desired lateral offset q (T,)} from its path; None: 0.
    Takes ``ref`` as :attr:`xi` does."""
    succession: tuple[str, ...] = ()
    """A team that elects a new leader when its leader is lost (Sec. 5.3; docs/reference/faults.md,
    "A new leader"): its members in the scenario's robot order, the first one the first
    leader. Empty: the leader never changes and no robot is left ungraded."""
    reference: Callable[[str, np.ndarray], np.ndarray] | None = None
    """(robot, its path coordinate s (T,)) -> the team's reference coordinate C (T,) it
    stands for as leader: it keeps its slot, s = C + p(C)."""


def no_transition(xi_ref: np.ndarray) -> np.ndarray:
    """No formation change ever: (T,) False."""
    return np.zeros(np.shape(xi_ref), dtype=bool)


def robot_params(scenario: "Scenario", cls: type, name: str) -> Any:
    """Robot ``name``'s ``[controller]`` table parsed into the family's config ``cls``."""
    return from_table(cls, scenario.robot(name).params, f"robots.{name}.controller")


def closed_period(paths: Iterable[Path]) -> float:
    """The longest closed path's length (the period of a coordinate on it), 0 if none is closed."""
    return max((p.length for p in paths if p.closed), default=0.0)


def along_path_geometry(family: str, paths: dict[str, Path], s_d: dict[str, float],
                        q: dict[str, float] | None = None) -> TeamGeometry:
    """Robots spaced along their paths by fixed offsets: xi_i = s_i - s_di (5.42), the slot of
    robot i at xi_ref the offset point o(xi_ref + s_di, q_i) (5.10)."""
    q = q or {}
    return TeamGeometry(
        family, paths,
        xi=lambda S: {n: S[n] - s_d[n] for n in S},
        slots=lambda x: {n: offset_points(paths[n], x + s_d[n], q.get(n, 0.0)) for n in paths},
        in_transition=no_transition, period=closed_period(paths.values()))


def declared_geometry(scenario: "Scenario") -> TeamGeometry:
    """The geometry the scenario declares in ``[metrics] path_offsets`` (any controller)."""
    s_d = {n: float(v) for n, v in scenario.metrics["path_offsets"].items()}
    q = {n: float(v) for n, v in (scenario.metrics.get("lateral_offsets") or {}).items()}
    paths = {r.name: scenario.paths[r.path] for r in scenario.robots}
    return along_path_geometry("declared", paths, s_d, q)
