"""roles_metrics on a synthetic trace with a known outcome (Chapter 6 metrics)."""

from types import SimpleNamespace

import numpy as np
import pytest

from orchestrator.analysis.roles import roles_metrics

DT = 0.5
G0 = [[0.0, 0.0], [1.0, 0.0]]  # formation 0: two positions
G1 = [[0.0, 1.0], [1.0, 1.0], [2.0, 1.0]]  # formation 1: three positions, one stays empty


def _robot(start, steps):
    """steps: list of (t, xy, telemetry dict); pose held between samples."""
    t = np.array([s[0] for s in steps])
    pose = np.array([[*s[1], 0.0] for s in steps])
    return SimpleNamespace(t=t, pose=pose, telemetry_t=t.copy(), telemetry=[s[2] for s in steps])


def _trace():
    # robot a: task 0 -> position 1 (swapped with the optimum), done at t=2; task 1 -> position 0
    a = _robot((0.0, 0.0), [
        (0.0, (0.0, 0.0), {"task": 0, "task_done": False, "formation_targets": G0, "assigned_index": 1,
                           "conflicts_resolved": 0}),
        (0.5, (0.5, 0.0), {"task": 0, "task_done": False, "conflicts_resolved": 1}),
        (1.0, (1.0, 0.0), {"task": 0, "task_done": True, "conflicts_resolved": 1}),
        (1.5, (1.0, 0.0), {"task": 0, "task_done": True, "conflicts_resolved": 1}),
        (2.0, (1.0, 0.0), {"task": 1, "task_done": False, "formation_targets": G1, "assigned_index": 0,
                           "conflicts_resolved": 1}),
        (2.5, (0.5, 0.5), {"task": 1, "task_done": False, "conflicts_resolved": 1}),
        (3.0, (0.0, 1.0), {"task": 1, "task_done": True, "conflicts_resolved": 1}),
        (3.5, (0.0, 1.0), {"task": 1, "task_done": True, "conflicts_resolved": 1}),
    ])
    # robot b: task 0 -> position 0 at t=1.5; task 1 -> position 1, never done
    b = _robot((1.0, 0.0), [
        (0.0, (1.0, 0.0), {"task": 0, "task_done": False, "formation_targets": G0, "assigned_index": 0,
                           "conflicts_resolved": 0}),
        (0.5, (1.0, 0.0), {"task": 0, "task_done": False, "conflicts_resolved": 0}),
        (1.0, (0.5, 0.0), {"task": 0, "task_done": False, "conflicts_resolved": 0}),
        (1.5, (0.0, 0.0), {"task": 0, "task_done": True, "conflicts_resolved": 0}),
        (2.0, (0.0, 0.0), {"task": 0, "task_done": True, "conflicts_resolved": 0}),
        (2.5, (0.0, 0.0), {"task": 1, "task_done": False, "formation_targets": G1, "assigned_index": 1,
                           "conflicts_resolved": 2}),
        (3.0, (0.5, 0.5), {"task": 1, "task_done": False, "conflicts_resolved": 2}),
        (3.5, (0.8, 0.8), {"task": 1, "task_done": False, "conflicts_resolved": 2}),
    ])
    return SimpleNamespace(robots={"a": a, "b": b}, dt=DT)


def _scenario():
    robots = [SimpleNamespace(name=n, controller="roles", params={"formations": [G0, G1]}) for n in ("a", "b")]
    return SimpleNamespace(robots=robots)


