"""The robot runtime as a pipeline of stages (issue 23): the order the docs give, and the
behaviour of each stage's public surface (docs/reference/faults.md, safety.md, detours.md,
sensing.md)."""

from __future__ import annotations

import dataclasses
import pathlib
import re

import numpy as np
import pytest

from agent.runtime import RobotRuntime
from agent.stages import (STAGE_ORDER, ControlStage, Counters, CutOffRule, EnvelopeStage, FaultStage, HoldStage,
                          LivenessStage, TrustStage)
from copath.config import ConfigError
from copath.control import Observation, Outgoing, StepResult
from copath.models import OmniModel, integrate_body_velocity, limit_change, world_velocity_list
from copath.safety import GuardConfig, SafetyConfig, SafetyGuard
from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.messages import Obs, PeerEnvelope
from tests.conftest import config

ROOT = pathlib.Path(__file__).resolve().parents[2]

KEYS = Keys("stages")


def _e55(**run):
    scen = load_scenario(config("e5.5-"))
    return dataclasses.replace(scen, run=dataclasses.replace(scen.run, **run)) if run else scen


def _env(sender: str, stamp: float, pos=(0.0, 0.0), seq: int = 1) -> PeerEnvelope:
    return PeerEnvelope(sender, seq, stamp, "state", list(pos), {})


def _handles(*names):
    return lambda scenario, name: name in names


# -- the order -------------------------------------------------------------------------------
def test_the_pipeline_runs_its_stages_in_the_documented_order():
    """The runtime's stages, and docs/reference/architecture.md's "One tick", name the same
    stages in the same order."""
    rt = RobotRuntime(_e55(), "r2", KEYS)
    assert tuple(s.name for s in rt.stages) == STAGE_ORDER
    text = (ROOT / "docs" / "reference" / "architecture.md").read_text()
    block = text[text.index("robot runtime (agent/runtime.py), in order:"):]
    documented = re.findall(r"^[ ]+\|[ ]+([a-z]+)[ ]{2,}", block.split("```")[0], flags=re.M)
    assert tuple(documented) == STAGE_ORDER


def test_the_stages_run_in_that_order_within_one_step():
    """Each stage's entry point, recorded as the step calls it."""
    scen = _e55()
    rt = RobotRuntime(scen, "r2", KEYS)
    calls = []
    entry = {"trust": "advance", "estimate": "pose", "faults": "release", "liveness": "update", "detour": "step",
             "control": "step", "hold": "apply", "safety": "apply", "envelopes": "send"}
    for stage in rt.stages:
        method = getattr(stage, entry[stage.name])

        def spy(*a, _m=method, _n=stage.name, **k):
            calls.append(_n)
            return _m(*a, **k)
        setattr(stage, entry[stage.name], spy)
    pose = list(scen.robot("r2").pose)
    rt.step(Obs(0, 0.0, pose, meas={"odom": [], "fixes": [], "headings": []}), 0.0)
    assert tuple(calls) == STAGE_ORDER


# -- trust -----------------------------------------------------------------------------------
def test_trust_keeps_envelopes_until_the_first_clock_and_refuses_stale_stamps():
    trust = TrustStage(_e55())
    early = _env("r1", 4.9)
    assert not trust.started and trust.keep_early(early)
    assert trust.advance(5.0) == [early] and trust.started
    assert not trust.keep_early(_env("r1", 5.0))  # a clock now: checked at once
    assert trust.admit(_env("r1", 4.9), "peer")
    assert not trust.admit(_env("r1", -50.0), "peer") and trust.reject_log.total == 1
    assert not trust.admit(_env("r1", -50.0), "overheard", record=False) and trust.reject_log.total == 1
    trust.advance(3.0)
    assert trust.now == 5.0  # never back


