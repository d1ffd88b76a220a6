"""Unit tests of the decentralised safety filter (copath.safety)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from copath.config import ConfigError, from_table
from copath.models import OmniModel, UnicycleModel
from copath.safety import HELD_DEADBAND_RAD, GuardConfig, Neighbour, SafetyConfig, SafetyFilter, SafetyGuard, max_speed

CFG = SafetyConfig(enabled=True)


def _pair_run(model, cmd, pose_a, pose_b, dt, steps, cfg=CFG, age=None):
    """Two robots driving at each other, each filtering with what the other sent one tick ago."""
    fa, fb = SafetyFilter(cfg, model, dt), SafetyFilter(cfg, model, dt)
    pa, pb = np.array(pose_a, float), np.array(pose_b, float)
    age = dt if age is None else age
    s = max_speed(model)
    dmin, results = math.inf, []
    prev_a, prev_b = pa.copy(), pb.copy()
    for _ in range(steps):
        ra = fa.filter(pa, cmd, [Neighbour(tuple(prev_b[:2]), age, model.radius, s)])
        rb = fb.filter(pb, cmd, [Neighbour(tuple(prev_a[:2]), age, model.radius, s)])
        results += [ra, rb]
        prev_a, prev_b = pa.copy(), pb.copy()
        pa = model.step(pa, model.saturate(ra.command)[0], dt)
        pb = model.step(pb, model.saturate(rb.command)[0], dt)
        dmin = min(dmin, float(np.hypot(*(pa[:2] - pb[:2]))))
    return dmin, results


def test_safe_nominal_command_passes_unchanged():
    f = SafetyFilter(CFG, OmniModel(), 0.05)
    nominal = np.array([0.3, -0.1, 0.2])
    far = [Neighbour((3.0, 0.0), 0.05, 0.2, 2.0), Neighbour((0.0, -2.5), 0.5, 0.2, 2.0)]
    res = f.filter([0.0, 0.0, 0.4], nominal, far)
    assert not res.active and res.change == 0.0
    assert res.command is not None and np.array_equal(res.command, nominal)
    # moving away from a close neighbour is safe too
    res = f.filter([0.0, 0.0, 0.0], [-0.5, 0.0, 0.0], [Neighbour((0.5, 0.0), 0.05, 0.2, 0.5)])
    assert not res.active and np.array_equal(res.command, [-0.5, 0.0, 0.0])
    # a nominal command beyond the limits is left to the model's saturation when it is safe
    fu = SafetyFilter(CFG, UnicycleModel(), 0.1)
    res = fu.filter([0.0, 0.0, 0.0], [2.0, 0.0], [Neighbour((-3.0, 0.0), 0.1, 0.06, 0.5)])
    assert not res.active and np.array_equal(res.command, [2.0, 0.0])


def test_no_neighbours_no_ranges_is_identity():
    f = SafetyFilter(CFG, UnicycleModel(), 0.1)
    res = f.filter([1.0, 2.0, 0.3], [0.4, -0.7])
    assert not res.active and np.array_equal(res.command, [0.4, -0.7])


@pytest.mark.parametrize("model,dt,cmd", [
    (OmniModel(), 0.05, [1.0, 0.0, 0.0]),
    (UnicycleModel(), 0.1, [0.5, 0.0]),
])
def test_head_on_robots_are_kept_apart(model, dt, cmd):
    # exactly head-on, in each robot's body frame the nominal drives straight at the other
    dmin, results = _pair_run(model, cmd, [0.0, 0.0, 0.0], [2.0, 0.0, math.pi], dt, steps=int(8 / dt))
    assert dmin >= 2 * model.radius  # discs never overlap
    assert any(r.active for r in results)  # and the filter had to act
    # without the filter they would have collided (anti-triviality)
    pa, pb = np.array([0.0, 0.0, 0.0]), np.array([2.0, 0.0, math.pi])
    d0 = math.inf
    for _ in range(int(8 / dt)):
        pa, pb = model.step(pa, model.saturate(cmd)[0], dt), model.step(pb, model.saturate(cmd)[0], dt)
        d0 = min(d0, float(np.hypot(*(pa[:2] - pb[:2]))))
    assert d0 < 2 * model.radius


def test_head_on_with_stale_positions_is_kept_apart():
    # positions 0.3 s old (delay) at 0.1 s period: the filter inflates by the distance moved
    model = OmniModel()
    cfg = SafetyConfig(enabled=True, speed_max_mps=1.0)
    dmin, _ = _pair_run(model, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [3.0, 0.02, math.pi], 0.1, 80, cfg, age=0.3)
    assert dmin >= 2 * model.radius


def test_unicycle_filter_without_lookahead_changes_only_the_forward_speed():
    # lookahead_m = 0: the centre of a unicycle moves along its heading, so the barrier constrains
    # v and omega stays nominal
    model = UnicycleModel()
    cfg = SafetyConfig(enabled=True, lookahead_m=0.0)
    dmin, results = _pair_run(model, [0.3, 0.1], [0.0, 0.02, 0.0], [0.6, 0.0, math.pi], 0.1, 60, cfg)
    assert dmin >= 2 * model.radius
    active = [r for r in results if r.active]
    assert active and all(r.command[1] == pytest.approx(0.1, abs=1e-6) for r in active)
    assert any(r.command[0] < 0.3 - 1e-3 for r in active)


@pytest.mark.parametrize("seed", range(5))
def test_command_stays_within_limits(seed):
    rng = np.random.default_rng(seed)
    omni, uni = OmniModel(), UnicycleModel(v_max=0.5, omega_max=1.0)
    cap = SafetyConfig(enabled=True, speed_max_mps=0.8)
    for model, cfg in ((omni, CFG), (omni, cap), (uni, CFG), (uni, cap)):
        f = SafetyFilter(cfg, model, 0.1)
        for _ in range(30):
            pose = rng.uniform(-0.2, 0.2, 3)
            nbrs = [Neighbour(tuple(rng.uniform(-0.6, 0.6, 2)), 0.1, 0.1, 0.5) for _ in range(rng.integers(1, 5))]
            nominal = rng.uniform(-4.0, 4.0, model.command_size)
            res = f.filter(pose, nominal, nbrs)
            if not res.active:
                continue
            u = res.command
            if model is omni:
                assert np.max(np.abs(model.wheel_speeds(u))) <= model.qdot_max * (1 + 1e-6)
            else:
                assert abs(u[0]) <= model.v_max * (1 + 1e-6) and abs(u[1]) <= model.omega_max * (1 + 1e-6)
            if cfg.speed_max_mps is not None:
                assert f.centre_speed(u) <= cfg.speed_max_mps * (1 + 1e-6)


def test_speed_cap_is_enforced_away_from_everyone():
    f = SafetyFilter(SafetyConfig(enabled=True, speed_max_mps=0.5), OmniModel(), 0.1)
    res = f.filter([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    assert res.active and f.centre_speed(res.command) <= 0.5 + 1e-9
    # the cap is the inscribed octagon of the speed disc; along x it meets a face at cap cos(pi/8)
    assert res.command[0] == pytest.approx(0.5 * math.cos(math.pi / 8), abs=1e-6)


def test_range_reading_stops_a_robot_at_a_wall():
    model = UnicycleModel()
    f = SafetyFilter(CFG, model, 0.1)
    angles = 2 * math.pi * np.arange(12) / 12
    pose = np.array([0.0, 0.0, 0.0])
    wall_x = 0.6
    for _ in range(60):
        ranges = np.full(12, np.inf)
        ranges[0] = wall_x - pose[0] - model.radius  # ray straight ahead
        res = f.filter(pose, [0.5, 0.0], ranges=ranges, angles=angles)
        pose = model.step(pose, model.saturate(res.command)[0], 0.1)
    assert pose[0] + model.radius <= wall_x


def test_barriers_inflate_stale_neighbours():
    f = SafetyFilter(CFG, OmniModel(), 0.1)
    fresh = f.barriers([0, 0, 0], [Neighbour((1.0, 0.0), 0.0, 0.2, 1.0)])[1][0]
    stale = f.barriers([0, 0, 0], [Neighbour((1.0, 0.0), 0.25, 0.2, 1.0)])[1][0]
    assert fresh - stale == pytest.approx(0.25)  # 1 m/s times 0.25 s
    gone = f.barriers([0, 0, 0], [Neighbour((1.0, 0.0), CFG.max_age_s + 1, 0.2, 1.0)])[1]
    assert len(gone) == 0


def test_guard_keeps_newest_position_and_counts():
    models = {"a": OmniModel(), "b": OmniModel()}
    g = SafetyGuard(GuardConfig(safety=CFG, name="a", models=models, dt=0.1))
    g.hear("b", [0.5, 0.0], 1.0)
    g.hear("b", [5.0, 0.0], 0.5)  # older message arriving late is ignored
    (nb,) = g.neighbours(1.2)
    assert nb.position == (0.5, 0.0) and nb.age == pytest.approx(0.2)
    assert nb.speed_max == pytest.approx(max_speed(OmniModel()))
    res = g.apply([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 1.2)
    assert res.active and g.interventions == 1 and g.change_max == pytest.approx(res.change)
    assert g.counters()["safety_interventions"] == 1


def test_max_speed_of_models():
    assert max_speed(UnicycleModel(v_max=0.4)) == 0.4
    # omni: qdot_max / cos(pi/6) along a wheel's axis direction
    assert max_speed(OmniModel()) == pytest.approx(1.9 / math.cos(math.pi / 6), rel=1e-4)


def test_config_errors_name_key_value_and_rule():
    with pytest.raises(ConfigError, match=r"safety.gamma = -1.0 is not allowed; must be > 0"):
        from_table(SafetyConfig, {"gamma": -1.0}, "safety")
    with pytest.raises(ConfigError, match=r"safety.speed_max_mps = 0.0 is not allowed"):
        from_table(SafetyConfig, {"speed_max_mps": 0.0}, "safety")
    with pytest.raises(ConfigError, match=r"safety.gamma = 30.0 is not allowed; must be <= 1/run.dt"):
        SafetyFilter(SafetyConfig(gamma=30.0), OmniModel(), 0.05)


def test_guard_extrapolates_with_an_acceleration_bound():
    models = {"a": OmniModel(), "b": OmniModel()}
    g = SafetyGuard(GuardConfig(safety=SafetyConfig(enabled=True, accel_max_mps2=1.0, speed_max_mps=2.0), name="a",
                                models=models, dt=0.1))
    g.hear("b", [1.0, 0.0], 0.0)
    g.hear("b", [1.05, 0.0], 0.1)  # 0.5 m/s along x
    (nb,) = g.neighbours(0.3)
    # extrapolated 0.2 s ahead, spread 1.0 * (0.3 - 0.0) * 0.2 = 0.06 m instead of 2.0 * 0.2 = 0.4 m
    assert nb.position == pytest.approx((1.15, 0.0)) and nb.spread == pytest.approx(0.06)
    g1 = SafetyGuard(GuardConfig(safety=SafetyConfig(enabled=True, speed_max_mps=2.0), name="a", models=models,
                                 dt=0.1))
    g1.hear("b", [1.0, 0.0], 0.0)
    g1.hear("b", [1.05, 0.0], 0.1)
    (nb1,) = g1.neighbours(0.3)
    assert nb1.position == (1.05, 0.0) and nb1.spread is None  # speed bound only: 0.4 m
    f = g.filter
    assert f.barriers([0, 0, 0], [nb])[1][0] == pytest.approx(1.15 - 0.4 - CFG.margin_m - 0.06)


def test_unicycles_driving_head_on_steer_round_each_other():
    # with the look-ahead point the filter also changes omega; the deadlock rule turns both to
    # their right, so they pass each other instead of stopping nose to nose
    model = UnicycleModel(v_max=0.5, omega_max=1.0)
    dmin, results = _pair_run(model, [0.3, 0.0], [0.0, 0.0, 0.0], [2.0, 0.0, math.pi], 0.1, 150)
    assert dmin >= 2 * model.radius
    active = [r for r in results if r.active]
    assert any(abs(r.command[1]) > 0.1 for r in active)  # it steered
    assert any(r.biased for r in active)
    # and they get past each other (each ends beyond the other's start), discs apart all along
    assert _passes(model, CFG, np.array([0.0, 0.0, 0.0]), np.array([2.0, 0.0, math.pi]))


def _passes(model, cfg, pa, pb, steps=150, dt=0.1):
    """Two unicycles driving at each other: True when each ends beyond the other's start."""
    fa, fb = SafetyFilter(cfg, model, dt), SafetyFilter(cfg, model, dt)
    s = max_speed(model)
    pa, pb = pa.copy(), pb.copy()
    prev_a, prev_b = pa.copy(), pb.copy()
    for _ in range(steps):
        ra = fa.filter(pa, [0.3, 0.0], [Neighbour(tuple(prev_b[:2]), dt, model.radius, s, lookahead=0.05)])
        rb = fb.filter(pb, [0.3, 0.0], [Neighbour(tuple(prev_a[:2]), dt, model.radius, s, lookahead=0.05)])
        prev_a, prev_b = pa.copy(), pb.copy()
        pa = model.step(pa, model.saturate(ra.command)[0], dt)
        pb = model.step(pb, model.saturate(rb.command)[0], dt)
        assert np.hypot(*(pa[:2] - pb[:2])) >= 2 * model.radius
    return bool(pa[0] > 2.0 and pb[0] < 0.0)


