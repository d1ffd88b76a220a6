"""Sec. 5.3 geometry: offset-curve velocity profiles (5.4)-(5.5), quintic transitions (5.3),
formation schedules, the leader's plan indexed by its age, and morphing (5.28)-(5.29)."""

import math

import numpy as np
import pytest

from agent.controllers.leader_following.controller import (
    FormationSchedule,
    LeaderPlan,
    follower_reference,
    planned_min_separation,
)
from copath.config import ConfigError
from copath.morphing import configuration, desired_speed, morphing
from copath.offsets import Quintic, offset_state
from copath.paths import circle, ellipse, lemniscate

LEM = lemniscate(2.3)


def _schedule(windows=(("column", 2.0, 4.0),)):
    forms = {
        "triangle": {"f1": [-0.6, 0.4], "f2": [-0.6, -0.4]},
        "column": {"f1": [-0.6, 0.0], "f2": [-1.2, 0.0]},
    }
    sched = [{"formation": f, "s_start": a, "s_end": b} for f, a, b in windows]
    return FormationSchedule.from_params(forms, "triangle", sched, "controller")


@pytest.mark.parametrize("q0, q1", [(0.4, -0.3), (-0.5, 0.2), (0.0, 0.5)])
def test_offset_velocities_match_finite_differences(q0, q1):
    """u_i = H u_c (5.4) and omega_i = k_i u_i (5.5) against differences of o(s(t))."""
    quint = Quintic(q0, q1, 1.0, 3.0)
    u_c = 0.4
    t = np.linspace(2.0, 7.0, 2001)  # s = 0.8 .. 2.8 m, through the transition
    s = u_c * t
    q, dq, ddq = quint(s)
    geo = offset_state(LEM, s, q, dq, ddq)
    h = t[1] - t[0]
    vel = np.gradient(geo.pos, h, axis=0)
    speed_fd = np.hypot(vel[:, 0], vel[:, 1])
    omega_fd = np.gradient(np.unwrap(np.arctan2(vel[:, 1], vel[:, 0])), h)
    u_i = geo.H * u_c  # (5.4)
    omega_i = geo.kappa * u_i  # (5.5)
    inner = slice(5, -5)
    np.testing.assert_allclose(u_i[inner], speed_fd[inner], atol=2e-4)
    np.testing.assert_allclose(omega_i[inner], omega_fd[inner], atol=5e-3)
    # the heading of the offset curve is its direction of motion
    np.testing.assert_allclose(np.cos(geo.theta[inner] - np.arctan2(vel[inner, 1], vel[inner, 0])), 1.0, atol=1e-6)


def test_quintic_boundary_conditions_and_shape():
    """(5.2): value, slope and curvature match at both ends; monotone in between (5.3)."""
    qu = Quintic(0.4, -0.2, 2.0, 5.0)
    q, d1, d2 = qu(np.array([2.0, 5.0]))
    np.testing.assert_allclose(q, [0.4, -0.2])
    np.testing.assert_allclose(d1, 0.0, atol=1e-12)
    np.testing.assert_allclose(d2, 0.0, atol=1e-12)
    s = np.linspace(2.0, 5.0, 301)
    qs, d1s, d2s = qu(s)
    assert np.all(np.diff(qs) <= 1e-12)
    np.testing.assert_allclose(qs[150], 0.1, atol=1e-12)  # midpoint: half way
    # slope and curvature are consistent with the values (finite differences)
    np.testing.assert_allclose(np.gradient(qs, s)[2:-2], d1s[2:-2], atol=1e-3)
    np.testing.assert_allclose(np.gradient(d1s, s)[2:-2], d2s[2:-2], atol=2e-3)


def test_formation_schedule_offsets_follow_the_quintic():
    sch = _schedule()
    p, dp, ddp, q, dq, ddq = sch.offsets("f2", np.array([0.0, 2.0, 3.0, 4.0, 9.0]))
    np.testing.assert_allclose(p, [-0.6, -0.6, -0.9, -1.2, -1.2])
    np.testing.assert_allclose(q, [-0.4, -0.4, -0.2, 0.0, 0.0])
    assert dp[0] == dp[-1] == dq[0] == dq[-1] == 0.0
    assert dp[2] == pytest.approx(-0.6 / 2.0 * 1.875)  # peak slope 30/16 dq/ds at the middle
    assert sch.in_transition(3.0) and not sch.in_transition(5.0)


