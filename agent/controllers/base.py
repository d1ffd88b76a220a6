"""The controller contract now lives in the library: :mod:`copath.control.contract`.

Kept so that ``from agent.controllers.base import ...`` still works.
"""

from copath.control.contract import (  # noqa: F401
    Controller,
    Observation,
    Outgoing,
    PeerMessage,
    RobotContext,
    StepResult,
)

__all__ = ["Controller", "Observation", "Outgoing", "PeerMessage", "RobotContext", "StepResult"]
