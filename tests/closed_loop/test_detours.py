"""Detours round a blocked lane in closed loop (one process, ``run_scenario``; docs/reference/detours.md):
the robots go round a box on their lane, keep their distance from it and from each other,
make at least 90 % of the progress they make without it, and are back in coordination
within 20 s after the last robot has passed."""

from __future__ import annotations

import dataclasses
import tomllib

import numpy as np
import pytest

from copath.scenario import ObstacleSpec, load_scenario
from copath.slots import track_coordinate
from copath.grading import grade
from orchestrator.run.inprocess import run_scenario
from orchestrator.testkit.records import closing_counters
from orchestrator.analysis.truth import cross_track_series, truth_series
from orchestrator.run.validate import validate_table
from tests.faults.user_controller import scenario_text
from tests.conftest import config


def _progress(res, scen) -> dict[str, float]:
    """How far each robot truly got along its path [m] (path coordinate of a true position (M1) of docs/reference/metrics.md)."""
    ser = truth_series(res.trace, scen)
    if ser is None:  # one robot: no team
        S = {r.name: track_coordinate(scen.paths[r.path], res.trace.robots[r.name].pose[:, :2]) for r in scen.robots}
    else:
        S = ser.s
    return {n: float(s[-1] - s[0]) for n, s in S.items()}


def _without_obstacles(scen):
    return dataclasses.replace(scen, obstacles=())


def test_one_robot_goes_round_a_sensed_box_and_rejoins_its_path():
    """Fast: the E5.5 robot r1 alone, a 0.2 m box on its lane 1.3 m ahead, sensed only."""
    scen = load_scenario(config("e5.5-column-box-on-lane"))
    r1 = dataclasses.replace(scen.robot("r1"), neighbours=())
    box = [[0.273, 0.255], [0.473, 0.255], [0.473, 0.455], [0.273, 0.455]]  # centred on r(2.5)
    scen = dataclasses.replace(scen, robots=(r1,),
                               obstacles=(dataclasses.replace(scen.obstacles[0], vertices=tuple(map(tuple, box))),))
    res = run_scenario(scen, duration_s=20.0)
    free = run_scenario(_without_obstacles(scen), duration_s=20.0)
    m, r = res.metrics, res.metrics["robots"]["r1"]
    assert r["detours"] == 1 and r["stalled_s"] == 0.0
    assert m["fleet"]["collisions"] == 0 and m["fleet"]["min_obstacle_clearance_m"] > 0.0
    assert _progress(res, scen)["r1"] >= 0.9 * _progress(free, scen)["r1"]
    ends = [e for e in res.trace.events if e.what == "detour_end"]
    assert len(ends) == 1
    # rejoining its path after the detour ended: within 4 cm of it over the last 2 s and
    # converging (the Lyapunov law's own rate, Sec. 5.5)
    e = cross_track_series(res.trace, scen)["r1"]
    t = res.trace.robots["r1"].t
    last = e[t >= t[-1] - 2.0]
    assert t[-1] - ends[0].t > 2.0 and np.max(last) < 0.04 and last[-1] < 0.5 * last[0]


def _check(scen, res, free, targets: bool = True, stalled_s: float = 0.0, switching: bool = False):
    """The goals of issue 20 (docs/reference/detours.md); ``targets``: the scenario's own too;
    ``stalled_s``: the most time any robot may be stalled (M4c); ``switching``: a team that
    loosens by design while it switches formations (Sec. 6.6: 0.34 m without the box, at times
    the box shifts): its coordination is checked back under 0.05 m over the last 10 s instead."""
    m = res.metrics
    graded = grade(scen.targets, m) if targets else []
    assert all(g.passed for g in graded), [(g.target.key, g.value) for g in graded if not g.passed]
    assert m["fleet"]["collisions"] == 0
    if m["fleet"]["min_obstacle_clearance_m"] is not None:
        assert m["fleet"]["min_obstacle_clearance_m"] > 0.0
    with_box, without = _progress(res, scen), _progress(free, scen)
    for n in with_box:
        assert with_box[n] >= 0.9 * without[n], (n, with_box[n], without[n])
    assert any(r["detours"] >= 1 for r in m["robots"].values())  # the robots whose lane is blocked
    assert all(r["stalled_s"] <= stalled_s for r in m["robots"].values()), {n: r["stalled_s"] for n, r in m["robots"].items()}
    # coordination among the robots back under 0.05 m within 20 s after the last has passed
    ser = truth_series(res.trace, scen)
    if switching:
        assert np.nanmax(ser.coordination_error[ser.t >= ser.t[-1] - 10.0]) < 0.05
    else:
        _recovers(ser, _passes(res.trace.events))


