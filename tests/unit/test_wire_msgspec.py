"""The msgspec decoder of the wire (copath/wire/messages.py) against the Python checks.

``unpack`` decodes with msgspec and falls back on ``unpack_checked`` (msgpack and the Python
checks) for whatever it refuses. These tests feed both the same valid records and thousands
of mutated ones: they must accept the same records, with values of the same types, and
refuse the rest with the same error (docs/journal/performance.md, the wire, msgspec (P18))."""

from __future__ import annotations

import math
import random

import msgpack
import pytest

from agent.controllers.consensus.payloads import PAYLOADS as CONSENSUS
from agent.controllers.roles.payloads import PAYLOADS as ROLES
from copath.wire.messages import (WIRE_VERSION, Command, End, Estimate, Event, Obs, PeerEnvelope, Start, Stats,
                                  Telemetry, Truth, WireError, unpack, unpack_checked)
from copath.wire.payloads import register_payloads

register_payloads(CONSENSUS)
register_payloads(ROLES)

ROLE = {"task": 0, "index": 1, "phase": 2, "pos": [0.5, 1.0], "vel": [0.0, 0.1], "deg": 2, "z": 0.3, "eta": 0.1,
        "claim": -1, "d": 0.2, "taken": [1, 2], "park": [3.0, 4.0], "rulings": [[[1.0, 0.0], "r1", "r2"]],
        "ac_x": [1.0, 2.0], "ac_to": ["r2"], "known": {"r2": [1.0, 2.0]}, "zdot": 0.0,
        "claims": {"r3": [[0.0, 1.0], 2.5, True]}, "gone": {"r4": 3.0}}

VALID = [
    Obs(3, 0.3, [0.0, 1.0, 0.5], [1.0, math.inf], {"r2": 1, "r3": 4}),
    Obs(4, 0.4, [0.0, 1.0, 0.5], None, None, {"odom": [[0.0, 0.1, 0.2, 0.0]], "fixes": [[0.1, 1.0, 2.0]],
                                                "headings": [[0.1, 0.5]]}),
    Estimate(2, 0.2, [0.0, 1.0, 0.1, 0.0], [[1.0, 0.0, 0.0, 0.0]] * 4, [0.5], [2], {"accepted": 3}),
    Command(5, 0.5, [0.2, -0.1], 0.12, {"*": 4, "r2": 1}),
    Telemetry(5, 0.5, {"s": 1.0, "ref": [1.0, 2.0, 3.0], "ok": True, "n": None, "nested": {"a": [1, 2.5]}}),
    Truth(1, 0.1, ["r1", "r2"], [[0.0, 0.0, 0.0], [1.0, 1.0, 0.5]], [[0.1, 0.0], [0.2, 0.1]], [False, True],
          [0.1, 0.2], [math.inf, 2.0], [[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]]),
    PeerEnvelope("r2", 7, 0.5, "coord_state", [1.0, 2.0], {"s": 0.1, "sdot": 0.2, "s_d": 0.0, "sddot": 0.01},
                 None, [0.1, 0.0, 0.0]),
    PeerEnvelope("r2", 8, 0.6, "coord_state", [1.0, 2.0], {"s": 1, "sdot": 0.2, "s_d": 0.0}, [0.1, 0.0, 0.1]),
    PeerEnvelope("r3", 9, 0.7, "role_state", [1.0, 2.0], dict(ROLE)),
    PeerEnvelope("r3", 10, 0.7, "progress", [1.0, 2.0], {"xi": 1.0, "tags": ["a"], "nested": {"k": [1, 2.5]}}),
    Start(1.7e9, 0.1, "lockstep"),
    End(800, 80.0, "duration", True),
    Event(0.5, "sim", "missed_tick", {"robot": "r1", "k": [1, 2]}),
    Stats("r1", 3, {"received": 2, "cpu_s": 1.5}),
]

BAD_VALUES = [math.nan, math.inf, -math.inf, True, False, None, "x", b"x", [], [math.nan], [[1.0]], {}, {"a": math.nan},
              {1: 2.0}, {"a": {2: 1.0}}, [{"a": [{3: None}]}], [[[[[[[[[[[[1.0]]]]]]]]]]]], msgpack.ExtType(5, b"x"),
              {"a": b"x"}, 2**63, -1, 1.5, [1.0, 2.0], [1.0, 2.0, 3.0], ["a"], [True], {"a": 1}, {"a": "b"},
              [[1.0, 2.0]], [[1.0, 2.0, 3.0, 4.0]], [1, math.inf], [[0.0, 0.1, 0.2, 0.0, 1.0, 2.0]]]


