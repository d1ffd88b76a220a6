"""The public controller kit: the contract every controller implements and the pieces
that built-in and user controllers share.

A user controller imports from here only::

    from copath.control import Observation, PeerMessage, Outgoing, StepResult, RobotContext

See ``docs/reference/controllers.md`` for the contract and how to test a controller. A
controller family declares itself on its factory (:func:`controller`): its parameters, and
what the rest of copath asks it instead of its name: its team geometry
(:mod:`copath.team`), its message schemas, its done rule (:mod:`copath.occupancy`) and
whether it handles being cut off or obstacles itself.

The kit (shared by the built-in controllers; ``docs/reference/controllers-notes.md`` says what
moved where):

- :class:`LatestMessages` (:mod:`copath.control.inbox`): the newest message per
  neighbour and kind, by stamp, with its age;
- :meth:`copath.paths.Path.project`: a pose projected onto a path (global, or near a
  previous guess so that it stays continuous along self-crossing curves);
- :class:`VirtualVehicle` (:mod:`copath.control.virtual`): the path coordinate of a
  path-following virtual vehicle, advanced with the held s-dot over the actual time
  between control instants;
- :class:`PathTable`: one tabulated path (x, y, theta, kappa, dkappa/ds) for solvers
  and horizons (``Path.table()`` builds and caches it);
- the model limits on the model classes (:meth:`copath.models.OmniModel.max_speed`,
  :meth:`~copath.models.OmniModel.max_rotation`,
  :meth:`~copath.models.OmniModel.saturate_wheels`);
- one table of solver options in :mod:`copath.mpc` (:func:`copath.mpc.qp_options`,
  :func:`copath.mpc.jit_options`).
"""

from .contract import Controller, Observation, Outgoing, PeerMessage, RobotContext, StepResult
from .factory import ControllerFactory, as_factory, controller, deferred
from .inbox import LatestMessages, Received
from .virtual import VirtualVehicle
from copath.paths import PathTable

__all__ = ["Controller", "Observation", "Outgoing", "PeerMessage", "RobotContext", "StepResult",
           "ControllerFactory", "deferred", "controller", "as_factory",
           "LatestMessages", "Received", "PathTable", "VirtualVehicle"]