def _recovers(ser, passes, tol: float = 0.05, within: float = 20.0, hold: float = 5.0) -> None:
    """After each pass of the team round a block (that the run outlasts by ``within``), the
    coordination error is under ``tol`` at some tick within ``within`` seconds and stays
    under it for ``hold`` seconds (or until the next pass begins)."""
    checked = 0
    for i, (_, end) in enumerate(passes):
        if end + within > ser.t[-1]:  # the run ends first: back under tol by its end
            if ser.t[-1] > end:
                assert ser.coordination_error[-1] < tol, (end, float(ser.coordination_error[-1]))
                checked += 1
            continue
        nxt = passes[i + 1][0] if i + 1 < len(passes) else np.inf
        e = ser.coordination_error
        back = np.nonzero((ser.t > end) & (ser.t <= end + within) & (e < tol))[0]
        assert len(back), f"pass ending at {end:.1f} s: coordination not back under {tol} m within {within} s"
        t0 = ser.t[back[0]]
        span = (ser.t >= t0) & (ser.t <= min(t0 + hold, nxt))
        assert np.nanmax(e[span]) < tol, (end, t0, float(np.nanmax(e[span])))
        checked += 1
    assert checked, "no pass ended early enough to check the recovery"


def _held_detours(res) -> list[tuple[float, str]]:
    return [(round(e.t, 2), e.source) for e in res.trace.events
            if e.what == "detour_start" and e.detail.get("reason") == "held"]


@pytest.mark.parametrize("policy", ["restart", "continue"])
def test_a_robot_the_fleet_restarts_is_waited_for_and_one_that_stays_lost_is_gone_round(policy):
    """E5.5, r2 killed at 14 s and back at 14.3 s: under ``restart`` r3, behind it, waits for it
    (``restart_wait_s`` = 2 s) and no robot leaves its lane; under ``continue`` r3 goes round r2's
    held disc at once (docs/reference/detours.md, "A robot the fleet restarts")."""
    scen = load_scenario(config("e5.5-column-lemniscate")).with_overrides(run={"on_robot_failure": policy})
    res = run_scenario(scen, duration_s=30.0, kills={"r2": [14.0]}, restarts={"r2": [14.3]})
    assert res.metrics["fleet"]["collisions"] == 0
    held = _held_detours(res)
    if policy == "restart":
        assert held == []
        assert res.metrics["robots"]["r3"]["detours"] == 0
    else:
        assert [who for _, who in held] == ["r3"] and 14.0 < held[0][0] <= 14.3


