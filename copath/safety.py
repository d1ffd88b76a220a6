"""Decentralised safety filter: control barrier functions around any controller's command.

The dissertation's multi-robot laws (DMPC Sec. 5.4, consensus Sec. 5.5, leader-following
Sec. 5.3, the Chapter 6 navigation (6.11)) keep a formation geometry but have no
collision avoidance between robots. This filter sits between a controller and the robot
and changes the nominal command as little as possible so that robot discs (the models'
``radius``, Chapter 3) never overlap, in the spirit of the safety barrier certificates of
Wang, Ames and Egerstedt, "Safety barrier certificates for collisions-free multirobot
systems", IEEE Trans. Robotics 33(3), 2017, in their decentralised form: each robot solves
its own small QP with only what it hears and takes half of every pairwise constraint.

Per robot i and heard neighbour j (centre ``p_j`` from the neighbour's message, age
``a_j``; own centre ``p_i``, kinematics (3.1)/(3.3)):

    h_ij = ||p_i - p_j|| - (r_i + r_j + margin + s_j a_j)            (barrier, [m])
    n_ij^T pdot_i >= -(gamma / 2) h_ij,   n_ij = (p_i - p_j) / ||p_i - p_j||

where ``s_j`` bounds the neighbour's speed, so ``s_j a_j`` is the distance it may have
moved since it sent its position. When its model declares acceleration limits (enforced by
the simulator) and its message carries its velocity, it lies instead within
:func:`prediction_bound` of the arc predicted from that velocity (:func:`predict_position`),
a tighter disc; with only an assumed ``accel_max_mps2``, within a disc around a two-sample
extrapolation (:class:`SafetyGuard`). A robot whose own model declares ``a_max`` closes a gap
at most at the speed from which it can still stop in its half (``braking``); docs/reference/safety.md,
"Acceleration limits". The true direction to it is then within
``kappa = 2 sin(asin(rho / d) / 2)`` of ``n_ij`` (``rho`` that distance, ``d`` the heard
separation), so every neighbour row is tightened to ``n_ij^T pdot_i - kappa |pdot_i|``: two
rows (both signs of v) for a unicycle, six (a polygon bound on the speed) for an omni robot.
A range reading (sensor ring, Sec. 4.4.3) gives a point ``o`` with the same half condition
``n^T pdot_i >= -(gamma / 2) h``: a static obstacle is then only approached more slowly, and
a point on another robot, whose own filter sees this one too, is covered as a pair. ``pdot_i = G(theta) u`` is linear in the command
(omni: the body velocities rotated; unicycle: ``v (cos theta, sin theta)``, so these rows
constrain only v of a unicycle).

A unicycle also steers: its look-ahead point ``z_i = p_i + l (cos theta, sin theta)`` moves
with ``zdot = T(theta) (v, omega)``, T invertible for l > 0 (the mapping of the Robotarium's
``create_unicycle_barrier_certificate``). A neighbour's heading is not in its messages, so
its look-ahead point is only known to lie within ``l_j`` of its centre; the look-ahead rows

    h_z = ||z_i - p_j|| - (r_i + r_j + margin + s_j a_j + l_i + l_j),
    n_z^T zdot_i >= -(gamma / 2) h_z

keep the centres apart whenever h_z >= 0 (``||p_i - p_j|| >= ||z_i - p_j|| - l_i``). They
are soft (a slack of their own) and not clamped (a look-ahead point inside its disc is pushed
out gently), while the centre rows stay hard: those carry the guarantee. The filter is the QP

    min_u (u - u_ref)^T W (u - u_ref) + rho (sigma + sigma^2) + rho_z (sigma_z + sigma_z^2)
    s.t.  n^T G u + sigma >= -gamma_share max(h, 0)   (centre rows, range readings),
          n_z^T T u + sigma_z >= -gamma_share h_z      (look-ahead rows),  sigma, sigma_z >= 0,
          model limits (omni wheel speeds (3.2); unicycle |v| <= v_max, |omega| <= omega_max),
          optional speed cap |pdot| <= speed_max_mps,

solved by CasADi's ``conic`` interface with DAQP, with ``u_ref`` the nominal command. A centre
barrier already crossed (h < 0: an overlapping start, or a stale neighbour's grown disc) only
forbids closing in further (h clamped at 0), so stopping (u = 0) always satisfies every hard
row; the slack ``sigma`` (exact penalty) is a guard that keeps the QP solvable whatever the
numbers. A nominal command that already satisfies every row (after the model's own
saturation) is returned unchanged: the filter is inactive, and bit for bit invisible, away
from other robots.

Committed plans (``commit_accel_mps2``; docs/reference/safety.md, "Committed plans"): each robot
promises to stay, for ``commit_horizon_s`` after every envelope it publishes, within
``e(tau) = commit_radius_m + commit_speed_mps tau + commit_accel_mps2 tau^2 / 2`` of the arc
that envelope's position and velocity predict, and keeps every such promise a neighbour may
still hold (soft rows, :meth:`SafetyFilter.tube_rows`; leaving a tube is counted). A
neighbour heard ``tau`` ago is then a disc of radius e(tau) moving along its arc, which the
robot keeps out of by itself, with the whole gap: ``n^T (pdot - c') - e' >= -gamma h``
(braking-aware for ``a_max``). One robot's rows keep a pair apart while the other keeps its
promise, as the assumed trajectories of the DMPC (Sec. 5.4) and the compatibility constraints
of Dunbar and Murray (Automatica 42(4), 2006) let neighbours plan against each other.

A robot whose liveliness went (its process died or froze; ``continue``/``restart``) is held still
by the simulator: it is a static disc round where it may have stopped, kept out of with the
whole gap and never forgotten with age (:meth:`SafetyGuard._held`; docs/reference/safety.md, "A lost
robot"), instead of a position that ages and is forgotten after ``max_age_s``. A robot gone
quiet (no message for the lease) is kept alike: every robot holds itself still once it has
lost every other one (the runtime's cut-off rule), so a silent robot stops at a time the others
can bound from its last stamp (``silent_hold_s`` later; docs/reference/safety.md, "A lost robot").

Deadlock rule (after Wang, Ames and Egerstedt 2017, Sec. VI): when a barrier slows the
robot, the QP is solved once more with ``u_ref`` the nominal velocity of the steered point
turned to the right by ``deadlock_turn_rad``; fixed and decentralised, so symmetric jams
(twelve robots crossing a circle) unwind into a roundabout and lockstep runs stay
reproducible.

The derivation, the chosen constants and the guarantee are written out in
``docs/reference/safety.md``. The filter is pure: no clock, no transport; the runtime times it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Mapping, NamedTuple, Sequence

import numpy as np

from .config import require
from .models import OmniModel, UnicycleModel, scale_velocities

__all__ = ["SafetyConfig", "GuardConfig", "Neighbour", "Tube", "TubeSet", "SafetyResult", "SafetyFilter", "SafetyGuard",
           "max_speed", "max_turn_rate", "prediction_bound", "predict_position", "commit_radius", "plan_velocity"]


def require_lag(key: str, value, allowed_more: str = "") -> None:
    """Check a command lag (``safety.command_lag_periods``, docs/reference/safety.md, "Late
    commands"): a finite number of control periods >= 1; ``allowed_more`` adds to the message."""
    require(isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 1,
            key, value, f"must be a number of control periods >= 1{allowed_more}")


@dataclass(frozen=True)
class SafetyConfig:
    """The ``[safety]`` table of a scenario (one filter per robot, same settings for all)."""

    enabled: bool = False
    """Filter every robot's command (off unless the scenario turns it on)."""
    detours: bool = True
    """Detour round a blocked lane (``copath/detour.py``, docs/reference/detours.md): a path follower
    leaves its lane round an obstacle or a held robot and rejoins it. On by default (issue 20:
    every path-following family gets round a blocked lane without opting in); it acts only where
    something blocks a lane, so runs without obstacles or failures keep their figures.
    ``false`` turns it off (the robots then stop in front of a block, as before it)."""
    gamma: float | None = None
    """Barrier gain gamma [1/s]: a gap h may close at most at rate gamma h, each robot of a pair
    taking half; gamma * dt <= 1 keeps the discrete-time step from overshooting. None: 0.8 / dt
    (chosen)."""
    margin_m: float = 0.01
    """Clearance added to the sum of the two footprint radii [m] (chosen)."""
    speed_max_mps: float | None = None
    """Speed bound of every filtered robot [m/s]: each filter caps its own robot's speed at it and
    assumes it of its neighbours. None: no cap, neighbours bounded by their model's limit."""
    accel_max_mps2: float | None = None
    """Assumed bound on every robot's acceleration [m/s^2] (not enforced; a neighbour whose model
    declares ``a_max`` and sends its velocity is predicted with that instead). With it, a neighbour's
    position is extrapolated with the velocity of its last two messages and inflated by
    accel_max_mps2 * (now - t_previous) * age when that is tighter than speed * age.
    None: speed bound only."""
    braking: bool = True
    """Robots whose model declares an acceleration limit a_max (enforced by the simulator) get
    braking-distance-aware rows: their share of a gap h closes at most at sqrt(a_max h), the
    speed from which they can still stop within h / 2 (docs/reference/safety.md, "acceleration limits").
    False: first-order rows only, which assume the command is reached at once."""
    max_age_s: float = 2.0
    """A neighbour's position older than this is forgotten [s] (it left communication)."""
    overhear: bool = True
    """Fixed graphs: also read the position in the broadcasts of robots that are not graph
    neighbours (the controller still hears only its neighbours). Lockstep runs then wait for
    every overheard message too (docs/reference/faults.md, "Overheard messages and the
    lockstep barrier")."""
    use_ranges: bool = True
    """Add a barrier per range reading when the scenario has sensors."""
    slack_weight: float = 1.0e4
    """Exact-penalty weight rho of the barrier slack (chosen)."""
    lookahead_m: float = 0.05
    """Unicycles: distance l of the look-ahead point z = p + l (cos theta, sin theta) whose
    velocity the filter shapes, so it can steer as well as brake [m]; 0 filters v only
    (chosen: 0.05 m, the Robotarium's projection distance)."""
    deadlock_turn_rad: float | None = None
    """Deadlock rule: while a barrier slows the robot, its QP aims at the nominal velocity of
    the steered point (a unicycle's look-ahead point, an omni robot's centre) turned to the
    right by this angle [rad], same speed; 0 switches the rule off. None: 1.2 rad for
    unicycles (chosen: the circle swap completes clean and under delay and loss), 0 for omni
    robots (they can sidestep; the rule would cost E5.1 its formation under faults);
    docs/reference/safety.md."""

    held_turn_m: float = 0.3
    """Deadlock rule beside a held robot: when the disc of a robot lost by its token (held still
    by the simulator) lies ahead on the robot's right within this distance of its edge, and no
    live robot's disc lies ahead within it, the rule turns left instead [m] (a held robot does
    not turn, and turning right into it is a trap; docs/reference/safety.md, "Deadlock rule");
    0: always right (chosen: 0.2-0.4 m gave figures within a few points of each other on E5.6's
    circle swap, 0.15 m jammed it)."""

    commit_accel_mps2: float | None = None
    """Committed plans (docs/reference/safety.md, "Committed plans"): every filtered robot promises to stay,
    for ``commit_horizon_s`` after each envelope it publishes, within
    ``commit_radius_m + commit_accel_mps2 tau^2 / 2`` of the arc predicted from that envelope's
    position and velocity (tau the time since its stamp), and its neighbours bound it by that
    tube instead of its acceleration limits while the envelope is younger than the horizon.
    None: no commitment (the acceleration-limit bound only)."""
    commit_radius_m: float = 0.02
    """Committed plans: tube radius at the stamp [m] (chosen)."""
    commit_speed_mps: float = 0.0
    """Committed plans: growth of the tube radius with the plan's age [m/s] (the tube is
    ``commit_radius_m + commit_speed_mps tau + commit_accel_mps2 tau^2 / 2``; chosen)."""
    commit_horizon_s: float = 2.5
    """Committed plans: how long each published plan is kept [s] (chosen: above the largest
    age of information at 1 s of delay and 50 % loss in the measured runs)."""
    acknowledge_plans: bool | Literal["while_held"] = False
    """Committed plans: every envelope acknowledges the plans its filter holds, and a robot keeps
    no plan older than every robot that may hold one has acknowledged (docs/reference/safety.md,
    "Acknowledged plans"). Off by
    default (chosen: on, E5.4 with r4 killed at 30 s made 86 % of its progress without the kill
    instead of 91 %; docs/journal/faults.md, "Acknowledged plans"). ``"while_held"``: the
    envelopes acknowledge as with ``true``, and a robot leaves out unacknowledged plans only
    while it holds a robot still (lost, or gone quiet): the others keep every plan of the
    horizon, as without acknowledgements, until a robot is lost (docs/reference/safety.md,
    "Acknowledged plans while a robot is held")."""
    command_lag_periods: float | None = None
    """How many control periods one command may drive, and how late after its stamp a sent
    velocity may take effect: the filter's gain is gamma / L, its braking rows hold a speed
    for L periods, and a neighbour's prediction has a lag of L periods (docs/reference/safety.md,
    "Late commands"). None: 1 with the lockstep clock (a command drives exactly the period
    after the tick it answers: the filter as before), 2 with the realtime clock (chosen:
    commands a period late were measured, docs/journal/faults.md, "How late a realtime
    command is")."""

    def __post_init__(self) -> None:
        a_c = self.commit_accel_mps2
        require(a_c is None or (math.isfinite(a_c) and a_c > 0),
                "safety.commit_accel_mps2", self.commit_accel_mps2, "must be > 0 (or left out: no commitment)")
        require(math.isfinite(self.commit_radius_m) and self.commit_radius_m > 0, "safety.commit_radius_m",
                self.commit_radius_m, "must be > 0")
        require(math.isfinite(self.commit_speed_mps) and self.commit_speed_mps >= 0, "safety.commit_speed_mps",
                self.commit_speed_mps, "must be >= 0")
        require(math.isfinite(self.commit_horizon_s) and self.commit_horizon_s > 0, "safety.commit_horizon_s",
                self.commit_horizon_s, "must be > 0")
        if self.command_lag_periods is not None:
            require_lag("safety.command_lag_periods", self.command_lag_periods,
                        " (or left out: 1 in lockstep, 2 in realtime)")
        require(self.gamma is None or self.gamma > 0, "safety.gamma", self.gamma, "must be > 0")
        require(self.margin_m >= 0, "safety.margin_m", self.margin_m, "must be >= 0")
        require(self.speed_max_mps is None or self.speed_max_mps > 0, "safety.speed_max_mps",
                self.speed_max_mps, "must be > 0 (or left out for no cap)")
        require(self.accel_max_mps2 is None or self.accel_max_mps2 > 0, "safety.accel_max_mps2",
                self.accel_max_mps2, "must be > 0 (or left out)")
        require(self.max_age_s > 0, "safety.max_age_s", self.max_age_s, "must be > 0")
        require(isinstance(self.acknowledge_plans, bool) or self.acknowledge_plans == "while_held",
                "safety.acknowledge_plans", self.acknowledge_plans, 'must be true, false or "while_held"')
        require(self.slack_weight > 0, "safety.slack_weight", self.slack_weight, "must be > 0")
        require(math.isfinite(self.lookahead_m) and self.lookahead_m >= 0, "safety.lookahead_m",
                self.lookahead_m, "must be >= 0 (0: the filter changes only v of a unicycle)")
        require(self.deadlock_turn_rad is None or (math.isfinite(self.deadlock_turn_rad)
                                                    and 0 <= self.deadlock_turn_rad <= math.pi / 2),
                "safety.deadlock_turn_rad", self.deadlock_turn_rad, "must be in [0, pi/2] (0: no deadlock rule)")
        require(math.isfinite(self.held_turn_m) and self.held_turn_m >= 0, "safety.held_turn_m", self.held_turn_m,
                "must be >= 0 (0: the deadlock rule always turns right)")


class Neighbour(NamedTuple):
    """What the filter knows about another robot: its last heard position and how old it is.

    Immutable, with named fields, as a frozen dataclass, but built in a tenth of the time: a
    guard builds one per heard robot at every step (docs/journal/performance.md, against IR-SIM (P15))."""

    position: tuple[float, float]
    """Centre [x, y] the robot sent [m]."""
    age: float
    """Receiver's clock minus the message's stamp [s] (0 for a lost robot held still: its disc
    holds now and later)."""
    radius: float
    """Its footprint radius [m] (for a lost robot held still, grown to cover where it may have
    stopped)."""
    speed_max: float
    """Bound on its speed [m/s] (inflates its disc by speed_max * age)."""
    spread: float | None = None
    """Distance it may be from ``position`` now [m], when known better than speed_max * age."""
    lookahead: float = 0.0
    """Its look-ahead distance [m] (unicycles filtering with one): its look-ahead point is within
    this of its centre, heading unknown."""
    predicted: bool = False
    """True when ``position`` is predicted from the velocity it sent under its enforced
    acceleration limit (``spread`` the guaranteed error of that prediction)."""
    committed: tuple[float, float, float, float] | None = None
    """Committed plans: the neighbour keeps within its tube, the disc (``position``, ``spread``)
    moving at (vx, vy) [m/s] and growing at the rate [m/s], and it accelerates by at most the
    last entry [m/s^2] relative to it; None when it has made no such promise for this age."""
    held: bool = False
    """A lost robot held still by the simulator: a static disc round where it may have stopped
    (docs/reference/safety.md, "A lost robot"); the detour stage goes round it (docs/reference/detours.md)."""
    silent: bool = False
    """Held because it went quiet (no message for the lease), not because its token went: its
    disc bounds where it may have driven before holding itself, not where the simulator holds it."""


@dataclass(frozen=True)
class Tube:
    """One plan this robot published and must still honour (committed plans): at this instant it
    must be within ``radius`` of ``centre``, a disc that moves at ``velocity`` and grows at
    ``growth``."""

    centre: tuple[float, float]
    """The plan's point now [m] (the arc predicted from the published position and velocity)."""
    velocity: tuple[float, float]
    """The plan point's velocity now [m/s]."""
    radius: float
    """Tube radius now [m]: commit_radius_m + commit_accel_mps2 tau^2 / 2."""
    growth: float
    """Rate of the radius now [m/s]: commit_accel_mps2 tau."""


@dataclass(frozen=True)
class TubeSet:
    """The tubes of committed plans (docs/reference/safety.md, "Committed plans") as arrays, one row per
    :class:`Tube`: the filter's hot path makes no object per plan and step."""

    centre: np.ndarray
    """Plan points now, (k, 2) [m]."""
    velocity: np.ndarray
    """Their velocities, (k, 2) [m/s]."""
    radius: np.ndarray
    """Tube radii, (k,) [m]."""
    growth: np.ndarray
    """Rates of the radii, (k,) [m/s]."""

    def __len__(self) -> int:
        return len(self.radius)

    @staticmethod
    def of(tubes: "Sequence[Tube] | TubeSet") -> "TubeSet":
        """The arrays of ``tubes`` (returned as they are when already a set)."""
        if isinstance(tubes, TubeSet):
            return tubes
        if isinstance(tubes, _PlanTubes):
            return tubes.arrays()
        return TubeSet(np.asarray([t.centre for t in tubes], dtype=float).reshape(-1, 2),
                       np.asarray([t.velocity for t in tubes], dtype=float).reshape(-1, 2),
                       np.asarray([t.radius for t in tubes], dtype=float),
                       np.asarray([t.growth for t in tubes], dtype=float))

    def select(self, keep: np.ndarray) -> "TubeSet":
        """The tubes where the boolean mask ``keep`` is true."""
        return TubeSet(self.centre[keep], self.velocity[keep], self.radius[keep], self.growth[keep])

    def tubes(self) -> list[Tube]:
        """One :class:`Tube` per row."""
        return [Tube((float(c[0]), float(c[1])), (float(v[0]), float(v[1])), float(r), float(g))
                for c, v, r, g in zip(self.centre, self.velocity, self.radius, self.growth)]


def _tube_centre(px: float, py: float, speed: float, ch: float, sh: float, w: float, t: float, tau: float
                 ) -> tuple[float, float, float, float]:
    """A committed plan's arc at ``t`` = max(tau, 0) after its stamp (its centre x, y) and the sine and
    cosine that turn its velocity: by w tau (a plan stamped after now has its arc at tau = 0 and its
    velocity turned by w tau). The operations of :func:`predict_position` and :func:`plan_velocity`,
    in their order: the same numbers."""
    a = w * t
    sa, cas = math.sin(a), math.cos(a)
    if speed < 1e-12:
        cx, cy = px, py
    else:
        if abs(a) < 1e-9:
            dx_b, dy_b = speed * t, 0.0 * t
        else:
            dx_b = (speed * sa) / w
            dy_b = (speed * (1.0 - cas)) / w
        cx, cy = px + ch * dx_b - sh * dy_b, py + sh * dx_b + ch * dy_b
    if t is not tau:
        sa, cas = math.sin(w * tau), math.cos(w * tau)
    return cx, cy, sa, cas


class _PlanTubes:
    """A guard's tubes at one instant (committed plans), computed on floats, with what the
    filter's pass-through test needs (:meth:`SafetyFilter._clear`); the arrays (:meth:`arrays`)
    are built only when the full test runs.

    Per kept plan, ``rows`` holds the tube (centre x, y, velocity x, y, radius less
    ``TUBE_MARGIN_M``, growth): the arc of :func:`predict_position` (``_arc``, with the constants
    taken when the plan was published), :func:`plan_velocity` (the sent velocity turned by
    w tau) and :func:`commit_radius`, the same operations in the same order, so the same
    numbers. With a robot's centre (x, y) and its filter, ``normals`` holds per tube the unit
    normal ``m = d / |d|`` (d from the plan's point to the centre) and the room
    ``m^T c' + growth + rate(g) - CLEAR_MARGIN`` that ``m^T`` (steered velocity) may use (the
    terms of :meth:`SafetyFilter.tube_rows`), and ``inside`` tells whether every tube holds
    the centre by more than ``CLEAR_MARGIN`` (the guard's exact test of a broken tube would
    find none; else it runs that test on the arrays). One loop on floats costs less than the
    sixty numpy calls on arrays of 25 plans it replaces (docs/journal/performance.md, safety
    filter second pass (P19))."""

    __slots__ = ("normals", "inside", "_plans", "_now", "_cfg", "_rows", "_set")

    def __init__(self, plans, now: float, cfg: SafetyConfig, filt: "SafetyFilter | None" = None,
                 x: float = 0.0, y: float = 0.0) -> None:
        self._plans, self._now, self._cfg = list(plans), now, cfg
        self._rows = None
        self._set = None
        if filt is None:
            self.normals, self.inside = [], False
            return
        r0, cs, ca, half_a = cfg.commit_radius_m, cfg.commit_speed_mps, cfg.commit_accel_mps2, 0.5 * cfg.commit_accel_mps2
        sqrt = math.sqrt
        gamma = filt.gamma
        a_max = filt.model.a_max if filt.config.braking else None
        a_dt = 0.5 * a_max * filt.dt if a_max is not None else 0.0
        a_dt2 = a_dt**2
        normals = []
        append = normals.append
        inside = True
        # the operations of :meth:`_tube_rows`, per plan, followed by the pass-through test's terms
        for stamp, px, py, vx, vy, w, speed, ch, sh in plans:
            tau = now - stamp
            t = tau if tau >= 0.0 else 0.0
            cx, cy, sa, cas = _tube_centre(px, py, speed, ch, sh, w, t, tau)
            cvx, cvy = cas * vx - sa * vy, sa * vx + cas * vy
            radius = r0 + cs * t + half_a * (t * t) - TUBE_MARGIN_M
            dx, dy = x - cx, y - cy
            dist = sqrt(dx * dx + dy * dy)
            g = radius - dist
            if g + TUBE_MARGIN_M < CLEAR_MARGIN:
                inside = False
            inv = dist if dist > 1e-9 else 1e-9
            mx, my = dx / inv, dy / inv
            rate = gamma * g
            if a_max is not None and g > 0:
                stop = sqrt(a_dt2 + a_max * g) - a_dt
                if stop < rate:
                    rate = stop
            append((mx, my, mx * cvx + my * cvy + (cs + ca * tau) + rate - CLEAR_MARGIN))
        self.normals = normals
        self.inside = inside

    def __len__(self) -> int:
        return len(self._plans)

    @property
    def rows(self) -> list[tuple[float, float, float, float, float, float]]:
        """Per plan (centre x, y, velocity x, y, radius less ``TUBE_MARGIN_M``, growth), computed
        when first asked for (the pass-through test needs only :attr:`normals`)."""
        if self._rows is None:
            self._rows = self._tube_rows()
        return self._rows

    def _tube_rows(self) -> list[tuple[float, float, float, float, float, float]]:
        cfg, now = self._cfg, self._now
        r0, cs, ca, half_a = cfg.commit_radius_m, cfg.commit_speed_mps, cfg.commit_accel_mps2, 0.5 * cfg.commit_accel_mps2
        rows = []
        for stamp, px, py, vx, vy, w, speed, ch, sh in self._plans:
            tau = now - stamp
            t = tau if tau >= 0.0 else 0.0
            cx, cy, sa, cas = _tube_centre(px, py, speed, ch, sh, w, t, tau)
            rows.append((cx, cy, cas * vx - sa * vy, sa * vx + cas * vy, r0 + cs * t + half_a * (t * t) - TUBE_MARGIN_M,
                         cs + ca * tau))
        return rows

    def arrays(self) -> TubeSet:
        """The tubes as a :class:`TubeSet` (the same numbers)."""
        if self._set is None:
            a = np.array(self.rows, dtype=float).reshape(-1, 6)
            self._set = TubeSet(a[:, 0:2], a[:, 2:4], a[:, 4], a[:, 5])
        return self._set


def commit_radius(config: SafetyConfig, tau: float) -> float:
    """Radius of the committed tube ``tau`` after a plan's stamp [m] (docs/reference/safety.md,
    "Committed plans")."""
    tau = max(tau, 0.0)
    return config.commit_radius_m + config.commit_speed_mps * tau + 0.5 * config.commit_accel_mps2 * tau**2


def plan_velocity(velocity, tau: float) -> tuple[float, float]:
    """Velocity of the arc of :func:`predict_position` ``tau`` after the stamp [m/s]: the sent
    world velocity turned by thetadot tau."""
    vx, vy, w = float(velocity[0]), float(velocity[1]), float(velocity[2])
    c, s = math.cos(w * tau), math.sin(w * tau)
    return c * vx - s * vy, s * vx + c * vy


class SafetyResult(NamedTuple):
    """What the filter did at one instant: immutable, with named fields (a ``NamedTuple``: built
    once per robot step, in a fifth of a frozen dataclass's time)."""

    command: np.ndarray
    """Command to apply (the nominal one, unchanged, when the filter is inactive)."""
    active: bool
    """True when the nominal command violated a barrier and the QP was solved."""
    change: float
    """Norm of the change from the nominal command as the model would apply it (saturated), 0 when
    inactive."""
    slack: float = 0.0
    """Slack sigma of the barriers (> 0: a barrier could not be met within the limits)."""
    min_barrier: float = math.inf
    """Smallest centre barrier value h over the neighbours and range readings [m] (inf without any)."""
    ok: bool = True
    """False when the QP failed and the robot was stopped instead."""
    biased: bool = False
    """True when the deadlock rule's right-hand bias shaped the command."""


def max_speed(model: OmniModel | UnicycleModel) -> float:
    """Largest translational speed the model's limits allow [m/s].

    Unicycle: v_max. Omni: max over directions of qdot_max / max_k |M_k (cos phi, sin phi, 0)|
    with the wheel map (3.2) (the wheel polygon's farthest vertex; 2.19 m/s for the defaults).
    """
    if isinstance(model, UnicycleModel):
        return float(model.v_max)
    phi = np.linspace(0.0, 2 * math.pi, 721)
    d = np.stack([np.cos(phi), np.sin(phi)])
    peak = np.max(np.abs(model.M[:, :2] @ d), axis=0)
    return float(model.qdot_max / peak.min())


def max_turn_rate(model: OmniModel | UnicycleModel) -> float:
    """Largest yaw rate the model's limits allow [rad/s]: omega_max of a unicycle, qdot_max / L_w
    of an omni robot ((3.2) with u = v = 0)."""
    if isinstance(model, UnicycleModel):
        return float(model.omega_max)
    return float(model.qdot_max / model.L_w)


def prediction_bound(tau: float, speed: float, a_max: float, alpha_max: float | None, omega_bound: float,
                     lag: float) -> float:
    """Guaranteed bound on how far a neighbour is, ``tau`` after its message, from the arc
    predicted with the velocity it sent (:func:`predict_position`) [m] (docs/reference/safety.md,
    "acceleration limits").

    Its body translational velocity b (omni (u, v), unicycle (v, 0)) changes by at most a_max per
    second and its yaw rate by at most alpha_max (or by at most 2 omega_bound without that
    limit); the sent velocity is the one it applies from up to ``lag`` (one control period)
    before or after the stamp. With T = tau + lag and the world velocity R(theta) b,
    ``|V(t) - V_pred(t)| <= |b(t) - b_0| + |b_0| |theta(t) - theta_0 - omega_0 t|``, whose
    integral over [0, tau] is at most ``a_max T^2 / 2 + |b_0| alpha_max T^3 / 6`` (or
    ``a_max T^2 / 2 + |b_0| omega_bound T^2``)."""
    T = max(tau, 0.0) + lag
    turn = speed * alpha_max * T**3 / 6.0 if alpha_max is not None else speed * omega_bound * T**2
    return a_max * T**2 / 2.0 + turn


def predict_position(position, velocity, tau: float) -> tuple[float, float]:
    """Where a neighbour heard at ``position`` with world velocity ``velocity`` = (xdot, ydot,
    thetadot) is ``tau`` later if it holds its body command: an arc of (3.1)/(3.3) [m]."""
    vx, vy, w = (float(c) for c in velocity)
    speed = math.hypot(vx, vy)
    if speed < 1e-12:
        return float(position[0]), float(position[1])
    heading = math.atan2(vy, vx)
    return _arc(float(position[0]), float(position[1]), speed, math.cos(heading), math.sin(heading), w,
                max(tau, 0.0))


def _arc(x: float, y: float, speed: float, c: float, s: float, w: float, t: float) -> tuple[float, float]:
    """Centre after holding the body velocity (speed, 0, w) for t from (x, y) heading (c, s) = (cos,
    sin): the closed form of (3.1)/(3.3), operation for operation that of
    :func:`copath.models.integrate_body_velocity` (the same numbers, without its array)."""
    a = w * t
    if abs(a) < 1e-9:
        dx_b, dy_b = speed * t, 0.0 * t
    else:
        sa, ca = math.sin(a), math.cos(a)
        dx_b = (speed * sa + 0.0 * (ca - 1.0)) / w
        dy_b = (speed * (1.0 - ca) + 0.0 * sa) / w
    return x + c * dx_b - s * dy_b, y + s * dx_b + c * dy_b


LOOKAHEAD_SLACK_SHARE = 0.01
"""Weight of the look-ahead rows' slack relative to ``slack_weight`` (chosen: still an exact
penalty for command changes of the size of the limits)."""

LOOKAHEAD_RECOVERY = 0.25
"""A look-ahead point inside its inflated disc (h_z < 0) is pushed out at this fraction of the
rate gamma / 2 |h_z| (chosen: gentle, so stale, jumping positions do not make it chatter)."""

TUBE_SLACK_SHARE = 0.1
"""Weight of the committed tube's slack relative to ``slack_weight`` (chosen: the robot gives up
its own promise before a centre row, which carries the collision guarantee)."""

TUBE_MARGIN_M = 0.005
"""The robot keeps this far inside its committed tubes [m] (chosen: the applied velocity ramps
within a period, at most a_max dt^2 / 2 = 1.5 mm at 0.3 m/s^2 and 0.1 s)."""

CLEAR_MARGIN = 1e-9
"""Margin by which the pass-through test of :meth:`SafetyFilter.filter` on floats must hold
before the filter skips building its rows [m/s] (many orders above the rounding of a row,
so the test never passes where the full one fails)."""

SCREEN_MARGIN = 1e-6
"""Margin by which a far neighbour's rows must hold by the bounds of the far-neighbour screen
before the pass-through test skips its disc [m/s] (many orders above the rounding of a row and
of the bounds, so a skipped row is one the full test finds met with ``CLEAR_MARGIN`` to spare;
docs/reference/safety.md, "The far-neighbour screen")."""

SCREEN_MIN_HEARD = 8
"""The guard screens far neighbours when it has heard at least this many robots (chosen: with
5 heard, E5.4, the screen's bounds cost about what the discs they save cost, 2-6 us per step
more in replays of recorded calls; with 15, E5.4 grown to 16, 13-20 us less; docs/journal/performance.md,
far-neighbour screen (P25)). Either way the result is the same."""

SCREEN_EPS = 1e-9
"""A screened disc whose barrier's lower bound is this far above the smallest barrier found
is not computed [m] (its barrier cannot be the smallest: many orders above the rounding of a
barrier and of its bound)."""

HARD, LOOKAHEAD, TUBE = 0, 1, 2
"""Slack of a row: the centre rows', the look-ahead rows' or the committed tube's."""
_NS = 3  # slack variables

UNICYCLE_TURN_RAD = 1.2
"""Default turn of the deadlock rule for unicycles [rad] (chosen, docs/reference/safety.md)."""

HELD_DEADBAND_RAD = 0.1
"""Half-width of the dead band round straight ahead in which the deadlock rule keeps the side it
took beside a held robot at its last decision (chosen: 0.05, 0.1 and 0.2 rad measured alike; without it
a nominal aimed at the held disc flipped the side at every step, docs/journal/detours.md, "A side
that flips at every step")."""

SLOWED = 1.0 - 1e-6
"""The deadlock rule applies when a barrier leaves the robot's steered point less than this
fraction of its nominal speed (chosen: whenever a barrier slows it; with 0.2 or 0.5, "nearly
stopped", the twelve robots of the circle swap close their gaps first and jam under delay and
loss)."""

_NO_TUBES = TubeSet(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0))

