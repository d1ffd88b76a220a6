"""Late commands (docs/reference/safety.md, "Late commands"): a realtime robot steps on its own
timer with an observation up to a period old, and its command may drive for more than one
period; the filter certifies its command for that."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agent.runtime import RobotRuntime
from agent.stages.safety import command_lag_periods
from copath.config import ConfigError, from_table
from copath.models import OmniModel, limit_change, world_velocity_list
from copath.safety import GuardConfig, SafetyConfig, SafetyFilter, SafetyGuard
from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.messages import Obs, unpack
from tests.conftest import config

DT, PHYSICS = 0.05, 0.005  # the DMPC triangle's period; the realtime simulator integrates finer
OMNI = OmniModel(a_max=1.0, alpha_max=3.0)  # E5.2's robots
COMMIT = {"commit_accel_mps2": 0.2, "commit_speed_mps": 0.05}  # E5.2's committed plans


def _head_on(phase: dict[str, int], fixed: bool, committed: bool = False) -> float:
    """Two omni robots driving at each other at 0.5 m/s, each filtered, in a small realtime
    simulator: observations every period, the physics (with the enforced a_max) every 5 ms, each
    robot stepping ``phase`` physics steps after the observation it uses, its command driving
    from then on. ``fixed``: as the runtime does now (envelopes say when their position was
    true, ``pos_t``; the filter knows its pose's time; ``command_lag_periods = 2``); else as
    before (the pose taken as the step's, one period).
    Returns the smallest distance of the centres [m]."""
    cfg = SafetyConfig(enabled=True, speed_max_mps=1.0, **(COMMIT if committed else {}))
    names = ("a", "b")
    guards = {n: SafetyGuard(GuardConfig(safety=cfg, name=n, models=dict.fromkeys(names, OMNI), dt=DT,
                                         lag_periods=2.0 if fixed else 1.0)) for n in names}
    pose = {"a": np.array([0.0, 0.0, 0.0]), "b": np.array([1.2, 0.0, math.pi])}
    applied = {n: np.zeros(3) for n in names}  # the simulator's
    sent = {n: np.zeros(3) for n in names}  # the envelopes' (the runtime's own limiter)
    cmd = {n: np.zeros(3) for n in names}
    envelope: dict[str, tuple] = {}
    obs = {n: p.copy() for n, p in pose.items()}
    per = int(round(DT / PHYSICS))
    d_min = math.inf
    for step in range(int(6.0 / PHYSICS)):
        k, j = divmod(step, per)
        if j == 0:
            obs = {n: p.copy() for n, p in pose.items()}
        for n in names:
            if j != phase[n]:
                continue
            t_obs, now = k * DT, k * DT + j * PHYSICS
            other = "b" if n == "a" else "a"
            if other in envelope:
                guards[n].hear(other, *envelope[other])
            res = guards[n].apply(obs[n], [0.5, 0.0, 0.0], now, pose_t=t_obs if fixed else None)
            cmd[n] = np.asarray(res.command, dtype=float)
            sent[n] = limit_change(OMNI, sent[n], OMNI.saturate(cmd[n])[0], DT)
            vel = world_velocity_list(OMNI, float(obs[n][2]), sent[n])
            guards[n].published(t_obs if fixed else now, obs[n], vel)
            envelope[n] = (obs[n][:2].tolist(), now, vel, t_obs if fixed else None)
        for n in names:
            applied[n] = limit_change(OMNI, applied[n], OMNI.saturate(cmd[n])[0], PHYSICS)
            c, s = math.cos(pose[n][2]), math.sin(pose[n][2])
            u, v, w = applied[n]
            pose[n] = pose[n] + PHYSICS * np.array([c * u - s * v, s * u + c * v, w])
        d_min = min(d_min, float(np.hypot(*(pose["a"][:2] - pose["b"][:2]))))
    return d_min


@pytest.mark.parametrize("committed", [False, True])
@pytest.mark.parametrize("phase", [(0, 0), (9, 9), (9, 1), (5, 9)])
def test_robots_stepping_late_in_the_period_keep_footprints_and_margin(phase, committed):
    """Stepping up to 45 ms after the observation (a 50 ms period), each robot's filter takes
    its pose on to the step's time and bounds its command for two periods: the pair keeps
    r_a + r_b + margin = 0.41 m (up to the millimetre's fraction the physics adds)."""
    d = _head_on(dict(zip("ab", phase)), fixed=True, committed=committed)
    assert d >= 2 * OMNI.radius + 0.01 - 5e-4


def test_before_the_change_a_late_step_drove_a_pair_into_contact():
    """The same run with the pose taken as the step's (in the filter and in the envelopes) and a
    command bounded for one period: the filters passed commands that met (0.35 m of centres
    against 0.40 m of footprints)."""
    assert _head_on({"a": 9, "b": 9}, fixed=False) < 2 * OMNI.radius - 0.02


def test_one_period_of_lag_is_the_filter_before_bit_for_bit():
    """Lockstep (the pose's time is the step's, one period): the same rows and commands as a
    filter built without the lag, so lockstep and in-process metrics do not move."""
    cfg = SafetyConfig(enabled=True, speed_max_mps=1.0, **COMMIT)
    plain, lagged = SafetyFilter(cfg, OMNI, DT), SafetyFilter(cfg, OMNI, DT, lag_periods=1.0)
    assert (plain.gamma, plain.dt) == (lagged.gamma, lagged.hold)
    models = {"a": OMNI, "b": OMNI}
    g1 = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=DT))
    g2 = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=DT, lag_periods=1.0))
    for g in (g1, g2):
        g.hear("b", [0.55, 0.05], 0.95, [-0.3, 0.0, 0.1])
        g.published(0.95, [0.0, 0.0, 0.0], [0.4, 0.0, 0.0])
    r1 = g1.apply([0.0, 0.0, 0.0], [0.5, 0.0, 0.0], 1.0)
    r2 = g2.apply([0.0, 0.0, 0.0], [0.5, 0.0, 0.0], 1.0, pose_t=1.0)
    assert r1.active and r1.command.tolist() == r2.command.tolist()


