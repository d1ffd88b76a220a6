"""Team geometry of the leader-following family for grading from the truth (Sec. 5.3): the
leader's xi is its path coordinate s_L (the reference point C), a follower's is s_i - p_i(C);
the slot of robot i at xi_ref is o(xi_ref + p_i, q_i), (p, q) at xi_ref ((5.1)-(5.3), (5.10)).
A team that loses its leader goes on under a new one (docs/reference/faults.md, "A new
leader"): the geometry names the succession and how a new leader stands for C."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from copath.slots import offset_points, solve_coordinate
from copath.team import TeamGeometry, robot_params

from .config import FollowerConfig

if TYPE_CHECKING:
    from copath.scenario import Scenario

__all__ = ["LEADER", "FOLLOWER", "leader_following_geometry"]

LEADER = "leader_nmpc"
FOLLOWER = "follower_nmpc"
"""The family's registered names: which robot of a team leads."""


def leader_following_geometry(scenario: "Scenario") -> TeamGeometry | None:
    """The team's geometry; None unless it has a leader and followers."""
    leaders = [r.name for r in scenario.robots if r.controller == LEADER]
    followers = [r.name for r in scenario.robots if r.controller == FOLLOWER]
    if not leaders or not followers:
        return None
    leader = leaders[0]
    path = scenario.paths[scenario.robot(leader).path]
    paths = {r.name: path for r in scenario.robots}
    schedule = robot_params(scenario, FollowerConfig, followers[0]).formation_schedule(
        f"robots.{followers[0]}.controller")

    succession = tuple(r.name for r in scenario.robots if r.name == leader or r.name in followers)

    def xi(S, ref=None):
        # every member's s less its offset p at C: the first leader's is 0 (it is C),
        # so without ``ref`` (C = the first leader's s) this is the leader's s itself
        c = S[leader] if ref is None else ref
        out = {leader: S[leader]} if ref is None else {}
        for n in succession:
            if n in S and n not in out:
                out[n] = S[n] - schedule.offsets(n, c)[0]
        return out

    def slots(x):
        # the first leader's slot is C itself (offsets zero): it is the reference while it
        # leads, and where it goes when it comes back to follow a newer leader
        out = {}
        for n in succession:
            p, _, _, q, _, _ = schedule.offsets(n, x)
            out[n] = offset_points(path, x + p, q)
        return out

    def reference(n, s):
        # C with C + p_n(C) = s: the fixed point C <- s - p_n(C) (|p_n'| < 1 in a quintic change)
        return solve_coordinate(s, lambda c: -schedule.offsets(n, c)[0])

    def in_transition(x):
        x = np.asarray(x, dtype=float)
        mask = np.zeros(x.shape, dtype=bool)
        for w in schedule.windows:
            mask |= (x >= w.s_start) & (x <= w.s_end)
        return mask

    def lateral(S, ref=None):
        c = S[leader] if ref is None else ref
        out = {n: np.zeros(np.shape(S[n])) for n in S}
        for f in followers:
            if f in S:
                out[f] = schedule.offsets(f, c)[3]
        return out

    return TeamGeometry("leader_following", paths, xi, slots, in_transition,
                        period=path.length if path.closed else 0.0, leader=leader, lateral=lateral,
                        succession=succession, reference=reference)
