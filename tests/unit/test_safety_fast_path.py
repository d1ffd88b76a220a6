"""The safety filter's pass-through test on floats (``SafetyFilter._clear``, docs/reference/performance.md
against IR-SIM (P15)) decides as the full test on the QP's rows: it passes only where the rows hold, and then
returns the same smallest barrier; the filter's result is the one of the full path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from copath.models import OmniModel, UnicycleModel
from copath.safety import Neighbour, SafetyConfig, SafetyFilter, SafetyResult, Tube

CFG = SafetyConfig(enabled=True)
COMMIT = SafetyConfig(enabled=True, commit_accel_mps2=0.1)


def _full(f: SafetyFilter, pose, nominal, nbrs, tubes) -> SafetyResult:
    """The filter with the pass-through test switched off (every case through the rows)."""
    keep = f._clear
    f._clear = lambda *a, **k: None
    try:
        return f.filter(pose, nominal, nbrs, tubes=tubes)
    finally:
        f._clear = keep


def _case(model, rng, close: bool):
    pose = np.r_[rng.uniform(-0.2, 0.2, 2), rng.uniform(-math.pi, math.pi)]
    nbrs = []
    for _ in range(rng.integers(0, 7)):
        d = rng.uniform(0.15, 0.6) if close else rng.uniform(0.15, 4.0)
        a = rng.uniform(-math.pi, math.pi)
        age = float(rng.choice([0.0, 0.1, 0.3, 1.0, 3.0]))
        committed = None
        if rng.random() < 0.3:
            committed = (float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3)), 0.02, 0.1)
        nbrs.append(Neighbour((pose[0] + d * math.cos(a), pose[1] + d * math.sin(a)), age, model.radius,
                              0.5, float(rng.uniform(0.0, 0.1)) if rng.random() < 0.5 else None,
                              0.05 if isinstance(model, UnicycleModel) else 0.0, bool(rng.random() < 0.5), committed))
    tubes = [Tube((pose[0] + rng.uniform(-0.02, 0.02), pose[1] + rng.uniform(-0.02, 0.02)),
                  (float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3))), float(rng.uniform(0.02, 0.2)),
                  float(rng.uniform(0.0, 0.3))) for _ in range(rng.integers(0, 5))]
    size = 3 if isinstance(model, OmniModel) else 2
    nominal = rng.uniform(-0.6, 0.6, size)
    return pose, nominal, nbrs, tubes


@pytest.mark.parametrize("model,dt", [(UnicycleModel(a_max=0.3, alpha_max=1.0), 0.1), (UnicycleModel(), 0.1),
                                      (OmniModel(), 0.05)])
@pytest.mark.parametrize("cfg", [CFG, COMMIT, SafetyConfig(enabled=True, braking=False, lookahead_m=0.0)])
def test_pass_through_test_decides_as_the_full_test(model, dt, cfg):
    rng = np.random.default_rng(7)
    f = SafetyFilter(cfg, model, dt)
    passed = blocked = 0
    for i in range(400):
        pose, nominal, nbrs, tubes = _case(model, rng, close=i % 2 == 0)
        u_sat, _ = model.saturate(nominal)
        A, rhs, _, h_min = f.constraints(pose, nbrs, tubes=tubes)
        fast = f._clear(pose, nbrs, None, None, tubes, u_sat)
        if fast is not None:
            passed += 1
            assert np.all(A @ u_sat >= rhs - 1e-12)  # never passes where a row fails
            assert fast == h_min
        else:
            blocked += 1
        got, want = f.filter(pose, nominal, nbrs, tubes=tubes), _full(f, pose, nominal, nbrs, tubes)
        assert got.active == want.active and got.min_barrier == want.min_barrier
        assert np.array_equal(got.command, want.command) and got.change == want.change
    assert passed > 50 and blocked > 50  # both branches exercised


def test_range_readings_take_the_full_test():
    f = SafetyFilter(CFG, UnicycleModel(), 0.1)
    assert f._clear([0.0, 0.0, 0.0], [], np.array([1.0, np.inf]), np.array([0.0, 1.0]), [], np.array([0.1, 0.0])) is None