# -- faults ----------------------------------------------------------------------------------
def test_faults_release_drops_lost_senders_and_those_beyond_range_but_all_were_heard():
    scen = _e55()
    scen = dataclasses.replace(scen, network=dataclasses.replace(scen.network, range_m=1.0))
    counters = Counters()
    faults = FaultStage(scen, "r2", counters)
    faults.push(_env("r1", 0.0, (0.5, 0.0)))
    faults.push(_env("r3", 0.0, (5.0, 0.0)))
    out = faults.release(0.1, np.zeros(3), frozenset())
    assert sorted(out.senders) == ["r1", "r3"]
    assert [m.sender for m in out.messages] == ["r1"] and [e.sender for e in out.envelopes] == ["r1"]
    assert out.messages[0].age == pytest.approx(0.1)
    assert counters.received == 2 and counters.out_of_range == 1 and counters.delivered == 1
    faults.push(_env("r1", 0.1, (0.5, 0.0), seq=2))
    lost = faults.release(0.2, np.zeros(3), frozenset({"r1"}))
    assert lost.senders == ["r1"] and lost.messages == [] and counters.delivered == 1


def test_faults_report_each_drop_once_the_step_after_its_stamp():
    scen = _e55()
    scen = dataclasses.replace(scen, network=dataclasses.replace(scen.network, loss=1.0))
    counters = Counters()
    faults = FaultStage(scen, "r2", counters)
    faults.push(_env("r1", 0.0, seq=1))
    faults.push(_env("r3", 0.1, seq=1))
    assert faults.release(0.2, np.zeros(3), frozenset()).messages == []
    assert faults.events(0.0) == []  # nothing stamped before 0
    (ev,) = faults.events(0.2)
    assert ev.what == "faults_injected" and ev.detail["dropped"] == 2 and sorted(ev.detail["from"]) == ["r1", "r3"]
    assert faults.events(0.3) == []  # once
    faults.close()
    assert counters.dropped_by_faults == 2


# -- liveness and the cut-off rule --------------------------------------------------------------
def test_liveness_finds_a_silent_sender_and_a_robot_cut_off_from_every_one_it_heard():
    scen = _e55()
    live = LivenessStage(scen, "r3", CutOffRule.for_robot(scen, "r3", _handles()), overhearing=False)
    lease = scen.run.lease_s
    live.heard(["r2"], 1.0)
    assert live.update(1.0, frozenset()).lost == frozenset()
    t = 1.0 + lease + 0.1
    out = live.update(t, frozenset())
    assert out.lost == {"r2"} and out.cut_off
    assert [e.what for e in out.events] == ["peer_silent", "cut_off"] and out.events[1].detail == {"held": True}
    assert live.quiet_for_filter(t) == {"r2"}
    live.heard(["r2"], t + 0.1)
    back = live.update(t + 0.1, frozenset())
    assert not back.cut_off and [e.what for e in back.events] == ["peer_heard", "reconnected"]


def test_a_robot_whose_every_peer_died_is_not_cut_off():
    scen = _e55()
    live = LivenessStage(scen, "r3", CutOffRule.for_robot(scen, "r3", _handles()), overhearing=False)
    live.heard(["r2"], 1.0)
    live.peer_alive("r2", False)
    live.peer_alive("r3", False)  # its own token: not a peer
    out = live.update(5.0, live.lost)
    assert live.lost == {"r2"} and out.lost == {"r2"} and not out.cut_off
    assert [e.what for e in out.events] == ["peer_lost"]


def test_with_overhearing_a_robot_overheard_within_the_lease_keeps_it_connected():
    scen = _e55()
    live = LivenessStage(scen, "r3", CutOffRule.for_robot(scen, "r3", _handles()), overhearing=True)
    live.heard(["r2"], 1.0)
    live.overheard_all(["r1"], 2.5)
    out = live.update(2.6, frozenset())
    assert out.lost == {"r2"} and not out.cut_off  # r2 silent in the inbox, r1 overheard
    assert live.quiet_for_filter(2.6) == frozenset()  # for the filter, silence is any envelope's


