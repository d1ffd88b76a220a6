"""metrics.json: the machine-readable result of a run, computed from its message log.

The same function serves a real run (records read back from ``run.mcap``) and an
in-process run (records kept in memory), so a run's figures are always explainable
from its log. Keys are a public contract: add keys, never rename; a figure that does not
apply to a scenario is ``null``.

Definitions (errors are taken after ``run.settle_s``; docs/reference/metrics.md, truth figures (M1-M6)):
- coordination, formation, cross-track and task figures come from the simulator's truth
  and the scenario's geometry (:mod:`orchestrator.analysis.truth`,
  :mod:`orchestrator.analysis.roles`), never from what a controller says about itself;
  the controllers' own figures are kept as ``*_reported``;
- path error: distance from the simulator's true position to the controller's reference
  point ``ref`` at the same instant; heading error: |wrap(theta - theta_ref)|;
  steps flagged ``in_transition`` are left out;
- reported coordination error: max over robot pairs (all pairs, or graph edges with
  ``[metrics] coordination_pairs = "edges"``) of the reported |xi_i - xi_j| (modulo
  ``xi_period``), with each robot's xi interpolated onto the simulator's ticks;
- min separation: smallest centre distance between two robots; a collision is the
  onset of an overlap of two robot discs, or of a disc with an obstacle.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from copath.paths import wrap_to_pi
from copath.scenario import Scenario
from copath.slots import track_coordinate
from copath.wire.keys import Keys
from copath.wire.messages import Command, End, Estimate, Event, Stats, Telemetry, Truth

from orchestrator.analysis.figures import json_number as _f
from orchestrator.analysis.estimation import ESTIMATION_KEYS, estimation_metrics
from orchestrator.analysis.truth import cross_track_series, detour_counts, stall_metrics, team_geometry, truth_metrics, truth_series

__all__ = ["RobotTrace", "Trace", "trace_from_records", "compute_metrics", "metrics_from_log", "log_metrics", "reported_coordination_series", "METRIC_KEYS"]

ROBOT_KEYS = (
    "path_error_max_m",
    "path_error_rms_m",
    "heading_error_max_rad",
    "speed_error_rms_mps",
    "solve_ms_p50",
    "solve_ms_p99",
    "limit_violations",
    "missed_ticks",
    "wheel_speed_max_mps",
    "solver_failures",
    "control_effort",
    "cross_track_error_max_m",
    "cross_track_error_rms_m",
) + ESTIMATION_KEYS
# the safety filter (copath.safety), from the runtime's safety_* telemetry; null when it is off
SAFETY_KEYS = ("safety_interventions", "safety_change_max", "safety_ms_p50", "safety_ms_p99")
ROBOT_KEYS = ROBOT_KEYS + SAFETY_KEYS
# received messages the robot refused (schema, origin, stamp window; copath.wire.trust), from
# its closing account; null when the robot left none (killed) (docs/reference/faults.md)
ROBOT_KEYS = ROBOT_KEYS + ("messages_rejected",)
# run.on_robot_failure: process restarts and the simulated time the robot was gone (from the
# simulator's robot_lost / robot_rejoined events; 0 when it never was)
ROBOT_KEYS = ROBOT_KEYS + ("restarts", "outage_s")
# a process lost (killed, frozen) whose robot never commanded again before the run's end: its
# outage_s runs to the end (docs/reference/faults.md, "Outages from the commands"); false when it came back
# or never went
ROBOT_KEYS = ROBOT_KEYS + ("outage_open",)
# realtime clock: control periods whose step ended after the next period had begun, from the
# robot's closing account; null in lockstep (where the simulator counts missed_ticks)
ROBOT_KEYS = ROBOT_KEYS + ("deadline_misses",)
# the path coordinate s (path coordinate of a true position, M1) of the true position at the run's end; null without a path
# (docs/reference/metrics.md, M4b)
ROBOT_KEYS = ROBOT_KEYS + ("path_progress_m",)
# controller steps that raised (or returned an invalid command), each stopping the robot for
# that step, from the runtime's controller_error telemetry (docs/reference/controllers.md, "When step()
# fails"); the fleet's is their sum. solver_failures counts only the controller's own solver_ok
ROBOT_KEYS = ROBOT_KEYS + ("controller_errors",)
# blocked lanes (docs/reference/metrics.md, M4c; docs/reference/detours.md): time stalled from the truth (null
# without a path) and detours started, from the runtime's detour_start events
ROBOT_KEYS = ROBOT_KEYS + ("stalled_s", "detours")
FLEET_KEYS = (
    "coordination_error_max_m",
    "coordination_error_rms_m",
    "min_separation_m",
    "collisions",
    "messages_published",
    "messages_recorded",
    "messages_dropped_by_faults",
    "tasks_completed",
    "tasks_total",
    "task_times_s",
    "assignment_cost",
    "assignment_cost_optimal",
    "conflicts_resolved",
    "min_obstacle_clearance_m",
    "formation_error_max_m",
    "formation_error_transition_max_m",
    "coordination_error_max_reported_m",
    "coordination_error_rms_reported_m",
    "formation_error_max_reported_m",
    "tasks_completed_reported",
    "task_times_reported_s",
    "messages_rejected",
    # realtime clock (null in lockstep): agents' deadline misses, their share of the agents'
    # control periods, and physics steps the simulator started late (docs/reference/performance.md)
    "deadline_misses",
    "deadline_miss_rate",
    "physics_overruns",
    # the recorder's own accounts (over Zenoh; null in one process): records that never
    # reached it (gaps in each sender's sequence numbers), and process incarnations that
    # left no closing account (killed), whose published count is taken from their last
    # sequence number (docs/reference/faults.md, "Accounts that survive a kill")
    "messages_lost",
    "accounts_reconstructed",
    # a leader-following team (Sec. 5.3): who led from when, [[t, robot], ...], by the
    # succession rule on the simulator's loss events; null for other teams (docs/reference/metrics.md, formation error (M3))
    "leaders",
    "controller_errors",
)
METRIC_KEYS = {"robots": ROBOT_KEYS, "fleet": FLEET_KEYS}


@dataclass
class RobotTrace:
    """What the log says about one robot."""

    t: np.ndarray
    """(n,) simulator tick times [s]."""
    pose: np.ndarray
    """(n, 3) true poses."""
    command: np.ndarray
    """(n, k) applied commands."""
    violated: np.ndarray
    wheel_max: np.ndarray
    clearance: np.ndarray | None
    telemetry_t: np.ndarray
    """(m,) controller step times [s]."""
    telemetry: list[dict]
    solve_ms: np.ndarray
    radius: float = 0.0

    def pose_at(self, times: np.ndarray) -> np.ndarray:
        """True pose interpolated at ``times`` (heading unwrapped first)."""
        if len(self.t) == 0:
            return np.full((len(times), 3), np.nan)
        th = np.unwrap(self.pose[:, 2])
        return np.stack([np.interp(times, self.t, self.pose[:, 0]), np.interp(times, self.t, self.pose[:, 1]),
                         np.interp(times, self.t, th)], axis=-1)


@dataclass
class Trace:
    robots: dict[str, RobotTrace]
    dt: float
    stats: dict[str, dict] = field(default_factory=dict)
    events: list[Event] = field(default_factory=list)
    end: End | None = None
    sim_time_s: float = 0.0
    estimates: dict[str, list[Estimate]] = field(default_factory=dict)
    """Each robot's Estimate records (``[sensing]`` estimator; metrics_estimation.py)."""
    outages: dict[str, list[tuple[float, float | None, float | None]]] = field(default_factory=dict)
    """Per robot, each loss of its process (the simulator's ``robot_lost``, not a radio
    silence): (event time, its last command's time before it or None, its first command's
    time after it or None: never back), in log order."""


