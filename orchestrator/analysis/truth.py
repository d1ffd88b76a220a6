"""Coordination and formation figures from the simulator's truth (Chapters 5-6).

A controller never grades itself: these figures use only the true poses in the log and
the scenario's paths, offsets and formations, never what a controller reports. Each
robot's true position is projected onto its path with a search near the previous tick
(:func:`copath.slots.track_coordinate`, continuous through the crossing of the
lemniscate); the team's desired geometry turns those path coordinates into

- a coordination coordinate xi_i per robot: robots are coordinated when all xi agree
  (modulo the period on a shared closed path), as in the controllers' own laws;
- a reference coordinate xi_ref of the team: the leader's xi where the formation is
  defined relative to a leader (Sec. 5.3, Sec. 5.5.5), the mean of all xi otherwise. A
  leader-following team whose leader is lost goes on under a new one (docs/reference/faults.md, "A
  new leader"): who leads when is decided from the losses the simulator recorded
  (:func:`leader_sequence`), and xi_ref is then recovered from the new leader's true
  position and its slot;
- in every family, a robot the simulator records lost (``robot_lost`` .. ``robot_rejoined``)
  is not graded while it is lost, and a mean reference is the live robots' mean; once back
  it is graded again (its errors counting as a change until it is in its slot);
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

with o(s, q) = r(s) + q n(s) the offset point (5.10). See docs/reference/metrics.md.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from copath.config import ConfigError
from copath.graph import stand_ins
from copath.paths import Path
from copath.scenario import Scenario
from copath.slots import track_coordinate, wrap_near
from copath.team import TeamGeometry, declared_geometry

from orchestrator.analysis.figures import json_number as _f

logger = logging.getLogger(__name__)

__all__ = ["TeamGeometry", "TruthSeries", "team_geometry", "truth_series", "truth_metrics", "cross_track_series",
           "leader_sequence", "outages", "stalled_mask", "stall_metrics", "detour_counts",
           "STALL_WINDOW_S", "STALL_PROGRESS_M"]


def team_geometry(scenario: Scenario) -> TeamGeometry | None:
    """The team's desired geometry, or None (a single robot, or a team no family grades).

    ``[metrics] path_offsets`` declares one for any controller
    (:func:`copath.team.declared_geometry`); otherwise the team is graded by the geometry its
    family declares on its factory (:attr:`copath.control.ControllerFactory.geometry`) when
    every robot's factory declares the same one. No family is named here."""
    if len(scenario.robots) < 2:
        return None
    if scenario.metrics.get("path_offsets"):
        build = declared_geometry
    else:
        from agent.controllers import team_factories  # noqa: PLC0415 (the registry: light, no law)

        declared = {f.geometry if f is not None else None for f in team_factories(scenario).values()}
        build = declared.pop() if len(declared) == 1 else None
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
    """Max over the scored pairs of |xi_i - xi_j| (modulo the period) [m]; NaN at a tick
    where no pair is graded."""
    formation_error: dict[str, np.ndarray]
    """Distance of each slot-holding robot from its slot at xi_ref [m]; NaN while it is not
    graded (lost, or leading a team with a succession)."""
    in_transition: np.ndarray
    leaders: list[tuple[float, str]] | None = None
    """Who led, from when: [(t, robot), ...] (a team with a succession), else None."""
    lost: dict[str, np.ndarray] = field(default_factory=dict)
    """(T,) True while a robot was lost (robots ever lost only; every family)."""
    rejoining: dict[str, np.ndarray] = field(default_factory=dict)
    """(T,) True from a lost robot's return until it is within ``formation_tolerance_m`` of
    its slot (robots that came back only): its formation errors count as a change, and its
    coordination pairs are not scored."""


def outages(events: Iterable) -> list[tuple[float, str, bool]]:
    """(t, robot, lost) of the simulator's ``robot_lost`` (True) and ``robot_rejoined``
    (False) events, in time order: the losses on record (docs/reference/faults.md, "When a robot
    dies, freezes or goes quiet"), never what a controller says."""
    out = [(float(e.t), str(e.detail.get("robot")), e.what == "robot_lost") for e in events
           if e.source == "sim" and e.what in ("robot_lost", "robot_rejoined")]
    return sorted(out, key=lambda o: o[0])


