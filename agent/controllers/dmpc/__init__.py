"""The ``dmpc`` controller family: distributed MPC of omni robots with morphing for several
paths (Sec. 5.4, Algorithm 5.1).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the law and its OCP (CasADi; imported when a robot builds it);
- :mod:`.payloads`    the schema of its ``assumed_traj`` message;
- :mod:`.geometry`    its team geometry for grading from the truth.
"""

from __future__ import annotations

from copath.control import RobotContext, controller

from .config import DMPCConfig
from .geometry import dmpc_geometry
from .payloads import PAYLOADS

__all__ = ["build", "DMPCConfig"]


@controller(config=DMPCConfig, needs_path=True, models=("omni",), geometry=dmpc_geometry, payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: DMPCConfig):
    """Builder of ``dmpc`` (Sec. 5.4, Algorithm 5.1)."""
    from .controller import DMPCController  # noqa: PLC0415 (CasADi loads with the robot only)

    return DMPCController(ctx, cfg)