def test_lookahead_barrier_bound_keeps_centres_apart():
    # h_z = ||z_i - p_j|| - (r_i + r_j + margin + spread + l_i + l_j) >= 0 implies
    # ||p_i - p_j|| >= ||z_i - p_j|| - l_i >= r_i + r_j + margin (docs/reference/safety.md)
    rng = np.random.default_rng(3)
    model = UnicycleModel()
    f = SafetyFilter(CFG, model, 0.1)
    lk = f.lookahead
    assert lk == pytest.approx(CFG.lookahead_m)
    for _ in range(200):
        pose = np.r_[rng.uniform(-0.5, 0.5, 2), rng.uniform(-math.pi, math.pi)]
        nb = Neighbour(tuple(rng.uniform(-0.5, 0.5, 2)), 0.1, 0.06, 0.5, lookahead=lk)
        n, hz = f.lookahead_barriers(pose, [nb])
        z = pose[:2] + lk * np.array([math.cos(pose[2]), math.sin(pose[2])])
        d = np.hypot(*(z - nb.position))
        assert hz[0] == pytest.approx(d - (model.radius + 0.06 + CFG.margin_m + 0.05 + 2 * lk))
        assert n[0] == pytest.approx((z - nb.position) / d)
        if hz[0] >= 0:
            assert np.hypot(*(pose[:2] - nb.position)) >= model.radius + 0.06 + CFG.margin_m
    # the look-ahead map is the Robotarium's uni_to_si: zdot = T(theta) (v, omega)
    th = 0.7
    T = f.lookahead_map(th)
    assert T @ [0.2, 0.0] == pytest.approx([0.2 * math.cos(th), 0.2 * math.sin(th)])
    assert T @ [0.0, 1.0] == pytest.approx([-lk * math.sin(th), lk * math.cos(th)])


