"""The time cap of an MPC solve (docs/reference/controllers.md, "Solve time cap"): a realtime
solve that runs past its cap stops, falls back (Sec. 2.2's shifted plan, else stop) and is put
on the timeline; lockstep solves are never capped."""

import dataclasses
import math

import numpy as np
import pytest

from agent.controllers.dmpc import build
from agent.stages import ControlStage, Counters
from copath.control import Observation, RobotContext
from copath.models import OmniModel
from copath.mpc import OCP, MPCSolver, SolverConfig
from copath.paths import ellipse

PATH = ellipse(1.5, 1.0, rotation=math.pi / 6)
DT = 0.05


def _ocp() -> OCP:
    import casadi as ca  # noqa: PLC0415

    return OCP(nx=2, nu=1, N=10, dt=0.1, dynamics=lambda x, u, p: ca.vertcat(x[1], u[0]),
               stage_residual=lambda x, u, p: ca.vertcat(x[0], 0.1 * u[0]),
               terminal_residual=lambda x, p: x, u_lb=[-1.0], u_ub=[1.0])


def test_a_capped_solve_falls_back_and_is_counted():
    mpc = MPCSolver(_ocp(), SolverConfig(jit=False, max_solve_s=30.0))
    first = mpc.solve([1.0, 0.0])
    assert first.ok and not first.timed_out and mpc.timeouts == 0
    mpc.config = dataclasses.replace(mpc.config, max_solve_s=1e-9)  # every solve is over its cap
    capped = mpc.solve([0.9, -0.1])
    assert capped.timed_out and not capped.ok and capped.fallback == "shifted"
    np.testing.assert_allclose(capped.u[0], first.u[1])  # the previous plan, shifted by one step
    assert "time cap" in capped.status and mpc.timeouts == 1 and mpc.failures == 1
    fresh = MPCSolver(_ocp(), SolverConfig(jit=False, max_solve_s=1e-9)).solve([1.0, 0.0])
    assert fresh.timed_out and fresh.fallback == "stop" and np.all(fresh.u == 0.0)


def test_a_cap_far_above_the_solve_changes_nothing():
    plain = MPCSolver(_ocp(), SolverConfig(jit=False))
    capped = MPCSolver(_ocp(), SolverConfig(jit=False, max_solve_s=30.0))
    assert plain._cap is None and capped._cap is not None
    x = np.array([1.0, 0.0])
    for _ in range(5):
        a, b = plain.solve(x), capped.solve(x)
        assert a.ok and b.ok and not b.timed_out
        np.testing.assert_array_equal(a.u, b.u)
        np.testing.assert_array_equal(a.x, b.x)
        x = a.x[1]


def _ctx(realtime: bool, **params) -> RobotContext:
    base = {"formation": {"r1": 0.0, "r2": -0.4}, "q": -0.4, **params}
    return RobotContext(name="r1", index=0, model=OmniModel(), paths={"main": PATH}, path="main",
                        neighbours=("r2",), robots=("r1", "r2"), dt=DT, params=base, realtime=realtime)


def test_the_dmpc_is_capped_in_realtime_only():
    assert build(_ctx(False)).mpc.config.max_solve_s is None
    assert build(_ctx(True)).mpc.config.max_solve_s == pytest.approx(4 * DT)
    assert build(_ctx(True, max_solve_periods=0)).mpc.config.max_solve_s is None


def test_a_dmpc_solve_over_its_cap_is_an_event_and_the_robot_stops():
    ctl = build(_ctx(True, max_solve_periods=1e-9))
    counters = Counters()
    stage = ControlStage(ctl, "r1", 3, counters)
    pose = np.array([*np.asarray(PATH.pos(0.3), float).reshape(-1)[:2], 0.5])
    res = stage.step(Observation(t=0.0, pose=pose, dt=DT), [], 0, 0.0)
    assert res.command == [0.0, 0.0, 0.0]  # no plan yet: the fallback is stop
    assert res.failure is not None and res.failure.what == "solve_timeout"
    assert res.failure.detail["fallback"] == "stop" and res.failure.detail["cap_s"] == pytest.approx(1e-9 * DT)
    assert counters.as_dict()["solve_timeouts"] == 1 and counters.controller_errors == 0


def test_a_robot_knows_its_run_is_realtime_from_the_scenario():
    from copath.scenario import load_scenario  # noqa: PLC0415
    from tests.conftest import config  # noqa: PLC0415

    scen = load_scenario(config("e5.2-dmpc-ellipse-triangle"))
    assert not RobotContext.for_robot(scen, "r1").realtime
    assert RobotContext.for_robot(scen.with_overrides(run={"clock": "realtime"}), "r1").realtime
