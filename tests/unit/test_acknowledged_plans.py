"""Acknowledged plans (docs/reference/safety.md, "Acknowledged plans"): a robot keeps no
committed plan older than every robot that may hold one has acknowledged, and the whole
horizon while any of them has acknowledged nothing."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from copath.models import OmniModel
from copath.safety import GuardConfig, SafetyConfig, SafetyGuard
from copath.wire.messages import PeerEnvelope, WireError, unpack, unpack_checked

CFG = SafetyConfig(enabled=True, commit_accel_mps2=0.2, commit_speed_mps=0.05, acknowledge_plans=True)
DT = 0.1


def _guard(names=("a", "b", "c"), cfg=CFG) -> SafetyGuard:
    return SafetyGuard(GuardConfig(safety=cfg, name="a", models={n: OmniModel() for n in names}, dt=DT))


def _publish(g: SafetyGuard, n: int) -> None:
    for k in range(n):
        g.published(k * DT, (0.1 * k, 0.0), (1.0, 0.0, 0.0))


def _stamps(g: SafetyGuard, now: float) -> list[float]:
    return [round(p[0], 6) for p in g._kept(now)]


def test_plans_older_than_every_acknowledgement_are_dropped():
    g = _guard()
    _publish(g, 20)  # plans at 0.0 .. 1.9 s, all younger than the 2.5 s horizon at 1.95 s
    assert len(_stamps(g, 1.95)) == 20
    g.hear("b", (1.0, 1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.8, "c": 1.7})
    assert len(_stamps(g, 1.95)) == 20  # c has acknowledged nothing yet: the horizon alone
    g.hear("c", (1.0, -1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.6, "b": 1.9})
    assert _stamps(g, 1.95) == [1.6, 1.7, 1.8, 1.9]  # the oldest acknowledgement (c's) and newer
    g.hear("c", (1.0, -1.0), 2.0, (0.0, 0.0, 0.0), acks={"a": 1.5})  # never back: acknowledgements only rise
    assert _stamps(g, 1.95) == [1.6, 1.7, 1.8, 1.9]
    g.hear("c", (1.0, -1.0), 2.1, (0.0, 0.0, 0.0), acks={"a": 1.9})
    assert _stamps(g, 1.95) == [1.8, 1.9]  # b's 1.8 is the oldest now; the acknowledged plan stays


def test_a_lost_robot_holds_nothing_and_one_back_holds_anything_until_it_acknowledges():
    g = _guard()
    _publish(g, 20)
    g.hear("b", (1.0, 1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.9})
    g.hear("c", (1.0, -1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.7})
    assert _stamps(g, 1.95) == [1.7, 1.8, 1.9]
    g.apply(np.array([1.9, 0.0, 0.0]), [0.0, 0.0, 0.0], 1.95, lost=("c",))  # c's process died
    assert _stamps(g, 1.95) == [1.9]  # only b may hold a plan, and it holds the newest
    g.apply(np.array([1.9, 0.0, 0.0]), [0.0, 0.0, 0.0], 2.0, lost=())  # c's token is back: a new process
    g.published(2.0, (2.0, 0.0), (1.0, 0.0, 0.0))
    # c may hold any plan of the horizon: all are kept again until it acknowledges
    assert _stamps(g, 2.0) == [round(0.1 * k, 6) for k in range(21)]
    g.published(2.1, (2.1, 0.0), (1.0, 0.0, 0.0))
    assert len(_stamps(g, 2.1)) == 22
    g.hear("c", (1.0, -1.0), 2.2, (0.0, 0.0, 0.0), acks={"a": 2.1})
    g.hear("b", (1.0, 1.0), 2.2, (0.0, 0.0, 0.0), acks={"a": 2.1})
    assert _stamps(g, 2.2) == [2.1]


def test_a_silent_robot_keeps_its_last_acknowledgement_and_the_horizon_still_drops():
    g = _guard()
    _publish(g, 20)
    g.hear("b", (1.0, 1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.9})
    g.hear("c", (1.0, -1.0), 0.5, (0.0, 0.0, 0.0), acks={"a": 0.4})  # c heard last at 0.5 s
    assert _stamps(g, 1.95)[0] == 0.4
    assert _stamps(g, 2.95)[0] == 0.5  # older than the horizon: dropped whatever c acknowledged


def test_acknowledgements_name_the_time_each_held_plan_is_dated_from():
    g = _guard()
    assert g.acks() == {}
    g.hear("c", (1.0, -1.0), 0.7, (0.0, 0.0, 0.0), pos_t=0.66)
    g.hear("b", (1.0, 1.0), 0.7, (0.0, 0.0, 0.0))
    assert g.acks() == {"b": 0.7, "c": 0.66}  # the pose's time: the key of the sender's own plan
    assert list(g.acks()) == ["b", "c"]  # sorted: equal runs give equal bytes
    assert _guard(cfg=SafetyConfig(enabled=True)).acks() is None  # no committed plans, nothing to acknowledge
    unacked = _guard(cfg=SafetyConfig(enabled=True, commit_accel_mps2=0.2))  # the default: not acknowledged
    assert unacked.acks() is None
    _publish(unacked, 20)
    unacked.hear("b", (1.0, 1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.9})
    unacked.hear("c", (1.0, -1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.9})
    assert len(_stamps(unacked, 1.95)) == 20  # acknowledgements it does not use change nothing


def test_acknowledgements_travel_in_the_envelope_and_bad_ones_are_refused():
    env = PeerEnvelope("b", 3, 0.7, "coord_state", [0.0, 0.0], {"s": 0.1, "sdot": 0.2, "s_d": 0.0},
                       None, [0.1, 0.0, 0.0], None, {"a": 0.6, "c": 0.65})
    assert unpack(env.pack()) == env and unpack_checked(env.pack()) == env
    d = env.to_dict()
    old = {k: v for k, v in d.items() if k != "acks"}  # written before the field existed
    import msgpack  # noqa: PLC0415

    assert unpack(msgpack.packb(old, use_bin_type=True)).acks is None
    for bad in ({"a": float("nan")}, {"a": "0.6"}, ["a", 0.6]):
        d2 = copy.deepcopy(d)
        d2["acks"] = bad
        with pytest.raises(WireError, match="acks"):
            unpack(msgpack.packb(d2, use_bin_type=True))


@pytest.mark.parametrize("clock", ["lockstep", "realtime"])
def test_the_runtime_acknowledges_what_its_filter_holds_and_keeps_less_when_acknowledged(clock):
    """r1 and r2 of the E5.2 triangle (committed plans), stepped by hand: r2's envelopes
    acknowledge r1's plan by its pose's time; once r2 and r3 have acknowledged, r1 keeps no
    older plan."""
    import dataclasses  # noqa: PLC0415

    from agent.runtime import RobotRuntime  # noqa: PLC0415
    from copath.scenario import load_scenario  # noqa: PLC0415
    from copath.wire.keys import Keys  # noqa: PLC0415
    from copath.wire.messages import Obs  # noqa: PLC0415
    from tests.conftest import config  # noqa: PLC0415

    scen = load_scenario(config("e5.2-dmpc"))
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, clock=clock))
    dt = scen.run.dt
    late = 0.02 if clock == "realtime" else 0.0  # a realtime robot steps after its observation
    rts = {n: RobotRuntime(scen, n, Keys("ack")) for n in ("r1", "r2", "r3")}
    out = {}
    for k in range(6):
        for n, rt in rts.items():
            out[n] = rt.step(Obs(k, k * dt, list(scen.robot(n).pose)), k * dt + late)
        for n, o in out.items():
            for _, env in o.peers:
                for m, rt in rts.items():
                    if m != n:
                        rt.receive(env)
                        rt.overhear(env)
    envs = {n: o.peers[0][1] for n, o in out.items()}
    # each holds the others' plans of the tick before (delivered after every robot stepped),
    # keyed by the pose's time (the observation's), not the step's
    assert all(e.acks == {m: pytest.approx(4 * dt) for m in rts if m != n} for n, e in envs.items())
    assert all(e.stamp == pytest.approx(5 * dt + late) for e in envs.values())
    guard = rts["r1"].safety.guard
    # r1's filter has taken in the envelopes of the tick before (the last ones wait for its next
    # step), which acknowledged its plan of two ticks ago: of its six plans it keeps three
    assert [p[0] for p in guard._kept(5 * dt)] == pytest.approx([3 * dt, 4 * dt, 5 * dt])


def test_while_held_keeps_every_plan_until_a_robot_is_held_still_and_again_once_it_is_heard():
    """``acknowledge_plans = "while_held"`` (docs/reference/safety.md, "Acknowledged plans while a
    robot is held"): the same acknowledgements, used only while the filter holds a robot still."""
    cfg = SafetyConfig(enabled=True, commit_accel_mps2=0.2, commit_speed_mps=0.05, acknowledge_plans="while_held")
    g, always = _guard(cfg=cfg), _guard()
    for guard in (g, always):
        _publish(guard, 20)
        guard.hear("b", (1.0, 1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.9})
        guard.hear("c", (1.0, -1.0), 1.9, (0.0, 0.0, 0.0), acks={"a": 1.7})
    assert g.acks() == always.acks() == {"b": 1.9, "c": 1.9}  # acknowledged on the wire all the same
    assert len(_stamps(g, 1.95)) == 20 and _stamps(always, 1.95) == [1.7, 1.8, 1.9]  # nobody held: all kept
    for guard in (g, always):
        guard.apply(np.array([1.9, 0.0, 0.0]), [0.0, 0.0, 0.0], 1.95, lost=("c",))  # c's process died
    assert _stamps(g, 1.95) == _stamps(always, 1.95) == [1.9]  # c held still: only what b may hold
    for guard in (g, always):
        guard.apply(np.array([1.9, 0.0, 0.0]), [0.0, 0.0, 0.0], 2.0, lost=())  # c's token is back ...
        guard.published(2.0, (2.0, 0.0), (1.0, 0.0, 0.0))
        guard.hear("b", (1.0, 1.0), 2.0, (0.0, 0.0, 0.0), acks={"a": 2.0})
    assert _stamps(g, 2.0) == [round(0.1 * k, 6) for k in range(21)]  # ... unacknowledged: the horizon
    for guard in (g, always):
        guard.hear("c", (1.0, -1.0), 2.1, (0.0, 0.0, 0.0), acks={"a": 2.0})  # ... and heard: no longer held
        guard.apply(np.array([2.0, 0.0, 0.0]), [0.0, 0.0, 0.0], 2.1, lost=())
    assert _stamps(always, 2.05) == [2.0]
    assert len(_stamps(g, 2.05)) == 21  # nobody held any more: every plan of the horizon again


@pytest.mark.parametrize("value", ["sometimes", 1, "true"])
def test_acknowledge_plans_refuses_anything_but_true_false_or_while_held(value):
    from copath.config import ConfigError  # noqa: PLC0415

    with pytest.raises(ConfigError, match=r"safety\.acknowledge_plans = .* is not allowed; must be true, false or \"while_held\""):
        SafetyConfig(enabled=True, commit_accel_mps2=0.2, acknowledge_plans=value)