def test_unicycle_safe_nominal_near_a_neighbour_passes_unchanged():
    # driving away from a close neighbour, look-ahead rows included: nothing to do
    f = SafetyFilter(CFG, UnicycleModel(), 0.1)
    res = f.filter([0.0, 0.0, 0.0], [0.3, 0.2], [Neighbour((-0.25, 0.0), 0.1, 0.06, 0.5, lookahead=0.05)])
    assert not res.active and not res.biased and np.array_equal(res.command, [0.3, 0.2])


def test_deadlock_rule_turns_right_and_is_deterministic():
    model = UnicycleModel(v_max=0.5, omega_max=1.0)
    f = SafetyFilter(CFG, model, 0.1)
    nb = [Neighbour((0.3, 0.0), 0.1, 0.06, 0.5, lookahead=0.05)]  # straight ahead, close
    a = f.filter([0.0, 0.0, 0.0], [0.3, 0.0], nb)
    b = SafetyFilter(CFG, model, 0.1).filter([0.0, 0.0, 0.0], [0.3, 0.0], nb)
    assert a.active and a.biased and np.array_equal(a.command, b.command)
    assert a.command[1] < 0  # heading +x, the right is -y: a clockwise turn
    assert abs(a.command[0]) <= model.v_max + 1e-9 and abs(a.command[1]) <= model.omega_max + 1e-9
    off = SafetyFilter(SafetyConfig(enabled=True, deadlock_turn_rad=0.0), model, 0.1)
    c = off.filter([0.0, 0.0, 0.0], [0.3, 0.0], nb)
    assert c.active and not c.biased and abs(c.command[1]) < 1e-6  # symmetric: no reason to turn
    # omni robots: off unless asked for
    assert SafetyFilter(CFG, OmniModel(), 0.05).turn == 0.0
    assert SafetyFilter(SafetyConfig(enabled=True, deadlock_turn_rad=0.5), OmniModel(), 0.05).turn == 0.5