def leader_sequence(succession: Sequence[str], lost: Iterable[tuple[float, str, bool]],
                    t0: float = 0.0) -> list[tuple[float, str]]:
    """Who leads a Sec. 5.3 team from when, [(t, robot), ...] from ``t0``, by the
    succession rule of docs/reference/faults.md ("A new leader") applied to the losses on record.

    ``succession`` is the team in the scenario's robot order; ``lost`` holds (t, robot,
    True) for a loss and (t, robot, False) for a return (:func:`outages`). The first robot
    leads; when the robot leading is lost, the first robot of ``succession`` not lost at
    that instant leads. A robot that comes back does not take the lead back (it follows
    the leader of the higher term); like every member it leads again only by this rule,
    when the leader of the time is lost and it comes first. No one is elected while fewer
    than two members are left: a member that has lost every other member elects no one.
    Records of one instant are applied together (the members see them at the same step).
    """
    if not succession:
        return []
    leader = succession[0]
    seq = [(float(t0), leader)]
    gone: set[str] = set()
    for t, group in itertools.groupby(sorted(lost, key=lambda o: o[0]), key=lambda o: o[0]):
        for _, robot, is_lost in group:
            (gone.add if is_lost else gone.discard)(robot)
        left = [r for r in succession if r not in gone]
        if leader in gone and len(left) >= 2:
            leader = left[0]
            seq.append((float(t), leader))
    return seq


def _spans(t: np.ndarray, seq: list[tuple[float, str]]):
    """(robot, (T,) mask) of each entry of a leader sequence: from its time to the next."""
    for k, (t_k, n) in enumerate(seq):
        t_next = seq[k + 1][0] if k + 1 < len(seq) else np.inf
        yield n, (t >= t_k - 1e-9) & (t < t_next - 1e-9)


def _lost_masks(t: np.ndarray, lost: list[tuple[float, str, bool]], names: list[str]) -> dict[str, np.ndarray]:
    """(T,) True while each robot ever lost was lost (from its loss to its return)."""
    masks: dict[str, np.ndarray] = {}
    since: dict[str, float] = {}
    for t_e, n, is_lost in lost:
        if n not in names:
            continue
        m = masks.setdefault(n, np.zeros(len(t), dtype=bool))
        if is_lost and n not in since:
            since[n] = t_e
        elif not is_lost and n in since:
            m |= (t >= since.pop(n) - 1e-9) & (t < t_e - 1e-9)
    for n, t_l in since.items():
        masks[n] |= t >= t_l - 1e-9
    return {n: m for n, m in masks.items() if m.any()}


def _reference(geo: TeamGeometry, S: dict[str, np.ndarray], t: np.ndarray,
               seq: list[tuple[float, str]]) -> np.ndarray:
    """The team's C on every tick from the leader of the time: its s less its slot offset
    (it keeps its slot, docs/reference/faults.md "A new leader"), each span moved to the lap of the
    one before so C stays continuous on a closed path."""
    ref = np.full(len(t), np.nan)
    prev = None
    for n, span in _spans(t, seq):
        if not span.any() or n not in S:
            continue
        c = np.asarray(geo.reference(n, S[n][span]), dtype=float)
        if prev is not None and geo.period > 0:
            c = c + geo.period * np.round((prev - c[0]) / geo.period)
        ref[span], prev = c, c[-1]
    return ref


def _worst(errors) -> np.ndarray:
    """Largest error over robots at each tick, NaN only where every robot's is."""
    return np.fmax.reduce(np.asarray(list(errors), dtype=float), axis=0)


def _pairs(scenario: Scenario, names: list[str]) -> list[tuple[str, str]]:
    if scenario.metrics["coordination_pairs"] == "edges":
        return [(a, b) for a, b in scenario.edges() if a in names and b in names]
    return list(itertools.combinations(sorted(names), 2))


def _live_edges(edges: list[tuple[str, str]], names: list[str],
                unscored: dict[str, np.ndarray], T: int) -> dict[tuple[str, str], np.ndarray]:
    """The graph's edges graded at each tick when some robots are not (lost, or on their way
    back to their slot): the edges between graded robots, and the ungraded robots contracted
    out of the graph, as the robots' stand-ins contract them (:func:`copath.graph.stand_ins`,
    docs/reference/faults.md "Stand-ins for a lost neighbour"): two graded robots joined through
    ungraded ones only are a pair. So a robot whose only neighbour is lost is still graded,
    against the robots its neighbour listened to (docs/reference/metrics.md, coordination error (M2)).
    Returns each pair with the (T,) mask of the ticks it is graded on."""
    graph: dict[str, list[str]] = {n: [] for n in names}
    for a, b in edges:
        graph[a].append(b)
        graph[b].append(a)
    order = [n for n in names if n in unscored]
    state = np.array([unscored[n] for n in order])  # (robots, T)
    out: dict[tuple[str, str], np.ndarray] = {}
    for col in np.unique(state, axis=1).T:
        gone = {n for n, g in zip(order, col) if g}
        ticks = (state == col[:, None]).all(axis=0)
        live = [(a, b) for a, b in edges if a not in gone and b not in gone]
        joined = [tuple(sorted((a, b))) for a in names if a not in gone for b in stand_ins(graph, a, gone)]
        for pair in dict.fromkeys(live + joined):
            out.setdefault(pair, np.zeros(T, dtype=bool))[ticks] = True
    return out


