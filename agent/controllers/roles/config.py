"""Configuration of the role-assignment controller (Chapter 6; values of E6.1-E6.5)."""

from __future__ import annotations

from dataclasses import dataclass

from copath.config import require
from copath.occupancy import ARRIVE_TOL_M

__all__ = ["RolesConfig", "ORIENTATIONS"]

ORIENTATIONS = ("consensus", "given")


@dataclass(frozen=True)
class RolesConfig:
    """Parameters of :class:`agent.controllers.roles.controller.RolesController`."""

    formations: tuple[tuple[tuple[float, float], ...], ...] = ()
    """Queue of target formations, each a list of template positions x^d_k [m]; a scenario
    gives them as ``formations_files = ["shapes/letter-r.csv", ...]`` (CSV of x,y rows, read
    by the scenario loader)."""
    orientation: str = "consensus"
    """``consensus``: rotation from the robots' first principal axis (Algorithm 6.1);
    ``given``: the templates keep their orientation, rotated by ``rotation_rad`` (E6.1)."""
    rotation_rad: float = 0.0
    """Counter-clockwise rotation of the templates when ``orientation = "given"`` [rad]."""
    transform_every_task: bool = True
    """Agree on translation (and rotation) again before every formation (E6.2, E6.5);
    False computes it once at the start and keeps it (E6.1)."""
    relay_positions: bool = False
    """Relay the table of known start positions and claims over several hops, so the local
    Hungarian problem covers every robot a robot has heard of, not only its neighbours
    (the text exchanges positions with neighbours only)."""
    gather_s: float = 1.0
    """With ``relay_positions``: the table must not have grown for this long before the
    initial choice [s]."""
    isotropy: float = 1.2
    """Principal axis fallback: lambda_1 < isotropy * lambda_2 keeps the template's own
    orientation (robots or template nearly isotropic)."""
    consensus_gain: float = 1.0
    """Multiplier of the Metropolis step (1 = Metropolis iteration)."""
    consensus_tol: float = 1e-3
    """Local agreement that ends the consensus: neighbour estimates and own change over
    ``consensus_hold_s`` within this [m, m^2]."""
    consensus_hold_s: float = 2.0
    """How long the agreement must hold before the transform is adopted [s]."""
    consensus_timeout_s: float = 60.0
    """Adopt the current estimate after this long even without agreement [s]."""
    k_c: float = 1.0
    """Heading gain of (6.11) [1/s]."""
    gamma: float = 0.5
    """gamma = |v_max| of (6.11) [m/s]."""
    k_r: float = 0.2
    """Repulsion gain k_r of (6.12)."""
    R_max: float = 0.4
    """Influence distance of the potential field (6.12) [m]."""
    F_max: float = 5.0
    """Clip of the repulsive displacement [m]: only a numerical guard, since (6.11) bounds
    the speed by gamma whatever the distance to the shifted target (a clip below the
    distance to the target would let a robot drive on into an obstacle)."""
    side: float = 0.5
    """Sideways share of the repulsion against head-on standstills."""
    threshold: float = 0.1
    """Task-switch threshold on z of (6.16)."""
    k_z: float = 0.2
    """Forgetting factor k_z of (6.16) [1/s]."""
    k_p: float = 8.0
    """Proportional gain on the Metropolis Laplacian in (6.16) [1/s]."""
    k_i: float = 4.0
    """Integral gain on the Metropolis Laplacian in (6.16) [1/s]."""
    min_task_s: float = 2.0
    """Shortest time spent on a task before the threshold may end it [s]."""
    arrive_tol: float = ARRIVE_TOL_M
    """A robot has finished its task within this distance of its target [m]."""
    stop_radius: float = 0.01
    """Closer than this to the (shifted) target the robot stands still [m]."""
    park_clearance: float = 0.5
    """Distance a robot without a role keeps from every target [m]."""
    settle_s: float = 1.5
    """A robot without a role has finished when it has not moved for this long [s]."""
    neighbour_timeout_s: float = 0.5
    """A neighbour not heard for this long leaves N_i [s]."""
    stuck_s: float = 3.0
    """Standstill detection: less than 3 cm of motion over this long away from the target [s]."""
    escape_s: float = 2.0
    """Duration of a sideways target change that breaks a standstill [s]."""
    escape_m: float = 0.3
    """Size of that sideways change [m]."""

    def __post_init__(self) -> None:
        require(len(self.formations) >= 1, "formations", self.formations,
                "need at least one formation (formations_files = [...])")
        for i, f in enumerate(self.formations):
            require(len(f) >= 1, f"formations[{i}]", f, "a formation needs at least one position")
        require(self.orientation in ORIENTATIONS, "orientation", self.orientation, f"allowed: {', '.join(ORIENTATIONS)}")
        require(self.isotropy >= 1.0, "isotropy", self.isotropy, "must be >= 1")
        require(0.0 < self.consensus_gain <= 2.0, "consensus_gain", self.consensus_gain, "must be in (0, 2]")
        for name in ("consensus_tol", "k_c", "gamma", "k_r", "R_max", "F_max", "k_z", "k_p", "arrive_tol",
                     "park_clearance", "neighbour_timeout_s", "stuck_s", "escape_s", "consensus_timeout_s"):
            v = getattr(self, name)
            require(v > 0, name, v, "must be > 0")
        for name in ("gather_s", "consensus_hold_s", "k_i", "side", "min_task_s", "stop_radius", "settle_s", "escape_m"):
            v = getattr(self, name)
            require(v >= 0, name, v, "must be >= 0")
        require(0.0 < self.threshold < 1.0, "threshold", self.threshold, "must be in (0, 1)")
        require(self.stop_radius < self.arrive_tol, "stop_radius", self.stop_radius, "must be < arrive_tol")