def trace_from_records(records, keys: Keys, radii: dict[str, float] | None = None) -> Trace:
    """Build a :class:`Trace` from (log_time_ns, key, record) tuples of one run."""
    truth: list[Truth] = []
    tele: dict[str, list[Telemetry]] = {}
    cmds: dict[str, list[Command]] = {}
    stats: dict[str, dict] = {}
    events: list[Event] = []
    end = None
    dt = 0.0
    estimates: dict[str, list[Estimate]] = {}
    lost: list[tuple[str, float, int]] = []  # (robot, event time, its commands before the event)
    for _, key, rec in records:
        rel = keys.relative(key)
        if isinstance(rec, Truth):
            truth.append(rec)
        elif isinstance(rec, Telemetry):
            tele.setdefault(rel.split("/")[1], []).append(rec)
        elif isinstance(rec, Command):
            cmds.setdefault(rel.split("/")[1], []).append(rec)
        elif isinstance(rec, Stats):
            stats[rec.proc] = dict(rec.counters)
        elif isinstance(rec, Event):
            events.append(rec)
            if rec.source == "sim" and rec.what == "robot_lost" and rec.detail.get("cause") != "silence":
                lost.append((str(rec.detail.get("robot")), float(rec.t), len(cmds.get(str(rec.detail.get("robot")), ()))))
        elif isinstance(rec, Estimate):
            estimates.setdefault(rel.split("/")[1], []).append(rec)
        elif isinstance(rec, End):
            end = rec
        elif getattr(rec, "TYPE", "") == "start":
            dt = rec.dt
    truth.sort(key=lambda r: r.k)
    names = truth[0].names if truth else sorted(set(tele) | set(cmds))
    robots = {}
    for i, n in enumerate(names):
        tt = np.array([r.t for r in truth])
        pose = np.array([r.poses[i] for r in truth]).reshape(-1, 3)
        command = np.array([r.commands[i] for r in truth]) if truth else np.zeros((0, 2))
        violated = np.array([r.violated[i] for r in truth], dtype=bool)
        wheel = np.array([r.wheel_max[i] for r in truth])
        clearance = np.array([r.clearance[i] for r in truth]) if truth and truth[0].clearance is not None else None
        tl = sorted(tele.get(n, []), key=lambda r: (r.t, r.k))
        robots[n] = RobotTrace(
            t=tt,
            pose=pose,
            command=command,
            violated=violated,
            wheel_max=wheel,
            clearance=clearance,
            telemetry_t=np.array([r.t for r in tl]),
            telemetry=[r.data for r in tl],
            solve_ms=np.array([c.solve_ms for c in cmds.get(n, [])]),
            radius=(radii or {}).get(n, 0.0),
        )
    sim_time = float(truth[-1].t + dt) if truth else 0.0
    outages: dict[str, list[tuple[float, float | None, float | None]]] = {}
    for n, t, i in lost:
        c = cmds.get(n, [])
        outages.setdefault(n, []).append((t, float(c[i - 1].t) if i > 0 else None,
                                          float(c[i].t) if i < len(c) else None))
    return Trace(robots, dt, stats, events, end, sim_time, estimates, outages)


