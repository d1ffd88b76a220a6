"""Receivers validate: non-finite numbers, senders that do not match their key, records on
the wrong key and stamps outside the window are rejected and counted; none blocks a queue."""

from __future__ import annotations

import math

import msgpack
import pytest

from agent.runtime import RobotRuntime
from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.messages import Command, End, Obs, PeerEnvelope, Truth, WireError, unpack
from copath.wire.trust import RejectLog, StampWindow, check_origin
from tests.conftest import config

KEYS = Keys("t")


def _coord(sender="r2", seq=1, stamp=0.1, s=0.5):
    return PeerEnvelope(sender, seq, stamp, "coord_state", [0.0, 0.0], {"s": s, "sdot": 0.2, "s_d": 0.0})


def _forge(record_dict: dict) -> bytes:
    return msgpack.packb(record_dict, use_bin_type=True)


@pytest.mark.parametrize("field,value", [("stamp", math.nan), ("stamp", math.inf), ("stamp", -math.inf)])
def test_non_finite_stamp_is_rejected(field, value):
    d = _coord().to_dict()
    d[field] = value
    with pytest.raises(WireError, match="not a float"):
        unpack(_forge(d))


@pytest.mark.parametrize("value", [math.nan, math.inf])
def test_non_finite_payload_number_is_rejected(value):
    d = _coord().to_dict()
    d["payload"]["s"] = value
    with pytest.raises(WireError):
        unpack(_forge(d))


def test_non_finite_number_nested_in_an_any_field_is_rejected():
    env = _coord()
    d = env.to_dict()
    d["kind"] = "role_state"
    d["payload"] = {"task": 0, "index": 0, "phase": 0, "pos": [0.0, 0.0], "vel": [0.0, 0.0], "deg": 1, "z": 0.0,
                    "eta": 0.0, "claim": -1, "d": 0.0, "taken": [], "park": [0.0, 0.0],
                    "rulings": [[[math.nan, 0.0], "r1", "r2"]]}
    with pytest.raises(WireError, match="finite"):
        unpack(_forge(d))
    d["payload"]["rulings"] = [[[1.0, 0.0], "r1", "r2"]]
    assert unpack(_forge(d)).payload["rulings"][0][1] == "r1"


def test_range_sensor_infinity_still_passes_but_nan_does_not():
    obs = Obs(3, 0.3, [0.0, 0.0, 0.0], [1.0, math.inf], {"r2": 1})
    assert unpack(obs.pack()).ranges[1] == math.inf
    d = obs.to_dict()
    d["ranges"] = [math.nan]
    with pytest.raises(WireError):
        unpack(_forge(d))
    d = obs.to_dict()
    d["expect"] = {"r2": "many"}
    with pytest.raises(WireError, match="expect"):
        unpack(_forge(d))


def test_expect_and_sent_pack_in_name_order_whatever_the_insertion_order():
    a = Obs(1, 0.1, [0.0, 0.0, 0.0], None, {"r3": 2, "r1": 5, "r2": 1})
    b = Obs(1, 0.1, [0.0, 0.0, 0.0], None, {"r2": 1, "r3": 2, "r1": 5})
    assert a.pack() == b.pack()
    assert list(unpack(a.pack()).expect) == ["r1", "r2", "r3"]
    c1 = Command(1, 0.1, [0.1, 0.0], 0.0, {"r3": 1, "*": 4})
    c2 = Command(1, 0.1, [0.1, 0.0], 0.0, {"*": 4, "r3": 1})
    assert c1.pack() == c2.pack()


@pytest.mark.parametrize("rel,rec,ok", [
    ("peer/r2/all", _coord("r2"), True),
    ("peer/r2/to/r1", _coord("r2"), True),
    ("peer/r3/all", _coord("r2"), False),          # sender does not match its key
    ("robot/r1/obs", Obs(0, 0.0, [0.0, 0.0, 0.0]), True),
    ("robot/r1/cmd", Obs(0, 0.0, [0.0, 0.0, 0.0]), False),  # an observation on a command key
    ("robot/r1/obs", End(0, 0.0, "forged"), False),  # an end record on a robot's key
    ("sim/end", End(0, 0.0, "done"), True),
    ("sim/start", End(0, 0.0, "forged"), False),
    ("sim/truth", Truth(0, 0.0, [], [], [], [], []), True),
    ("peer/r2/sideways", _coord("r2"), False),
])
def test_a_record_must_belong_on_its_key(rel, rec, ok):
    key = f"{KEYS.prefix}/{rel}"
    if ok:
        check_origin(key, rec)
    else:
        with pytest.raises(WireError):
            check_origin(key, rec)


def test_stamp_window():
    w = StampWindow(future_s=1.0, past_s=10.0)
    w.check(5.5, 5.0)
    for bad in (7.0, -6.0, math.nan):
        with pytest.raises(WireError):
            w.check(bad, 5.0)


def test_reject_log_counts_by_reason_and_rate_limits_its_events():
    log = RejectLog(min_interval_s=1.0)
    assert log.event("r1", 0.0, wall=0.0) is None
    for _ in range(500):
        log.add("k", "stamp = 1e9 s is far ahead")
    ev = log.event("r1", 1.0, wall=10.0)
    assert ev.what == "messages_rejected" and ev.detail["count"] == 500 and ev.detail["total"] == 500
    log.add("k", "not a msgpack record: x")
    assert log.event("r1", 1.1, wall=10.5) is None  # within the interval: aggregated
    ev = log.flush("r1", 2.0)
    assert ev.detail["count"] == 1 and ev.detail["total"] == 501 and len(ev.detail["by_reason"]) == 2


def test_a_forged_stamp_neither_blocks_the_inbox_nor_crashes_the_controller():
    """The issue's case: a message from the far future at the head of the fault queue
    used to block a robot's inbox for the rest of the run."""
    scen = load_scenario(config("e5.5-"))
    rt = RobotRuntime(scen, "r1", KEYS)
    pose = list(scen.robot("r1").pose)
    rt.receive(_coord("r2", seq=1, stamp=1e12, s=1e6))   # far future
    rt.receive(_coord("r2", seq=2, stamp=-1e6))          # far past
    delivered = 0
    dt = scen.run.dt
    for k in range(1, 20):
        rt.receive(_coord("r2", seq=k + 2, stamp=(k - 1) * dt, s=0.1 * k))
        rt.step(Obs(k, k * dt, pose), k * dt)
        delivered = rt.counters.delivered
    assert rt.reject_log.total == 2
    assert delivered >= 18  # every genuine message got through
    assert rt.counters.controller_errors == 0
    assert rt.closing_counters()["rejected"] == 2
