"""The in-memory Link: key expressions, synchronous delivery, liveliness, and the node
code running the lockstep protocol on it (the in-process loop)."""

from __future__ import annotations

import pytest

from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.link import Link, MemoryBus, MemoryLink, key_matches
from agent.io_ros2 import CommandTap
from agent.controllers.consensus.payloads import PAYLOADS as CONSENSUS_PAYLOADS
from copath.wire.messages import Command, Obs, PeerEnvelope, Stats, WireError, unpack
from copath.wire.payloads import register_payloads
from copath.wire.trust import check_origin
from copath.wire.session import ZenohLink
from orchestrator.run.inprocess import run_scenario
from tests.conftest import config

register_payloads(CONSENSUS_PAYLOADS)  # coord_state's schema, whatever ran before (the file alone too)


@pytest.mark.parametrize(("key", "expr", "hit"), [
    ("copath/r/peer/r1/all", "copath/r/peer/*/all", True),
    ("copath/r/peer/r1/to/r2", "copath/r/peer/*/all", False),
    ("copath/r/peer/r1/to/r2", "copath/r/peer/*/to/r2", True),
    ("copath/r/peer/r1/to/r3", "copath/r/peer/*/to/r2", False),
    ("copath/r/robot/r1/cmd", "copath/r/**", True),
    ("copath/r", "copath/r/**", True),
    ("copath/r/robot/r1/cmd", "copath/r/robot/*/cmd", True),
    ("copath/r/robot/r1/obs", "copath/r/robot/*/cmd", False),
    ("copath/other/robot/r1/cmd", "copath/r/**", False),
])
def test_key_expressions_match_like_zenoh(key, expr, hit):
    assert key_matches(key, expr) is hit


def test_publish_delivers_synchronously_to_every_matching_subscriber_and_is_recorded():
    bus = MemoryBus(clock=lambda: 1.5)
    a, b = bus.link(), bus.link()
    got_a, got_b = [], []
    a.subscribe("k/*/x", lambda k, r: got_a.append((k, r)))
    b.subscribe("k/**", lambda k, r: got_b.append((k, r)))
    rec = Stats("p", 0, {})
    b.publish("k/1/x", rec)
    b.publish("k/1/y", rec)
    assert got_a == [("k/1/x", rec)]  # the object itself, no copy
    assert got_b == [("k/1/x", rec), ("k/1/y", rec)]
    assert b.published == 2 and a.published == 0
    assert bus.records == [(1_500_000_000, "k/1/x", rec), (1_500_000_000, "k/1/y", rec)]
    assert MemoryLink.synchronous and not ZenohLink.synchronous


def _protocol_members() -> set[str]:
    return {m for m in Link.__annotations__} | {m for m, v in vars(Link).items()
                                                   if callable(v) and not m.startswith("_")}


def test_every_link_implements_everything_the_link_protocol_declares():
    """The nodes read ``synchronous``, ``reject_log`` and ``drop_when_congested`` from the
    Protocol, not by ``getattr`` with a default: each implementation has every member."""
    members = _protocol_members()
    assert {"synchronous", "reject_log", "drop_when_congested", "published", "rejects"} <= members
    for cls in (MemoryLink, ZenohLink, CommandTap):
        missing = {m for m in members if not hasattr(cls, m) and m not in _instance_attrs(cls)}
        assert not missing, f"{cls.__name__} lacks {sorted(missing)}"
    assert isinstance(MemoryBus().link(), Link)


def _instance_attrs(cls) -> set[str]:
    """Attributes an instance gets in ``__init__`` (ZenohLink needs a session to build)."""
    import inspect  # noqa: PLC0415

    return {m for m in ("published", "reject_log") if f"self.{m} =" in inspect.getsource(cls.__init__)}


def test_the_ros2_command_tap_is_the_wrapped_link_with_commands_copied_to_the_driver():
    bus = MemoryBus()
    inner = bus.link()
    sent = []

    class _Driver:
        def command(self, cmd):
            sent.append(list(cmd))

    tap = CommandTap(inner, "k/cmd", _Driver())
    got = []
    tap.subscribe("k/**", lambda k, r: got.append(k))
    tap.drop_when_congested("k/obs")  # a memory bus never congests: accepted, nothing changes
    tap.publish("k/cmd", Command(0, 0.0, [0.3, 0.1], 0.0, {}))
    tap.publish("k/other", Stats("p", 0, {}))
    assert isinstance(tap, Link) and tap.synchronous
    assert sent == [[0.3, 0.1]] and got == ["k/cmd", "k/other"]
    assert tap.published == inner.published == 2 and tap.reject_log is inner.reject_log
    tap.close()
    tap.publish("k/other", Stats("p", 0, {}))
    assert got == ["k/cmd", "k/other"]  # closed: its subscription went with the wrapped link


