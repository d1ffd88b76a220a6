"""Sec. 5.4 DMPC pieces: assumed trajectories (Algorithm 5.1), their interpolation and
extrapolation, the terminal-controller tail, and the compatibility constraint of (5.18)."""

import math

import numpy as np
import pytest

from copath.control import Observation, PeerMessage, RobotContext
from agent.controllers.dmpc import build
from agent.controllers.dmpc.controller import AssumedTrajectory, DMPCController, assumed_trajectory, terminal_rollout
from copath.config import ConfigError
from copath.models import OmniModel
from copath.paths import ellipse

PATH = ellipse(1.5, 1.0, rotation=math.pi / 6)
DT = 0.05


def _ctx(name="r1", neighbours=("r2",), **params) -> RobotContext:
    base = {"formation": {"r1": 0.0, "r2": -0.4}, "q": -0.4}
    base.update(params)
    return RobotContext(name=name, index=0, model=OmniModel(), paths={"main": PATH}, path="main",
                        neighbours=neighbours, robots=("r1", "r2"), dt=DT, params=base)


def test_interpolation_inside_and_linear_extrapolation_outside():
    tr = AssumedTrajectory(t0=10.0, dt=0.1, values=np.array([1.0, 1.04, 1.10, 1.20]))
    np.testing.assert_allclose(tr.at([10.0, 10.05, 10.25, 10.3]), [1.0, 1.02, 1.15, 1.2])
    # past the end: last slope (1.0 m/s); before the start: first slope (0.4 m/s)
    np.testing.assert_allclose(tr.at([10.5, 9.9]), [1.4, 0.96])
    np.testing.assert_allclose(tr.scaled(2.0).at(10.05), 2.04)
    with pytest.raises(ValueError):
        AssumedTrajectory(0.0, 0.1, np.array([1.0]))


def test_assumed_trajectory_is_shifted_plan_plus_terminal_tail():
    s_plan = np.array([2.0, 2.02, 2.04, 2.06])
    tr = assumed_trajectory(5.0, DT, s_plan, 2.081)
    assert tr.t0 == 5.0 and tr.dt == DT and tr.t_end == pytest.approx(5.0 + 4 * DT)
    np.testing.assert_allclose(tr.values, [2.0, 2.02, 2.04, 2.06, 2.081])
    # on the next update's grid t_k+1 + j dt it starts at s*(t_k+1; t_k)
    np.testing.assert_allclose(tr.at(5.0 + DT + DT * np.arange(3)), [2.02, 2.04, 2.06])


def test_terminal_controller_tail_moves_at_the_desired_speed():
    """At the equilibrium the terminal laws of (5.21) give sdot = u_o; an x_e > 0 speeds s up."""
    x_eq = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0])
    s = terminal_rollout(x_eq, kappa=1.2, q=-0.4, u_o=0.4, k_terminal=(0.5, 0.5, 0.5, 0.5), duration=0.1)
    assert s[-1] == pytest.approx(3.0 + 0.04, abs=1e-9)
    ahead = x_eq.copy()
    ahead[0] = 0.2  # robot ahead of its reference point
    s2 = terminal_rollout(ahead, kappa=0.0, q=0.0, u_o=0.4, k_terminal=(0.5, 0.5, 0.5, 0.5), duration=0.1)
    assert s2[-1] > s[-1]


@pytest.fixture(scope="module")
def tight():
    """A robot whose neighbour announces progress far ahead: the coupling pulls hard."""
    return build(_ctx(mu=2.0))


@pytest.fixture(scope="module")
def loose():
    return build(_ctx(mu=1000.0))


