"""The virtual vehicle of path following, advanced at the actual step times.

Path following lets a virtual vehicle move along the path with a speed s-dot that the
controller chooses (Secs. 4.2, 4.4, 5.3). Between control instants the chosen s-dot is
held (the zero-order hold of the inputs, (2.17)), and the time between instants is the
measured one, not the nominal period: the robots of Secs. 5.3.3 and 5.4.3 run
asynchronously with varying cycle times. :class:`VirtualVehicle` is that bookkeeping::

    vehicle = VirtualVehicle(s0)              # s0 = None: set it at the first step
    ...
    def step(self, obs, inbox):
        if not vehicle.started:
            vehicle.start(path.project(obs.pose[:2]))
        s = vehicle.advance(obs.t)            # s at this instant
        sdot = ...                            # chosen by the controller
        vehicle.hold(obs.t, sdot)             # held until the next instant
"""

from __future__ import annotations

__all__ = ["VirtualVehicle"]


class VirtualVehicle:
    """Path coordinate s [m] moving with the last chosen speed s-dot [m/s].

    Parameters
    ----------
    s : float, optional
        Initial path coordinate; None means "not placed yet" (see :meth:`start`).
    """

    def __init__(self, s: float | None = None) -> None:
        self.s: float | None = None if s is None else float(s)
        self.sdot = 0.0
        """Speed held since :attr:`t` [m/s]."""
        self.t: float | None = None
        """Time up to which s has been advanced with :attr:`sdot` [s], None before the
        first :meth:`hold`."""

    @property
    def started(self) -> bool:
        """True once the vehicle has a path coordinate."""
        return self.s is not None

    def start(self, s: float) -> None:
        """Place the vehicle at s (e.g. the projection of the robot onto the path)."""
        self.s = float(s)

    def advance(self, t: float) -> float:
        """Move s to time t with the held speed (never backwards in time); returns s.

        Advancing twice to the same time moves s once."""
        if self.s is None:
            raise ValueError("the virtual vehicle has no path coordinate yet; call start(s) first")
        if self.t is not None and t > self.t:
            self.s += self.sdot * (t - self.t)
            self.t = float(t)
        return self.s

    def hold(self, t: float, sdot: float) -> None:
        """Hold speed ``sdot`` from time t on."""
        self.t, self.sdot = float(t), float(sdot)