def _outage(trace: Trace, name: str) -> tuple[int, float, bool]:
    """(rejoins, seconds gone, still gone at the end) of one robot.

    A lost process (killed, frozen) is gone from its last command before the simulator's
    ``robot_lost`` to its first command after it, in the commands' own times (the truth of
    what it did, not when its token came back), or to the run's end when it never
    commanded again. A radio silence (``cause = "silence"``) counts from the simulator's
    events, as time gone, not as a rejoin: no process was restarted (docs/reference/faults.md)."""
    lost_at, total, rejoins = None, 0.0, 0
    for e in sorted((e for e in trace.events if e.source == "sim" and e.detail.get("robot") == name), key=lambda e: e.t):
        silence = e.detail.get("cause") == "silence"
        if e.what == "robot_rejoined" and not silence:
            rejoins += 1
        if e.what == "robot_lost" and silence and lost_at is None:
            lost_at = e.t
        elif e.what == "robot_rejoined" and silence and lost_at is not None:
            total += e.t - lost_at
            lost_at = None
    if lost_at is not None:
        total += max(0.0, trace.sim_time_s - lost_at)
    still_out, last_back = False, float("-inf")
    for t, before, after in trace.outages.get(name, []):
        start = t if before is None else before
        if after is not None and after <= last_back:  # a second loss before it came back: counted
            continue
        end = after if after is not None else max(start, trace.sim_time_s)
        total += max(0.0, end - max(start, last_back))
        last_back = end
        still_out = after is None
    return rejoins, round(total, 6), still_out


