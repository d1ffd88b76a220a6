"""Coordination and formation figures from the simulator's truth (Chapters 5-6).

A controller never grades itself: these figures use only the true poses in the log and
the scenario's paths, offsets and formations, never what a controller reports. Each
robot's true position is projected onto its path with a search near the previous tick
(:func:`copath.slots.track_coordinate`, continuous through the crossing of the
lemniscate); the team's desired geometry turns those path coordinates into

- a coordination coordinate xi_i per robot: robots are coordinated when all xi agree
  (modulo the period on a shared closed path), as in the controllers' own laws;
- a reference coordinate xi_ref of the team: the leader's xi where the formation is
  defined relative to a leader (Sec. 5.3, Sec. 5.5.5), the mean of all xi otherwise;
- each robot's slot at xi_ref (a point of its offset curve), so the formation error of a
  robot is the distance from its true position to that slot;
- the formation changes under way at xi_ref: the scheduled quintic transitions
  ((5.1)-(5.3)), each extended until every robot is within ``[metrics]
  formation_tolerance_m`` of its new slot. Errors during a change are reported as
  ``formation_error_transition_max_m``, not dropped.

Families (the controllers' ``type``):

=====================  ====================================  ================================
family                 xi_i                                  slot of robot i at xi_ref
=====================  ====================================  ================================
consensus (Sec. 5.5)   s_i - s_di  (5.42)                    r_i(xi_ref + s_di)
dmpc (Sec. 5.4)        P_B/P_i s_i - psi_di  (5.29)           o_i(P_i/P_B (xi_ref + psi_di), q_i)
leader/follower 5.3    leader s_L; follower s_i - p_i(s_L)   o(xi_ref + p_i, q_i), (p, q) at xi_ref
heterogeneous 5.5.5    leader s_L; follower s_i + s_di       o(xi_ref - s_di, q_i)
formation switching    s_i - s_di(s_i)  (Sec. 6.2.4)         o(s, q_i(s)), s - s_di(s) = xi_ref
=====================  ====================================  ================================

with o(s, q) = r(s) + q n(s) the offset point (5.10). See docs/metrics.md.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from copath.config import ConfigError, from_table
from copath.paths import Path
from copath.scenario import Scenario
from copath.slots import offset_points, solve_coordinate, switching_offsets, track_coordinate, wrap_near

from .figures import json_number as _f

logger = logging.getLogger(__name__)

__all__ = ["TeamGeometry", "TruthSeries", "team_geometry", "truth_series", "truth_metrics", "cross_track_series",
           "FAMILIES"]


@dataclass
class TeamGeometry:
    """The desired geometry of one team, as pure functions of path coordinates."""

    family: str
    paths: dict[str, Path]
    """Path each robot's true position is projected onto."""
    xi: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]]
    """{robot: s (T,)} -> {robot: xi (T,)}."""
    slots: Callable[[np.ndarray], dict[str, np.ndarray]]
    """xi_ref (T,) -> {robot: slot position (T, 2)} (robots that hold a slot)."""
    in_transition: Callable[[np.ndarray], np.ndarray]
    """xi_ref (T,) -> (T,) True while a formation change is under way."""
    period: float = 0.0
    """Period of xi (a shared closed path's length) or 0."""
    leader: str | None = None
    """The robot whose xi is the team's reference, or None for the mean."""
    lateral: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None
    """{robot: s (T,)} -> {robot: desired lateral offset q (T,)} from its path; None: 0."""


def _params(scenario: Scenario, cls, name: str):
    return from_table(cls, scenario.robot(name).params, f"robots.{name}.controller")


def _no_transition(xi_ref: np.ndarray) -> np.ndarray:
    return np.zeros(np.shape(xi_ref), dtype=bool)


def _consensus(scenario: Scenario) -> TeamGeometry:
    from agent.controllers.consensus import ConsensusConfig  # noqa: PLC0415

    paths = {r.name: scenario.paths[r.path] for r in scenario.robots}
    s_d = {n: _params(scenario, ConsensusConfig, n).s_d for n in paths}
    period = max((p.length for p in paths.values() if p.closed), default=0.0)
    return TeamGeometry(
        "consensus", paths,
        xi=lambda S: {n: S[n] - s_d[n] for n in S},
        slots=lambda x: {n: offset_points(paths[n], x + s_d[n], 0.0) for n in paths},
        in_transition=_no_transition, period=period)


