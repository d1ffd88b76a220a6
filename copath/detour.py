"""Detours round a blocked lane: a runtime stage between the observation and any controller.

The dissertation's path-following laws (Chapters 4-6) keep a robot on its path; obstacles
are handled only by the single-robot unicycle NMPC (Sec. 4.4.3). The safety filter
(``copath.safety``) keeps robots and obstacles apart but cannot make progress: a robot whose
lane is blocked stops in front of the block for good. This stage plans the lateral part of a
detour and leaves the rest to the controller, in the split of Nav2 (a planner decides where,
the controller follows, a collision monitor vetoes): here the path is the plan, the detour a
local re-plan of it, the controller unchanged and the safety filter the monitor.

The lane of a robot is its path shifted by its lateral offset q (0 on the path, q of (5.10)
for an offset slot). When a disc blocks the lane ahead (its distance from the lane less than
its radius plus the robot's radius, the safety margin and :attr:`DetourConfig.clearance_m`),
the lane is shifted sideways by a smooth bump

    d(s) = A sigma(s),   sigma: 0 before the block, a quintic ramp up, 1 alongside, a ramp down,

round the blocking discs, on the side that needs the smaller shift (ties: the robot's right,
a fixed rule as the right-hand rules of ORCA and of the safety filter's deadlock rule, so two
robots meeting head-on both keep right and pass). The controller is shown its pose moved
back onto the lane by ``-d(s) n(s)`` (and, for a unicycle, its heading turned by the bump's
slope): it follows its path as before, its path coordinate s and so its coordination
variable are unchanged, and its body-frame commands are those it would give on the path.
The safety filter still acts on the true pose, with the true margins.

Blocks come from

- obstacles declared ``known = true`` (a map every robot is given), as discs round them;
- the range ring: each reading is a point, inflated by half the gap between neighbouring rays
  at its range (an object narrower than the gap lies between two rays), less the readings
  explained by a live neighbour's disc (teammates are not obstacles: the safety filter and
  coordination handle them);
- a lost robot held still: the static disc the safety filter keeps out of
  (:meth:`copath.safety.SafetyGuard.neighbours`, docs/reference/safety.md "A lost robot"), or without the
  filter a disc round its last heard position;
- no progress: a robot that has moved less than ``stall_progress_m`` along its path for
  ``stall_s`` with a live neighbour's disc on its lane ahead goes round it on its right (the
  deadlock of two CBF-filtered robots head-on, Grover et al. 2020: the filter alone keeps
  them still on the boundary of the safe set).
- a teammate that holds the robot back: a robot that has detoured before and whose command
  the safety filter keeps changing behind a live teammate on its lane goes round it (a column
  that a detour inverted restores its order, docs/reference/detours.md, "Passing a teammate").

The stage is pure (no clock, no transport): :meth:`DetourPlanner.step` takes the time, pose,
readings and what the runtime heard, and returns the pose to show the controller and the
events of the step. docs/reference/detours.md gives the method, its constants and its limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from .models import limit_change
from .paths import Path, wrap_to_pi

__all__ = ["DetourConfig", "Disc", "DetourPlan", "DetourPlanner", "DetourStep", "bump", "polygon_disc", "ray_discs",
           "plan_shift", "stretch_command", "turn_command"]


@dataclass(frozen=True)
class DetourConfig:
    """Constants of the detour stage (docs/reference/detours.md; all chosen)."""

    lookahead_m: float = 1.2
    """How far ahead along the path the lane is checked [m]."""
    clearance_m: float = 0.06
    """Gap kept between the robot's disc and a blocking disc beyond the safety margin [m]."""
    margin_m: float = 0.01
    """The safety filter's margin (``safety.margin_m``) [m]."""
    ramp_m: float = 0.7
    """Length of the ramps into and out of the detour along the path [m]."""
    min_ramp_m: float = 0.25
    """Shortest ramp into a detour (a block seen late) [m]."""
    max_offset_m: float = 1.0
    """Largest lateral shift; a lane that needs more on both sides is blocked wall to wall [m]."""
    offset_rate_mps: float = 0.15
    """Largest rate at which the bump's height grows when a detour is widened [m/s]."""
    stall_detours: bool = True
    """Whether no progress with a live neighbour on the lane starts a detour (off where the
    safety filter's own deadlock rule already unwinds head-on jams: docs/reference/detours.md)."""
    stall_s: float = 4.0
    """No progress for this long with a live neighbour on the lane ahead starts a detour [s]."""
    stall_progress_m: float = 0.05
    """Progress along the path below which the robot counts as making none [m]."""
    memory_s: float = 3.0
    """Sensed points are kept this long after they were last seen [s]."""
    pass_detours: bool = True
    """Whether a robot that has detoured, and whose command the safety filter keeps cutting behind
    a live teammate on its lane, goes round that teammate (restores a column's order)."""
    restart_wait_s: float = 2.0
    """Under ``run.on_robot_failure = "restart"``: a robot just lost is waited for this long before its
    held disc blocks the lane; the safety filter keeps the robot out of the disc meanwhile (a
    killed process back commanding in 0.2-0.35 s, a frozen one in 1.2-1.35 s in the realtime soaks,
    docs/reference/detours.md, "A robot the fleet restarts")."""
    pressed_share: float = 0.5
    """Share of the steps of the last ``stall_s`` with the filter acting that counts as held back."""
    turn_first: bool = False
    """Whether a unicycle turns on the spot before a steep ramp round a held robot (on for a
    unicycle in a column: docs/reference/detours.md, "Turn first")."""
    turn_first_rad: float = 0.785
    """A unicycle on a detour's ramp in, further than this off the ramp's steepest heading ahead,
    turns on the spot first [rad] (Nav2's RotationShimController, its ``angular_dist_threshold``
    default; docs/reference/detours.md, "Turn first")."""
    turn_done_rad: float = 0.3925
    """... until it is within this of that heading [rad] (the shim's ``angular_disengage_threshold``
    default)."""