def _rejected(counters: dict | None) -> int | None:
    """Messages a process refused, from its closing account (None without one)."""
    if counters is None:
        return None
    return int(max(int(counters.get("rejects", 0) or 0), int(counters.get("rejected", 0) or 0)))


def _deadline(counters: dict | None, clock: str, rt: "RobotTrace | None" = None) -> tuple[int | None, int]:
    """(deadline misses, control periods) of a realtime robot: from the running account in
    its telemetry, summed over its processes (each restart counts from 0 again), so a
    process killed before its closing account counts too; else from its closing account."""
    if clock != "realtime":
        return None, 0
    if rt is not None and rt.telemetry and "realtime_periods" in rt.telemetry[-1]:
        misses = periods = 0
        last = (0, 0)
        for d in rt.telemetry:
            n = d.get("realtime_periods")
            if n is None:
                continue
            if n < last[1]:  # a new process: the previous one's account is closed
                misses, periods = misses + last[0], periods + last[1]
            last = (int(d.get("deadline_misses", 0) or 0), int(n))
        return misses + last[0], periods + last[1]
    if counters is None:
        return None, 0
    return int(counters.get("deadline_misses", 0) or 0), int(counters.get("realtime_periods", 0) or 0)


def _robot_metrics(rt: RobotTrace, settle: float, model_kind: str, missed: int) -> dict[str, Any]:
    m: dict[str, Any] = dict.fromkeys(ROBOT_KEYS)
    tel_t = rt.telemetry_t
    refs = [(t, d["ref"], d.get("in_transition", False)) for t, d in zip(tel_t, rt.telemetry)
            if d.get("ref") is not None and t >= settle - 1e-9]
    refs = [(t, r) for t, r, tr in refs if not tr]
    if refs and len(rt.t):
        times = np.array([t for t, _ in refs])
        ref = np.array([r for _, r in refs], dtype=float)
        p = rt.pose_at(times)
        e = np.hypot(p[:, 0] - ref[:, 0], p[:, 1] - ref[:, 1])
        m["path_error_max_m"] = _f(e.max())
        m["path_error_rms_m"] = _f(np.sqrt(np.mean(e**2)))
        if ref.shape[1] >= 3:
            he = np.abs(wrap_to_pi(p[:, 2] - ref[:, 2]))
            m["heading_error_max_rad"] = _f(he.max())
    se = [d["speed_error"] for t, d in zip(tel_t, rt.telemetry)
          if d.get("speed_error") is not None and t >= settle - 1e-9]
    if se:
        m["speed_error_rms_mps"] = _f(np.sqrt(np.mean(np.square(se))))
    if len(rt.solve_ms):
        m["solve_ms_p50"] = _f(np.percentile(rt.solve_ms, 50))
        m["solve_ms_p99"] = _f(np.percentile(rt.solve_ms, 99))
    m["limit_violations"] = int(rt.violated.sum())
    m["missed_ticks"] = int(missed)
    if model_kind == "omni" and len(rt.wheel_max):
        m["wheel_speed_max_mps"] = _f(rt.wheel_max.max())
    m["solver_failures"] = int(sum(1 for d in rt.telemetry if d.get("solver_ok") is False))
    m["controller_errors"] = int(sum(1 for d in rt.telemetry if d.get("controller_error")))
    if len(rt.command) > 1 and len(rt.t) > 1:
        # integral of the squared applied command over the run: sum |u|^2 dt
        dts = np.diff(rt.t, append=rt.t[-1] + (rt.t[-1] - rt.t[-2]))
        m["control_effort"] = _f(float(np.sum(np.sum(rt.command**2, axis=1) * dts)))
    m.update(_safety_metrics(rt.telemetry))
    return m


