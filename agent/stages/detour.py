"""Stage "detour": the controller sees its pose moved back onto its lane while a detour round
a blocked stretch is under way (docs/reference/detours.md, "The method"; the planner is
:class:`copath.detour.DetourPlanner`)."""

from __future__ import annotations

import numpy as np

from copath.control import PeerMessage
from copath.detour import DetourPlanner, stretch_command, turn_command
from copath.scenario import Scenario
from copath.wire.messages import Event

from .liveness import LivenessStage
from .safety import SafetyStage

__all__ = ["DetourStage"]


class DetourStage:
    """One robot's detour stage (active only with a :attr:`planner`: a robot that follows a
    path, with ``[safety] detours`` on and a controller that does not avoid obstacles itself).

    Reads: the robot's pose, its range ring, the other robots' discs (the safety filter's
    neighbours when it runs: a lost robot is its held disc; else the positions heard in the
    inbox), whether the robot is held still and whether the safety filter changed its last
    command (a robot held back behind a teammate, docs/reference/detours.md, "Passing a teammate").
    Writes: the pose the controller sees, the lane's shift (telemetry ``detour_offset``) and
    ``detour_start`` / ``detour_end`` events."""

    name = "detour"

    def __init__(self, scenario: Scenario, name: str, planner: DetourPlanner | None) -> None:
        self.robot = name
        self.planner = planner
        self._model = scenario.robot(name).model
        self._dt = float(scenario.run.dt)
        self._radii = {r.name: r.model.radius for r in scenario.robots}
        self._positions: dict[str, tuple[float, float, float]] = {}
        """Without the safety filter: the last position each peer sent, and its stamp."""
        self._lease = float(scenario.run.lease_s)
        self._held_at: float | None = None
        """The last instant the runtime held this robot still (cut off) [s]."""
        self._wait = (planner.config.restart_wait_s
                      if planner is not None and scenario.run.on_robot_failure == "restart" else 0.0)
        """How long a robot just lost is waited for before its held disc blocks the lane [s]: its
        process is restarted under ``restart`` (docs/reference/detours.md, "A robot the fleet restarts")."""
        self._interventions = 0
        """The safety filter's count of changed commands at the last step."""
        self._stretch: tuple[float, float, float] | None = None
        """This step's lane stretch (an omni robot on a shifted lane; :func:`copath.detour.stretch_command`)."""
        self._turn: tuple[float, float] | None = None
        """This step's turn on the spot (a unicycle before a steep ramp; :func:`copath.detour.turn_command`)."""

    def step(self, now: float, pose: np.ndarray, ranges, angles, inbox: list[PeerMessage], events: list[Event],
             held: bool, liveness: LivenessStage, safety: SafetyStage | None) -> tuple[np.ndarray, float]:
        """The pose the controller sees and the lane's shift; the stage's events are appended
        to ``events``. A robot the runtime holds still (cut off) plans nothing."""
        self._stretch = self._turn = None
        if self.planner is None or held:
            self._held_at = now
            return pose, 0.0
        planner, peers, quiet_held = self.planner, [], False
        # a robot just released from a cut-off hold judged the others silent from its own
        # deafness: until it has listened for a lease, their held discs are not blocks
        deaf = self._held_at is not None and now - self._held_at <= self._lease
        quiet = liveness.quiet_for_filter(now) if safety is not None else frozenset()
        lost = liveness.lost
        if self._wait and lost:  # a robot the fleet restarts blocks the lane once lost for the wait
            at = liveness.lost_at
            lost = frozenset(r for r in lost if now - at.get(r, now) >= self._wait - 1e-9)
        if safety is not None and (ranges is not None or liveness.lost or quiet
                                   or planner.plan is not None or planner.stalled(now)
                                   or planner.held_back(now)):
            # a held disc is a block only while its robot is lost or quiet at this step: the filter
            # learns of a return in its own stage, after this one, and a robot restarted this very
            # tick was once planned round as a disc grown for its outage (an E5.4 soak: a 0.81 m
            # detour, the column out of order for a minute; docs/journal/faults.md, "Chaos soak, realtime")
            gone = lost | quiet
            for name, nb in safety.guard.named_neighbours(now):  # held discs, and live ones to tell teammates in the ring
                spread = nb.spread if nb.spread is not None else nb.speed_max * nb.age
                held_now = nb.held and not deaf and name in gone
                quiet_held = quiet_held or (held_now and name not in liveness.lost)
                peers.append((nb.position[0], nb.position[1], nb.radius + (0.0 if nb.held else spread), held_now))
        else:
            for m in inbox:
                if m.position is not None:
                    self._positions[m.sender] = (m.position[0], m.position[1], m.stamp)
            for r, (x, y, stamp) in self._positions.items():
                spread = min(0.5 * max(now - stamp, 0.0), 0.5)
                peers.append((x, y, self._radii.get(r, 0.0) + spread, r in lost and not deaf))
        pressed = False
        if safety is not None:
            pressed = safety.guard.interventions != self._interventions
            self._interventions = safety.guard.interventions
        out = planner.step(now, pose, ranges, angles, peers, pressed, quiet_held)
        self._stretch, self._turn = out.stretch, out.turn
        events += [Event(float(now), self.robot, what, detail) for what, detail in out.events]
        return out.pose, out.offset

    @property
    def turning(self) -> bool:
        """Whether this step turns the robot on the spot before a detour's ramp."""
        return self._turn is not None

    def command(self, cmd, applied=None):
        """The controller's command mapped onto the shifted lane (:func:`copath.detour.stretch_command`),
        or a turn on the spot before a steep ramp (:func:`copath.detour.turn_command`, from the
        command the robot ``applied`` last); the same object while no lane is shifted."""
        return turn_command(stretch_command(cmd, self._stretch), self._turn, self._model, applied, self._dt)