def _drive(ctrl: DMPCController, steps=40):
    """Step a robot on its slot while neighbour r2 claims to be 1 m ahead; return the
    largest |s_plan - s_hat| over k >= 1 of every update after the first."""
    pose = np.array([*PATH.pos(0.0), PATH.theta(0.0)])
    x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
    pose = np.array([x + 0.4 * math.sin(th), y - 0.4 * math.cos(th), th])  # q = -0.4
    worst = 0.0
    model = OmniModel()
    for k in range(steps):
        t = k * DT
        nb = PeerMessage("r2", "assumed_traj", t - DT, DT,
                         {"t0": t - DT, "dt": DT, "s_hat": list(1.0 - 0.4 + 0.4 * DT * np.arange(12)),
                          "psi_scale": 1.0})
        prev = ctrl.own_assumed
        res = ctrl.step(Observation(t=t, pose=pose, dt=DT), [nb])
        assert res.telemetry["solver_ok"], k
        if prev is not None:
            new = ctrl.own_assumed
            grid = t + DT * np.arange(1, ctrl.cfg.horizon)
            worst = max(worst, float(np.max(np.abs(new.at(grid) - prev.at(grid)))))
        pose = model.step(pose, res.command, DT)
    return worst


def test_compatibility_constraint_holds_and_binds(tight, loose):
    bound = DT**2 * tight.cfg.mu  # delta^2 mu = 0.005 m
    dev_tight = _drive(tight)
    dev_loose = _drive(loose)
    assert dev_tight <= bound + 1e-4
    # without a binding bound the same pull moves the plan further: the constraint is active
    assert dev_loose > 2 * bound


def test_neighbour_messages_newest_wins_and_wrap_near_own_progress():
    ctrl = build(_ctx())
    L = PATH.length
    old = PeerMessage("r2", "assumed_traj", 1.0, 0.05, {"t0": 1.0, "dt": DT, "s_hat": [5.0, 5.02], "psi_scale": 1.0})
    new = PeerMessage("r2", "assumed_traj", 2.0, 0.05, {"t0": 2.0, "dt": DT, "s_hat": [L + 0.1, L + 0.12]})
    ctrl._receive([new, old], 2.05)  # out of order: the older one must not replace the newer
    stamp, traj = ctrl.neighbour_traj["r2"]
    assert stamp == 2.0 and traj.values[0] == pytest.approx(L + 0.1)
    # a lap ahead on the closed path is the same place
    np.testing.assert_allclose(ctrl._wrap_near(np.array([L + 0.1]), np.array([0.0])), [0.1])
    # a robot that is not a neighbour reaches the controller only as a stand-in for a lost one
    # (the runtime's choice, docs/reference/faults.md, "Stand-ins for a lost neighbour"): coupled
    # while its trajectory is fresh, in a problem built for one more term, then dropped again
    stand_in = PeerMessage("r3", "assumed_traj", 3.0, 0.05, {"t0": 3.0, "dt": DT, "s_hat": [1.0, 1.1]})
    ctrl._receive([stand_in], 3.05)
    assert "r3" in ctrl.neighbour_traj
    one = ctrl.mpc
    assert ctrl._slots(3.05) == ("r2", "r3") and ctrl.mpc is not one and ctrl.mpc.ocp.n_p == one.ocp.n_p + 2
    assert ctrl._slots(3.0 + ctrl.cfg.stale_after_s + 0.1) == ("r2",) and ctrl.mpc is one


def test_lost_neighbour_leaves_the_robot_working():
    """No neighbour message at all (lost): the coupling is dropped, the robot still follows."""
    ctrl = build(_ctx())
    pose = np.array([1.9, 0.9, 2.1])
    model = OmniModel()
    for k in range(60):
        res = ctrl.step(Observation(t=k * DT, pose=pose, dt=DT), [])
        assert res.telemetry["neighbours_used"] == 0
        ref = np.array(res.telemetry["ref"][:2])  # the reference of this step's pose
        error = float(np.hypot(*(pose[:2] - ref)))
        pose = model.step(pose, res.command, DT)
    assert error < 0.01
    assert res.telemetry["sdot"] == pytest.approx(0.4, abs=0.05)


def test_offset_beyond_curvature_radius_is_refused():
    with pytest.raises(ConfigError, match="cusp"):
        build(_ctx(q=0.7))  # the ellipse's kappa_max = 1.5 1/m: |q| < 0.67 m
