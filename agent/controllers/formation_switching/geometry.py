"""Team geometry of the formation-switching family for grading from the truth (Sec. 6.2.4):
xi_i = s_i - s_di(s_i), the slot of robot i at xi_ref the offset point o(s, q_i(s)) where
s - s_di(s) = xi_ref, the offsets moving by the quintic (5.1)-(5.3) during a switch."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from copath.slots import offset_points, solve_coordinate, switching_offsets
from copath.team import TeamGeometry, closed_period, robot_params

from .config import FormationSwitchingConfig

if TYPE_CHECKING:
    from copath.scenario import Scenario

__all__ = ["switching_geometry"]


def switching_geometry(scenario: "Scenario") -> TeamGeometry:
    paths, cfgs = {}, {}
    for r in scenario.robots:
        paths[r.name] = scenario.paths[r.path]
        cfgs[r.name] = robot_params(scenario, FormationSwitchingConfig, r.name)

    def offs(n, s):
        c = cfgs[n]
        return switching_offsets(c.slots, c.switch_at, c.transition_m, s)

    def own_s(n, x):
        return solve_coordinate(x, lambda s: offs(n, s)[0])

    def slots(x):
        out = {}
        for n in paths:
            s = own_s(n, x)
            out[n] = offset_points(paths[n], s, offs(n, s)[1])
        return out

    def in_transition(x):
        return np.any([offs(n, own_s(n, x))[2] for n in paths], axis=0)

    return TeamGeometry("formation_switching", paths,
                        xi=lambda S: {n: S[n] - offs(n, S[n])[0] for n in S},
                        slots=slots, in_transition=in_transition, period=closed_period(paths.values()),
                        lateral=lambda S: {n: offs(n, S[n])[1] for n in S})
