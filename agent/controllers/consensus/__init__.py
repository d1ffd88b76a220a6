"""The ``consensus`` controller family: Lyapunov path following and second-order consensus
of unicycles (Sec. 5.5).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the law (imported when a robot builds it);
- :mod:`.payloads`    the schema of its ``coord_state`` broadcast;
- :mod:`.geometry`    its team geometry for grading from the truth.
"""

from __future__ import annotations

from copath.control import RobotContext, controller, deferred

from .config import ConsensusConfig
from .payloads import PAYLOADS

__all__ = ["build", "ConsensusConfig"]


team_geometry = deferred("agent.controllers.consensus.geometry:consensus_geometry")
"""The team's geometry for grading from the truth (:func:`.geometry.consensus_geometry`), imported when
the metrics ask: a robot that only builds the law never loads it."""


@controller(config=ConsensusConfig, needs_path=True, geometry=team_geometry, payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: ConsensusConfig):
    """Builder of ``consensus`` (Sec. 5.5)."""
    from .controller import ConsensusController  # noqa: PLC0415 (the law loads with the robot only)

    return ConsensusController(ctx, cfg)