MIN_SPREAD = 0.25
"""A shifted lane keeps 1 - kappa q at least this (chosen: the lane's own radius of curvature
stays above a quarter of the path's, so the path coordinate of a point on it is unique nearby;
0.4 refused E5.1's follower a 0.14 m shift inside a bend round its held leader and sent it
0.94 m the other way, docs/journal/detours.md, "On by default")."""


@dataclass(frozen=True)
class Disc:
    """Something that blocks: a disc in the plane."""

    x: float
    y: float
    radius: float
    kind: str
    """``known``, ``sensed``, ``held`` or ``peer``."""


def polygon_disc(vertices) -> tuple[float, float, float]:
    """(x, y, radius) of a disc round a polygon: centred at its vertices' mean."""
    v = np.asarray(vertices, dtype=float).reshape(-1, 2)
    c = v.mean(axis=0)
    return float(c[0]), float(c[1]), float(np.max(np.hypot(*(v - c).T)))


def ray_discs(pose, ranges, angles, robot_radius: float, max_range: float) -> list[tuple[float, float, float]]:
    """(x, y, radius) of each finite range reading: the point it hit (a reading is measured from
    the robot's rim, ``sim/world.py``), inflated by half the chord between two neighbouring rays
    at that distance, so an object between two rays is covered."""
    if ranges is None or angles is None or len(angles) == 0:
        return []
    r = np.asarray(ranges, dtype=float)
    a = np.asarray(angles, dtype=float)
    ok = np.isfinite(r) & (r < max_range - 1e-9)
    if not ok.any():
        return []
    d = r[ok] + robot_radius
    b = float(pose[2]) + a[ok]
    half = d * math.sin(math.pi / len(a))
    x = float(pose[0]) + d * np.cos(b)
    y = float(pose[1]) + d * np.sin(b)
    return [(float(xi), float(yi), float(h)) for xi, yi, h in zip(x, y, half)]


def bump(u, u_lo: float, u_hi: float, ramp_in: float, ramp_out: float) -> np.ndarray:
    """The bump's shape sigma at the distance ``u`` along the path from the detour's start:
    a quintic smoothstep 6x^5 - 15x^4 + 10x^3 (zero slope and curvature at both ends) over
    [u_lo - ramp_in, u_lo], 1 on [u_lo, u_hi], the mirror ramp over [u_hi, u_hi + ramp_out]."""
    u = np.asarray(u, dtype=float)
    x_in = np.clip((u - (u_lo - ramp_in)) / max(ramp_in, 1e-9), 0.0, 1.0)
    x_out = np.clip((u_hi + ramp_out - u) / max(ramp_out, 1e-9), 0.0, 1.0)
    x = np.minimum(x_in, x_out)
    return x**3 * (10.0 + x * (-15.0 + 6.0 * x))


def _bump_slope(u: float, u_lo: float, u_hi: float, ramp_in: float, ramp_out: float) -> float:
    """d sigma / du at ``u``."""
    if u_lo - ramp_in < u < u_lo:
        x, g = (u - (u_lo - ramp_in)) / max(ramp_in, 1e-9), 1.0 / max(ramp_in, 1e-9)
    elif u_hi < u < u_hi + ramp_out:
        x, g = (u_hi + ramp_out - u) / max(ramp_out, 1e-9), -1.0 / max(ramp_out, 1e-9)
    else:
        return 0.0
    return 30.0 * x**2 * (1.0 - x) ** 2 * g


