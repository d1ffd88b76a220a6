"""Distributed role assignment and formation switching (Chapter 6), registry name ``roles``.

One module per concern:

- :mod:`.config`      its parameters;
- :mod:`.averaging`   average consensus (Metropolis, edge-flow form) and the PI dynamic
                      consensus (6.16);
- :mod:`.rotation`    translation and rotation of the target formation, (6.3), (6.8)-(6.9);
- :mod:`.assignment`  local Hungarian (6.7) and negotiation, Algorithm 6.2;
- :mod:`.navigation`  (6.10)-(6.11) navigation and the repulsive field (6.12)-(6.15);
- :mod:`.peers`       the neighbour table (the range-limited graph, Def. 10);
- :mod:`.agreement`   the agreement on translation and rotation, Algorithm 6.1;
- :mod:`.phases`      one state object per later phase of a task (assignment and
                      negotiation, navigation, task sequencing);
- :mod:`.controller`  the per-robot state machine tying them together;
- :mod:`.payloads`    the schema of its ``role_state`` broadcast;
- :mod:`.tasks`       its done rule: each robot's task queue for the occupancy rule.

It declares ``handles_cut_off``: a robot cut off from every other is handled by the
controller (docs/reference/ambiguities.md, robot lost in role assignment (A38): held still, or driving on to a position
kept for it within ``R_max``), not by the runtime's hold; the others' safety filters keep
it as any robot gone quiet before that rule (forgotten after ``safety.max_age_s``): a
static disc covering ``R_max`` more blocked the positions next to it (E6.3: the circle was
never completed).
"""

from __future__ import annotations

from copath.control import RobotContext, controller

from .config import RolesConfig
from .payloads import MESSAGE_KIND, PAYLOADS
from .tasks import task_queue

__all__ = ["build", "RolesConfig", "MESSAGE_KIND"]


@controller(config=RolesConfig, models=("unicycle",), payloads=PAYLOADS, tasks=task_queue, handles_cut_off=True)
def build(ctx: RobotContext, cfg: RolesConfig):
    """Registry builder ``roles`` (Chapter 6)."""
    from .controller import RolesController  # noqa: PLC0415 (the law loads with the robot only)

    return RolesController(ctx, cfg)