def test_lookahead_config_errors():
    with pytest.raises(ConfigError, match=r"safety.lookahead_m = -0.1 is not allowed; must be >= 0"):
        from_table(SafetyConfig, {"lookahead_m": -0.1}, "safety")
    with pytest.raises(ConfigError, match=r"safety.deadlock_turn_rad = 2.0 is not allowed; must be in \[0, pi/2\]"):
        from_table(SafetyConfig, {"deadlock_turn_rad": 2.0}, "safety")


@pytest.mark.parametrize("model,cmd", [(UnicycleModel(), [0.4, 0.0]), (OmniModel(), [0.4, 0.0, 0.0])])
def test_stale_neighbour_direction_tightens_moving_across(model, cmd):
    # heading +y, passing a neighbour 0.2 s old at (d, 0): the heard direction is exactly across
    # the motion, but the neighbour may be anywhere within 0.1 m of where it was heard, so
    # the true direction is within kappa = 2 sin(asin(0.1 / d) / 2) and fast motion across is
    # closing in; the filter brakes it (without the kappa term it would pass the command)
    f = SafetyFilter(CFG, model, 0.1)
    d = model.radius + 0.06 + CFG.margin_m + 0.1 + 0.005  # the inflated barrier just holds (h = 5 mm)
    nb = [Neighbour((d, 0.0), 0.2, 0.06, 0.5)]
    pose = [0.0, 0.0, math.pi / 2]
    assert f._direction_error(pose, nb)[0] == pytest.approx(2 * math.sin(math.asin(0.1 / d) / 2))
    res = f.filter(pose, cmd, nb)
    assert res.active
    if model.kind == "unicycle":  # it cannot sidestep: it brakes
        assert abs(res.command[0]) < 0.4 * 0.5
    else:  # it may sidestep: closing along any direction within kappa of the heard one is bounded
        vx = (f.centre_velocity_map(pose[2]) @ res.command)[0]
        kappa = f._direction_error(pose, nb)[0]
        assert -vx - kappa * float(np.hypot(*res.command[:2])) >= -0.5 * f.gamma * 0.005 - 1e-6
        assert vx < 0  # it turned away from the neighbour
    # fresh position (age 0): no direction error, the same motion across passes unchanged
    fresh = SafetyFilter(SafetyConfig(enabled=True, lookahead_m=0.0), model, 0.1)
    assert not fresh.filter(pose, cmd, [Neighbour((d - 0.1, 0.0), 0.0, 0.06, 0.5)]).active


# -- acceleration limits: the simulator enforces them, the filter's prediction relies on them --

def _world(model: dict, n: int = 1):
    from copath.scenario import parse_scenario  # noqa: PLC0415
    from sim.world import World  # noqa: PLC0415

    robots = [{"name": f"r{i + 1}", "model": model, "pose": [2.0 * i, 0.0, 0.0]} for i in range(n)]
    return World(parse_scenario({"id": "accel", "run": {"duration_s": 5.0, "dt": 0.1}, "robots": robots,
                                 "controller": {"type": "tests.closed_loop.test_safety:build_silent"}}))


@pytest.mark.parametrize("model, cmd", [
    ({"type": "unicycle", "v_max": 0.5, "omega_max": 1.0, "a_max": 0.3, "alpha_max": 1.0}, [0.5, 1.0]),
    ({"type": "omni", "a_max": 1.0, "alpha_max": 4.0}, [0.8, -0.6, 2.0]),
])
def test_simulator_enforces_the_acceleration_limit(model, cmd):
    w = _world(model)
    m = w.models["r1"]
    dt = 0.1
    trans = (lambda c: float(np.hypot(c[0], c[1]))) if m.kind == "omni" else (lambda c: abs(float(c[0])))
    prev = np.zeros(len(cmd))
    speeds = []
    for k in range(60):  # full speed ahead, then a full stop: both at the limit, never beyond
        w.command("r1", cmd if k < 30 else np.zeros(len(cmd)))
        w.advance(dt)
        app = w.applied["r1"].copy()
        assert trans(app - prev) <= m.a_max * dt * (1 + 1e-9)
        assert abs(app[-1] - prev[-1]) <= m.alpha_max * dt * (1 + 1e-9)
        speeds.append(trans(app))
        prev = app
    assert speeds[0] == pytest.approx(m.a_max * dt)  # at the limit from rest
    assert max(speeds) == pytest.approx(trans(np.asarray(cmd)))  # the command is reached
    assert speeds[-1] == pytest.approx(0.0)  # and the stop
    # truth records (saturate_all without moving) do not advance the rate limit
    w.command("r1", cmd)
    w.saturate_all()
    w.saturate_all()
    assert trans(w.applied["r1"]) == pytest.approx(m.a_max * dt)