def plan_shift(lateral: Sequence[float], radii: Sequence[float], width: float, q: float) -> tuple[float, float]:
    """(shift to the left (+n, >= 0), shift to the right (<= 0)) of a lane at lateral offset
    ``q`` that clears every disc (lateral offset ``lateral[i]`` from the path, radius
    ``radii[i]``) by ``width``: the lane then passes every disc on that side; (0, 0) without
    a disc."""
    if not len(lateral):
        return 0.0, 0.0
    e = np.asarray(lateral, dtype=float) - q
    rho = np.asarray(radii, dtype=float) + width
    return max(0.0, float(np.max(e + rho))), min(0.0, float(np.min(e - rho)))


@dataclass
class DetourPlan:
    """One detour: the bump's height A (signed along the left normal), its span along the path
    in the robot's direction of travel from ``s0`` (u = dir (s - s0)), and its base lane."""

    s0: float
    direction: int
    target: float
    """Height the bump grows to [m] (signed)."""
    height: float
    """Height now [m]."""
    u_lo: float
    u_hi: float
    ramp_in: float
    ramp_out: float
    q: float
    """Lateral offset of the lane the detour leaves and rejoins [m]."""
    started: float
    reason: str
    abandoned: bool = False
    """Given up (no progress on the detour for ``stall_s``): the height falls back to 0."""
    passing: tuple[float, float] | None = None
    """A detour round a live teammate (reason ``passing``): where it was last seen; the detour
    is lengthened while it stays beside or ahead on the base lane."""
    entered: bool = False
    """A unicycle that turns first is out on the shifted lane: its controller steers again
    (docs/reference/detours.md, "Turn first")."""

    def u(self, s: float) -> float:
        return self.direction * (s - self.s0)

    def offset(self, s: float) -> float:
        return float(self.height * bump(self.u(s), self.u_lo, self.u_hi, self.ramp_in, self.ramp_out))

    def slope(self, s: float) -> float:
        """d offset / ds."""
        return self.height * self.direction * _bump_slope(self.u(s), self.u_lo, self.u_hi, self.ramp_in,
                                                          self.ramp_out)

    def steepest_in(self, s: float) -> float:
        """The steepest slope of the ramp in still ahead of ``s``: the smoothstep is steepest
        half way up (15/8 of its mean slope), and falls after."""
        mid = self.u_lo - 0.5 * self.ramp_in
        return self.slope(self.s0 + self.direction * max(self.u(s), mid))

    def done(self, s: float) -> bool:
        return self.u(s) >= self.u_hi + self.ramp_out


@dataclass
class DetourStep:
    pose: np.ndarray
    """The pose to show the controller (the true one when no detour is under way)."""
    offset: float = 0.0
    """Lateral shift of the lane now [m]."""
    events: list[tuple[str, dict]] = field(default_factory=list)
    """(what, detail) of ``detour_start`` / ``detour_end`` events of this step."""
    stretch: tuple[float, float, float] | None = None
    """An omni robot on a shifted lane: (the lane's stretch, the path's heading, the robot's
    heading) for :func:`stretch_command`; None otherwise (the command is passed on as it is)."""
    turn: tuple[float, float] | None = None
    """A unicycle to turn on the spot first: (the heading to turn to, the robot's heading) for
    :func:`turn_command`; None otherwise."""


TURN_GAIN = 2.0
"""Turn rate per radian of heading still to turn, on the spot [1/s] (chosen: the robot's own
``omega_max`` caps it; E5.4's 1 rad/s from half a radian on)."""


def turn_command(cmd, turn: tuple[float, float] | None, model=None, applied=None, dt: float = 0.0):
    """A unicycle's command while it turns on the spot first (docs/reference/detours.md, "Turn
    first"): its forward speed brought to 0 and its turn rate towards the heading ``turn[0]`` from
    ``turn[1]`` (``TURN_GAIN`` per radian, capped at ``omega_max``), as fast as its base can from
    the command it ``applied`` last (:func:`copath.models.limit_change`: ``a_max``,
    ``alpha_max``); the same object when ``turn`` is None."""
    if turn is None:
        return cmd
    w = TURN_GAIN * wrap_to_pi(turn[0] - turn[1])
    if model is not None:
        w = max(-model.omega_max, min(model.omega_max, w))
    out = np.array([0.0, w])
    if model is not None and applied is not None and dt > 0:
        out = limit_change(model, applied, out, dt)
    return out


