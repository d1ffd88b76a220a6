"""``run.until = "tasks_done"`` ends a Chapter 6 run on the truth, by the metrics' own rule
(copath.occupancy): the last formation's announced targets occupied by the true
positions, not the robots' reports of being done."""

import numpy as np
import pytest

from agent.controllers import task_queues
from copath.occupancy import LastFormationWatch, first_occupied, occupied, queues_from_json, queues_to_json
from copath.scenario import load_scenario
from copath.wire.messages import Event, Telemetry
from orchestrator.run.inprocess import run_scenario
from sim.node import TaskWatch, sim_tasks
from tests.conftest import config

SQUARE = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]


def _placed(dx=2.0, dy=-1.0):
    return (np.asarray(SQUARE) + [dx, dy]).tolist()


def test_occupancy_needs_one_robot_per_target():
    G = np.asarray(SQUARE)
    assert occupied(G + 0.01, G, 0.05)
    two_on_one = np.array([[0, 0], [0.01, 0], [1, 1], [0, 1]], dtype=float)
    assert not occupied(two_on_one, G, 0.05)  # every target near a robot is not enough: a matching
    assert not occupied(G + 0.06, G, 0.05)
    surplus = np.vstack([G, [[3.0, 3.0]]])  # N > M: every target occupied, the fifth robot anywhere
    assert occupied(surplus, G, 0.05)
    assert occupied(G[:3], G, 0.05) and not occupied(np.vstack([G[:2], [[5.0, 5.0]]]), G, 0.05)  # N < M: every robot on a target
    P = np.stack([G + 1.0, two_on_one, G + 0.02, G])
    assert first_occupied(P, G, 0.05) == 2


def test_watch_uses_the_first_announcement_and_ignores_non_rigid_targets():
    w = LastFormationWatch(["a", "b", "c", "d"], [SQUARE, SQUARE], 0.05)
    G = np.asarray(_placed())
    w.update("b", 3.0, {"task": 1, "formation_targets": G.tolist()})
    w.update("a", 3.0, {"task": 1, "formation_targets": (G + 5).tolist()})  # same time, earlier robot wins
    w.update("c", 2.0, {"task": 0, "formation_targets": SQUARE})  # an earlier task does not count
    assert np.allclose(w.targets, G + 5)
    assert not w.completed(2.9, G + 5)  # before the announcement
    assert w.completed(3.0, G + 5) and not w.completed(3.0, G)
    skew = LastFormationWatch(["a"], [SQUARE], 0.05)
    skew.update("a", 0.0, {"task": 0, "formation_targets": [[0, 0], [2, 0], [1, 1], [0, 1]]})
    assert skew.targets is None and not skew.completed(1.0, np.asarray(SQUARE))


def test_reports_of_done_do_not_stop_the_run_the_truth_does():
    s = load_scenario(config("e6.5-"))
    watch = TaskWatch(s, task_queues(s))  # the roles family's declared queues, as the orchestrator hands them
    assert watch.names == list(s.robot_names)
    last = len(s.robots[0].params["formations"]) - 1
    names = watch.names
    template = np.asarray(s.robots[0].params["formations"][last], dtype=float)
    G = template + [0.3, -0.2]
    far = {n: np.array([10.0 + i, 0.0, 0.0]) for i, n in enumerate(names)}
    for n in names:  # every robot says it is done with the last formation
        watch.update(n, Telemetry(100, 10.0, {"task": last, "task_done": True, "formation_targets": G.tolist()}))
    assert not watch.done(10.0, far)
    on = {n: np.array([*G[i % len(G)], 0.0]) for i, n in enumerate(names)}
    on.update({n: far[n] for n in names[len(G):]})  # surplus robots wait anywhere
    assert watch.done(10.0, on)


def test_the_task_queues_reach_the_simulator_process_unchanged():
    """What ``copath run`` passes the simulator process (``--tasks``) is what the family declared."""
    s = load_scenario(config("e6.5-"))
    queues = task_queues(s)
    assert list(queues) == list(s.robot_names)
    back = queues_from_json(queues_to_json(queues))
    assert list(back) == list(queues)
    for n, q in queues.items():
        assert back[n].arrive_tol == q.arrive_tol
        assert np.allclose(np.asarray(back[n].formations[-1], dtype=float), np.asarray(q.formations[-1], dtype=float))
    with pytest.raises(ValueError, match="task queues"):
        queues_from_json('{"r1": {"formations": 3}}')
    # the process: --tasks, else the families asked (copath sim), else refused for tasks_done
    assert list(sim_tasks(s, queues_to_json(queues), None)) == list(queues)
    assert sim_tasks(s, None, task_queues) == queues
    with pytest.raises(ValueError, match="--tasks"):
        sim_tasks(s, None, None)


@pytest.fixture(scope="module")
def early_reports():
    """E6.5 with robots that call a target reached 0.3 m short of it: they report every
    formation done (and move on) before the truth has completed it."""
    s = load_scenario(config("e6.5-"))
    s = s.with_overrides(controller={"arrive_tol": 0.3}, metrics={"task_tolerance_m": 0.05})
    return s, run_scenario(s)


def test_the_run_ends_a_margin_after_the_truth_completes_the_last_formation(early_reports):
    s, res = early_reports
    run = s.run
    ev = [r for _, _, r in res.records if isinstance(r, Event) and r.what == "tasks_done"]
    assert len(ev) == 1
    t_done = ev[0].detail["t"]
    # the truth, from the log: the first announcement of the last formation's targets, then
    # the first truth tick on which the true positions occupy them within 5 cm
    last = len(s.robots[0].params["formations"]) - 1
    robots = list(res.trace.robots.values())
    t_a, G = min((t, i, np.asarray(d["formation_targets"]))
                 for i, rt in enumerate(robots)
                 for t, d in zip(rt.telemetry_t, rt.telemetry)
                 if d.get("task") == last and d.get("formation_targets") is not None)[::2]
    t_truth = robots[0].t
    P = np.stack([rt.pose[:, :2] for rt in robots], axis=1)
    win = np.nonzero(t_truth >= t_a - 1e-9)[0]
    hits = [k for k in win if occupied(P[k], G, 0.05)]
    assert hits and t_done == pytest.approx(t_truth[hits[0]], abs=1e-9)
    # reports came earlier: every robot said the last formation was done before the truth did
    reported = min(t for rt in robots for t, d in zip(rt.telemetry_t, rt.telemetry)
                   if d.get("task") == last and d.get("task_done"))
    assert reported < t_done
    f = res.metrics["fleet"]
    # the reports count every formation; the truth misses the ones the team left too early
    assert f["tasks_completed_reported"] == f["tasks_total"] > f["tasks_completed"] >= 1
    assert res.metrics["sim_time_s"] == pytest.approx(t_done + run.until_margin_s + run.dt, abs=1e-6)
