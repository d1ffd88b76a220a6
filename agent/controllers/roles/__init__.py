"""Distributed role assignment and formation switching (Chapter 6), registry name ``roles``.

One module per concern:

- :mod:`.consensus`   average consensus (Metropolis, edge-flow form) and the PI dynamic
                      consensus (6.16);
- :mod:`.rotation`    translation and rotation of the target formation, (6.3), (6.8)-(6.9),
                      Algorithm 6.1;
- :mod:`.assignment`  local Hungarian (6.7) and negotiation, Algorithm 6.2;
- :mod:`.navigation`  (6.10)-(6.11) navigation and the repulsive field (6.12)-(6.15);
- :mod:`.phases`      one state object per phase of a task (agreement, assignment and
                      negotiation, navigation, task sequencing) and the neighbour table;
- :mod:`.controller`  the per-robot state machine tying them together.
"""

from agent.controllers.roles.config import RolesConfig
from agent.controllers.roles.controller import MESSAGE_KIND, RolesController, build

__all__ = ["build", "RolesController", "RolesConfig", "MESSAGE_KIND"]