def test_a_late_pose_is_taken_on_along_the_published_velocity():
    """A pose 40 ms old, the robot driving at 0.5 m/s: the filter sees the robot 2 cm further
    on, so the gap it bounds is 2 cm smaller (and grows no disc by the speed bound)."""
    cfg = SafetyConfig(enabled=True, speed_max_mps=1.0)
    g = SafetyGuard(GuardConfig(safety=cfg, name="a", models={"a": OMNI, "b": OMNI}, dt=DT, lag_periods=2.0))
    g.hear("b", [0.6, 0.0], 1.0, [0.0, 0.0, 0.0])
    g.published(0.95, [0.0, 0.0, 0.0], [0.5, 0.0, 0.0])
    moved, reach = g._own_now(np.array([0.0, 0.0, 0.0]), 0.04, 1.0)
    assert moved[:2].tolist() == pytest.approx([0.02, 0.0])
    T = 0.04 + 2 * DT  # the age and the lag of two periods: prediction_bound
    assert reach == pytest.approx(1.0 * T**2 / 2 + 0.5 * 3.0 * T**3 / 6)
    fresh = g.apply([0.0, 0.0, 0.0], [0.5, 0.0, 0.0], 1.04, pose_t=1.04)
    late = g.apply([0.0, 0.0, 0.0], [0.5, 0.0, 0.0], 1.04, pose_t=1.0)
    assert late.min_barrier < fresh.min_barrier - 0.02


def test_lag_setting_defaults_by_clock_and_refuses_bad_values():
    scen = load_scenario(config("e5.2-dmpc"))
    assert command_lag_periods(scen) == 1.0  # lockstep
    realtime = dataclasses.replace(scen, run=dataclasses.replace(scen.run, clock="realtime"))
    assert command_lag_periods(realtime) == 2.0
    own = dataclasses.replace(realtime, safety=dataclasses.replace(realtime.safety, command_lag_periods=3))
    assert command_lag_periods(own) == 3.0
    for bad, rule in ((0.5, ">= 1"), (0, ">= 1"), (float("nan"), ">= 1"), ("two", "a number"), (True, "")):
        with pytest.raises(ConfigError, match=r"safety\.command_lag_periods = .*" + rule):
            from_table(SafetyConfig, {"enabled": True, "command_lag_periods": bad}, "safety")
    with pytest.raises(ConfigError, match="lag_periods"):
        GuardConfig(safety=SafetyConfig(enabled=True), name="a", models={"a": OMNI}, dt=DT, lag_periods=0.0)


def test_a_realtime_robot_says_when_its_envelope_position_was_true():
    """The runtime's envelopes keep the step's stamp (the controllers' clock) and carry the
    observation's time as ``pos_t``; in lockstep the two are the same and ``pos_t`` is left out;
    a receiver's filter dates the position from it."""
    scen = load_scenario(config("e5.2-dmpc"))
    real = dataclasses.replace(scen, run=dataclasses.replace(scen.run, clock="realtime"))
    pose = list(scen.robot("r1").pose)
    out = RobotRuntime(real, "r1", Keys("late")).step(Obs(3, 0.15, pose), 0.19)
    assert out.peers and {(env.stamp, env.pos_t) for _, env in out.peers} == {(0.19, 0.15)}
    assert all(env.pos == pose[:2] for _, env in out.peers)
    env = out.peers[0][1]
    assert unpack(env.pack()) == env  # over the wire
    lock = RobotRuntime(scen, "r1", Keys("late")).step(Obs(3, 0.15, pose), 0.15)
    assert {(e.stamp, e.pos_t) for _, e in lock.peers} == {(0.15, None)}
    g = SafetyGuard(GuardConfig(safety=SafetyConfig(enabled=True), name="a", models={"a": OMNI, "b": OMNI}, dt=DT))
    g.hear("b", [1.0, 0.0], 0.19, [0.0, 0.0, 0.0], pos_t=0.15)
    assert g.neighbours(0.2)[0].age == pytest.approx(0.05)