def truth_series(trace, scenario: Scenario, geometry: TeamGeometry | None = None) -> TruthSeries | None:
    """Coordination and formation series from the true poses of ``trace``.

    A team with a succession (Sec. 5.3) is measured from the leader it has at each tick
    (:func:`leader_sequence` on the trace's loss events): C from the leader's true
    position and its slot, and no formation error for the robot leading (it defines C; its
    lateral error is its cross-track error). In every family a robot is not graded while it
    is lost (held still, or cut off; the simulator's loss events), and a mean reference is
    the mean of the live robots. A robot that comes back is graded again at once, its errors
    counting as a formation change (and its coordination pairs left out) until it is
    within ``formation_tolerance_m`` of its slot."""
    geo = geometry or team_geometry(scenario)
    if geo is None:
        return None
    names = [n for n in geo.paths if n in trace.robots and len(trace.robots[n].t)]
    if len(names) < 2:
        return None
    T = min(len(trace.robots[n].t) for n in names)
    t = trace.robots[names[0]].t[:T]
    S = {n: track_coordinate(geo.paths[n], trace.robots[n].pose[:T, :2]) for n in names}
    # every family grades the live robots only (docs/reference/metrics.md, coordination error (M2)): a robot is left out
    # while the simulator records it lost, and graded again once it is back in its slot
    gone = outages(getattr(trace, "events", None) or ())
    lost = _lost_masks(t, gone, names)
    leaders = leader_sequence(geo.succession, gone, float(t[0])) if geo.succession else None
    if leaders is not None and len(leaders) > 1:
        xi_ref = _reference(geo, S, t, leaders)
        XI = geo.xi(S, ref=xi_ref)
    else:
        XI = geo.xi(S)
        # the anchor of the laps: the leader, else the first robot never lost (a robot held
        # still would move the others' laps as they pass it)
        anchor = next((n for n in names if n not in lost), names[0])
        first = XI[geo.leader] if geo.leader in XI else XI[anchor]
        # xi of every robot moved to the lap of the first one, so a mean is meaningful
        near = {n: first + wrap_near(XI[n] - first, geo.period) for n in names}
        if geo.leader in XI:
            xi_ref = first
        elif lost:  # the mean of the live robots at each tick
            live = np.array([np.where(lost[n], np.nan, near[n]) if n in lost else near[n] for n in names])
            xi_ref = np.where(np.isnan(live).all(axis=0), first, np.nanmean(
                np.where(np.isnan(live).all(axis=0)[None, :], 0.0, live), axis=0))
        else:
            xi_ref = np.mean([near[n] for n in names], axis=0)
    slots = geo.slots(xi_ref)
    form = {n: np.hypot(*(trace.robots[n].pose[:T, :2] - P).T) for n, P in slots.items() if n in S}
    skip = {n: m.copy() for n, m in lost.items()}
    for n, span in _spans(t, leaders or ([(float(t[0]), geo.leader)] if geo.leader else [])):
        skip[n] = skip[n] | span if n in skip else span
    for n in list(form):
        if n in skip and skip[n].all():
            del form[n]
        elif n in skip and skip[n].any():
            form[n] = np.where(skip[n], np.nan, form[n])
    tol = float(scenario.metrics["formation_tolerance_m"])
    rejoining = {}
    for n, m in lost.items():
        back = np.nonzero(m[:-1] & ~m[1:])[0] + 1
        if n in form and len(back):
            rejoining[n] = _returning(back, form[n], tol)
            # on its way back it drove off its path, where the projection can slide along
            # the wrong stretch (the lemniscate's crossing): once it is in its slot, its s is
            # the slot's, C + p(C) = C + s - xi, and the projection goes on from there
            for k in np.nonzero(rejoining[n][:-1] & ~rejoining[n][1:])[0] + 1:
                s0 = float(xi_ref[k] + S[n][k] - XI[n][k])
                S[n] = np.concatenate([S[n][:k], track_coordinate(geo.paths[n], trace.robots[n].pose[k:T, :2], s0=s0)])
                XI = geo.xi(S, ref=xi_ref) if leaders is not None and len(leaders) > 1 else geo.xi(S)
    pairs = _pairs(scenario, names)
    coord = None
    unscored = {n: lost.get(n, False) | rejoining.get(n, False) for n in set(lost) | set(rejoining)}
    graded = None
    if unscored and scenario.metrics["coordination_pairs"] == "edges":
        graded = _live_edges(pairs, names, unscored, T)
        pairs = list(graded)
    if pairs:
        errs = [np.abs(wrap_near(XI[a] - XI[b], geo.period)) for a, b in pairs]
        if graded is not None:
            coord = _worst(np.where(graded[p], e, np.nan) for p, e in zip(pairs, errs))
        elif unscored:
            none = np.zeros(T, dtype=bool)
            errs = [np.where(unscored.get(a, none) | unscored.get(b, none), np.nan, e)
                    for (a, b), e in zip(pairs, errs)]
            coord = _worst(errs)
        else:
            coord = np.max(errs, axis=0)
    moving = np.asarray(geo.in_transition(xi_ref), dtype=bool)
    if form and moving.any():
        settled = [np.where(rejoining[n], np.nan, e) if n in rejoining else e for n, e in form.items()]
        moving = _until_arrived(moving, _worst(settled), tol)
    return TruthSeries(t, S, XI, xi_ref, coord, form, moving, leaders, lost, rejoining)