def _safety_metrics(telemetry: list[dict]) -> dict[str, Any]:
    """Interventions of the safety filter (steps at which it changed the command), the largest
    command change and its time per call [ms]; all null when the filter is off."""
    ms = [d["safety_ms"] for d in telemetry if d.get("safety_ms") is not None]
    if not ms:
        return dict.fromkeys(SAFETY_KEYS)
    changes = [d.get("safety_change") or 0.0 for d in telemetry if d.get("safety_active")]
    return {"safety_interventions": len(changes), "safety_change_max": _f(max(changes, default=0.0)),
            "safety_ms_p50": _f(np.percentile(ms, 50)), "safety_ms_p99": _f(np.percentile(ms, 99))}


def reported_coordination_series(trace: Trace, scenario: Scenario, settle: float = 0.0):
    """(ticks, error) of the coordination the controllers report: max over the scored
    pairs (``[metrics] coordination_pairs``) of |xi_i - xi_j| (modulo ``xi_period``), each
    robot's telemetry ``xi`` interpolated onto the simulator's ticks after ``settle``;
    None when fewer than two robots report xi. The metrics and the plots both use it."""
    xs = {}
    period = 0.0
    for n, rt in trace.robots.items():
        pts = [(t, d["xi"]) for t, d in zip(rt.telemetry_t, rt.telemetry) if d.get("xi") is not None]
        if pts:
            xs[n] = np.array(pts, dtype=float)
            period = max(period, max(float(d.get("xi_period") or 0.0) for d in rt.telemetry if "xi" in d))
    if len(xs) < 2:
        return None
    ref = next(iter(trace.robots.values()))
    grid = ref.t[ref.t >= settle - 1e-9]
    lo = max(a[0, 0] for a in xs.values())
    hi = min(a[-1, 0] for a in xs.values())
    grid = grid[(grid >= lo - 1e-9) & (grid <= hi + 1e-9)]
    if len(grid) == 0:
        return None
    vals = {n: np.interp(grid, a[:, 0], a[:, 1]) for n, a in xs.items()}
    if scenario.metrics["coordination_pairs"] == "edges":
        pairs = [(a, b) for a, b in scenario.edges() if a in vals and b in vals]
    else:
        pairs = list(itertools.combinations(sorted(vals), 2))
    if not pairs:
        return None
    err = np.zeros(len(grid))
    for a, b in pairs:
        d = vals[a] - vals[b]
        if period > 0:
            d = d - period * np.round(d / period)
        err = np.maximum(err, np.abs(d))
    return grid, err


def _coordination_reported(trace: Trace, scenario: Scenario, settle: float):
    series = reported_coordination_series(trace, scenario, settle)
    if series is None:
        return None, None
    err = series[1]
    return _f(err.max()), _f(np.sqrt(np.mean(err**2)))


def _separation(trace: Trace, scenario: Scenario):
    names = list(trace.robots)
    radii = {r.name: r.model.radius for r in scenario.robots}
    if len(names) < 2:
        return None, 0
    n_t = min(len(trace.robots[n].t) for n in names)
    if n_t == 0:
        return None, 0
    P = np.stack([trace.robots[n].pose[:n_t, :2] for n in names], axis=1)  # (T, R, 2)
    D = np.linalg.norm(P[:, :, None, :] - P[:, None, :, :], axis=-1)
    iu = np.triu_indices(len(names), 1)
    d = D[:, iu[0], iu[1]]  # (T, pairs)
    lim = np.array([radii[names[i]] + radii[names[j]] for i, j in zip(*iu)])
    overlap = d < lim
    onsets = overlap[0].sum() + np.logical_and(overlap[1:], ~overlap[:-1]).sum()
    return _f(d.min()), int(onsets)


