"""Role assignment without a lost robot (Ch. 6, Algorithm 6.2; docs/reference/ambiguities.md, robot lost in role assignment (A38)).

E6.3 (16 robots, 12 positions) with r5's radio silent for the rest of the run and
``run.on_robot_failure = "continue"``: the team leaves r5 out of its assignment problem,
or releases the position r5 claimed, and a robot that had no position takes it, so the
circle is still completed (measured on the simulator's truth) without a collision.
The silent r5, which hears nobody and so has lost every other robot, applies the same
rule to itself: it holds still unless it was last heard within R_max of its position.
In-process and seeded: each run takes a few seconds.
"""

from __future__ import annotations

import numpy as np

from agent.controllers.roles.assignment import RoleBook
from agent.controllers.roles.controller import RolesController
from agent.controllers.roles.peers import Peer, PeerTable
from agent.controllers.roles.phases import ASSIGNED, EN_ROUTE, Assignment
from copath.control import Observation, PeerMessage, RobotContext
from copath.models import UnicycleModel
from orchestrator import api
from orchestrator.run.inprocess import run_scenario

SCENARIO = "e6.3-roles-circle-surplus-robots"


def _silent(start_s: float):
    return api.run(SCENARIO, {"run.on_robot_failure": "continue",
                              "network.silence": [{"robot": "r5", "start_s": start_s, "end_s": 1000.0}]},
                   inprocess=True)


def _claims(run) -> dict[str, list[tuple[float, int]]]:
    """Per robot, (time, position index) every time it announced a claim (-1: none)."""
    return {name: [(float(t), int(d["assigned_index"])) for t, d in zip(rt.telemetry_t, rt.telemetry)
                   if d.get("assigned_index") is not None]
            for name, rt in run.trace.robots.items()}


def _final_targets(run) -> np.ndarray:
    for rt in run.trace.robots.values():
        for d in rt.telemetry:
            if d.get("formation_targets"):
                return np.asarray(d["formation_targets"], dtype=float)
    raise AssertionError("no robot announced the formation's targets")


def test_silent_before_the_choice_the_circle_is_completed_without_it():
    run = _silent(2.0)  # lost at about 3 s, before anyone chose a position (about 10 s)
    fleet = run.metrics["fleet"]
    assert fleet["tasks_completed"] == 1
    assert fleet["collisions"] == 0
    claims = _claims(run)
    assert all(pos < 0 for _, pos in claims.get("r5", []))  # r5 never heard anyone: never claimed
    held = {pos for name, seq in claims.items() if name != "r5" and seq for _, pos in seq[-1:] if pos >= 0}
    assert held == set(range(12))  # the other 15 hold all 12 positions between them
    G = _final_targets(run)
    p5 = run.poses()["r5"][-1, 1:3]
    assert float(np.min(np.hypot(*(G - p5).T))) > 0.05  # r5 fills none of them


def test_a_position_claimed_before_the_loss_is_taken_by_another_robot():
    run = _silent(10.0)  # r5 claimed its position at about 9.5 s, lost at about 11 s, still far from it
    fleet = run.metrics["fleet"]
    assert fleet["tasks_completed"] == 1
    assert fleet["collisions"] == 0
    claims = _claims(run)
    before = [pos for t, pos in claims["r5"] if t < 10.0 and pos >= 0]
    assert before, "r5 should have claimed a position before it went silent"
    k = before[-1]
    takers = [name for name, seq in claims.items() if name != "r5" and any(t > 10.0 and pos == k for t, pos in seq)]
    assert len(takers) == 1, f"position {k} released by r5 taken by {takers}"  # one robot, not every waiting one
    # no two live robots hold the same position at the end
    final = [seq[-1][1] for name, seq in claims.items() if name != "r5" and seq and seq[-1][1] >= 0]
    assert len(final) == len(set(final))


def test_a_robot_cut_off_from_every_other_holds_still_and_nobody_hits_it():
    run = _silent(11.0)  # r5 last heard at 10.9 s, 0.41 m from its position (R_max = 0.4 m): released
    fleet = run.metrics["fleet"]
    assert fleet["collisions"] == 0  # before the rule r5 drove on, blind, into r3 on its old position
    assert fleet["min_separation_m"] > 0.25
    assert fleet["tasks_completed"] == 1
    claims = _claims(run)
    k = [pos for t, pos in claims["r5"] if pos >= 0][-1]
    takers = [name for name, seq in claims.items() if name != "r5" and any(t > 11.0 and pos == k for t, pos in seq)]
    assert len(takers) == 1
    # r5 loses every other robot one lease (1 s) after its radio goes quiet, and stands still from then on
    P = run.poses()["r5"]
    held = P[P[:, 0] >= 12.2, 1:3]
    assert len(held) > 50 and float(np.max(np.hypot(*(held - held[0]).T))) < 1e-3
    G = _final_targets(run)
    assert float(np.hypot(*(G[k] - held[-1]))) > 0.25  # short of the position it was heading for