def test_a_restart_that_takes_longer_than_the_wait_is_gone_round_after_it():
    """The wait is bounded: r2 back only after 6 s, and r3 starts round its disc 2 s after the
    kill (not before it, and not never)."""
    scen = load_scenario(config("e5.5-column-lemniscate")).with_overrides(run={"on_robot_failure": "restart"})
    res = run_scenario(scen, duration_s=24.0, kills={"r2": [14.0]}, restarts={"r2": [20.0]})
    held = _held_detours(res)
    assert held and held[0][1] == "r3" and 16.0 <= held[0][0] <= 16.3, held
    assert res.metrics["fleet"]["collisions"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("prefix", ["e5.5-column-box-on-lane", "e5.2-dmpc-obstacle-between-lanes",
                                    "e5.7-heterogeneous-box-on-route"])
def test_bundled_blocked_lane_scenarios_meet_their_goals(prefix):
    scen = load_scenario(config(prefix))
    _check(scen, run_scenario(scen), run_scenario(_without_obstacles(scen)))


def _passes(events) -> list[tuple[float, float]]:
    """(first detour_start, last detour_end) of each pass of the team round a block: detours
    that overlap in time belong to one pass."""
    spans = sorted((e.t, e.what) for e in events if e.what in ("detour_start", "detour_end"))
    out, open_, start = [], 0, None
    for t, what in spans:
        if what == "detour_start":
            start = t if open_ == 0 else start
            open_ += 1
        else:
            open_ -= 1
            if open_ == 0:
                out.append((start, t))
    return out


@pytest.mark.slow
def test_e5_4_with_r1_killed_the_live_robots_go_round_it():
    """E5.4 with its front robot r1 killed at 10 s (held still on the lane by the simulator):
    the live robots go round its disc on every lap, never touch it, make at least 90 % of
    their progress without the failure, and the live robots, graded over the chain
    4-1-3-6-5-2 with r1 contracted out of it (r4 against r3, docs/reference/metrics.md,
    coordination error (M2)), are back in coordination within 20 s after the last of them has passed."""
    scen = load_scenario(config("e5.4-")).with_overrides(run={"on_robot_failure": "continue"},
                                                         metrics={"coordination_pairs": "edges"},
                                                         safety={"detours": True})
    res = run_scenario(scen, duration_s=80.0, kills={"r1": 10.0})
    free = run_scenario(scen, duration_s=80.0)
    m = res.metrics
    assert m["fleet"]["collisions"] == 0
    got, without = _progress(res, scen), _progress(free, scen)
    for n in ("r2", "r3", "r4", "r5", "r6"):
        assert got[n] >= 0.9 * without[n], (n, got[n], without[n])
        assert m["robots"][n]["detours"] >= 1
    _recovers(truth_series(res.trace, scen), _passes(res.trace.events))


@pytest.mark.slow
def test_circle_swap_with_a_robot_killed_at_the_crossing_unjams():
    """E5.6's twelve-robot circle swap with r1 killed at 5 s, 0.56 m from the centre every lane
    crosses: the live robots wheel round it and make at least 90 % of their progress without
    the failure, touching nothing. Without the deadlock rule's left turn beside a held robot
    (``safety.held_turn_m = 0``) the crowd knots round r1's disc and its slowest robot makes
    about half (docs/journal/detours.md, "A right turn into a held robot")."""
    scen = load_scenario(config("e5.6-circle")).with_overrides(run={"on_robot_failure": "continue"},
                                                               safety={"detours": True})
    without = _progress(run_scenario(scen, duration_s=55.0), scen)
    shares = {}
    for held_turn in (0.3, 0.0):
        s = scen.with_overrides(safety={"held_turn_m": held_turn})
        res = run_scenario(s, duration_s=55.0, kills={"r1": 5.0})
        assert res.metrics["fleet"]["collisions"] == 0
        got = _progress(res, s)
        shares[held_turn] = min(got[n] / without[n] for n in got if n != "r1")
    assert shares[0.3] >= 0.9 and shares[0.0] < 0.7, shares


@pytest.mark.slow
def test_circle_swap_with_a_robot_killed_dead_ahead_of_another_does_not_rock_in_place(monkeypatch):
    """E5.6's circle swap with r1 killed at 14 s: r10 is left alone with r1's disc dead ahead of
    its nominal. The deadlock rule keeps its side there (``HELD_DEADBAND_RAD``) and r10 goes round;
    decided afresh at each step, the side flipped every step and r10 rocked in place beside the
    disc to the end, about an eighth of its progress (docs/journal/detours.md, "A side that flips
    at every step")."""
    import copath.safety  # noqa: PLC0415

    scen = load_scenario(config("e5.6-circle")).with_overrides(run={"on_robot_failure": "continue"},
                                                               safety={"detours": True})
    without = _progress(run_scenario(scen, duration_s=64.0), scen)
    shares, band0 = {}, copath.safety.HELD_DEADBAND_RAD
    for band in (band0, 0.0):
        monkeypatch.setattr(copath.safety, "HELD_DEADBAND_RAD", band)
        res = run_scenario(scen, duration_s=64.0, kills={"r1": 14.0})
        assert res.metrics["fleet"]["collisions"] == 0
        got = _progress(res, scen)
        shares[band] = min(got[n] / without[n] for n in got if n != "r1")
    assert shares[band0] >= 0.85 and shares[0.0] < 0.3, shares


def _box(path, s: float, half: float = 0.1, known: bool = True) -> ObstacleSpec:
    """A square box of side 2 ``half`` centred on the path at ``s``."""
    x, y = (float(v) for v in path.frame(s)[:2])
    return ObstacleSpec(((x - half, y - half), (x + half, y - half), (x + half, y + half), (x - half, y + half)),
                        known=known)


def _user_controller_team():
    """Four robots on an oval with a user controller (``tests/faults/user_controller.py``, pure
    pursuit with a speed correction from the neighbours' progress), no safety filter."""
    return validate_table(tomllib.loads(scenario_text(duration=40.0)))


# Every path-following family round a box on its lane (issue 20), with the detour stage on by
# default: (scenario, path, box at s [m], run length [s]).
FAMILIES = {
    # the leader (the first to meet it) and, in the column, both followers (E5.1: column from
    # the leader's s = 8.5 m)
    "leader-following": (lambda: load_scenario(config("e5.1-")), "main", 10.0, 45.0),
    # E6.6's line (before the switch to a column at xi = 3 m): r2, in the middle, on the path
    # (a box met during the switch is not passed: docs/reference/detours.md, "What it cannot do")
    "formation-switching": (lambda: load_scenario(config("e6.6-")), "main", 2.5, 65.0),
    # a user controller through the runtime, without the safety filter
    "user-controller": (_user_controller_team, "oval", 3.0, 40.0),
}


@pytest.mark.slow
@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_every_path_following_family_goes_round_a_box_on_its_lane(family):
    """Leader-following (Sec. 5.3), formation switching (Sec. 6.6) and a user controller go
    round a 0.2 m box on the map (``known = true``) placed on their path, without being told
    to (``[safety] detours`` is on by default): no contact, clearance > 0, >= 90 % of their
    progress without the box, back in coordination within 20 s after the last has passed.
    Consensus (E5.4, E5.5), DMPC (E5.2) and the heterogeneous team (E5.7) are the bundled
    scenarios above."""
    build, path, s_box, duration = FAMILIES[family]
    free = build()
    assert free.safety.detours  # the default
    scen = dataclasses.replace(free, obstacles=(_box(free.paths[path], s_box),))
    # the scenario's own targets are those of the run without the box (a formation kept within
    # 2 cm, say): the goals here are issue 20's. Measured 2026-12-02: stalled at most 0.8 s
    # (E6.6's r3 slows behind r2 while r2 rejoins the line); E6.6 loosens by up to 0.34 m
    # while it switches (line -> column from xi = 3 m, during r2's rejoin; 0.001 m over the
    # last 10 s measured)
    _check(scen, run_scenario(scen, duration_s=duration), run_scenario(free, duration_s=duration), targets=False,
           stalled_s=1.0, switching=family == "formation-switching")


@pytest.mark.slow
def test_e5_1_the_team_goes_round_its_killed_leader():
    """E5.1 with the leader killed at 12 s (held still on the lane by the simulator) and range
    sensors on, detours on by default: f1 leads (Sec. 5.3, the election of
    docs/reference/faults.md), both followers go round the held leader without touching it, keep
    >= 90 % of their progress without the failure (measured 2026-12-02: 100 %) and are back in
    coordination within 20 s after the last has passed (0.22 m during the pass)."""
    scen = load_scenario(config("e5.1-"))
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, on_robot_failure="continue"),
                               sensors=dataclasses.replace(scen.sensors, enabled=True))
    assert scen.safety.detours
    res = run_scenario(scen, duration_s=45.0, kills={"leader": 12.0})
    free = run_scenario(scen, duration_s=45.0)
    m = res.metrics
    assert m["fleet"]["collisions"] == 0 and m["fleet"]["min_separation_m"] >= 0.4
    got, without = _progress(res, scen), _progress(free, scen)
    for n in ("f1", "f2"):
        assert got[n] >= 0.9 * without[n], (n, got[n], without[n])
        assert m["robots"][n]["detours"] >= 1
    _recovers(truth_series(res.trace, scen), _passes(res.trace.events))


