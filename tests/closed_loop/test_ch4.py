"""Chapter 4 experiments in closed loop (in-process lockstep runner, no noise).

Each test runs a scenario file from ``configs/`` through ``orchestrator.run.inprocess``
(the simulator integrates the commands with the robot models, ranges come from
``sim/geometry.py``) and asserts the behaviour the dissertation reports, with explicit
tolerances. JIT compilation is switched off here: it changes solve times, not results.
"""

from __future__ import annotations

import copy
import tomllib

import numpy as np
import pytest

from copath.scenario import parse_scenario
from orchestrator.run.inprocess import run_scenario
from tests.conftest import config

NO_JIT = {"jit": False}


def _raw(prefix: str) -> dict:
    return tomllib.loads(config(prefix).read_text())


def _run(raw: dict, controller: dict | None = None, pose=None, noise_free: bool = True, duration=None):
    raw = copy.deepcopy(raw)
    raw["controller"] = {**raw.get("controller", {}), **NO_JIT, **(controller or {})}
    if pose is not None:
        raw["robots"][0]["pose"] = list(pose)
    if noise_free:
        raw.pop("noise", None)
    return run_scenario(parse_scenario(raw), duration_s=duration)


def _after(rt, settle: float):
    """Telemetry rows and true poses at the controller step times after ``settle``."""
    t = np.asarray(rt.telemetry_t)
    keep = t >= settle
    poses = rt.pose_at(t[keep])
    return [d for d, k in zip(rt.telemetry, keep) if k], poses, t[keep]


def _time_error(rt):
    """Distance to the time-parameterised reference (telemetry ``ref_time``) per step."""
    t = np.asarray(rt.telemetry_t)
    p = rt.pose_at(t)
    ref = np.array([d["ref_time"] for d in rt.telemetry])
    return t, np.hypot(p[:, 0] - ref[:, 0], p[:, 1] - ref[:, 1])


def _effort(rt) -> float:
    """Control effort of a unicycle: integral of omega^2 + (dv/dt)^2 over the run."""
    cmd = np.asarray(rt.command)
    dt = float(np.median(np.diff(rt.t)))
    acc = np.diff(cmd[:, 0], prepend=0.0) / dt
    return float(np.sum((cmd[:, 1] ** 2 + acc**2) * dt))


# -- Sec. 4.2: omni NMPC -----------------------------------------------------------


def test_e4_2_path_following_eight_at_1mps_N10():
    raw = _raw("e4.2-")
    res = _run(raw, {"horizon": 10})
    m = res.metrics["robots"]["r1"]
    assert raw["run"]["settle_s"] > 0
    assert m["path_error_max_m"] < 0.05
    assert m["heading_error_max_rad"] < 0.1
    assert m["limit_violations"] == 0
    assert m["wheel_speed_max_mps"] <= 1.9 + 1e-6
    assert m["solver_failures"] == 0
    # the virtual vehicle runs at u_R once converged
    rows, _, _ = _after(res.trace.robots["r1"], raw["run"]["settle_s"])
    sdot = np.array([d["sdot"] for d in rows])
    assert abs(float(np.median(sdot)) - 1.0) < 0.02


def test_e4_1_trajectory_tracking_eight():
    res = _run(_raw("e4.1-"))
    m = res.metrics["robots"]["r1"]
    assert m["path_error_max_m"] < 0.03
    assert m["heading_error_max_rad"] < 0.1
    assert m["limit_violations"] == 0 and m["solver_failures"] == 0


# -- Sec. 4.3: LTV-MPC QP -----------------------------------------------------------


def test_e4_3_ltv_qp_slows_for_friction_and_tracks():
    raw = _raw("e4.3-")
    res = _run(raw)
    m = res.metrics["robots"]["r1"]
    assert m["path_error_max_m"] < 0.05
    assert m["limit_violations"] == 0 and m["solver_failures"] == 0
    rt = res.trace.robots["r1"]
    from copath.paths import eight_curve

    path = eight_curve(1.8, 1.2)
    c = raw["controller"]
    speed = np.hypot(rt.command[:, 0], rt.command[:, 1])
    s = np.array([d["s"] for d in rt.telemetry])
    n = min(len(speed), len(s))
    friction = np.sqrt(c["mu"] * c["g"] / np.maximum(np.abs(path.kappa(s[:n])), 1e-9))
    # respects the friction limit (4.26) at every step, and really slows in the lobes
    assert np.all(speed[:n] <= friction + 1e-3)
    assert speed.max() == pytest.approx(c["u_R"], abs=1e-6)
    assert speed.min() < 0.75  # sqrt(0.18 * 9.81 / 3.28) = 0.733 m/s at the sharpest turns
    assert np.all(speed <= c["u_max"] + 1e-9)


