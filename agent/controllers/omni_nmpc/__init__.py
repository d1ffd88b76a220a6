"""The ``omni_nmpc`` controller family: NMPC path following (``omni_nmpc_pf``) and trajectory
tracking (``omni_nmpc_tt``) of one omnidirectional robot (Sec. 4.2).

- :mod:`.config`      their parameters and the gain condition (4.10);
- :mod:`.controller`  the NMPC laws (CasADi; imported when a robot builds one).
"""

from __future__ import annotations

from copath.control import RobotContext, controller

from .config import OmniPFConfig, OmniTTConfig

__all__ = ["build_path_following", "build_trajectory_tracking", "OmniPFConfig", "OmniTTConfig"]


@controller(config=OmniPFConfig, needs_path=True, models=("omni",))
def build_path_following(ctx: RobotContext, cfg: OmniPFConfig):
    """Builder of ``omni_nmpc_pf`` (Sec. 4.2, E4.2)."""
    from .controller import OmniPathFollowingController  # noqa: PLC0415 (CasADi loads with the robot only)

    return OmniPathFollowingController(ctx, cfg)


@controller(config=OmniTTConfig, needs_path=True, models=("omni",))
def build_trajectory_tracking(ctx: RobotContext, cfg: OmniTTConfig):
    """Builder of ``omni_nmpc_tt`` (Sec. 4.2, E4.1)."""
    from .controller import OmniTrackingController  # noqa: PLC0415

    return OmniTrackingController(ctx, cfg)