def _ack_steps(res) -> dict[str, int]:
    """Each robot's closing count of steps at which it left out unacknowledged plans
    (docs/reference/safety.md, "Acknowledged plans")."""
    return closing_counters(res.records, "safety_ack_steps")


def test_e5_4_leaves_out_unacknowledged_plans_only_once_a_robot_is_held():
    """E5.4 ships ``safety.acknowledge_plans = "while_held"`` (docs/reference/safety.md,
    "Acknowledged plans while a robot is held"): without a loss no robot leaves out a plan (the
    run is the one without acknowledgements, key by key); with r4 killed at 10 s the live robots
    leave out unacknowledged plans, from then on only."""
    scen = load_scenario(config("e5.4-")).with_overrides(run={"on_robot_failure": "continue"})
    assert scen.safety.acknowledge_plans == "while_held"
    clean = run_scenario(scen, duration_s=14.0)
    plain = run_scenario(scen.with_overrides(safety={"acknowledge_plans": False}), duration_s=14.0).metrics
    assert _ack_steps(clean) == dict.fromkeys(plain["robots"], 0)
    for n, r in clean.metrics["robots"].items():
        assert r["path_progress_m"] == plain["robots"][n]["path_progress_m"], n
    killed = _ack_steps(run_scenario(scen, duration_s=14.0, kills={"r4": 10.0}))
    steps_after = round((14.0 - 10.0) / scen.run.dt)
    assert set(killed) == set(plain["robots"]) - {"r4"}  # a killed process leaves no closing account
    assert all(0 < k <= steps_after for k in killed.values()), killed


