"""Message round trips, angle wrapping and fault-layer properties (hypothesis)."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import agent.controllers.consensus  # noqa: F401  (declaring the family registers its coord_state schema)
from copath.paths import wrap_to_pi
from copath.scenario import NetworkConfig, Partition
from copath.wire.faults import FaultyInbox, LinkFaults
from copath.wire.messages import (Command, End, Event, Obs, PeerEnvelope, Stats, Telemetry, Truth, WireError,
                                  unpack, validate_payload)

fin = st.floats(allow_nan=False, allow_infinity=False, width=64)
name = st.from_regex(r"[a-z][a-z0-9_]{0,6}", fullmatch=True)


@given(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False))
def test_wrap_to_pi_range_and_equivalence(a):
    w = wrap_to_pi(a)
    assert -math.pi <= w <= math.pi
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-6) and math.isclose(math.cos(w), math.cos(a), abs_tol=1e-6)


@given(st.integers(0, 2**31), fin, st.lists(fin, min_size=3, max_size=3),
       st.one_of(st.none(), st.lists(st.floats(min_value=0, max_value=10), max_size=12)),
       st.one_of(st.none(), st.dictionaries(name, st.integers(0, 1000), max_size=4)))
def test_obs_round_trip(k, t, pose, ranges, expect):
    m = Obs(k, t, pose, ranges, expect)
    assert unpack(m.pack()) == m


@given(st.integers(0, 10**6), fin, st.lists(fin, min_size=2, max_size=3), fin,
       st.dictionaries(st.one_of(st.just("*"), name), st.integers(0, 10**6), max_size=4))
def test_command_round_trip(k, t, cmd, solve, sent):
    m = Command(k, t, cmd, solve, sent)
    assert unpack(m.pack()) == m


@given(name, st.integers(1, 10**9), fin, fin, fin, fin, fin)
def test_peer_envelope_round_trip(sender, seq, stamp, x, y, s, sdot):
    m = PeerEnvelope(sender, seq, stamp, "coord_state", [x, y], {"s": s, "sdot": sdot, "s_d": 0.0})
    assert unpack(m.pack()) == m


@given(st.integers(0, 1000), fin, st.lists(st.lists(fin, min_size=3, max_size=3), min_size=1, max_size=4))
def test_truth_and_records_round_trip(k, t, poses):
    n = len(poses)
    names = [f"r{i}" for i in range(n)]
    m = Truth(k, t, names, poses, [[0.0, 0.0]] * n, [False] * n, [0.0] * n, None, None)
    assert unpack(m.pack()) == m
    for rec in (Telemetry(k, t, {"s": 1.0, "ref": [1.0, 2.0, 3.0], "ok": True}), End(k, t, "done", True),
                Event(t, "sim", "missed_tick", {"robot": "r1"}), Stats("r1", 3, {"received": 2})):
        assert unpack(rec.pack()) == rec


def test_invalid_records_are_rejected_with_a_reason():
    import msgpack

    with pytest.raises(WireError, match="version"):
        unpack(msgpack.packb({"v": 99, "type": "obs"}))
    with pytest.raises(WireError, match="unknown record type"):
        unpack(msgpack.packb({"v": 1, "type": "nope"}))
    with pytest.raises(WireError, match="missing field 'pose'"):
        unpack(msgpack.packb({"v": 1, "type": "obs", "k": 1, "t": 0.0}))
    with pytest.raises(WireError, match="not a floats"):
        unpack(msgpack.packb({"v": 1, "type": "obs", "k": 1, "t": 0.0, "pose": "x", "ranges": None, "expect": None}))
    with pytest.raises(WireError, match="coord_state: missing field 's_d'"):
        validate_payload("coord_state", {"s": 1.0, "sdot": 0.2})
    with pytest.raises(WireError):
        unpack(b"\xc1garbage")


def test_user_message_kinds_pass_with_plain_finite_payloads():
    validate_payload("progress", {"xi": 1.0, "v": 0.2, "tags": ["a"], "nested": {"k": [1, 2.5]}})
    with pytest.raises(WireError, match="kind 'Bad Kind' is not allowed"):
        validate_payload("Bad Kind", {"x": 1.0})
    with pytest.raises(WireError, match=r"progress\.xi = nan is not a finite number"):
        validate_payload("progress", {"xi": float("nan")})
    with pytest.raises(WireError, match=r"progress\.p\[1\] = inf is not a finite number"):
        validate_payload("progress", {"p": [0.0, float("inf")]})
    with pytest.raises(WireError, match="payload must be a map"):
        validate_payload("progress", [1.0])


@given(st.integers(0, 2**32 - 1), st.floats(0, 1), st.floats(0, 200), st.floats(0, 50))
def test_fault_decisions_are_a_function_of_seed_and_link(seed, loss, delay, jitter):
    net = NetworkConfig(delay_ms=delay, jitter_ms=jitter, loss=loss, burst_p_gb=0.1, burst_p_bg=0.3)
    a, b = LinkFaults(net, seed, "r2"), LinkFaults(net, seed, "r2")
    # interleave senders differently: per-link streams make the decisions identical
    ra = [a.release_time("r1", 0.1 * i) for i in range(30)] + [a.release_time("r3", 0.1 * i) for i in range(30)]
    rb3 = [b.release_time("r3", 0.1 * i) for i in range(30)]
    rb1 = [b.release_time("r1", 0.1 * i) for i in range(30)]
    assert ra == rb1 + rb3
    for i, r in enumerate(rb1):
        assert r is None or 0.1 * i + delay / 1000 - 1e-12 <= r <= 0.1 * i + (delay + jitter) / 1000 + 1e-12


def test_loss_rate_and_partition_window():
    net = NetworkConfig(loss=0.2, partitions=(Partition((("r1", "r2"),), 1.0, 2.0),))
    f = LinkFaults(net, 7, "r2")
    rel = [f.release_time("r1", 0.01 * i) for i in range(10000)]
    in_window = [r for i, r in enumerate(rel) if 1.0 <= 0.01 * i < 2.0]
    assert all(r is None for r in in_window) and f.partitioned == 100
    outside = [r for i, r in enumerate(rel) if not 1.0 <= 0.01 * i < 2.0]
    assert 0.17 < sum(r is None for r in outside) / len(outside) < 0.23


def test_burst_loss_clusters_drops():
    net = NetworkConfig(burst_p_gb=0.05, burst_p_bg=0.25, burst_loss=1.0)
    f = LinkFaults(net, 3, "r2")
    lost = np.array([f.release_time("r1", float(i)) is None for i in range(20000)])
    # stationary bad-state share p_gb / (p_gb + p_bg) = 1/6; mean burst length 1/p_bg = 4
    assert 0.13 < lost.mean() < 0.2
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], lost.astype(int), [0]]))))[::2]
    assert 3.0 < runs.mean() < 5.0


def test_inbox_never_delivers_in_the_sending_instant_and_orders_by_release():
    inbox = FaultyInbox(LinkFaults(NetworkConfig(delay_ms=0.0), 0, "r2"))
    inbox.push("r1", 1.0, "a")
    assert inbox.pop_ready(1.0) == []
    assert inbox.pop_ready(1.1) == ["a"]
    d = FaultyInbox(LinkFaults(NetworkConfig(delay_ms=250.0), 0, "r2"))
    d.push("r1", 0.0, "x")
    d.push("r1", 0.1, "y")
    assert d.pop_ready(0.2) == [] and d.pop_ready(0.25) == ["x"] and d.pop_ready(0.4) == ["y"]