def compute_metrics(
    trace: Trace,
    scenario: Scenario,
    *,
    run_id: str,
    clock: str,
    wall_time_s: float,
    messages_published: int | None,
    messages_recorded: int | None,
) -> dict[str, Any]:
    """The metrics.json object of a run."""
    settle = scenario.run.settle_s
    missed = trace.stats.get("sim", {}).get("missed_ticks", {}) or {}
    robots = {}
    for r in scenario.robots:
        rt = trace.robots.get(r.name)
        if rt is None:
            robots[r.name] = dict.fromkeys(ROBOT_KEYS)
            continue
        robots[r.name] = _robot_metrics(rt, settle, r.model.kind, missed.get(r.name, 0))
        robots[r.name].update(estimation_metrics(trace.estimates.get(r.name), rt.pose_at))
        robots[r.name]["messages_rejected"] = _rejected(trace.stats.get(r.name))
        robots[r.name]["restarts"], robots[r.name]["outage_s"], robots[r.name]["outage_open"] = _outage(trace, r.name)
        robots[r.name]["deadline_misses"] = _deadline(trace.stats.get(r.name), clock, rt)[0]
    geometry = team_geometry(scenario)
    series = truth_series(trace, scenario, geometry) if geometry is not None else None
    for n, e in cross_track_series(trace, scenario, geometry, series).items():
        t = trace.robots[n].t
        e = e[t >= settle - 1e-9]
        if n in robots and len(e):
            robots[n]["cross_track_error_max_m"] = _f(e.max())
            robots[n]["cross_track_error_rms_m"] = _f(np.sqrt(np.mean(e**2)))
    paths = dict(geometry.paths) if geometry is not None else {
        r.name: scenario.paths[r.path] for r in scenario.robots if r.path}
    tracked: dict[str, np.ndarray] = {}
    for n, path in paths.items():
        rt = trace.robots.get(n)
        if n in robots and rt is not None and len(rt.t):
            known = series.s.get(n) if series is not None else None
            if known is None or len(known) != len(rt.t):
                known = track_coordinate(path, np.asarray(rt.pose)[:, :2])
            robots[n]["path_progress_m"] = _f(known[-1])
            tracked[n] = known
    if tracked:
        t_any = trace.robots[next(iter(tracked))].t
        for n, v in stall_metrics(t_any, tracked, scenario, paths, series, geometry).items():
            robots[n]["stalled_s"] = v
    for n, c in detour_counts(trace.events, robots).items():
        robots[n]["detours"] = c
    fleet: dict[str, Any] = dict.fromkeys(FLEET_KEYS)
    fleet.update(truth_metrics(trace, scenario, series))
    fleet["coordination_error_max_reported_m"], fleet["coordination_error_rms_reported_m"] = \
        _coordination_reported(trace, scenario, settle)
    fleet["min_separation_m"], collisions = _separation(trace, scenario)
    clearances = [rt.clearance for rt in trace.robots.values() if rt.clearance is not None and len(rt.clearance)]
    if clearances:
        fleet["min_obstacle_clearance_m"] = _f(min(c.min() for c in clearances))
        for c in clearances:
            hit = c < 0
            collisions += int(hit[0]) + int(np.logical_and(hit[1:], ~hit[:-1]).sum())
    fleet["collisions"] = int(collisions)
    errors = [m["controller_errors"] for m in robots.values() if m.get("controller_errors") is not None]
    fleet["controller_errors"] = sum(errors) if errors else None
    fleet["messages_published"] = messages_published
    fleet["messages_recorded"] = messages_recorded
    fleet["messages_dropped_by_faults"] = int(
        sum(int(s.get("dropped_by_faults", 0)) + int(s.get("partitioned", 0)) + int(s.get("silenced", 0) or 0)
            for s in trace.stats.values())
    )
    rejected = [_rejected(trace.stats.get(p)) for p in ("sim", *scenario.robot_names)]
    fleet["messages_rejected"] = None if all(n is None for n in rejected) else sum(n or 0 for n in rejected)
    if clock == "realtime":
        dl = [_deadline(trace.stats.get(n), clock, trace.robots.get(n)) for n in scenario.robot_names]
        dl = [d for d in dl if d[0] is not None]
        if dl:
            fleet["deadline_misses"] = sum(m for m, _ in dl)
            periods = sum(n for _, n in dl)
            fleet["deadline_miss_rate"] = _f(fleet["deadline_misses"] / periods) if periods else None
        sim_stats = trace.stats.get("sim")
        if sim_stats is not None:
            fleet["physics_overruns"] = int(sim_stats.get("physics_overruns", 0) or 0)
    fe = [d["formation_error"] for rt in trace.robots.values() for t, d in zip(rt.telemetry_t, rt.telemetry)
          if d.get("formation_error") is not None and t >= settle - 1e-9 and not d.get("in_transition", False)]
    if fe:
        fleet["formation_error_max_reported_m"] = _f(max(fe))
    from agent.controllers import task_queues  # noqa: PLC0415 (the registry: light, no law)

    if task_queues(scenario):  # a family with a done rule (Chapter 6 task queues)
        from orchestrator.analysis.roles import roles_metrics  # noqa: PLC0415

        fleet.update(roles_metrics(trace, scenario))
    return {
        "scenario": scenario.id,
        "title": scenario.title,
        "run_id": run_id,
        "clock": clock,
        "seed": scenario.run.seed,
        "sim_time_s": _f(trace.sim_time_s),
        "wall_time_s": _f(wall_time_s),
        "settle_s": scenario.run.settle_s,
        "robots": robots,
        "fleet": fleet,
    }


