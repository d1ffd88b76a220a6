"""``run.command_timeout_s``: in a realtime run a robot whose base has had no command for the
timeout stops, as a real base's command timeout stops it (docs/reference/faults.md, "A base
stops on stale commands"): an agent whose step hangs keeps its liveliness token, and its robot
drove on its last command, blind (a DMPC solve of 7 s in the realtime chaos soak ran r2 into r1)."""

from __future__ import annotations

import numpy as np
import pytest

from copath.scenario import ConfigError, parse_scenario
from copath.wire.keys import Keys
from copath.wire.link import MemoryBus, MemoryLink
from copath.wire.messages import Event
from orchestrator.studies.bench.scale import scenario_table
from sim.node import SimNode

KEYS = Keys("cmdtimeout")


def _node(timeout: float | None = None) -> tuple[SimNode, MemoryBus]:
    table = scenario_table(3, 0.1, 5.0, 2.0)
    if timeout is not None:
        table["run"]["command_timeout_s"] = timeout
    bus = MemoryBus()
    return SimNode(parse_scenario(table), KEYS, MemoryLink(bus)), bus


def _timeouts(bus: MemoryBus) -> list[dict]:
    return [r.detail for _, _, r in bus.records if isinstance(r, Event) and r.what == "command_timeout"]


def test_a_base_without_commands_for_the_timeout_stops_once_and_says_so():
    node, bus = _node()
    assert node.scenario.run.command_timeout_s == 1.0  # the default
    size = node.scenario.robot("r1").model.command_size
    go = [0.3] + [0.1] * (size - 1)
    for name in ("r1", "r2"):
        node.world.command(name, go)
        node._cmd_at[name] = 0.0
    node._cmd_at["r2"] = 0.6  # r2 commanded later
    node._stop_stale(0.9)
    assert _timeouts(bus) == [] and np.any(node.world.requested["r1"] != 0)
    node._stop_stale(1.2)  # r1's last command is 1.2 s old, r2's 0.6 s
    assert [d["robot"] for d in _timeouts(bus)] == ["r1"] and node.command_timeouts == 1
    assert not np.any(node.world.requested["r1"]) and np.any(node.world.requested["r2"] != 0)
    node._stop_stale(1.5)  # said once, not every tick
    assert len(_timeouts(bus)) == 1
    node._stop_stale(1.7)  # r2 now stale as well
    assert [d["robot"] for d in _timeouts(bus)] == ["r1", "r2"] and node.command_timeouts == 2


def test_a_robot_held_as_lost_is_left_alone_and_its_return_restarts_the_clock():
    node, bus = _node()
    node._cmd_at["r3"] = 0.0
    node.down.add("r3")  # lost under continue/restart: the simulator already holds it
    node._stop_stale(5.0)
    assert _timeouts(bus) == []
    node.world.t = 5.0
    node._start_rec = None
    node._transitions.put(("r3", True))  # its restarted process is back
    node._apply_transitions()
    node._stop_stale(5.5)  # half a second to send its first command
    assert _timeouts(bus) == []
    node._stop_stale(6.2)
    assert [d["robot"] for d in _timeouts(bus)] == ["r3"]


def test_zero_turns_it_off_and_a_negative_timeout_is_refused_naming_it():
    node, bus = _node(0.0)
    node._cmd_at["r1"] = 0.0
    node._stop_stale(100.0)
    assert _timeouts(bus) == [] and node.command_timeouts == 0
    with pytest.raises(ConfigError, match=r"run.command_timeout_s = -1"):
        _node(-1.0)
