"""A robot that has lost every robot it has heard, at least one by silence, is cut off: the
runtime commands zero until it hears one again (docs/reference/faults.md, "Gone quiet"), unless its
controller handles that itself (the roles controller, docs/reference/ambiguities.md, robot lost in role assignment (A38))."""

from __future__ import annotations

import pytest

from agent.runtime import RobotRuntime, handles_cut_off, silent_hold_s
from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.messages import Obs
from tests.conftest import config

KEYS = Keys("cutoff")


def _pair():
    """E5.5's r2 and r3 (r3's only neighbour is r2), at their start poses."""
    scen = load_scenario(config("e5.5-"))
    return scen, {n: RobotRuntime(scen, n, KEYS) for n in ("r2", "r3")}, {r.name: list(r.pose) for r in scen.robots}


def _step(rt, pose, k, dt):
    return rt.step(Obs(k, k * dt, pose), k * dt)


def test_a_robot_that_hears_nobody_for_the_lease_holds_still_until_it_hears_one_again():
    scen, rts, poses = _pair()
    dt, lease = scen.run.dt, scen.run.lease_s
    r2, r3 = rts["r2"], rts["r3"]
    events, cmds = [], {}
    k_quiet = 20  # r2's messages stop reaching r3 from here on (r3's radio gone quiet)
    k_back = 40
    for k in range(60):
        out2 = _step(r2, poses["r2"], k, dt)
        out3 = _step(r3, poses["r3"], k, dt)
        events += [(round(e.t, 2), e.what) for e in out3.events if e.what in ("cut_off", "reconnected")]
        cmds[k] = out3.command.cmd
        if k < k_quiet or k >= k_back:
            for _, env in out2.peers:
                r3.receive(env)
    # r2's last message before the silence is stamped (k_quiet - 1) dt and read at k_quiet dt;
    # r3 is cut off at the first step more than a lease later, and back the step after a
    # message arrives again
    t_cut = round(k_quiet * dt + lease + dt, 2)
    assert events == [(t_cut, "cut_off"), (round((k_back + 1) * dt, 2), "reconnected")]
    held = [k for k in cmds if t_cut - 1e-9 <= k * dt < (k_back + 1) * dt - 1e-9]
    assert held and all(cmds[k] == [0.0] * len(cmds[k]) for k in held)
    assert any(abs(c) > 1e-6 for c in cmds[k_quiet - 1])  # it was driving before
    assert any(abs(c) > 1e-6 for c in cmds[59])  # and drives again
    # the others' safety filters can bound where it stopped: within a lease, a period to go
    # quiet, two periods of reading and the network's delay after its last stamp
    assert silent_hold_s(scen) == pytest.approx(lease + 3 * dt + (scen.network.delay_ms + scen.network.jitter_ms) / 1e3)


def test_a_robot_that_never_heard_anyone_is_not_cut_off():
    scen, rts, poses = _pair()
    r3 = rts["r3"]
    outs = [_step(r3, poses["r3"], k, scen.run.dt) for k in range(30)]
    assert not r3.cut_off and not any(e.what == "cut_off" for o in outs for e in o.events)


def test_the_roles_controller_handles_being_cut_off_itself():
    roles = load_scenario(config("e6.3-"))
    assert all(handles_cut_off(roles, n) for n in roles.robot_names)
    assert not RobotRuntime(roles, roles.robot_names[0], KEYS).cut_off_rule.holds
    e55 = load_scenario(config("e5.5-"))
    assert not any(handles_cut_off(e55, n) for n in e55.robot_names)


def test_run_cut_off_drive_lets_a_cut_off_robot_drive_on_and_its_silence_be_forgotten():
    """``run.cut_off = "drive"``: the old behaviour, chosen per scenario. The robot is still
    found cut off (the event is on the timeline) but its controller's command goes out, and
    no safety filter keeps a silent robot as held."""
    import dataclasses

    from copath.scenario import ConfigError

    scen = load_scenario(config("e5.5-"))
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, cut_off="drive"))
    rts = {n: RobotRuntime(scen, n, KEYS) for n in ("r2", "r3")}
    assert not rts["r3"].cut_off_rule.holds and rts["r3"].safety.guard.silent_hold_s is None
    poses = {r.name: list(r.pose) for r in scen.robots}
    dt, moving = scen.run.dt, []
    for k in range(40):
        out2 = _step(rts["r2"], poses["r2"], k, dt)
        out3 = _step(rts["r3"], poses["r3"], k, dt)
        moving.append(any(abs(c) > 1e-6 for c in out3.command.cmd))
        if k < 10:
            for _, env in out2.peers:
                rts["r3"].receive(env)
    assert rts["r3"].cut_off and all(moving)  # cut off from 2.1 s, and still driving
    with pytest.raises((ConfigError, ValueError), match="run.cut_off = 'stop' is not allowed; allowed: hold, drive"):
        dataclasses.replace(scen.run, cut_off="stop")
