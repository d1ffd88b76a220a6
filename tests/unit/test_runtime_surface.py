"""What a node reads from a robot's runtime goes through its public surface (issue 23):
the step clock, the command's size, the last command, and the reject log it shares with
its link (docs/reference/faults.md, "Rejected messages and the lockstep barrier")."""

from __future__ import annotations

from agent.node import AgentNode
from agent.runtime import RobotRuntime
from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.link import MemoryBus
from copath.wire.messages import Obs, PeerEnvelope
from copath.wire.trust import RejectLog
from tests.conftest import config

KEYS = Keys("surface")


def _e55():
    scen = load_scenario(config("e5.5-"))
    return scen, {r.name: list(r.pose) for r in scen.robots}


def test_the_step_clock_follows_the_steps_and_never_goes_back():
    scen, poses = _e55()
    rt = RobotRuntime(scen, "r2", KEYS)
    assert rt.now == 0.0
    rt.step(Obs(3, 0.3, poses["r2"]), 0.3)
    assert rt.now == 0.3
    rt.step(Obs(2, 0.2, poses["r2"]), 0.2)  # an older instant (a realtime reordering) keeps the clock
    assert rt.now == 0.3


def test_last_command_is_the_command_of_the_latest_step_with_the_models_size():
    scen, poses = _e55()
    rt = RobotRuntime(scen, "r2", KEYS)
    assert rt.command_size == scen.robot("r2").model.command_size
    assert rt.last_command == (0.0,) * rt.command_size
    out = rt.step(Obs(0, 0.0, poses["r2"]), 0.0)
    assert rt.last_command == tuple(out.command.cmd) and len(out.command.cmd) == rt.command_size


def test_rejects_are_counted_once_in_the_log_the_node_shares_with_its_link():
    scen, poses = _e55()
    rt = RobotRuntime(scen, "r3", KEYS)
    link = MemoryBus().link("r3")
    AgentNode(rt, KEYS, link, "lockstep")
    rt.step(Obs(50, 5.0, poses["r3"]), 5.0)
    stale = PeerEnvelope("r2", 1, -100.0, "state", [0.0, 0.0], {})  # stamped far outside the window
    rt.receive(stale)
    assert link.rejects == 1 and link.reject_log.total == 1
    assert rt.closing_counters()["rejected"] == 1


def test_count_rejects_in_moves_the_count_to_the_given_log():
    scen, poses = _e55()
    rt = RobotRuntime(scen, "r3", KEYS)
    rt.step(Obs(50, 5.0, poses["r3"]), 5.0)
    log = RejectLog()
    rt.count_rejects_in(log)
    rt.receive(PeerEnvelope("r2", 1, 1e6, "state", [0.0, 0.0], {}))  # from the future
    assert log.total == 1 and rt.reject_log is log