# -- Sec. 4.4: unicycle NMPC ---------------------------------------------------------

MODES = {"pf": "e4.4-unicycle-nmpc-pf", "tt": "e4.4-unicycle-nmpc-tt", "combined": "e4.4-unicycle-nmpc-combined"}


@pytest.fixture(scope="module")
def e44_runs():
    """Every mode from every posture of E4.4 (12 short runs), shared by the tests below."""
    out = {}
    for mode, prefix in MODES.items():
        raw = _raw(prefix)
        for i, pose in enumerate(raw["notes"]["postures"]):
            out[mode, i] = (raw, _run(raw, pose=pose))
    return out


@pytest.mark.long  # tier: README "Test tiers"
@pytest.mark.parametrize("mode", list(MODES))
def test_e4_4_converges_from_all_postures(e44_runs, mode):
    for i in range(4):
        raw, res = e44_runs[mode, i]
        m = res.metrics["robots"]["r1"]
        assert m["path_error_max_m"] < 0.01, (mode, i, m)
        assert m["heading_error_max_rad"] < 0.05, (mode, i, m)
        assert m["limit_violations"] == 0
        t, terr = _time_error(res.trace.robots["r1"])
        if mode != "pf":  # time convergence: the robot is where the clock says
            assert terr[t >= raw["run"]["settle_s"]].max() < 0.01, (mode, i)


@pytest.mark.long  # tier: README "Test tiers"
def test_e4_4_path_following_needs_less_effort_than_tracking(e44_runs, capsys):
    rows = []
    for i in range(4):
        e_pf = _effort(e44_runs["pf", i][1].trace.robots["r1"])
        e_tt = _effort(e44_runs["tt", i][1].trace.robots["r1"])
        e_c = _effort(e44_runs["combined", i][1].trace.robots["r1"])
        rows.append((i, e_pf, e_tt, e_c))
        assert e_pf < e_tt, (i, e_pf, e_tt)
    with capsys.disabled():
        print("\nE4.4 control effort  int(omega^2 + a^2) dt   [posture: PF / TT / combined]")
        for i, a, b, c in rows:
            print(f"  posture {i}: {a:7.2f} / {b:7.2f} / {c:7.2f}")


def test_e4_5_static_obstacle_avoided_and_time_recovered():
    raw = _raw("e4.5-")
    res = _run(raw)
    fleet, m = res.metrics["fleet"], res.metrics["robots"]["r1"]
    rt = res.trace.robots["r1"]
    assert fleet["collisions"] == 0
    assert fleet["min_obstacle_clearance_m"] > 0.0
    assert np.nanmin(rt.clearance) > 0.0
    t, terr = _time_error(rt)
    assert terr[(t > 3.0) & (t < 6.0)].max() > 0.3  # the obstacle really forced a detour
    assert terr[t >= raw["run"]["settle_s"]].max() < 0.02  # ... and time convergence returned
    assert m["path_error_max_m"] < 0.02


def test_e4_6_moving_obstacles_robot_backs_up_and_rejoins():
    raw = _raw("e4.6-")
    res = _run(raw)
    fleet = res.metrics["fleet"]
    rt = res.trace.robots["r1"]
    assert fleet["collisions"] == 0
    assert np.nanmin(rt.clearance) > 0.0
    assert rt.command[:, 0].min() < 0.0  # it backs up
    t, terr = _time_error(rt)
    assert terr[t >= raw["run"]["settle_s"]].max() < 0.02
    assert res.metrics["robots"]["r1"]["path_error_max_m"] < 0.02


def test_e4_7_real_robot_variant_follows_the_reference():
    raw = _raw("e4.7-")
    res = _run(raw, noise_free=False)  # with the chosen camera noise
    m = res.metrics["robots"]["r1"]
    assert m["path_error_max_m"] < 0.05
    t, terr = _time_error(res.trace.robots["r1"])
    assert terr[t >= raw["run"]["settle_s"]].max() < 0.05