def metrics_from_log(path) -> dict[str, Any]:
    """metrics.json recomputed from a run log alone (``copath metrics RUN.mcap``).

    The scenario comes from the log's metadata; ``messages_published`` from the closing
    accounts in the log; ``wall_time_s`` is not in the log and is null; ``ok`` and
    ``failure`` come from the recorded outcome. Raises ValueError for a log without a
    scenario.
    """
    from copath.scenario import ConfigError, parse_scenario  # noqa: PLC0415

    from orchestrator.log.mcap import read_log  # noqa: PLC0415

    log = read_log(path)
    raw = log.scenario_raw
    if not raw:
        raise ValueError(f"{path}: the log has no scenario in its metadata (not a copath run log?)")
    try:
        scenario = parse_scenario(raw, base_dir=None, source=str(raw.get("_source", "")))
    except ConfigError as exc:
        raise ValueError(f"{path}: the recorded scenario does not parse: {exc}") from exc
    outcome = log.metadata.get("outcome", {})
    ok = outcome.get("ok", "True") == "True"
    return log_metrics(log, scenario, run_id=log.run_id, clock=log.metadata.get("copath", {}).get("clock", ""),
                       wall_time_s=None, ok=ok, failure=outcome.get("reason"))


def log_metrics(log, scenario: Scenario, *, run_id: str, clock: str, wall_time_s: float | None, ok: bool,
                failure: str | None) -> dict[str, Any]:
    """metrics.json of a read-back log (:func:`orchestrator.log.mcap.read_log`): the one
    computation behind ``copath run`` and ``copath metrics``. Messages published come from
    the closing accounts (null for a failed run, whose accounts may be missing)."""
    keys = Keys(run_id)
    stats = [r for _, _, r in log.records if isinstance(r, Stats)]
    recorded = sum(1 for _, k, _ in log.records if not keys.relative(k).startswith("stats/")) + log.rejected
    accounts = [json.loads(v) for v in log.metadata.get("accounts", {}).values()]
    published = sum(s.published for s in stats) if stats and ok else None
    if accounts:  # the recorder's ground truth: closed accounts, and the dead ones up to their last record
        published = sum(a["closed"] if a.get("closed") is not None else a["last"] for a in accounts)
    m = compute_metrics(trace_from_records(log.records, keys), scenario, run_id=run_id, clock=clock,
                        wall_time_s=float("nan") if wall_time_s is None else wall_time_s,
                        messages_published=published, messages_recorded=recorded)
    if accounts:
        m["fleet"]["messages_lost"] = int(sum(a["missing"] for a in accounts))
        m["fleet"]["accounts_reconstructed"] = sum(1 for a in accounts if a.get("closed") is None)
    m["ok"] = ok
    m["failure"] = None if ok else failure
    return m
