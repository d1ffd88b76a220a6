"""``run.liveliness_grace_s``: a liveliness token that goes and comes back within the grace
period is not a lost process (a transport reset under CPU starvation, docs/reference/faults.md)."""

from __future__ import annotations

import pytest

from agent.node import AgentNode
from agent.runtime import RobotRuntime
from copath.scenario import ConfigError, parse_scenario
from copath.wire.keys import Keys
from copath.wire.link import MemoryBus, MemoryLink
from orchestrator.studies.bench.scale import scenario_table
from sim.node import SimNode

KEYS = Keys("grace")


def _scenario(grace: float | None = None):
    table = scenario_table(3, 0.1, 5.0, 2.0)
    if grace is not None:
        table["run"]["liveliness_grace_s"] = grace
    return parse_scenario(table)


def test_sim_counts_a_robot_lost_only_after_the_grace_period():
    node = SimNode(_scenario(), KEYS, MemoryLink(MemoryBus()))
    for n in node.names:
        node._on_alive(KEYS.alive(n), True)
    node._on_alive(KEYS.alive("r2"), False)  # before the start: waited for again, not lost
    assert "r2" not in node.alive and node._lost_reason() is None
    node._on_alive(KEYS.alive("r2"), True)
    node._started_run = True
    node._on_alive(KEYS.alive("r2"), False)
    assert node._lost_reason() is None  # within the grace period
    node._on_alive(KEYS.alive("r2"), True)  # back: forgiven
    node._gone_at.clear()
    node._on_alive(KEYS.alive("r3"), False)
    node._gone_at["r3"] -= 5.5  # as if 5.5 s had passed (grace 5 s)
    assert node._lost_reason() == "robot r3 lost (its process stopped)"
    assert node._lost_reason() == "robot r3 lost (its process stopped)"  # stays lost


def test_sim_with_zero_grace_loses_a_robot_at_once():
    node = SimNode(_scenario(0.0), KEYS, MemoryLink(MemoryBus()))
    node._on_alive(KEYS.alive("r1"), True)
    node._started_run = True
    node._on_alive(KEYS.alive("r1"), False)
    assert node._lost_reason() == "robot r1 lost (its process stopped)"


def test_agent_stops_only_when_the_simulator_stays_away():
    sc = _scenario()
    node = AgentNode(RobotRuntime(sc, "r2", KEYS), KEYS, MemoryLink(MemoryBus()), "realtime")
    node._on_sim_alive(KEYS.alive("sim"), True)
    node._on_sim_alive(KEYS.alive("sim"), False)
    assert not node._end_due()
    node._on_sim_alive(KEYS.alive("sim"), True)  # back within the grace period
    assert not node._end_due() and node._sim_gone_at is None
    node._on_sim_alive(KEYS.alive("sim"), False)
    node._sim_gone_at -= 5.5
    assert node._end_due() and node.ended.is_set()


def test_negative_grace_is_refused_with_key_and_value():
    with pytest.raises(ConfigError, match=r"run.liveliness_grace_s = -1"):
        _scenario(-1.0)


def test_lease_must_be_positive_and_reaches_the_table():
    table = scenario_table(2, 0.1, 5.0, 2.0, lease=5.0)
    assert parse_scenario(table).run.lease_s == 5.0
    table["run"]["lease_s"] = 0
    with pytest.raises(ConfigError, match=r"run.lease_s = 0"):
        parse_scenario(table)


def test_a_token_change_under_restart_wakes_the_lockstep_wait():
    """Under ``continue``/``restart`` a token that goes or comes wakes the lockstep wait for
    commands (``sim.node._WAKE``), so the loss is applied while the others step on, and a
    restart from the zygote (0.2-0.3 s) is not applied in the same poll as the loss."""
    from sim.node import _WAKE

    table = scenario_table(3, 0.1, 5.0, 2.0)
    table["run"]["on_robot_failure"] = "restart"
    table["run"]["clock"] = "lockstep"
    node = SimNode(parse_scenario(table), KEYS, MemoryLink(MemoryBus()))
    for n in node.names:
        node._on_alive(KEYS.alive(n), True)
    assert node.cmds.empty()  # before the start: no transition, nothing to wake
    node._started_run = True
    node._on_alive(KEYS.alive("r2"), False)
    assert node.cmds.get_nowait() is _WAKE and node._transitions.get_nowait() == ("r2", False)
    node._on_alive(KEYS.alive("r2"), True)
    assert node.cmds.get_nowait() is _WAKE and node._transitions.get_nowait() == ("r2", True)
    table["run"]["clock"] = "realtime"  # its loop polls the transitions every physics step: no wake
    rt = SimNode(parse_scenario(table), KEYS, MemoryLink(MemoryBus()))
    rt._started_run = True
    rt._on_alive(KEYS.alive("r2"), True)
    rt._on_alive(KEYS.alive("r2"), False)
    assert rt.cmds.empty() and rt._transitions.qsize() == 2
