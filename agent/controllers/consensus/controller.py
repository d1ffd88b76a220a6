"""Lyapunov path following + second-order consensus for unicycles (Sec. 5.5, (5.33)-(5.46)).

Each robot follows its own path Gamma_i parameterised by arc length s_i. Its virtual
vehicle's path coordinate obeys the second-order consensus (5.42), which tracks the
common group speed v_0 and drives s_i - s_j to s_dij = s_di - s_dj over an undirected
connected graph (Theorem 8). The unicycle tracks the virtual vehicle with (5.39)-(5.40)
and the transient heading shaping delta(y_e) of [211].

Neighbour messages are old when they arrive: each carries the sender's acceleration, the
receiver predicts the neighbour over the message age, and beyond ``age_nominal_s`` the
coupling gains of (5.42) are scheduled on that age, so the law keeps working at a second
of delay and half the messages lost (docs/reference/envelope.md).

The reusable pieces (errors (5.33), the tracking law (5.39)-(5.40) with the closed-form
delta-dot of docs/reference/ambiguities.md, algebraic loop through delta-dot (A18), the consensus acceleration (5.42)) are module functions so
other controllers (heterogeneous team, formation switching) call them instead of
copying them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from copath.models import scale_velocities
from copath.paths import wrap_to_pi

from copath.control import (
    LatestMessages,
    Observation,
    Outgoing,
    PeerMessage,
    Received,
    RobotContext,
    StepResult,
)

from .config import ConsensusConfig, ConsensusGains
from .payloads import MESSAGE_KIND

__all__ = [
    "ConsensusGains",
    "ConsensusConfig",
    "ConsensusController",
    "NeighbourState",
    "tracking_errors",
    "tracking_law",
    "consensus_acceleration",
    "neighbour_states",
    "age_weight",
    "MESSAGE_KIND",
]


@dataclass(frozen=True)
class NeighbourState:
    """A neighbour's coordination state as used by (5.42)."""

    xi: float
    """s_j - s_dj, extrapolated to now [m]."""
    sdot: float
    """sdot_j [m/s], extrapolated to now with the sender's acceleration when it sent one."""
    weight: float = 1.0
    """Time scale g in (0, 1] of the coupling from the age of the information
    (:func:`age_weight`): k2 enters as g^2 k2, k3 as g k3."""


def age_weight(age: float, nominal: float) -> float:
    """Time scale of the coupling from the age of information: 1 up to ``nominal``,
    nominal / age beyond.

    The coupling of (5.42) with k2 -> g^2 k2 and k3 -> g k3 is the nominal coupling run
    g times slower; a delay tau in it acts like the delay g tau in the nominal one, so
    g = nominal / age keeps the effective delay at ``nominal`` (docs/reference/envelope.md)."""
    return 1.0 if age <= nominal else nominal / age


def _coordination(payload: Mapping[str, Any]) -> tuple[float, float, float, float]:
    """(s_j, sdot_j, s_dj, sddot_j) of a ``coord_state`` payload (sddot_j = 0 when not sent)."""
    return float(payload["s"]), float(payload["sdot"]), float(payload["s_d"]), float(payload.get("sddot", 0.0))


def neighbour_states(
    received: Iterable[Received],
    t: float,
    xi: float,
    coordinate: Callable[[Mapping[str, Any]], tuple[float, ...]],
    extrapolate: bool = True,
    period: float = 0.0,
    age_nominal_s: float | None = None,
    predict_acceleration: bool = True,
) -> list[NeighbourState]:
    """The neighbours' coordination states of (5.42) at time t from their newest messages.

    ``coordinate(payload)`` gives (c_j, cdot_j, offset_j[, cddot_j]) with xi_j = c_j -
    offset_j; c_j and cdot_j are predicted over the message age a with the received rate
    and acceleration, c_j + cdot_j a + cddot_j a^2 / 2 and cdot_j + cddot_j a
    (docs/reference/controllers-notes.md, consensus virtual vehicle (N3); docs/reference/envelope.md). With ``age_nominal_s`` each
    neighbour's coupling is weighted by :func:`age_weight`. On a shared closed path of
    length ``period`` a lap apart is the same place: xi_j is moved by whole periods next
    to this robot's own ``xi``.
    """
    out = []
    for got in received:
        c, cdot, offset, *rest = coordinate(got.payload)
        cddot = rest[0] if rest and predict_acceleration else 0.0
        a = got.since_stamp(t)
        if extrapolate:
            c, cdot = c + cdot * a + 0.5 * cddot * a * a, cdot + cddot * a
        xi_j = c - offset
        if period:
            xi_j += period * round((xi - xi_j) / period)
        w = 1.0 if age_nominal_s is None else age_weight(a, age_nominal_s)
        out.append(NeighbourState(xi=xi_j, sdot=cdot, weight=w))
    return out


