"""The heterogeneous-team controller family (Sec. 5.5.5): an omni leader (``hetero_leader``)
commanding unicycle followers (``hetero_follower``).

- :mod:`.config`      the leader's and the followers' parameters;
- :mod:`.controller`  the leader's NMPC and command law, the followers (CasADi; imported
                      when a robot builds one);
- :mod:`.payloads`    the schemas of ``hetero_cmd`` and ``hetero_report``;
- :mod:`.geometry`    the team geometry for grading from the truth.
"""

from __future__ import annotations

from copath.control import RobotContext, controller, deferred

from .config import HeteroFollowerConfig, HeteroLeaderConfig
from .payloads import PAYLOADS

__all__ = ["build_leader", "build_follower", "HeteroLeaderConfig", "HeteroFollowerConfig"]


team_geometry = deferred("agent.controllers.heterogeneous.geometry:heterogeneous_geometry")
"""The team's geometry for grading from the truth (:func:`.geometry.heterogeneous_geometry`), imported when
the metrics ask: a robot that only builds the law never loads it."""


@controller(config=HeteroLeaderConfig, needs_path=True, models=("omni",), geometry=team_geometry,
            payloads=PAYLOADS)
def build_leader(ctx: RobotContext, cfg: HeteroLeaderConfig):
    """Builder of ``hetero_leader`` (Sec. 5.5.5)."""
    from .controller import HeteroLeader  # noqa: PLC0415 (CasADi loads with the robot only)

    return HeteroLeader(ctx, cfg)


@controller(config=HeteroFollowerConfig, models=("unicycle",), geometry=team_geometry, payloads=PAYLOADS)
def build_follower(ctx: RobotContext, cfg: HeteroFollowerConfig):
    """Builder of ``hetero_follower`` (Sec. 5.5.5)."""
    from .controller import HeteroFollower  # noqa: PLC0415

    return HeteroFollower(ctx, cfg)
