"""The ``ltv_mpc`` controller family: path following of an omni robot by an LTV-MPC QP with a
velocity profile (Sec. 4.3).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the profile, the QP and the law (CasADi; imported when a robot builds it).
"""

from __future__ import annotations

from copath.control import RobotContext, controller

from .config import LTVConfig

__all__ = ["build", "LTVConfig"]


@controller(config=LTVConfig, needs_path=True, models=("omni",))
def build(ctx: RobotContext, cfg: LTVConfig):
    """Builder of ``ltv_mpc`` (Sec. 4.3, E4.3)."""
    from .controller import LTVController  # noqa: PLC0415 (CasADi loads with the robot only)

    return LTVController(ctx, cfg)
