"""The ``formation_switching`` controller family: formation switching while following a path
(Sec. 6.2.4, E6.6).

- :mod:`.config`      its parameters;
- :mod:`.controller`  the law (imported when a robot builds it);
- :mod:`.payloads`    the schema of its ``formation_state`` broadcast;
- :mod:`.geometry`    its team geometry for grading from the truth.
"""

from __future__ import annotations

from copath.control import RobotContext, controller, deferred

from .config import FormationSwitchingConfig
from .payloads import PAYLOADS

__all__ = ["build", "FormationSwitchingConfig"]


team_geometry = deferred("agent.controllers.formation_switching.geometry:switching_geometry")
"""The team's geometry for grading from the truth (:func:`.geometry.switching_geometry`), imported when
the metrics ask: a robot that only builds the law never loads it."""


@controller(config=FormationSwitchingConfig, needs_path=True, models=("unicycle",), geometry=team_geometry,
            payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: FormationSwitchingConfig):
    """Registry builder ``formation_switching`` (E6.6)."""
    from .controller import FormationSwitchingController  # noqa: PLC0415 (the law loads with the robot only)

    return FormationSwitchingController(ctx, cfg)
