"""The ``dmpc`` controller family: distributed MPC of omni robots with morphing for several
paths (Sec. 5.4, Algorithm 5.1).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the law and its OCP (CasADi; imported when a robot builds it);
- :mod:`.payloads`    the schema of its ``assumed_traj`` message;
- :mod:`.geometry`    its team geometry for grading from the truth.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from copath.control import RobotContext, controller

from .config import DMPCConfig
from .payloads import PAYLOADS

if TYPE_CHECKING:
    from copath.scenario import Scenario
    from copath.team import TeamGeometry

__all__ = ["build", "DMPCConfig"]


def team_geometry(scenario: "Scenario") -> "TeamGeometry | None":
    """The team's geometry for grading from the truth,
    :func:`.geometry.dmpc_geometry`, imported here: a robot that only builds the law
    never loads it."""
    from .geometry import dmpc_geometry  # noqa: PLC0415

    return dmpc_geometry(scenario)


@controller(config=DMPCConfig, needs_path=True, models=("omni",), geometry=team_geometry, payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: DMPCConfig):
    """Builder of ``dmpc`` (Sec. 5.4, Algorithm 5.1)."""
    from .controller import DMPCController  # noqa: PLC0415 (CasADi loads with the robot only)

    return DMPCController(ctx, cfg)