def test_a_robot_cut_off_next_to_its_position_keeps_it_and_drives_on():
    run = _silent(12.0)  # r5 last heard within R_max of its position: the others keep it for r5
    fleet = run.metrics["fleet"]
    assert fleet["collisions"] == 0
    assert fleet["tasks_completed"] == 1
    claims = _claims(run)
    k = [pos for t, pos in claims["r5"] if pos >= 0][-1]
    assert not [name for name, seq in claims.items() if name != "r5" and any(t > 12.0 and pos == k for t, pos in seq)]
    G = _final_targets(run)
    assert float(np.hypot(*(G[k] - run.poses()["r5"][-1, 1:3]))) < 0.05  # r5 filled it, blind


def _killed(name: str, t_kill: float) -> tuple[dict, dict[str, np.ndarray]]:
    """E6.3 in one process, ``continue``; ``name``'s process goes away at ``t_kill`` (its link
    closes: its token disappears, the simulator holds it still). Metrics and true poses."""
    res = run_scenario(api.load(SCENARIO, {"run.on_robot_failure": "continue"}), run_id="killed",
                       kills={name: t_kill})
    assert res.ok
    return res.metrics, {n: np.column_stack([rt.t, rt.pose]) for n, rt in res.trace.robots.items()}


def test_a_dead_robot_is_passed_like_a_silent_one():
    """The others cannot tell a dead robot from a silent one: the same release, and the dead
    one stands where the silent one holds itself still."""
    metrics, poses = _killed("r5", 11.0)
    fleet = metrics["fleet"]
    assert fleet["collisions"] == 0 and fleet["min_separation_m"] > 0.25
    assert fleet["tasks_completed"] == 1  # r5 stopped 0.41 m from its position: released, and filled by another
    P = poses["r5"]
    still = P[P[:, 0] >= 11.2, 1:3]
    assert float(np.max(np.hypot(*(still - still[0]).T))) < 1e-3


class _Line:
    """Three roles controllers in a hand loop (three positions on a line, lockstep, messages
    one step old); robots in ``cut`` hear nobody and nobody hears them, and both sides
    report each other lost at once, as a silent radio does after the lease."""

    DT = 0.1

    def __init__(self) -> None:
        params = {"formations": (((-1.0, 0.0), (0.0, 0.0), (1.0, 0.0)),), "orientation": "given",
                  "transform_every_task": False, "relay_positions": True, "consensus_hold_s": 0.5}
        self.model = UnicycleModel(v_max=0.5, omega_max=3.4)
        names = ("r1", "r2", "r3")
        self.ctl = {n: RolesController(RobotContext(n, i, self.model, {}, None, (), names, self.DT, params))
                    for i, n in enumerate(names)}
        self.pose = {n: np.array(p) for n, p in zip(names, [(-2.0, -1.5, 0.0), (0.0, -1.5, 1.5), (2.0, -1.5, 3.0)])}
        self.msgs: list[PeerMessage] = []
        self.t = 0.0

    def run(self, until: float, cut: frozenset[str] = frozenset()) -> dict[str, float]:
        """Step to ``until``; the distance each robot drove."""
        moved = dict.fromkeys(self.ctl, 0.0)
        while self.t < until - 1e-9:
            out, cmds = [], {}
            for n, c in self.ctl.items():
                lost = frozenset(self.ctl) - {n} if n in cut else frozenset(cut) - {n}
                res = c.step(Observation(t=self.t, pose=self.pose[n], dt=self.DT, lost=lost),
                             [m for m in self.msgs if m.sender != n and m.sender not in lost])
                cmds[n] = res.command
                out += [PeerMessage(n, o.kind, self.t, self.DT, o.payload, position=tuple(self.pose[n][:2]))
                        for o in res.messages]
            for n in self.ctl:
                new = self.model.step(self.pose[n], cmds[n], self.DT)
                moved[n] += float(np.hypot(*(new[:2] - self.pose[n][:2])))
                self.pose[n] = new
            self.msgs, self.t = out, self.t + self.DT
        return moved

    def distance(self, name: str) -> float:
        return self.ctl[name].roles.distance(self.pose[name][:2])


def test_a_controller_cut_off_far_from_its_position_holds_still_until_it_hears_again():
    line = _Line()
    line.run(2.0)
    assert all(c.roles.phase == ASSIGNED for c in line.ctl.values())
    assert line.distance("r1") > 0.6 and line.distance("r3") > 0.6  # R_max = 0.4 m
    moved = line.run(5.0, cut=frozenset({"r1"}))
    assert moved["r1"] == 0.0  # lost every other robot: its position may be someone else's by now
    assert moved["r3"] > 0.3  # r3 lost only r1: it goes on
    assert line.ctl["r3"].roles.gone.keys() == {"r1"}
    line.run(12.0)  # heard again: its next claim lifts the tombstones, it drives on
    assert all(not c.roles.gone for c in line.ctl.values())
    assert max(line.distance(n) for n in line.ctl) < 0.05