def _returning(back: np.ndarray, error: np.ndarray, tol: float) -> np.ndarray:
    """(T,) True from each return (tick indices ``back``) of a robot until its ``error``
    is within ``tol`` (to the end if it never is)."""
    out = np.zeros(len(error), dtype=bool)
    for k in back:
        arrived = np.nonzero(error[k:] <= tol)[0]
        out[k:k + arrived[0] if len(arrived) else len(out)] = True
    return out


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
    (outside formation changes) and formation_error_transition_max_m (during them, and
    while a robot that came back returns to its slot), all after ``run.settle_s`` and over
    the robots graded at each tick; ``leaders`` ([[t, robot], ...], who led from when, for
    a team with a succession); None where the team has no such geometry."""
    out: dict[str, Any] = dict.fromkeys(("coordination_error_max_m", "coordination_error_rms_m",
                                         "formation_error_max_m", "formation_error_transition_max_m", "leaders"))
    ser = series if series is not None else truth_series(trace, scenario)
    if ser is None:
        return out
    if ser.leaders is not None:
        out["leaders"] = [[_f(t), n] for t, n in ser.leaders]
    after = ser.t >= scenario.run.settle_s - 1e-9
    if ser.coordination_error is not None and after.any():
        e = ser.coordination_error[after]
        e = e[~np.isnan(e)]
        if len(e):
            out["coordination_error_max_m"] = _f(e.max())
            out["coordination_error_rms_m"] = _f(np.sqrt(np.mean(e**2)))
    if ser.formation_error:
        E = np.array(list(ser.formation_error.values()))  # (robots, T)
        none = np.zeros(len(ser.t), dtype=bool)
        change = ser.in_transition[None, :] | np.array([ser.rejoining.get(n, none) for n in ser.formation_error])
        graded = after[None, :] & ~np.isnan(E)
        steady, moving = E[graded & ~change], E[graded & change]
        if len(steady):
            out["formation_error_max_m"] = _f(steady.max())
        if len(moving):
            out["formation_error_transition_max_m"] = _f(moving.max())
    return out


def cross_track_series(trace, scenario: Scenario, geometry: TeamGeometry | None = None,
                       series: TruthSeries | None = None) -> dict[str, np.ndarray]:
    """Cross-track error of each robot that has a path: |lateral offset of its true position
    from its path - desired lateral offset| [m], on the simulator's ticks.

    The lateral offset is (p - r(s)) . n(s) at the projection s of the true position; the
    desired one is the robot's offset q (5.10) (zero for a robot on its path). ``series``
    lends its path coordinates (the same projection) when it has them, and, after a new
    leader was elected, the team's C from the leader of the time (the followers' q are
    scheduled on C); a lost robot's desired q is held at its value at the loss (it is held
    still, or cut off from the team's C)."""
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
    elected = (series is not None and series.leaders is not None and len(series.leaders) > 1
               and all(len(v) == len(series.xi_ref) for v in S.values()))
    if geo is not None and geo.lateral is not None and elected:
        q = geo.lateral(S, ref=series.xi_ref)
    elif geo is not None and geo.lateral is not None and (geo.leader is None or geo.leader in S):
        q = geo.lateral(S)
    else:
        q = {n: np.zeros(len(S[n])) for n in S}
    for n, m in (series.lost.items() if series is not None else ()):
        if n in q and len(q[n]) == len(m):  # held at the last tick before each loss
            q[n] = q[n][np.maximum.accumulate(np.where(m, 0, np.arange(len(m))))]
    out = {}
    for n in S:
        x, y, th, _ = paths[n].frame(S[n])
        lat = -(P[n][:, 0] - x) * np.sin(th) + (P[n][:, 1] - y) * np.cos(th)
        out[n] = np.abs(lat - q[n])
    return out