def test_a_restarted_robot_heard_in_the_step_its_token_returns_is_not_quiet():
    """A frozen robot is silent for the lease, then killed and restarted: its token goes and
    comes back, and its new process's first envelope reaches the inbox in the step the token is
    seen back, before the filter overhears it. It is heard, so not quiet (once, r6 began a
    0.80 m detour round it in that step; docs/journal/faults.md, "Heard, so not quiet")."""
    scen = _e55()
    live = LivenessStage(scen, "r3", CutOffRule.for_robot(scen, "r3", _handles()), overhearing=True)
    live.heard(["r2"], 1.0)
    live.overheard_all(["r1", "r2"], 1.0)
    live.overheard_all(["r1"], 2.3)  # r2 frozen from 1.0 s
    live.update(2.3, frozenset())
    assert live.quiet_for_filter(2.3) == {"r2"}
    live.peer_alive("r2", False)
    live.update(2.4, live.lost)
    live.peer_alive("r2", True)
    live.heard(["r2"], 2.5)
    live.overheard_all(["r1"], 2.5)
    live.update(2.5, live.lost)
    assert live.quiet_for_filter(2.5) == frozenset()


def test_the_cut_off_rule_of_a_robot():
    scen = _e55()
    rule = CutOffRule.for_robot(scen, "r3", _handles("r1"))
    assert rule.mode == "hold" and rule.holds and rule.silent_hold_s == pytest.approx(1.3)
    assert rule.handled_by_controller == {"r1"}
    assert not CutOffRule.for_robot(scen, "r1", _handles("r1")).holds  # its controller handles it
    drive = CutOffRule.for_robot(_e55(cut_off="drive"), "r3", _handles())
    assert not drive.holds and drive.silent_hold_s is None
    slow = dataclasses.replace(scen, network=dataclasses.replace(scen.network, delay_ms=1000.0))
    assert not CutOffRule.for_robot(slow, "r3", _handles()).holds  # the others' filters would forget it
    off = dataclasses.replace(scen, safety=dataclasses.replace(scen.safety, enabled=False))
    assert CutOffRule.for_robot(off, "r3", _handles("r1")).handled_by_controller == frozenset()


def test_hold_zeroes_a_held_robots_command_and_says_so():
    hold = HoldStage(CutOffRule("hold", 1.3, True, frozenset()), 2)
    tel = {}
    assert hold.apply(True, [0.3, 0.1], tel) == [0.0, 0.0] and tel == {"cut_off": True}
    tel = {}
    assert hold.apply(False, [0.3, 0.1], tel) == [0.3, 0.1] and tel == {}
    assert HoldStage(CutOffRule("drive", None, False, frozenset()), 2).apply(True, [0.3, 0.1], tel) == [0.3, 0.1]


# -- control -----------------------------------------------------------------------------------
class _Failing:
    def __init__(self, command):
        self.command = command

    def step(self, obs, inbox):
        if self.command is None:
            raise ZeroDivisionError("boom")
        return StepResult(self.command, [], {"ok": 1})


def test_control_stops_the_robot_at_a_failing_step_and_reports_the_first_failure_only():
    counters = Counters()
    ctl = ControlStage(_Failing(None), "r1", 2, counters)
    ctl.log_tracebacks = False
    obs = Observation(t=0.0, pose=np.zeros(3), dt=0.1)
    first = ctl.step(obs, [], 0, 0.0)
    assert first.command == [0.0, 0.0] and first.telemetry == {"controller_error": True}
    assert first.failure.what == "controller_error" and first.failure.detail["error"] == "ZeroDivisionError"
    assert ctl.step(obs, [], 1, 0.1).failure is None and counters.controller_errors == 2
    bad = ControlStage(_Failing([float("nan"), 0.0]), "r1", 2, Counters())
    assert bad.step(obs, [], 0, 0.0).command == [0.0, 0.0]
    good = ControlStage(_Failing([0.2, 0.1]), "r1", 2, Counters()).step(obs, [], 0, 0.0)
    assert good.command == [0.2, 0.1] and good.telemetry == {"ok": 1} and good.failure is None