def stretch_command(cmd, stretch: tuple[float, float, float] | None):
    """The controller's command mapped from the shown pose to the true one (the same object when
    ``stretch`` is None: no lane shifted, or a unicycle).

    The controller paces its path coordinate s as if it were on its base lane (lateral offset
    q), where a metre along the path is 1 - kappa q metres of travel; alongside the block the
    shifted lane is 1 - kappa (q + d) metres per metre of path (longer on the outside of a
    bend). The component of an omni robot's body velocity along the path's tangent is scaled
    by their ratio, ``stretch[0]``, so that s, and with it the coordination variable, advances
    at the rate the controller commands (docs/reference/detours.md, "How the controller follows
    it"). A unicycle's command is left as it is: its speed and turn rate are capped together,
    and a faster unicycle turned later round a held robot (docs/journal/detours.md, "Lane
    stretch")."""
    if stretch is None:
        return cmd
    lam, th, heading = stretch
    out = np.array(cmd, dtype=float, copy=True)
    if out.shape == (3,):
        # omni (u, v, omega) in the body frame: the path's tangent at angle th - heading
        c, s = math.cos(th - heading), math.sin(th - heading)
        along = out[0] * c + out[1] * s
        out[0] += (lam - 1.0) * along * c
        out[1] += (lam - 1.0) * along * s
    return out


