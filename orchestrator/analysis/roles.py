"""Fleet metrics of the role-assignment scenarios (Chapter 6, E6.1-E6.5).

:func:`roles_metrics` reads what the ``roles`` controllers logged (telemetry ``task``,
``task_done``, ``formation_targets``, ``assigned_index``, ``conflicts_resolved``) and the
simulator's true poses, and returns the fleet keys of metrics.json:

- ``tasks_total``: formations in the queue;
- ``tasks_completed``: formations k completed by the truth: at some tick between the
  first agreement on k's targets and the first robot moving on to k+1, the true
  positions occupy the targets, one robot per target (every target when there are at
  least as many robots as targets, Sec. 6.2.1; every robot on its own target otherwise),
  each within the tolerance ``[metrics] task_tolerance_m`` (default: the controllers'
  ``arrive_tol``). The targets are the template after the translation (and rotation) the
  team agreed on (Algorithm 6.1, announced as ``formation_targets``); announced targets
  that are not a rigid motion of the template do not count. The rule lives in
  :mod:`copath.occupancy`, which the simulator's stop rule ``run.until = "tasks_done"``
  uses too;
- ``task_times_s``: for each truth-completed formation, the time from the first robot
  starting it (t = 0 for the first) to that tick;
- ``tasks_completed_reported`` and ``task_times_reported_s``: the same from what the
  controllers report (every robot working on k with ``task_done``; a robot lost by the
  simulator's record, ``robot_lost`` until ``robot_rejoined``, reports nothing and is left
  out);
- ``assignment_cost``: sum over formations of (6.5), sum_i ||x_i - g_p(i)||^2, for the
  roles the robots finally held, with x_i the true positions at the instant the first
  robot agreed on the formation's targets;
- ``assignment_cost_optimal``: the same with the centralised Hungarian method (6.7) on
  full information (all robots, the same targets, the same instant);
- ``conflicts_resolved``: negotiations initiated, summed over robots.

Extra keys: ``assignment_cost_per_task``, ``assignment_cost_optimal_per_task`` and
``assignment_duplicates`` (positions held by more than one robot at the end of a
formation, which the negotiation must prevent).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from copath.occupancy import first_occupied, formations, is_rigid_placement, task_tolerance

from agent.controllers import task_queues
from orchestrator.analysis.truth import outages

__all__ = ["roles_metrics"]


def _latest(times: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Index of the latest sample at or before each grid time (-1 before the first)."""
    return np.searchsorted(times, grid + 1e-9, side="right") - 1