def test_follower_reference_is_consistent_in_time_during_a_transition():
    """The reference velocities (u_p = sdot_c + pdot, docs/reference/ambiguities.md, u_p when the along-track offset varies (A28)) match the motion of the
    reference pose when p and q change together."""
    sch = _schedule()
    t = np.linspace(4.0, 11.0, 3501)
    s_c = 0.4 * t  # leader at 0.4 m/s: s_c = 1.6 .. 4.4 m covers the window [2, 4]
    ref = follower_reference(LEM, sch, "f2", s_c, 0.4)
    h = t[1] - t[0]
    vel = np.gradient(ref.pose[:, :2], h, axis=0)
    inner = slice(5, -5)
    np.testing.assert_allclose(ref.u[inner], np.hypot(vel[inner, 0], vel[inner, 1]), atol=5e-4)
    np.testing.assert_allclose(ref.omega[inner], np.gradient(np.unwrap(ref.pose[:, 2]), h)[inner], atol=1e-2)
    # the tabulated geometry gives the same reference
    fast = follower_reference(LEM.table(), sch, "f2", s_c, 0.4)
    np.testing.assert_allclose(fast.pose, ref.pose, atol=1e-5)
    np.testing.assert_allclose(fast.u, ref.u, atol=1e-4)


def test_progress_projection_recovers_the_path_coordinate():
    sch = _schedule()
    ref = follower_reference(LEM, sch, "f1", np.array([1.0]), 0.4)
    th = ref.pose[0, 2]
    ahead = ref.pose[0, :2] + 0.03 * np.array([math.cos(th), math.sin(th)])
    s_true = follower_reference(LEM, sch, "f1", np.array([1.0]), 0.4).s_i[0]
    # 3 cm along the offset curve is 3 cm / H of path coordinate
    assert ref.progress_of(ahead) - s_true == pytest.approx(0.03 / ref.H[0], abs=1e-9)


def test_leader_plan_is_indexed_by_its_age():
    """s_c(tau) = s_l + integral of the piecewise-constant planned sdot, held beyond."""
    plan = LeaderPlan(s_l=1.0, sdot_pred=(0.2, 0.4, 0.6), delta_l=0.1, stamp=5.0,
                      age_at_receipt=0.05, t_receipt=5.05)
    s, sd = plan.progress(np.array([5.05, 5.15, 5.25, 5.55]))
    np.testing.assert_allclose(s, [1.01, 1.0 + 0.02 + 0.02, 1.0 + 0.02 + 0.04 + 0.6 * 0.05, 1.12 + 0.6 * 0.25])
    np.testing.assert_allclose(sd, [0.2, 0.4, 0.6, 0.6])
    # fill-in: the same plan later has a larger age and extrapolates further
    assert plan.age(6.05) == pytest.approx(1.05)


def test_schedule_validation_names_the_key():
    with pytest.raises(ConfigError, match="schedule"):
        _schedule((("column", 2.0, 4.0), ("triangle", 3.5, 6.0)))  # overlapping windows
    with pytest.raises(ConfigError, match="formation"):
        _schedule((("wedge", 2.0, 4.0),))


def test_planned_separation_detects_a_colliding_schedule():
    # E5.1's staged change (F2 drops back before both move onto the path) stays apart
    staged = FormationSchedule.from_params(
        {"triangle": {"f1": [-0.6, 0.4], "f2": [-0.6, -0.4]}, "stagger": {"f1": [-0.6, 0.4], "f2": [-1.2, -0.4]},
         "column": {"f1": [-0.6, 0.0], "f2": [-1.2, 0.0]}},
        "triangle", [{"formation": "stagger", "s_start": 2.0, "s_end": 3.5},
                     {"formation": "column", "s_start": 3.5, "s_end": 5.5}], "c")
    assert planned_min_separation(LEM, staged, -1.0, 12.0)[0] > 0.5
    # moving both followers onto the path at the same p would merge their slots
    forms = {"triangle": {"f1": [-0.6, 0.4], "f2": [-0.6, -0.4]},
             "column": {"f1": [-0.6, 0.0], "f2": [-0.6, 0.0]}}
    bad = FormationSchedule.from_params(forms, "triangle", [{"formation": "column", "s_start": 2.0, "s_end": 4.0}], "c")
    d, s_at, pair = planned_min_separation(LEM, bad, -1.0, 6.0)
    assert d < 0.05 and s_at >= 2.0 and set(pair) == {"f1", "f2"}


def test_morphing_speeds_and_base_coordinates():
    """(5.28)-(5.29) with the E5.3 paths: u_1,d = 0.505 m/s for sigma_B = 0.4 m/s."""
    g1 = ellipse(1.5, 1.0, rotation=math.pi / 6)
    g3 = circle(1.0, rotation=math.pi / 2)
    m = morphing(g1, g3)
    assert g1.length == pytest.approx(7.9327, abs=1e-4)
    assert m.desired_speed(0.4) == pytest.approx(0.5050, abs=1e-4)
    assert desired_speed(g1.length, g3.length, 0.4) == pytest.approx(m.desired_speed(0.4))
    assert m.sigma(m.desired_speed(0.4)) == pytest.approx(0.4)  # sigma_i = sigma_B keeps the formation
    assert m.s(m.psi(3.3)) == pytest.approx(3.3)
    # one period of the base path is one period of the own path
    assert m.psi(g1.length) == pytest.approx(g3.length)
    pts = configuration([g1, g3], [m, morphing(g3, g3)], np.array([0.0, 1.0]))
    assert pts.shape == (2, 2, 2)
    np.testing.assert_allclose(pts[0, 1], g3.pos(0.0))
