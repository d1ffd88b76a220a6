"""copath.estimation: the pose EKF (consistency, delayed measurements, outlier gate) and
the [sensing] configuration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from copath.config import ConfigError
from copath.estimation import BUILTIN_PROFILES, EstimatorConfig, PoseEKF, SensorProfile, parse_sensing
from copath.paths import wrap_to_pi
from copath.models import OmniModel, UnicycleModel
from sim.sensing import RobotSensors

DT = 0.1
# Gaussian sensors with delays and a drifting compass bias, no outliers (the NEES test needs the model to hold)
PROFILE = SensorProfile(fix_rate_hz=25.0, fix_std_m=0.02, fix_latency_s=0.12, heading_rate_hz=10.0,
                        heading_std_rad=0.05, heading_latency_s=0.05, heading_bias_rad=0.05,
                        heading_bias_walk=0.005, odom_slip=0.05, odom_std=0.01)


def _unicycle_cmd(k: int) -> np.ndarray:
    return np.array([0.3, 0.4 * math.sin(0.05 * k)])


def _omni_cmd(k: int) -> np.ndarray:
    return np.array([0.3 * math.cos(0.03 * k), 0.2, 0.3 * math.sin(0.05 * k)])


def _closed_loop_run(seed: int, model, cmd_of, n_steps: int, profile: SensorProfile = PROFILE):
    """Drive a robot open-loop through the simulator's sensor models and filter it:
    returns (n, 3) estimation errors (heading wrapped) and (n, 3, 3) covariances."""
    pose = np.array([0.0, 0.0, 0.3])
    sensors = RobotSensors(profile, model, seed, 0, pose)
    raw, meas = sensors.read(0.0)
    ekf = PoseEKF(profile, model.kind, EstimatorConfig(), 0.0, raw)
    errs, covs = [], []
    for k in range(n_steps):
        u = cmd_of(k)
        sensors.advance(k * DT, pose, u, DT)
        pose = model.step(pose, u, DT)
        t = (k + 1) * DT
        raw, meas = sensors.read(t)
        res = ekf.step(t, meas["odom"], meas["fixes"], meas["headings"])
        e = res.pose - pose
        e[2] = wrap_to_pi(e[2])
        errs.append(e)
        covs.append(res.P[:3, :3])
    return np.array(errs), np.array(covs)


@pytest.mark.long  # tier: README "Test tiers" (about 10 s each)
@pytest.mark.parametrize("model,cmd_of", [(UnicycleModel(), _unicycle_cmd), (OmniModel(), _omni_cmd)],
                         ids=["unicycle", "omni"])
def test_nees_is_within_chi_square_bounds_over_seeded_runs(model, cmd_of):
    runs, n = 40, 200
    nees = np.zeros((runs, n))
    for m in range(runs):
        e, P = _closed_loop_run(m, model, cmd_of, n)
        nees[m] = np.einsum("ni,ni->n", e, np.linalg.solve(P, e[:, :, None])[:, :, 0])
    avg = nees.mean(axis=0)[20:]  # after the start-up transient (2 s)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * runs) / runs
    inside = np.mean((avg >= lo) & (avg <= hi))
    # a consistent filter: the run-averaged NEES lies in its 95 % band most of the time,
    # and its overall mean is close to the state dimension 3
    assert inside >= 0.8, f"only {inside:.0%} of instants within [{lo:.2f}, {hi:.2f}]; mean {avg.mean():.2f}"
    assert 2.0 <= avg.mean() <= 4.0


def _odometry(n: int, u=(0.3, 0.0, 0.2)):
    return [[k * DT, (k + 1) * DT, *u] for k in range(n)]


def test_delayed_measurement_repropagated_equals_undelayed():
    profile = SensorProfile(fix_std_m=0.02, fix_latency_s=0.35, heading_std_rad=0.05, heading_latency_s=0.35,
                            odom_slip=0.05)
    rng = np.random.default_rng(3)
    n = 40
    odom = _odometry(n)
    # measurements taken at instants inside ticks, with noise; none in the last 0.4 s
    fixes = [[t, 0.3 * t + rng.normal(0, 0.02), 0.01 * t + rng.normal(0, 0.02)] for t in np.arange(0.03, 3.5, 0.04)]
    heads = [[t, 0.2 * t + rng.normal(0, 0.05)] for t in np.arange(0.07, 3.5, 0.1)]
    pose0 = [0.0, 0.0, 0.0]
    a = PoseEKF(profile, "omni", EstimatorConfig(), 0.0, pose0)
    b = PoseEKF(profile, "omni", EstimatorConfig(), 0.0, pose0)
    delay = 0.3
    for k in range(n):
        t = (k + 1) * DT
        now = [f for f in fixes if t - DT < f[0] <= t], [h for h in heads if t - DT < h[0] <= t]
        late = ([f for f in fixes if t - DT < f[0] + delay <= t], [h for h in heads if t - DT < h[0] + delay <= t])
        ra = a.step(t, [odom[k]], *now)
        rb = b.step(t, [odom[k]], *late)
    assert rb.late == 0 and (rb.accepted, rb.rejected) == (ra.accepted, ra.rejected)
    assert ra.accepted + ra.rejected == len(fixes) + len(heads)
    np.testing.assert_allclose(rb.x, ra.x, atol=1e-9)
    np.testing.assert_allclose(rb.P, ra.P, atol=1e-12)
    # and the delay matters: fusing the same fixes at their arrival time instead gives another estimate
    c = PoseEKF(profile, "omni", EstimatorConfig(), 0.0, pose0)
    for k in range(n):
        t = (k + 1) * DT
        restamped = ([[t, *f[1:]] for f in fixes if t - DT < f[0] + delay <= t],
                     [[t, *h[1:]] for h in heads if t - DT < h[0] + delay <= t])
        rc = c.step(t, [odom[k]], *restamped)
    assert np.linalg.norm(rc.x[:2] - ra.x[:2]) > 1e-3


def test_gate_rejects_injected_outliers():
    profile = SensorProfile(fix_std_m=0.02, heading_std_rad=0.03, odom_slip=0.05)
    rng = np.random.default_rng(7)
    ekf = PoseEKF(profile, "unicycle", EstimatorConfig(), 0.0, [0.0, 0.0, 0.0])
    pose = np.zeros(3)
    model = UnicycleModel()
    injected = 0
    good_rejected_bound = 0
    for k in range(300):
        u = np.array([0.3, 0.2])
        t0, pose_t0 = k * DT, pose
        pose = model.step(pose, u, DT)
        t = (k + 1) * DT
        fixes = []
        for j in range(1, 3):  # two fixes per tick, the second at the tick
            tm = t0 + j * DT / 2
            p = model.step(pose_t0, u, tm - t0)
            z = p[:2] + rng.normal(0, 0.02, 2)
            if k % 10 == 5 and j == 1:
                z = z + rng.choice([-1, 1], 2) * rng.uniform(0.3, 1.0, 2)  # an outlier of 0.3-1 m per axis
                injected += 1
            fixes.append([tm, *z])
        heads = [[t, pose[2] + rng.normal(0, 0.03)]]
        good_rejected_bound += 3
        res = ekf.step(t, [[t0, t, *u]], fixes, heads)
        assert np.hypot(*(res.pose[:2] - pose[:2])) < 0.06
    assert res.rejected >= injected
    # the 99.9 % gate rejects few good measurements
    assert res.rejected - injected <= 0.01 * good_rejected_bound
    assert res.accepted + res.rejected == 3 * 300


def test_compass_bias_is_estimated():
    model = UnicycleModel()
    profile = SensorProfile(fix_std_m=0.02, heading_std_rad=0.03, heading_bias_rad=0.15, odom_slip=0.03)
    pose = np.array([0.0, 0.0, 0.0])
    sensors = RobotSensors(profile, model, 11, 0, pose)
    raw, _ = sensors.read(0.0)
    ekf = PoseEKF(profile, "unicycle", EstimatorConfig(bias_std0_rad=0.2), 0.0, raw)
    for k in range(600):
        u = np.array([0.3, 0.3 * math.sin(0.02 * k)])
        sensors.advance(k * DT, pose, u, DT)
        pose = model.step(pose, u, DT)
        _, m = sensors.read((k + 1) * DT)
        res = ekf.step((k + 1) * DT, m["odom"], m["fixes"], m["headings"])
    assert res.x[3] == pytest.approx(0.15, abs=0.03)
    assert abs(wrap_to_pi(res.x[2] - pose[2])) < 0.03


def test_predict_ahead_follows_the_command():
    ekf = PoseEKF(SensorProfile(fix_std_m=0.01), "unicycle", EstimatorConfig(), 0.0, [1.0, 2.0, 0.0])
    np.testing.assert_allclose(ekf.predict_ahead(0.5, [0.4, 0.0]), [1.2, 2.0, 0.0])
    np.testing.assert_allclose(ekf.predict_ahead(0.0, [0.4, 0.0]), [1.0, 2.0, 0.0])


def test_duplicate_observation_is_ignored():
    ekf = PoseEKF(PROFILE, "unicycle", EstimatorConfig(), 0.0, [0.0, 0.0, 0.0])
    args = ([[0.0, 0.1, 0.3, 0.1]], [[0.05, 0.016, 0.0]], [[0.08, 0.0]])
    r1 = ekf.step(0.1, *args)
    r2 = ekf.step(0.1, *args)  # a realtime agent may step twice on one observation
    np.testing.assert_allclose(r1.x, r2.x)
    assert r2.accepted == r1.accepted == 2 and r2.nis == []


# -- configuration ------------------------------------------------------------------------

def test_builtin_profiles_and_ideal():
    assert BUILTIN_PROFILES["ideal"].ideal
    assert not BUILTIN_PROFILES["realistic-unicycle"].ideal
    cfg = parse_sensing({"profile": "realistic", "robots": {"r2": "ideal"}}, ["r1", "r2"])
    assert cfg.profile_for("r1", "omni") is BUILTIN_PROFILES["realistic-omni"]
    assert cfg.profile_for("r1", "unicycle") is BUILTIN_PROFILES["realistic-unicycle"]
    assert cfg.profile_for("r2", "unicycle").ideal
    assert not parse_sensing(None).enabled


def test_custom_profile_starts_from_its_base():
    cfg = parse_sensing({"profile": "cam", "profiles": {"cam": {"base": "realistic-unicycle", "fix_std_m": 0.05}}})
    p = cfg.profile_for("r1", "unicycle")
    assert p.fix_std_m == 0.05 and p.heading_std_rad == BUILTIN_PROFILES["realistic-unicycle"].heading_std_rad


@pytest.mark.parametrize("table,needle", [
    ({"profile": "fancy"}, "sensing.profile = 'fancy' is not allowed; profiles:"),
    ({"robots": {"r9": "ideal"}}, "sensing.robots.r9 = 'ideal' is not allowed; must name a robot"),
    ({"profiles": {"cam": {"fix_std_m": -1.0}}}, "sensing.profiles.cam.fix_std_m = -1.0 is not allowed"),
    ({"profiles": {"cam": {"fix_sdt_m": 1.0}}}, "sensing.profiles.cam.fix_sdt_m = 1.0 is not allowed; allowed keys"),
    ({"profiles": {"cam": {"base": "nope"}}}, "sensing.profiles.cam.base = 'nope' is not allowed"),
    ({"gate_prob": 1.5}, "sensing.gate_prob = 1.5 is not allowed"),
    ({"estimator": "yes"}, "sensing.estimator = 'yes' is not allowed; expected true or false"),
])
def test_sensing_errors_name_key_value_and_rule(table, needle):
    with pytest.raises(ConfigError) as exc:
        parse_sensing(table, ["r1", "r2"])
    assert needle in str(exc.value)
