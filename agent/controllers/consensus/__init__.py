"""The ``consensus`` controller family: Lyapunov path following and second-order consensus
of unicycles (Sec. 5.5).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the law (imported when a robot builds it);
- :mod:`.payloads`    the schema of its ``coord_state`` broadcast;
- :mod:`.geometry`    its team geometry for grading from the truth.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from copath.control import RobotContext, controller

from .config import ConsensusConfig
from .payloads import PAYLOADS

if TYPE_CHECKING:
    from copath.scenario import Scenario
    from copath.team import TeamGeometry

__all__ = ["build", "ConsensusConfig"]


def team_geometry(scenario: "Scenario") -> "TeamGeometry | None":
    """The team's geometry for grading from the truth,
    :func:`.geometry.consensus_geometry`, imported here: a robot that only builds the law
    never loads it."""
    from .geometry import consensus_geometry  # noqa: PLC0415

    return consensus_geometry(scenario)


@controller(config=ConsensusConfig, needs_path=True, geometry=team_geometry, payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: ConsensusConfig):
    """Builder of ``consensus`` (Sec. 5.5)."""
    from .controller import ConsensusController  # noqa: PLC0415 (the law loads with the robot only)

    return ConsensusController(ctx, cfg)