def roles_metrics(trace, scenario) -> dict[str, Any]:
    """Task and assignment figures of a Ch. 6 run.

    Parameters
    ----------
    trace : orchestrator.analysis.metrics.Trace
        ``trace.robots[name]`` with ``t`` (n,), ``pose`` (n, 3), ``telemetry_t`` (m,) and
        ``telemetry`` (list of m dicts).
    scenario : copath.scenario.Scenario
        The scenario (its roles robots' ``formations`` give the templates and the task count).

    Returns
    -------
    dict
        The fleet keys listed in the module docstring.
    """
    queues = task_queues(scenario)
    forms = formations(queues)
    names = [n for n in queues if n in trace.robots]
    out: dict[str, Any] = {
        "tasks_total": len(forms),
        "tasks_completed": 0,
        "task_times_s": [],
        "tasks_completed_reported": 0,
        "task_times_reported_s": [],
        "assignment_cost": None,
        "assignment_cost_optimal": None,
        "conflicts_resolved": 0,
        "assignment_cost_per_task": [],
        "assignment_cost_optimal_per_task": [],
        "assignment_duplicates": 0,
    }
    if not names or not forms:
        return out
    robots = {n: trace.robots[n] for n in names}
    tol = task_tolerance(scenario, names, queues)
    grid = np.unique(np.concatenate([np.asarray(rt.telemetry_t, dtype=float) for rt in robots.values()]))
    if len(grid) == 0:
        return out
    task = np.full((len(names), len(grid)), -1, dtype=int)
    done = np.zeros((len(names), len(grid)), dtype=bool)
    for i, rt in enumerate(robots.values()):
        tt = np.asarray(rt.telemetry_t, dtype=float)
        if len(tt) == 0:
            continue
        tk = np.array([int(d.get("task", -1)) if d.get("task") is not None else -1 for d in rt.telemetry])
        dn = np.array([bool(d.get("task_done", False)) for d in rt.telemetry])
        idx = _latest(tt, grid)
        ok = idx >= 0
        task[i, ok] = tk[idx[ok]]
        done[i, ok] = dn[idx[ok]]

    # robots lost by the simulator's record (robot_lost .. robot_rejoined) report nothing:
    # the live ones' reports decide
    lost = np.zeros((len(names), len(grid)), dtype=bool)
    since: dict[str, float] = {}
    for t_e, n, is_lost in outages(getattr(trace, "events", ())):
        if n not in robots:
            continue
        if is_lost:
            since.setdefault(n, t_e)
        elif n in since:
            lost[names.index(n)] |= (grid >= since.pop(n) - 1e-9) & (grid < t_e - 1e-9)
    for n, t_l in since.items():
        lost[names.index(n)] |= grid >= t_l - 1e-9

    conflicts = 0
    for rt in robots.values():
        vals = [d["conflicts_resolved"] for d in rt.telemetry if d.get("conflicts_resolved") is not None]
        conflicts += int(vals[-1]) if vals else 0
    out["conflicts_resolved"] = conflicts

    # true positions of the roles robots on the simulator's ticks
    T = min(len(rt.t) for rt in robots.values())
    t_truth = np.asarray(next(iter(robots.values())).t[:T], dtype=float)
    P = np.stack([np.asarray(rt.pose, dtype=float)[:T, :2] for rt in robots.values()], axis=1)  # (T, n, 2)

    times, times_rep, cost, cost_opt = [], [], [], []
    for k in range(len(forms)):
        on_k = task == k
        started = np.nonzero(on_k.any(axis=0))[0]
        if len(started) == 0:
            continue
        t_start = 0.0 if k == 0 else float(grid[started[0]])
        full = np.nonzero(np.all((on_k & done) | lost, axis=0) & np.any(on_k & done & ~lost, axis=0))[0]
        t_rep = float(grid[full[0]]) if len(full) else None
        if t_rep is not None:
            times_rep.append(round(t_rep - t_start, 6))
        # targets and instant: the first robot to agree on formation k
        first = None
        for rt in robots.values():
            for t, d in zip(rt.telemetry_t, rt.telemetry):
                if d.get("task") == k and d.get("formation_targets") is not None:
                    if first is None or t < first[0]:
                        first = (float(t), np.asarray(d["formation_targets"], dtype=float).reshape(-1, 2))
                    break
        if first is None:
            continue
        t_a, G = first
        # truth: the targets occupied between the agreement and the first robot on task k+1
        later = np.nonzero((task > k).any(axis=0))[0]
        t_next = float(grid[later[0]]) if len(later) else np.inf
        t_end = None
        if is_rigid_placement(forms[k], G):
            win = np.nonzero((t_truth >= t_a - 1e-9) & (t_truth <= t_next + 1e-9))[0]
            hit = first_occupied(P[win], G, tol) if len(win) else None
            if hit is not None:
                t_end = float(t_truth[win[hit]])
                times.append(round(t_end - t_start, 6))
        horizon = t_end if t_end is not None else (t_rep if t_rep is not None else np.inf)
        X, held = [], []
        for rt in robots.values():
            X.append(_pose_at(rt, t_a))
            idx = -1
            for t, d in zip(rt.telemetry_t, rt.telemetry):
                if t > horizon + 1e-9:
                    break
                if d.get("task") == k and d.get("assigned_index") is not None:
                    idx = int(d["assigned_index"])
            held.append(idx)
        X = np.asarray(X)
        held = np.asarray(held)
        valid = (held >= 0) & (held < len(G))
        c = float(np.sum((X[valid] - G[held[valid]]) ** 2))
        C = np.sum((X[:, None, :] - G[None, :, :]) ** 2, axis=-1)
        rows, cols = linear_sum_assignment(C)
        c_opt = float(C[rows, cols].sum())
        _, counts = np.unique(held[valid], return_counts=True)
        out["assignment_duplicates"] += int(np.sum(counts > 1))
        cost.append(round(c, 6))
        cost_opt.append(round(c_opt, 6))
    out["tasks_completed"] = len(times)
    out["task_times_s"] = times
    out["tasks_completed_reported"] = len(times_rep)
    out["task_times_reported_s"] = times_rep
    out["assignment_cost_per_task"] = cost
    out["assignment_cost_optimal_per_task"] = cost_opt
    if cost:
        out["assignment_cost"] = round(float(sum(cost)), 6)
        out["assignment_cost_optimal"] = round(float(sum(cost_opt)), 6)
    return out


def _pose_at(rt, t: float) -> np.ndarray:
    """Position at time t by linear interpolation of the true poses."""
    tt = np.asarray(rt.t, dtype=float)
    P = np.asarray(rt.pose, dtype=float)
    return np.array([np.interp(t, tt, P[:, 0]), np.interp(t, tt, P[:, 1])])