def test_simulator_without_a_limit_applies_the_command_at_once():
    w = _world({"type": "unicycle", "v_max": 0.5, "omega_max": 1.0})
    w.command("r1", [0.4, -0.7])
    w.advance(0.1)
    assert w.applied["r1"].tolist() == [0.4, -0.7]


@pytest.mark.parametrize("kind", ["unicycle", "omni"])
@pytest.mark.parametrize("seed", range(6))
def test_prediction_bound_holds_for_a_neighbour_at_its_limits(kind, seed):
    """A neighbour sends its velocity, then brakes, accelerates and turns at its limits (bang-bang
    commands, physics steps of 10 ms): where it really is stays within the guaranteed bound of
    the arc predicted from what it sent, at every age."""
    from copath.models import limit_change, world_velocity  # noqa: PLC0415
    from copath.safety import max_turn_rate, prediction_bound, predict_position  # noqa: PLC0415

    rng = np.random.default_rng(seed)
    if kind == "unicycle":
        m = UnicycleModel(v_max=0.5, omega_max=1.0, a_max=0.3, alpha_max=1.0)
        cmd0 = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-1.0, 1.0)])
    else:
        m = OmniModel(a_max=1.0, alpha_max=4.0)
        cmd0 = m.saturate(np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-3, 3)]))[0]
    dt_ctl, dt_phys = 0.1, 0.01
    pose = np.array([0.0, 0.0, rng.uniform(-math.pi, math.pi)])
    applied = cmd0.copy()
    vel = world_velocity(m, pose[2], applied)  # what it sends with its position
    p0 = pose[:2].copy()
    speed = float(np.hypot(vel[0], vel[1]))
    worst = 0.0
    cmd = cmd0
    for k in range(1, 301):  # 3 s
        if k % 10 == 0:  # a new extreme command every control period
            lim = [m.v_max, m.omega_max] if kind == "unicycle" else [1.0, 1.0, 3.0]
            cmd = m.saturate(rng.choice([-1.0, 1.0], len(lim)) * np.asarray(lim))[0]
        applied = limit_change(m, applied, cmd, dt_phys)
        pose = m.step(pose, applied, dt_phys)
        tau = k * dt_phys
        err = float(np.hypot(*(pose[:2] - np.asarray(predict_position(p0, vel, tau)))))
        bound = prediction_bound(tau, speed, m.a_max, m.alpha_max, max_turn_rate(m), dt_ctl)
        assert err <= bound + 1e-9, (tau, err, bound)
        worst = max(worst, err / bound)
    assert worst > 0.05  # the test exercises the bound, it is not vacuous


def test_guard_predicts_a_neighbour_with_its_sent_velocity_and_enforced_limit():
    lim = UnicycleModel(v_max=0.5, omega_max=1.0, a_max=0.3, alpha_max=1.0)
    models = {"a": lim, "b": lim, "c": UnicycleModel(v_max=0.5, omega_max=1.0)}
    g = SafetyGuard(GuardConfig(safety=SafetyConfig(enabled=True), name="a", models=models, dt=0.1))
    g.hear("b", [1.0, 0.0], 0.0, [0.2, 0.0, 0.0])  # limited: predicted along its velocity
    g.hear("c", [0.0, 1.0], 0.0, [0.2, 0.0, 0.0])  # no declared limit: the speed bound as before
    nb_b, nb_c = g.neighbours(1.0)
    assert nb_b.predicted and nb_b.position == pytest.approx((1.2, 0.0))
    assert nb_b.spread == pytest.approx(0.3 * 1.1**2 / 2 + 0.2 * 1.0 * 1.1**3 / 6)
    assert nb_b.spread < 0.5 * 1.0  # tighter than v_max * age
    assert not nb_c.predicted and nb_c.position == (0.0, 1.0) and nb_c.spread is None
    g.hear("b", [1.2, 0.0], 0.5)  # a message without the velocity (an old log): the speed bound
    assert g.neighbours(1.0)[0].spread is None


def test_barrier_lets_a_robot_with_an_acceleration_limit_close_only_as_fast_as_it_can_stop():
    cfg = SafetyConfig(enabled=True)
    nb = [Neighbour((1.0, 0.0), 0.0, 0.06, 0.5)]
    free = SafetyFilter(cfg, UnicycleModel(), 0.1)
    lim = SafetyFilter(cfg, UnicycleModel(a_max=0.25), 0.1)
    A, rhs_free, _, h = free.constraints([0, 0, 0], nb)
    _, rhs_lim, _, _ = lim.constraints([0, 0, 0], nb)
    assert rhs_free[0] == pytest.approx(-0.5 * free.gamma * h)  # the first-order barrier
    c = -rhs_lim[0]  # its stopping speed: shedding 0.25 * 0.1 m/s a period, it stops within h / 2
    assert c**2 / (2 * 0.25) + c * 0.1 / 2 == pytest.approx(h / 2)
    res = lim.filter([0, 0, 0], [0.5, 0.0], nb)
    assert res.active and res.command[0] <= c + 1e-6