@pytest.mark.slow
def test_e5_4_with_r1_killed_at_30_s_the_robot_behind_it_can_brake_and_turn_off(monkeypatch):
    """E5.4 with r1 killed at 30 s: r2, 0.4 m behind it, must stop and turn about 90 degrees off its
    lane. Every plan of the last 2.5 s it promised (committed plans, a braking of 0.1 m/s^2)
    holds it on its way into r1's disc; leaving out the plans nobody holds any more
    (``acknowledge_plans = "while_held"``, what E5.4 ships) it turns off and every live robot
    makes at least 90 % of its progress without the kill (94.5 % measured), against 87.4 % keeping
    them all (docs/journal/detours.md, "Promises that hold the robot behind a held one"). Measured
    without the turn first, which stops r2 before its ramp whatever it promised (with it: 94.3 %
    and 93.6 %)."""
    from copath.detour import DetourPlanner  # noqa: PLC0415

    monkeypatch.setattr(DetourPlanner, "_entry_angle", lambda self, *a: None)
    scen = load_scenario(config("e5.4-")).with_overrides(run={"on_robot_failure": "continue"})
    without = _progress(run_scenario(scen, duration_s=80.0), scen)
    shares = {}
    for ack in ("while_held", False):
        s = scen.with_overrides(safety={"acknowledge_plans": ack})
        res = run_scenario(s, duration_s=80.0, kills={"r1": 30.0})
        assert res.metrics["fleet"]["collisions"] == 0
        got = _progress(res, s)
        shares[ack] = min(got[n] / without[n] for n in got if n != "r1")
    assert shares["while_held"] >= 0.9 and shares[False] < 0.9, shares