def test_roles_metrics_on_a_synthetic_trace():
    m = roles_metrics(_trace(), _scenario())
    assert m["tasks_total"] == 2
    # reported: task 0 both working on it and done at t = 1.5; task 1: b never finishes
    assert m["tasks_completed_reported"] == 1
    assert m["task_times_reported_s"] == [pytest.approx(1.5)]
    # truth: the two positions of task 0 are occupied from t = 0 (a and b swapped), task 1
    # never has both robots on distinct targets
    assert m["tasks_completed"] == 1
    assert m["task_times_s"] == [pytest.approx(0.0)]
    # task 0 at t = 0: a at (0,0) holds position 1 (cost 1), b at (1,0) holds 0 (cost 1);
    # the optimum keeps both where they are (cost 0)
    assert m["assignment_cost_per_task"][0] == pytest.approx(2.0)
    assert m["assignment_cost_optimal_per_task"][0] == pytest.approx(0.0)
    # task 1, first agreement at t = 2.0: a at (1,0) -> (0,1) costs 2, b at (0,0) -> (1,1)
    # costs 2; the optimum sends a to (1,1) (1) and b to (0,1) (1)
    assert m["assignment_cost_per_task"][1] == pytest.approx(4.0)
    assert m["assignment_cost_optimal_per_task"][1] == pytest.approx(2.0)
    assert m["assignment_cost"] == pytest.approx(6.0)
    assert m["assignment_cost_optimal"] == pytest.approx(2.0)
    assert m["conflicts_resolved"] == 3
    assert m["assignment_duplicates"] == 0


def test_roles_metrics_counts_duplicates_and_handles_no_roles_robots():
    tr = _trace()
    tr.robots["b"].telemetry[0] = dict(tr.robots["b"].telemetry[0], assigned_index=1)
    m = roles_metrics(tr, _scenario())
    assert m["assignment_duplicates"] == 1
    empty = roles_metrics(tr, SimpleNamespace(robots=[SimpleNamespace(name="a", controller="consensus", params={})]))
    assert empty["tasks_total"] == 0 and empty["assignment_cost"] is None


def test_truth_tasks_ignore_a_team_that_claims_done_away_from_the_targets():
    tr = _trace()
    for rt in tr.robots.values():  # everyone claims task 1 done at the end, b is at (0.8, 0.8)
        rt.telemetry[-1] = dict(rt.telemetry[-1], task=1, task_done=True)
    m = roles_metrics(tr, _scenario())
    assert m["tasks_completed_reported"] == 2 and m["tasks_completed"] == 1
    # once b really stands on (1, 1) the truth counts the task, 1.5 s after it started at t = 2
    tr.robots["b"].pose[-1, :2] = (1.0, 1.0 + 0.04)
    m = roles_metrics(tr, _scenario())
    assert m["tasks_completed"] == 2 and m["task_times_s"][1] == pytest.approx(1.5)
    # 4 cm is outside a 3 cm tolerance
    strict = _scenario()
    strict.metrics = {"task_tolerance_m": 0.03}
    assert roles_metrics(tr, strict)["tasks_completed"] == 1


def test_truth_tasks_reject_announced_targets_that_are_not_the_template():
    tr = _trace()
    bent = [[0.0, 0.0], [0.5, 0.5]]  # not a rigid motion of G0
    for rt in tr.robots.values():
        rt.telemetry[0] = dict(rt.telemetry[0], formation_targets=bent)
    assert roles_metrics(tr, _scenario())["tasks_completed"] == 0


def test_a_robot_lost_on_record_is_left_out_of_the_reported_completion():
    """b's reports stop while it is lost (the simulator's robot_lost .. robot_rejoined):
    a's report of task 1 alone completes it while b is lost, not before, not after."""
    tr = _trace()
    tr.robots["a"].telemetry[-1] = dict(tr.robots["a"].telemetry[-1], task_done=True)
    assert roles_metrics(tr, _scenario())["tasks_completed_reported"] == 1  # b never reports task 1 done
    ev = lambda t, what: SimpleNamespace(t=t, source="sim", what=what, detail={"robot": "b"})  # noqa: E731
    tr.events = [ev(2.75, "robot_lost")]
    m = roles_metrics(tr, _scenario())
    # a reports task 1 done from t = 3.0, b is lost from 2.75: task 1 reported at 3.0, 1.0 s after t = 2.0
    assert m["tasks_completed_reported"] == 2 and m["task_times_reported_s"][1] == pytest.approx(1.0)
    tr.events = [ev(2.75, "robot_lost"), ev(2.9, "robot_rejoined")]  # back before a is done
    assert roles_metrics(tr, _scenario())["tasks_completed_reported"] == 1
    tr.events = [SimpleNamespace(t=2.75, source="r1", what="robot_lost", detail={"robot": "b"})]
    assert roles_metrics(tr, _scenario())["tasks_completed_reported"] == 1  # only the simulator's record counts