def test_peer_envelope_carries_the_velocity_and_old_envelopes_stay_readable():
    import msgpack  # noqa: PLC0415

    from copath.wire.messages import PeerEnvelope, WireError, unpack  # noqa: PLC0415

    env = PeerEnvelope("r1", 3, 1.5, "follower_status", [1.0, 2.0], {"tracking_error": 0.0}, None, [0.2, -0.1, 0.5])
    assert unpack(env.pack()) == env
    old = env.to_dict()
    del old["vel"]  # a log written before the field existed
    assert unpack(msgpack.packb(old, use_bin_type=True)).vel is None
    with pytest.raises(WireError, match="peer.vel"):
        PeerEnvelope.from_dict({**env.to_dict(), "vel": [0.2, 0.1]})


@pytest.mark.parametrize("model", [
    {"type": "unicycle", "v_max": 0.5, "omega_max": 1.0, "a_max": 0.3, "alpha_max": 1.0},
    {"type": "omni", "a_max": 1.0, "alpha_max": 4.0},
    {"type": "unicycle", "v_max": 0.5, "omega_max": 1.0},
    {"type": "omni"},
])
def test_simulator_rows_apply_exactly_what_the_model_methods_do(model):
    """The simulator saturates and rate-limits all robots at once (row-wise); a robot
    predicts its own applied command, and so the velocity it sends, with the models'
    single-robot methods. The filter's prediction bound needs the two to agree."""
    from copath.models import limit_change

    w = _world(model, n=3)
    rng = np.random.default_rng(7)
    prev = {n: np.zeros(len(w.applied[n])) for n in w.applied}
    for _ in range(40):
        cmds = {n: rng.uniform(-3, 3, size=len(prev[n])) for n in prev}
        for n, c in cmds.items():
            w.command(n, c)
        w.advance(0.1)
        for n, c in cmds.items():
            m = w.models[n]
            expect = limit_change(m, prev[n], m.saturate(c)[0], 0.1)
            np.testing.assert_allclose(w.applied[n], expect, rtol=0, atol=1e-12)
            prev[n] = expect


def test_vectorised_tubes_and_predictions_are_the_scalar_ones_bit_for_bit():
    """The guard computes every kept plan's tube with numpy at once and a neighbour's arc from
    constants taken when it was heard; both must give exactly the numbers of the scalar
    predict_position / plan_velocity / commit_radius (so the filter decides the same)."""
    from copath.models import integrate_body_velocity  # noqa: PLC0415
    from copath.safety import TUBE_MARGIN_M, TubeSet, commit_radius, plan_velocity, predict_position  # noqa: PLC0415

    cfg = SafetyConfig(enabled=True, commit_accel_mps2=0.2, commit_speed_mps=0.05)
    dt = 0.1
    models = {"a": UnicycleModel(a_max=0.3, alpha_max=1.0), "b": UnicycleModel(a_max=0.3, alpha_max=1.0)}
    g = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=dt))
    rng = np.random.default_rng(7)
    plans = []
    for k in range(40):
        stamp = k * dt
        # straight (w = 0), standing (v = 0) and turning plans
        w = 0.0 if k % 5 == 0 else float(rng.uniform(-1.5, 1.5))
        vel = (0.0, 0.0, w) if k % 7 == 0 else (float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.5, 0.5)), w)
        pos = (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)))
        g.published(stamp, pos, vel)
        g.hear("b", pos, stamp, vel)
        plans.append((stamp, pos, vel))
        now = stamp + 0.05
        tubes = g.tubes(now)
        kept = [p for p in plans if now - p[0] < cfg.commit_horizon_s - 1e-9]
        assert len(tubes) == len(kept) > 0
        for t, (s, p, v) in zip(tubes, kept):
            tau = now - s
            assert t.centre == predict_position(p, v, tau)
            assert t.velocity == plan_velocity(v, tau)
            assert t.radius == commit_radius(cfg, tau) - TUBE_MARGIN_M
            assert t.growth == cfg.commit_speed_mps + cfg.commit_accel_mps2 * tau
        for nb in g.neighbours(now + 0.3):
            if nb.predicted:
                assert nb.position == predict_position(pos, vel, (now + 0.3) - stamp)
        assert len(TubeSet.of(tubes)) == len(tubes) and TubeSet.of(tubes).tubes() == tubes
    # predict_position is the closed form of the models' integrator, same numbers
    for _ in range(200):
        p, v, tau = rng.uniform(-3, 3, 2), rng.uniform(-1, 1, 3), float(rng.uniform(0, 3))
        ref = integrate_body_velocity((p[0], p[1], math.atan2(v[1], v[0])), (math.hypot(v[0], v[1]), 0.0, v[2]), tau)
        assert predict_position(p, v, tau) == (float(ref[0]), float(ref[1]))


def test_filter_takes_tubes_as_objects_or_arrays_alike():
    from copath.safety import Tube, TubeSet  # noqa: PLC0415

    cfg = SafetyConfig(enabled=True, commit_accel_mps2=0.2)
    f = SafetyFilter(cfg, UnicycleModel(a_max=0.3), 0.1)
    tubes = [Tube((0.05, 0.0), (0.3, 0.0), 0.03, 0.02), Tube((0.0, 0.1), (0.0, 0.0), 0.05, 0.0)]
    a = f.filter([0.0, 0.0, 0.0], [0.5, 0.8], (), tubes=tubes)
    b = f.filter([0.0, 0.0, 0.0], [0.5, 0.8], (), tubes=TubeSet.of(tubes))
    assert a.active and np.array_equal(a.command, b.command)