def tracking_errors(pose, ref_pose) -> tuple[float, float, float]:
    """Errors (5.33): robot frame, desired minus actual; theta_e wrapped."""
    x, y, th = pose.tolist() if type(pose) is np.ndarray and pose.dtype == np.float64 else (float(v) for v in pose)
    xd, yd, thd = (float(v) for v in ref_pose)
    c, s = math.cos(th), math.sin(th)
    dx, dy = xd - x, yd - y
    return c * dx + s * dy, -s * dx + c * dy, wrap_to_pi(thd - th)


def _sin_diff_ratio(a: float, b: float) -> float:
    """(sin a - sin b) / (a - b) = cos((a+b)/2) sinc((a-b)/2), safe at a = b."""
    h = 0.5 * (a - b)
    sinc = 1.0 - h * h / 6.0 if abs(h) < 1e-4 else math.sin(h) / h
    return math.cos(0.5 * (a + b)) * sinc


def tracking_law(
    errors: tuple[float, float, float],
    v_d: float,
    kappa: float,
    sdot: float,
    k1: float,
    k4: float,
    k5: float,
    theta_a: float = math.pi / 4,
) -> tuple[float, float, float]:
    """Unicycle tracking law (5.39)-(5.40) of a virtual vehicle moving at sdot.

    Returns ``(v, omega, delta)``. delta-dot = c y_e-dot depends on omega through (5.34),
    an algebraic loop solved in closed form (docs/reference/ambiguities.md, algebraic loop through delta-dot (A18)):
    omega = (A - c sdot sin theta_e) / (1 - c x_e), with the delta-dot term dropped
    when the denominator is near singular (|x_e| >= 4/pi m on the wrong side).
    """
    x_e, y_e, th_e = errors
    sgn = 1.0 if v_d >= 0 else -1.0
    t = math.tanh(y_e)
    delta = -sgn * theta_a * t
    v = k4 * x_e + v_d * math.cos(th_e)  # (5.39)
    omega_d = kappa * v_d
    A = k5 * (th_e - delta) + omega_d + k1 * y_e * v_d * _sin_diff_ratio(th_e, delta)
    c = -sgn * theta_a * (1.0 - t * t)  # d delta / d y_e
    den = 1.0 - c * x_e
    if den > 0.2:
        omega = (A - c * sdot * math.sin(th_e)) / den  # (5.40) with delta-dot solved
    else:
        omega = A
    return v, omega, delta


def consensus_acceleration(
    errors: tuple[float, float, float],
    delta: float,
    kappa: float,
    sdot: float,
    xi: float,
    neighbours: Sequence[NeighbourState],
    cfg: ConsensusConfig,
    v_d: float,
    v_d_dot: float = 0.0,
) -> float:
    """Second-order consensus with a reference velocity, (5.42).

    s-ddot = v_d-dot - k6 (sdot - v_d) - x_e cos th_e - y_e sin th_e - (th_e - delta) kappa / k1
             - 2 k2 sum_j (xi_i - xi_j) - k3 sum_j (sdot_i - sdot_j),
    with xi = s - s_d, so xi_i - xi_j = s_i - s_j - s_dij.
    """
    x_e, y_e, th_e = errors
    acc = (
        v_d_dot
        - cfg.k6 * (sdot - v_d)
        - x_e * math.cos(th_e)
        - y_e * math.sin(th_e)
        - (th_e - delta) * kappa / cfg.k1
    )
    for n in neighbours:
        g = n.weight
        acc -= 2.0 * g * g * cfg.k2 * (xi - n.xi) + g * cfg.k3 * (sdot - n.sdot)
    return acc