def test_a_controller_cut_off_within_r_max_of_its_position_drives_on():
    line = _Line()
    line.run(4.0)
    assert 0.05 < line.distance("r1") < 0.4  # the others keep its position for it
    moved = line.run(8.0, cut=frozenset({"r1"}))
    assert moved["r1"] > 0.1 and line.distance("r1") < 0.05


def test_a_released_position_is_skipped_by_later_merges_until_released_no_more():
    book = RoleBook("r1", 0, 4)
    book.claim(0)
    book.merge([[0, 2]], [])
    book.release([2])  # its claimer is lost
    assert book.available == [1, 2, 3]
    book.merge([[0, 2]], [])  # a neighbour that has not learnt of the loss yet
    assert book.available == [1, 2, 3]
    book.merge([], [2])  # a live robot claims it
    assert book.available == [1, 3]
    book.release([0])  # own position is never released
    assert 0 in book.taken


def _peer(index: int, heard: float, payload: dict) -> Peer:
    return Peer(heard=heard, age=0.0, position=np.array([float(index), 0.0]), velocity=np.zeros(2), task=0,
                index=index, phase=ASSIGNED, payload=payload)


def test_the_tombstone_holds_against_old_news_and_lifts_when_the_robot_claims_again():
    roles = Assignment("r1", 0, 3, np.zeros(2), 0.0)
    roles.take(0)
    roles.track_claims({"r3": _peer(2, 1.0, {"claim": 2, "d": 1.0, "taken": [2]})}, frozenset(), 1.0, 0.4)
    roles.merge({"r3": _peer(2, 1.0, {"claim": 2, "taken": [2]})})
    assert roles.book.available == [1]
    # r3 is lost here; r2 has not learnt of it and relays r3's old claim and taken set
    old_news = {"claim": 1, "d": 0.5, "taken": [1, 2], "claims": {"r3": [2, 1.0, EN_ROUTE, 2.0, 0.0]}}
    roles.track_claims({"r2": _peer(1, 2.0, old_news)}, frozenset({"r3"}), 2.0, 0.4)
    roles.merge({"r2": _peer(1, 2.0, old_news)})
    assert roles.gone == {"r3": 1.0} and roles.book.available == [2]
    # r2 relays a claim r3 made after it was lost here: r3 is back, the tombstone goes
    news = dict(old_news, claims={"r3": [2, 3.0, EN_ROUTE, 2.0, 0.0]})
    roles.track_claims({"r2": _peer(1, 3.0, news)}, frozenset({"r3"}), 3.0, 0.4)
    roles.merge({"r2": _peer(1, 3.0, news)})
    assert roles.gone == {} and roles.book.available == []


def test_a_lost_robot_last_heard_next_to_its_position_keeps_it():
    roles = Assignment("r1", 0, 3, np.zeros(2), 0.0)
    roles.take(0)
    roles.track_claims({"r3": _peer(2, 1.0, {"claim": 2, "d": 0.3})}, frozenset(), 1.0, 0.4)
    roles.merge({"r3": _peer(2, 1.0, {"claim": 2, "taken": [2]})})
    roles.track_claims({}, frozenset({"r3"}), 2.0, 0.4)
    assert roles.gone == {"r3": 1.0} and 2 in roles.book.taken  # within R_max: its body blocks it anyway


def test_malformed_claims_and_tombstones_are_skipped():
    roles = Assignment("r1", 0, 3, np.zeros(2), 0.0)
    bad = {"claim": 1, "d": 0.5, "claims": {"r3": ["x", 1.0, 0, 0.0, 0.0], "r4": [1, float("nan"), 0, 0.0, 0.0],
                                            "r5": [2], "r6": [0, 1.0, 0, 0.0, 0.0]},
           "gone": {"r7": "soon", "r8": float("nan"), "r9": 0.5}}
    roles.track_claims({"r2": _peer(1, 1.0, bad)}, frozenset(), 1.0, 0.4)
    assert set(roles.claims) == {"r2", "r6"} and roles.gone == {"r9": 0.5}


def test_a_lost_robot_leaves_the_graph_at_once():
    table = PeerTable(timeout=0.5)
    table.peers["r2"] = Peer(heard=1.0, age=0.0, position=np.array([1.0, 2.0]), velocity=np.zeros(2), task=0,
                             index=1, phase=0, payload={})
    assert set(table.fresh(1.1)) == {"r2"}
    table.ingest([], 1.2, frozenset({"r2"}))
    assert table.fresh(1.2) == {}
    assert [list(p) for p in table.wrecks()] == [[1.0, 2.0]]  # still an obstacle where last heard