def _typed(x):
    """A value with the exact type of every element (1 == 1.0 == True in Python)."""
    if isinstance(x, dict):
        return {k: _typed(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_typed(v) for v in x]
    if isinstance(x, float) and math.isnan(x):
        return ("nan",)
    return (type(x).__name__, x)


def _outcome(fn, data):
    try:
        rec = fn(data)
    except WireError as exc:
        return ("refused", str(exc))
    return ("accepted", type(rec).__name__, _typed({n: getattr(rec, n) for n in rec.FIELDS}))


def _same(data):
    fast, checked = _outcome(unpack, data), _outcome(unpack_checked, data)
    assert fast == checked, data
    return fast[0]


@pytest.mark.parametrize("rec", VALID, ids=lambda r: r.TYPE)
def test_valid_records_decode_to_equal_records_with_equal_types(rec):
    assert _same(rec.pack()) == "accepted"
    assert unpack(rec.pack()) == rec


def _mutations(rng: random.Random, d: dict) -> list[dict]:
    out = []
    for key in list(d):
        for bad in BAD_VALUES:
            m = dict(d)
            m[key] = bad
            out.append(m)
        m = dict(d)
        del m[key]
        out.append(m)
    for key in ("payload", "data", "detail", "counters", "expect", "meas", "counts", "sent"):
        if isinstance(d.get(key), dict):
            for inner in list(d[key]) + ["new"]:
                for bad in rng.sample(BAD_VALUES, 8):
                    m = dict(d)
                    m[key] = {**d[key], inner: bad}
                    out.append(m)
                m = dict(d)
                m[key] = {k: v for k, v in d[key].items() if k != inner}
                out.append(m)
    for extra in ({"x": 1}, {"type": "obs"}, {"type": "nope"}, {"v": WIRE_VERSION + 1}, {"v": "1"}, {"kind": "Bad Kind"},
                  {"kind": "coord_state"}, {"kind": "role_state"}, {"kind": 3}):
        out.append({**d, **extra})
    return out


@pytest.mark.parametrize("rec", VALID, ids=lambda r: r.TYPE)
def test_mutated_records_are_accepted_or_refused_alike_with_the_same_error(rec):
    rng = random.Random(7)
    counts = {"accepted": 0, "refused": 0}
    for m in _mutations(rng, rec.to_dict()):
        counts[_same(msgpack.packb(m, use_bin_type=True))] += 1
    assert counts["refused"] > 20 and counts["accepted"] > 0  # both sides exercised


def test_damaged_bytes_and_foreign_maps_are_refused_alike():
    rng = random.Random(3)
    packed = [r.pack() for r in VALID]
    n = 0
    for _ in range(3000):
        data = bytearray(rng.choice(packed))
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        if rng.random() < 0.3:
            data = data[: rng.randrange(len(data))]
        n += _same(bytes(data)) == "refused"
    assert n > 1000
    for data in (b"", b"\xc1garbage", msgpack.packb([1, 2]), msgpack.packb({"v": 1}), msgpack.packb({1: 2}),
                 msgpack.packb({"v": 1, "type": "obs", 3: 4, "k": 1, "t": 0.0, "pose": [0.0], "ranges": None,
                                "expect": None, "meas": None})):
        _same(data)


def _old_pack(rec) -> bytes:
    """The packer before msgspec: msgpack over ``to_dict`` (every field through ``to_plain``)."""
    return msgpack.packb(rec.to_dict(), use_bin_type=True)


def test_packed_bytes_are_the_msgpack_packers_bytes_numpy_values_included():
    np = pytest.importorskip("numpy")
    recs = list(VALID) + [
        Obs(np.int64(3), np.float64(0.3), np.array([0.0, 1.0, 0.5]), list(np.array([1.0, np.inf])), {"r3": 4, "r2": 1}),
        Command(5, np.float32(0.5), np.array([0.2, -0.1], dtype=np.float32), np.float64(0.12), {"r2": 1, "*": 4}),
        Telemetry(5, 0.5, {"s": np.float64(1.0), "ref": np.arange(3.0), 7: (1, 2), "ok": np.bool_(True),
                           "m": np.eye(2), "i": np.int32(-4), "big": 2**40, "neg": -2**35}),
        Truth(1, 0.1, ["r1"], np.zeros((1, 3)), np.ones((1, 2)), [np.bool_(False)], np.array([0.1]), None, None),
        PeerEnvelope("r2", 7, np.float64(0.5), "coord_state", (1.0, 2.0), {"s": np.float64(0.1), "sdot": 0.2,
                     "s_d": 0}, None, np.array([0.1, 0.0, 0.0])),
        Event(0.5, "r1", "x", {"a": [np.float32(1.5), (2, 3)], "b": {"c": np.uint8(7)}}),
    ]
    for rec in recs:
        assert rec.pack() == _old_pack(rec), rec


@pytest.mark.parametrize("stem", ["e5.5-", "e6.5-", "e5.2-dmpc-ellipse"])
def test_every_record_of_an_in_process_run_packs_to_the_same_bytes_and_decodes_alike(stem):
    from copath.scenario import load_scenario
    from orchestrator.run.inprocess import run_scenario
    from tests.conftest import config

    res = run_scenario(load_scenario(config(stem)), duration_s=2.0)
    assert len(res.records) > 100
    for _, _, rec in res.records:
        data = rec.pack()
        assert data == _old_pack(rec)
        assert _outcome(unpack, data) == _outcome(unpack_checked, data)


def _nested(depth: int, leaf):
    v = leaf
    for i in range(depth):
        v = [v] if i % 2 else {"k": v}
    return v


def test_any_fields_at_the_depth_limit_are_accepted_or_refused_alike():
    """A role_state ``any`` field is checked in C (``_PLAIN_FINITE``): at, below and past the
    nesting limit of the Python check, with finite and non-finite leaves and empty containers
    at the last level, both decoders agree."""
    outcomes = set()
    for depth in range(6, 12):
        for leaf in (1.0, 2, "s", None, True, math.nan, -math.inf, [], {}, [1.0], {"a": 1.0}):
            for field in ("known", "rulings", "claims", "gone"):
                payload = {**ROLE, field: _nested(depth, leaf)}
                outcomes.add(_same(PeerEnvelope("r3", 9, 0.7, "role_state", [1.0, 2.0], payload).pack()))
    assert outcomes == {"accepted", "refused"}