# -- envelopes ---------------------------------------------------------------------------------
def test_envelopes_number_each_message_and_count_what_went_to_whom():
    scen = _e55()
    stage = EnvelopeStage(scen, "r2", KEYS)
    msgs = [Outgoing("state", {"s": 1.0}), Outgoing("plan", {"s": 2.0}, to=("r1", "r3"))]
    peers, vel = stage.send(0.0, np.zeros(3), [0.2, 0.0, 0.0][:scen.robot("r2").model.command_size], msgs, None)
    assert [k for k, _ in peers] == [KEYS.peer_broadcast("r2"), KEYS.peer_direct("r2", "r1"),
                                     KEYS.peer_direct("r2", "r3")]
    assert [e.seq for _, e in peers] == [1, 2, 2] and stage.sent == {"*": 1, "r1": 1, "r3": 1}
    assert all(e.vel == vel and e.cov is None for _, e in peers) and len(vel) == 3


@pytest.mark.parametrize("odometry", [False, True])
@pytest.mark.parametrize("prefix, robot", [("e5.5-", "r2"), ("e5.2-dmpc-ellipse-triangle", "r1")])
def test_a_restarted_robot_promises_nothing_until_it_has_seen_its_base_move(odometry, prefix, robot):
    """A process that joined a run in progress does not know what its base applies (the killed
    process's command, braked by the simulator since): its envelopes carry no velocity until it
    has seen the base move, from odometry or two poses, and then the base's velocity, rate-limited
    towards its own command from there (docs/journal/faults.md, "A restarted robot's first promise").
    A unicycle (E5.5) and an omni robot (E5.2), whose base also slides sideways."""
    scen = load_scenario(config(prefix))
    model = scen.robot(robot).model
    stage = EnvelopeStage(scen, robot, KEYS)
    stage.rejoined()
    msgs = [Outgoing("state", {"s": 1.0})]
    dt = scen.run.dt
    base = [0.15, 0.1] if model.command_size == 2 else [0.15, -0.04, 0.1]  # (u, omega) / (u, v, omega)
    p0 = np.array([1.0, 2.0, 3.0])
    p1 = integrate_body_velocity(p0, base if len(base) == 3 else [base[0], 0.0, base[1]], dt)  # the simulator's step
    odom = [[0.0, dt, *base]] if odometry else ()
    cmd = [0.3] + [0.0] * (model.command_size - 1)
    stage.observe(0.0, p0, odom)
    if not odometry:
        peers, vel = stage.send(0.0, p0, cmd, msgs, None)
        assert vel is None and all(e.vel is None for _, e in peers) and not stage.known
        stage.observe(0.0, p0)  # the same observation again: nothing learnt
        assert not stage.known
        stage.observe(dt, p1)
    assert stage.known
    np.testing.assert_allclose(stage.applied, base, atol=1e-9)
    peers, vel = stage.send(dt, p1, cmd, msgs, None)
    expected = limit_change(model, np.asarray(base), model.saturate(cmd)[0], dt)
    assert vel == pytest.approx(world_velocity_list(model, float(p1[2]), expected))
    assert peers[0][1].vel == vel
    # a fresh run's robot starts from rest, as before
    fresh = EnvelopeStage(scen, robot, KEYS)
    assert fresh.known and not fresh.applied.any()


# -- the safety filter's config ------------------------------------------------------------------
def test_the_guard_takes_a_keyword_config_and_names_a_bad_field():
    models = {"a": OmniModel(), "b": OmniModel()}
    with pytest.raises(TypeError):
        GuardConfig(SafetyConfig(enabled=True), "a", models, 0.1)  # keywords only
    with pytest.raises(ConfigError, match="name = 'z' is not allowed"):
        GuardConfig(safety=SafetyConfig(enabled=True), name="z", models=models, dt=0.1)
    with pytest.raises(ConfigError, match="dt = 0.0 is not allowed"):
        GuardConfig(safety=SafetyConfig(enabled=True), name="a", models=models, dt=0.0)
    cfg = SafetyConfig(enabled=True, max_age_s=2.0)
    g = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=0.1, silent_hold_s=3.0))
    assert g.silent_hold_s is None  # longer than max_age_s: a silent robot is kept as any other
    assert SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=0.1, silent_hold_s=1.3)).silent_hold_s == 1.3


