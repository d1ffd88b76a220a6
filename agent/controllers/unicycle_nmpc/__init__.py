"""The ``unicycle_nmpc`` controller family: NMPC of a unicycle blending path following and
trajectory tracking, with obstacles from range sensors (Sec. 4.4).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the NMPC law (CasADi; imported when a robot builds it).

Obstacles are constraints of its own problem (Sec. 4.4.3), so it declares
``handles_obstacles``: the runtime's detour stage leaves it alone (docs/reference/detours.md).
"""

from __future__ import annotations

from copath.control import RobotContext, controller

from .config import UnicycleNMPCConfig

__all__ = ["build", "UnicycleNMPCConfig"]


@controller(config=UnicycleNMPCConfig, needs_path=True, models=("unicycle",), handles_obstacles=True)
def build(ctx: RobotContext, cfg: UnicycleNMPCConfig):
    """Builder of ``unicycle_nmpc`` (Sec. 4.4, E4.4-E4.7)."""
    from .controller import UnicycleNMPCController  # noqa: PLC0415 (CasADi loads with the robot only)

    return UnicycleNMPCController(ctx, cfg)