def test_a_silent_robot_is_held_as_a_static_disc_until_heard_again():
    """A robot gone quiet holds itself still once cut off, at the latest ``silent_hold_s``
    after its last stamp (docs/reference/safety.md, "A lost robot"): a static disc covering where it
    may have driven by then, not forgotten with age; heard again, an ordinary neighbour."""
    models = {"a": OmniModel(), "b": OmniModel(), "c": OmniModel()}
    cfg = SafetyConfig(enabled=True, speed_max_mps=1.0)
    g = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=0.1, silent_hold_s=1.3, handles_cut_off={"c"}))
    g.hear("b", (2.0, 0.0), 5.0)
    g.hear("c", (0.0, 2.0), 5.0)
    g.apply((0.0, 0.0, 0.0), [0.0, 0.0, 0.0], 6.1, silent={"b", "c"})
    for now in (9.0, 20.0):  # long after max_age_s (2 s): what the filter still keeps
        nbs = {nb.position: nb for nb in g.neighbours(now) if nb.age <= cfg.max_age_s}
        assert list(nbs) == [(2.0, 0.0)]  # c (its own rule) is forgotten as before; b is held
        held = nbs[(2.0, 0.0)]
        assert held.age == 0.0 and held.radius == pytest.approx(models["b"].radius + 1.3 * 1.0)
    g.apply((0.0, 0.0, 0.0), [0.0, 0.0, 0.0], 20.0, silent={"b", "c"})
    g.hear("b", (2.5, 0.0), 20.05)  # its radio is back
    g.apply((0.0, 0.0, 0.0), [0.0, 0.0, 0.0], 20.1, silent=())
    nb = next(nb for nb in g.neighbours(20.1) if nb.position == (2.5, 0.0))
    assert nb.age == pytest.approx(0.05) and nb.radius == models["b"].radius
    # without silent_hold_s (or above max_age_s) a silent robot is forgotten as before
    g2 = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=0.1, silent_hold_s=2.5))
    g2.hear("b", (2.0, 0.0), 5.0)
    g2.apply((0.0, 0.0, 0.0), [0.0, 0.0, 0.0], 6.1, silent={"b"})
    assert not [nb for nb in g2.neighbours(9.0) if nb.age <= cfg.max_age_s]


def test_deadlock_rule_keeps_its_side_when_a_held_robot_is_dead_ahead():
    """A held disc within HELD_DEADBAND_RAD of straight ahead lies on neither side: the side of
    the last decision beside a held robot stands, so a nominal aimed at the disc does not flip
    the turn at every step (the circle swap's r10, rocking in place beside r1 for 30 s); out of
    the band, or after a call with no held robot in reach, the geometry decides again."""
    model = UnicycleModel(v_max=0.5, omega_max=1.0)
    f = SafetyFilter(CFG, model, 0.1)
    pose, nominal = [0.0, 0.0, 0.0], [0.3, 0.0]
    held = Neighbour((0.3, -0.05), 0.0, 0.1, 0.5, spread=0.0, held=True)  # 0.165 rad right of ahead
    ahead_left = held._replace(position=(0.3, 0.3 * math.tan(0.5 * HELD_DEADBAND_RAD)))  # within the band, left
    fresh = SafetyFilter(CFG, model, 0.1)
    assert fresh.turn_side(pose, nominal, [ahead_left]) == 1  # no decision before: the disc is (just) left
    assert f.turn_side(pose, nominal, [held]) == -1 and f.held_side == -1
    assert f.turn_side(pose, nominal, [ahead_left]) == -1  # in the band: the last side stands
    assert f.filter(pose, nominal, [ahead_left]).command[1] > 0  # and the filter turns left with it
    beyond = held._replace(position=(0.3, 0.3 * math.tan(2 * HELD_DEADBAND_RAD)))  # left, out of the band
    assert f.turn_side(pose, nominal, [beyond]) == 1 and f.held_side == 1
    assert f.turn_side(pose, nominal, []) == 1 and f.held_side is None  # nothing held in reach: forgotten
    assert f.turn_side(pose, nominal, [ahead_left]) == 1
    f.turn_side(pose, nominal, [held])
    live = Neighbour((0.35, 0.1), 0.1, 0.06, 0.5)
    assert f.turn_side(pose, nominal, [ahead_left, live]) == 1 and f.held_side is None  # a live robot: the convention


