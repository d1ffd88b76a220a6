"""``Obs.down`` (docs/reference/faults.md, "When the others learn of a loss"): in lockstep the
simulator's observations name the robots whose token is gone at that tick, a declared kill from
the tick it falls due; every robot takes its losses from them, not from its own token watch, so
its teammates learn of a kill at the same step in one process and over Zenoh."""

from __future__ import annotations

from agent.node import AgentNode
from agent.runtime import RobotRuntime
from copath.wire.keys import Keys
from copath.wire.link import MemoryBus, MemoryLink
from copath.wire.messages import Obs
from orchestrator import api
from orchestrator.run.inprocess import run_scenario
from sim.world import World
from tests.conftest import config

SCENARIO = "e5.4-six-robots-lemniscate-r1-killed"  # r1 killed at 10 s
KEYS = Keys("down")


def _obs(records, robot: str) -> dict[int, Obs]:
    return {r.k: r for _, key, r in records if isinstance(r, Obs) and key.endswith(f"/robot/{robot}/obs")}


def _sim_events(records, what: str) -> list:
    return [r for _, _, r in records if getattr(r, "TYPE", "") == "event" and r.source == "sim" and r.what == what]


def _told(records, what: str) -> list[tuple[str, float]]:
    return sorted((e.source, round(e.t, 2)) for _, _, e in records
                  if getattr(e, "TYPE", "") == "event" and e.what == what and e.detail.get("robot") == "r1")


def test_a_declared_kill_is_said_in_the_observations_of_the_tick_it_falls_due():
    res = run_scenario(api.load(config(SCENARIO), overrides=["run.duration_s=11", "run.settle_s=1"]))
    for robot in ("r2", "r6"):
        obs = _obs(res.records, robot)
        assert [obs[k].down for k in (0, 100, 101, 109)] == [[], [], ["r1"], ["r1"]]
    assert 100 in _obs(res.records, "r1") and 101 in _obs(res.records, "r1")  # it dies on observation 101
    # every teammate learns of it at its step of tick 101, the step r1 no longer takes
    assert _told(res.records, "peer_lost") == [(n, 10.1) for n in ("r2", "r3", "r4", "r5", "r6")]


def test_a_restarted_robot_is_down_until_its_token_is_back():
    scen = api.load(config(SCENARIO), overrides=["run.duration_s=10", "run.settle_s=1", 'run.on_robot_failure="restart"',
                                                 'run.kills=[{robot="r1", at_s=8.0}]'])
    res = run_scenario(scen)
    obs = _obs(res.records, "r2")
    assert [obs[k].down for k in (80, 81, 90, 91)] == [[], ["r1"], ["r1"], []]
    assert _told(res.records, "peer_lost") == [(n, 8.1) for n in ("r2", "r3", "r4", "r5", "r6")]
    assert _told(res.records, "peer_rejoined") == [(n, 9.1) for n in ("r2", "r3", "r4", "r5", "r6")]


def test_a_lockstep_robot_takes_its_losses_from_the_observations_and_a_realtime_one_from_its_watch():
    scen = api.load(config(SCENARIO))
    node = AgentNode(RobotRuntime(scen, "r2", KEYS), KEYS, MemoryLink(MemoryBus()), "lockstep")
    node._on_robot_alive(KEYS.alive("r3"), False)  # before any observation: its watch
    assert node.rt.lost == {"r3"}
    node._lockstep_step(World(scen).observe("r2", 0, {}, ["r1"]))
    assert node.rt.lost == {"r1"}
    node._on_robot_alive(KEYS.alive("r4"), False)  # said by the next observation, not now
    assert node.rt.lost == {"r1"}
    node._lockstep_step(World(scen).observe("r2", 1, {}, ["r1", "r2", "stranger"]))
    assert node.rt.lost == {"r1"}  # itself and a name outside the team left out
    live = AgentNode(RobotRuntime(scen, "r2", KEYS), KEYS, MemoryLink(MemoryBus()), "realtime")
    live._on_robot_alive(KEYS.alive("r4"), False)
    assert live.rt.lost == {"r4"}
    assert World(scen).observe("r2", 0).down is None  # realtime observations say nothing of it


def test_a_realtime_robot_dies_at_its_declared_kill_on_the_run_s_clock():
    """Between its steps at ``at_s + dt/2``, not on the observation after (a period late); a
    process that began after a kill's time is not killed by it (a restart)."""
    scen = api.load(config(SCENARIO))  # r1 killed at 10 s, dt 0.1
    node = AgentNode(RobotRuntime(scen, "r1", KEYS), KEYS, MemoryLink(MemoryBus()), "realtime", die=lambda: None)
    assert node._kill_by(10.0) is None  # no observation yet: not running
    assert not node._kill_due(0.0)  # its first observation
    assert node._kill_by(10.0) is None and node._kill_by(10.1) == 10.05
    back = AgentNode(RobotRuntime(scen, "r1", KEYS), KEYS, MemoryLink(MemoryBus()), "realtime", die=lambda: None)
    assert not back._kill_due(11.1)  # a restart's first observation, after the kill
    assert back._kill_by(80.0) is None


def test_a_kill_falls_due_on_the_same_tick_for_the_agent_the_simulator_and_the_one_process_loop():
    """``kill_tick``: the first tick whose observation comes at or after ``at_s + dt/2``. The
    one-process loop closed a kill's link after tick ``round(at_s / dt)``, which rounds half to
    even: a kill at 10.15 s fell at tick 103 there and at 102 over Zenoh."""
    from copath.scenario import Kill, kill_tick  # noqa: PLC0415

    for at_s, tick in ((10.0, 101), (10.03, 101), (10.06, 102), (10.05, 101), (10.15, 102), (0.01, 1)):
        assert kill_tick(at_s, 0.1) == tick, at_s
        due = Kill("r1", at_s).due_s(0.1)
        assert (tick - 1) * 0.1 < due - 1e-9 and tick * 0.1 >= due - 1e-9  # the agent's test, the same tick
    res = run_scenario(api.load(config(SCENARIO), overrides=["run.duration_s=10.6", "run.settle_s=1",
                                                             'run.kills=[{robot="r1", at_s=10.15}]']))
    assert [round(r.t, 2) for r in _sim_events(res.records, "robot_lost")] == [10.2]
    last = max(r.k for _, key, r in res.records if getattr(r, "TYPE", "") == "cmd" and key.endswith("/robot/r1/cmd"))
    assert last == 101  # it answered observation 101 and no later one
