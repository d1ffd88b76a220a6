"""The lockstep barrier (docs/reference/faults.md, "Overheard messages and the lockstep barrier"):
with the safety filter overhearing, a robot waits for every message each robot sent, its
neighbours' and the others', before it steps; without overhearing, for its neighbours' only."""

from __future__ import annotations

import collections

from agent.node import AgentNode
from agent.runtime import RobotRuntime
from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.link import MemoryBus, MemoryLink
from copath.wire.messages import PeerEnvelope
from sim.world import World
from tests.conftest import config

KEYS = Keys("barrier")
NAME = "e5.4-six-robots-lemniscate-r1-lost"  # r1 listens to r4 and r3; it overhears r2, r5 and r6


def _sent(scen) -> dict[str, dict[str, int]]:
    """What each robot sent in one tick: one message to each neighbour (``Command.sent``)."""
    return {r.name: {n: 1 for n in r.neighbours} for r in scen.robots}


def _env(sender: str, stamp: float) -> PeerEnvelope:
    return PeerEnvelope(sender, 1, stamp, "coord_state", [0.0, 0.0], {"s": 0.0, "sdot": 0.2, "s_d": 0.0})


def test_with_the_filter_overhearing_a_robot_waits_for_every_robots_messages():
    scen = load_scenario(config(NAME))
    assert scen.safety.enabled and scen.safety.overhear and not scen.safety.acknowledge_plans
    world = World(scen)
    obs = world.observe("r1", 1, _sent(scen))
    # every message each of the others sent (r3 to r1 and r6, r5 to r2 and r6), not only r1's
    assert obs.expect == {"r2": 1, "r3": 2, "r4": 1, "r5": 2, "r6": 2}
    # summed once a tick: the next robot's observation leaves out its own, not r1's
    assert world.observe("r2", 1, _sent(scen)).expect == {"r1": 2, "r3": 2, "r4": 1, "r5": 2, "r6": 2}
    rt = RobotRuntime(scen, "r1", KEYS)
    assert rt.awaits_overheard
    assert rt.missing(obs.expect) == obs.expect  # nothing arrived: it waits for all five
    for sender in ("r3", "r3", "r4", "r5", "r5", "r6", "r6"):  # r2's message is late
        rt.overhear(_env(sender, 0.0))
    assert rt.missing(obs.expect) == {"r2": 1}  # a non-neighbour's message is waited for
    rt.overhear(_env("r2", 0.0))
    assert rt.missing(obs.expect) == {}
    # given up on (the barrier's timeout): written off, so the next tick waits for its own only
    obs2 = world.observe("r1", 2, {s: {n: 2 * c for n, c in d.items()} for s, d in _sent(scen).items()})
    assert obs2.expect == {s: 2 * c for s, c in obs.expect.items()}  # the next tick's sums, not the last
    assert rt.write_off(obs2.expect, 0.2) == obs.expect
    assert rt.missing(obs2.expect) == {}


def test_without_overhearing_a_robot_waits_for_its_neighbours_messages_only():
    scen = load_scenario(config(NAME)).with_overrides(safety={"overhear": False})
    obs = World(scen).observe("r1", 1, _sent(scen))
    assert obs.expect == {"r2": 0, "r3": 1, "r4": 1, "r5": 0, "r6": 0}  # those addressed to r1
    rt = RobotRuntime(scen, "r1", KEYS)
    assert not rt.awaits_overheard
    rt.trust.advance(0.1)  # the first step's clock
    assert rt.missing(obs.expect) == {"r3": 1, "r4": 1}
    rt.receive(_env("r3", 0.0))
    rt.receive(_env("r4", 0.0))
    assert rt.missing(obs.expect) == {}


class _Interrupted(collections.deque):
    """A node's queue whose every append is followed by a step's drain and barrier check, as
    when the step thread runs between two appends of the link's thread."""

    def __init__(self, on_append) -> None:
        super().__init__()
        self._on_append = on_append

    def append(self, item) -> None:
        super().append(item)
        self._on_append()


def test_a_message_counted_overheard_has_reached_the_inbox_in_the_same_drain():
    """A message on a key both overheard and listened to arrives once and is queued twice, for
    the filter and for the controller. The barrier counts the overheard copy; were the step
    thread to drain between the two appends and find the overheard copy alone, it would step
    without the message in the controller's inbox, which got it a tick late (CI 2026-12-04: a
    lockstep E5.5 run with 100 ms delay left the in-process run at t = 0.1 s)."""
    scen = load_scenario(config(NAME))
    node = AgentNode(RobotRuntime(scen, "r1", KEYS), KEYS, MemoryLink(MemoryBus()), "lockstep")
    node.start()
    node.inline = False  # the link's threads append, the step thread drains (an agent process)
    rt = node.rt
    rt.trust.advance(0.0)
    expect = {"r3": 1}
    steps = []

    def step_now() -> None:  # the step thread, at this instant
        node._drain_peers()
        if not rt.missing(expect):  # the barrier lets it step: the controller's copy must be in
            steps.append(rt.counters.received)

    node.peers, node.overheard = _Interrupted(step_now), _Interrupted(step_now)
    node._on_overheard_or_peer(KEYS.peer_broadcast("r3"), _env("r3", 0.0))
    assert steps and all(n == 1 for n in steps)
    assert rt.overheard_from == {"r3": 1} and rt.received_from == {"r3": 1}