def test_a_failing_callback_is_counted_as_a_reject_and_delivery_goes_on():
    bus = MemoryBus()
    bad, good = bus.link(), bus.link()
    got = []

    def boom(k, r):
        raise RuntimeError("boom")

    bad.subscribe("k", boom)
    good.subscribe("k", lambda k, r: got.append(r))
    good.publish("k", 1)
    assert bad.rejects == 1 and got == [1]


@pytest.mark.parametrize(("rec", "key"), [
    (PeerEnvelope("r1", 1, 0.1, "mine", [0.0, 0.0], {"x": float("nan")}), "peer/r1/all"),
    (PeerEnvelope("r1", 1, 0.1, "coord_state", [0.0, 0.0], {"s": 1.0, "sdot": 0.1}), "peer/r1/to/r2"),
    (PeerEnvelope("r3", 1, 0.1, "mine", [0.0, 0.0], {"x": 1.0}), "peer/r1/all"),  # another's key
    (Obs(1, 0.1, [0.0, 0.0, float("inf")]), "robot/r2/obs"),
])
def test_a_validating_bus_refuses_what_a_zenoh_subscriber_refuses_with_the_same_error(rec, key):
    keys = Keys("v")
    key = f"{keys.prefix}/{key}"
    with pytest.raises(WireError) as wire:  # what a Zenoh subscriber does with the bytes
        check_origin(key, unpack(rec.pack()))
    bus = MemoryBus(validate=True)
    a, b, pub = bus.link(), bus.link(), bus.link()
    got, refused = [], []
    a.subscribe(f"{keys.prefix}/**", lambda k, r: got.append(r))
    b.subscribe(f"{keys.prefix}/**", lambda k, r: got.append(r), on_reject=lambda k, e: refused.append((k, e)))
    pub.publish(key, rec)
    assert got == [] and refused == [(key, str(wire.value))]
    assert a.rejects == b.rejects == 1 and pub.rejects == 0
    assert a.reject_log.last == (key, str(wire.value))
    good = PeerEnvelope("r1", 2, 0.2, "mine", [0.0, 0.0], {"x": 1.0})
    pub.publish(f"{keys.prefix}/peer/r1/all", good)
    assert got == [good, good]


def test_liveliness_has_history_and_a_closed_link_drops_its_tokens_and_subscriptions():
    bus = MemoryBus()
    a, w = bus.link(), bus.link()
    a.declare_token("run/alive/r1")
    seen = []
    w.watch_liveliness("run/alive/*", lambda k, alive: seen.append((k, alive)))
    assert seen == [("run/alive/r1", True)]
    got = []
    a.subscribe("x", lambda k, r: got.append(r))
    a.close()
    assert seen[-1] == ("run/alive/r1", False)
    w.publish("x", 1)
    assert got == []


def test_in_process_run_is_the_node_code_with_closing_accounts_and_counts():
    sc = load_scenario(config("e5.5-"))
    res = run_scenario(sc, duration_s=3.0)
    keys = Keys(res.metrics["run_id"])
    stats = {r.proc: r for _, k, r in res.records if isinstance(r, Stats)}
    assert set(stats) == {"sim", "r1", "r2", "r3"}
    n_ticks = 30
    counts: dict[str, int] = {}
    for _, k, _ in res.records:
        counts[k] = counts.get(k, 0) + 1
    assert counts[keys.truth] == n_ticks and all(counts[keys.cmd(n)] == n_ticks for n in ("r1", "r2", "r3"))
    # every published record is in the log, and each process accounts for its own
    assert res.metrics["fleet"]["messages_published"] == sum(s.published for s in stats.values()) == len(res.records) - 4
    # the lockstep barrier never had to give up: every expected message was already delivered
    assert all("barrier_timeouts" not in s.counters for s in stats.values())
    assert all(s.counters["steps"] == n_ticks for p, s in stats.items() if p != "sim")
