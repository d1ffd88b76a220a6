"""The MPC scaffolding's alternative solver paths run the same controllers."""

from copath.scenario import load_scenario
from orchestrator.run.inprocess import run_scenario
from tests.conftest import config


def test_ipopt_with_gauss_newton_hessian_follows_the_eight_curve():
    s = load_scenario(config("e4.2-")).with_overrides(
        controller={"solver": "ipopt", "hessian": "gauss-newton", "jit": False}, run={"settle_s": 3.0})
    m = run_scenario(s, duration_s=6.0).metrics["robots"]["r1"]
    assert m["solver_failures"] == 0
    assert m["path_error_max_m"] < 0.05 and m["limit_violations"] == 0