class ConsensusController:
    """One robot of the Sec. 5.5 team: path following + consensus on s (Theorem 8)."""

    def __init__(self, ctx: RobotContext, cfg: ConsensusConfig) -> None:
        self.ctx = ctx
        self.cfg = cfg
        self.path = ctx.own_path
        self.model = ctx.model
        self.s: float | None = cfg.s0
        self.sdot = cfg.v0
        self.inbox = LatestMessages(kinds=(MESSAGE_KIND,))
        self._rejoin_until: float | None = None
        """A restarted process: until when it looks for its neighbours' progress (:meth:`_rejoin`)."""

    def _neighbour_states(self, t: float, xi: float) -> list[NeighbourState]:
        return neighbour_states(self.inbox.fresh(MESSAGE_KIND, t, self.cfg.stale_after_s).values(), t, xi,
                                _coordination, self.cfg.extrapolate,
                                self.path.length if self.path.closed else 0.0, self.cfg.age_nominal_s,
                                self.cfg.predict_acceleration)

    def _rejoin(self, t: float) -> bool:
        """A restarted process (``Observation.joined``): its virtual vehicle starts from its
        neighbours' progress, xi_i = mean_j xi_j (the consensus value (5.42) drives it to) and
        their mean speed, not from its own projection, which lags by what it lost while it was
        held still. Started there, the whole team was pulled back to it by the consensus terms
        (E5.4, r5 killed for 1 s: 0.3 m behind, the team re-coordinated in 27 s); now its own
        tracking law (5.39) closes the gap (docs/reference/faults.md, "Restart"). Its first step
        may come before any neighbour message (in one process a new node hears only what is
        sent after it started): it starts from its projection and moves to its neighbours'
        progress at the first step that has one, within ``stale_after_s``. True once done."""
        xi = self.s - self.cfg.s_d
        states = self._neighbour_states(t, xi)
        if states:
            self.s = float(np.mean([n.xi for n in states])) + self.cfg.s_d
            self.sdot = min(max(float(np.mean([n.sdot for n in states])), 0.0), self.cfg.sdot_max)
        return bool(states)

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        cfg = self.cfg
        self.inbox.update(inbox, obs.t, obs.lost)  # a lost robot leaves the graph at once
        if self.s is None:
            self.s = self.path.project(obs.pose[:2])
            self._rejoin_until = obs.t + cfg.stale_after_s if obs.joined else None
        if self._rejoin_until is not None and (self._rejoin(obs.t) or obs.t >= self._rejoin_until):
            self._rejoin_until = None
        s, sdot = self.s, self.sdot
        x_d, y_d, th_d, kappa = self.path.frame(s)
        errors = tracking_errors(obs.pose, (x_d, y_d, th_d))
        v_d = cfg.v0
        v, omega, delta = tracking_law(errors, v_d, kappa, sdot, cfg.k1, cfg.k4, cfg.k5, cfg.theta_a)
        if self.model.kind == "unicycle":  # UnicycleModel.saturate on floats: the scaling of Sec. 5.5.3
            v, omega = scale_velocities(v, omega, self.model.v_max, self.model.omega_max)
        xi = s - cfg.s_d
        acc = consensus_acceleration(errors, delta, kappa, sdot, xi, self._neighbour_states(obs.t, xi), cfg, v_d)
        # integrate the virtual vehicle at the control rate (docs/reference/controllers-notes.md, consensus virtual vehicle (N3))
        self.sdot = min(max(sdot + acc * obs.dt, 0.0), cfg.sdot_max)
        self.s = s + self.sdot * obs.dt
        sddot = (self.sdot - sdot) / obs.dt  # the acceleration applied, for the neighbours' prediction
        msg = Outgoing(MESSAGE_KIND, {"s": s, "sdot": sdot, "s_d": cfg.s_d, "sddot": sddot})
        telemetry = {
            "ref": [x_d, y_d, th_d],
            "s": s,
            "sdot": sdot,
            "xi": xi,
            "speed_error": sdot - v_d,
            "xi_period": self.path.length if self.path.closed else 0.0,
        }
        return StepResult(np.array([float(v), float(omega)]), [msg], telemetry)

