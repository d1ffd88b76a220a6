"""The ``formation_switching`` controller family: formation switching while following a path
(Sec. 6.2.4, E6.6).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the law (imported when a robot builds it);
- :mod:`.payloads`    the schema of its ``formation_state`` broadcast;
- :mod:`.geometry`    its team geometry for grading from the truth.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from copath.control import RobotContext, controller

from .config import FormationSwitchingConfig
from .payloads import PAYLOADS

if TYPE_CHECKING:
    from copath.scenario import Scenario
    from copath.team import TeamGeometry

__all__ = ["build", "FormationSwitchingConfig"]


def team_geometry(scenario: "Scenario") -> "TeamGeometry | None":
    """The team's geometry for grading from the truth,
    :func:`.geometry.switching_geometry`, imported here: a robot that only builds the law
    never loads it."""
    from .geometry import switching_geometry  # noqa: PLC0415

    return switching_geometry(scenario)


@controller(config=FormationSwitchingConfig, needs_path=True, models=("unicycle",), geometry=team_geometry,
            payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: FormationSwitchingConfig):
    """Registry builder ``formation_switching`` (E6.6)."""
    from .controller import FormationSwitchingController  # noqa: PLC0415 (the law loads with the robot only)

    return FormationSwitchingController(ctx, cfg)