def test_a_robot_in_a_column_takes_no_deadlock_turn_beside_a_held_robot():
    """A robot that shares its path with a teammate (``in_column``) takes no deadlock turn while a
    held robot is among its neighbours: the filter only slows it, and its detour takes it round
    (in E5.4 the turn spun the robot just behind a held one on the spot while the next one went
    past, docs/reference/safety.md, "Deadlock rule"). Beside a live robot the rule still turns,
    and a robot on a path of its own still turns beside a held one."""
    model = UnicycleModel(v_max=0.5, omega_max=1.0)
    pose, nominal = [0.0, 0.0, 0.0], [0.3, 0.0]
    held = Neighbour((0.3, 0.05), 0.0, 0.1, 0.5, spread=0.0, held=True)  # ahead, a little to the left
    live = Neighbour((0.3, 0.0), 0.1, 0.06, 0.5, lookahead=0.05)
    column = SafetyFilter(CFG, model, 0.1, in_column=True)
    own = SafetyFilter(CFG, model, 0.1)
    no_rule = SafetyFilter(SafetyConfig(enabled=True, deadlock_turn_rad=0.0), model, 0.1)
    res = column.filter(pose, nominal, [held])
    assert res.active and not res.biased  # the filter's own solution, as without the rule
    assert np.array_equal(res.command, no_rule.filter(pose, nominal, [held]).command)
    turned = own.filter(pose, nominal, [held])
    assert turned.biased and not np.allclose(turned.command, res.command)
    assert column.filter(pose, nominal, [live]).biased  # a live robot: the convention
    assert column.filter(pose, nominal, [live]).command[1] < 0


def test_deadlock_rule_turns_left_beside_a_held_robot_on_the_right():
    """A robot lost by its token, held still, does not turn: with its disc ahead on the right,
    the rule's right turn would steer into it, so it turns left; a live robot ahead keeps the
    convention (right), and so does a silent robot's disc."""
    model = UnicycleModel(v_max=0.5, omega_max=1.0)
    f = SafetyFilter(CFG, model, 0.1)
    pose, nominal = [0.0, 0.0, 0.0], [0.3, 0.0]
    held_right = Neighbour((0.3, -0.05), 0.0, 0.1, 0.5, spread=0.0, held=True)
    res = f.filter(pose, nominal, [held_right])
    assert res.active and res.biased and res.command[1] > 0  # counter-clockwise: away from the disc
    assert f.turn_side(pose, nominal, [held_right]) == -1
    # mirrored: the held disc on the left, the usual right turn
    held_left = held_right._replace(position=(0.3, 0.05))
    assert f.turn_side(pose, nominal, [held_left]) == 1
    assert f.filter(pose, nominal, [held_left]).command[1] < 0
    # a live robot ahead within the reach: the two keep the convention
    live = Neighbour((0.35, 0.1), 0.1, 0.06, 0.5)
    assert f.turn_side(pose, nominal, [held_right, live]) == 1
    # behind, or its edge beyond held_turn_m of the centre: right
    assert f.turn_side(pose, nominal, [held_right._replace(position=(-0.3, -0.05))]) == 1
    far = 0.1 + CFG.held_turn_m + 0.01
    assert f.turn_side(pose, nominal, [held_right._replace(position=(far, -0.05))]) == 1
    # a silent robot's disc (where it may have stopped) keeps the right turn
    assert f.turn_side(pose, nominal, [held_right._replace(silent=True)]) == 1
    no_rule = SafetyFilter(SafetyConfig(enabled=True, deadlock_turn_rad=0.0), model, 0.1)
    assert no_rule.turn_side(pose, nominal, [held_right]) == 1  # no rule: no side to choose
    off = SafetyFilter(SafetyConfig(enabled=True, held_turn_m=0.0), model, 0.1)
    assert off.turn_side(pose, nominal, [held_right]) == 1 and off.filter(pose, nominal, [held_right]).command[1] < 0
    with pytest.raises(ConfigError, match=r"safety.held_turn_m = -0.1 is not allowed; must be >= 0"):
        from_table(SafetyConfig, {"held_turn_m": -0.1}, "safety")


def test_while_a_detour_turns_the_robot_the_filter_brakes_and_leaves_the_turn_alone():
    """A unicycle pressed against a held disc ahead on its right, turned right on the spot by a
    detour's turn first (docs/reference/detours.md, "Turn first"; docs/reference/safety.md, "A
    turn on the spot"): the filter lets the turn through, where the soft look-ahead row (its
    look-ahead point pushed out of the disc) would turn it back left. Asked to drive as well,
    it brakes and keeps the turn rate: every row is taken at the turn's rate, so neither a soft
    row's slack nor the deadlock rule throws the rate to the other side."""
    model = UnicycleModel(v_max=0.5, omega_max=1.0)
    f = SafetyFilter(CFG, model, 0.1)
    pose = [0.0, 0.0, 0.0]
    held = Neighbour((0.2, -0.03), 0.0, 0.1, 0.5, spread=0.0, held=True)  # the look-ahead point inside its disc
    A, rhs, soft, _ = f.constraints(pose, [held])
    assert np.any((soft == 1) & (A @ np.array([0.0, -1.0]) < rhs))  # the look-ahead row refuses the turn
    assert f.filter(pose, [0.0, -1.0], [held]).command[1] > -0.9  # not turning: it turns it back
    res = f.filter(pose, [0.0, -1.0], [held], turning=True)
    assert not res.active and res.command.tolist() == [0.0, -1.0]
    free = f.filter(pose, [0.3, -0.5], [held])
    assert free.biased and free.command[1] > 0.0  # not turning: the deadlock rule turns it left
    braked = f.filter(pose, [0.3, -0.5], [held], turning=True)
    assert braked.active and not braked.biased and 0.0 <= braked.command[0] < 0.3
    assert braked.command[1] == pytest.approx(-0.5, abs=1e-9)
    A, rhs, _, _ = f.constraints(pose, [held])
    assert np.all((A @ braked.command >= rhs - 1e-9) | (soft != 0))  # the centre rows hold at the turn's rate
