"""Team geometry of the consensus family for grading from the truth (Sec. 5.5):
xi_i = s_i - s_di (5.42), the slot of robot i at xi_ref the path point r_i(xi_ref + s_di)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from copath.team import TeamGeometry, along_path_geometry, robot_params

from .config import ConsensusConfig

if TYPE_CHECKING:
    from copath.scenario import Scenario

__all__ = ["consensus_geometry"]


def consensus_geometry(scenario: "Scenario") -> TeamGeometry:
    paths = {r.name: scenario.paths[r.path] for r in scenario.robots}
    s_d = {n: robot_params(scenario, ConsensusConfig, n).s_d for n in paths}
    return along_path_geometry("consensus", paths, s_d)