STALL_WINDOW_S = 2.0
"""A robot is stalled when its path coordinate moved less than :data:`STALL_PROGRESS_M` over the
last this many seconds (docs/reference/metrics.md, M4c; chosen: two control horizons of the slowest
laws, well above a tick)."""
STALL_PROGRESS_M = 0.05
"""Progress below which a robot counts as stalled over :data:`STALL_WINDOW_S` [m] (chosen: 0.025
m/s on average, an eighth of the slowest nominal speed of the bundled teams, 0.2 m/s)."""


def stalled_mask(t: np.ndarray, s: np.ndarray, lost: np.ndarray | None = None, ahead: np.ndarray | None = None,
                 end: float | None = None) -> np.ndarray:
    """(T,) True at the ticks where a robot is stalled (docs/reference/metrics.md, M4c): over the window
    ``(t - STALL_WINDOW_S, t]`` its true path coordinate ``s`` moved by less than
    :data:`STALL_PROGRESS_M` either way, it was not lost at any tick of the window (``lost``),
    it is not waiting for its team (``ahead``: its coordination coordinate is ahead of the
    team's reference by more than the formation tolerance) and it has not reached the end
    ``end`` of an open path. The first window of the run is never stalled (no history)."""
    t = np.asarray(t, dtype=float)
    s = np.asarray(s, dtype=float)
    out = np.zeros(len(t), dtype=bool)
    if len(t) < 2:
        return out
    j = np.searchsorted(t, t - STALL_WINDOW_S + 1e-9, side="left")
    full = t - t[0] >= STALL_WINDOW_S - 1e-9
    out = full & (np.abs(s - s[j]) < STALL_PROGRESS_M)
    if lost is not None and lost.any():
        c = np.concatenate([[0], np.cumsum(lost.astype(int))])
        out &= (c[np.arange(len(t)) + 1] - c[j]) == 0
    if ahead is not None:
        out &= ~ahead
    if end is not None:
        out &= s < end - STALL_PROGRESS_M
    return out


def stall_metrics(t: np.ndarray, S: dict[str, np.ndarray], scenario: Scenario, paths: dict[str, Path],
                  series: TruthSeries | None = None, geometry: TeamGeometry | None = None) -> dict[str, float]:
    """``stalled_s`` of every robot with a path: the time it was stalled (:func:`stalled_mask`)
    [s], counted in the simulator's ticks; lost and waiting from ``series`` when the team has
    a geometry."""
    out: dict[str, float] = {}
    dt = float(scenario.run.dt)
    tol = float(scenario.metrics["formation_tolerance_m"])
    for n, s in S.items():
        T = min(len(t), len(s))
        lost = ahead = None
        if series is not None and len(series.t) == T:
            lost = series.lost.get(n)
            if n in series.xi and geometry is not None and geometry.leader != n:
                ahead = wrap_near(series.xi[n] - series.xi_ref, geometry.period) > tol
        path = paths[n]
        mask = stalled_mask(t[:T], s[:T], lost, ahead, None if path.closed else path.length)
        out[n] = _f(float(mask.sum()) * dt)
    return out


def detour_counts(events: Iterable, names: Iterable[str]) -> dict[str, int]:
    """Detours each robot started: its runtime's ``detour_start`` events (docs/reference/detours.md)."""
    out = dict.fromkeys(names, 0)
    for e in events:
        if e.what == "detour_start" and e.source in out:
            out[e.source] += 1
    return out
