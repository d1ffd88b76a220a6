"""Stage "control": the robot's controller steps on what the earlier stages made of the
observation and the inbox; its failures are contained (docs/reference/controllers.md, "The
contract" and "When step() fails")."""

from __future__ import annotations

import logging
import math
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from copath.control import Observation, PeerMessage
from copath.wire.messages import Event

from .counters import Counters

logger = logging.getLogger("agent.runtime")

__all__ = ["ControlResult", "ControlStage"]

_ERROR_CHARS = 300
"""An exception's message is cut to this length in the ``controller_error`` event."""
_TRACEBACK_CHARS = 6000
"""The traceback in the ``controller_error`` event keeps its last this many characters."""


@dataclass
class ControlResult:
    command: list[float]
    """The controller's command (zeros when its step failed)."""
    messages: list = field(default_factory=list)
    """Its outgoing peer messages (none when its step failed)."""
    telemetry: dict = field(default_factory=dict)
    solve_ms: float = 0.0
    """Wall time of the controller's step [ms]."""
    failure: Event | None = None
    """The ``controller_error`` event of this robot's first failure."""


class ControlStage:
    """The controller of one robot.

    Reads: the :class:`~copath.control.Observation` and the inbox of this instant.
    Writes: the command, outgoing messages and telemetry; :class:`Counters`
    ``controller_errors``; the first failure's ``controller_error`` event (and, with
    :attr:`log_tracebacks`, its traceback in the process's log)."""

    name = "control"

    def __init__(self, controller, name: str, command_size: int, counters: Counters) -> None:
        self.controller = controller
        self.robot = name
        self.command_size = command_size
        self.log_tracebacks = True
        """Log the first controller failure's traceback (an agent process's log); the
        in-process loop turns it off: the traceback travels in the event, the terminal gets
        one line (``orchestrator/run/failures.py``)."""
        self._counters = counters

    def step(self, observation: Observation, inbox: list[PeerMessage], k: int, now: float) -> ControlResult:
        """One controller step; an exception inside it, or a command that is not
        :attr:`command_size` finite values, stops the robot for this step instead of killing it."""
        t0 = time.perf_counter()
        try:
            res = self.controller.step(observation, inbox)
            c = res.command
            cmd = (c.tolist() if type(c) is np.ndarray and c.ndim == 1 and c.dtype == np.float64  # the common case
                   else [float(x) for x in np.asarray(c, dtype=float).reshape(-1)])
            if len(cmd) != self.command_size or not all(map(math.isfinite, cmd)):
                raise ValueError(f"controller returned command {cmd!r}; expected {self.command_size} finite values")
            messages, telemetry = res.messages, dict(res.telemetry)
        except Exception as exc:  # the robot stops for this step instead of dying
            cmd, messages, telemetry = [0.0] * self.command_size, [], {"controller_error": True}
            failure = self._failed(exc, k, now)
        else:
            failure = None
            if "solve_timeout" in telemetry:
                failure = self._timed_out(telemetry["solve_timeout"], k, now)
        return ControlResult(cmd, messages, telemetry, (time.perf_counter() - t0) * 1e3, failure)

    def _failed(self, exc: BaseException, k: int, now: float) -> Event | None:
        """Count a failed controller step (an exception in ``step()`` or an invalid command;
        docs/reference/controllers.md, "When step() fails"). The first failure of this robot is logged
        with its traceback (the process's log) and becomes a ``controller_error`` event
        (robot, time, exception, traceback) that the orchestrator prints as one line; later
        ones are only counted: each failed step's telemetry says ``controller_error`` (the
        count in metrics.json) and the closing account has the total."""
        self._counters.controller_errors += 1
        if self._counters.controller_errors > 1:
            return None
        what = f"{type(exc).__name__}: {exc}"[:_ERROR_CHARS]
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        if self.log_tracebacks:
            logger.error("robot %s: controller step failed at t=%.3f s (tick %d): %s\n%s"
                         "the robot stops at every failing step; further failures are counted "
                         "(controller_errors), not logged", self.robot, now, k, what, tb)
        return Event(float(now), self.robot, "controller_error",
                     {"k": int(k), "error": type(exc).__name__, "message": str(exc)[:_ERROR_CHARS],
                      "traceback": tb[-_TRACEBACK_CHARS:]})

    def _timed_out(self, detail, k: int, now: float) -> Event:
        """A solve stopped by its time cap (the controller's telemetry ``solve_timeout``:
        docs/reference/controllers.md, "Solve time cap"): counted, logged, and a
        ``solve_timeout`` event (robot, time, the cap and the fallback the controller used)."""
        self._counters.add("solve_timeouts")
        detail = dict(detail) if isinstance(detail, dict) else {}
        logger.warning("robot %s: a solve reached its time cap at t=%.3f s (tick %d): %s; fallback command used",
                       self.robot, now, k, detail)
        return Event(float(now), self.robot, "solve_timeout", {"k": int(k), **detail})

    def close(self) -> None:
        """The closing account's word on failures (the first one's traceback is logged already)."""
        if self._counters.controller_errors > 1 and self.log_tracebacks:
            logger.error("robot %s: controller step failed %d times in all (traceback of the first above)",
                         self.robot, self._counters.controller_errors)
