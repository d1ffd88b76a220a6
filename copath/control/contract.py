"""The controller contract: observation + neighbour messages in, command + messages out.

A controller is a plain object built once per robot and stepped every control period.
It imports no zenoh, msgpack or clock; it runs unchanged inside an agent process over
Zenoh (``agent/node.py``) and in the in-process loop used by tests and benchmarks
(``orchestrator/run/inprocess.py``).

Telemetry contract
------------------
``StepResult.telemetry`` is a flat dict of plain values (floats, ints, bools, lists of
floats, or None) recorded every step and used by ``orchestrator/analysis/metrics.py``:

``ref``                [x, y, theta] the pose the robot should be at now (path reference
                       point, tracked trajectory point or formation slot); path and
                       heading errors are computed from the simulator's truth against it.
``s``, ``sdot``        path coordinate and virtual-vehicle speed.
``xi``                 coordination coordinate: robots are coordinated when all xi are
                       equal (e.g. s_i - s_di, or progress in base-path coordinates).
``xi_period``          period of xi (the shared closed path's length) or 0: differences
                       of xi are compared modulo this period.
``speed_error``        virtual-vehicle speed error (sdot - v_d) [m/s].
``solver_ok``          False when the solve failed and a fallback command was used.
``formation_error``    distance to the formation slot where a formation is defined.
``in_transition``      True while a formation change is under way (errors excluded).
``task``, ``task_done`` task index and whether this robot has finished it (Ch. 6).
``target``             [x, y] assigned target position or None (Ch. 6).
``conflicts_resolved`` cumulative count of negotiations this robot initiated (Ch. 6).
``leading``, ``term``  whether this robot leads its leader-following team (Sec. 5.3) and
                       the election term it knows (0 until a leader is lost, docs/reference/faults.md).
Keys that do not apply are simply left out. With ``[safety]`` on, the runtime adds
``safety_active``, ``safety_change`` and ``safety_ms`` (``copath.safety``, docs/reference/safety.md);
controllers never set them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping, Protocol, Sequence

import numpy as np

from copath.models import OmniModel, UnicycleModel
from copath.paths import Path

if TYPE_CHECKING:
    from copath.scenario import Scenario

__all__ = ["Observation", "PeerMessage", "Outgoing", "StepResult", "RobotContext", "Controller"]


@dataclass(frozen=True)
class Observation:
    """What the robot knows at a control instant (never another robot's truth)."""

    t: float
    """Controller time [s] (the simulator clock, synchronised once at start-up)."""
    pose: np.ndarray
    """(3,) own pose estimate (x, y, theta) [m, m, rad]."""
    dt: float
    """Nominal control period [s]."""
    ranges: np.ndarray | None = None
    """(N_s,) range readings [m] of the sensor ring, ``inf`` where nothing is within range."""
    sensor_angles: np.ndarray | None = None
    """(N_s,) bearings of the range sensors in the body frame [rad]."""
    sensor_max_range: float = 0.0
    """Range of each sensor [m]."""
    lost: frozenset[str] = frozenset()
    """Robots known to be gone: their liveliness token disappeared (process dead or frozen),
    or this robot has heard nothing from them for the lease (a radio gone quiet, until heard
    again). A controller drops them from its graph (``run.on_robot_failure``)."""
    joined: bool = False
    """This robot's process joined a run in progress (a restart, ``run.on_robot_failure =
    "restart"``): a controller that starts a coordination state may take it from its
    neighbours' messages instead of its own start (docs/reference/faults.md, "Restart")."""


@dataclass(frozen=True)
class PeerMessage:
    """A message from a neighbour, as delivered after the fault layer."""

    sender: str
    kind: str
    stamp: float
    """Sender's clock at sending [s]."""
    age: float
    """Receiver's clock minus stamp at delivery [s] (age of information)."""
    payload: Mapping[str, Any]
    position: tuple[float, float] | None = None
    """Sender's own position estimate, carried for range-limited graphs (Def. 10)."""
    position_cov: tuple[float, float, float] | None = None
    """Covariance (Pxx, Pxy, Pyy) of ``position`` when the sender runs an estimator
    (``[sensing]``, copath.estimation), so a receiver can weight it; else None."""


@dataclass(frozen=True)
class Outgoing:
    """A message to send: ``to=None`` means every neighbour (fixed graph) or every
    robot in communication range (dynamic graph)."""

    kind: str
    payload: Mapping[str, Any]
    to: tuple[str, ...] | None = None


@dataclass
class StepResult:
    command: np.ndarray
    """Body velocities: omni (u, v, omega), unicycle (v, omega)."""
    messages: list[Outgoing] = field(default_factory=list)
    telemetry: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RobotContext:
    """Everything a controller builder may know about its robot and scenario."""

    name: str
    index: int
    """0-based index of the robot in the scenario's robot list."""
    model: OmniModel | UnicycleModel
    paths: Mapping[str, Path]
    path: str | None
    """Name of this robot's own path (key of ``paths``), if any."""
    neighbours: tuple[str, ...]
    """Fixed-graph neighbours (empty when the graph is range-limited)."""
    robots: tuple[str, ...]
    """Names of all robots in the scenario (for broadcasts such as a leader's)."""
    dt: float
    """Control period [s]."""
    params: Mapping[str, Any]
    """The merged ``[controller]`` table for this robot (``type`` removed)."""
    seed: int = 0
    comm_range: float = 0.0
    """Communication range r [m] of a dynamic graph; 0 for a fixed graph."""
    realtime: bool = False
    """The run steps on the wall clock (``run.clock = "realtime"``): a controller may cap its
    solves' wall time there (docs/reference/controllers.md, "Solve time cap"), never in lockstep."""

    @classmethod
    def for_robot(cls, scenario: "Scenario", name: str) -> "RobotContext":
        """The context of robot ``name`` of a validated scenario."""
        spec = scenario.robot(name)
        comm_range = scenario.network.range_m
        return cls(
            name=name,
            index=scenario.robot_names.index(name),
            model=spec.model,
            paths=scenario.paths,
            path=spec.path,
            neighbours=spec.neighbours,
            robots=scenario.robot_names,
            dt=scenario.run.dt,
            params=dict(spec.params),
            seed=scenario.run.seed,
            comm_range=comm_range,
            realtime=scenario.run.clock == "realtime",
        )

    @property
    def own_path(self) -> Path:
        if self.path is None:
            raise ValueError(f"robot {self.name!r} needs a path (robots.path) for this controller")
        return self.paths[self.path]


class Controller(Protocol):
    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult: ...
