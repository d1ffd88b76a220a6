"""The public controller kit: the contract every controller implements and the pieces
that built-in and user controllers share.

A user controller imports from here only::

    from copath.control import Observation, PeerMessage, Outgoing, StepResult, RobotContext

See ``docs/controllers.md`` for the contract and how to test a controller.
"""

from .contract import Controller, Observation, Outgoing, PeerMessage, RobotContext, StepResult
from .factory import ControllerFactory, as_factory, controller

__all__ = ["Controller", "Observation", "Outgoing", "PeerMessage", "RobotContext", "StepResult",
           "ControllerFactory", "controller", "as_factory"]