def _dmpc(scenario: Scenario) -> TeamGeometry:
    from agent.controllers.dmpc import DMPCConfig  # noqa: PLC0415
    from copath.morphing import morphing  # noqa: PLC0415

    paths, morph, q, psi_d = {}, {}, {}, {}
    period = 0.0
    for r in scenario.robots:
        cfg = _params(scenario, DMPCConfig, r.name)
        own = scenario.paths[r.path]
        base = scenario.paths[cfg.base_path] if cfg.base_path else own
        paths[r.name], morph[r.name], q[r.name], psi_d[r.name] = own, morphing(own, base), cfg.q, cfg.offset(r.name)
        period = max(period, base.length if base.closed else 0.0)
    return TeamGeometry(
        "dmpc", paths,
        xi=lambda S: {n: morph[n].psi(S[n]) - psi_d[n] for n in S},
        slots=lambda x: {n: offset_points(paths[n], morph[n].s(x + psi_d[n]), q[n]) for n in paths},
        in_transition=_no_transition, period=period,
        lateral=lambda S: {n: np.full(np.shape(S[n]), q[n]) for n in S})


def _leader_following(scenario: Scenario) -> TeamGeometry:
    from agent.controllers.leader_following import FollowerConfig  # noqa: PLC0415

    leader = next(r.name for r in scenario.robots if r.controller == "leader_nmpc")
    followers = [r.name for r in scenario.robots if r.controller == "follower_nmpc"]
    path = scenario.paths[scenario.robot(leader).path]
    paths = {r.name: path for r in scenario.robots}
    schedule = _params(scenario, FollowerConfig, followers[0]).formation_schedule(f"robots.{followers[0]}.controller")

    def xi(S):
        out = {leader: S[leader]}
        for f in followers:
            p = schedule.offsets(f, S[leader])[0]
            out[f] = S[f] - p
        return out

    def slots(x):
        out = {}
        for f in followers:
            p, _, _, q, _, _ = schedule.offsets(f, x)
            out[f] = offset_points(path, x + p, q)
        return out

    def in_transition(x):
        x = np.asarray(x, dtype=float)
        mask = np.zeros(x.shape, dtype=bool)
        for w in schedule.windows:
            mask |= (x >= w.s_start) & (x <= w.s_end)
        return mask

    def lateral(S):
        out = {n: np.zeros(np.shape(S[n])) for n in S}
        for f in followers:
            if f in S:
                out[f] = schedule.offsets(f, S[leader])[3]
        return out

    return TeamGeometry("leader_following", paths, xi, slots, in_transition,
                        period=path.length if path.closed else 0.0, leader=leader, lateral=lateral)


def _heterogeneous(scenario: Scenario) -> TeamGeometry:
    from agent.controllers.heterogeneous import HeteroLeaderConfig  # noqa: PLC0415

    leader = next(r.name for r in scenario.robots if r.controller == "hetero_leader")
    cfg = _params(scenario, HeteroLeaderConfig, leader)
    path = scenario.paths[scenario.robot(leader).path]
    offs = {n: (float(v[0]), float(v[1])) for n, v in cfg.followers.items()}
    paths = {r.name: path for r in scenario.robots}
    return TeamGeometry(
        "heterogeneous", paths,
        xi=lambda S: {n: S[n] + (offs[n][0] if n in offs else 0.0) for n in S},
        slots=lambda x: {n: offset_points(path, x - sd, q) for n, (sd, q) in offs.items()},
        in_transition=_no_transition, period=path.length if path.closed else 0.0, leader=leader,
        lateral=lambda S: {n: np.full(np.shape(S[n]), offs[n][1] if n in offs else 0.0) for n in S})


