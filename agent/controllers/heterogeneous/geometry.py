"""Team geometry of the heterogeneous family for grading from the truth (Sec. 5.5.5): the
leader's xi is its path coordinate s_L, a follower's s_i + s_di; the slot of follower i at
xi_ref is o(xi_ref - s_di, q_i) (5.10)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from copath.slots import offset_points
from copath.team import TeamGeometry, no_transition, robot_params

from .config import HeteroLeaderConfig

if TYPE_CHECKING:
    from copath.scenario import Scenario

__all__ = ["LEADER", "FOLLOWER", "heterogeneous_geometry"]

LEADER = "hetero_leader"
FOLLOWER = "hetero_follower"
"""The family's registered names: which robot of a team leads."""


def heterogeneous_geometry(scenario: "Scenario") -> TeamGeometry | None:
    """The team's geometry; None unless it has a leader and followers."""
    kinds = {r.controller for r in scenario.robots}
    if kinds != {LEADER, FOLLOWER}:
        return None
    leader = next(r.name for r in scenario.robots if r.controller == LEADER)
    cfg = robot_params(scenario, HeteroLeaderConfig, leader)
    path = scenario.paths[scenario.robot(leader).path]
    offs = {n: (float(v[0]), float(v[1])) for n, v in cfg.followers.items()}
    paths = {r.name: path for r in scenario.robots}
    return TeamGeometry(
        "heterogeneous", paths,
        xi=lambda S: {n: S[n] + (offs[n][0] if n in offs else 0.0) for n in S},
        slots=lambda x: {n: offset_points(path, x - sd, q) for n, (sd, q) in offs.items()},
        in_transition=no_transition, period=path.length if path.closed else 0.0, leader=leader,
        lateral=lambda S: {n: np.full(np.shape(S[n]), offs[n][1] if n in offs else 0.0) for n in S})