_PLAN = ("stamp", "x", "y", "vx", "vy", "w", "speed", "cos_heading", "sin_heading")
"""Columns of a guard's published plans (the last three: the arc's constants)."""


def _row_norms(d: np.ndarray) -> np.ndarray:
    """Norms of the rows of a (k, 2) array: ``np.linalg.norm(d, axis=1)``, the same numbers
    (sqrt of x^2 + y^2 summed in that order), without its per-call overhead."""
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])


def _spread(nb: Neighbour) -> float:
    """Distance the neighbour may be from its heard position now [m]."""
    return nb.speed_max * max(nb.age, 0.0) if nb.spread is None else nb.spread


_HALF_PI = 0.5 * math.pi
_SQRT2 = math.sqrt(2.0)  # 2 sin(pi / 4): the largest direction error

_DIRS = np.array([[math.cos(a), math.sin(a), 0.0] for a in np.arange(6) * math.pi / 3])
_COS_DIR = math.cos(math.pi / 6)  # |x| <= max_k c_k^T x / cos(pi / 6) for the six directions c_k

_OCTAGON = np.array([[math.cos(a), math.sin(a)] for a in np.arange(4) * math.pi / 4])
_COS8 = math.cos(math.pi / 8)


def awaits_overheard(cfg: SafetyConfig) -> bool:
    """Whether a lockstep robot waits for every message it overhears, not only its
    neighbours' (``Obs.expect`` then counts every message of each sender): whenever the
    safety filter is fed by overhearing. What the filter keeps out of, what the envelopes
    acknowledge (``safety.acknowledge_plans``) and when a robot finds another quiet or itself cut
    off all depend on when an overheard envelope arrived; a barrier that waited only for the
    neighbours let one arrive a tick late now and then, and a lockstep run over Zenoh then
    left the in-process run (E5.4 with r1 quiet: r1 found itself cut off a tick later and
    held 2 cm further on; docs/reference/faults.md, "Overheard messages and the lockstep barrier")."""
    return bool(cfg.enabled and cfg.overhear)