def _switching(scenario: Scenario) -> TeamGeometry:
    from agent.controllers.formation_switching import FormationSwitchingConfig  # noqa: PLC0415

    paths, cfgs = {}, {}
    for r in scenario.robots:
        paths[r.name] = scenario.paths[r.path]
        cfgs[r.name] = _params(scenario, FormationSwitchingConfig, r.name)

    def offs(n, s):
        c = cfgs[n]
        return switching_offsets(c.slots, c.switch_at, c.transition_m, s)

    def own_s(n, x):
        return solve_coordinate(x, lambda s: offs(n, s)[0])

    def slots(x):
        out = {}
        for n in paths:
            s = own_s(n, x)
            out[n] = offset_points(paths[n], s, offs(n, s)[1])
        return out

    def in_transition(x):
        return np.any([offs(n, own_s(n, x))[2] for n in paths], axis=0)

    period = max((p.length for p in paths.values() if p.closed), default=0.0)
    return TeamGeometry("formation_switching", paths,
                        xi=lambda S: {n: S[n] - offs(n, S[n])[0] for n in S},
                        slots=slots, in_transition=in_transition, period=period,
                        lateral=lambda S: {n: offs(n, S[n])[1] for n in S})


def _declared(scenario: Scenario) -> TeamGeometry:
    """The geometry the scenario declares in ``[metrics] path_offsets`` (any controller)."""
    s_d = {n: float(v) for n, v in scenario.metrics["path_offsets"].items()}
    q = {n: float(v) for n, v in (scenario.metrics.get("lateral_offsets") or {}).items()}
    paths = {r.name: scenario.paths[r.path] for r in scenario.robots}
    period = max((p.length for p in paths.values() if p.closed), default=0.0)
    return TeamGeometry(
        "declared", paths,
        xi=lambda S: {n: S[n] - s_d[n] for n in S},
        slots=lambda x: {n: offset_points(paths[n], x + s_d[n], q.get(n, 0.0)) for n in paths},
        in_transition=_no_transition, period=period)


FAMILIES: dict[frozenset, Callable[[Scenario], TeamGeometry]] = {
    frozenset({"consensus"}): _consensus,
    frozenset({"dmpc"}): _dmpc,
    frozenset({"leader_nmpc", "follower_nmpc"}): _leader_following,
    frozenset({"hetero_leader", "hetero_follower"}): _heterogeneous,
    frozenset({"formation_switching"}): _switching,
}
"""Controller types of a team -> builder of its desired geometry."""


def team_geometry(scenario: Scenario) -> TeamGeometry | None:
    """The team's desired geometry, or None (a single robot, or a family without one)."""
    if len(scenario.robots) < 2:
        return None
    build = (_declared if scenario.metrics.get("path_offsets")
             else FAMILIES.get(frozenset(r.controller for r in scenario.robots)))
    if build is None:
        return None
    try:
        return build(scenario)
    except (ConfigError, KeyError, ValueError, StopIteration) as exc:  # never fail a finished run
        logger.warning("no truth geometry for scenario %s: %s", scenario.id, exc)
        return None


@dataclass
class TruthSeries:
    """Truth-based series of one run on the simulator's ticks (arrays of length T)."""

    t: np.ndarray
    s: dict[str, np.ndarray]
    """Path coordinate of each robot's true position."""
    xi: dict[str, np.ndarray]
    xi_ref: np.ndarray
    coordination_error: np.ndarray | None
    """Max over the scored pairs of |xi_i - xi_j| (modulo the period) [m]."""
    formation_error: dict[str, np.ndarray]
    """Distance of each slot-holding robot from its slot at xi_ref [m]."""
    in_transition: np.ndarray


def _pairs(scenario: Scenario, names: list[str]) -> list[tuple[str, str]]:
    if scenario.metrics["coordination_pairs"] == "edges":
        return [(a, b) for a, b in scenario.edges() if a in names and b in names]
    return list(itertools.combinations(sorted(names), 2))


