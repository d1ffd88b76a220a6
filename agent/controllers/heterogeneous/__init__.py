"""The heterogeneous-team controller family (Sec. 5.5.5): an omni leader (``hetero_leader``)
commanding unicycle followers (``hetero_follower``).

- :mod:`.config`      the leader's and the followers' parameters;
- :mod:`.controller`  the leader's NMPC and command law, the followers (CasADi; imported
                      when a robot builds one);
- :mod:`.payloads`    the schemas of ``hetero_cmd`` and ``hetero_report``;
- :mod:`.geometry`    the team geometry for grading from the truth.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from copath.control import RobotContext, controller

from .config import HeteroFollowerConfig, HeteroLeaderConfig
from .payloads import PAYLOADS

if TYPE_CHECKING:
    from copath.scenario import Scenario
    from copath.team import TeamGeometry

__all__ = ["build_leader", "build_follower", "HeteroLeaderConfig", "HeteroFollowerConfig"]


def team_geometry(scenario: "Scenario") -> "TeamGeometry | None":
    """The team's geometry for grading from the truth,
    :func:`.geometry.heterogeneous_geometry`, imported here: a robot that only builds the law
    never loads it."""
    from .geometry import heterogeneous_geometry  # noqa: PLC0415

    return heterogeneous_geometry(scenario)


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