class SafetyFilter:
    """One robot's barrier QP, built once for its model; :meth:`filter` passes numbers only.

    Parameters
    ----------
    config : SafetyConfig
    model : OmniModel | UnicycleModel
        The robot's own model (limits and radius).
    dt : float
        Control period [s]; gamma * dt must not exceed 1.
    capacity : int
        Number of barrier rows to build the QP for up front (neighbours, their look-ahead rows
        for a unicycle, range readings); more rows rebuild it once, larger.
    lag_periods : float
        How many control periods one command may drive (``safety.command_lag_periods`` for
        the run's clock; 1: exactly one, as in lockstep).
    """

    def __init__(self, config: SafetyConfig, model: OmniModel | UnicycleModel, dt: float,
                 capacity: int = 0, lag_periods: float = 1.0, in_column: bool = False) -> None:
        require(config.gamma is None or config.gamma * dt <= 1.0 + 1e-12, "safety.gamma", config.gamma,
                f"must be <= 1/run.dt = {1.0 / dt:g} 1/s so a barrier cannot be overshot in one period")
        self.config = config
        self.model = model
        require_lag("lag_periods", lag_periods)
        self.dt = float(dt)
        self.hold = self.dt * float(lag_periods)
        """How long one command may drive [s]: the control period times the command lag
        (``safety.command_lag_periods``; docs/reference/safety.md, "Late commands")."""
        self.gamma = (config.gamma if config.gamma is not None else 0.8 / self.dt) / float(lag_periods)
        """Barrier gain in use [1/s]: ``safety.gamma`` (0.8 / dt) over the command lag, so a gap
        closes by at most gamma * hold * h <= h while one command drives."""
        self.omni = isinstance(model, OmniModel)
        self._plain_unicycle = type(model).saturate is UnicycleModel.saturate
        self.m = model.command_size
        self.r_eff = model.radius
        self.lookahead = 0.0 if self.omni else float(config.lookahead_m)
        """Look-ahead distance l of this robot [m] (0: omni, or a unicycle filtering v only)."""
        turn = config.deadlock_turn_rad
        self.turn = float(turn) if turn is not None else (0.0 if self.omni else UNICYCLE_TURN_RAD)
        """Deadlock rule's turn of the reference [rad] (0: off)."""
        self.held_turn = float(config.held_turn_m)
        """Reach of the deadlock rule's left turn beside a held robot [m] (:meth:`turn_side`)."""
        self.in_column = bool(in_column)
        """The robot shares its path with a teammate (a column): while a held robot is among its
        neighbours it takes no deadlock turn (docs/reference/safety.md, "Deadlock rule": the
        column's robots pass a held one by their detours, one behind the other; the turn spun
        the robot just behind it on the spot while the next went past)."""
        self.held_side: int | None = None
        """The side :meth:`turn_side` took at its last decision beside a held robot (None: none
        since a call without one in reach); kept within ``HELD_DEADBAND_RAD`` of straight ahead."""
        # command-space weight W: wheel-speed scale for the turn rate (L_w, or the half axle b);
        # a unicycle with a look-ahead point: |zdot - zdot_nom|^2 = (u - u_nom)^T diag(1, l^2) (u - u_nom)
        if self.omni:
            self._W = np.diag([1.0, 1.0, model.L_w**2])
        else:
            self._W = np.diag([1.0, (self.lookahead or model.b)**2])
        # limits as rows L u in [-lim, lim]
        if self.omni:
            self._L = model.M.copy()
            self._lim = np.full(3, model.qdot_max)
        else:
            self._L = np.eye(2)
            self._lim = np.array([model.v_max, model.omega_max])
        self._cap = config.speed_max_mps
        # speed cap rows C u in [-c, c]: omni, the inner octagon of the disc |(u, v)| <= cap
        # (4 directions, bound cap cos(pi/8)); unicycle, |v| <= cap
        if self.omni:
            self._C = np.hstack([_OCTAGON, np.zeros((4, 1))])
            self._c = np.full(4, (self._cap or 0.0) * _COS8)
        else:
            self._C = np.array([[1.0, 0.0]])
            self._c = np.array([self._cap or 0.0])
        # constant parts of the QP: Hessian, limit and cap rows, slack bound
        m = self.m
        # variables (u, sigma, sigma_z, sigma_c): the centre barriers' slack, the look-ahead rows'
        # own, cheaper one (those rows steer; the centre rows keep robots apart) and the committed
        # tube's (the robot's own promise, given up before any centre row)
        self._H = np.zeros((m + _NS, m + _NS))
        self._H[:m, :m] = 2 * self._W
        self._H[m, m] = 2 * config.slack_weight
        self._H[m + 1, m + 1] = 2 * config.slack_weight * LOOKAHEAD_SLACK_SHARE
        self._H[m + 2, m + 2] = 2 * config.slack_weight * TUBE_SLACK_SHARE
        rows_a, rows_l = [self._L], [self._lim]
        if self._cap is not None:
            rows_a.append(self._C)
            rows_l.append(self._c)
        self._fixed_a = np.hstack([np.vstack(rows_a), np.zeros((sum(len(r) for r in rows_l), _NS))])
        self._fixed_u = np.concatenate(rows_l)
        self._fixed_l = -self._fixed_u
        self._lbx = np.r_[np.full(m, -np.inf), np.zeros(_NS)]
        self._ubx = np.full(m + _NS, np.inf)
        self._qp = None
        self._rows = 0
        if capacity:
            self._solver(capacity)

    # -- geometry ----------------------------------------------------------------------
    def centre_velocity_map(self, theta: float) -> np.ndarray:
        """G(theta): (2, m) map from the command to the centre's world velocity, (3.1)/(3.3)."""
        c, s = math.cos(theta), math.sin(theta)
        if self.omni:
            return np.array([[c, -s, 0.0], [s, c, 0.0]])
        return np.array([[c, 0.0], [s, 0.0]])

    def lookahead_map(self, theta: float) -> np.ndarray:
        """T(theta): (2, 2) map from a unicycle's (v, omega) to the velocity of its look-ahead
        point z = p + l (cos theta, sin theta) (the Robotarium's ``uni_to_si`` mapping); invertible
        for l > 0, so the filter can shape any direction of zdot."""
        c, s, lk = math.cos(theta), math.sin(theta), self.lookahead
        return np.array([[c, -lk * s], [s, lk * c]])

    def lookahead_barriers(self, pose, neighbours: Sequence[Neighbour]) -> tuple[np.ndarray, np.ndarray]:
        """Look-ahead rows of a unicycle (l > 0): normals (k, 2) and values (k,) [m] of

            h_z = ||z_i - p_j|| - (r_i + r_j + margin + spread_j + l_i + l_j),

        the neighbour's centre p_j standing for its look-ahead point (within l_j of it, heading
        unknown); the condition is ``n @ zdot >= -(gamma / 2) h_z``. Empty for l = 0."""
        if not self.lookahead:
            return np.zeros((0, 2)), np.zeros(0)
        cfg = self.config
        th = float(pose[2])
        z = np.array([float(pose[0]) + self.lookahead * math.cos(th), float(pose[1]) + self.lookahead * math.sin(th)])
        heard = [nb for nb in neighbours if nb.age <= cfg.max_age_s]
        if not heard:
            return np.zeros((0, 2)), np.zeros(0)
        # the predicted centre when the neighbour's velocity and acceleration limit are known
        # (its spread is then carried by the hard centre rows only), else the heard disc
        spread = np.array([0.0 if nb.predicted else _spread(nb) for nb in heard], dtype=float)
        dist = (self.r_eff + np.array([nb.radius for nb in heard], dtype=float) + cfg.margin_m + spread
                + self.lookahead + np.array([nb.lookahead for nb in heard], dtype=float))
        d = z[None, :] - np.array([nb.position for nb in heard], dtype=float)
        norm = _row_norms(d)
        return d / np.maximum(norm, 1e-9)[:, None], norm - dist

    def barriers(self, pose, neighbours: Sequence[Neighbour], ranges=None, angles=None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Barrier rows: normals n (k, 2), values h (k,) [m] and gains (k,) [1/s] so that
        ``n @ pdot >= -gain * h`` is each barrier's condition; see the module docstring."""
        return self._barriers(pose, neighbours, ranges, angles)[:3]

    def _barriers(self, pose, neighbours: Sequence[Neighbour], ranges=None, angles=None):
        """:meth:`barriers` plus the distances |p_i - p_j| (k,) and the neighbours heard (the first
        rows), so :meth:`constraints` need not compute them again."""
        cfg = self.config
        q = np.array([float(pose[0]), float(pose[1])])
        heard = [nb for nb in neighbours if nb.age <= cfg.max_age_s]
        spreads = np.array([_spread(nb) for nb in heard], dtype=float)
        pts, dist = [], []
        if heard:
            pts.append(np.array([nb.position for nb in heard], dtype=float))
            dist.append(self.r_eff + np.array([nb.radius for nb in heard], dtype=float) + cfg.margin_m + spreads)
        if cfg.use_ranges and ranges is not None and angles is not None:
            x, y, th = (float(v) for v in pose)
            r = np.asarray(ranges, dtype=float)
            hit = np.isfinite(r)
            a = th + np.asarray(angles, dtype=float)[hit]
            rr = self.model.radius + r[hit]  # readings start on the robot's rim
            pts.append(np.stack([x + rr * np.cos(a), y + rr * np.sin(a)], axis=1))
            dist.append(np.full(len(rr), self.r_eff + cfg.margin_m))
        d = q[None, :] - np.concatenate(pts) if pts else np.zeros((0, 2))
        norm = _row_norms(d)
        n = d / np.maximum(norm, 1e-9)[:, None]
        # every row takes half the gap: a neighbour's filter takes the other half, and a range
        # point may be another robot whose filter sees this one too
        gain = np.full(len(norm), 0.5 * self.gamma)
        return n, norm - (np.concatenate(dist) if dist else np.zeros(0)), gain, norm, heard, spreads

    def _direction_error(self, pose, neighbours: Sequence[Neighbour]) -> np.ndarray:
        """kappa_j = |n - n_hat| bound for each neighbour row: 2 sin(asin(min(1, rho / d)) / 2)
        for a neighbour within rho of its heard centre at distance d."""
        q = np.array([float(pose[0]), float(pose[1])])
        heard = [nb for nb in neighbours if nb.age <= self.config.max_age_s]
        if not heard:
            return np.zeros(0)
        d = np.linalg.norm(q[None, :] - np.asarray([nb.position for nb in heard], dtype=float), axis=1)
        ratio = np.minimum(1.0, np.array([_spread(nb) for nb in heard]) / np.maximum(d, 1e-9))
        return 2.0 * np.sin(0.5 * np.arcsin(ratio))

    def centre_speed(self, u) -> float:
        """Speed of the robot's centre under command u [m/s]."""
        return float(np.hypot(u[0], u[1])) if self.omni else abs(float(u[0]))

    # -- the filter --------------------------------------------------------------------
    def constraints(self, pose, neighbours: Sequence[Neighbour] = (), ranges=None, angles=None,
                    tubes: Sequence[Tube] | TubeSet = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Every barrier as a row on the command: ``A u >= rhs``, which rows are soft (look-ahead
        rows), and the smallest centre barrier value.

        Centre rows (all models, range readings) and, for a unicycle with l > 0, look-ahead rows.
        A barrier already crossed (an overlapping start, or a stale neighbour whose disc has
        grown over the robot) asks only not to close in further (h clamped at 0), so stopping
        stays feasible."""
        th = float(pose[2])
        n, h, gain, norm, heard, spreads = self._barriers(pose, neighbours, ranges, angles)
        A = n @ self.centre_velocity_map(th)  # (k, m): n^T G(theta)
        rhs = -gain * np.maximum(h, 0.0)
        if self.config.braking and self.model.a_max is not None:
            # braking-distance-aware: the robot reaches a command only at a_max, so its share of a
            # gap h may close at most at the speed c from which it stops, decelerating at a_max,
            # within h / 2 (sqrt(a_max h) in continuous time); that bound shrinks at most at rate
            # a_max while the pair closes at it, so the applied velocity can follow it
            # (docs/reference/safety.md, "acceleration limits")
            # (discrete: velocity held over dt, shed by a_max dt per period, so it stops within
            # c^2 / (2 a) + c dt / 2 <= h / 2, the positive root c below)
            a_dt = 0.5 * self.model.a_max * self.hold
            stop = np.sqrt(a_dt**2 + self.model.a_max * np.maximum(h, 0.0)) - a_dt
            rhs = -np.minimum(gain * np.maximum(h, 0.0), stop)
        # committed neighbours (docs/reference/safety.md, "committed plans"): the neighbour stays in its
        # tube, a disc moving at c' and growing at e', so this robot alone keeps out of it, with
        # the whole gap: n^T (pdot - c') - e' >= -rate(h), rate = gamma h, or the speed from which
        # it stops relative to the disc within h (deceleration a_max less the disc's own)
        h_list = h.tolist()
        for k, nb in enumerate(heard):
            if nb.committed is None:
                continue
            vx, vy, grow, acc = nb.committed
            hk = max(h_list[k], 0.0)
            rate = self.gamma * hk
            if self.config.braking and self.model.a_max is not None:
                a_rel = max(self.model.a_max - acc, 0.1 * self.model.a_max)
                a_dt = 0.5 * a_rel * self.hold
                rate = min(rate, math.sqrt(a_dt**2 + 2.0 * a_rel * hk) - a_dt)
            rhs[k] = float(n[k] @ np.array([vx, vy])) + grow - rate
        h_min = float(h.min()) if len(h) else math.inf
        # a neighbour heard `spread` ago lies anywhere in a disc of that radius, so the true
        # normal is within |n - n_hat| <= kappa of the heard one and the true closing rate is
        # n^T pdot >= n_hat^T pdot - kappa |pdot| (docs/reference/safety.md, "stale directions")
        kappa = np.zeros(len(h))
        if heard:  # the neighbour rows come first (as _direction_error, with the distances at hand)
            ratio = np.minimum(1.0, spreads / np.maximum(norm[:len(heard)], 1e-9))
            kappa[:len(heard)] = 2.0 * np.sin(0.5 * np.arcsin(ratio))
        if not self.omni:  # |pdot| = |v|: one row for each sign of v, exact
            K = np.zeros((len(h), 2))
            K[:, 0] = kappa
            blocks_a, blocks_r = [A - K, A + K], [rhs, rhs]
        elif np.any(kappa > 0):  # |(u, v)| <= max_k c_k^T (u, v) / cos(pi / K): K rows per neighbour
            moving = kappa > 0
            blocks_a = [A[~moving]] + [A[moving] - (kappa[moving] / _COS_DIR)[:, None] * c[None, :] for c in _DIRS]
            blocks_r = [rhs[~moving], np.tile(rhs[moving], len(_DIRS))]
        else:
            blocks_a, blocks_r = [A], [rhs]
        blocks_s = [np.full(sum(len(r) for r in blocks_r), HARD)]
        if self.lookahead:
            # look-ahead rows are not clamped: a look-ahead point inside its inflated disc is
            # pushed back out (which reopens the gaps a robot needs to steer round the others);
            # they are soft, so they can never make the QP infeasible
            nz, hz = self.lookahead_barriers(pose, heard)
            blocks_a.append(nz @ self.lookahead_map(th))
            blocks_r.append(-0.5 * self.gamma * np.where(hz > 0, hz, LOOKAHEAD_RECOVERY * hz))
            blocks_s.append(np.full(len(hz), LOOKAHEAD))
        if tubes:
            At, rt = self.tube_rows(pose, tubes)
            blocks_a.append(At)
            blocks_r.append(rt)
            blocks_s.append(np.full(len(rt), TUBE))
        return np.concatenate(blocks_a), np.concatenate(blocks_r), np.concatenate(blocks_s), h_min

    def tube_rows(self, pose, tubes: Sequence[Tube] | TubeSet) -> tuple[np.ndarray, np.ndarray]:
        """Rows ``A u >= rhs`` that keep the robot in every tube it committed to (committed plans).

        With d = p - c (c the plan's point), g = radius - |d| the room left and m = d / |d|,
        g' = growth - m^T (pdot - c'), and the row asks g' >= -rate(g): rate = gamma g (first
        order), capped by the braking speed of the centre rows for a robot with ``a_max`` (it
        reaches a command only gradually). A unicycle shapes its look-ahead point's velocity
        (steering moves it sideways; the centre moves along the heading only)."""
        q = np.array([float(pose[0]), float(pose[1])])
        th = float(pose[2])
        vmap = self.lookahead_map(th) if self.lookahead else self.centre_velocity_map(th)
        ts = TubeSet.of(tubes)
        d = q[None, :] - ts.centre
        dist = _row_norms(d)
        mvec = d / np.maximum(dist, 1e-9)[:, None]
        g = ts.radius - dist
        rate = self.gamma * g
        if self.config.braking and self.model.a_max is not None:
            a_dt = 0.5 * self.model.a_max * self.hold
            stop = np.sqrt(a_dt**2 + self.model.a_max * np.maximum(g, 0.0)) - a_dt
            rate = np.where(g > 0, np.minimum(rate, stop), rate)
        bound = np.einsum("ij,ij->i", mvec, ts.velocity) + ts.growth + rate
        return -(mvec @ vmap), -bound

    def steered_velocity(self, u, theta: float) -> np.ndarray:
        """Velocity of the point the filter steers: the look-ahead point of a unicycle (l > 0),
        else the centre [m/s]."""
        if self.lookahead:
            return self.lookahead_map(theta) @ np.asarray(u, dtype=float)[:2]
        return self.centre_velocity_map(theta) @ np.asarray(u, dtype=float)

    def biased_reference(self, u_nom, theta: float, psi: float) -> np.ndarray | None:
        """The nominal command with its steered velocity turned right by ``psi`` [rad] (the
        deadlock rule); None when that cannot be expressed (a unicycle with l = 0, or a nominal
        that does not move)."""
        if not psi or (not self.omni and not self.lookahead):
            return None
        nu = self.steered_velocity(u_nom, theta)
        if float(np.hypot(*nu)) < 1e-6:
            return None
        c, s = math.cos(psi), math.sin(psi)
        ref = np.array([c * nu[0] + s * nu[1], -s * nu[0] + c * nu[1]])  # R(-psi) nu
        if self.omni:
            c, s = math.cos(theta), math.sin(theta)
            return np.array([c * ref[0] + s * ref[1], -s * ref[0] + c * ref[1], float(u_nom[2])])
        return np.linalg.solve(self.lookahead_map(theta), ref)

    def turn_side(self, pose, u_nom, neighbours: Sequence[Neighbour]) -> int:
        """The deadlock rule's side: +1 (right) or -1 (left). Right is the convention every
        live robot keeps, so two that meet pass each other. A robot lost by its token is held
        still by the simulator where it stopped and turns no more: when its disc lies ahead on
        the right within ``held_turn_m`` of its edge, turning right steers into it, and the rule
        turns left, unless a live robot's disc lies ahead within that reach too (the two must
        keep the convention between them). A silent robot's disc (a bound on where it may have
        stopped, ``Neighbour.silent``) keeps the right turn. Measured on E5.6's circle swap:
        docs/journal/detours.md, "A right turn into a held robot".

        A held disc within ``HELD_DEADBAND_RAD`` of straight ahead lies on neither side: there
        the side of the last decision beside a held robot (:attr:`held_side`) stands. Decided
        afresh at every step, a nominal aimed at the disc turned the robot left, then right, and
        it rocked in place for good (docs/journal/detours.md, "A side that flips at every step")."""
        if not self.held_turn or not self.turn:  # no rule, or no left turn to take
            return 1
        nu = self.steered_velocity(u_nom, float(pose[2]))
        x, y = float(pose[0]), float(pose[1])
        band = math.sin(HELD_DEADBAND_RAD) * math.hypot(nu[0], nu[1])
        held_right = ahead = beside = False
        for nb in neighbours:
            dx, dy = nb.position[0] - x, nb.position[1] - y
            dist = math.hypot(dx, dy)
            if nu[0] * dx + nu[1] * dy <= 0.0 or dist >= self.held_turn + nb.radius + _spread(nb):
                continue  # behind, or its edge beyond the reach of this robot's centre
            if not nb.held:
                self.held_side = None
                return 1
            if nb.silent:
                continue
            beside = True
            cross = nu[0] * dy - nu[1] * dx  # < 0: on the right of the steered velocity
            ahead = ahead or abs(cross) <= band * dist
            held_right = held_right or cross < 0.0
        side = -1 if held_right else 1
        if ahead and self.held_side is not None:
            side = self.held_side
        self.held_side = side if beside else None
        return side

    def filter(self, pose, nominal, neighbours: Sequence[Neighbour] = (), ranges=None, angles=None,
               tubes: Sequence[Tube] | TubeSet = (), turning: bool = False) -> SafetyResult:
        """Minimally modify ``nominal`` so every barrier holds; return it unchanged if they do.

        When the solution slows the robot (its steered point's speed is a fraction r < 1 of the
        nominal's), the QP is solved once more towards the nominal turned right by
        ``deadlock_turn_rad`` (:meth:`biased_reference`; left beside a held robot,
        :meth:`turn_side`): a fixed, decentralised rule that breaks symmetric deadlocks and
        keeps lockstep runs reproducible.

        ``turning``: the robot is turning on the spot before a detour's ramp (docs/reference/detours.md,
        "Turn first"): the soft look-ahead rows are left out, every other row is taken at the
        nominal turn rate so that only v changes, and no deadlock turn is taken
        (docs/reference/safety.md, "A turn on the spot")."""
        u_nom, u_sat, cap_ok = self._saturated(nominal)
        if cap_ok:
            h_min = self._clear(pose, neighbours, ranges, angles, tubes, u_sat)
            if h_min is not None:
                return SafetyResult(u_nom, False, 0.0, 0.0, h_min)
        u_sat = np.asarray(u_sat, dtype=float)
        A, rhs, soft, h_min = self.constraints(pose, neighbours, ranges, angles, tubes)
        if self.lookahead and turning:
            # a turn on the spot (a detour's turn first, docs/reference/detours.md): the centre rows
            # carry the whole guarantee whatever the turn, and the soft look-ahead rows (the
            # look-ahead point pushed out of a disc it is in) would only turn it the other way; the
            # turn rate is the turn's, each row taken at it, so the filter moves v alone (a slack
            # row with a small turn term, a tube's, would otherwise throw the rate to +-omega_max)
            keep = soft != LOOKAHEAD
            A, rhs, soft = A[keep], rhs[keep] - A[keep, 1] * u_sat[1], soft[keep]
            A[:, 1] = 0.0
        if cap_ok and np.all(A @ u_sat >= rhs - 1e-12):
            return SafetyResult(u_nom, False, 0.0, 0.0, h_min)
        th = float(pose[2])
        u, sigma, ok = self._solve(A, rhs, u_sat, soft)
        biased = False
        speed_nom = float(np.hypot(*self.steered_velocity(u_sat, th)))
        ratio = float(np.hypot(*self.steered_velocity(u, th))) / speed_nom if speed_nom > 1e-9 else 1.0
        blocked = bool(np.any((A @ u_sat < rhs - 1e-12) & (soft != TUBE)))  # a barrier, not the cap or the tube
        if ok and blocked and ratio < SLOWED:
            # no deadlock turn while the detour turns the robot, nor beside a held robot in a column
            turn = 0.0 if turning or (self.in_column and any(nb.held for nb in neighbours)) else self.turn
            ref = self.biased_reference(u_sat, th, turn * self.turn_side(pose, u_sat, neighbours)) if turn else None
            if ref is not None:
                ub, sb, okb = self._solve(A, rhs, ref, soft)
                if okb:
                    u, sigma, biased = ub, sb, True
        if not ok:  # stopping satisfies every barrier with h >= 0
            u = np.zeros(self.m)
        return SafetyResult(u, True, float(np.linalg.norm(u - u_sat)), sigma, h_min, ok, biased)

    def _saturated(self, nominal):
        """The nominal command as an array, as the model would apply it (saturated; a unicycle's
        saturate on floats), and whether that meets the speed cap."""
        u_nom = np.asarray(nominal, dtype=float).reshape(self.m)
        if not self._plain_unicycle:
            u_sat, _ = self.model.saturate(u_nom)
        else:
            v, w = u_nom.tolist()
            u_sat = scale_velocities(v, w, self.model.v_max, self.model.omega_max)
        return u_nom, u_sat, self._cap is None or self.centre_speed(u_sat) <= self._cap * (1 + 1e-9)

    def _screen_terms(self, u) -> tuple[float, float, float, float]:
        """What the far-neighbour screen (:meth:`SafetyGuard._pass_through`) needs of the command
        ``u``: ``speed`` = |pdot| (the centre's speed), ``k`` (a centre row's lhs is at least
        ``-speed (1 + k kappa)``: 1 for a unicycle, ``1 / cos(pi / 6)`` for an omni robot's six
        rows), the look-ahead distance l (0: no look-ahead rows) and ``|zdot|`` = |T(theta) u|."""
        if self.omni:
            return math.hypot(float(u[0]), float(u[1])), 1.0 / _COS_DIR, 0.0, 0.0
        v, w = float(u[0]), float(u[1])
        return abs(v), 1.0, self.lookahead, math.hypot(v, self.lookahead * w)

    def _clear(self, pose, neighbours: Sequence[Neighbour], ranges, angles, tubes, u) -> float | None:
        """The pass-through test of :meth:`filter` without building the QP's rows: the smallest
        centre barrier (as :meth:`constraints` returns it, the same number) when the saturated
        nominal ``u`` meets every row of :meth:`constraints` by more than ``CLEAR_MARGIN``, else
        None (then :meth:`filter` builds the rows and decides as before).

        The same rows as :meth:`constraints`, on Python floats for the neighbours (a handful per
        robot, where numpy's per-call cost dominates) and with numpy for the committed tubes. A
        row evaluated here may differ from the matrix product in the last bits; the margin,
        many orders above that, makes this test pass only where :meth:`constraints` passes too,
        so the filter's decisions and commands are those of the full test (docs/journal/performance.md,
        against IR-SIM (P15)). Range readings are left to the full test."""
        cfg = self.config
        if cfg.use_ranges and ranges is not None and angles is not None:
            return None
        x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        c, s = math.cos(th), math.sin(th)
        if self.omni:
            u0, u1 = float(u[0]), float(u[1])
            px, py = c * u0 - s * u1, s * u0 + c * u1  # G(theta) u, the centre's velocity
            dir_max = max(dx * u0 + dy * u1 for dx, dy, _ in _DIRS.tolist())  # max_k c_k^T (u, v)
        else:
            v, w = float(u[0]), float(u[1])
            px, py = c * v, s * v
            lk = self.lookahead
            zx, zy = c * v - lk * s * w, s * v + lk * c * w  # T(theta) u, the look-ahead point's velocity
            z0, z1 = x + lk * c, y + lk * s
        half = 0.5 * self.gamma
        a_max = self.model.a_max if cfg.braking else None
        a_dt = 0.5 * a_max * self.hold if a_max is not None else 0.0
        h_min = math.inf
        omni, gamma, r_eff, margin, max_age = self.omni, self.gamma, self.r_eff, cfg.margin_m, cfg.max_age_s
        look = not omni and lk
        sqrt = math.sqrt
        for (nbx, nby), age, radius, speed_max, spread, nb_look, predicted, committed, _, _ in neighbours:
            if age > max_age:
                continue
            if spread is None:  # _spread
                spread = speed_max * max(age, 0.0)
            dx, dy = x - nbx, y - nby
            norm = sqrt(dx * dx + dy * dy)
            inv = norm if norm > 1e-9 else 1e-9
            nx, ny = dx / inv, dy / inv
            h = norm - (r_eff + radius + margin + spread)  # as constraints computes it: the same h_min
            if h < h_min:
                h_min = h
            hp = h if h > 0.0 else 0.0
            if committed is not None:
                cvx, cvy, grow, acc = committed
                rate = gamma * hp
                if a_max is not None:
                    a_rel = max(a_max - acc, 0.1 * a_max)
                    ar_dt = 0.5 * a_rel * self.hold
                    rate = min(rate, sqrt(ar_dt**2 + 2.0 * a_rel * hp) - ar_dt)
                rhs = nx * cvx + ny * cvy + grow - rate
            elif a_max is not None:
                rhs = -min(half * hp, sqrt(a_dt**2 + a_max * hp) - a_dt)
            else:
                rhs = -half * hp
            ratio = spread / inv
            kappa = 2.0 * math.sin(0.5 * math.asin(ratio if ratio < 1.0 else 1.0)) if ratio > 0.0 else 0.0
            if omni:
                lhs = nx * px + ny * py - (kappa / _COS_DIR * dir_max if kappa > 0 else 0.0)
            else:
                lhs = (nx * c + ny * s) * v - kappa * abs(v)
            if not lhs >= rhs + CLEAR_MARGIN:
                return None
            if look:
                spread_l = 0.0 if predicted else spread
                ex, ey = z0 - nbx, z1 - nby
                nz = sqrt(ex * ex + ey * ey)
                invz = nz if nz > 1e-9 else 1e-9
                hz = nz - (r_eff + radius + margin + spread_l + lk + nb_look)
                rz = -half * (hz if hz > 0 else LOOKAHEAD_RECOVERY * hz)
                if not (ex * zx + ey * zy) / invz >= rz + CLEAR_MARGIN:
                    return None
        if isinstance(tubes, _PlanTubes):  # a guard's tubes, their rooms at hand
            vx, vy = (zx, zy) if (not self.omni and self.lookahead) else (px, py)
            for mx, my, room in tubes.normals:
                if not mx * vx + my * vy <= room:
                    return None
        elif len(tubes):
            ts = TubeSet.of(tubes)
            vx, vy = (zx, zy) if (not self.omni and self.lookahead) else (px, py)
            d = np.array([x, y])[None, :] - ts.centre
            dist = _row_norms(d)
            inv = np.maximum(dist, 1e-9)
            g = ts.radius - dist
            rate = self.gamma * g
            if a_max is not None:
                stop = np.sqrt(a_dt**2 + a_max * np.maximum(g, 0.0)) - a_dt
                rate = np.where(g > 0, np.minimum(rate, stop), rate)
            # m^T (steered velocity - c') <= growth + rate, m = d / |d|
            lhs = (d[:, 0] * (vx - ts.velocity[:, 0]) + d[:, 1] * (vy - ts.velocity[:, 1])) / inv
            if not np.all(lhs <= ts.growth + rate - CLEAR_MARGIN):
                return None
        return h_min

    def _solver(self, k: int):
        """The conic for at least k barrier rows: rows are limits, speed cap, then a padded
        block of barriers whose size only grows (built once per size, outside the control loop
        when the capacity is given up front)."""
        cap = max(k, 1)
        if self._qp is None or self._rows < cap:
            import casadi as ca  # noqa: PLC0415  (only robots with a filter load CasADi)

            self._rows = max(cap, 2 * self._rows)
            nv = self.m + _NS
            rows = len(self._fixed_l) + self._rows
            self._qp = ca.conic(f"safety_qp_{self._rows}", "daqp",
                                {"h": ca.Sparsity.dense(nv, nv), "a": ca.Sparsity.dense(rows, nv)},
                                {"error_on_fail": False})
        return self._qp

    def _solve(self, A: np.ndarray, rhs: np.ndarray, u_ref: np.ndarray, soft: np.ndarray | None = None
               ) -> tuple[np.ndarray, float, bool]:
        """QP towards ``u_ref``; ``soft`` gives each row's slack: ``HARD`` (centre rows, range
        readings), ``LOOKAHEAD`` (the cheaper slack of the look-ahead rows) or ``TUBE`` (the
        committed tube's)."""
        k, m = A.shape
        qp = self._solver(k)
        pad = self._rows - k
        soft = np.zeros(k, dtype=int) if soft is None else np.asarray(soft, dtype=int)
        w = self.config.slack_weight
        g = np.concatenate([-2 * self._W @ u_ref, [w, w * LOOKAHEAD_SLACK_SHARE, w * TUBE_SLACK_SHARE]])
        slack_cols = (soft[:, None] == np.arange(_NS)[None, :]).astype(float)
        a = np.vstack([self._fixed_a, np.hstack([A, slack_cols]), np.zeros((pad, m + _NS))])
        lba = np.concatenate([self._fixed_l, rhs, np.full(pad, -np.inf)])
        uba = np.concatenate([self._fixed_u, np.full(k + pad, np.inf)])
        sol = qp(h=self._H, g=g, a=a, lba=lba, uba=uba, lbx=self._lbx, ubx=self._ubx)
        x = np.asarray(sol["x"]).ravel()
        ok = bool(qp.stats().get("success", False)) and bool(np.all(np.isfinite(x)))
        return x[:m], max(float(x[m]), 0.0), ok


@dataclass(frozen=True, kw_only=True)
class GuardConfig:
    """What one robot's :class:`SafetyGuard` is built from (keyword fields)."""

    safety: SafetyConfig
    """The scenario's ``[safety]`` table."""
    name: str
    """This robot's name."""
    models: Mapping[str, OmniModel | UnicycleModel] = field(hash=False)
    """Every robot's model, for footprint radii and speed bounds."""
    dt: float
    """Control period [s]."""
    sensor_count: int = 0
    """Number of range readings per observation (0 without sensors)."""
    silent_hold_s: float | None = None
    """For a robot gone quiet: how long after its last stamp it holds itself still at the
    latest (cut off: docs/reference/safety.md, "A lost robot"); None, or more than ``max_age_s``
    (a disc that large is a wall, not a robot), keeps a silent robot as any other,
    forgotten after ``max_age_s``."""
    handles_cut_off: frozenset[str] = frozenset()
    """Robots whose controllers handle being cut off themselves (they may drive on): kept
    as any other when silent."""
    lag_periods: float = 1.0
    """How late a sent velocity may take effect after its stamp, in control periods
    (``safety.command_lag_periods`` resolved for the run's clock)."""
    in_column: bool = False
    """This robot shares its path with another robot (:attr:`SafetyFilter.in_column`)."""

    def __post_init__(self) -> None:
        require(self.name in self.models, "name", self.name, f"allowed: one of the robots {sorted(self.models)}")
        require(self.dt > 0, "dt", self.dt, "expected a control period > 0 s")
        require(self.sensor_count >= 0, "sensor_count", self.sensor_count, "expected 0 or more readings")
        require_lag("lag_periods", self.lag_periods)
        object.__setattr__(self, "handles_cut_off", frozenset(self.handles_cut_off))


class SafetyGuard:
    """One robot's filter plus what it has heard and what it did (pure: ``now`` is passed in).

    The runtime calls :meth:`hear` with the position and stamp of every peer message it
    accepts (after faults and the range filter; including overheard broadcasts of robots
    that are not graph neighbours) and :meth:`apply` once per control instant.

    Parameters
    ----------
    config : GuardConfig
    """

    def __init__(self, config: GuardConfig) -> None:
        self.config = config
        name, models, dt, sensor_count = config.name, config.models, config.dt, config.sensor_count
        cfg = config.safety
        self.name = name
        own = models[name]
        # rows per neighbour: omni 6 (stale directions); unicycle 2 (both signs of v), + 1 look-ahead row
        omni = isinstance(own, OmniModel)
        per_robot = len(_DIRS) if omni else 2 + int(cfg.lookahead_m > 0)
        rows = per_robot * (len(models) - 1) + (sensor_count if cfg.use_ranges else 0) * (1 if omni else 2)
        self._config = cfg
        self._commit = cfg.commit_accel_mps2 is not None
        self._ack = self._commit and bool(cfg.acknowledge_plans)
        self._ack_held_only = cfg.acknowledge_plans == "while_held"
        """Unacknowledged plans are left out only while a robot is held still (``"while_held"``)."""
        if self._commit:  # one tube row per plan still kept
            rows += int(math.ceil(cfg.commit_horizon_s / dt)) + 1
        self.filter = SafetyFilter(cfg, own, dt, capacity=rows, lag_periods=config.lag_periods,
                                   in_column=config.in_column)
        cap = cfg.speed_max_mps
        self._bounds = {n: (m.radius, max_speed(m) if cap is None else min(cap, max_speed(m)),
                            0.0 if isinstance(m, OmniModel) else float(cfg.lookahead_m))
                        for n, m in models.items()}
        self._accel = cfg.accel_max_mps2
        # enforced limits of each robot's model: (a_max, alpha_max, yaw-rate bound)
        self._limits = {n: (m.a_max, m.alpha_max, max_turn_rate(m)) for n, m in models.items()}
        # what the far-neighbour screen reads per robot: r_i + r_j + margin, speed bound, look-ahead, limits
        self._static = {n: (self.filter.r_eff + self._bounds[n][0] + cfg.margin_m, *self._bounds[n][1:], *self._limits[n])
                        for n in models}
        self._dt = float(dt)
        self._lag = float(config.lag_periods) * self._dt
        """Lag of the prediction bound [s]: a sent velocity takes effect within it of its stamp."""
        self._own_vel: tuple[float, float, float, float] | None = None
        """The stamp and world velocity (xdot, ydot, thetadot) this robot last published: what
        it drives on while its pose is older than the clock (:meth:`apply`)."""
        self._vel: dict[str, tuple[float, float, float]] = {}
        self._arcs: dict[str, tuple[float, float, float]] = {}  # speed, cos and sin of the heading of _vel
        self._heard: dict[str, tuple[float, float, float]] = {}  # position and when it was true
        self._stamps: dict[str, float] = {}  # the stamp of each robot's newest message
        self._before: dict[str, tuple[float, float, float]] = {}  # the sample before the newest
        self._order: list[str] = []  # the robots heard, sorted
        self.interventions = 0
        """Control instants at which the command was changed."""
        self.change_max = 0.0
        """Largest norm of a command change."""
        self.qp_failures = 0
        """QP failures (the robot was stopped instead)."""
        self.slack_steps = 0
        """Instants at which a barrier could not be met within the limits (slack > 0)."""
        self.bias_steps = 0
        """Instants at which the deadlock rule's right-hand bias shaped the command."""
        self._plans: list[tuple[float, ...]] = []
        """Plans this robot published and still keeps, in the order published, one tuple each
        (``_PLAN``: the stamp, position and world velocity, and the arc's constants, computed
        once when published)."""
        self._ordered = True
        """Whether the plans' stamps rise (then the plans past the horizon are the first ones)."""
        self._acked: dict[str, float] = {}
        """Per robot, the time of this robot's plan it says its filter holds (``PeerEnvelope.acks``):
        no plan older than the oldest of these over the robots that may hold one is kept
        (:meth:`_ack_floor`; docs/reference/safety.md, "Acknowledged plans")."""
        self.commit_breaks = 0
        """Control instants at which the robot was outside a tube it committed to (the guarantee's
        premise broken; docs/reference/safety.md, "Committed plans")."""
        self.commit_excess_max = 0.0
        """Largest distance outside a committed tube [m]."""
        self.ack_steps = 0
        """Control instants at which acknowledgements let the robot leave out plans of the horizon
        that no robot may hold any more (docs/reference/safety.md, "Acknowledged plans")."""
        self._lost_at: dict[str, float] = {}
        """Robots lost (held still by the simulator) and when this robot first knew it [s]."""
        self._back_at: dict[str, float] = {}
        """Of those, the ones back (no longer lost, not heard since) and when this robot knew [s]."""
        hold = config.silent_hold_s
        self._silent_hold = float(hold) if hold is not None and hold <= cfg.max_age_s else None
        self._own_rule = config.handles_cut_off
        self._quiet: set[str] = set()
        """Of :attr:`_lost_at`, the robots lost by silence (they hold themselves still, cut off)."""

    def published(self, stamp: float, position, velocity) -> None:
        """Record a plan this robot published (the position and world velocity of its envelopes
        stamped ``stamp``): with committed plans it keeps within the tube around it for
        ``commit_horizon_s``."""
        if velocity is not None:
            self._own_vel = (float(stamp), float(velocity[0]), float(velocity[1]), float(velocity[2]))
        if not self._commit or velocity is None:
            return
        stamp = float(stamp)
        plans = self._plans
        if plans and plans[-1][0] == stamp:
            return
        vx, vy, w = float(velocity[0]), float(velocity[1]), float(velocity[2])
        heading = math.atan2(vy, vx)  # the arc's constants, as predict_position computes them
        if plans and stamp < plans[-1][0]:
            self._ordered = False
        plans.append((stamp, float(position[0]), float(position[1]), vx, vy, w, math.hypot(vx, vy),
                      math.cos(heading), math.sin(heading)))

    def tubes(self, now: float) -> list[Tube]:
        """The tubes this robot must stay in at ``now`` (plans younger than the horizon)."""
        return self.tube_set(now).tubes()

    def tube_set(self, now: float) -> TubeSet:
        """:meth:`tubes` as arrays: per plan the same numbers as :func:`predict_position`,
        :func:`plan_velocity` and :func:`commit_radius`, operation for operation."""
        if not self._commit:
            return _NO_TUBES
        plans = self._kept(now)
        return _PlanTubes(plans, now, self._config).arrays() if plans else _NO_TUBES

    def _kept(self, now: float) -> list[tuple[float, ...]]:
        """The plans younger than the horizon at ``now`` (the older ones are dropped) and no older
        than every robot that may hold one has acknowledged (:meth:`_ack_floor`)."""
        plans = self._plans
        horizon = self._config.commit_horizon_s - 1e-9
        if self._ordered:
            k = 0
            while k < len(plans) and not now - plans[k][0] < horizon:
                k += 1
            if k:
                del plans[:k]
        elif not all(now - p[0] < horizon for p in plans):
            plans[:] = [p for p in plans if now - p[0] < horizon]
        # the acknowledged ones: left out, not dropped (a robot back from a loss, unacknowledged,
        # may hold any plan of the horizon again)
        floor = self._ack_floor()
        if plans and plans[0][0] < floor:
            if self._ordered:
                k = 1
                while k < len(plans) and plans[k][0] < floor:
                    k += 1
                return plans[k:]
            return [p for p in plans if p[0] >= floor]
        return plans

    def _ack_floor(self) -> float:
        """The time of the oldest plan of this robot that a robot's filter may still hold: the
        oldest acknowledgement over every other filtered robot but the lost ones (a dead
        process holds nothing; one back from a restart counts again, unacknowledged until it
        acknowledges). A robot that has acknowledged nothing (never heard, out of range, or back
        from a loss) may hold any plan younger than the horizon: -inf, the horizon alone
        (docs/reference/safety.md, "Acknowledged plans"). With ``"while_held"``, -inf too while
        this robot holds no robot still ("Acknowledged plans while a robot is held")."""
        if not self._ack:
            return -math.inf
        acked, lost, back = self._acked, self._lost_at, self._back_at
        if self._ack_held_only and not lost:
            return -math.inf  # nobody held still: every plan of the horizon is kept
        floor = math.inf
        for name in self._bounds:
            if name == self.name or (name in lost and name not in back and name not in self._quiet):
                continue
            t = acked.get(name)
            if t is None:
                return -math.inf
            if t < floor:
                floor = t
        return floor

    def acks(self) -> dict[str, float] | None:
        """What this robot's envelopes acknowledge (``PeerEnvelope.acks``): for each robot it has
        heard, the time its plan held here is dated from (the position's time); None without
        committed plans or with them unacknowledged (``safety.acknowledge_plans``)."""
        if not self._ack:
            return None
        heard = self._heard
        return {n: heard[n][2] for n in self._heard_order()}

    @property
    def silent_hold_s(self) -> float | None:
        """How long after its last stamp a robot gone quiet is kept as held still [s]: the
        config's ``silent_hold_s``, None when that is None or longer than ``max_age_s``."""
        return self._silent_hold

    def hear(self, sender: str, position, stamp: float, velocity=None, pos_t: float | None = None,
             acks: Mapping[str, float] | None = None) -> None:
        """Remember the newest position (and world velocity (xdot, ydot, thetadot), when the
        message carries it) a robot sent; older stamps are ignored. ``pos_t``: when the position
        was true, if before the stamp (a realtime robot's pose is up to a period older than its
        step; docs/reference/safety.md, "Late commands"): the position and its arc are dated
        from it. ``acks``: the sender's acknowledgements (``PeerEnvelope.acks``); the one of this
        robot's plans is remembered (:meth:`_ack_floor`)."""
        if sender == self.name or sender not in self._bounds:
            return
        if acks is not None and self._ack:
            t = acks.get(self.name)
            if t is not None and t > self._acked.get(sender, -math.inf):
                self._acked[sender] = float(t)
        last = self._stamps.get(sender)
        if last is None or stamp >= last:
            old = self._heard.get(sender)
            at = float(stamp) if pos_t is None else min(float(pos_t), float(stamp))
            if old is not None and at > old[2]:
                self._before[sender] = old
            self._stamps[sender] = float(stamp)
            self._heard[sender] = (float(position[0]), float(position[1]), at)
            self._arcs.pop(sender, None)  # the arc's constants are computed when first needed (_arc_of)
            if velocity is not None and len(velocity) == 3:
                self._vel[sender] = (float(velocity[0]), float(velocity[1]), float(velocity[2]))
            else:
                self._vel.pop(sender, None)

    def _arc_of(self, sender: str) -> tuple[float, float, float]:
        """The speed and the cosine and sine of the heading of the velocity ``sender`` last sent, as
        :func:`predict_position` computes them: computed once per message, when first needed (a
        neighbour the far-neighbour screen skips needs none of them)."""
        arc = self._arcs.get(sender)
        if arc is None:
            vx, vy, _ = self._vel[sender]
            heading = math.atan2(vy, vx)
            arc = self._arcs[sender] = (math.hypot(vx, vy), math.cos(heading), math.sin(heading))
        return arc

    def neighbours(self, now: float) -> list[Neighbour]:
        """What the filter knows of every robot heard, at ``now``: a disc around its heard or
        predicted position (:meth:`_neighbour`), or, for a robot held still since it was lost, a
        static disc (:meth:`_held`)."""
        return [nb for _, nb in self.named_neighbours(now)]

    def _heard_order(self) -> list[str]:
        """The robots heard, sorted (sorted again only when one is heard for the first time)."""
        if len(self._order) != len(self._heard):
            self._order = sorted(self._heard)
        return self._order

    def named_neighbours(self, now: float) -> list[tuple[str, Neighbour]]:
        """:meth:`neighbours` with each robot's name, in the same order."""
        lost = self._lost_at
        out = []
        for sender in self._heard_order():
            nb = self._held(sender, now) if sender in lost else self._neighbour(sender, now)
            if nb is not None:
                out.append((sender, nb))
        return out

    def _neighbour(self, sender: str, now: float) -> Neighbour:
        """The disc that holds ``sender`` at ``now`` by its last message (docs/reference/safety.md).

        The committed branch writes out :func:`commit_radius`, :func:`prediction_bound`,
        :func:`plan_velocity` and :func:`predict_position` (whose sine and cosine of w tau it
        shares) with the same operations in the same order: the same numbers, without four
        calls per neighbour and step."""
        x, y, stamp = self._heard[sender]
        r, s, look = self._bounds[sender]
        age = max(now - stamp, 0.0)
        nb = None
        a_max, alpha_max, w_bound = self._limits[sender]
        vel = self._vel.get(sender)
        cfg = self._config
        if self._commit and vel is not None and age < cfg.commit_horizon_s:
            # the sender keeps within its committed tube around the arc it published
            # (docs/reference/safety.md, "committed plans"); with an enforced limit, the tighter of the two
            speed, ch, sh = self._arc_of(sender)
            tau = max(age, 0.0)
            spread = cfg.commit_radius_m + cfg.commit_speed_mps * tau + 0.5 * cfg.commit_accel_mps2 * tau**2
            if a_max is not None:
                T = tau + self._lag
                turn = speed * alpha_max * T**3 / 6.0 if alpha_max is not None else speed * w_bound * T**2
                bound = a_max * T**2 / 2.0 + turn
                spread = min(spread, bound)
            if spread < s * age:
                vx, vy, w = vel
                a = w * age
                sa, ca = math.sin(a), math.cos(a)
                cv = (ca * vx - sa * vy, sa * vx + ca * vy)  # plan_velocity
                grow = cfg.commit_speed_mps + cfg.commit_accel_mps2 * age
                # the disc's own acceleration: the arc's turn and the radius's growth
                acc = speed * abs(w) + cfg.commit_accel_mps2
                if speed < 1e-12:  # predict_position (_arc)
                    centre = (x, y)
                else:
                    if abs(a) < 1e-9:
                        dx_b, dy_b = speed * age, 0.0 * age
                    else:  # (_arc's zero terms add nothing: left out, the same numbers)
                        dx_b, dy_b = (speed * sa) / w, (speed * (1.0 - ca)) / w
                    centre = (x + ch * dx_b - sh * dy_b, y + sh * dx_b + ch * dy_b)
                nb = Neighbour(centre, age, r, s, spread, look, True, (cv[0], cv[1], grow, acc))
        elif a_max is not None and vel is not None:
            # the sender's enforced acceleration limit and its sent velocity: a guaranteed,
            # tighter disc around the predicted arc (docs/reference/safety.md, "acceleration limits")
            spread = prediction_bound(age, self._arc_of(sender)[0], a_max, alpha_max, w_bound, self._lag)
            if spread < s * age:
                nb = Neighbour(self._predict(sender, x, y, age), age, r, s, spread, look, True)
        elif self._accel is not None:
            prev = self._before.get(sender)
            if prev is not None:
                # velocity averaged over [t0, t1] is within accel * (t - t0) of the velocity at
                # any t in [t1, now]: extrapolate and bound the error of the displacement
                x0, y0, t0 = prev
                vx, vy = (x - x0) / (stamp - t0), (y - y0) / (stamp - t0)
                spread = self._accel * (now - t0) * age
                if spread < s * age:
                    nb = Neighbour((x + vx * age, y + vy * age), age, r, s, spread, look)
        return Neighbour((x, y), age, r, s, lookahead=look) if nb is None else nb

    def _pass_through(self, now: float, pose, u, tubes) -> float | None:
        """:meth:`SafetyFilter._clear` of every robot heard (the pass-through test: the smallest
        centre barrier, or None when a row is not met by ``CLEAR_MARGIN`` to spare) for the
        saturated nominal ``u``, with the far-neighbour screen (docs/reference/safety.md, "The
        far-neighbour screen"): the same answer, without the disc of a neighbour whose rows hold
        by bounds alone.

        Per robot heard within ``max_age_s`` (not lost): its disc (:meth:`_neighbour`) is the heard
        position moved by at most the arc's length ``speed age`` (a chord is no longer than its
        arc), or not moved, with the spread :meth:`_neighbour` gives (the same branch and the same
        operations, without a sine or a cosine). So its centre barrier is at least
        ``h_lb = |p_i - p_heard| - reach - (r_i + r_j + margin + spread)`` and the ratio behind its
        direction error at most ``spread / (|p_i - p_heard| - reach)``. When every row it makes
        holds for ``u`` by these bounds with ``SCREEN_MARGIN`` to spare, its disc is not computed;
        the others' discs (and every robot lost or silent, held still, and the extrapolations of an
        assumed acceleration bound) go to :meth:`SafetyFilter._clear`. The smallest barrier stays
        exact: a skipped disc is computed after all when its bound is not above the smallest found
        by ``SCREEN_EPS``."""
        f = self.filter
        speed, k, lk, zspeed = f._screen_terms(u)
        order = self._heard_order()
        cfg = self._config
        lost, heard, static, vels = self._lost_at, self._heard, self._static, self._vel
        commit, horizon, max_age, lag = self._commit, cfg.commit_horizon_s, cfg.max_age_s, self._lag
        r0, cs, half_ca, ca = cfg.commit_radius_m, cfg.commit_speed_mps, 0.5 * cfg.commit_accel_mps2 if commit else 0.0, \
            cfg.commit_accel_mps2
        gamma = f.gamma
        half = 0.5 * gamma
        a_own = f.model.a_max if cfg.braking else None
        a_dt = 0.5 * a_own * f.hold if a_own is not None else 0.0
        x, y = float(pose[0]), float(pose[1])
        hypot, sqrt = math.hypot, math.sqrt
        exact, skipped = [], []
        for sender in order:
            if sender in lost:
                nb = self._held(sender, now)
                if nb is not None:
                    exact.append(nb)
                continue
            x0, y0, stamp = heard[sender]
            age = now - stamp
            if age < 0.0:  # max(now - stamp, 0.0), as _neighbour takes it
                age = 0.0
            if age > max_age:
                continue  # no row: the pass-through test skips it
            base, s, look, a_max, alpha_max, w_bound = static[sender]
            vel = vels.get(sender)
            reach, spread, committed = 0.0, s * age, False
            if commit and vel is not None and age < horizon:
                v_j = hypot(vel[0], vel[1])
                sp = r0 + cs * age + half_ca * age**2  # _neighbour's spread, the same operations
                if a_max is not None:
                    T = age + lag
                    turn = v_j * alpha_max * T**3 / 6.0 if alpha_max is not None else v_j * w_bound * T**2
                    bound = a_max * T**2 / 2.0 + turn
                    if bound < sp:
                        sp = bound
                if sp < spread:
                    reach, spread, committed = v_j * age, sp, True
            elif a_max is not None and vel is not None:
                v_j = hypot(vel[0], vel[1])
                sp = prediction_bound(age, v_j, a_max, alpha_max, w_bound, lag)
                if sp < spread:
                    reach, spread = v_j * age, sp
            elif self._accel is not None:
                exact.append(self._neighbour(sender, now))
                continue
            dx, dy = x - x0, y - y0
            lo = sqrt(dx * dx + dy * dy) - reach  # <= the distance to its disc's centre
            h_lb = lo - (base + spread)
            ok = h_lb > 0.0
            if ok:
                # the direction error kappa = 2 sin(asin(rho / d) / 2) <= asin(rho / d) <= (pi / 2) rho / d, and <= sqrt(2)
                kappa = min(_HALF_PI * spread / lo, _SQRT2)
                need = speed * (1.0 + k * kappa) + SCREEN_MARGIN  # the centre row's -lhs at most
                if committed:  # rhs = n^T c' + growth - rate <= |c'| + growth - rate(h_lb)
                    rate = gamma * h_lb
                    if a_own is not None:
                        a_rel = max(a_own - (v_j * abs(vel[2]) + ca), 0.1 * a_own)
                        ar_dt = 0.5 * a_rel * f.hold
                        rate = min(rate, sqrt(ar_dt**2 + 2.0 * a_rel * h_lb) - ar_dt)
                    ok = rate >= need + v_j + (cs + ca * age)
                elif a_own is not None:
                    ok = min(half * h_lb, sqrt(a_dt**2 + a_own * h_lb) - a_dt) >= need
                else:
                    ok = half * h_lb >= need
                if ok and lk:  # the look-ahead row: |z_i - p_j| >= |p_i - p_j| - l_i
                    hz = h_lb - 2.0 * lk - look
                    ok = hz > 0.0 and half * hz >= zspeed + SCREEN_MARGIN
            if ok:
                skipped.append((h_lb, sender))
            else:
                exact.append(self._neighbour(sender, now))
        h_min = f._clear(pose, exact, None, None, tubes, u)
        if h_min is None or not skipped:
            return h_min
        skipped.sort()
        margin, r_eff = cfg.margin_m, f.r_eff
        for h_lb, sender in skipped:
            if h_lb - SCREEN_EPS >= h_min:
                break  # this one's barrier and every later one's are above the smallest
            # its rows hold (above): only its barrier, with the operations of _clear
            (nbx, nby), age, radius, speed_max, spread, *_ = self._neighbour(sender, now)
            if spread is None:
                spread = speed_max * max(age, 0.0)
            dx, dy = x - nbx, y - nby
            h = sqrt(dx * dx + dy * dy) - (r_eff + radius + margin + spread)
            if h < h_min:
                h_min = h
        return h_min

    def _held(self, sender: str, now: float) -> Neighbour | None:
        """A robot lost (its liveliness token went), which the simulator holds still from then on,
        as a static obstacle (docs/reference/safety.md, "A lost robot"): it drove on, within the discs of
        :meth:`_neighbour`, from its last stamp until it was held, at most one control period
        after this robot learnt of the loss (in realtime the simulator and this robot learn of it
        from the same token, each at its own next tick; in lockstep the robot learns of it from
        the observation of the tick the simulator held it, ``Obs.down``), and has not moved since. One disc covers all of
        those: centred half-way along the path of their centres, with half that path's length
        plus the largest of their radii (the last). Its centre is known and it does not move, so
        it is kept out of with the whole gap (as a committed disc at rest), without the
        stale-direction tightening, and is not forgotten with age. None when the hold came more
        than ``max_age_s`` after the last message (forgotten, as any such robot). A robot gone quiet
        holds itself still once cut off, at the latest ``silent_hold_s`` after its last stamp: the
        same disc with that age (docs/reference/safety.md, "A lost robot").

        Once it is back (a restarted process) and until its first new message is heard, it may
        drive again from one period before this robot knew: that disc, inflated by its speed
        bound times the time since, as a neighbour heard then."""
        x, y, stamp = self._heard[sender]
        quiet = sender in self._quiet
        if quiet:  # it holds itself still once cut off: silent_hold_s after its last stamp at the latest
            age = self._silent_hold + (self._stamps[sender] - stamp)
        else:
            age = max(self._lost_at[sender] + self._dt - stamp, 0.0)
            if age > self._config.max_age_s:
                return None
        nb = self._neighbour(sender, stamp + age)
        # the discs' centres run from (x, y) to nb.position, a path of length `run` (an arc at the
        # sent speed, or a straight extrapolation); every point of it is within run / 2 of the
        # chord's midpoint, and the discs' radii grow with the age up to the spread at `age`
        end = nb.position
        run = self._arc_of(sender)[0] * age if nb.predicted else math.hypot(end[0] - x, end[1] - y)
        reach = 0.5 * run + _spread(nb)
        a_max = self._limits[sender][0]
        if a_max is not None:
            # held at zero command, it brakes at a_max from its speed at the hold: within a_max of
            # the sent one per second since up to a period before the stamp (prediction_bound's lag)
            vel = self._vel.get(sender)
            v_hold = nb.speed_max if vel is None else min(nb.speed_max, self._arc_of(sender)[0] + a_max * (age + self._dt))
            reach += v_hold**2 / (2.0 * a_max)
        centre = (0.5 * (x + end[0]), 0.5 * (y + end[1]))
        back = self._back_at.get(sender)
        if back is None:  # at rest, its centre is the point to keep off: no look-ahead of its own
            return Neighbour(centre, 0.0, nb.radius + reach, nb.speed_max, 0.0, 0.0, False, (0.0, 0.0, 0.0, 0.0), True,
                             quiet)
        since = max(now - back, 0.0) + self._dt
        if since > self._config.max_age_s:
            return None
        # where it may be: the held disc's reach (it stopped somewhere in it) plus what it can
        # have driven since; with a_max it was held at rest or braking (at most v_hold) and
        # speeds up at a_max only. The reach is the disc's spread, not its footprint: a robot
        # already near the disc keeps from closing in on it in every direction it may lie in
        # (the stale-direction rows), not only on its centre (docs/reference/safety.md, "A lost robot")
        moved = nb.speed_max * since
        if a_max is not None:
            moved = min(moved, v_hold * since + 0.5 * a_max * since**2)
        return Neighbour(centre, since, nb.radius, nb.speed_max, reach + moved, nb.lookahead)

    def _note_lost(self, lost, now: float, silent=()) -> None:
        """Remember when this robot first knew each robot lost; a robot is held until it is back
        and has been heard again with a stamp from after that (a restarted process, a radio
        heard again). A silent robot is held only if it was heard here (its last stamp is the
        hold's origin) and :attr:`_silent_hold` is set."""
        if self._silent_hold is not None:
            silent = [n for n in silent if n not in lost and n in self._heard and n not in self._own_rule]
        else:
            silent = ()
        for name in (*lost, *silent):
            if name != self.name and name in self._bounds:
                self._lost_at.setdefault(name, float(now))
                self._back_at.pop(name, None)
                if name in lost:  # a process gone: its acknowledgements go with it (a restart holds none)
                    self._acked.pop(name, None)
        self._quiet = {n for n in self._quiet if n in self._lost_at and n not in lost}
        self._quiet.update(n for n in silent if n != self.name and n in self._bounds)
        gone = set(lost) | set(silent)
        for name, t in list(self._lost_at.items()):
            if name in gone:
                continue
            if name in self._stamps and self._stamps[name] >= t:
                del self._lost_at[name]
                self._back_at.pop(name, None)
                self._quiet.discard(name)
            else:
                self._back_at.setdefault(name, float(now))

    def _predict(self, sender: str, x: float, y: float, age: float) -> tuple[float, float]:
        """:func:`predict_position` of the sender's last message ``age`` (>= 0) later, with the arc's
        constants computed once when it was heard (the same numbers)."""
        speed, c, s = self._arc_of(sender)
        if speed < 1e-12:
            return x, y
        return _arc(x, y, speed, c, s, self._vel[sender][2], age)

    def apply(self, pose, command, now: float, ranges=None, angles=None, lost=(), silent=(),
              pose_t: float | None = None, turning: bool = False) -> SafetyResult:
        """Filter one command and record the intervention. ``lost``: robots whose liveliness
        token went (``Observation.lost`` less the merely silent ones), which the simulator holds
        still: static obstacles from then on (:meth:`_held`). ``silent``: robots not heard for
        the lease, which hold themselves still once cut off: static obstacles too, from
        ``silent_hold_s`` after their last stamp.

        ``pose_t``: when ``pose`` was true (its observation's time; None: ``now``). A realtime
        robot steps on its own timer with the newest observation, up to a period old, and has
        moved since on the command it sent last: the filter takes its pose ``now - pose_t``
        further along the arc of the velocity it last published and grows every neighbour's
        disc by the error of that prediction (:func:`prediction_bound`, the lag of the
        command's delivery; without an enforced ``a_max`` or a velocity published at the last
        step, its pose stays and the discs grow by its speed bound times the age). Its
        committed tubes are taken at ``pose_t``, the stamp of the plans it published from that
        pose (docs/reference/safety.md, "Late commands")."""
        if lost or silent or self._lost_at:
            self._note_lost(lost, now, silent)
        plan_t = now if pose_t is None else min(float(pose_t), now)
        tubes = _NO_TUBES
        if self._commit:
            plans = self._kept(plan_t)
            if self._ack and len(plans) < len(self._plans):
                self.ack_steps += 1
            if plans:
                tubes = _PlanTubes(plans, plan_t, self._config, self.filter, float(pose[0]), float(pose[1]))
                if not tubes.inside:  # near or past a tube's edge: the exact test, on the arrays
                    tubes = tubes.arrays()
                    d = np.array([float(pose[0]), float(pose[1])])[None, :] - tubes.centre
                    gap = tubes.radius + TUBE_MARGIN_M - np.hypot(d[:, 0], d[:, 1])
                    if gap.min() < 0:
                        self.commit_breaks += 1
                        self.commit_excess_max = max(self.commit_excess_max, float(-gap.min()))
                        # a tube already left is broken (counted): pulling back into it would not undo that
                        tubes = tubes.select(gap >= 0)
        if plan_t == now and len(self._heard) >= SCREEN_MIN_HEARD and not (
                self._config.use_ranges and ranges is not None and angles is not None):
            # the pass-through test with the far-neighbour screen (docs/reference/safety.md,
            # "The far-neighbour screen"): the result of filter's own test, fewer discs computed;
            # not for a pose older than the clock (the discs grow by the robot's own reach, below)
            u_nom, u_sat, cap_ok = self.filter._saturated(command)
            if cap_ok:
                h_min = self._pass_through(now, pose, u_sat, tubes)
                if h_min is not None:
                    return SafetyResult(u_nom, False, 0.0, 0.0, h_min)
        neighbours = self.neighbours(now)
        if plan_t < now and neighbours:
            moved, reach = self._own_now(pose, now - plan_t, plan_t)
            if ranges is not None and self._config.use_ranges:
                # range readings are points seen from the pose they were taken at: it stays, and
                # the discs grow by the whole way the robot may have gone
                reach += math.hypot(float(moved[0]) - float(pose[0]), float(moved[1]) - float(pose[1]))
            else:
                pose = moved
            neighbours = [nb._replace(spread=_spread(nb) + reach) for nb in neighbours]
        res = self.filter.filter(pose, command, neighbours, ranges, angles, tubes, turning)
        if res.active:
            self.interventions += 1
            self.change_max = max(self.change_max, res.change)
            self.qp_failures += int(not res.ok)
            self.slack_steps += int(res.slack > 1e-9)
            self.bias_steps += int(res.biased)
        return res

    def _own_now(self, pose, age: float, pose_t: float) -> tuple[np.ndarray, float]:
        """This robot's pose ``age`` after ``pose`` was true, and how far from it the robot may be
        [m] (:meth:`apply`): predicted on the velocity it last published, when that was at the
        previous step or later and its model's ``a_max`` is enforced; else the pose itself and
        its speed bound times the age."""
        a_max, alpha_max, w_bound = self._limits[self.name]
        _, s_own, _ = self._bounds[self.name]
        own = self._own_vel
        if a_max is None or own is None or own[0] < pose_t - self._dt - 1e-9:
            return pose, s_own * age
        _, vx, vy, w = own
        speed = math.hypot(vx, vy)
        x, y = predict_position(pose, (vx, vy, w), age)
        spread = prediction_bound(age, speed, a_max, alpha_max, w_bound, self._lag)
        if spread >= s_own * age:
            return pose, s_own * age
        return np.array([x, y, float(pose[2]) + w * age]), spread

    def counters(self) -> dict[str, float | int]:
        """Closing counters (``safety_*``) for the robot's stats record."""
        return {"safety_interventions": self.interventions, "safety_change_max": round(self.change_max, 6),
                "safety_qp_failures": self.qp_failures, "safety_slack_steps": self.slack_steps,
                "safety_bias_steps": self.bias_steps,
                **({"safety_commit_breaks": self.commit_breaks,
                    "safety_commit_excess_max": round(self.commit_excess_max, 6)} if self._commit else {}),
                **({"safety_ack_steps": self.ack_steps} if self._ack else {})}