def truth_series(trace, scenario: Scenario, geometry: TeamGeometry | None = None) -> TruthSeries | None:
    """Coordination and formation series from the true poses of ``trace``."""
    geo = geometry or team_geometry(scenario)
    if geo is None:
        return None
    names = [n for n in geo.paths if n in trace.robots and len(trace.robots[n].t)]
    if len(names) < 2:
        return None
    T = min(len(trace.robots[n].t) for n in names)
    t = trace.robots[names[0]].t[:T]
    S = {n: track_coordinate(geo.paths[n], trace.robots[n].pose[:T, :2]) for n in names}
    XI = geo.xi(S)
    first = XI[geo.leader] if geo.leader in XI else XI[names[0]]
    # xi of every robot moved to the lap of the first one, so a mean is meaningful
    near = {n: first + wrap_near(XI[n] - first, geo.period) for n in names}
    xi_ref = first if geo.leader in XI else np.mean([near[n] for n in names], axis=0)
    pairs = _pairs(scenario, names)
    coord = None
    if pairs:
        coord = np.max([np.abs(wrap_near(XI[a] - XI[b], geo.period)) for a, b in pairs], axis=0)
    slots = geo.slots(xi_ref)
    form = {n: np.hypot(*(trace.robots[n].pose[:T, :2] - P).T) for n, P in slots.items() if n in S}
    moving = np.asarray(geo.in_transition(xi_ref), dtype=bool)
    if form and moving.any():
        tol = float(scenario.metrics["formation_tolerance_m"])
        moving = _until_arrived(moving, np.max(list(form.values()), axis=0), tol)
    return TruthSeries(t, S, XI, xi_ref, coord, form, moving)


def _until_arrived(window: np.ndarray, error: np.ndarray, tol: float) -> np.ndarray:
    """A formation change lasts from the start of its scheduled window until every robot is
    within ``tol`` of its new slot (the end of the window at the earliest)."""
    out = window.copy()
    ends = np.nonzero(window[:-1] & ~window[1:])[0] + 1
    for k in ends:
        arrived = np.nonzero(error[k:] <= tol)[0]
        stop = k + arrived[0] if len(arrived) else len(out)
        out[k:stop] = True
    return out


def truth_metrics(trace, scenario: Scenario, series: TruthSeries | None = None) -> dict[str, Any]:
    """Fleet keys from the truth: coordination_error_max_m / _rms_m, formation_error_max_m
    (outside formation changes) and formation_error_transition_max_m (during them), all
    after ``run.settle_s``; None where the team has no such geometry."""
    out: dict[str, Any] = dict.fromkeys(("coordination_error_max_m", "coordination_error_rms_m",
                                         "formation_error_max_m", "formation_error_transition_max_m"))
    ser = series if series is not None else truth_series(trace, scenario)
    if ser is None:
        return out
    after = ser.t >= scenario.run.settle_s - 1e-9
    if ser.coordination_error is not None and after.any():
        e = ser.coordination_error[after]
        out["coordination_error_max_m"] = _f(e.max())
        out["coordination_error_rms_m"] = _f(np.sqrt(np.mean(e**2)))
    if ser.formation_error:
        fe = np.max(list(ser.formation_error.values()), axis=0)
        steady = after & ~ser.in_transition
        moving = after & ser.in_transition
        if steady.any():
            out["formation_error_max_m"] = _f(fe[steady].max())
        if moving.any():
            out["formation_error_transition_max_m"] = _f(fe[moving].max())
    return out


def cross_track_series(trace, scenario: Scenario, geometry: TeamGeometry | None = None,
                       series: TruthSeries | None = None) -> dict[str, np.ndarray]:
    """Cross-track error of each robot that has a path: |lateral offset of its true position
    from its path - desired lateral offset| [m], on the simulator's ticks.

    The lateral offset is (p - r(s)) . n(s) at the projection s of the true position; the
    desired one is the robot's offset q (5.10) (zero for a robot on its path). ``series``
    lends its path coordinates (the same projection) when it has them."""
    geo = geometry if geometry is not None else team_geometry(scenario)
    paths = dict(geo.paths) if geo is not None else {r.name: scenario.paths[r.path] for r in scenario.robots if r.path}
    S, P = {}, {}
    for n, path in paths.items():
        rt = trace.robots.get(n)
        if rt is None or not len(rt.t):
            continue
        P[n] = np.asarray(rt.pose, dtype=float)[:, :2]
        known = series.s.get(n) if series is not None else None
        S[n] = known if known is not None and len(known) == len(P[n]) else track_coordinate(path, P[n])
    if not S:
        return {}
    if geo is not None and geo.lateral is not None and (geo.leader is None or geo.leader in S):
        q = geo.lateral(S)
    else:
        q = {n: np.zeros(len(S[n])) for n in S}
    out = {}
    for n in S:
        x, y, th, _ = paths[n].frame(S[n])
        lat = -(P[n][:, 0] - x) * np.sin(th) + (P[n][:, 1] - y) * np.cos(th)
        out[n] = np.abs(lat - q[n])
    return out
