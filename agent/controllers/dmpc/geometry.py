"""Team geometry of the dmpc family for grading from the truth (Sec. 5.4): xi_i =
P_B/P_i s_i - psi_di (the morphing (5.28)-(5.29)), the slot of robot i at xi_ref the offset
point o_i(P_i/P_B (xi_ref + psi_di), q_i) (5.10)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from copath.morphing import morphing
from copath.slots import offset_points
from copath.team import TeamGeometry, no_transition, robot_params

from .config import DMPCConfig

if TYPE_CHECKING:
    from copath.scenario import Scenario

__all__ = ["dmpc_geometry"]


def dmpc_geometry(scenario: "Scenario") -> TeamGeometry:
    paths, morph, q, psi_d = {}, {}, {}, {}
    period = 0.0
    for r in scenario.robots:
        cfg = robot_params(scenario, DMPCConfig, r.name)
        own = scenario.paths[r.path]
        base = scenario.paths[cfg.base_path] if cfg.base_path else own
        paths[r.name], morph[r.name], q[r.name], psi_d[r.name] = own, morphing(own, base), cfg.q, cfg.offset(r.name)
        period = max(period, base.length if base.closed else 0.0)
    return TeamGeometry(
        "dmpc", paths,
        xi=lambda S: {n: morph[n].psi(S[n]) - psi_d[n] for n in S},
        slots=lambda x: {n: offset_points(paths[n], morph[n].s(x + psi_d[n]), q[n]) for n in paths},
        in_transition=no_transition, period=period,
        lateral=lambda S: {n: np.full(np.shape(S[n]), q[n]) for n in S})
