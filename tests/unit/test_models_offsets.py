"""Kinematic models (Ch. 3) and offset curves (Appendix A)."""

import math

import numpy as np
import pytest

from copath.models import OmniModel, UnicycleModel, integrate_body_velocity, rotation_speed_limit, scale_velocities
from copath.offsets import Quintic, constant_offset_velocities, offset_state
from copath.paths import circle, lemniscate


def test_world_wheel_matrix_is_rotated_body_map():
    m = OmniModel()
    for th in np.linspace(-3, 3, 7):
        body = np.array([0.3, -0.2, 0.7])
        c, s = math.cos(th), math.sin(th)
        world = np.array([c * body[0] - s * body[1], s * body[0] + c * body[1], body[2]])
        np.testing.assert_allclose(m.world_wheel_matrix(th) @ world, m.wheel_speeds(body), atol=1e-12)


def test_rotation_speed_limit_table_of_spec():
    # docs/reference/derivations.md, speed disc (D2): r(omega) = 1.900, 1.705, 1.315, 0.925 at |omega| = 0, 1, 3, 5
    np.testing.assert_allclose(rotation_speed_limit(np.array([0, 1, 3, -5])), [1.9, 1.705, 1.315, 0.925], atol=1e-9)
    m = OmniModel()
    # every translation direction with |v| <= r(omega) is feasible for the wheels
    for w in (0.0, 1.0, 3.0):
        for a in np.linspace(0, 2 * np.pi, 37):
            r = float(rotation_speed_limit(w))
            assert np.abs(m.wheel_speeds([r * math.cos(a), r * math.sin(a), w])).max() <= 1.9 + 1e-9


def test_omni_saturation_scales_to_wheel_limit_and_flags_violation():
    m = OmniModel()
    cmd, violated = m.saturate([3.0, 0.0, 0.0])
    assert violated and np.abs(m.wheel_speeds(cmd)).max() == pytest.approx(1.9)
    cmd, violated = m.saturate([0.5, 0.1, 0.2])
    assert not violated and np.allclose(cmd, [0.5, 0.1, 0.2])


def test_unicycle_scaling_preserves_curvature():
    v, w = scale_velocities(1.0, 3.0, 0.5, 1.0)
    assert w / v == pytest.approx(3.0) and abs(w) <= 1.0 + 1e-12 and abs(v) <= 0.5 + 1e-12
    m = UnicycleModel(v_max=0.5, omega_max=1.0, b=0.05)
    np.testing.assert_allclose(m.wheel_speeds([0.2, 1.0]), [0.25, 0.15])


def test_exact_integration_matches_fine_euler():
    pose = np.array([0.3, -0.1, 0.4])
    cmd = (0.4, 0.2, 0.9)
    exact = integrate_body_velocity(pose, cmd, 0.5)
    p = pose.copy()
    n = 20000
    for _ in range(n):
        c, s = math.cos(p[2]), math.sin(p[2])
        p = p + 0.5 / n * np.array([c * cmd[0] - s * cmd[1], s * cmd[0] + c * cmd[1], cmd[2]])
    np.testing.assert_allclose(exact, p, atol=1e-4)


def test_quintic_boundary_conditions():
    q = Quintic(0.0, 0.5, 2.0, 4.0)
    for s, val in ((2.0, 0.0), (4.0, 0.5), (3.0, 0.25)):
        assert float(q(s)[0]) == pytest.approx(val)
    for s in (2.0, 4.0):
        assert float(q(s)[1]) == pytest.approx(0.0) and float(q(s)[2]) == pytest.approx(0.0)
    s = np.linspace(2.1, 3.9, 50)
    h = 1e-6
    np.testing.assert_allclose((q(s + h)[0] - q(s - h)[0]) / (2 * h), q(s)[1], atol=1e-6)
    np.testing.assert_allclose((q(s + h)[1] - q(s - h)[1]) / (2 * h), q(s)[2], atol=1e-4)


def test_offset_of_a_circle_is_a_circle():
    p = circle(1.0)
    st = offset_state(p, np.linspace(0, 6, 20), 0.3)
    np.testing.assert_allclose(np.hypot(st.pos[:, 0], st.pos[:, 1]), 0.7, atol=1e-9)
    np.testing.assert_allclose(st.kappa, 1 / 0.7, rtol=1e-6)
    np.testing.assert_allclose(st.H, 0.7, rtol=1e-9)
    u_r, w_r, k_i = constant_offset_velocities(1.0, 0.3, 0.4)
    assert u_r == pytest.approx(0.28) and w_r == pytest.approx(0.4) and k_i == pytest.approx(1 / 0.7)


def test_offset_identities_against_finite_differences():
    """(A.4): dl/ds = H; (A.10): curvature of the offset curve; heading = direction of motion."""
    p = lemniscate(2.3)
    q = Quintic(-0.2, 0.3, 1.0, 4.0)
    s = np.linspace(1.2, 3.8, 40)
    h = 1e-5

    def state(x):
        qq, dq, ddq = q(x)
        return offset_state(p, x, qq, dq, ddq)

    st, sp, sm = state(s), state(s + h), state(s - h)
    d = (sp.pos - sm.pos) / (2 * h)
    np.testing.assert_allclose(np.hypot(d[:, 0], d[:, 1]), st.H, atol=1e-5)
    np.testing.assert_allclose(np.arctan2(np.sin(np.arctan2(d[:, 1], d[:, 0]) - st.theta),
                                          np.cos(np.arctan2(d[:, 1], d[:, 0]) - st.theta)), 0, atol=1e-5)
    dtheta = (np.unwrap(sp.theta) - np.unwrap(sm.theta)) / (2 * h)
    np.testing.assert_allclose(dtheta / st.H, st.kappa, atol=1e-3)


def test_offset_beyond_radius_of_curvature_is_refused():
    with pytest.raises(ValueError, match="cusp"):
        offset_state(circle(1.0), 0.5, 1.2)
