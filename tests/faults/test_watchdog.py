"""An agent that hears nothing from the simulator for run.watchdog_s commands zero
velocity and says so, once until the next observation."""

from __future__ import annotations

import time

from agent.node import AgentNode
from agent.runtime import RobotRuntime
from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.link import MemoryBus
from copath.wire.messages import Command, Event, Obs
from tests.conftest import config


def test_a_silent_simulator_trips_the_watchdog_once():
    scen = load_scenario(config("e5.5-"))
    keys = Keys("wd")
    bus = MemoryBus()
    node = AgentNode(RobotRuntime(scen, "r1", keys), keys, bus.link(), "realtime")
    assert node.watchdog_s == scen.run.watchdog_s > 0
    node._watchdog()  # no observation yet: not armed
    assert bus.records == []
    node.latest_obs = Obs(7, 0.7, list(scen.robot("r1").pose))
    node._heard = time.monotonic()
    node._watchdog()  # heard recently
    assert bus.records == []
    node._heard = time.monotonic() - node.watchdog_s - 0.1
    node._watchdog()
    node._watchdog()  # once, until the next observation
    recs = [r for _, _, r in bus.records]
    cmds = [r for r in recs if isinstance(r, Command)]
    events = [r for r in recs if isinstance(r, Event)]
    assert len(cmds) == 1 and cmds[0].cmd == [0.0, 0.0] and cmds[0].k == 7
    assert len(events) == 1 and events[0].what == "watchdog" and events[0].detail["silent_s"] >= node.watchdog_s
    node._on_obs(keys.obs("r1"), Obs(8, 0.8, list(scen.robot("r1").pose)))  # heard again: re-armed
    assert node._tripped is False
