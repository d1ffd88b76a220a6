"""The ``consensus`` controller family: Lyapunov path following and second-order consensus
of unicycles (Sec. 5.5).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the law (imported when a robot builds it);
- :mod:`.payloads`    the schema of its ``coord_state`` broadcast;
- :mod:`.geometry`    its team geometry for grading from the truth.
"""

from __future__ import annotations

from copath.control import RobotContext, controller

from .config import ConsensusConfig
from .geometry import consensus_geometry
from .payloads import PAYLOADS

__all__ = ["build", "ConsensusConfig"]


@controller(config=ConsensusConfig, needs_path=True, geometry=consensus_geometry, payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: ConsensusConfig):
    """Builder of ``consensus`` (Sec. 5.5)."""
    from .controller import ConsensusController  # noqa: PLC0415 (the law loads with the robot only)

    return ConsensusController(ctx, cfg)
