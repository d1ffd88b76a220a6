"""sim/sensing.py and the world's observations under [sensing]: rates, latency stamps,
noise, outliers, bias drift, odometry, seeding; the wire records that carry them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from copath.estimation import SensorProfile
from copath.paths import wrap_to_pi
from copath.models import OmniModel, UnicycleModel
from copath.scenario import load_scenario
from copath.wire.messages import Estimate, Obs, PeerEnvelope, WireError, unpack
from sim.sensing import RobotSensors
from sim.world import World
from tests.conftest import config

DT = 0.1


def _drive(profile: SensorProfile, seconds: float, seed: int = 0, index: int = 0, model=None, cmd=(0.3, 0.2)):
    """Drive a unicycle for ``seconds``; returns per-read records (t, true poses of the
    ticks, raw, meas) and the true-pose function of time."""
    model = model or UnicycleModel()
    pose = np.array([1.0, -1.0, 0.5])
    s = RobotSensors(profile, model, seed, index, pose)
    starts = []
    reads = [(0.0, *s.read(0.0))]
    for k in range(int(round(seconds / DT))):
        starts.append((k * DT, pose.copy()))
        s.advance(k * DT, pose, np.asarray(cmd), DT)
        pose = model.step(pose, cmd, DT)
        reads.append(((k + 1) * DT, *s.read((k + 1) * DT)))

    def truth(t: float) -> np.ndarray:
        k = min(int(t / DT + 1e-9), len(starts) - 1)
        t0, p0 = starts[k]
        return model.step(p0, cmd, t - t0)

    return reads, truth, s


def test_fixes_come_at_their_rate_stamped_and_delayed():
    p = SensorProfile(fix_rate_hz=25.0, fix_std_m=0.02, fix_latency_s=0.12, heading_rate_hz=10.0,
                      heading_std_rad=0.05, heading_latency_s=0.05)
    reads, truth, _ = _drive(p, 10.0)
    fixes = [(t, f) for t, _, m in reads for f in m["fixes"]]
    heads = [(t, h) for t, _, m in reads for h in m["headings"]]
    taken = np.array([f[0] for _, f in fixes])
    np.testing.assert_allclose(np.diff(taken), 1 / 25.0, atol=1e-9)  # 25 Hz, in order
    assert len(fixes) == pytest.approx((10.0 - 0.12) * 25, abs=2)
    for t_read, f in fixes:  # delivered at the first read after taken + latency
        assert f[0] + 0.12 <= t_read + 1e-9 < f[0] + 0.12 + DT + 1e-9
    for t_read, h in heads:
        assert h[0] + 0.05 <= t_read + 1e-9 < h[0] + 0.05 + DT + 1e-9
    err = np.array([np.subtract(f[1:], truth(f[0])[:2]) for _, f in fixes])
    assert np.mean(err, axis=0) == pytest.approx([0, 0], abs=0.006)
    assert np.std(err, axis=0) == pytest.approx([0.02, 0.02], rel=0.15)  # measured at the pose when taken
    herr = np.array([wrap_to_pi(h[1] - truth(h[0])[2]) for _, h in heads])
    assert np.std(herr) == pytest.approx(0.05, rel=0.2)


def test_outliers_and_bias_drift():
    p = SensorProfile(fix_std_m=0.01, outlier_prob=0.1, outlier_std_m=0.5, heading_std_rad=0.0,
                      heading_bias_rad=0.1, heading_bias_walk=0.02)
    reads, truth, s = _drive(p, 20.0, seed=4)
    fixes = [f for _, _, m in reads for f in m["fixes"]]
    far = sum(np.hypot(*np.subtract(f[1:], truth(f[0])[:2])) > 0.1 for f in fixes)
    assert s.outliers == pytest.approx(0.1 * len(fixes), rel=0.35) and far >= 0.8 * s.outliers
    bias = np.array([wrap_to_pi(h[1] - truth(h[0])[2]) for _, _, m in reads for h in m["headings"]])
    assert bias[0] == pytest.approx(0.1, abs=0.02)
    assert np.std(np.diff(bias)) == pytest.approx(0.02 * math.sqrt(1 / 25.0), rel=0.2)  # a random walk


def test_odometry_is_the_applied_velocity_with_slip():
    exact, _, _ = _drive(SensorProfile(fix_std_m=0.01), 2.0)
    for t, _, m in exact[1:]:
        assert m["odom"] == [[pytest.approx(t - DT), pytest.approx(t), 0.3, 0.2]]
    slip, _, _ = _drive(SensorProfile(fix_std_m=0.01, odom_slip=0.1), 30.0)
    v = np.array([m["odom"][0][2] for _, _, m in slip[1:]])
    assert np.mean(v) == pytest.approx(0.3, rel=0.03) and np.std(v) == pytest.approx(0.03, rel=0.2)


def test_raw_reading_holds_the_latest_arrivals():
    p = SensorProfile(fix_std_m=0.01, fix_latency_s=0.3, heading_std_rad=0.01)
    reads, _, _ = _drive(p, 3.0, model=OmniModel(), cmd=(0.2, 0.1, 0.3))
    for t, raw, m in reads[5:]:
        if m["fixes"]:
            assert raw[:2] == m["fixes"][-1][1:]
        if m["headings"]:
            assert raw[2] == m["headings"][-1][1]


def test_seeded_per_robot():
    p = SensorProfile(fix_std_m=0.02)
    a, _, _ = _drive(p, 1.0, seed=1, index=0)
    b, _, _ = _drive(p, 1.0, seed=1, index=0)
    c, _, _ = _drive(p, 1.0, seed=1, index=1)
    assert a[-1][2] == b[-1][2] and a[-1][2] != c[-1][2]


def test_ideal_sensing_leaves_scenarios_unchanged():
    sc = load_scenario(config("e5.5-"))
    assert not sc.sensing.enabled
    w = World(sc)
    obs = w.observe("r1", 0)
    assert obs.meas is None and obs.pose == [float(v) for v in sc.robot("r1").pose]
    zero = sc.with_overrides(sensing={"profile": "quiet", "profiles": {"quiet": {"fix_rate_hz": 10.0}}})
    assert zero.sensing.enabled and World(zero).observe("r1", 0).meas is None  # all terms zero: true pose


def test_world_with_a_profile_sends_readings_and_measurements():
    sc = load_scenario(config("e5.5-")).with_overrides(sensing={"profile": "realistic", "robots": {"r2": "ideal"}})
    w = World(sc)
    for k in range(5):
        w.t = k * sc.run.dt
        for n in sc.robot_names:
            w.command(n, [0.2, 0.1])
        if k:
            o1 = w.observe("r1", k)
            assert o1.meas is not None and len(o1.meas["odom"]) == 1
            assert o1.pose != [float(v) for v in w.poses["r1"]]
            assert w.observe("r2", k).meas is None
        w.advance(sc.run.dt)


def test_noise_pose_std_and_a_sensing_profile_do_not_mix():
    sc = load_scenario(config("e5.5-"))
    with pytest.raises(Exception, match="noise.pose_std"):
        sc.with_overrides(noise={"pose_std": [0.01, 0.01, 0.01]}, sensing={"profile": "realistic"})


# -- wire ------------------------------------------------------------------------------------

def test_obs_with_measurements_and_estimate_round_trip():
    meas = {"odom": [[0.0, 0.1, 0.3, 0.2]], "fixes": [[0.04, 1.0, 2.0]], "headings": [[0.05, 0.3]]}
    o = Obs(1, 0.1, [1.0, 2.0, 0.3], None, None, meas)
    assert unpack(o.pack()) == o
    e = Estimate(1, 0.1, [1.0, 2.0, 0.3, 0.01], np.eye(4).tolist(), [0.5], [2],
                 {"accepted": 3, "rejected": 0, "late": 0})
    assert unpack(e.pack()) == e
    env = PeerEnvelope("r1", 1, 0.1, "coord_state", [1.0, 2.0], {"s": 1.0, "sdot": 0.3, "s_d": 0.0},
                       [1e-4, 0.0, 1e-4])
    assert unpack(env.pack()) == env
    d = env.to_dict()
    d["cov"] = [1.0]
    with pytest.raises(WireError, match="peer.cov"):
        PeerEnvelope.from_dict(d)


def test_obs_with_malformed_measurements_is_rejected():
    bad = Obs(1, 0.1, [1.0, 2.0, 0.3], None, None, {"odom": [], "fixes": [[0.1, 1.0]], "headings": []})
    with pytest.raises(WireError, match="obs.meas.fixes"):
        unpack(bad.pack())
