"""A peer message lost on the wire in lockstep: the barrier waits for it once, writes it off,
and the run goes on at its normal pace (docs/reference/faults.md, "Lost messages and the
lockstep barrier").

A router link that resets drops what was in flight on it; before the write-off, every later
barrier stayed one message short and each tick waited its full timeout (5 s a tick over
Zenoh; ``tests/faults/test_netns.py`` is that case across two hosts). Here the in-process bus
drops chosen messages of r3, so the count is exact: one lost message is one barrier timeout at
each robot that listens to r3 or overhears it, whatever the run's length, and a written-off message that turns
up later is not counted again (it would hide the next loss).

In one process the robots step in their order, so a robot already holds the messages of this
tick from the robots before it; the barrier counts messages, so one of those stands in for a
lost one of the previous tick (a forged message does the same, docs/reference/faults.md). The
lost messages are therefore r3's, the last robot's: what r1 and r2 hold of r3 is all from
earlier ticks."""

from __future__ import annotations

import pytest

from copath.scenario import load_scenario
from copath.wire.link import MemoryBus
from copath.wire.messages import PeerEnvelope, Stats
from orchestrator.run import inprocess
from tests.conftest import config


def _lossy_bus(lost: set[float], late: dict[float, float] | None = None, sender: str = "r3"):
    """A MemoryBus class that drops ``sender``'s peer messages stamped at the times in ``lost``
    [s] (on every key, as a reset link does) and delivers the one stamped ``s`` again once the
    run reaches ``late[s]``."""
    late = dict(late or {})

    class LossyBus(MemoryBus):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.held: list[tuple[str, PeerEnvelope]] = []

        def _deliver(self, key, record):
            now = self.clock()
            for k, r in list(self.held):
                if now >= late[round(r.stamp, 6)] - 1e-9:
                    self.held.remove((k, r))
                    super()._deliver(k, r)
            stamp = round(record.stamp, 6) if isinstance(record, PeerEnvelope) and record.sender == sender else None
            if stamp in lost:
                if stamp in late:
                    self.held.append((key, record))
                return
            super()._deliver(key, record)

    return LossyBus


def _accounts(res) -> dict[str, dict]:
    return {r.proc: r.counters for _, _, r in res.records if isinstance(r, Stats)}


def _run(monkeypatch, scenario, duration_s: float, lost, late=None):
    monkeypatch.setattr(inprocess, "MemoryBus", _lossy_bus(set(lost), late))
    return inprocess.run_scenario(scenario, duration_s=duration_s)


@pytest.mark.parametrize("overhear", [True, False], ids=["overheard", "neighbours-only"])
@pytest.mark.parametrize("duration_s", [3.0, 6.0])
def test_one_lost_message_costs_each_listener_one_barrier_timeout_however_long_the_run(monkeypatch, duration_s,
                                                                                       overhear):
    """With the safety filter overhearing (E5.5's default) every robot waits for every message
    r3 sent (docs/reference/faults.md, "Overheard messages and the lockstep barrier"); without,
    only r3's graph neighbour r2 does."""
    sc = load_scenario(config("e5.5-")).with_overrides(safety={"overhear": overhear})
    assert sc.robot_names[-1] == "r3" and sc.safety.enabled
    listeners = sorted(n for n in sc.robot_names if n != "r3" and (overhear or "r3" in sc.robot(n).neighbours))
    assert listeners == (["r1", "r2"] if overhear else ["r2"])
    res = _run(monkeypatch, sc, duration_s, lost={1.0})
    acc = _accounts(res)
    for n in listeners:  # before the write-off: one timeout per tick after 1 s (20 and 50)
        assert acc[n].get("barrier_timeouts") == 1 and acc[n].get("barrier_written_off") == 1, (n, acc[n])
    for n in set(sc.robot_names) - set(listeners):
        assert "barrier_timeouts" not in acc[n], (n, acc[n])
    ticks = round(duration_s / sc.run.dt)
    assert all(acc[n]["steps"] == ticks for n in sc.robot_names)
    assert res.metrics["ok"]


def test_a_written_off_message_that_arrives_late_does_not_hide_the_next_loss(monkeypatch):
    sc = load_scenario(config("e5.5-"))
    # r3's message of 1.0 s turns up at 1.5 s; its message of 2.0 s is lost for good: counting
    # the late one would make the barrier of 2.1 s believe the lost one had arrived
    res = _run(monkeypatch, sc, 3.0, lost={1.0, 2.0}, late={1.0: 1.5})
    acc = _accounts(res)
    for n in ("r1", "r2"):  # r3's listener r2, and r1, which overhears it for its filter
        assert acc[n].get("barrier_timeouts") == 2 and acc[n].get("barrier_written_off") == 2, (n, acc[n])
