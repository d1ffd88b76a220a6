"""The ``dmpc`` controller family: distributed MPC of omni robots with morphing for several
paths (Sec. 5.4, Algorithm 5.1).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the law and its OCP (CasADi; imported when a robot builds it);
- :mod:`.payloads`    the schema of its ``assumed_traj`` message;
- :mod:`.geometry`    its team geometry for grading from the truth.
"""

from __future__ import annotations

from copath.control import RobotContext, controller, deferred

from .config import DMPCConfig
from .payloads import PAYLOADS

__all__ = ["build", "DMPCConfig"]


team_geometry = deferred("agent.controllers.dmpc.geometry:dmpc_geometry")
"""The team's geometry for grading from the truth (:func:`.geometry.dmpc_geometry`), imported when
the metrics ask: a robot that only builds the law never loads it."""


@controller(config=DMPCConfig, needs_path=True, models=("omni",), geometry=team_geometry, payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: DMPCConfig):
    """Builder of ``dmpc`` (Sec. 5.4, Algorithm 5.1)."""
    from .controller import DMPCController  # noqa: PLC0415 (CasADi loads with the robot only)

    return DMPCController(ctx, cfg)
