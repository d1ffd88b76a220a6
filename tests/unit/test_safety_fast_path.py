"""The safety filter's pass-through test on floats (``SafetyFilter._clear``, docs/reference/performance.md
against IR-SIM (P15)) decides as the full test on the QP's rows: it passes only where the rows hold, and then
returns the same smallest barrier; the filter's result is the one of the full path. The guard's tubes
and neighbour discs on floats (docs/journal/performance.md, safety filter second pass (P19)) are the
numbers of the array and scalar functions, and decide as they do."""

from __future__ import annotations

import math

import numpy as np
import pytest

from copath.models import OmniModel, UnicycleModel
from copath.safety import (TUBE_MARGIN_M, GuardConfig, Neighbour, SafetyConfig, SafetyFilter, SafetyGuard, SafetyResult, Tube,
                           commit_radius, plan_velocity, predict_position, prediction_bound)

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


def _reference_apply(g: SafetyGuard, pose, command, now: float) -> tuple[SafetyResult, int, float]:
    """The guard's step as it was before its tubes were computed on floats: every tube as
    arrays, the broken ones (centre outside by any amount) counted and dropped, the rest to the
    filter's test on arrays."""
    tubes = g.tube_set(now)
    breaks, excess = 0, 0.0
    if len(tubes):
        d = np.array([float(pose[0]), float(pose[1])])[None, :] - tubes.centre
        gap = tubes.radius + TUBE_MARGIN_M - np.hypot(d[:, 0], d[:, 1])
        if gap.min() < 0:
            breaks, excess = 1, float(-gap.min())
            tubes = tubes.select(gap >= 0)
    return g.filter.filter(pose, command, g.neighbours(now), None, None, tubes), breaks, excess


@pytest.mark.parametrize("model", [UnicycleModel(a_max=0.3, alpha_max=1.0), UnicycleModel(), OmniModel()])
@pytest.mark.parametrize("braking", [True, False])
def test_guard_tubes_on_floats_decide_as_the_arrays(model, braking):
    """The guard's committed tubes computed on floats (the pass-through test's rooms and the
    test of a broken tube by a margin) give the filter's result and the break counters of the
    exact test on the tubes' arrays, in cases inside, near the edge of and outside a tube."""
    cfg = SafetyConfig(enabled=True, commit_accel_mps2=0.1, braking=braking)
    dt = 0.05 if isinstance(model, OmniModel) else 0.1
    models = {"a": model, "b": model}
    rng = np.random.default_rng(11)
    kinds = {"pass": 0, "blocked": 0, "broken": 0}
    for case in range(150):
        g = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=dt))
        x, y, th = 0.0, 0.0, float(rng.uniform(-math.pi, math.pi))
        v, w = float(rng.uniform(0.0, 0.4)), float(rng.uniform(-0.5, 0.5))
        odd = case % 3 == 0  # plans the robot does not follow (a straight one, a standing one)
        for k in range(int(rng.integers(1, 30))):  # plans along the robot's own arc, with noise
            if case % 10 == 0 and k == 3:
                g.published(k * dt - 0.5, (x, y), (0.1, 0.0, 0.0))  # one stamp out of order
            vel = (v * math.cos(th) + float(rng.normal(0, 0.002)), v * math.sin(th) + float(rng.normal(0, 0.002)),
                   0.0 if odd and k % 7 == 0 else w)
            g.published(k * dt, (x, y), (0.0, 0.0, w) if odd and k % 11 == 5 else vel)
            (x, y), th = predict_position((x, y), (v * math.cos(th), v * math.sin(th), w), dt), th + w * dt
        now = k * dt + dt
        if rng.random() < 0.5:
            g.hear("b", (x + float(rng.uniform(-1, 1)), y + float(rng.uniform(-1, 1))), now - dt, (0.1, 0.0, 0.0))
        off = float(rng.choice([0.0, 0.0, 0.002, 0.01, 0.1]))
        pose = (x + off * float(rng.normal()), y + off * float(rng.normal()), th)
        size = 3 if isinstance(model, OmniModel) else 2
        command = np.r_[v + float(rng.normal(0, 0.1)), rng.normal(0, 0.3, size - 1)]
        want, breaks, excess = _reference_apply(g, pose, command, now)
        got = g.apply(pose, command, now)
        assert np.array_equal(got.command, want.command)
        assert (got.active, got.change, got.slack, got.min_barrier, got.ok, got.biased) == (
            want.active, want.change, want.slack, want.min_barrier, want.ok, want.biased)
        assert g.commit_breaks == breaks and g.commit_excess_max == excess
        kinds["broken" if breaks else ("blocked" if got.active else "pass")] += 1
    assert min(kinds.values()) > 5, kinds  # every branch exercised


def test_neighbour_discs_are_the_scalar_functions():
    """A committed or predicted neighbour's disc is the one :func:`commit_radius`,
    :func:`prediction_bound`, :func:`plan_velocity` and :func:`predict_position` give, bit for bit."""
    cfg = SafetyConfig(enabled=True, commit_accel_mps2=0.1, commit_speed_mps=0.02)
    dt = 0.1
    models = {"a": UnicycleModel(a_max=0.3, alpha_max=1.0), "b": UnicycleModel(a_max=0.3, alpha_max=1.0),
              "c": UnicycleModel(a_max=0.3), "d": UnicycleModel()}
    g = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=dt))
    rng = np.random.default_rng(3)
    checked = 0
    for k in range(300):
        stamp = k * 0.01
        for name in ("b", "c", "d"):
            vel = (float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.5, 0.5)), 0.0 if k % 9 == 0 else float(rng.uniform(-1, 1)))
            if k % 13 == 0:
                vel = (0.0, 0.0, vel[2])
            g.hear(name, (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3))), stamp, vel)
        now = stamp + float(rng.choice([0.0, 0.05, 0.3, 1.0, 2.4, 3.0]))
        for nb, name in zip(g.neighbours(now), ("b", "c", "d")):
            pos, vel = g._heard[name][:2], g._vel[name]
            age = max(now - stamp, 0.0)
            a_max, alpha_max, w_bound = g._limits[name]
            if nb.committed is not None:
                spread = commit_radius(cfg, age)
                if a_max is not None:
                    spread = min(spread, prediction_bound(age, math.hypot(vel[0], vel[1]), a_max, alpha_max, w_bound, dt))
                cv = plan_velocity(vel, age)
                speed = math.hypot(vel[0], vel[1])
                assert nb.position == predict_position(pos, vel, age) and nb.spread == spread
                assert nb.committed == (cv[0], cv[1], cfg.commit_speed_mps + cfg.commit_accel_mps2 * age,
                                        speed * abs(vel[2]) + cfg.commit_accel_mps2)
                checked += 1
            elif nb.predicted:
                assert nb.position == predict_position(pos, vel, age)
                assert nb.spread == prediction_bound(age, math.hypot(vel[0], vel[1]), a_max, alpha_max, w_bound, dt)
            else:
                assert nb.position == pos
    assert checked > 100