def test_e5_4_with_r4_killed_at_30_s_the_robot_behind_it_turns_first_and_the_column_keeps_its_order(monkeypatch):
    """E5.4 with r4 killed at 30 s, r5 0.55 m behind it: r5 turns on the spot towards the steep
    ramp of its detour before it drives on (docs/reference/detours.md, "Turn first") and goes round
    r4 ahead of r6, so the column keeps its order. Without the turn r5 rolls on into r4's disc,
    stands pressed against it, and r6 passes it (the inversion of docs/journal/detours.md)."""
    from copath.detour import DetourPlanner  # noqa: PLC0415

    scen = load_scenario(config("e5.4-")).with_overrides(run={"on_robot_failure": "continue"})

    def gap(res) -> np.ndarray:  # r5's path coordinate less r6's, from the truth, after the kill
        ser = truth_series(res.trace, scen)
        after = ser.t >= 30.0
        return (ser.s["r5"] - ser.s["r6"])[after]

    kept = gap(run_scenario(scen, duration_s=45.0, kills={"r4": 30.0}))
    monkeypatch.setattr(DetourPlanner, "_entry_angle", lambda self, *a: None)
    rolled = gap(run_scenario(scen, duration_s=45.0, kills={"r4": 30.0}))
    assert kept.min() > 0.1, kept.min()  # r5 stays ahead of r6 (0.5 m apart in the column)
    assert rolled.min() < 0.0, rolled.min()  # r6 went past r5


def test_no_robot_turns_first_round_a_robot_held_because_it_is_quiet(monkeypatch):
    """The r1-lost variant (r1's radio quiet from 10 s, held as a disc grown with its silence):
    the column goes round it as it did before the turn first, to the bit (docs/reference/detours.md,
    "Turn first": round a quiet robot four robots turned in a row and each made 3 % less
    progress); the detour stage is told which held robots are only quiet."""
    from copath.detour import DetourPlanner  # noqa: PLC0415

    scen = load_scenario(config("e5.4-six-robots-lemniscate-r1-lost"))
    calls = []
    step = DetourPlanner.step
    monkeypatch.setattr(DetourPlanner, "step", lambda self, *a: calls.append(a[-1]) or step(self, *a))
    shipped = run_scenario(scen, duration_s=25.0).metrics
    assert any(calls)  # told: some steps had a quiet held robot in reach
    monkeypatch.setattr(DetourPlanner, "_entry_angle", lambda self, *a: None)
    never = run_scenario(scen, duration_s=25.0).metrics
    for n, r in shipped["robots"].items():
        assert r["path_progress_m"] == never["robots"][n]["path_progress_m"], n
    assert sum(r["detours"] for r in shipped["robots"].values()) == 5


@pytest.mark.slow
def test_e5_4_with_r4_killed_at_30_s_is_back_in_coordination_within_20_s_of_the_pass():
    """The same kill graded as the failure sweep grades it (issue 20's goal): every live robot at
    least 90 % of its progress without the kill, and the coordination among the live robots back
    under 0.05 m within 20 s after the last of them has passed r4 (10.8 s measured; 25.8 s before
    the turn first, the column inverted)."""
    from orchestrator.studies.bench.failure_sweep import baseline, run_case  # noqa: PLC0415

    scen = load_scenario(config("e5.4-"))
    row = run_case(scen, "kill", "r4", 30.0, 80.0, baseline(scen, 80.0))
    assert row["collisions"] == 0 and row["progress_min"] >= 0.9, row
    assert row["recoord_after_pass_max_s"] is not None and row["recoord_after_pass_max_s"] <= 20.0, row["passes"]
