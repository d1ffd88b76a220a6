"""Formation switching while following a path (Sec. 6.2.4, Exp. (ii); Figs 6.8-6.9; E6.6).

The coordinated path-following law of Sec. 5.5 (tracking law (5.39)-(5.40), second-order
consensus (5.42), from :mod:`agent.controllers.consensus.controller`) runs on offset references:
robot i's slot of formation f is an along-track offset s_di and a lateral offset q_i
from the common C2 base path, so its reference is the offset point
o(s_i) = r(s_i) + q_i n(s_i) (Appendix A; :func:`copath.offsets.offset_state`) and the
robots are coordinated when all xi_i = s_i - s_di agree.

A formation switch (the selection mechanism is assumed to exist, Sec. 6.2.4: here a
schedule on the formation coordinate xi) moves both offsets from the old slot to the new
one with the quintic (5.1)-(5.3) over ``transition_m`` metres of the robot's own path
coordinate, so q, q' and q'' stay continuous and the offset curve stays C2; the change
of s_di speeds the robot up or slows it down through the consensus (as p_i in Sec. 5.3,
docs/reference/ambiguities.md, changes of the along-track offset (A32)). During a transition, the repulsive field (6.12)-(6.15)
(:func:`agent.controllers.roles.navigation.repulsive_shift`) pushes the reference
position away from the other robots so that crossing slots do not collide.

The consensus runs on xi with xi-dot = sdot (1 - s_d'(s)): when s_d varies along the
transition the robots must move at different sdot, and (5.42) is written for the
coordination coordinate (with constant s_d the two coincide).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from copath.offsets import Quintic, offset_state

from copath.control import LatestMessages, Observation, Outgoing, PeerMessage, RobotContext, StepResult
from agent.controllers.consensus.controller import (
    NeighbourState,
    neighbour_states,
    consensus_acceleration,
    tracking_errors,
    tracking_law,
)
from agent.controllers.roles.navigation import NavigationGains, repulsion_magnitude, repulsive_shift

from .config import FormationSwitchingConfig
from .payloads import MESSAGE_KIND

__all__ = ["FormationSwitchingConfig", "FormationSwitchingController", "MESSAGE_KIND"]


def _formation_coordinate(payload) -> tuple[float, float, float, float]:
    """(xi_j, xi-dot_j, 0, xi-ddot_j) of a ``formation_state`` payload (xi-ddot_j = 0 when not sent)."""
    return float(payload["xi"]), float(payload["xidot"]), 0.0, float(payload.get("xiddot", 0.0))


class FormationSwitchingController:
    """One robot of E6.6: Sec. 5.5 coordinated path following on switching offset slots."""

    def __init__(self, ctx: RobotContext, cfg: FormationSwitchingConfig) -> None:
        if ctx.model.kind != "unicycle":
            raise ValueError(f"robots.{ctx.name}: formation_switching drives unicycles (Sec. 5.5)")
        self.cfg = cfg
        self.ccfg = cfg.consensus()
        self.path = ctx.own_path
        self.model = ctx.model
        self.gains = NavigationGains(k_r=cfg.k_r, R_max=cfg.R_max, F_max=cfg.F_max, side=0.0)
        self.index = ctx.index
        self.s: float | None = cfg.s0
        self.xidot = cfg.v0
        self.formation = 0
        self.transitions: list[tuple[Quintic, Quintic]] = []
        self.inbox = LatestMessages(kinds=(MESSAGE_KIND,))
        self._arriving = False

    # -- slot geometry -----------------------------------------------------------------
    def _slot(self, s: float) -> tuple[float, float, float, float, float, bool]:
        """(s_d, s_d', q, q', q'', in_transition) at own path coordinate s."""
        sd, q = self.cfg.slots[self.formation]
        for qs, qq in self.transitions:  # only the transition under way matters
            if s < qq.s_end:
                sd_v, sd_1, _ = qs(s)
                q_v, q_1, q_2 = qq(s)
                return float(sd_v), float(sd_1), float(q_v), float(q_1), float(q_2), s > qq.s_start
        return sd, 0.0, q, 0.0, 0.0, False

    def _schedule(self, s: float) -> None:
        """Start the next switch once the formation coordinate reaches its xi (Sec. 6.2.4)."""
        k = self.formation
        if k >= len(self.cfg.switch_at):
            return
        sd_old, q_old = self.cfg.slots[k]
        if s - sd_old < self.cfg.switch_at[k]:
            return
        sd_new, q_new = self.cfg.slots[k + 1]
        s_a = self.cfg.switch_at[k] + sd_old  # where this robot's transition starts
        s_b = s_a + self.cfg.transition_m
        self.transitions = [(Quintic(sd_old, sd_new, s_a, s_b), Quintic(q_old, q_new, s_a, s_b))]
        self.formation = k + 1

    # -- step -----------------------------------------------------------------------------
    def _neighbours(self, t: float, xi: float) -> list[NeighbourState]:
        return neighbour_states(self.inbox.fresh(MESSAGE_KIND, t, self.cfg.stale_after_s).values(), t, xi,
                                _formation_coordinate, age_nominal_s=self.cfg.age_nominal_s,
                                predict_acceleration=self.cfg.predict_acceleration)

    def _shape(self, p: np.ndarray, ref: np.ndarray, t: float) -> np.ndarray:
        """Reference position pushed away from the other robots, (6.12)-(6.15), plus the
        along-track share that orders robots meeting side by side."""
        cfg = self.cfg
        fresh = self.inbox.fresh(MESSAGE_KIND, t, cfg.stale_after_s)
        others = {n: np.asarray(got.position, dtype=float) for n, got in fresh.items() if got.position is not None}
        target = repulsive_shift(p, ref[:2], list(others.values()), self.gains)
        if cfg.along > 0:
            tang = np.array([math.cos(ref[2]), math.sin(ref[2])])
            for n, q in others.items():
                R = float(np.hypot(*(p - q)))
                F = repulsion_magnitude(R, cfg.k_r, cfg.R_max, cfg.F_max)
                if F <= 0.0:
                    continue
                ahead = float((p - q) @ tang)
                index = int(fresh[n].payload.get("index", 0))
                sign = 1.0 if ahead > 1e-3 or (abs(ahead) <= 1e-3 and self.index > index) else -1.0
                target = target + cfg.along * F * sign * tang
        return target

    def step(self, obs: Observation, inbox: Sequence[PeerMessage]) -> StepResult:
        cfg = self.cfg
        self.inbox.update(inbox, obs.t, obs.lost)
        if self.s is None:
            self.s = self.path.project(obs.pose[:2])
        s = self.s
        self._schedule(s)
        sd, dsd, q, dq, ddq, moving = self._slot(s)
        xi = s - sd
        one = max(1.0 - dsd, 0.2)  # d xi / d s; the quintic keeps |s_d'| < 1 for sensible lengths
        sdot = min(max(self.xidot / one, 0.0), cfg.sdot_max)
        geo = offset_state(self.path, s, q, dq, ddq)  # (A.4)-(A.10)
        ref = np.array([float(geo.pos[0]), float(geo.pos[1]), float(geo.theta)])
        # (6.12)-(6.15): during a transition the reference is pushed away from the others
        target = ref[:2]
        if moving or cfg.repel_always:
            target = self._shape(np.asarray(obs.pose[:2], dtype=float), ref, obs.t)
        errors = tracking_errors(obs.pose, (target[0], target[1], ref[2]))
        H, kappa = float(geo.H), float(geo.kappa)
        u = H * sdot  # speed of the reference point along the offset curve (A.8)
        v, omega, delta = tracking_law(errors, u, kappa, u, cfg.k1, cfg.k4, cfg.k5, cfg.theta_a)
        cmd, _ = self.model.saturate((v, omega))
        acc = consensus_acceleration(errors, delta, kappa, self.xidot, xi, self._neighbours(obs.t, xi),
                                     self.ccfg, cfg.v0)
        xidot = self.xidot
        self.xidot = min(max(xidot + acc * obs.dt, 0.0), cfg.sdot_max * one)
        self.s = s + min(max(self.xidot / one, 0.0), cfg.sdot_max) * obs.dt
        slot_error = float(np.hypot(*(ref[:2] - np.asarray(obs.pose[:2], dtype=float))))
        # the change is under way from the start of the transition until the robot has
        # reached its new slot (telemetry contract: errors excluded meanwhile)
        if moving:
            self._arriving = True
        elif self._arriving and slot_error < self.cfg.arrive_tol:
            self._arriving = False
        xiddot = (self.xidot - xidot) / obs.dt  # the acceleration applied, for the neighbours' prediction
        msg = Outgoing(MESSAGE_KIND, {"xi": xi, "xidot": xidot, "formation": self.formation, "index": self.index,
                                      "xiddot": xiddot})
        telemetry = {
            "ref": [float(c) for c in ref],
            "s": s,
            "sdot": sdot,
            "xi": xi,
            "speed_error": xidot - cfg.v0,
            "in_transition": bool(moving or self._arriving),
            "task": self.formation,
            "formation_error": slot_error,
        }
        return StepResult(np.asarray(cmd, dtype=float), [msg], telemetry)