def test_the_runtime_overhears_nothing_before_its_first_step_and_counts_a_strangers_bad_stamp_once():
    scen = _e55()
    rt = RobotRuntime(scen, "r3", KEYS)  # r3 listens to r2 only
    rt.overhear(_env("r1", -60.0))  # from before a restart: stale at the first clock
    assert "overheard" not in rt.counters.extra
    rt.step(Obs(50, 5.0, list(scen.robot("r3").pose)), 5.0)
    assert "overheard" not in rt.counters.extra and rt.reject_log.total == 0  # dropped, not a reject
    rt.overhear(_env("r1", 4.9))
    rt.overhear(_env("r1", -50.0))  # a stranger's bad stamp: counted here
    rt.overhear(_env("r2", -50.0))  # a neighbour's: counted where its inbox copy arrives
    assert rt.counters.extra["overheard"] == 1 and rt.reject_log.total == 1


def test_a_restarted_robot_sees_in_its_first_step_who_it_overheard_before_it():
    # a robot restarted mid-run hears the others' broadcasts before its first step: the newest
    # of each sender is kept and goes to its safety filter at the first step's clock (before,
    # it saw no one for a period, docs/reference/faults.md "Restart")
    scen = _e55()
    rt = RobotRuntime(scen, "r3", KEYS)
    r1 = scen.robot("r1").pose
    rt.overhear(_env("r1", 4.8, pos=r1[:2], seq=7))
    rt.overhear(_env("r1", 4.9, pos=r1[:2], seq=8))  # the newer one is kept
    rt.overhear(_env("r2", 4.9, pos=scen.robot("r2").pose[:2], seq=3))
    assert "overheard" not in rt.counters.extra
    rt.step(Obs(50, 5.0, list(scen.robot("r3").pose)), 5.0)
    assert rt.counters.extra["overheard"] == 2 and rt.reject_log.total == 0
    seen = [nb.position for nb in rt.safety.guard.neighbours(5.0)]
    assert len(seen) == 2 and all(np.allclose(p, q) for p, q in zip(sorted(seen), sorted([r1[:2], scen.robot("r2").pose[:2]])))


def test_a_robot_whose_token_came_back_is_not_quiet_for_the_filter_until_the_lease_ends():
    # a restarted process is not yet heard when its token comes back: for the filter and the
    # detour stage it drives again (a robot back from a hold), not a radio gone quiet that holds
    # itself still (docs/journal/faults.md, "First instant or for good")
    scen = _e55()
    lease = scen.run.lease_s
    for overhearing in (False, True):
        live = LivenessStage(scen, "r3", CutOffRule.for_robot(scen, "r3", _handles()), overhearing=overhearing)
        live.heard(["r1", "r2"], 1.0)
        live.overheard_all(["r1", "r2"], 1.0)
        live.peer_alive("r2", False)  # its process froze at 1.0 and was killed
        t_lost = 1.0 + lease + 0.05
        live.heard(["r1"], t_lost)
        live.overheard_all(["r1"], t_lost)
        live.update(t_lost, live.lost)
        assert live.quiet_for_filter(t_lost) == frozenset()  # lost, not quiet
        live.peer_alive("r2", True)  # restarted: its token is back, no message yet
        t_back = t_lost + 0.1
        live.heard(["r1"], t_back)
        live.overheard_all(["r1"], t_back)
        out = live.update(t_back, live.lost)
        assert [e.what for e in out.events if e.what.startswith("peer_")][0] == "peer_rejoined"
        assert live.quiet_for_filter(t_back) == frozenset(), overhearing
        t_late = t_back + lease + 0.1  # a lease after its return and still not heard: quiet again
        live.heard(["r1"], t_late)
        live.overheard_all(["r1"], t_late)
        live.update(t_late, live.lost)
        assert live.quiet_for_filter(t_late) == {"r2"}, overhearing
        live.heard(["r2"], t_late + 0.1)
        live.overheard_all(["r2"], t_late + 0.1)
        live.update(t_late + 0.1, live.lost)
        assert live.quiet_for_filter(t_late + 0.1) == frozenset()