class DetourPlanner:
    """One robot's detour stage (docs/reference/detours.md).

    Parameters
    ----------
    path : Path
        The robot's path.
    radius : float
        Its footprint radius [m].
    unicycle : bool
        Whether its heading is turned with the bump's slope (a unicycle steers along it; an
        omni robot's heading is its own).
    dt : float
        Control period [s].
    known : sequence of (vertices, velocity)
        Obstacles every robot is given (``known = true``): convex polygons at t = 0 and
        their constant velocities.
    sensor_max_range : float
        The range ring's range (0 without one) [m].
    config : DetourConfig
    """

    def __init__(self, path: Path, radius: float, unicycle: bool, dt: float, known: Iterable = (),
                 sensor_max_range: float = 0.0, config: DetourConfig = DetourConfig()) -> None:
        self.path = path
        self.dt = float(dt)
        self.radius = float(radius)
        self.unicycle = bool(unicycle)
        self.config = config
        self.known = [(np.asarray(v, dtype=float).reshape(-1, 2), np.asarray(vel, dtype=float).reshape(2))
                      for v, vel in known]
        self.sensor_max_range = float(sensor_max_range)
        self.plan: DetourPlan | None = None
        self.s: float | None = None
        self.direction = 1
        self._history: list[tuple[float, float, float]] = []  # (t, x, y) over the last stall_s
        self._pressed: list[tuple[float, bool]] = []  # (t, the filter acted at the step before) over the last stall_s
        self._tracked: list[tuple[float, float]] = []  # (t, s) over the last second while tracking
        self._sensed: dict[tuple[int, int], tuple[float, float, float, float]] = {}  # cell -> (x, y, r, t seen)
        self.detours = 0
        self._quiet_until = -math.inf
        """No new detour before this time (after one was given up) [s]."""
        self._turning = False
        """A unicycle turning on the spot before its ramp (:meth:`_entry_angle`)."""
        self._turned_at = -math.inf
        """The last instant it was turning on the spot [s]: no progress while it turns is not a
        detour given up."""
        self.width = self.radius + config.margin_m + config.clearance_m

    # ------------------------------------------------------------------ discs
    def _discs(self, t: float, pose, ranges, angles, peers: Sequence[tuple[float, float, float, bool]]) -> list[Disc]:
        """Everything that may block: known obstacles at ``t``, remembered sensed points not
        explained by a live peer, held peers. ``peers``: (x, y, radius, held)."""
        out = []
        for verts, vel in self.known:
            x, y, r = polygon_disc(verts + vel * t)
            out.append(Disc(x, y, r, "known"))
        live = [(x, y, r) for x, y, r, held in peers if not held]
        for x, y, r in ray_discs(pose, ranges, angles, self.radius, self.sensor_max_range):
            if any(math.hypot(x - px, y - py) <= pr + 0.05 for px, py, pr in live):
                continue  # a teammate, not an obstacle
            self._sensed[(round(x / 0.05), round(y / 0.05))] = (x, y, r, t)
        for key, (x, y, r, seen) in list(self._sensed.items()):
            if t - seen > self.config.memory_s:
                del self._sensed[key]
            else:
                out.append(Disc(x, y, r, "sensed"))
        out += [Disc(x, y, r, "held") for x, y, r, held in peers if held]
        return out

    # ------------------------------------------------------------------ tracking
    def _track(self, t: float, pose: np.ndarray) -> tuple[float, float, float, float, float]:
        """The robot's path coordinate (searched near the last one while tracking), the path's
        frame (x, y, theta, kappa) there, and its direction of travel along the path: a
        unicycle's heading, else its motion over the last second (forward until it has moved)."""
        p = pose[:2]
        if self.s is None:
            self.s = float(self.path.project(p))
            self._tracked = []
        else:
            self.s = self._nearest(p, self.s)
        frame = self.path.frame(self.s)
        self._tracked.append((t, self.s))
        while len(self._tracked) > 2 and self._tracked[0][0] < t - 1.0 - 1e-9:
            self._tracked.pop(0)
        if self.unicycle:
            self.direction = 1 if math.cos(float(pose[2]) - frame[2]) >= 0.0 else -1
        elif t - self._tracked[0][0] >= 1.0 - 1e-9 and abs(self.s - self._tracked[0][1]) > 0.02:
            self.direction = 1 if self.s > self._tracked[0][1] else -1
        return (self.s, *frame)

    def _nearest(self, p: np.ndarray, s: float) -> float:
        """The projection of p near s: Newton steps on (p - r(s)) . t(s) = 0 with the path's
        scalar frame (a robot moves a few centimetres per period; ``Path.nearest``'s sampled
        search costs a hundred times more)."""
        px, py = float(p[0]), float(p[1])
        for _ in range(4):
            x, y, th, k = self.path.frame(s)
            c, si = math.cos(th), math.sin(th)
            ex, ey = px - x, py - y
            f = ex * c + ey * si
            den = 1.0 - k * (-ex * si + ey * c)
            step = f / den if den > 0.2 else f
            step = max(-0.3, min(0.3, step))
            s += step
            if abs(step) < 1e-7:
                break
        return float(s)

    def _remember(self, t: float, p: np.ndarray) -> None:
        """Keep the robot's positions over the last ``stall_s`` (for :meth:`stalled`)."""
        self._history.append((t, float(p[0]), float(p[1])))
        while len(self._history) > 2 and self._history[1][0] <= t - self.config.stall_s + 1e-9:
            self._history.pop(0)

    def stalled(self, t: float) -> bool:
        """No progress: over the last ``stall_s`` the robot stayed within ``stall_progress_m``
        of where it is (a robot that moves along its path moves in the plane)."""
        h = self._history
        if not h or t - h[0][0] < self.config.stall_s - 1e-9:
            return False
        x, y = h[-1][1], h[-1][2]
        return all(math.hypot(a - x, b - y) < self.config.stall_progress_m for _, a, b in h)

    def held_back(self, t: float) -> bool:
        """The safety filter acted at ``pressed_share`` of the steps of the last ``stall_s``."""
        h = self._pressed
        if not h or t - h[0][0] < self.config.stall_s - 1e-9:
            return False
        return sum(p for _, p in h) >= self.config.pressed_share * len(h)

    # ------------------------------------------------------------------ step
    def step(self, t: float, pose, ranges=None, angles=None,
             peers: Sequence[tuple[float, float, float, bool]] = (), pressed: bool = False,
             quiet_held: bool = False) -> DetourStep:
        """One control instant: the pose to show the controller and the detour's events.

        ``peers``: every other robot the runtime knows of as (x, y, radius, held): ``held``
        for a lost robot held still (a static obstacle), else a live neighbour's disc.
        ``pressed``: the safety filter changed the robot's command at the step before.
        ``quiet_held``: a held robot among them is only quiet, not lost: its disc grows with its
        silence, and a robot that turns first does not (docs/reference/detours.md, "Turn first")."""
        pose = np.asarray(pose, dtype=float)
        p = pose[:2]
        discs = self._discs(t, pose, ranges, angles, peers)
        self._remember(t, p)
        self._pressed.append((t, bool(pressed)))
        while len(self._pressed) > 2 and self._pressed[1][0] <= t - self.config.stall_s + 1e-9:
            self._pressed.pop(0)
        passing = (self.plan is None and self.config.pass_detours and self.detours > 0 and t >= self._quiet_until
                   and self.held_back(t))
        live_pass = [(x, y, r) for x, y, r, held in peers
                     if not held and math.hypot(x - p[0], y - p[1]) <= 1.0] if passing else []
        reach = self.config.lookahead_m + self.width + 0.5
        near = [d for d in discs if math.hypot(d.x - p[0], d.y - p[1]) <= reach + d.radius]
        live_near = []
        if self.plan is None and not near:
            if self.config.stall_detours and self.stalled(t):
                live_near = [(x, y, r) for x, y, r, held in peers
                             if not held and math.hypot(x - p[0], y - p[1]) <= 1.0]
            if not live_near and not live_pass:
                self.s = None  # nothing to track: the stage costs next to nothing away from obstacles
                return DetourStep(pose)
        s, x0, y0, th0, k0 = self._track(t, pose)
        events: list[tuple[str, dict]] = []
        n0 = np.array([-math.sin(th0), math.cos(th0)])
        e_now = float((p - np.array([x0, y0])) @ n0)
        plan = self.plan
        q = plan.q if plan is not None else e_now
        if plan is None and t < self._quiet_until:
            return DetourStep(pose, 0.0, events)
        if plan is None:
            reason = None
            blocking = self._blocking(s, q, near, 0.0, self.config.lookahead_m)
            if blocking:
                reason = blocking[0][0].kind
            elif live_near:
                peer_discs = [Disc(x, y, r, "peer") for x, y, r in live_near]
                blocking = self._blocking(s, q, peer_discs, 0.0, 0.6)
                reason = "stalled" if blocking else None
            if not blocking and live_pass:
                peer_discs = [Disc(x, y, r, "peer") for x, y, r in live_pass]
                blocking = self._blocking(s, q, peer_discs, 0.0, 0.6)
                reason = "passing" if blocking else None
            if blocking:
                # passing a teammate in a column: the lane is the teammate's (the robot held back
                # behind it is pushed off its own by the filter)
                plan = self._new_plan(t, s, blocking[0][2] if reason == "passing" else q, blocking, near, reason,
                                      self.stalled(t))
                if plan is not None and reason == "passing":
                    plan.passing = (blocking[0][0].x, blocking[0][0].y)
                if plan is not None:
                    self.plan = plan
                    self.detours += 1
                    events.append(("detour_start", {"reason": reason, "side": "left" if plan.target * plan.direction > 0 else "right",
                                                    "offset_m": round(abs(plan.target), 4), "s": round(s, 4)}))
        elif (not plan.abandoned and t - max(plan.started, self._turned_at) >= self.config.stall_s
              and self.stalled(t)):
            # no progress on the detour itself (a unicycle that cannot turn round a block seen
            # too close): give it up smoothly and leave the robot to the safety filter a while
            plan.abandoned, plan.target = True, 0.0
            self._quiet_until = t + 2.0 * self.config.stall_s
        elif not plan.abandoned and plan.reason == "held" and not any(d.kind == "held" for d in near):
            # the held robot is back (heard again): nothing is left to go round; fall back smoothly
            plan.abandoned, plan.target = True, 0.0
        elif not plan.abandoned:
            self._extend(plan, s, near)
            if plan.passing is not None:
                self._follow(plan, s, peers)
        plan = self.plan
        if plan is None:
            return DetourStep(pose, 0.0, events)
        # the height grows towards the target at a bounded rate (a widened detour does not jump)
        step = self.config.offset_rate_mps * self.dt
        plan.height += max(-step, min(step, plan.target - plan.height)) if plan.height != plan.target else 0.0
        if plan.done(s) or (plan.abandoned and plan.height == 0.0):
            events.append(("detour_end", {"duration_s": round(t - plan.started, 3), "s": round(s, 4),
                                          "abandoned": plan.abandoned}))
            self.plan = None
            return DetourStep(pose, 0.0, events)
        d = plan.offset(s)
        entry = self._entry_angle(plan, s, p, near, quiet_held) if self.unicycle else None
        turn = None
        if entry is not None:
            want = th0 + (0.0 if plan.direction > 0 else math.pi) + entry
            err = abs(wrap_to_pi(want - float(pose[2])))
            self._turning = err > (self.config.turn_done_rad if self._turning else self.config.turn_first_rad)
            if self._turning:
                self._turned_at = t
                turn = (want, float(pose[2]))
        else:
            self._turning = False
        if d == 0.0 and entry is None:
            return DetourStep(pose, 0.0, events)
        seen = pose.copy()
        seen[:2] = p - d * n0
        spread = 1.0 - k0 * (plan.q + d)
        if self.unicycle:
            seen[2] = pose[2] - (math.atan2(plan.slope(s), spread) if entry is None else plan.direction * entry)
            return DetourStep(seen, d, events, turn=turn)
        base = 1.0 - k0 * plan.q
        return DetourStep(seen, d, events, (spread / base, th0, float(pose[2])) if base > 1e-6 else None)

    def _entry_angle(self, plan: DetourPlan, s: float, p: np.ndarray, near: Sequence[Disc], quiet_held: bool
                     ) -> float | None:
        """The heading, off the direction of travel (> 0: to the left), that a unicycle which turns
        first holds on the ramp into its detour; None when it does not turn first
        (docs/reference/detours.md, "Turn first").

        On the ramp into a detour (before the lane is fully shifted) the lane's heading is the
        path's turned by the ramp's slope; a block met late gets a short, steep ramp (up to 70
        degrees for 0.36 m over 0.25 m) that a unicycle driving on at its pace enters before it
        has turned, into the block. So, as Nav2's RotationShimController does before its path
        follower drives, a robot further than ``turn_first_rad`` off this heading turns on the
        spot towards it until within ``turn_done_rad``, and its controller is shown it as the
        lane's heading until the ramp is behind it, so that it drives out along the turn instead
        of turning back to the ramp's flat start. A robot within a held disc's clearance (its
        radius plus the detour's width) does not turn first: its way out is the tangent or
        behind, where the safety filter's look-ahead rows steer it; nor does one whose ramp in
        is behind it (``plan.entered`` from then on), nor one near a robot held because it is
        quiet, whose disc, grown with its silence, gives gentler ramps and more robots turning
        in a row."""
        cfg = self.config
        if not cfg.turn_first or plan.reason != "held" or plan.abandoned or plan.entered or quiet_held:
            return None
        u = plan.u(s)
        reached = any(d.kind == "held" and math.hypot(d.x - float(p[0]), d.y - float(p[1])) < d.radius + self.width
                      for d in near)
        if u >= plan.u_lo or reached:
            plan.entered = True  # on the shifted lane, or at the held disc's edge already: the controller steers
            return None
        return plan.direction * math.atan2(plan.steepest_in(s), 1.0)

    def _lane(self, s: float, q: float, u0: float, u1: float, n: int = 25):
        """Points of the lane at lateral offset q from u0 to u1 ahead, with their s."""
        ss = s + self.direction * np.linspace(u0, u1, n)
        x, y, th, _ = self.path.frame(ss)
        return ss, np.stack([x - q * np.sin(th), y + q * np.cos(th)], axis=-1)

    def _blocking(self, s: float, q: float, discs: Sequence[Disc], u0: float, u1: float
                  ) -> list[tuple[Disc, float, float]]:
        """(disc, its u along the lane, its lateral offset from the path) of the discs on the lane
        at lateral offset q between u0 and u1 ahead."""
        if not discs:
            return []
        ss, P = self._lane(s, q, u0, u1)
        th = float(self.path.frame(float(ss[0]))[2])
        tx, ty = self.direction * math.cos(th), self.direction * math.sin(th)
        out = []
        for d in discs:
            if (d.x - P[0, 0]) * tx + (d.y - P[0, 1]) * ty <= 0.0:
                continue  # centred behind: driving on leads out of it (a held robot just behind)
            dist = np.hypot(P[:, 0] - d.x, P[:, 1] - d.y)
            k = int(np.argmin(dist))
            if dist[k] < d.radius + self.width:
                x, y, th, _ = self.path.frame(float(ss[k]))
                lat = -(d.x - x) * math.sin(th) + (d.y - y) * math.cos(th)
                out.append((d, self.direction * (float(ss[k]) - s), float(lat)))
        return out

    def _new_plan(self, t: float, s: float, q: float, blocking, near: Sequence[Disc], reason: str,
                  stalled: bool = False) -> DetourPlan | None:
        """The detour round ``blocking`` from the robot's path coordinate ``s`` (None: no side has
        room). Its ramp in ends where the first disc begins and is at least ``min_ramp_m`` long;
        a robot ``stalled`` in front of a disc nearer than that gets the ramp behind it, so the
        shift shows in what its controller sees at once (a step in the pose it is shown, taken
        at rest): a ramp that begins where a robot stands still is one it never enters
        (docs/reference/detours.md, "A robot stalled at the block")."""
        cfg = self.config
        right = -self.direction  # the robot's right as a sign along the left normal n
        side = self._side(s, q, blocking, near, right, prefer_right=reason in ("stalled", "passing"))
        if side is None:
            return None
        target, group = side
        u_lo = min(u - d.radius - self.width for d, u, _ in group)
        u_hi = max(u + d.radius + self.width for d, u, _ in group)
        if stalled and u_lo < cfg.min_ramp_m:
            ramp_in, u_lo = cfg.min_ramp_m, max(u_lo, 0.0)
        else:
            ramp_in = min(cfg.ramp_m, max(u_lo, cfg.min_ramp_m))
            u_lo = max(u_lo, ramp_in)
        return DetourPlan(s, self.direction, target, target, u_lo, max(u_hi, u_lo), ramp_in, cfg.ramp_m, q, t, reason)

    def _side(self, s: float, q: float, blocking, near: Sequence[Disc], right: int, prefer_right: bool):
        """(signed height, the discs it clears) of the side that needs the smaller shift and whose
        shifted lane is free of every other disc near; ties (within 2 cm) and stalls go right."""
        cfg = self.config
        options = []
        for sign in (right, -right):
            group = list(blocking)
            for _ in range(4):  # widen round discs the shifted lane would meet
                left_shift, right_shift = plan_shift([lat for _, _, lat in group], [d.radius for d, _, _ in group],
                                                     self.width, q)
                h = left_shift if sign > 0 else right_shift
                if abs(h) > cfg.max_offset_m:
                    h = None
                    break
                if not self._room(s, q + h, group):
                    h = None
                    break
                more = [b for b in self._blocking(s, q + h, near, 0.0, cfg.lookahead_m + 0.5)
                        if all(b[0] is not g[0] for g in group)]
                if not more:
                    break
                group += more
            else:
                h = None
            if h is not None:
                options.append((abs(h), sign != right, h, group))
        if not options:
            return None
        if prefer_right and any(not o[1] for o in options):
            options = [o for o in options if not o[1]]
        best = min(options, key=lambda o: (o[0] - 0.02 * (not o[1]), o[1]))
        return best[2], best[3]

    def _room(self, s: float, q: float, group) -> bool:
        """Whether a lane at lateral offset q stays well short of the path's centres of
        curvature alongside the discs (1 - kappa q >= MIN_SPREAD): inside a tight bend the
        offset lane would fold over itself and the path coordinate would jump."""
        u1 = max(u for _, u, _ in group) + self.config.ramp_m
        ss = s + self.direction * np.linspace(0.0, u1, 25)
        kappa = np.asarray(self.path.kappa(ss), dtype=float)
        return bool(np.all(1.0 - kappa * q >= MIN_SPREAD))

    def _follow(self, plan: DetourPlan, s: float, peers) -> None:
        """A detour round a live teammate: lengthened while the teammate (the live disc nearest
        where it was last seen) stays beside or ahead, so the robot rejoins its lane past it."""
        px, py = plan.passing
        live = [(x, y, r) for x, y, r, held in peers if not held and math.hypot(x - px, y - py) <= 0.3]
        if not live:
            return
        x, y, r = min(live, key=lambda d: math.hypot(d[0] - px, d[1] - py))
        plan.passing = (x, y)
        if plan.u(s) > plan.u_hi:
            return  # rejoining
        u = plan.direction * (float(self._nearest(np.array([x, y]), s)) - plan.s0) + r + self.width
        plan.u_hi = max(plan.u_hi, u)

    def _extend(self, plan: DetourPlan, s: float, near: Sequence[Disc]) -> None:
        """Discs newly seen on the base lane beside or ahead of the detour widen and lengthen it,
        on the same side (a box whose far side comes into view)."""
        u = plan.u(s)
        top = plan.u_hi + plan.ramp_out + 0.2
        if u > plan.u_hi + 0.5 * plan.ramp_out:
            return  # rejoining: what lies ahead is the next detour's
        ss = plan.s0 + plan.direction * np.linspace(max(u - 0.3, 0.0), top, 25)
        x, y, th, _ = self.path.frame(ss)
        P = np.stack([x - plan.q * np.sin(th), y + plan.q * np.cos(th)], axis=-1)
        for d in near:
            dist = np.hypot(P[:, 0] - d.x, P[:, 1] - d.y)
            k = int(np.argmin(dist))
            if dist[k] >= d.radius + self.width:
                continue
            lat = -(d.x - x[k]) * math.sin(th[k]) + (d.y - y[k]) * math.cos(th[k])
            need = (lat - plan.q + d.radius + self.width) if plan.target > 0 else (lat - plan.q - d.radius - self.width)
            if plan.target > 0 and need > plan.target:
                plan.target = min(need, self.config.max_offset_m)
            elif plan.target < 0 and need < plan.target:
                plan.target = max(need, -self.config.max_offset_m)
            uk = plan.direction * (float(ss[k]) - plan.s0) + d.radius + self.width
            plan.u_hi = max(plan.u_hi, uk)
