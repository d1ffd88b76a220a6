"""The leader-following controller family (Sec. 5.3): ``leader_nmpc`` and ``follower_nmpc``.

- :mod:`.config`      the leader's and the followers' parameters;
- :mod:`.formation`   curvilinear formations, their changes and the follower reference;
- :mod:`.controller`  the leader, the followers and the succession of leaders (CasADi;
                      imported when a robot builds one);
- :mod:`.payloads`    the schemas of ``leader_plan`` and ``follower_status``;
- :mod:`.geometry`    the team geometry for grading from the truth.
"""

from __future__ import annotations

from copath.control import RobotContext, controller, deferred

from .config import FollowerConfig, LeaderConfig
from .payloads import PAYLOADS

__all__ = ["build_leader", "build_follower", "LeaderConfig", "FollowerConfig"]


team_geometry = deferred("agent.controllers.leader_following.geometry:leader_following_geometry")
"""The team's geometry for grading from the truth (:func:`.geometry.leader_following_geometry`), imported when
the metrics ask: a robot that only builds the law never loads it."""


@controller(config=LeaderConfig, needs_path=True, models=("omni",), geometry=team_geometry,
            payloads=PAYLOADS)
def build_leader(ctx: RobotContext, cfg: LeaderConfig):
    """Builder of ``leader_nmpc`` (Sec. 5.3)."""
    from .controller import LeaderFollowing  # noqa: PLC0415 (CasADi loads with the robot only)

    return LeaderFollowing(ctx, cfg, lead=True)


@controller(config=FollowerConfig, needs_path=True, models=("omni",), geometry=team_geometry,
            payloads=PAYLOADS)
def build_follower(ctx: RobotContext, cfg: FollowerConfig):
    """Builder of ``follower_nmpc`` (Sec. 5.3)."""
    from .controller import LeaderFollowing  # noqa: PLC0415

    return LeaderFollowing(ctx, cfg, lead=False)
