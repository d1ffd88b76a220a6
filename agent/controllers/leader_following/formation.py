"""Curvilinear formations of Sec. 5.3: the followers' offsets (p_i, q_i) from the leader's
reference point C along its path, their changes by the quintic (5.3), and the follower
reference trajectory (5.4)-(5.5) on the offset curve (App. A)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from copath.config import require
from copath.offsets import Quintic, offset_state
from copath.paths import Path, PathTable

__all__ = ["FormationSchedule", "FollowerReference", "follower_reference", "planned_min_separation"]


@dataclass(frozen=True)
class _Window:
    formation: str
    s_start: float
    s_end: float


@dataclass(frozen=True)
class FormationSchedule:
    """Curvilinear formation offsets (p_i, q_i) of every follower along the leader's s.

    ``formations`` maps a formation name to ``{robot: (p, q)}``; the leader is the
    reference point C with (0, 0). The team starts in ``initial`` and moves to the
    formation of each window over [s_start, s_end] of the leader's path coordinate,
    with p and q following the quintic (5.3). Windows must not overlap.
    """

    formations: Mapping[str, Mapping[str, tuple[float, float]]]
    initial: str
    windows: tuple[_Window, ...] = ()

    @classmethod
    def from_params(cls, formations: Any, initial: str, schedule: Any, where: str) -> "FormationSchedule":
        """Build from the scenario tables; raises ConfigError naming the key."""
        require(isinstance(formations, Mapping) and formations, f"{where}.formations", formations,
                "expected a table {name = {robot = [p, q], ...}, ...}")
        forms: dict[str, dict[str, tuple[float, float]]] = {}
        robots: set[str] | None = None
        for name, slots in formations.items():
            require(isinstance(slots, Mapping), f"{where}.formations.{name}", slots, "expected {robot = [p, q]}")
            forms[name] = {}
            for robot, pq in slots.items():
                ok = isinstance(pq, (list, tuple)) and len(pq) == 2 and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in pq)
                require(ok, f"{where}.formations.{name}.{robot}", pq, "expected [p, q] in metres")
                forms[name][robot] = (float(pq[0]), float(pq[1]))
            require(robots is None or set(forms[name]) == robots, f"{where}.formations.{name}", sorted(forms[name]),
                    f"every formation must place the same followers: {sorted(robots or [])}")
            robots = set(forms[name])
        require(initial in forms, f"{where}.initial_formation", initial, f"allowed: {', '.join(sorted(forms))}")
        wins = []
        for i, w in enumerate(schedule or []):
            key = f"{where}.schedule[{i}]"
            require(isinstance(w, Mapping) and set(w) == {"formation", "s_start", "s_end"}, key, w,
                    "expected {formation, s_start, s_end}")
            require(w["formation"] in forms, f"{key}.formation", w["formation"], f"allowed: {', '.join(sorted(forms))}")
            s0, s1 = float(w["s_start"]), float(w["s_end"])
            require(s1 > s0, f"{key}.s_end", s1, "must be greater than s_start")
            require(not wins or s0 >= wins[-1].s_end, f"{key}.s_start", s0,
                    "windows must be in order and must not overlap")
            wins.append(_Window(str(w["formation"]), s0, s1))
        return cls(forms, initial, tuple(wins))

    @property
    def followers(self) -> tuple[str, ...]:
        return tuple(self.formations[self.initial])

    def _segments(self, robot: str):
        """Quintics of p and q for each window: list of (window, Quintic_p, Quintic_q)."""
        out = []
        prev = self.formations[self.initial][robot]
        for w in self.windows:
            nxt = self.formations[w.formation][robot]
            out.append((w, Quintic(prev[0], nxt[0], w.s_start, w.s_end), Quintic(prev[1], nxt[1], w.s_start, w.s_end)))
            prev = nxt
        return out, prev

    def offsets(self, robot: str, s_c) -> tuple[np.ndarray, ...]:
        """(p, p', p'', q, q', q'') of ``robot`` at leader coordinate(s) s_c; ' = d/ds_c.
        A robot the formations do not place (the leader) is at C: all zero."""
        s_c = np.asarray(s_c, dtype=float)
        if robot not in self.formations[self.initial]:
            return tuple(np.zeros(s_c.shape) for _ in range(6))
        p0, q0 = self.formations[self.initial][robot]
        p = np.full(s_c.shape, p0)
        q = np.full(s_c.shape, q0)
        zeros = np.zeros(s_c.shape)
        dp, ddp, dq, ddq = zeros.copy(), zeros.copy(), zeros.copy(), zeros.copy()
        segs, _ = self._segments(robot)
        for w, qp, qq in segs:
            sel = s_c > w.s_start  # at and after the window's start the quintic holds (clipped)
            if not np.any(sel):
                continue
            pv, dpv, ddpv = qp(s_c)
            qv, dqv, ddqv = qq(s_c)
            p, dp, ddp = np.where(sel, pv, p), np.where(sel, dpv, dp), np.where(sel, ddpv, ddp)
            q, dq, ddq = np.where(sel, qv, q), np.where(sel, dqv, dq), np.where(sel, ddqv, ddq)
        return p, dp, ddp, q, dq, ddq

    def in_transition(self, s_c: float) -> bool:
        return any(w.s_start <= s_c <= w.s_end for w in self.windows)


@dataclass(frozen=True)
class FollowerReference:
    """Reference of one follower at a set of times (arrays of equal length)."""

    pose: np.ndarray
    """(n, 3) reference poses (x, y, theta) on the offset curve."""
    u: np.ndarray
    """(n,) reference translational speed u_{i,R} = H u_p (5.4) [m/s]."""
    omega: np.ndarray
    """(n,) reference yaw rate omega_{i,R} = k_i u_{i,R} (5.5) [rad/s]."""
    s_c: np.ndarray
    """(n,) estimated leader path coordinate [m]."""
    s_i: np.ndarray
    """(n,) own path coordinate s_i = s_c + p_i [m]."""
    p: np.ndarray
    """(n,) along-track offsets p_i [m]."""
    H: np.ndarray
    """(n,) dl/ds_i of the offset curve (A.4)."""

    def progress_of(self, xy) -> float:
        """First-order projection of a position onto the path coordinate at row 0:
        s_i + (p - o(s_i)) . t_i / H (the offset curve's tangent t_i, dl/ds = H)."""
        d = np.asarray(xy, dtype=float)[:2] - self.pose[0, :2]
        th = self.pose[0, 2]
        return float(self.s_i[0] + (d[0] * math.cos(th) + d[1] * math.sin(th)) / self.H[0])


def follower_reference(path: Path | PathTable, schedule: FormationSchedule, robot: str, s_c,
                       sdot_c) -> FollowerReference:
    """Reference poses and velocities of follower ``robot`` for leader progress s_c, sdot_c.

    s_i = s_c + p_i(s_c); o(s_i) = r(s_i) + q_i n(s_i) with heading theta_p + atan2(q', 1 - k q)
    (App. A). With p and q functions of s_c (the schedule's coordinate), the derivatives
    along the follower's own coordinate are dq/ds_i = q_c' / (1 + p_c') and
    d2q/ds_i^2 = (q_c'' (1 + p_c') - q_c' p_c'') / (1 + p_c')^3. The speed at s_i is
    u_p = sdot_c (1 + p_c') = sdot_c + pdot_i (docs/reference/ambiguities.md, u_p when the along-track offset varies (A28)), so u_{i,R} = H u_p (5.4) and
    omega_{i,R} = k_i u_{i,R} (5.5).
    """
    s_c = np.atleast_1d(np.asarray(s_c, dtype=float))
    sdot_c = np.broadcast_to(np.asarray(sdot_c, dtype=float), s_c.shape)
    p, dp, ddp, q, dq_c, ddq_c = schedule.offsets(robot, s_c)
    j = 1.0 + dp
    if np.any(j <= 0.05):
        raise ValueError("along-track offset changes faster than the leader moves (1 + dp/ds <= 0.05)")
    dq = dq_c / j
    ddq = (ddq_c * j - dq_c * ddp) / j**3
    s_i = s_c + p
    geo = offset_state(path, s_i, q, dq, ddq)
    u_p = sdot_c * j
    u = geo.H * u_p
    pose = np.column_stack([geo.pos[..., 0], geo.pos[..., 1], geo.theta])
    return FollowerReference(pose=pose, u=u, omega=geo.kappa * u, s_c=s_c, s_i=s_i, p=p, H=geo.H)


def planned_min_separation(path: Path, schedule: FormationSchedule, s_from: float, s_to: float,
                           leader: str = "leader", step: float = 0.02) -> tuple[float, float, tuple[str, str]]:
    """Smallest distance between planned slots (leader at C included) over s_c in [s_from, s_to].

    Returns (distance [m], s_c where it occurs, the pair of robots).
    """
    s_c = np.arange(s_from, s_to + step, step)
    names = [leader, *schedule.followers]
    pos = [np.asarray(path.pos(s_c))]
    for r in schedule.followers:
        ref = follower_reference(path, schedule, r, s_c, np.ones_like(s_c))
        pos.append(ref.pose[:, :2])
    best = (math.inf, float(s_from), (names[0], names[0]))
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            d = np.hypot(*(pos[a] - pos[b]).T)
            k = int(np.argmin(d))
            if d[k] < best[0]:
                best = (float(d[k]), float(s_c[k]), (names[a], names[b]))
    return best
