"""Chapter 4 models: error dynamics against finite differences of the true kinematics,
gain conditions, the velocity profile, condensing, and the shared MPC scaffolding."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from agent.controllers.ltv_mpc.controller import (
    LTVPathFollowingQP,
    VelocityProfile,
    condense,
    linear_model,
    ltv_error_dynamics,
    ltv_errors,
    profile_speed,
)
from agent.controllers.omni_nmpc.controller import (
    EightTrajectory,
    check_gain_conditions,
    gain_condition_margins,
    pf_error_dynamics,
    pf_errors,
    pf_virtual_inputs,
    tt_error_dynamics,
    tt_errors,
)
from agent.controllers.unicycle_nmpc.controller import (
    obstacle_cost,
    scan_points,
    terminal_law,
    uni_error_dynamics,
    uni_errors,
    uni_gain_condition_margins,
    uni_virtual_inputs,
)
from copath.config import ConfigError
from copath.models import OmniModel, body_velocity_between, integrate_body_velocity, rotation_speed_limit
from copath.mpc import OCP, MPCSolver, PathTable, SolverConfig
from copath.paths import circle, eight_curve, wrap_to_pi

H = 1e-6  # finite-difference step [s]


def _num(v) -> np.ndarray:
    return np.asarray(ca.DM(v) if not isinstance(v, np.ndarray) else v, dtype=float).reshape(-1)


@pytest.fixture(scope="module")
def eight():
    return eight_curve()


def _frame(path, s):
    x, y, th, _ = path.frame(s)
    return np.array([x, y, th])


@pytest.mark.parametrize("seed", range(20))
def test_body_velocity_between_inverts_the_exact_step(seed):
    """(3.1) integrated in closed form over dt, then read back from the two poses: the same twist,
    straight (omega = 0) or turning, across the heading's wrap at pi."""
    rng = np.random.default_rng(seed)
    pose = np.array([*rng.normal(0, 2, 2), rng.choice([np.pi - 0.01, rng.uniform(-np.pi, np.pi)])])
    body = rng.normal(0, 0.7, 3) * np.array([1, 1, rng.choice([0.0, 1.0])])
    dt = rng.uniform(0.02, 0.5)
    np.testing.assert_allclose(body_velocity_between(pose, integrate_body_velocity(pose, body, dt), dt), body,
                               atol=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_pf_error_dynamics_match_kinematics(eight, seed):
    """(4.2)/(4.4): d/dt of the path-frame errors (4.1) under (3.1) and s-dot."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0, eight.length)
    ref = _frame(eight, s)
    pose = ref + np.array([*rng.normal(0, 0.2, 2), rng.normal(0, 0.5)])
    body = rng.normal(0, 0.7, 3)
    sdot = rng.uniform(0.2, 1.2)

    def err(t):
        p = integrate_body_velocity(pose, body, t)
        e = pf_errors(p, _frame(eight, s + sdot * t))
        return e

    fd = (err(H) - err(-H)) / (2 * H)
    model = _num(pf_error_dynamics(err(0.0), body, sdot, eight.kappa(s)))
    np.testing.assert_allclose(model, fd, atol=2e-4)


def test_pf_virtual_inputs_are_regulation_form(eight):
    """(4.4)-(4.5): xdot_e = A(kappa s-dot) x_e + u_e with the corrected u_3 (docs/reference/ambiguities.md, sign of the third virtual input (A1))."""
    xe = np.array([0.1, -0.2, 0.3])
    body, sdot, k = np.array([0.8, 0.1, 0.4]), 0.9, 1.5
    ue = _num(pf_virtual_inputs(xe, body, sdot, k * sdot))
    A = np.array([[0, k * sdot, 0], [-k * sdot, 0, 0], [0, 0, 0]])
    np.testing.assert_allclose(_num(pf_error_dynamics(xe, body, sdot, k)), A @ xe + ue, atol=1e-12)
    # u_1, u_2 are u_R (cos, sin) alpha_e with alpha_e = theta_t - theta_d
    u_R = math.hypot(body[0], body[1])
    alpha_e = xe[2] + math.atan2(body[1], body[0])
    np.testing.assert_allclose(ue[:2], [-sdot + u_R * math.cos(alpha_e), u_R * math.sin(alpha_e)], atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_tt_error_dynamics_match_kinematics(seed):
    """(4.3): robot-frame errors of a reference moving along its tangent with (u_d, omega_d)."""
    rng = np.random.default_rng(seed)
    ref0 = rng.normal(0, 1, 3)
    pose = ref0 + np.array([*rng.normal(0, 0.2, 2), rng.normal(0, 0.4)])
    body = rng.normal(0, 0.7, 3)
    u_d, om_d = rng.uniform(0.3, 1.2), rng.normal(0, 1)

    def err(t):
        return tt_errors(integrate_body_velocity(pose, body, t), integrate_body_velocity(ref0, (u_d, 0, om_d), t))

    fd = (err(H) - err(-H)) / (2 * H)
    np.testing.assert_allclose(_num(tt_error_dynamics(err(0.0), body, u_d, om_d)), fd, atol=2e-4)


def test_eight_trajectory_derivatives():
    """E4.1 reference (4.14): u_d in [0.49, 1.20] m/s, heading and yaw rate consistent."""
    traj = EightTrajectory()
    t = np.linspace(0, 15.7, 4001)
    r = traj.sample(t)
    assert 0.47 < r[:, 3].min() < 0.51 and 1.18 < r[:, 3].max() < 1.22
    dt = t[1] - t[0]
    np.testing.assert_allclose(np.gradient(r[:, 0], dt)[1:-1], (r[:, 3] * np.cos(r[:, 2]))[1:-1], atol=1e-3)
    np.testing.assert_allclose(np.gradient(r[:, 2], dt)[1:-1], r[1:-1, 4], atol=2e-3)


def test_gain_conditions_omni():
    """(4.10) with the published E4.1/E4.2 values: margins 1.1; range [0.53, 9.47]."""
    m = gain_condition_margins([0.5] * 3, [0.1] * 3, [2.0] * 3)
    np.testing.assert_allclose(m, [1.1, 1.1, 1.1], atol=1e-12)
    lo = (1 - math.sqrt(1 - 4 * 0.05)) / 0.2
    hi = (1 + math.sqrt(1 - 4 * 0.05)) / 0.2
    assert gain_condition_margins([0.5] * 3, [0.1] * 3, [lo + 1e-9] * 3).min() >= 0
    assert gain_condition_margins([0.5] * 3, [0.1] * 3, [hi + 1e-3] * 3).min() < 0
    check_gain_conditions([0.5] * 3, [0.1] * 3, [2.0] * 3)
    with pytest.raises(ConfigError, match="alpha"):
        check_gain_conditions([0.5] * 3, [0.1] * 3, [0.2, 2.0, 2.0])


def test_gain_conditions_unicycle():
    """(4.48) with (4.55): 2.5 - 0.2 - 0.000625 - 2 and 0.015 - 0.01 - 0.0001 (twice)."""
    m = uni_gain_condition_margins([0.2, 2, 0.01, 0.01], [1e-4] * 3, [1, 1, 0.015, 0.015], [2.5, 1, 1])
    np.testing.assert_allclose(m, [0.299375, 0.0049, 0.0049], atol=1e-12)
    assert uni_gain_condition_margins([0.2, 2, 0.01, 0.01], [1e-4] * 3, [1, 1, 0.015, 0.015], [1.0, 1, 1])[0] < 0


@pytest.mark.parametrize("seed", range(5))
def test_ltv_error_dynamics_match_kinematics(eight, seed):
    """(4.22): errors (4.19) under the decoupled kinematics (4.20)."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0, eight.length)
    ref = _frame(eight, s)
    pose = ref + np.array([*rng.normal(0, 0.2, 2), rng.normal(0, 0.4)])
    theta_t0 = ref[2] + rng.normal(0, 0.3)
    u_R, Phi, omega, sdot = rng.uniform(0.3, 1.2), rng.normal(0, 1), rng.normal(0, 1), rng.uniform(0.3, 1.2)
    theta_b, omega_b = 0.3, 0.0

    def err(t):
        # motion with speed u_R along theta_t(t) = theta_t0 + Phi u_R t; heading theta + omega t
        if abs(Phi) > 1e-12:
            dx = (math.sin(theta_t0 + Phi * u_R * t) - math.sin(theta_t0)) / Phi
            dy = -(math.cos(theta_t0 + Phi * u_R * t) - math.cos(theta_t0)) / Phi
        else:
            dx, dy = u_R * t * math.cos(theta_t0), u_R * t * math.sin(theta_t0)
        p = np.array([pose[0] + dx, pose[1] + dy, pose[2] + omega * t])
        return ltv_errors(p, theta_t0 + Phi * u_R * t, _frame(eight, s + sdot * t), theta_b + omega_b * t)

    fd = (err(H) - err(-H)) / (2 * H)
    model = ltv_error_dynamics(err(0.0), u_R, Phi, omega, sdot, eight.kappa(s), omega_b)
    np.testing.assert_allclose(model, fd, atol=2e-4)


def test_linear_model_is_the_linearisation():
    """(4.23): A_c, B_c are the Jacobians of (4.22) at x_e = 0 with s-dot = u_R."""
    k, u_R, Ts = 1.7, 0.9, 0.05
    A, B = linear_model(k, u_R, Ts)
    xe0 = np.zeros(4)
    # virtual inputs (4.24) u = (-sdot + u_R cos a, Phi u_R - kappa sdot, omega - omega_b) at 0
    J = np.zeros((4, 4))
    for i in range(4):
        d = np.zeros(4)
        d[i] = 1e-6
        # hold s-dot = u_R and the inputs u_e = 0 -> Phi = kappa, omega = 0
        f = lambda x: ltv_error_dynamics(x, u_R, k, 0.0, u_R, k, 0.0) - np.array(  # noqa: E731
            [u_R * math.cos(x[2]) - u_R, 0, 0, 0])
        J[:, i] = (f(xe0 + d) - f(xe0 - d)) / 2e-6
    np.testing.assert_allclose(A, np.eye(4) + J * Ts, atol=1e-8)
    np.testing.assert_allclose(B, np.array([[1, 0, 0], [0, 0, 0], [0, 1, 0], [0, 0, 1]]) * Ts)


def test_condensing_matches_rollout():
    """(4.31) with the corrected products (docs/reference/ambiguities.md, transition products (A5)): X = G x + S U equals
    the recursion."""
    rng = np.random.default_rng(3)
    N, Ts = 6, 0.05
    kap, uR = rng.normal(0, 2, N), rng.uniform(0.5, 1.2, N)
    As, B = [], None
    for j in range(N):
        A, B = linear_model(kap[j], uR[j], Ts)
        As.append(A)
    G, S = condense(As, B)
    assert G.shape == (4 * N, 4) and S.shape == (4 * N, 3 * N)
    x0, U = rng.normal(0, 1, 4), rng.normal(0, 1, (N, 3))
    x, X = x0.copy(), []
    for j in range(N):
        x = As[j] @ x + B @ U[j]
        X.append(x)
    np.testing.assert_allclose(G @ x0 + S @ U.reshape(-1), np.concatenate(X), atol=1e-12)


def test_ltv_qp_matches_unconstrained_optimum():
    """(4.33): with inactive bounds the QP solution is -H^-1 f and H = 2 (S'QS + R)."""
    N = 4
    qp = LTVPathFollowingQP(N, 0.05, [300, 300, 7, 70], [1, 0.001, 3], jit=False)
    xe, kap, uR = np.array([0.05, -0.03, 0.02, 0.01]), np.full(N, 1.2), np.full(N, 0.9)
    Hm, f = qp.matrices(xe, kap, uR)
    assert np.all(np.linalg.eigvalsh(Hm) > 0)
    sol = qp.solve(xe, kap, uR, np.full(3 * N, -100.0), np.full(3 * N, 100.0))
    assert sol.ok
    np.testing.assert_allclose(sol.U.reshape(-1), -np.linalg.solve(Hm, f), rtol=1e-6, atol=1e-8)
    box = qp.solve(xe, kap, uR, np.full(3 * N, -0.01), np.full(3 * N, 0.01))
    assert box.ok and np.all(np.abs(box.U) <= 0.01 + 1e-9)


def test_rotation_limit_and_profile():
    """(4.17)-(4.18), (4.25)-(4.27) and the friction limit of E4.3."""
    np.testing.assert_allclose(rotation_speed_limit(np.array([0, 1, 3, 5])), [1.9, 1.705, 1.315, 0.925], atol=1e-9)
    np.testing.assert_allclose(OmniModel().max_rotation(np.array([0.4, 1.0, 1.315])), [7.692, 4.615, 3.0], atol=1e-3)
    u = profile_speed(np.array([0.0, 1.0, 3.28]), 1.0, 1.315, 0.18, 9.81)
    np.testing.assert_allclose(u, [1.0, 1.0, math.sqrt(0.18 * 9.81 / 3.28)], atol=1e-12)
    assert abs(u[2] - 0.733) < 1e-3
    # the rotation limit binds when the body turns fast: u_d = min(u_R, r(omega_b))
    assert profile_speed(0.0, 1.9, 2.0, 0.18, 9.81, omega_b=5.0) == pytest.approx(0.925)


def test_velocity_profile_lookahead(eight):
    """Look-ahead points follow the profile: spacing u Ts (to first order), >= N steps."""
    table = PathTable(eight)
    prof = VelocityProfile(table, lambda k: profile_speed(k, 1.0, 1.315, 0.18, 9.81))
    s, u, k = prof.lookahead(2.0, 15, 0.05)
    assert len(s) == 16 and np.all(np.diff(s) > 0)
    np.testing.assert_allclose(np.diff(s), 0.05 * 0.5 * (u[1:] + u[:-1]), rtol=0.02)
    assert np.all(u <= np.sqrt(0.18 * 9.81 / np.maximum(np.abs(k), 1e-9)) + 1e-4)
    assert u.max() <= 1.0 + 1e-12 and prof.u.min() == pytest.approx(0.733, abs=2e-3)
    s2, _, _ = prof.lookahead(2.0 + eight.length, 15, 0.05)  # wraps on the closed path
    np.testing.assert_allclose(s2 - eight.length, s, atol=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_unicycle_error_dynamics_match_kinematics(seed):
    """(4.38)-(4.41) on the unit circle of E4.4, with v = v_d + eta and a = v-dot."""
    rng = np.random.default_rng(seed)
    path = circle(1.0)
    s = rng.uniform(0, path.length)
    pose = _frame(path, s) + np.array([*rng.normal(0, 0.2, 2), rng.normal(0, 0.4)])
    v0, omega, a, sdot = rng.uniform(0, 1), rng.normal(0, 1), rng.normal(0, 1), rng.uniform(0, 1)
    v_d, vdot_d = 0.5, 0.1

    def err(t):
        # constant a and omega: integrate (3.3) with a fine RK4 over t
        n = 40
        x = np.array([*pose, v0])
        h = t / n
        f = lambda z: np.array([z[3] * math.cos(z[2]), z[3] * math.sin(z[2]), omega, a])  # noqa: E731
        for _ in range(n):
            k1 = f(x)
            k2 = f(x + h / 2 * k1)
            k3 = f(x + h / 2 * k2)
            k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return uni_errors(x[:3], _frame(path, s + sdot * t), x[3], v_d + vdot_d * t)

    fd = (err(1e-5) - err(-1e-5)) / 2e-5
    model = _num(uni_error_dynamics(err(0.0), sdot, omega, a, v_d, vdot_d, 1.0))
    np.testing.assert_allclose(model, fd, atol=1e-4)


def test_unicycle_terminal_law_inverts_virtual_inputs():
    """(4.50)-(4.51) read as docs/reference/ambiguities.md, terminal-law commands (A9): u_e(terminal commands) =
    -(alpha x, beta theta, gamma eta)."""
    xe = np.array([0.2, -0.1, 0.3, -0.05])
    gains, k, v_d, vdot_d = (2.5, 1.0, 1.0), 1.0, 0.5, 0.0
    sdot, om, a = terminal_law(xe, v_d, vdot_d, k, gains)
    ue = _num(uni_virtual_inputs(xe, sdot, om, a, v_d, vdot_d, k))
    np.testing.assert_allclose(ue, [-2.5 * 0.2, -1.0 * 0.3, -1.0 * -0.05], atol=1e-12)


def test_obstacle_cost_magnitudes_and_scan_points():
    """(4.54) with (4.55): about 0.55 at 0.1 m and 0.01 at 0.5 m straight ahead
    (docs/reference/derivations.md, obstacle cost magnitude (D8))."""
    pose = np.array([0.0, 0.0, 0.0])
    c01 = float(obstacle_cost(pose, [[0.1, 0.0]], [1.0], 1.5, 0.01, 10.0))
    c05 = float(obstacle_cost(pose, [[0.5, 0.0]], [1.0], 1.5, 0.01, 10.0))
    assert c01 == pytest.approx(1.5 * math.exp(-1.0), rel=1e-3) and c05 == pytest.approx(0.0101, rel=2e-2)
    assert float(obstacle_cost(pose, [[0.0, 0.1]], [1.0], 1.5, 0.01, 10.0)) < c01  # bearing decay
    angles = np.deg2rad(np.arange(0, 360, 30))
    ranges = np.full(12, np.inf)
    ranges[3] = 0.2  # 90 deg
    pts, w = scan_points([1.0, 2.0, math.pi / 2], ranges, angles, 0.06, 12)
    assert w.sum() == 1 and w[3] == 1
    np.testing.assert_allclose(pts[3], [1.0 - 0.26, 2.0], atol=1e-12)  # rim range + radius


def test_path_table_matches_path(eight):
    table = PathTable(eight)
    s = np.linspace(-3.0, 30.0, 333)
    geo = table(s)
    x, y, th, k = eight.frame(s)
    np.testing.assert_allclose(geo[0], x, atol=1e-6)
    np.testing.assert_allclose(geo[1], y, atol=1e-6)
    np.testing.assert_allclose(geo[2], th, atol=1e-5)
    np.testing.assert_allclose(geo[3], k, atol=1e-4)


# -- shared MPC scaffolding (copath/mpc.py) ------------------------------------------


def _double_integrator(N=10, **kw):
    return OCP(nx=2, nu=1, N=N, dt=0.1, dynamics=lambda x, u, p: ca.vertcat(x[1], u[0]),
               stage_residual=lambda x, u, p: ca.vertcat(x[0], x[1], 0.1 * u[0]),
               terminal_residual=lambda x, p: 3 * x, u_lb=[-1.0], u_ub=[1.0], **kw)


@pytest.fixture(scope="module")
def di_solver():
    return MPCSolver(_double_integrator(x_lb=[-5.0, -0.5], x_ub=[5.0, 0.5]), SolverConfig(jit=False))


def test_mpc_closed_loop_converges_with_bounds(di_solver):
    di_solver.reset()
    x = np.array([1.0, 0.0])
    for _ in range(80):
        res = di_solver.solve(x)
        assert res.ok and res.fallback is None
        assert abs(res.u0[0]) <= 1.0 + 1e-9 and np.all(np.abs(res.x[1:, 1]) <= 0.5 + 1e-6)
        x = x + 0.1 * np.array([x[1] + 0.05 * res.u0[0], res.u0[0]])  # exact for constant u
    assert np.linalg.norm(x) < 1e-3


def test_mpc_warm_start_is_the_shifted_plan(di_solver):
    di_solver.reset()
    res = di_solver.solve([1.0, 0.0])
    X, U = di_solver.shifted_plan()
    np.testing.assert_allclose(U[:-1], res.u[1:])
    np.testing.assert_allclose(X[:-1], res.x[1:])


def test_mpc_fallback_shifted_then_stop(di_solver):
    di_solver.reset()
    good = di_solver.solve([1.0, 0.0])
    assert good.ok
    # a state violating the hard bound |x_2| <= 0.5 beyond what the input can fix: infeasible
    bad = di_solver.solve([0.0, 3.0])
    assert not bad.ok and bad.fallback == "shifted"
    np.testing.assert_allclose(bad.u0, good.u[1])
    for _ in range(12):
        bad = di_solver.solve([0.0, 3.0])
    assert not bad.ok and bad.fallback == "stop" and np.all(bad.u == 0.0)


def test_mpc_soft_terminal_constraint_and_parameters():
    """Soft terminal rows get slack only when needed; parameters reach the dynamics."""
    ocp = OCP(nx=1, nu=1, N=5, dt=0.1, dynamics=lambda x, u, p: p[0] * u[0],
              stage_residual=lambda x, u, p: ca.vertcat(0.1 * u[0]), n_p=1,
              soft_terminal=lambda x, u, p: x, hT_lb=[0.2], hT_ub=[0.3], u_lb=[-1], u_ub=[1])
    m = MPCSolver(ocp, SolverConfig(jit=False))
    res = m.solve([0.0], p_stage=np.ones((5, 1)))  # reachable: x_N = 0.2 with sum u dt = 0.2
    assert res.ok and 0.2 - 1e-4 <= res.x[-1, 0] <= 0.3 + 1e-4 and res.slack.max() < 1e-4
    res = m.solve([0.0], p_stage=np.full((5, 1), 0.1))  # gain 0.1: at most 0.05 reachable
    assert res.ok and res.slack.max() > 0.1 and res.x[-1, 0] == pytest.approx(0.05, abs=1e-3)
    # bounds of one solve: the region moved within reach needs no slack; the next solve has the OCP's again
    res = m.solve([0.0], p_stage=np.full((5, 1), 0.1), hT_lb=[0.0], hT_ub=[0.04])
    assert res.ok and res.slack.max() < 1e-4 and res.x[-1, 0] <= 0.04 + 1e-4
    res = m.solve([0.0], p_stage=np.full((5, 1), 0.1))
    assert res.ok and res.slack.max() > 0.1


def test_solver_config_validation():
    with pytest.raises(ConfigError):
        SolverConfig(method="magic")
    with pytest.raises(ConfigError):
        SolverConfig(qp_solver="none")


def test_omni_pf_nmpc_solution_respects_wheel_box(eight):
    """Wheel speeds are decision variables: the limit (3.2) is an exact box."""
    from agent.controllers.omni_nmpc.controller import OmniPathFollowingNMPC

    model = OmniModel()
    n = OmniPathFollowingNMPC(eight, model, 5, 0.07, [0.5] * 3, [0.1] * 3, [2.0] * 3, solver=SolverConfig(jit=False))
    sol = n.solve([0.5, -0.4, 2.0], 0.0, 1.8)  # far off and asking for more than the wheels give
    assert sol.ok
    wheels = np.array([model.wheel_speeds(n.Minv @ q) for q in sol.result.u[:, :3]])
    assert np.abs(wheels).max() <= model.qdot_max + 1e-6
    np.testing.assert_allclose(model.wheel_speeds(sol.body), sol.wheels, atol=1e-9)
    assert sol.sdot.shape == (5,) and np.all(sol.sdot >= -1e-9)
    assert wrap_to_pi(0.0) == 0.0


def test_ltv_qp_fallback_on_infeasible_bounds():
    """An infeasible QP (lb > ub) never raises: shifted previous plan, else clipped zeros."""
    N = 3
    qp = LTVPathFollowingQP(N, 0.05, [300, 300, 7, 70], [1, 0.001, 3], jit=False)
    xe, kap, uR = np.array([0.05, -0.03, 0.02, 0.01]), np.full(N, 1.0), np.full(N, 1.0)
    good = qp.solve(xe, kap, uR, np.full(3 * N, -1.0), np.full(3 * N, 1.0))
    assert good.ok
    lb, ub = np.full(3 * N, 0.5), np.full(3 * N, -0.5)
    bad = qp.solve(xe, kap, uR, lb, ub)
    assert not bad.ok
    np.testing.assert_allclose(bad.U[0], np.clip(good.U[1], 0.5, -0.5))
    for _ in range(3):
        bad = qp.solve(xe, kap, uR, lb, ub)
    assert not bad.ok and np.all(np.isfinite(bad.U))
